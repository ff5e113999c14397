//! What `imulab calibrate` does with one recording or several of the same IMU: find the
//! still poses, fit the accelerometer and the gyro (multi-position), or the six faces
//! (six-position), or the table rates (rate table), check that the data supports the fit,
//! and assemble the calibration document with the notes a user must read. Several
//! recordings are each searched on their own clock; their poses are pooled for the
//! accelerometer, the gyro is fitted on the rotations within each, and a rate table's
//! segments are found in each.

use super::accel::fit_accel;
use super::file::{Calibration, Quality, TriadModel};
use super::gyro::fit_gyro;
use super::rate_table::{fit_rate_table, read_table, segments, Segment};
use super::recording::Recording;
use super::six_position::six_position;
use super::statics::{detect, Detection, DetectorOptions, StaticInterval};
use anyhow::{bail, Result};
use imulab_allan::units::STANDARD_GRAVITY as G0;
use imulab_earth as earth;
use std::path::PathBuf;

/// The calibration method.
#[derive(Debug, Clone, PartialEq)]
pub enum Mode {
    /// Many poses in any orientation (a hand or cube tumble).
    MultiPosition,
    /// Each axis up and down once, on an aligned fixture.
    SixPosition,
    /// Table rates (CSV) for the gyro.
    RateTable(PathBuf),
}

/// Where local gravity comes from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Gravity {
    /// Given, m/s².
    Value(f64),
    /// Normal gravity at latitude (deg) and height (m).
    At { lat_deg: f64, height_m: f64 },
    /// The session's place if it has one, else standard gravity.
    Auto,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    pub mode: Mode,
    pub detector: DetectorOptions,
    pub gravity: Gravity,
}

/// What one input gave.
#[derive(Debug, Clone)]
pub struct InputReport {
    pub source: String,
    pub samples: usize,
    /// Sample rate, Hz (from the median interval).
    pub rate_hz: f64,
    /// Still intervals found (tumble and six-position).
    pub detection: Option<Detection>,
    /// Poses used (after outliers dropped), rotations the gyro fit used, rate-table segments.
    pub poses: usize,
    pub rotations: usize,
    pub segments: usize,
}

/// A calibration with what was found on the way.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub calibration: Calibration,
    /// One per input, in order.
    pub inputs: Vec<InputReport>,
    /// Rate-table segments used.
    pub segments: Vec<Segment>,
    /// Six-position mode: the face each pose was taken as.
    pub faces: Vec<&'static str>,
    /// Local gravity used and where it came from.
    pub gravity: f64,
    pub gravity_source: String,
    /// Warnings and advice for the user.
    pub notes: Vec<String>,
}

fn local_gravity(place: Option<(f64, f64)>, g: Gravity) -> Result<(f64, String)> {
    Ok(match g {
        Gravity::Value(v) => {
            if !(v.is_finite() && (9.7..=9.9).contains(&v)) {
                bail!("--gravity {v} m/s² is not a gravity on the earth's surface (9.7-9.9)");
            }
            (v, "given with --gravity".into())
        }
        Gravity::At { lat_deg, height_m } => {
            if !(lat_deg.abs() <= 90.0 && height_m.is_finite()) {
                bail!("--latitude must be within ±90° and --height finite");
            }
            (
                earth::normal_gravity(lat_deg.to_radians(), height_m),
                format!("normal gravity at {lat_deg}° latitude, {height_m} m"),
            )
        }
        Gravity::Auto => match place {
            Some((lat, h)) => (
                earth::normal_gravity(lat, h),
                format!(
                    "normal gravity at the session's place ({:.4}°, {h} m)",
                    lat.to_degrees()
                ),
            ),
            None => (
                G0,
                "standard gravity 9.80665 m/s² (no place known: give --latitude/--height or --gravity, or the scale factors carry the difference to local gravity, up to 0.3 %)".into(),
            ),
        },
    })
}

/// Notes about poses noisier than the initial still period (something moved); `of` names
/// the input when there are several.
fn motion_notes(det: &Detection, poses: &[StaticInterval], of: &str) -> Vec<String> {
    let init_std = (det.init_accel_var / 3.0).sqrt();
    poses
        .iter()
        .filter_map(|p| {
            let s = (p.accel_std.iter().map(|v| v * v).sum::<f64>() / 3.0).sqrt();
            (s > 2.0 * init_std).then(|| {
                format!(
                    "pose {:.1}-{:.1} s{of} is {:.1}× noisier than the initial still period: the IMU may not have been at rest (hold it still, or rest it on something)",
                    p.t_start,
                    p.t_end,
                    s / init_std
                )
            })
        })
        .collect()
}

