//! The plain-text formats of the KF-GINS demo (i2Nav, Wuhan University), so public datasets
//! in that layout replay here and results compare line by line with KF-GINS:
//!
//! - IMU file: `sow dθx dθy dθz dvx dvy dvz` (s, rad, m/s; increments over the interval
//!   ending at `sow`, body axes forward-right-down); columns past the seventh are ignored,
//!   except the wheel speed (m/s) when `[odometer]` names its column.
//! - GNSS file: `sow lat lon h σN σE σD` (deg, deg, m, m), optionally followed by
//!   `vN vE vD σvN σvE σvD` (m/s).
//! - Navigation file (truth `.nav` and our `navresult` output):
//!   `week sow lat lon h vN vE vD roll pitch yaw` (deg, m, m/s, deg; yaw in [0, 360)).
//! - Configuration YAML: file paths, start/end time, initial state and σ, IMU noise
//!   (`imunoise: arw vrw gbstd abstd gsstd asstd corrtime`) and antenna lever arm, in the
//!   units KF-GINS documents (deg/√h, m/s/√h, deg/h, mGal, ppm, h).
//!
//! The YAML reader is a small hand-written one for the subset those files use (scalars, flow
//! lists `[a, b, c]`, one level of nesting, `#` comments): no YAML crate is in the dependency
//! set and this subset does not justify one. Anything outside it is an error naming the line.

use crate::config::{Axes, FusionConfig, GaussMarkov};
use crate::eskf::SensorErrors;
use crate::mechanisation::{wrap_pi, ImuInput, NavState};
use crate::navigator::{GnssObservation, NavSolution};
use nalgebra::Vector3;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

/// 1 mGal in m/s².
const MGAL: f64 = 1e-5;
/// 1 ppm as a fraction.
const PPM: f64 = 1e-6;

/// A problem with a KF-GINS file, naming the file and line.
#[derive(Debug, thiserror::Error)]
pub enum KfGinsError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}:{line}: {what}")]
    Syntax {
        path: String,
        line: usize,
        what: String,
    },
    #[error("{path}: {what}")]
    Config { path: String, what: String },
}

fn read(path: &Path) -> Result<String, KfGinsError> {
    std::fs::read_to_string(path).map_err(|source| KfGinsError::Io {
        path: path.display().to_string(),
        source,
    })
}

/// A value of the YAML subset: a scalar or a flow list of scalars.
#[derive(Debug, Clone, PartialEq)]
enum Value {
    Scalar(String),
    List(Vec<String>),
}

fn strip_comment(line: &str) -> &str {
    let mut quoted = false;
    for (i, c) in line.char_indices() {
        match c {
            '"' | '\'' => quoted = !quoted,
            '#' if !quoted => return &line[..i],
            _ => {}
        }
    }
    line
}

fn unquote(s: &str) -> String {
    let s = s.trim();
    let q = s.len() >= 2
        && ((s.starts_with('"') && s.ends_with('"')) || (s.starts_with('\'') && s.ends_with('\'')));
    if q {
        s[1..s.len() - 1].to_string()
    } else {
        s.to_string()
    }
}

/// Parses the YAML subset into `key` / `parent.key` → value.
fn parse_yaml(text: &str, origin: &str) -> Result<BTreeMap<String, Value>, KfGinsError> {
    let mut out = BTreeMap::new();
    let mut parent: Option<String> = None;
    for (n, raw) in text.lines().enumerate() {
        let line = strip_comment(raw).trim_end();
        if line.trim().is_empty() {
            continue;
        }
        let err = |what: &str| KfGinsError::Syntax {
            path: origin.to_string(),
            line: n + 1,
            what: what.to_string(),
        };
        let indented = line.starts_with(' ') || line.starts_with('\t');
        let Some((key, value)) = line.trim().split_once(':') else {
            return Err(err("expected `key: value`"));
        };
        let key = key.trim();
        if key.is_empty() || key.contains(' ') {
            return Err(err("bad key"));
        }
        let value = value.trim();
        let full = match (&parent, indented) {
            (Some(p), true) => format!("{p}.{key}"),
            (None, true) => return Err(err("indented key without a parent")),
            (_, false) => key.to_string(),
        };
        if value.is_empty() {
            if indented {
                return Err(err("only one level of nesting is supported"));
            }
            parent = Some(key.to_string());
            continue;
        }
        if !indented {
            parent = None;
        }
        let v = if let Some(inner) = value.strip_prefix('[') {
            let Some(inner) = inner.strip_suffix(']') else {
                return Err(err("unterminated list (lists must be on one line)"));
            };
            Value::List(
                inner
                    .split(',')
                    .map(unquote)
                    .filter(|s| !s.is_empty())
                    .collect(),
            )
        } else {
            Value::Scalar(unquote(value))
        };
        out.insert(full, v);
    }
    Ok(out)
}

