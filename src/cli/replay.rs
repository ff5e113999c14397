//! `imulab replay`: GNSS/INS replay through the error-state filter, of a recorded or
//! simulated session (HDF5 store) or of data in the KF-GINS text formats. Writes the
//! trajectory as HDF5, CSV, GeoJSON and KF-GINS navresult, and, with a truth (simulated
//! sessions, or `--truth FILE.nav`), the errors: RMS / p95 / max, drift per outage, NEES.

use crate::fusion::config::FusionConfig;
use crate::fusion::export;
use crate::fusion::kfgins::{self, KfGinsConfig};
use crate::fusion::mechanisation::NavState;
use crate::fusion::metrics::{errors, overlap_s, summarise};
use crate::fusion::navigator::{NavSolution, ReplayOptions, ReplayResult, ReplayStats};
use crate::fusion::session;
use crate::study::noise;
use anyhow::{bail, Context};
use clap::Args;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
#[command(
    group = clap::ArgGroup::new("input").required(true).args(["session", "kf_gins"]),
    after_help = "Examples:\n  imulab replay sessions/drive1 --outages every:300:60 --smooth\n  imulab replay sessions/drive1 --outages every:300:60 --compensate thermal-model.json\n  imulab replay sessions/drive1 --outages every:300:60 --calibration imu-cal.json\n  imulab replay --kf-gins dataset/kf-gins.yaml --truth dataset/truth.nav --out results/"
)]
pub struct ReplayArgs {
    /// Session directory to replay.
    pub session: Option<PathBuf>,
    /// IMU device of the session (default: the only one).
    #[arg(long, value_name = "D", requires = "session")]
    pub imu: Option<String>,
    /// GNSS device of the session (default: the only one).
    #[arg(long, value_name = "G", requires = "session")]
    pub gnss: Option<String>,
    /// Filter configuration (TOML, see docs/fusion.md) for a session replay; with --kf-gins,
    /// the motion constraints only ([nhc], [zupt], [zaru], [odometer], [vehicle]).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Turn on the non-holonomic constraint (land vehicle: no sideways or vertical body
    /// velocity) with the configured or default settings.
    #[arg(long)]
    pub nhc: bool,
    /// Take the GNSS fixes as white noise (inflated by `gnss.position_correlation_s`)
    /// instead of carrying the receiver's slowly varying position error as three filter
    /// states (the default for a session: the `[gnss.position_error]` of --config, else that
    /// of the fixes' class, see docs/fusion.md).
    #[arg(long, requires = "session")]
    pub white_gnss: bool,
    /// Turn on zero-velocity updates at detected standstills.
    #[arg(long)]
    pub zupt: bool,
    /// Turn on zero angular rate updates at detected standstills (gyro bias).
    #[arg(long)]
    pub zaru: bool,
    /// Turn on odometer updates from the wheel speed (with --kf-gins: the IMU file's column
    /// `[odometer] column`, default 8, in m/s).
    #[arg(long)]
    pub odometer: bool,
    /// KF-GINS configuration file instead of a session (paths inside resolve against the
    /// current directory).
    #[arg(long, value_name = "CONFIG.yaml")]
    pub kf_gins: Option<PathBuf>,
    /// Truth trajectory in KF-GINS .nav format (with --kf-gins), for error statistics.
    #[arg(long, value_name = "FILE.nav", requires = "kf_gins")]
    pub truth: Option<PathBuf>,
    /// Output directory (default: SESSION/replay plus SESSION/replay-NAME.h5, or the KF-GINS
    /// `outputpath`). With --out nothing is written anywhere else.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Withhold GNSS from START for DUR seconds (after the data start); repeatable.
    #[arg(long = "outage", value_name = "START:DUR")]
    pub outage: Vec<String>,
    /// Withhold GNSS for DUR seconds every PERIOD seconds (first outage at PERIOD).
    #[arg(long, value_name = "every:PERIOD:DUR")]
    pub outages: Option<String>,
    /// Also run the RTS smoother and write the smoothed trajectory.
    #[arg(long)]
    pub smooth: bool,
    /// IMU noise from an Allan fit (`imulab allan --json` output; FILE.json#DEVICE picks a
    /// device, default the replayed IMU's name or the only device). Unidentified terms keep
    /// the configured/preset values, with a warning.
    #[arg(long, value_name = "FIT.json", requires = "session")]
    pub noise: Option<String>,
    /// Name of the trajectory file written into the session without --out:
    /// SESSION/replay-NAME.h5.
    #[arg(long, default_value = "filter", requires = "session")]
    pub name: String,
    /// Thermal model (JSON from `imulab thermal --model`): remove its change of bias with
    /// temperature, bias(T) − bias(reference), from the session IMU's rates, by their
    /// `temp`, before the filter.
    #[arg(long, value_name = "MODEL", requires = "session")]
    pub compensate: Option<PathBuf>,
    /// Calibration file (`imulab calibrate`, docs/calibration.md): correct the session IMU's
    /// rates with its bias and scale/misalignment matrices, before --compensate and the filter.
    #[arg(long, value_name = "FILE", requires = "session")]
    pub calibration: Option<PathBuf>,
}