fn bias_only(poses: &[StaticInterval]) -> TriadModel {
    let n = poses.len().max(1) as f64;
    let mut bias = [0.0; 3];
    for p in poses {
        for (b, g) in bias.iter_mut().zip(&p.gyro_mean) {
            *b += g / n;
        }
    }
    TriadModel {
        bias,
        bias_sigma: [0.0; 3],
        matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        matrix_sigma: [[0.0; 3]; 3],
    }
}

/// " of input N" when there are several inputs, else nothing.
fn of_input(n: usize, i: usize) -> String {
    if n > 1 {
        format!(" of input {}", i + 1)
    } else {
        String::new()
    }
}

/// Largest relative difference between two inputs' sample rates taken as the same rate.
const RATE_TOLERANCE: f64 = 0.01;

/// Checks that the inputs can be one IMU's: the same sample rate and no two different
/// device names (a file's stem is no device name). Returns the device name.
fn check_inputs(recs: &[Recording]) -> Result<String> {
    let Some(first) = recs.first() else {
        bail!("no input to calibrate");
    };
    let rate = |r: &Recording| 1.0 / r.dt();
    for (i, r) in recs.iter().enumerate().skip(1) {
        let (a, b) = (rate(first), rate(r));
        if a.is_finite() && b.is_finite() && ((b - a) / a).abs() > RATE_TOLERANCE {
            bail!(
                "input {} ({}) is sampled at {b:.2} Hz but input 1 ({}) at {a:.2} Hz: several inputs must be one IMU at one sample rate",
                i + 1,
                r.source,
                first.source
            );
        }
    }
    let named: Vec<(usize, &Recording)> = recs
        .iter()
        .enumerate()
        .filter(|(_, r)| r.device_named)
        .collect();
    if let Some(&(k, a)) = named.first() {
        if let Some(&(i, b)) = named.iter().find(|(_, b)| b.device != a.device) {
            bail!(
                "input {} ({}) is device `{}` but input {} ({}) is `{}`: several inputs must be one IMU",
                i + 1,
                b.source,
                b.device,
                k + 1,
                a.source,
                a.device
            );
        }
        return Ok(a.device.clone());
    }
    Ok(first.device.clone())
}

/// Calibrates `rec`.
pub fn calibrate(rec: &Recording, opts: &Options) -> Result<Outcome> {
    calibrate_inputs(std::slice::from_ref(rec), opts)
}