/// A KF-GINS configuration file, in SI units (radians, m/s², fractions, seconds).
#[derive(Debug, Clone, PartialEq)]
pub struct KfGinsConfig {
    pub imu_path: PathBuf,
    pub gnss_path: PathBuf,
    pub output_path: PathBuf,
    pub imu_rate_hz: f64,
    pub start_s: f64,
    /// End of processing (seconds of week); `None` for the whole file (`endtime: -1`).
    pub end_s: Option<f64>,
    pub initial: NavState,
    pub initial_sensors: SensorErrors,
    pub initial_pos_std_m: Vector3<f64>,
    pub initial_vel_std_mps: Vector3<f64>,
    /// Roll, pitch, yaw σ, rad.
    pub initial_att_std_rad: Vector3<f64>,
    /// Initial σ of gyro bias, accel bias, gyro scale, accel scale when given separately
    /// (`initbgstd` …); our filter starts these at the process σ (KF-GINS's default), so
    /// [`KfGinsConfig::fusion_config`] reports them as not applied.
    pub initial_bias_std: Option<[Vector3<f64>; 4]>,
    /// Per-axis ARW (rad/√s), VRW (m/s/√s), σ of gyro bias (rad/s), accel bias (m/s²),
    /// gyro and accel scale (fractions), correlation time (s).
    pub arw: Vector3<f64>,
    pub vrw: Vector3<f64>,
    pub gyro_bias_std: Vector3<f64>,
    pub accel_bias_std: Vector3<f64>,
    pub gyro_scale_std: Vector3<f64>,
    pub accel_scale_std: Vector3<f64>,
    pub corr_time_s: f64,
    pub lever_arm_m: Vector3<f64>,
}

struct Keys<'a> {
    map: &'a BTreeMap<String, Value>,
    origin: &'a str,
}

impl Keys<'_> {
    fn err(&self, what: String) -> KfGinsError {
        KfGinsError::Config {
            path: self.origin.to_string(),
            what,
        }
    }

    fn num_of(&self, key: &str, s: &str) -> Result<f64, KfGinsError> {
        s.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| self.err(format!("`{key}`: `{s}` is not a finite number")))
    }

    fn scalar(&self, key: &str) -> Result<Option<f64>, KfGinsError> {
        match self.map.get(key) {
            None => Ok(None),
            Some(Value::Scalar(s)) => self.num_of(key, s).map(Some),
            Some(Value::List(_)) => Err(self.err(format!("`{key}` must be a number, not a list"))),
        }
    }

    fn req_scalar(&self, key: &str) -> Result<f64, KfGinsError> {
        self.scalar(key)?
            .ok_or_else(|| self.err(format!("missing key `{key}`")))
    }

    fn vec3(&self, key: &str) -> Result<Option<Vector3<f64>>, KfGinsError> {
        match self.map.get(key) {
            None => Ok(None),
            Some(Value::List(items)) if items.len() == 3 => Ok(Some(Vector3::new(
                self.num_of(key, &items[0])?,
                self.num_of(key, &items[1])?,
                self.num_of(key, &items[2])?,
            ))),
            Some(_) => Err(self.err(format!("`{key}` must be a list of 3 numbers"))),
        }
    }

    fn req_vec3(&self, key: &str) -> Result<Vector3<f64>, KfGinsError> {
        self.vec3(key)?
            .ok_or_else(|| self.err(format!("missing key `{key}`")))
    }

    fn path(&self, key: &str, base: &Path) -> Result<PathBuf, KfGinsError> {
        match self.map.get(key) {
            Some(Value::Scalar(s)) if !s.is_empty() => {
                let p = PathBuf::from(s);
                Ok(if p.is_absolute() { p } else { base.join(p) })
            }
            _ => Err(self.err(format!("missing or empty path `{key}`"))),
        }
    }
}