fn parse_pair(text: &str, what: &str) -> anyhow::Result<(f64, f64)> {
    let (a, b) = text
        .split_once(':')
        .with_context(|| format!("{what} `{text}`: expected two numbers separated by `:`"))?;
    let num = |s: &str| {
        s.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v >= 0.0)
            .with_context(|| format!("{what} `{text}`: `{s}` is not a non-negative number"))
    };
    Ok((num(a)?, num(b)?))
}

/// Outage windows relative to the start, from `--outage` and `--outages`, up to `span_s`.
pub fn parse_outages(
    single: &[String],
    periodic: Option<&str>,
    span_s: f64,
) -> anyhow::Result<Vec<(f64, f64)>> {
    let mut out = Vec::new();
    for s in single {
        let (start, dur) = parse_pair(s, "--outage")?;
        out.push((start, start + dur));
    }
    if let Some(p) = periodic {
        let Some(rest) = p.strip_prefix("every:") else {
            bail!("--outages `{p}`: expected every:PERIOD:DUR");
        };
        let (period, dur) = parse_pair(rest, "--outages")?;
        if period <= 0.0 || dur >= period {
            bail!("--outages `{p}`: need 0 < DUR < PERIOD");
        }
        let mut start = period;
        while start < span_s {
            out.push((start, start + dur));
            start += period;
        }
    }
    Ok(out)
}

/// Where the trajectory's times sit: GPS week and sow − t (for navresult), and the start.
struct TimeAxis {
    week: u32,
    sow_offset: f64,
    start: f64,
}

pub fn run(args: ReplayArgs) -> anyhow::Result<()> {
    match (&args.session, &args.kf_gins) {
        (Some(dir), None) => run_session(dir, &args),
        (None, Some(cfg)) => run_kf_gins(cfg, &args),
        _ => bail!("give either a SESSION directory or --kf-gins CONFIG.yaml"),
    }
}

