//! `imulab calibrate SESSION|FILE [...]`: from one recording or several of the same IMU,
//! finds the still poses, fits the accelerometer (bias, scale factors, misalignment) to
//! gravity magnitude and the gyro to the rotations between poses, or runs the six-position
//! or rate-table method; prints what it found with 95 %
//! intervals (and, for a simulated session, the truth beside each figure), and writes the
//! calibration file that `allan`, `report`, `thermal`, `export` and `replay` apply with
//! `--calibration` (docs/calibration.md).

use crate::calib::file::TriadModel;
use crate::calib::recording::Recording;
use crate::calib::run::{calibrate_inputs, Gravity, Mode, Options, Outcome};
use crate::calib::statics::DetectorOptions;
use crate::calib::truth::Truth;
use crate::sim::imu_model::G0;
use anyhow::{bail, Result};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  imulab calibrate runs/tumble -o imu-cal.json --kalibr imu-cal.yaml --matlab imu_cal.m\n  imulab calibrate runs/tumble-a runs/tumble-b -o imu-cal.json\n  imulab calibrate cube.csv --six-position --latitude 48.15 --height 520 -o cube-cal.json\n  imulab calibrate runs/table --rate-table rates.csv -o gyro-cal.json\n  imulab calibrate runs/table-x runs/table-y runs/table-z --rate-table rates.csv -o gyro-cal.json\n  imulab allan runs/static --calibration imu-cal.json\n\nSeveral inputs are one IMU's recordings (same device, same sample rate), each starting at\nrest and searched on its own clock: a tumble's poses are pooled, its rotations taken within\neach input; a rate table's rows go to the inputs in order, or by an `input` column (number\nfrom 1, or path) that start_s/end_s need with several inputs (docs/calibration.md)."
)]
pub struct CalibrateArgs {
    /// Session directories, or CSV/TSV/.npy files with columns gyro_x … accel_z (rad/s,
    /// m/s²) and a time column `t` (s) or --rate: one recording, or several of the same IMU
    /// (e.g. one rate-table mounting each).
    #[arg(required = true, num_args = 1.., value_name = "INPUT")]
    pub inputs: Vec<PathBuf>,
    /// Session IMU to calibrate (default: the only one); a file: the device name to record.
    #[arg(long)]
    pub device: Option<String>,
    /// Sample rate of a file without a time column, Hz.
    #[arg(long)]
    pub rate: Option<f64>,
    /// Six-position test: each axis up and down once, on a cube or aligned fixture.
    #[arg(long, conflicts_with = "rate_table")]
    pub six_position: bool,
    /// Rate-table mode: CSV with a `rate_dps` column (table rates in order) and optionally
    /// `start_s`,`end_s`, `axis` (body axis on the spindle) and `input` (number from 1, or
    /// path) per rate; one mounting gives its axis's scale factor and non-linearity, three
    /// (x, y, z on the spindle, in one input or one each) the whole M.
    #[arg(long, value_name = "CSV")]
    pub rate_table: Option<PathBuf>,
    /// Still period at the start that the detector's thresholds come from, s.
    #[arg(long, default_value_t = 30.0)]
    pub init_static: f64,
    /// Variance window of the still detector, s.
    #[arg(long, default_value_t = 1.0)]
    pub window: f64,
    /// A window is still below this multiple of the initial period's variance.
    #[arg(long, default_value_t = 4.0)]
    pub threshold: f64,
    /// Shortest still interval used as a pose, s.
    #[arg(long, default_value_t = 2.0)]
    pub min_static: f64,
    /// Largest rate away from the initial period's that still counts as at rest, °/s.
    #[arg(long, default_value_t = 0.5)]
    pub max_still_rate: f64,
    /// Local gravity, m/s² (default: from --latitude/--height, else the session's place,
    /// else 9.80665 with a warning).
    #[arg(long, conflicts_with = "latitude")]
    pub gravity: Option<f64>,
    /// Latitude of the bench, degrees (normal gravity there).
    #[arg(long)]
    pub latitude: Option<f64>,
    /// Height of the bench above the ellipsoid, m (with --latitude).
    #[arg(long, default_value_t = 0.0, requires = "latitude")]
    pub height: f64,
    /// Write the calibration file (JSON, docs/calibration.md).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Also write it as a Kalibr-style YAML.
    #[arg(long)]
    pub kalibr: Option<PathBuf>,
    /// Also write it as a MATLAB/Octave script.
    #[arg(long)]
    pub matlab: Option<PathBuf>,
}

fn mg(v: f64) -> f64 {
    v / G0 * 1e3
}

