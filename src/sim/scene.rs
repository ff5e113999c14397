//! Scenes: the TOML description of a simulation run (duration, rate, place, motion,
//! temperature, sensors with presets and overrides, seed, wanted outputs), parsed and
//! checked into a [`Scene`] the runner executes. Unknown keys are errors that name the key
//! and where it is; see docs/simulator.md for the format.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use nalgebra::UnitQuaternion;
use serde::Deserialize;

use super::attitude::{AttitudeProgram, RateTableSpec, TumbleSpec};
use super::gnss_model::{GnssSpec, GNSS_PRESETS};
use super::imu_model::{Channels, ImuSpec};
use super::motion::{MotionSpec, Segment, VehicleDynamics};
use super::presets::{imu_preset, imu_preset_names};
use super::serve::Fault;
use super::temperature::TemperatureProfile;
use super::wire::protocol_for;
use imulab_drivers::codec::{ImuOutput, Protocol};

/// Default start of simulated wall-clock time: 2026-01-05T00:00:00Z (a GPS week start is
/// not needed; any fixed instant keeps runs reproducible).
const DEFAULT_START_UTC_NS: i64 = 1_767_571_200_000_000_000;
/// Host monotonic clock at the first sample, ns.
pub const START_MONO_NS: i64 = 1_000_000_000;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    duration_s: f64,
    rate_hz: f64,
    #[serde(default)]
    seed: u64,
    start_utc: Option<toml::value::Datetime>,
    location: Location,
    motion: MotionFile,
    #[serde(default)]
    temperature: TemperatureProfile,
    #[serde(default)]
    imu: Vec<SensorEntry>,
    #[serde(default)]
    gnss: Vec<SensorEntry>,
    #[serde(default)]
    outputs: Outputs,
    #[serde(default)]
    fault: Vec<Fault>,
}

/// Where the scene takes place.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Location {
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Height above the WGS-84 ellipsoid, m.
    pub height_m: f64,
}

#[derive(Debug, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
enum MotionFile {
    Static {
        #[serde(default)]
        roll_deg: f64,
        #[serde(default)]
        pitch_deg: f64,
        #[serde(default)]
        heading_deg: f64,
    },
    Segments {
        #[serde(default)]
        heading_deg: f64,
        #[serde(default)]
        speed_mps: f64,
        segments: Vec<Segment>,
        #[serde(default)]
        vehicle: VehicleDynamics,
    },
    TruthFile {
        path: PathBuf,
    },
    Tumble(TumbleSpec),
    RateTable(RateTableSpec),
}

/// A sensor table: its name, an optional preset, and everything else as overrides.
#[derive(Debug, Deserialize)]
struct SensorEntry {
    name: String,
    preset: Option<String>,
    #[serde(flatten)]
    overrides: toml::Table,
}

/// Which optional outputs the scene wants.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Outputs {
    /// The true trajectory (`/truth/nav`).
    pub truth_nav: bool,
    /// The true biases and error-free inputs of each IMU (`/truth/imu/<name>`).
    pub truth_imu: bool,
    /// Write truth every this many samples (1: every sample).
    pub truth_every: u32,
}

impl Default for Outputs {
    fn default() -> Self {
        Outputs {
            truth_nav: true,
            truth_imu: true,
            truth_every: 1,
        }
    }
}

/// How the truth moves.
#[derive(Debug, Clone, PartialEq)]
pub enum Motion {
    /// Standing still with this attitude (body → NED): only gravity and earth rate.
    Static { quat_nb: UnitQuaternion<f64> },
    /// A vehicle driving the segments (see [`super::motion`]).
    Segments(MotionSpec),
    /// Truth read from a CSV file (see [`super::truth_file`]).
    TruthFile(PathBuf),
    /// Static poses joined by rotations (see [`super::attitude`]).
    Tumble(TumbleSpec),
    /// Constant-rate segments about one body axis (see [`super::attitude`]).
    RateTable(RateTableSpec),
}

/// One IMU of a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuEntry {
    pub name: String,
    pub spec: ImuSpec,
    pub channels: Channels,
    /// Protocol it is served in by `imulab sim --serve` (see [`super::wire`]).
    pub protocol: Protocol,
    /// What a `vectornav` or `mip` IMU sends: its rates, delta theta / delta velocity over
    /// the sample interval, or both.
    pub output: ImuOutput,
}

/// One GNSS receiver of a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct GnssEntry {
    pub name: String,
    pub spec: GnssSpec,
    /// Protocol it is served in by `imulab sim --serve` (see [`super::wire`]).
    pub protocol: Protocol,
}