fn run_session(dir: &Path, args: &ReplayArgs) -> anyhow::Result<()> {
    if args.name.is_empty()
        || !args
            .name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
    {
        bail!(
            "--name `{}`: use ASCII letters, digits, '_' or '-'",
            args.name
        );
    }
    let mut config = match &args.config {
        Some(p) => FusionConfig::from_file(p)?,
        None => FusionConfig::default(),
    };
    enable_constraints(&mut config, args);
    if config.odometer.enabled {
        bail!(
            "odometer: a session has no wheel-speed channel (docs/session-format.md); odometer updates work with --kf-gins, from a column of its IMU file"
        );
    }
    let session = crate::store::Session::open(dir)?;
    let out_dir = args.out.clone().unwrap_or_else(|| dir.join("replay"));
    let in_session = args
        .out
        .is_none()
        .then(|| dir.join(crate::store::layout::replay_file_name(&args.name)));
    // Before the replay, which can take minutes.
    ensure_writable(&out_dir)?;
    if in_session.is_some() {
        ensure_writable(dir)?;
    }
    for p in session.problems() {
        tracing::warn!("{p}");
    }
    let imu_device = session::pick(&session, crate::store::DeviceKind::Imu, args.imu.as_deref())?;
    let noise = noise_model(&session, &imu_device, args, &config)?;
    if let Some(n) = &noise {
        for w in &n.warnings {
            tracing::warn!("{w}");
        }
        config.imu = n.model;
        config.validate()?;
    }
    println!(
        "IMU noise: {}",
        noise.as_ref().map_or_else(
            || match &args.config {
                Some(p) => format!("configuration {}", p.display()),
                None => "default configuration (consumer MEMS; give --noise or --config)".into(),
            },
            |n| n.origin.clone()
        )
    );
    println!("GNSS: {}", receiver_error(&session, args, &mut config)?);
    let outages = parse_outages(&args.outage, args.outages.as_deref(), 30.0 * 86400.0)?;
    let thermal = args
        .compensate
        .as_deref()
        .map(crate::thermal::model::ThermalModel::load)
        .transpose()?;
    let calibration = args
        .calibration
        .as_deref()
        .map(|p| {
            crate::calib::Calibration::load(p)
                .and_then(|c| crate::calib::Corrector::new(&c, &imu_device))
        })
        .transpose()?;
    let options = ReplayOptions {
        outages: outages.clone(),
        smooth: args.smooth,
        calibration: calibration.map(|c| {
            std::sync::Arc::new(CalibrationRows(c))
                as std::sync::Arc<dyn crate::fusion::navigator::RowCorrection>
        }),
        ..ReplayOptions::default()
    };
    let r = session::replay_session(
        &session,
        Some(&imu_device),
        args.gnss.as_deref(),
        &config,
        options,
        thermal.as_ref(),
    )?;
    for p in r.problems.iter().chain(&r.compensation_warnings) {
        tracing::warn!("{p}");
    }
    println!(
        "replayed IMU `{}` with GNSS `{}` ({} epochs without a fix skipped)",
        r.imu_device, r.gnss_device, r.gnss_without_fix
    );
    if let Some(path) = &args.calibration {
        println!(
            "IMU rates calibrated with {} before the filter",
            path.display()
        );
    }
    if let Some(path) = &args.compensate {
        println!(
            "IMU rates thermally compensated with model {} before the filter",
            path.display()
        );
    }
    let (week, sow_offset) = r.gps_time.unwrap_or((0, 0.0));
    let axis = TimeAxis {
        week,
        sow_offset,
        start: 0.0,
    };
    let truth = (!r.truth.is_empty()).then_some(&r.truth);
    if let Some(path) = &in_session {
        let mut sets: Vec<(&str, &[NavSolution])> = vec![("filtered", &r.result.filtered)];
        if args.smooth {
            sets.push(("smoothed", &r.result.smoothed));
        }
        export::write_hdf5(path, &sets)?;
        println!("wrote {}", path.display());
    }
    write_outputs(
        &out_dir,
        &r.result,
        args.smooth,
        truth.map(|t| move |x: f64| session::truth_at(t, x)),
        &outages,
        args.outage.len(),
        &axis,
    )
}