impl KfGinsConfig {
    /// Reads a configuration file; relative data paths resolve against `base_dir` (KF-GINS
    /// resolves them against its working directory; pass the directory you would run it in).
    pub fn from_file(path: &Path, base_dir: &Path) -> Result<Self, KfGinsError> {
        Self::from_str(&read(path)?, &path.display().to_string(), base_dir)
    }

    /// Parses configuration text; `origin` names it in errors.
    pub fn from_str(text: &str, origin: &str, base_dir: &Path) -> Result<Self, KfGinsError> {
        let map = parse_yaml(text, origin)?;
        let k = Keys { map: &map, origin };
        let known = [
            "imupath",
            "gnsspath",
            "outputpath",
            "imudatalen",
            "imudatarate",
            "starttime",
            "endtime",
            "initpos",
            "initvel",
            "initatt",
            "initgyrbias",
            "initaccbias",
            "initgyrscale",
            "initaccscale",
            "initposstd",
            "initvelstd",
            "initattstd",
            "initbgstd",
            "initbastd",
            "initsgstd",
            "initsastd",
            "imunoise.arw",
            "imunoise.vrw",
            "imunoise.gbstd",
            "imunoise.abstd",
            "imunoise.gsstd",
            "imunoise.asstd",
            "imunoise.corrtime",
            "antlever",
            "odopath",
            "odolever",
        ];
        if let Some(unknown) = map.keys().find(|key| !known.contains(&key.as_str())) {
            return Err(k.err(format!("unknown key `{unknown}`")));
        }
        let pos = k.req_vec3("initpos")?;
        let att = k.req_vec3("initatt")?.map(f64::to_radians);
        let vel = k.vec3("initvel")?.unwrap_or_else(Vector3::zeros);
        if pos.x.abs() > 89.9 || pos.y.abs() > 360.0 {
            return Err(k.err(format!(
                "`initpos` latitude/longitude out of range: {pos:?}"
            )));
        }
        let start_s = k.scalar("starttime")?.unwrap_or(0.0);
        let end_s = k.scalar("endtime")?.filter(|&e| e >= 0.0);
        let deg_h = (1.0f64).to_radians() / 3600.0;
        let sqrt_h = 60.0;
        let zero = Vector3::zeros();
        let gbstd = k.req_vec3("imunoise.gbstd")? * deg_h;
        let abstd = k.req_vec3("imunoise.abstd")? * MGAL;
        let gsstd = k.vec3("imunoise.gsstd")?.unwrap_or(zero) * PPM;
        let asstd = k.vec3("imunoise.asstd")?.unwrap_or(zero) * PPM;
        let init_bias_std = match (
            k.vec3("initbgstd")?,
            k.vec3("initbastd")?,
            k.vec3("initsgstd")?,
            k.vec3("initsastd")?,
        ) {
            (None, None, None, None) => None,
            (bg, ba, sg, sa) => Some([
                bg.map_or(gbstd, |v| v * deg_h),
                ba.map_or(abstd, |v| v * MGAL),
                sg.map_or(gsstd, |v| v * PPM),
                sa.map_or(asstd, |v| v * PPM),
            ]),
        };
        let config = Self {
            imu_path: k.path("imupath", base_dir)?,
            gnss_path: k.path("gnsspath", base_dir)?,
            output_path: k
                .path("outputpath", base_dir)
                .unwrap_or_else(|_| base_dir.to_path_buf()),
            imu_rate_hz: k.req_scalar("imudatarate")?,
            start_s,
            end_s,
            initial: NavState {
                t_s: start_s,
                lat_rad: pos.x.to_radians(),
                lon_rad: wrap_pi(pos.y.to_radians()),
                height_m: pos.z,
                vel_ned: vel,
                quat_nb: nalgebra::UnitQuaternion::from_euler_angles(att.x, att.y, att.z),
            },
            initial_sensors: SensorErrors {
                gyro_bias: k.vec3("initgyrbias")?.unwrap_or(zero) * deg_h,
                accel_bias: k.vec3("initaccbias")?.unwrap_or(zero) * MGAL,
                gyro_scale: k.vec3("initgyrscale")?.unwrap_or(zero) * PPM,
                accel_scale: k.vec3("initaccscale")?.unwrap_or(zero) * PPM,
                gnss_position_error: zero,
            },
            initial_pos_std_m: k.req_vec3("initposstd")?,
            initial_vel_std_mps: k.req_vec3("initvelstd")?,
            initial_att_std_rad: k.req_vec3("initattstd")?.map(f64::to_radians),
            initial_bias_std: init_bias_std,
            arw: k.req_vec3("imunoise.arw")?.map(f64::to_radians) / sqrt_h,
            vrw: k.req_vec3("imunoise.vrw")? / sqrt_h,
            gyro_bias_std: gbstd,
            accel_bias_std: abstd,
            gyro_scale_std: gsstd,
            accel_scale_std: asstd,
            corr_time_s: k.req_scalar("imunoise.corrtime")? * 3600.0,
            lever_arm_m: k.vec3("antlever")?.unwrap_or(zero),
        };
        if config.imu_rate_hz <= 0.0 {
            return Err(k.err(format!(
                "`imudatarate` must be positive, got {}",
                config.imu_rate_hz
            )));
        }
        Ok(config)
    }