/// A checked scene, ready to run.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    pub duration_s: f64,
    pub rate_hz: f64,
    pub seed: u64,
    /// Wall-clock time of the first sample, ns since the Unix epoch.
    pub start_wall_ns: i64,
    pub location: Location,
    pub motion: Motion,
    pub temperature: TemperatureProfile,
    pub imus: Vec<ImuEntry>,
    pub gnss: Vec<GnssEntry>,
    pub outputs: Outputs,
    /// Faults a byte-stream serve injects (`[[fault]]` tables; see [`super::serve`]).
    pub faults: Vec<Fault>,
    /// The scene file as written (kept in the session manifest).
    pub source: toml::Table,
}

/// Alternative ways to give one quantity: an override in one form removes the preset's
/// value in the other.
const ALTERNATIVES: &[&[&str]] = &[
    &["arw_deg_rth", "noise_density_dps_rthz"],
    &["vrw_mg_rth", "noise_density_ug_rthz"],
];

impl Scene {
    /// Reads and checks the scene file at `path`; relative paths inside are taken relative
    /// to the file's directory.
    pub fn load(path: &Path) -> Result<Scene> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read scene {}", path.display()))?;
        let dir = path.parent().unwrap_or(Path::new("."));
        Scene::parse(&text, dir).with_context(|| format!("scene {}", path.display()))
    }

    /// Parses and checks scene text; `base_dir` resolves relative paths.
    pub fn parse(text: &str, base_dir: &Path) -> Result<Scene> {
        let file: SceneFile = toml::from_str(text).map_err(|e| anyhow!("{e}"))?;
        let source: toml::Table = toml::from_str(text).map_err(|e| anyhow!("{e}"))?;
        if !(file.rate_hz.is_finite() && file.rate_hz > 0.0 && file.rate_hz <= 100_000.0) {
            bail!("rate_hz must be in (0, 100000], got {}", file.rate_hz);
        }
        if !(file.duration_s.is_finite() && file.duration_s > 0.0) {
            bail!("duration_s must be > 0, got {}", file.duration_s);
        }
        let samples = file.duration_s * file.rate_hz;
        if samples > 1e11 {
            bail!("duration_s × rate_hz = {samples:.3e} samples is too many");
        }
        let loc = file.location;
        if !(loc.lat_deg.abs() <= 89.9 && loc.lon_deg.is_finite() && loc.height_m.is_finite()) {
            bail!(
                "location: lat_deg must be within ±89.9 and all values finite, got {} {} {}",
                loc.lat_deg,
                loc.lon_deg,
                loc.height_m
            );
        }
        let start_wall_ns = match &file.start_utc {
            None => DEFAULT_START_UTC_NS,
            Some(dt) => chrono::DateTime::parse_from_rfc3339(&dt.to_string())
                .map_err(|e| anyhow!("start_utc {dt}: {e} (write e.g. 2026-03-02T08:00:00Z)"))?
                .timestamp_nanos_opt()
                .ok_or_else(|| anyhow!("start_utc {dt} is out of range"))?,
        };
        let motion = match file.motion {
            MotionFile::Static {
                roll_deg,
                pitch_deg,
                heading_deg,
            } => {
                if !(roll_deg.is_finite() && pitch_deg.is_finite() && heading_deg.is_finite()) {
                    bail!("motion: roll_deg, pitch_deg and heading_deg must be finite");
                }
                Motion::Static {
                    quat_nb: UnitQuaternion::from_euler_angles(
                        roll_deg.to_radians(),
                        pitch_deg.to_radians(),
                        heading_deg.to_radians(),
                    ),
                }
            }
            MotionFile::Segments {
                heading_deg,
                speed_mps,
                segments,
                vehicle,
            } => Motion::Segments(MotionSpec {
                lat_deg: loc.lat_deg,
                lon_deg: loc.lon_deg,
                height_m: loc.height_m,
                heading_deg,
                speed_mps,
                segments,
                vehicle,
            }),
            MotionFile::TruthFile { path } => Motion::TruthFile(base_dir.join(path)),
            MotionFile::Tumble(spec) => {
                AttitudeProgram::tumble(&spec, file.seed, loc.lat_deg, loc.lon_deg, loc.height_m)
                    .map_err(|e| anyhow!("motion (tumble): {e}"))?;
                Motion::Tumble(spec)
            }
            MotionFile::RateTable(spec) => {
                AttitudeProgram::rate_table(&spec, loc.lat_deg, loc.lon_deg, loc.height_m)
                    .map_err(|e| anyhow!("motion (rate_table): {e}"))?;
                Motion::RateTable(spec)
            }
        };
        file.temperature
            .validate()
            .map_err(|e| anyhow!("temperature: {e}"))?;
        if file.outputs.truth_every == 0 {
            bail!("outputs.truth_every must be >= 1");
        }
        let mut names: Vec<&str> = Vec::new();
        let mut imus = Vec::new();
        for (i, entry) in file.imu.iter().enumerate() {
            let at = format!("imu[{i}] ({})", entry.name);
            check_name(&entry.name, &names).with_context(|| at.clone())?;
            names.push(&entry.name);
            imus.push(imu_entry(entry).with_context(|| at.clone())?);
        }
        let mut gnss = Vec::new();
        for (i, entry) in file.gnss.iter().enumerate() {
            let at = format!("gnss[{i}] ({})", entry.name);
            check_name(&entry.name, &names).with_context(|| at.clone())?;
            names.push(&entry.name);
            gnss.push(gnss_entry(entry, file.rate_hz).with_context(|| at.clone())?);
        }
        for (i, fault) in file.fault.iter().enumerate() {
            fault
                .check(&names)
                .with_context(|| format!("fault[{i}] ({})", fault.sensor))?;
        }
        Ok(Scene {
            duration_s: file.duration_s,
            rate_hz: file.rate_hz,
            seed: file.seed,
            start_wall_ns,
            location: loc,
            motion,
            temperature: file.temperature,
            imus,
            gnss,
            outputs: file.outputs,
            faults: file.fault,
            source,
        })
    }

    /// Sets the seed (also in `source`, so a session records the seed actually used).
    pub fn set_seed(&mut self, seed: u64) {
        self.seed = seed;
        // TOML integers are i64: seeds above i64::MAX cannot be written back.
        let as_toml =
            i64::try_from(seed).map_or(toml::Value::String(seed.to_string()), toml::Value::Integer);
        self.source.insert("seed".into(), as_toml);
    }

    /// Number of truth/IMU samples the scene runs.
    pub fn samples(&self) -> u64 {
        (self.duration_s * self.rate_hz).round() as u64
    }
}