/// Sets the receiver-error states of a session replay (see [`ReplayArgs::white_gnss`]) and
/// says what the filter assumes.
fn receiver_error(
    session: &crate::store::Session,
    args: &ReplayArgs,
    config: &mut FusionConfig,
) -> anyhow::Result<String> {
    let g = &mut config.gnss;
    if args.white_gnss {
        g.position_error = Default::default();
        return Ok(format!(
            "fixes white, correlation time {} s (--white-gnss)",
            g.position_correlation_s
        ));
    }
    let origin = if g.position_error.enabled() {
        "[gnss.position_error] of the configuration".to_string()
    } else {
        let fix = session::dominant_fix_type(session, args.gnss.as_deref())?;
        match fix.and_then(|f| Some((f, noise::gnss_error_for_fix(f)?))) {
            Some((f, e)) => {
                g.position_error = e;
                format!(
                    "the {} receiver class of its {f:?} fixes",
                    noise::gnss_preset_for_fix(f).unwrap_or("standalone")
                )
            }
            None => {
                return Ok("no position fix to model the receiver error from".to_string());
            }
        }
    };
    config.validate()?;
    let e = config.gnss.position_error;
    Ok(format!(
        "receiver position error as 3 filter states, σ {} m horizontal, {} m vertical, τ {} s, from {origin} (--white-gnss: fixes white)",
        e.horizontal_m, e.vertical_m, e.tau_s
    ))
}

/// The IMU noise for a session replay: `--noise` (Allan fit) over the configuration; else,
/// without `--config`, the simulator preset the session's IMU was made with (read from the
/// manifest); else None (the configuration as it is).
fn noise_model(
    session: &crate::store::Session,
    imu_device: &str,
    args: &ReplayArgs,
    config: &FusionConfig,
) -> anyhow::Result<Option<noise::NoiseModel>> {
    if let Some(arg) = &args.noise {
        let (path, device) = noise::split_device(arg);
        let report = noise::read_allan_report(Path::new(path))?;
        let device = match device {
            Some(d) => Some(d),
            None if report.axes.iter().any(|a| a.device == imu_device) => Some(imu_device),
            None => None,
        };
        let fit = noise::allan_device(&report, device, path)?;
        return Ok(Some(noise::model_from_allan(
            &fit,
            &config.imu,
            &format!("Allan fit {path}"),
        )));
    }
    if args.config.is_some() {
        return Ok(None);
    }
    match crate::study::simulated_imu_preset(session, imu_device) {
        Some(preset) => Ok(Some(noise::model_from_preset(&preset)?)),
        None => Ok(None),
    }
}

/// The `--nhc`, `--zupt`, `--zaru` switches over the configuration.
fn enable_constraints(config: &mut FusionConfig, args: &ReplayArgs) {
    config.nhc.enabled |= args.nhc;
    config.zupt.enabled |= args.zupt;
    config.zaru.enabled |= args.zaru;
    config.odometer.enabled |= args.odometer;
}

fn run_kf_gins(path: &Path, args: &ReplayArgs) -> anyhow::Result<()> {
    let base = std::env::current_dir().context("current directory")?;
    let config = KfGinsConfig::from_file(path, &base)?;
    let mut fusion = config.fusion_config();
    if let Some(p) = &args.config {
        crate::fusion::config::Constraints::from_file(p)?.apply(&mut fusion);
    }
    enable_constraints(&mut fusion, args);
    fusion.validate()?;
    let on: Vec<&str> = [
        (fusion.nhc.enabled, "NHC"),
        (fusion.zupt.enabled, "ZUPT"),
        (fusion.zaru.enabled, "ZARU"),
        (fusion.odometer.enabled, "odometer"),
    ]
    .iter()
    .filter(|(e, _)| *e)
    .map(|(_, n)| *n)
    .collect();
    if !on.is_empty() {
        println!("motion constraints: {}", on.join(", "));
    }
    if config.initial_bias_std.is_some() {
        tracing::warn!("initbgstd/initbastd/initsgstd/initsastd are not applied: initial sensor-error σ = imunoise σ");
    }
    let outages: Vec<(f64, f64)> =
        parse_outages(&args.outage, args.outages.as_deref(), 7.0 * 86400.0)?
            .into_iter()
            .map(|(a, b)| (a + config.start_s, b + config.start_s))
            .collect();
    let out_dir = args
        .out
        .clone()
        .unwrap_or_else(|| config.output_path.clone());
    ensure_writable(&out_dir)?;
    let result = kfgins::replay_files_with(&config, &fusion, &outages, args.smooth)?;
    let truth = match &args.truth {
        Some(p) => Some(kfgins::read_nav(p)?),
        None => None,
    };
    let axis = TimeAxis {
        week: truth.as_ref().and_then(|t| t.first()).map_or(0, |r| r.week),
        sow_offset: 0.0,
        start: config.start_s,
    };
    let lookup = truth.as_ref().map(|rows| {
        move |t: f64| -> Option<NavState> {
            let i = rows.partition_point(|r| r.nav.t_s < t - 1e-4);
            rows.get(i)
                .filter(|r| (r.nav.t_s - t).abs() < 1e-4)
                .map(|r| r.nav)
        }
    });
    write_outputs(
        &out_dir,
        &result,
        args.smooth,
        lookup,
        &outages,
        args.outage.len(),
        &axis,
    )
}