    /// Our filter configuration for this KF-GINS setup: 21 states, the IMU model with each
    /// noise per axis as the YAML gives it, the lever arm, and initial σ (largest axis;
    /// roll/pitch share one σ).
    /// Separate initial sensor-error σ (`initbgstd` …) are not applied; check
    /// [`KfGinsConfig::initial_bias_std`] to warn about them.
    pub fn fusion_config(&self) -> FusionConfig {
        let mut c = FusionConfig {
            states: 21,
            ..FusionConfig::default()
        };
        let axes = |v: &Vector3<f64>| Axes([v.x, v.y, v.z]);
        let gm = |v: &Vector3<f64>| GaussMarkov {
            sigma: axes(v),
            tau_s: self.corr_time_s,
        };
        c.imu.arw_rad_per_sqrt_s = axes(&self.arw);
        c.imu.vrw_mps_per_sqrt_s = axes(&self.vrw);
        c.imu.gyro_bias = gm(&self.gyro_bias_std);
        c.imu.accel_bias = gm(&self.accel_bias_std);
        c.imu.gyro_scale = gm(&self.gyro_scale_std);
        c.imu.accel_scale = gm(&self.accel_scale_std);
        c.gnss.lever_arm_m = self.lever_arm_m.into();
        c.gnss.min_position_sigma_m = 1e-3;
        // KF-GINS treats GNSS fixes as independent.
        c.gnss.position_correlation_s = 0.0;
        c.initial.position_m = self.initial_pos_std_m.max().max(1e-3);
        c.initial.velocity_mps = self.initial_vel_std_mps.max().max(1e-4);
        c.initial.roll_pitch_deg = self
            .initial_att_std_rad
            .x
            .max(self.initial_att_std_rad.y)
            .to_degrees()
            .max(1e-4);
        c.initial.heading_deg = self.initial_att_std_rad.z.to_degrees().max(1e-4);
        c
    }
}

fn numbers(line: &str, want: usize, path: &str, n: usize) -> Result<Option<Vec<f64>>, KfGinsError> {
    let line = line.trim();
    if line.is_empty() || line.starts_with('#') || line.starts_with('%') {
        return Ok(None);
    }
    let cols: Vec<&str> = line
        .split(|c: char| c.is_whitespace() || c == ',')
        .filter(|s| !s.is_empty())
        .collect();
    if cols.len() < want {
        return Err(KfGinsError::Syntax {
            path: path.to_string(),
            line: n + 1,
            what: format!("expected at least {want} columns, found {}", cols.len()),
        });
    }
    cols.iter()
        .enumerate()
        .map(|(i, s)| {
            s.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| KfGinsError::Syntax {
                    path: path.to_string(),
                    line: n + 1,
                    what: format!("column {}: `{s}` is not a finite number", i + 1),
                })
        })
        .collect::<Result<Vec<f64>, _>>()
        .map(Some)
}

/// Reads a KF-GINS IMU increment file, keeping rows in [`start`, `end`]. The first row's
/// interval is 1/`rate_hz`; later ones are the time differences.
pub fn read_imu(
    path: &Path,
    rate_hz: f64,
    start: f64,
    end: Option<f64>,
) -> Result<Vec<ImuInput>, KfGinsError> {
    Ok(read_imu_with_wheel_speed(path, rate_hz, start, end, None)?.0)
}