/// One line of a triad: bias (in `bias_unit` via `to_unit`), scale factors and
/// misalignments with 95 % intervals, and the truth when known.
fn triad_text(
    out: &mut String,
    name: &str,
    m: &TriadModel,
    truth: Option<&TriadModel>,
    bias_unit: &str,
    to_unit: f64,
) {
    let z = 1.96;
    let _ = write!(out, "  {name} bias ({bias_unit}):");
    for k in 0..3 {
        let _ = write!(
            out,
            " {:+.4} ±{:.4}",
            m.bias[k] * to_unit,
            z * m.bias_sigma[k] * to_unit
        );
    }
    if let Some(t) = truth {
        let _ = write!(
            out,
            "   truth {:+.4} {:+.4} {:+.4}",
            t.bias[0] * to_unit,
            t.bias[1] * to_unit,
            t.bias[2] * to_unit
        );
    }
    let _ = writeln!(out);
    let _ = write!(out, "  {name} scale factor (ppm):");
    for k in 0..3 {
        let _ = write!(
            out,
            " {:+.0} ±{:.0}",
            (m.matrix[k][k] - 1.0) * 1e6,
            z * m.matrix_sigma[k][k] * 1e6
        );
    }
    if let Some(t) = truth {
        let s = t.scale_factor_ppm();
        let _ = write!(out, "   truth {:+.0} {:+.0} {:+.0}", s[0], s[1], s[2]);
    }
    let _ = writeln!(out);
    let _ = write!(out, "  {name} misalignment (mrad, xy xz yx yz zx zy):");
    let pairs = [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)];
    for (i, j) in pairs {
        let _ = write!(
            out,
            " {:+.3}±{:.3}",
            m.matrix[i][j] * 1e3,
            z * m.matrix_sigma[i][j] * 1e3
        );
    }
    if let Some(t) = truth {
        let _ = write!(out, "   truth");
        for (i, j) in pairs {
            let _ = write!(out, " {:+.3}", t.matrix[i][j] * 1e3);
        }
    }
    let _ = writeln!(out);
}

/// The printed summary of an outcome.
pub fn summary_text(o: &Outcome, truth: Option<&Truth>, seconds: f64) -> String {
    let c = &o.calibration;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "calibration of {} ({}), {}",
        c.device, c.source, c.method
    );
    let several = o.inputs.len() > 1;
    for (i, input) in o.inputs.iter().enumerate() {
        let prefix = if several {
            format!("input {}: ", i + 1)
        } else {
            String::new()
        };
        if several {
            let found = if input.detection.is_some() {
                format!("{} poses, {} rotations", input.poses, input.rotations)
            } else {
                format!("{} segments", input.segments)
            };
            let _ = writeln!(
                s,
                "{prefix}{}, {} samples at {:.1} Hz: {found}",
                input.source, input.samples, input.rate_hz
            );
        }
        let Some(d) = &input.detection else {
            continue;
        };
        let _ = writeln!(
            s,
            "{prefix}still intervals: {} found (window {} samples; thresholds {:.1e} (m/s²)² accel, {:.1e} (rad/s)² gyro = {} × the initial period's)",
            d.intervals.len(),
            d.window,
            d.accel_threshold,
            d.gyro_threshold,
            (d.accel_threshold / d.init_accel_var).round()
        );
        let shown: Vec<String> = d
            .intervals
            .iter()
            .take(8)
            .map(|p| format!("{:.1}-{:.1} s", p.t_start, p.t_end))
            .collect();
        let more = d.intervals.len().saturating_sub(8);
        let _ = writeln!(
            s,
            "  {}{}",
            shown.join(", "),
            if more > 0 {
                format!(", … {more} more")
            } else {
                String::new()
            }
        );
    }
    if !o.faces.is_empty() {
        let _ = writeln!(s, "  faces: {}", o.faces.join(", "));
    }
    for seg in &o.segments {
        let _ = writeln!(
            s,
            "  table {:+.1} °/s, {} on the spindle: {}{:.1}-{:.1} s, {} samples",
            seg.rate_dps,
            ["x", "y", "z"][seg.spindle],
            if several {
                format!("input {}, ", seg.input + 1)
            } else {
                String::new()
            },
            seg.t_start,
            seg.t_end,
            seg.samples
        );
    }
    if c.accel.is_some() {
        let _ = writeln!(s, "gravity: {:.5} m/s², {}", o.gravity, o.gravity_source);
    }
    if let Some(a) = &c.accel {
        triad_text(&mut s, "accel", a, truth.map(|t| &t.accel), "mg", 1e3 / G0);
    }
    if let Some(g) = &c.gyro {
        // A rate table measures the gyro in the mounting fixture's frame, a tumble in the
        // accelerometer's.
        let gyro_truth = truth.map(|t| {
            if c.method == "rate-table" {
                &t.gyro_body
            } else {
                &t.gyro
            }
        });
        triad_text(
            &mut s,
            "gyro",
            g,
            gyro_truth,
            "deg/h",
            3600.0f64.to_degrees(),
        );
        if c.method != "rate-table" {
            let _ = writeln!(
                s,
                "  (the gyro bias is the mean still rate: it holds the earth rate's projection, up to 15 deg/h)"
            );
        }
    }
    for t in c.rate_table.iter().flatten() {
        let _ = writeln!(
            s,
            "rate table, spindle axis {}: scale factor {:+.1} ±{:.1} ppm, quadratic {:+.4} ±{:.4} ppm per deg/s, non-linearity {:.1} ppm of full scale ({} rates)",
            t.axis,
            t.scale_factor_ppm,
            1.96 * t.scale_factor_sigma_ppm,
            t.quadratic_ppm_per_dps,
            1.96 * t.quadratic_sigma_ppm_per_dps,
            t.nonlinearity_ppm_of_full_scale,
            t.rates_dps.len()
        );
    }
    let q = &c.quality;
    if let (Some(b), Some(a)) = (q.gravity_residual_before, q.gravity_residual_after) {
        let _ = writeln!(
            s,
            "gravity magnitude residual over {} poses: {:.3} mg raw, {:.4} mg calibrated",
            q.poses,
            mg(b),
            mg(a)
        );
    }
    if let (Some(b), Some(a)) = (q.rotation_residual_before, q.rotation_residual_after) {
        let _ = writeln!(
            s,
            "gravity direction after {} rotations: {:.3}° raw rates, {:.4}° calibrated",
            q.rotations,
            b.to_degrees(),
            a.to_degrees()
        );
    }
    for n in &o.notes {
        let _ = writeln!(s, "note: {n}");
    }
    let _ = writeln!(s, "calibrated in {seconds:.2} s");
    s
}