/// Creates `dir` if needed and checks a file can be created in it; otherwise one line
/// naming the directory and the reason (read-only session, archive, no permission).
pub fn ensure_writable(dir: &Path) -> anyhow::Result<()> {
    let fail = |e: std::io::Error| anyhow::anyhow!("cannot write into {}: {e}", dir.display());
    std::fs::create_dir_all(dir).map_err(fail)?;
    let probe = dir.join(format!(".imulab-write-check-{}", std::process::id()));
    std::fs::File::create(&probe).map_err(fail)?;
    std::fs::remove_file(&probe).map_err(fail)
}

/// Why a replay produced no trajectory (the filter never started), in one line.
fn no_output_reason(stats: &ReplayStats, start: f64) -> String {
    let span = |s: Option<(f64, f64)>| {
        s.map_or("none".to_string(), |(a, b)| {
            format!("+{:.1} to +{:.1} s", a - start, b - start)
        })
    };
    match (stats.imu_span_s, stats.gnss_span_s) {
        (None, _) => "no usable IMU sample (all rejected: non-finite or time not increasing)".into(),
        (_, None) => format!(
            "no usable GNSS fix to align with ({} invalid, {} duplicate, {} out of order)",
            stats.gnss_rejected_invalid, stats.gnss_rejected_duplicate, stats.gnss_rejected_out_of_order
        ),
        (Some((i0, i1)), Some((g0, g1))) if g1 < i0 || g0 > i1 => format!(
            "GNSS and IMU do not overlap: IMU {}, GNSS {}",
            span(stats.imu_span_s),
            span(stats.gnss_span_s)
        ),
        _ => format!(
            "the filter never aligned: no GNSS fix with a speed of at least the alignment speed while the IMU ran (IMU {}, GNSS {}, {} fixes withheld by outages); give alignment.heading_deg in --config for a standstill start",
            span(stats.imu_span_s),
            span(stats.gnss_span_s),
            stats.gnss_withheld_outage
        ),
    }
}

/// One line per input problem the replay handled (what was done about it).
fn input_handling(stats: &ReplayStats, start: f64) -> Vec<String> {
    let mut lines = Vec::new();
    if stats.imu_rejected_time > 0 {
        lines.push(format!(
            "{} IMU samples rejected: time not after the previous sample's (or an increment over more than {} s)",
            stats.imu_rejected_time,
            crate::fusion::navigator::MAX_IMU_GAP_S
        ));
    }
    if stats.imu_rejected_non_finite > 0 {
        lines.push(format!(
            "{} IMU samples rejected: non-finite values",
            stats.imu_rejected_non_finite
        ));
    }
    if stats.imu_gaps > 0 {
        lines.push(format!(
            "{} IMU time jumps over {} s: the INS coasted across each and restarted its integration history",
            stats.imu_gaps,
            crate::fusion::navigator::MAX_IMU_GAP_S
        ));
    }
    if stats.gnss_sigma_fallback > 0 {
        let (h, v, _) = crate::fusion::navigator::FALLBACK_SIGMA;
        lines.push(format!(
            "{} GNSS fixes had a zero, negative or missing position σ: used {h} m horizontal, {v} m vertical",
            stats.gnss_sigma_fallback
        ));
    }
    let rejected = stats.gnss_rejected_invalid
        + stats.gnss_rejected_duplicate
        + stats.gnss_rejected_out_of_order;
    if rejected > 0 {
        lines.push(format!(
            "{rejected} GNSS fixes rejected ({} invalid, {} duplicate time, {} out of order)",
            stats.gnss_rejected_invalid,
            stats.gnss_rejected_duplicate,
            stats.gnss_rejected_out_of_order
        ));
    }
    if let (Some((i0, i1)), Some((g0, g1))) = (stats.imu_span_s, stats.gnss_span_s) {
        if g0 > i0 + 1.0 || g1 < i1 - 1.0 {
            lines.push(format!(
                "GNSS covers +{:.1} to +{:.1} s of the IMU's +{:.1} to +{:.1} s; the rest is inertial only",
                g0 - start, g1 - start, i0 - start, i1 - start
            ));
        }
    }
    lines
}