/// Wheel-speed readings: (time, forward speed m/s).
pub type WheelSpeeds = Vec<(f64, f64)>;

/// [`read_imu`] that also reads the wheel speed (m/s) from the 1-based `column` of every
/// row, when given: (time, speed) per kept row. A row without that column is an error naming
/// the file and line.
pub fn read_imu_with_wheel_speed(
    path: &Path,
    rate_hz: f64,
    start: f64,
    end: Option<f64>,
    column: Option<usize>,
) -> Result<(Vec<ImuInput>, WheelSpeeds), KfGinsError> {
    let name = path.display().to_string();
    let mut out = Vec::new();
    let mut wheel = Vec::new();
    let mut prev_t: Option<f64> = None;
    let want = column.map_or(7, |c| c.max(7));
    for (n, line) in read(path)?.lines().enumerate() {
        let Some(v) = numbers(line, want, &name, n)? else {
            continue;
        };
        let t = v[0];
        let dt = prev_t.map_or(1.0 / rate_hz, |p| t - p);
        prev_t = Some(t);
        if t < start || end.is_some_and(|e| t > e) {
            continue;
        }
        out.push(ImuInput::Increments {
            t_s: t,
            dt_s: dt,
            dtheta: Vector3::new(v[1], v[2], v[3]),
            dvel: Vector3::new(v[4], v[5], v[6]),
        });
        if let Some(c) = column {
            wheel.push((t, v[c - 1]));
        }
    }
    Ok((out, wheel))
}

/// Reads a KF-GINS GNSS file (7 columns, or 13 with velocity and its σ).
pub fn read_gnss(path: &Path) -> Result<Vec<GnssObservation>, KfGinsError> {
    let name = path.display().to_string();
    let mut out = Vec::new();
    for (n, line) in read(path)?.lines().enumerate() {
        let Some(v) = numbers(line, 7, &name, n)? else {
            continue;
        };
        let with_vel = v.len() >= 13;
        out.push(GnssObservation {
            t_s: v[0],
            lat_rad: v[1].to_radians(),
            lon_rad: wrap_pi(v[2].to_radians()),
            height_m: v[3],
            sigma_ned_m: Vector3::new(v[4], v[5], v[6]),
            vel_ned: with_vel.then(|| Vector3::new(v[7], v[8], v[9])),
            sigma_vel_mps: if with_vel {
                Vector3::new(v[10], v[11], v[12])
            } else {
                Vector3::repeat(f64::NAN)
            },
        });
    }
    Ok(out)
}

/// One row of a navigation file (truth `.nav` or navresult).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavRow {
    pub week: u32,
    pub nav: NavState,
}

/// Reads a KF-GINS navigation file.
pub fn read_nav(path: &Path) -> Result<Vec<NavRow>, KfGinsError> {
    let name = path.display().to_string();
    let mut out = Vec::new();
    for (n, line) in read(path)?.lines().enumerate() {
        let Some(v) = numbers(line, 11, &name, n)? else {
            continue;
        };
        let (r, p, y) = (v[8].to_radians(), v[9].to_radians(), v[10].to_radians());
        out.push(NavRow {
            week: v[0].clamp(0.0, u32::MAX as f64) as u32,
            nav: NavState {
                t_s: v[1],
                lat_rad: v[2].to_radians(),
                lon_rad: wrap_pi(v[3].to_radians()),
                height_m: v[4],
                vel_ned: Vector3::new(v[5], v[6], v[7]),
                quat_nb: nalgebra::UnitQuaternion::from_euler_angles(r, p, y),
            },
        });
    }
    Ok(out)
}

/// Writes one navigation-file line for `nav` (yaw in [0, 360)).
pub fn format_nav_line(week: u32, nav: &NavState) -> String {
    let (r, p, y) = nav.quat_nb.euler_angles();
    format!(
        "{week} {:.6} {:.10} {:.10} {:.4} {:.6} {:.6} {:.6} {:.8} {:.8} {:.8}",
        nav.t_s,
        nav.lat_rad.to_degrees(),
        nav.lon_rad.to_degrees(),
        nav.height_m,
        nav.vel_ned.x,
        nav.vel_ned.y,
        nav.vel_ned.z,
        r.to_degrees(),
        p.to_degrees(),
        y.to_degrees().rem_euclid(360.0),
    )
}