fn check_name(name: &str, taken: &[&str]) -> Result<()> {
    if name.is_empty()
        || name.len() > 63
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
    {
        bail!("name must be 1-63 ASCII letters, digits, '_' or '-', got {name:?}");
    }
    if taken.contains(&name) {
        bail!("name {name:?} is used twice");
    }
    Ok(())
}

/// Overrides `base` with `over`, table by table; an override of one of a set of
/// [`ALTERNATIVES`] removes the others from `base`.
fn merge(base: &mut toml::Table, over: &toml::Table) {
    for (key, value) in over {
        for group in ALTERNATIVES {
            if group.contains(&key.as_str()) {
                for other in group.iter().filter(|k| **k != key) {
                    base.remove(*other);
                }
            }
        }
        match (base.get_mut(key), value) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
            _ => {
                base.insert(key.clone(), value.clone());
            }
        }
    }
}

fn imu_entry(entry: &SensorEntry) -> Result<ImuEntry> {
    let base = match &entry.preset {
        None => ImuSpec::default(),
        Some(p) => imu_preset(p).ok_or_else(|| {
            anyhow!(
                "unknown IMU preset {p:?}; known: {}",
                imu_preset_names().join(", ")
            )
        })?,
    };
    let mut overrides = entry.overrides.clone();
    let protocol = take_protocol(&mut overrides, false)?;
    let output = take_output(&mut overrides, protocol)?;
    let channels = match overrides.remove("channels") {
        None => Channels::ALL,
        Some(v) => {
            let list: Vec<String> = v.try_into().map_err(|e| {
                anyhow!("channels: {e} (write e.g. channels = [\"gyro\"] or [\"gyro.z\"])")
            })?;
            let mut c = Channels {
                gyro: [false; 3],
                accel: [false; 3],
            };
            for name in &list {
                let (triad, axis) = match name.split_once('.') {
                    Some((t, a)) => (t, Some(a)),
                    None => (name.as_str(), None),
                };
                let axes = match triad {
                    "gyro" => &mut c.gyro,
                    "accel" => &mut c.accel,
                    _ => bail!(
                        "channels: unknown channel {name:?} (gyro, accel, or one axis as gyro.x, accel.z, ...)"
                    ),
                };
                match axis {
                    None => *axes = [true; 3],
                    Some("x") => axes[0] = true,
                    Some("y") => axes[1] = true,
                    Some("z") => axes[2] = true,
                    Some(_) => bail!("channels: unknown axis in {name:?} (x, y, z)"),
                }
            }
            if !(c.has_gyro() || c.has_accel()) {
                bail!("channels: name at least one of gyro, accel");
            }
            c
        }
    };
    let mut table = toml::Table::try_from(&base).context("internal: preset to TOML")?;
    merge(&mut table, &overrides);
    // Each part is read on its own so an error names the table it is in.
    let mut spec = base;
    for (key, value) in table {
        let at = |e: toml::de::Error| anyhow!("{key}: {}", one_line(&e));
        match key.as_str() {
            "gyro" => spec.gyro = value.try_into().map_err(at)?,
            "accel" => spec.accel = value.try_into().map_err(at)?,
            "timing" => spec.timing = value.try_into().map_err(at)?,
            "thermal" => spec.thermal = value.try_into().map_err(at)?,
            "reference_temp_c" => spec.reference_temp_c = value.try_into().map_err(at)?,
            _ => bail!(
                "unknown key `{key}`, expected one of `name`, `preset`, `channels`, `protocol`, `output`, `gyro`, `accel`, `timing`, `thermal`, `reference_temp_c`"
            ),
        }
    }
    spec.validate().map_err(|e| anyhow!("{e}"))?;
    if protocol == Protocol::Vectornav
        && output != ImuOutput::Rates
        && !(channels.has_gyro() && channels.has_accel())
    {
        bail!("output: VectorNav's DeltaThetaVel carries delta theta and delta velocity together: simulate both gyro and accel, or output = \"rates\"");
    }
    Ok(ImuEntry {
        name: entry.name.clone(),
        spec,
        channels,
        protocol,
        output,
    })
}