/// The truth of simulated sessions among `inputs`: the scene's matrices (when every such
/// session has the same) and the mean of their true biases; `None` when no input is a
/// simulated session.
fn session_truth(inputs: &[PathBuf], device: &str) -> Option<Truth> {
    let truths: Vec<Truth> = inputs
        .iter()
        .filter(|p| p.is_dir())
        .filter_map(|p| Truth::of_session(Path::new(p), device).ok().flatten())
        .collect();
    let mut t = truths.first()?.clone();
    let same = |a: &TriadModel, b: &TriadModel| a.matrix == b.matrix;
    if truths
        .iter()
        .any(|u| !same(&u.accel, &t.accel) || !same(&u.gyro_body, &t.gyro_body))
    {
        return None;
    }
    let n = truths.len() as f64;
    for k in 0..3 {
        let mean = |f: &dyn Fn(&Truth) -> f64| truths.iter().map(f).sum::<f64>() / n;
        t.accel.bias[k] = mean(&|u| u.accel.bias[k]);
        t.gyro.bias[k] = mean(&|u| u.gyro.bias[k]);
        t.gyro_body.bias[k] = mean(&|u| u.gyro_body.bias[k]);
    }
    Some(t)
}

pub fn run(args: CalibrateArgs) -> Result<()> {
    let mode = match (&args.rate_table, args.six_position) {
        (Some(p), _) => Mode::RateTable(p.clone()),
        (None, true) => Mode::SixPosition,
        (None, false) => Mode::MultiPosition,
    };
    for (name, v) in [
        ("--init-static", args.init_static),
        ("--window", args.window),
        ("--threshold", args.threshold),
        ("--min-static", args.min_static),
        ("--max-still-rate", args.max_still_rate),
    ] {
        if !(v.is_finite() && v > 0.0) {
            bail!("{name} must be a positive number, got {v}");
        }
    }
    let gravity = match (args.gravity, args.latitude) {
        (Some(g), _) => Gravity::Value(g),
        (None, Some(lat)) => Gravity::At {
            lat_deg: lat,
            height_m: args.height,
        },
        (None, None) => Gravity::Auto,
    };
    let opts = Options {
        mode,
        detector: DetectorOptions {
            init_s: args.init_static,
            window_s: args.window,
            threshold: args.threshold,
            max_rate: args.max_still_rate.to_radians(),
            min_static_s: args.min_static,
        },
        gravity,
    };
    let read_start = Instant::now();
    let recs: Vec<Recording> = args
        .inputs
        .iter()
        .map(|p| Recording::read(p, args.device.as_deref(), args.rate))
        .collect::<Result<_>>()?;
    println!(
        "read {} samples{} in {:.2} s",
        recs.iter().map(Recording::len).sum::<usize>(),
        if recs.len() > 1 {
            format!(" from {} inputs", recs.len())
        } else {
            String::new()
        },
        read_start.elapsed().as_secs_f64()
    );
    let start = Instant::now();
    let outcome = calibrate_inputs(&recs, &opts)?;
    let seconds = start.elapsed().as_secs_f64();
    let truth = session_truth(&args.inputs, &outcome.calibration.device);
    print!("{}", summary_text(&outcome, truth.as_ref(), seconds));
    let cal = &outcome.calibration;
    if let Some(path) = &args.output {
        cal.save(path)?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &args.kalibr {
        std::fs::write(path, cal.kalibr_yaml(1.0 / recs[0].dt()))?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &args.matlab {
        std::fs::write(path, cal.matlab_script())?;
        println!("wrote {}", path.display());
    }
    if args.output.is_none() && args.kalibr.is_none() && args.matlab.is_none() {
        println!("(nothing written: give -o FILE to keep the calibration)");
    }
    Ok(())
}