fn write_outputs<F: Fn(f64) -> Option<NavState>>(
    out_dir: &Path,
    result: &ReplayResult,
    smooth: bool,
    truth: Option<F>,
    requested: &[(f64, f64)],
    single_outages: usize,
    axis: &TimeAxis,
) -> anyhow::Result<()> {
    let (filtered, stats) = (&result.filtered, &result.stats);
    if filtered.is_empty() {
        bail!("{}", no_output_reason(stats, axis.start));
    }
    for line in input_handling(stats, axis.start) {
        println!("{line}");
    }
    let data_end = filtered.last().map_or(f64::NEG_INFINITY, |s| s.nav.t_s);
    // The `--outage` windows come first; periodic ones are generated past the data.
    for (i, &(a, b)) in requested.iter().enumerate() {
        if a > data_end {
            if i < single_outages {
                println!(
                    "outage at +{:.0} s starts after the data ends (+{:.0} s): ignored",
                    a - axis.start,
                    data_end - axis.start
                );
            }
        } else if b > data_end + 1.0 {
            println!(
                "outage at +{:.0} s for {:.0} s runs past the end of the data: counted to +{:.0} s",
                a - axis.start,
                b - a,
                data_end - axis.start
            );
        }
    }
    let windows = &result.gnss_less;
    let mut sets: Vec<(&str, &[NavSolution])> = vec![("filtered", filtered)];
    if smooth {
        sets.push(("smoothed", &result.smoothed));
    }
    export::write_hdf5(&out_dir.join("replay.h5"), &sets)?;
    let mut report = serde_json::Map::new();
    for (name, sol) in &sets {
        let gps: Vec<NavSolution> = sol
            .iter()
            .map(|s| {
                let mut s = *s;
                s.nav.t_s += axis.sow_offset;
                s
            })
            .collect();
        kfgins::write_navresult(
            &out_dir.join(format!("{name}_navresult.nav")),
            axis.week,
            &gps,
        )?;
        export::write_csv(&out_dir.join(format!("{name}_trajectory.csv")), sol)?;
        export::write_geojson(&out_dir.join(format!("{name}_trajectory.geojson")), sol)?;
        if let Some(truth) = &truth {
            let s = summarise(&errors(sol, truth), windows);
            println!(
                "{name}: {} epochs vs truth: horizontal RMS {:.3} m, p95 {:.3} m, max {:.3} m; vertical RMS {:.3} m; NEES {:.2}; inside 3σ {:.1} %",
                s.epochs, s.horizontal.rms, s.horizontal.p95, s.horizontal.max, s.vertical.rms,
                s.nees_mean, 100.0 * s.inside_3sigma
            );
            for o in &s.outages {
                let drift = if o.unbounded {
                    "unbounded (position σ above 1 km)".to_string()
                } else {
                    format!("{:.3} m", o.max_horizontal_m)
                };
                let withheld = overlap_s((o.start_s, o.start_s + o.duration_s), requested);
                let origin = if withheld < 0.5 {
                    "no fixes in the data".to_string()
                } else if o.duration_s - withheld < 0.5 {
                    "withheld".to_string()
                } else {
                    format!(
                        "{withheld:.0} s withheld, {:.0} s without fixes in the data",
                        o.duration_s - withheld
                    )
                };
                println!(
                    "  outage at +{:.1} s for {:.1} s ({origin}): max horizontal drift {drift}",
                    o.start_s - axis.start,
                    o.duration_s,
                );
            }
            if let Some(t) = s.unbounded_from_s {
                println!(
                    "  {} epochs from +{:.0} s have a horizontal σ above {} m: their position error is unbounded and left out of the figures above",
                    s.unbounded_epochs,
                    t - axis.start,
                    crate::fusion::metrics::UNBOUNDED_SIGMA_M
                );
            }
            let mut json = export::summary_json(&s);
            if let Some(list) = json["outages"].as_array_mut() {
                for (j, o) in list.iter_mut().zip(&s.outages) {
                    j["withheld_s"] =
                        overlap_s((o.start_s, o.start_s + o.duration_s), requested).into();
                }
            }
            report.insert(name.to_string(), json);
        }
    }
    if let Some(s) = filtered.iter().find(|s| {
        (s.cov_nav[(0, 0)] + s.cov_nav[(1, 1)]).sqrt() > crate::fusion::metrics::UNBOUNDED_SIGMA_M
    }) {
        tracing::warn!(
            "without GNSS the position is unbounded from +{:.0} s (horizontal σ above {} m; covariance capped {} times)",
            s.nav.t_s - axis.start,
            crate::fusion::metrics::UNBOUNDED_SIGMA_M,
            stats.filter.covariance_caps
        );
    }
    println!(
        "IMU samples {} (rejected {}), GNSS used {} (withheld {}, rejected {}), NHC/ZUPT/ZARU/odometer updates {}/{}/{}/{}, filter PD events {}",
        stats.imu_samples,
        stats.imu_rejected_non_finite + stats.imu_rejected_time,
        stats.gnss_used,
        stats.gnss_withheld_outage,
        stats.gnss_rejected_invalid
            + stats.gnss_rejected_duplicate
            + stats.gnss_rejected_out_of_order,
        stats.nhc_updates,
        stats.zupt_updates,
        stats.zaru_updates,
        stats.odometer_updates,
        stats.filter.pd_events
    );
    if truth.is_none() && !windows.is_empty() {
        let total: f64 = windows.iter().map(|w| w.1 - w.0).sum();
        println!(
            "{} windows without GNSS ({total:.0} s in all; no truth, so no drift figures)",
            windows.len()
        );
    }
    if !report.is_empty() {
        let p = out_dir.join("errors.json");
        std::fs::write(&p, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("{}", p.display()))?;
    }
    println!("wrote {}", out_dir.display());
    Ok(())
}

/// A calibration file's corrector as the filter's row correction (the calibration crate and
/// the fusion crate know nothing of each other).
#[derive(Debug)]
struct CalibrationRows(crate::calib::Corrector);

impl crate::fusion::navigator::RowCorrection for CalibrationRows {
    fn apply(&self, gyro: &mut [[f64; 3]], accel: &mut [[f64; 3]]) {
        self.0.apply(gyro, accel)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outage_arguments_parse_and_reject_nonsense() {
        let o = parse_outages(&["10:5".into()], Some("every:100:30"), 350.0).expect("valid");
        assert_eq!(
            o,
            vec![(10.0, 15.0), (100.0, 130.0), (200.0, 230.0), (300.0, 330.0)]
        );
        assert!(parse_outages(&["10".into()], None, 1.0).is_err());
        assert!(parse_outages(&["a:5".into()], None, 1.0).is_err());
        assert!(parse_outages(&[], Some("every:10:20"), 100.0).is_err());
        assert!(parse_outages(&[], Some("often:10:2"), 100.0).is_err());
    }
}