/// Calibrates one IMU from the recordings `recs` (one or more, each on its own clock).
pub fn calibrate_inputs(recs: &[Recording], opts: &Options) -> Result<Outcome> {
    let device = check_inputs(recs)?;
    let source = recs
        .iter()
        .map(|r| r.source.as_str())
        .collect::<Vec<_>>()
        .join(" + ");
    let place = recs.iter().find_map(|r| r.place);
    let (g, gravity_source) = local_gravity(place, opts.gravity)?;
    let mut notes = Vec::new();
    let mut inputs: Vec<InputReport> = recs
        .iter()
        .map(|r| InputReport {
            source: r.source.clone(),
            samples: r.len(),
            rate_hz: 1.0 / r.dt(),
            detection: None,
            poses: 0,
            rotations: 0,
            segments: 0,
        })
        .collect();
    if let Mode::RateTable(path) = &opts.mode {
        let rows = read_table(path)?;
        let segs = segments(recs, &rows, &opts.detector)?;
        for s in &segs {
            inputs[s.input].segments += 1;
        }
        let (gyro, table) = fit_rate_table(&segs)?;
        let frame = if table.len() == 3 {
            "the mounting fixture's (x, y and z each along the spindle in turn; the fixture's alignment errors are part of M)"
        } else {
            notes.push(format!(
                "rate table: one mounting ({} on the spindle), so only that column of M is measured; mount x, y and z on the spindle in turn for the whole matrix",
                table[0].axis
            ));
            "the gyro's own axes (only the spindle axis's column of M is measured; the others are the identity's)"
        };
        let mut cal = Calibration::new(&device, &source, "rate-table", frame);
        cal.gyro = Some(gyro);
        cal.rate_table = Some(table);
        return Ok(Outcome {
            calibration: cal,
            inputs,
            segments: segs,
            faces: Vec::new(),
            gravity: g,
            gravity_source,
            notes,
        });
    }
    // The poses of every input, pooled, and the input each came from.
    let mut poses: Vec<StaticInterval> = Vec::new();
    let mut owner: Vec<usize> = Vec::new();
    for (i, rec) in recs.iter().enumerate() {
        let det = detect(rec, &opts.detector)?;
        if det
            .intervals
            .first()
            .is_none_or(|p| p.t_start > opts.detector.window_s)
        {
            bail!(
                "{}: the recording does not start still (no still interval at its start); it must start with --init-static {} s at rest",
                rec.source,
                opts.detector.init_s
            );
        }
        notes.extend(motion_notes(&det, &det.intervals, &of_input(recs.len(), i)));
        poses.extend(det.intervals.iter().cloned());
        owner.extend(std::iter::repeat_n(i, det.intervals.len()));
        inputs[i].detection = Some(det);
    }
    let six = opts.mode == Mode::SixPosition;
    let mut quality = Quality::default();
    let mut faces = Vec::new();
    let mut rejected: Vec<usize> = Vec::new();
    let (accel, frame, method) = if six {
        let (model, labels) = six_position(&poses, g)?;
        faces = labels;
        quality.poses = poses.len();
        let residual = |m: &TriadModel| {
            (poses
                .iter()
                .map(|p| {
                    let c = m.correct(&p.accel_mean);
                    ((c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt() - g).powi(2)
                })
                .sum::<f64>()
                / poses.len() as f64)
                .sqrt()
        };
        quality.gravity_residual_before = Some(residual(&bias_only(&[])));
        // (bias_only of no poses is the identity: the raw values.)
        quality.gravity_residual_after = Some(residual(&model));
        (
            model,
            "the fixture's (the cube faces' axes)",
            "six-position",
        )
    } else {
        let fit = fit_accel(&poses, g, recs.len() == 1)?;
        if !fit.converged {
            notes.push("the accelerometer fit did not report convergence; check the poses".into());
        }
        quality.poses = fit.poses_used;
        quality.rejected_pose_times_s = fit.rejected.iter().map(|&i| poses[i].t_start).collect();
        for &i in &fit.rejected {
            notes.push(format!(
                "pose {:.1}-{:.1} s{} left out: its gravity magnitude disagrees with the others (the IMU moved during it)",
                poses[i].t_start,
                poses[i].t_end,
                of_input(recs.len(), owner[i])
            ));
        }
        rejected.clone_from(&fit.rejected);
        quality.gravity_residual_before = Some(fit.residual_before);
        quality.gravity_residual_after = Some(fit.residual_after);
        quality.gravity_residual_constant_bias = Some(fit.residual_constant_bias);
        if let Some(d) = &fit.drift {
            quality.accel_bias_drift = Some(d.per_s);
            quality.accel_bias_drift_sigma = Some(d.sigma_per_s);
            let mg_h = d.per_s.map(|v| v / G0 * 1e3 * 3600.0);
            notes.push(format!(
                "the accelerometer bias drifted during the run ({:+.3} {:+.3} {:+.3} mg/h; F-test p = {:.1e}): fitted as linear in time, the bias written is its value at {:.0} s, the middle of the poses; with a constant bias the gravity residual is {:.4} mg",
                mg_h[0],
                mg_h[1],
                mg_h[2],
                d.p_value,
                d.t_mid_s,
                fit.residual_constant_bias / G0 * 1e3
            ));
        }
        (
            fit.model,
            "the accelerometer's (x along its x axis, y in its x-y plane)",
            "multi-position",
        )
    };
    // The poses used, per input: the gyro's rotations stay within one input.
    let used: Vec<Vec<StaticInterval>> = (0..recs.len())
        .map(|i| {
            poses
                .iter()
                .enumerate()
                .filter(|&(k, _)| owner[k] == i && !rejected.contains(&k))
                .map(|(_, p)| p.clone())
                .collect()
        })
        .collect();
    for (report, u) in inputs.iter_mut().zip(&used) {
        report.poses = u.len();
    }
    let runs: Vec<(&Recording, &[StaticInterval])> = recs
        .iter()
        .zip(&used)
        .map(|(r, u)| (r, u.as_slice()))
        .collect();
    let gyro = match fit_gyro(&runs, &accel) {
        Ok(fit) => {
            quality.rotations = fit.rotations;
            quality.rotation_residual_before = Some(fit.residual_before);
            quality.rotation_residual_after = Some(fit.residual_after);
            if !fit.converged {
                notes.push("the gyro fit did not report convergence; check the rotations".into());
            }
            for (report, u) in inputs.iter_mut().zip(&used) {
                report.rotations = u.len().saturating_sub(1);
            }
            fit.model
        }
        Err(e) => {
            notes.push(format!(
                "gyro: bias only, scale and misalignment not fitted: {e}"
            ));
            bias_only(&used.concat())
        }
    };
    let mut cal = Calibration::new(&device, &source, method, frame);
    cal.gravity = Some(g);
    cal.accel = Some(accel);
    cal.gyro = Some(gyro);
    cal.quality = quality;
    Ok(Outcome {
        calibration: cal,
        inputs,
        segments: Vec::new(),
        faces,
        gravity: g,
        gravity_source,
        notes,
    })
}