/// Removes the `output` key of an IMU table: rates (default), deltas or both, the last two
/// for the protocols that carry deltas.
fn take_output(overrides: &mut toml::Table, protocol: Protocol) -> Result<ImuOutput> {
    let Some(value) = overrides.remove("output") else {
        return Ok(ImuOutput::Rates);
    };
    let output: ImuOutput = value.try_into().map_err(|e| {
        anyhow!(
            "output: {} (\"rates\", \"deltas\" or \"both\")",
            one_line(&e)
        )
    })?;
    if output != ImuOutput::Rates && !matches!(protocol, Protocol::Vectornav | Protocol::Mip) {
        bail!(
            "output: protocol `{}` sends rates only (delta theta / delta velocity: vectornav, mip)",
            protocol.name()
        );
    }
    Ok(output)
}

/// Removes the `protocol` key from a sensor table and checks it for the sensor kind.
fn take_protocol(overrides: &mut toml::Table, gnss: bool) -> Result<Protocol> {
    let name = match overrides.remove("protocol") {
        None => None,
        Some(toml::Value::String(s)) => Some(s),
        Some(other) => bail!("protocol: expected a string, got {other}"),
    };
    protocol_for(name.as_deref(), gnss)
}

fn gnss_entry(entry: &SensorEntry, rate_hz: f64) -> Result<GnssEntry> {
    let preset = entry.preset.as_deref().unwrap_or("standalone");
    let base = GnssSpec::preset(preset).ok_or_else(|| {
        let known: Vec<&str> = GNSS_PRESETS.iter().map(|p| p.0).collect();
        anyhow!(
            "unknown GNSS preset {preset:?}; known: {}",
            known.join(", ")
        )
    })?;
    let mut overrides = entry.overrides.clone();
    let protocol = take_protocol(&mut overrides, true)?;
    let mut table = toml::Table::try_from(&base).context("internal: preset to TOML")?;
    merge(&mut table, &overrides);
    let spec: GnssSpec = toml::Value::Table(table)
        .try_into()
        .map_err(|e| anyhow!("{}", one_line(&e)))?;
    spec.validate().map_err(|e| anyhow!("{e}"))?;
    let ratio = rate_hz / spec.rate_hz;
    if (ratio - ratio.round()).abs() > 1e-9 || ratio < 1.0 {
        bail!(
            "rate_hz {} must divide the scene rate {rate_hz} Hz (fixes fall on truth samples)",
            spec.rate_hz
        );
    }
    Ok(GnssEntry {
        name: entry.name.clone(),
        spec,
        protocol,
    })
}