/// Writes a trajectory in KF-GINS's navresult format.
pub fn write_navresult(
    path: &Path,
    week: u32,
    solutions: &[NavSolution],
) -> Result<(), KfGinsError> {
    let io = |source| KfGinsError::Io {
        path: path.display().to_string(),
        source,
    };
    let file = std::fs::File::create(path).map_err(io)?;
    let mut w = std::io::BufWriter::new(file);
    for s in solutions {
        writeln!(w, "{}", format_nav_line(week, &s.nav)).map_err(io)?;
    }
    w.flush().map_err(io)
}

/// Replays the files a KF-GINS configuration names, starting from its initial state, with
/// GNSS withheld in `outages` ([start, end) in seconds of week).
pub fn replay_files(
    config: &KfGinsConfig,
    outages: &[(f64, f64)],
    smooth: bool,
) -> Result<crate::navigator::ReplayResult, KfGinsError> {
    replay_files_with(config, &config.fusion_config(), outages, smooth)
}

/// [`replay_files`] with the filter configuration given (the KF-GINS one with motion
/// constraints added, see [`crate::config::Constraints`]).
pub fn replay_files_with(
    config: &KfGinsConfig,
    fusion: &FusionConfig,
    outages: &[(f64, f64)],
    smooth: bool,
) -> Result<crate::navigator::ReplayResult, KfGinsError> {
    let (imu, wheel) = read_imu_with_wheel_speed(
        &config.imu_path,
        config.imu_rate_hz,
        config.start_s,
        config.end_s,
        fusion.odometer.enabled.then_some(fusion.odometer.column),
    )?;
    if imu.is_empty() {
        return Err(KfGinsError::Config {
            path: config.imu_path.display().to_string(),
            what: format!(
                "no IMU rows between {} and {:?} s",
                config.start_s, config.end_s
            ),
        });
    }
    let all = read_gnss(&config.gnss_path)?;
    let (imu_from, imu_to) = (imu[0].t_s(), imu[imu.len() - 1].t_s());
    let gnss: Vec<GnssObservation> = all
        .iter()
        .copied()
        .filter(|g| g.t_s >= imu_from && g.t_s <= imu_to)
        .collect();
    if gnss.is_empty() {
        let span = match (all.first(), all.last()) {
            (Some(a), Some(b)) => format!("its fixes span {:.3}-{:.3} s", a.t_s, b.t_s),
            _ => "it has no fixes".to_string(),
        };
        return Err(KfGinsError::Config {
            path: config.gnss_path.display().to_string(),
            what: format!(
                "no GNSS fix within the IMU data ({imu_from:.3}-{imu_to:.3} s of week): {span}; GNSS and IMU do not overlap"
            ),
        });
    }
    let options = crate::navigator::ReplayOptions {
        initial: Some(config.initial),
        initial_sensors: config.initial_sensors,
        outages: outages.to_vec(),
        smooth,
        calibration: None,
    };
    Ok(crate::navigator::replay_with_wheel_speed(
        fusion, imu, gnss, wheel, options,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    const DEMO: &str = r#"
# comment
imupath: "./dataset/imu.txt"
gnsspath: "./dataset/GNSS-RTK.txt"   # trailing comment
outputpath: "./dataset"
imudatalen: 7
imudatarate: 200
starttime: 456300
endtime: -1
initpos: [ 30.4447873701, 114.4718632047, 20.899 ]
initvel: [ 0.0, 0.0, 0.0 ]
initatt: [ 0.85421502, -2.03480295, 185.70235133 ]
initgyrbias: [ 0, 0, 0 ]
initaccbias: [ 0, 0, 0 ]
initgyrscale: [ 0, 0, 0 ]
initaccscale: [ 0, 0, 0 ]
initposstd: [ 0.005, 0.004, 0.008 ]
initvelstd: [ 0.003, 0.004, 0.004 ]
initattstd: [ 0.003, 0.003, 0.023 ]
imunoise:
  arw: [0.003, 0.003, 0.003]
  vrw: [0.03, 0.03, 0.03]
  gbstd: [0.027, 0.027, 0.027]
  abstd: [15.0, 15.0, 15.0]
  gsstd: [300.0, 300.0, 300.0]
  asstd: [300.0, 300.0, 300.0]
  corrtime: 4.0
antlever:  [ 0.136, -0.301, -0.184 ]
"#;

    #[test]
    fn reads_the_demo_configuration_in_si_units() {
        let c = KfGinsConfig::from_str(DEMO, "demo.yaml", Path::new("/data")).expect("valid");
        assert_eq!(c.imu_path, PathBuf::from("/data/./dataset/imu.txt"));
        assert_eq!(c.end_s, None);
        assert_eq!(c.start_s, 456300.0);
        assert!((c.arw.x - 0.003f64.to_radians() / 60.0).abs() < 1e-15);
        assert!((c.accel_bias_std.y - 15e-5).abs() < 1e-15);
        assert!((c.gyro_scale_std.z - 300e-6).abs() < 1e-15);
        assert_eq!(c.corr_time_s, 4.0 * 3600.0);
        let (_, _, yaw) = c.initial.quat_nb.euler_angles();
        assert!((yaw.to_degrees().rem_euclid(360.0) - 185.70235133).abs() < 1e-9);
        let f = c.fusion_config();
        f.validate().expect("usable filter config");
        assert_eq!(f.states, 21);
        assert_eq!(f.gnss.lever_arm_m, [0.136, -0.301, -0.184]);
    }

    #[test]
    fn configuration_errors_name_key_and_line() {
        let e = KfGinsConfig::from_str(
            &DEMO.replace("imudatarate: 200", "imudatarate: fast"),
            "c.yaml",
            Path::new("."),
        )
        .expect_err("not a number");
        assert!(
            e.to_string().contains("imudatarate") && e.to_string().contains("fast"),
            "{e}"
        );
        let e = KfGinsConfig::from_str(
            &DEMO.replace("antlever:  [ 0.136, -0.301, -0.184 ]", "antlevr: [0,0,0]"),
            "c.yaml",
            Path::new("."),
        )
        .expect_err("unknown key");
        assert!(e.to_string().contains("antlevr"), "{e}");
        let e =
            KfGinsConfig::from_str("initpos: [1, 2\n", "c.yaml", Path::new(".")).expect_err("list");
        assert!(e.to_string().contains("c.yaml:1"), "{e}");
        let e = KfGinsConfig::from_str(
            &DEMO.replace(
                "initatt: [ 0.85421502, -2.03480295, 185.70235133 ]",
                "initatt: [1, 2]",
            ),
            "c.yaml",
            Path::new("."),
        )
        .expect_err("short list");
        assert!(e.to_string().contains("initatt"), "{e}");
    }

    #[test]
    fn nav_line_round_trips() {
        let dir = tempfile::tempdir().expect("tempdir");
        let nav = NavState {
            t_s: 456300.005,
            lat_rad: 0.53,
            lon_rad: 1.99,
            height_m: 21.5,
            vel_ned: Vector3::new(1.0, -2.0, 0.1),
            quat_nb: nalgebra::UnitQuaternion::from_euler_angles(0.01, -0.02, -2.0),
        };
        let p = dir.path().join("x.nav");
        std::fs::write(
            &p,
            format!(
                "{}\n\n{}\n",
                format_nav_line(2200, &nav),
                format_nav_line(2200, &nav)
            ),
        )
        .expect("write");
        let rows = read_nav(&p).expect("read");
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0].week, 2200);
        let back = rows[0].nav;
        assert!(
            (back.lat_rad - nav.lat_rad).abs() < 1e-11
                && (back.vel_ned - nav.vel_ned).norm() < 1e-6
        );
        assert!((back.quat_nb.inverse() * nav.quat_nb).angle() < 1e-9);
        std::fs::write(&p, "2200 1 2 3\n").expect("write");
        let e = read_nav(&p).expect_err("short line");
        assert!(
            e.to_string().contains("x.nav:1") && e.to_string().contains("11 columns"),
            "{e}"
        );
        std::fs::write(&p, "1 2 3 4 5 6 nan\n").expect("write");
        let e = read_gnss(&p).expect_err("nan");
        assert!(e.to_string().contains("column 7"), "{e}");
    }
}