fn one_line(e: &toml::de::Error) -> String {
    e.message().replace('\n', " ")
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = r#"
        duration_s = 10
        rate_hz = 100
        seed = 5
        [location]
        lat_deg = 48.0
        lon_deg = 11.0
        height_m = 500
        [motion]
        kind = "static"
        [[imu]]
        name = "a"
        preset = "bench-cheap"
        channels = ["gyro"]
        [imu.gyro]
        noise_density_dps_rthz = [0.01, 0.01, 0.01]
        bias_dph = [1, 2, 3]
        [[gnss]]
        name = "rx"
        preset = "rtk"
        rate_hz = 5
        periodic_outage = { every_s = 4, duration_s = 1 }
    "#;

    #[test]
    fn parses_presets_and_overrides() {
        let s = Scene::parse(MINIMAL, Path::new(".")).unwrap();
        assert_eq!(s.samples(), 1000);
        let imu = &s.imus[0];
        assert_eq!(imu.channels, Channels::GYRO);
        assert_eq!(imu.spec.gyro.bias_dph, [1.0, 2.0, 3.0]);
        // The density override replaces the preset's ARW; the rest of the preset stays.
        assert_eq!(imu.spec.gyro.arw_deg_rth, None);
        assert_eq!(imu.spec.gyro.bias_instability_dph, [5.3, 4.8, 4.0]);
        assert_eq!(s.gnss[0].spec.rate_hz, 5.0);
        assert!(s.gnss[0].spec.in_outage(4.5));
        assert!(s.outputs.truth_nav);
    }

    fn err(text: &str) -> String {
        format!("{:#}", Scene::parse(text, Path::new(".")).unwrap_err())
    }

    #[test]
    fn unknown_keys_say_where() {
        let e = err(&MINIMAL.replace("bias_dph", "bias_dhp"));
        assert!(
            e.contains("imu[0] (a): gyro: unknown field `bias_dhp`"),
            "{e}"
        );
        let e = err(&MINIMAL.replace("[imu.gyro]", "[imu.gyros]"));
        assert!(e.contains("imu[0] (a): unknown key `gyros`"), "{e}");
        let e = err(&MINIMAL.replace("seed = 5", "seed = 5\nsede = 6"));
        assert!(e.contains("sede") && e.contains("line"), "{e}");
        let e = err(&MINIMAL.replace("periodic_outage", "periodic_outages"));
        assert!(
            e.contains("gnss[0] (rx)") && e.contains("periodic_outages"),
            "{e}"
        );
        let e = err(&MINIMAL.replace("kind = \"static\"", "kind = \"static\"\nroll = 1"));
        assert!(e.contains("roll"), "{e}");
    }

    #[test]
    fn bad_values_are_explained() {
        let e = err(&MINIMAL.replace("preset = \"bench-cheap\"", "preset = \"cheap\""));
        assert!(
            e.contains("unknown IMU preset") && e.contains("bench-cheap"),
            "{e}"
        );
        let e = err(&MINIMAL.replace("rate_hz = 5", "rate_hz = 3"));
        assert!(e.contains("must divide"), "{e}");
        let e = err(&MINIMAL.replace("channels = [\"gyro\"]", "channels = [\"mag\"]"));
        assert!(e.contains("mag"), "{e}");
        let e = err(&MINIMAL.replace("name = \"rx\"", "name = \"a\""));
        assert!(e.contains("used twice"), "{e}");
        let e = err(&MINIMAL.replace("bias_dph = [1, 2, 3]", "bias_dph = [1, 2]"));
        assert!(e.contains("imu[0]"), "{e}");
        let e = err(&MINIMAL.replace("duration_s = 10", "duration_s = -1"));
        assert!(e.contains("duration_s"), "{e}");
        let e = err("not toml [");
        assert!(e.contains("line"), "{e}");
    }

    #[test]
    fn channels_select_single_axes() {
        let one = MINIMAL.replace(
            r#"channels = ["gyro"]"#,
            r#"channels = ["gyro.z", "accel.x"]"#,
        );
        let s = Scene::parse(&one, Path::new(".")).unwrap();
        assert_eq!(
            s.imus[0].channels,
            Channels {
                gyro: [false, false, true],
                accel: [true, false, false]
            }
        );
        let bad = MINIMAL.replace(r#"channels = ["gyro"]"#, r#"channels = ["gyro.w"]"#);
        let e = format!("{:#}", Scene::parse(&bad, Path::new(".")).unwrap_err());
        assert!(e.contains("unknown axis in \"gyro.w\""), "{e}");
    }
}
