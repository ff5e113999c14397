//! Thermal characterisation of one axis: bias against the sensor temperature (polynomial,
//! order from the data, 95 % bands), the rising and falling branches fitted jointly (a shared
//! curve plus a gap polynomial: the hysteresis gap with its 95 % interval), the warm-up
//! transient of the first soak (nonlinear least squares, τ with its 95 % interval), and
//! per-plateau Allan noise terms; and of one device: the thermal lag of the sensor behind the
//! chamber.
//!
//! The plateau noise terms are fitted before the warm-up and the hysteresis: their bias
//! instability and rate random walk give the slow drift ([`super::drift`]) that the
//! intervals of the gap and of the warm-up add to the white-noise ones.
//!
//! Samples are reduced to block means (1 s by default) before the fits: the fits need the
//! bias level, not the white noise, and the means keep the work linear in the samples.

use super::drift::{Drift, PlateauCurve};
use super::polyfit::{fit_branches, fit_polynomial, PolyFit};
use super::warmup::{
    amplitude_interval, detection_limit, fit_exponential, tau_at_bound, tau_interval,
    transient_found,
};
use imulab_allan::analysis::{analyse_axis, AnalysisOptions};
use imulab_allan::deviation::DeviationKind;
use imulab_allan::input::AxisSeries;
use imulab_allan::taus::TauGrid;
use imulab_allan::units::{RateUnit, SensorKind, TermInUnits};
use serde::{Deserialize, Serialize};

/// Lowest and highest temperature a reading may have to count as valid, °C.
pub const VALID_TEMPERATURE_C: [f64; 2] = [-60.0, 150.0];
/// A temperature rate above this (°C/min) puts a block on the rising or falling branch.
pub const BRANCH_RATE_C_PER_MIN: f64 = 0.1;

/// Blocks within this of the temperature where their ramp started stay out of the hysteresis
/// fit (the bias is still moving between the branches there), °C.
pub const BRANCH_SETTLE_C: f64 = 5.0;

/// What to compute and how.
#[derive(Debug, Clone)]
pub struct ThermalOptions {
    /// Temperature the coefficients refer to, °C.
    pub reference_c: f64,
    /// Polynomial order, or `None` to choose it from the data.
    pub order: Option<usize>,
    pub max_order: usize,
    /// Block length of the means, s.
    pub block_s: f64,
    /// Warm-up tolerance in the input unit (`None`: 5 % of the amplitude).
    pub warmup_tolerance: Option<f64>,
    /// A plateau: the temperature stays in a band of ± this (highest − lowest ≤ 2×), °C.
    pub plateau_tolerance_c: f64,
    /// Shortest plateau analysed for noise terms, s.
    pub plateau_min_s: f64,
}

impl Default for ThermalOptions {
    fn default() -> Self {
        ThermalOptions {
            reference_c: 25.0,
            order: None,
            max_order: 3,
            block_s: 1.0,
            warmup_tolerance: None,
            plateau_tolerance_c: 0.3,
            plateau_min_s: 900.0,
        }
    }
}

/// One coefficient in datasheet units.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Coefficient {
    pub order: usize,
    pub value: f64,
    /// 95 % interval.
    pub low: f64,
    pub high: f64,
    pub unit: String,
}

/// The rising and falling branches, fitted jointly: a shared curve of the bias fit's order
/// plus a gap polynomial (rising minus falling) whose order BIC chooses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Hysteresis {
    pub rising: PolyFit,
    pub falling: PolyFit,
    /// The gap polynomial, rising minus falling, input unit.
    pub gap: PolyFit,
    /// The gap polynomial where it is largest in magnitude over the common range, datasheet unit.
    pub largest_gap: f64,
    /// 95 % half-width of `largest_gap`.
    pub largest_gap_ci95: f64,
    pub largest_gap_at_c: f64,
    /// Mean of the gap polynomial over the common range, datasheet unit.
    pub mean_gap: f64,
    pub unit: String,
}

/// The turn-on transient: bias(t) = settled + amplitude · e^(−t/τ) on the first soak.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Warmup {
    pub time_constant_s: f64,
    /// Profile-likelihood 95 % interval of the time constant, the drift included
    /// ([`super::warmup`]), s; the upper end is null (∞) where the data do not bound it.
    pub time_constant_ci95_s: [f64; 2],
    /// Linearised standard error of the time constant (Jacobian and drift) over its value.
    pub time_constant_relative_sigma: f64,
    /// Datasheet unit.
    pub amplitude: f64,
    /// Profile-likelihood 95 % interval of the amplitude, the drift included; ends the data
    /// do not bound are null (±∞).
    pub amplitude_ci95: [f64; 2],
    pub settled: f64,
    pub tolerance: f64,
    pub unit: String,
    /// When the transient is within `tolerance` of the settled value, s after the first sample.
    pub time_to_tolerance_s: f64,
    /// Length of the soak the fit used, s.
    pub soak_s: f64,
}

/// What a first soak without a detected transient could have shown: at each of a few time
/// constants, the smallest amplitude 3 standard errors (white noise and drift) out.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WarmupLimit {
    pub soak_s: f64,
    pub unit: String,
    pub limits: Vec<DetectionLimit>,
}

/// The smallest detectable amplitude (datasheet unit) of a transient with this time constant:
/// 3 standard errors of the fitted amplitude, white noise and drift.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DetectionLimit {
    pub time_constant_s: f64,
    pub amplitude: f64,
}

/// The time constants of the detection limits, as fractions of the soak (the test accepts
/// τ up to half the soak).
pub const DETECTION_LIMIT_SOAK_FRACTIONS: [f64; 4] = [0.05, 0.1, 0.25, 0.5];

/// The accelerometer scale factor at one temperature, from the poses with the axis along and
/// against gravity: (mean up − mean down) / 2 g₀ − 1, the bias cancelling.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScalePoint {
    pub temperature_c: f64,
    /// Scale-factor error, ppm (against standard gravity).
    pub scale_ppm: f64,
    /// Time in the up and the down poses, s.
    pub up_s: f64,
    pub down_s: f64,
}

/// Scale factor against temperature from gravity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScaleFactor {
    pub points: Vec<ScalePoint>,
    /// Scale-factor error (ppm) against the sensor temperature.
    pub fit: PolyFit,
    /// Its coefficients: ppm, ppm/degC, ppm/degC^2 with 95 % intervals.
    pub coefficients: Vec<Coefficient>,
}

/// Noise terms on one temperature plateau.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlateauNoise {
    pub temperature_c: f64,
    pub start_s: f64,
    pub duration_s: f64,
    pub terms: Vec<TermInUnits>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fit_error: Option<String>,
}

/// Everything found for one axis.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AxisThermal {
    pub device: String,
    pub axis: String,
    pub sensor: SensorKind,
    /// Unit the fits are in (the input's, SI for sessions).
    pub unit: RateUnit,
    /// Datasheet unit of bias: deg/h or mg.
    pub datasheet_unit: String,
    pub samples: u64,
    pub duration_s: f64,
    /// The fit against the sensor temperature, input unit.
    pub fit: PolyFit,
    /// Its coefficients in datasheet units.
    pub coefficients: Vec<Coefficient>,
    /// The fit against the chamber temperature, where the session has it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub chamber_fit: Option<PolyFit>,
    pub hysteresis: Option<Hysteresis>,
    pub warmup: Option<Warmup>,
    /// Where the first soak shows no transient: the amplitudes it could have detected.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warmup_detection_limit: Option<WarmupLimit>,
    /// Accelerometers: scale factor against temperature from ±1 g poses, where the run holds them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scale_factor: Option<ScaleFactor>,
    pub plateaus: Vec<PlateauNoise>,
    /// What could not be computed and why, and data problems skipped.
    pub notes: Vec<String>,
    /// Block means for the plots (decimated), not in the JSON.
    #[serde(skip)]
    pub trace: Trace,
}

/// Decimated block series for plots.
#[derive(Debug, Clone, Default)]
pub struct Trace {
    pub t_s: Vec<f64>,
    pub temp_c: Vec<f64>,
    pub bias: Vec<f64>,
    /// +1 rising, -1 falling, 0 neither.
    pub branch: Vec<i8>,
}

/// One axis's block means in time order.
struct Blocks {
    t_s: Vec<f64>,
    temp_c: Vec<f64>,
    chamber_c: Vec<f64>,
    bias: Vec<f64>,
    /// Index of the first sample of each block.
    start: Vec<usize>,
}

/// Datasheet unit and factor from `unit` for a bias.
pub fn datasheet_unit(sensor: SensorKind, unit: RateUnit) -> (&'static str, f64) {
    let si = unit.to_si();
    match sensor {
        SensorKind::Gyro => ("deg/h", si * 180.0 / std::f64::consts::PI * 3600.0),
        SensorKind::Accel => ("mg", si / imulab_allan::units::STANDARD_GRAVITY * 1000.0),
    }
}

fn coefficient_unit(base: &str, order: usize) -> String {
    match order {
        0 => base.to_string(),
        1 => format!("{base}/degC"),
        k => format!("{base}/degC^{k}"),
    }
}

/// A reading unchanged for at least this long is checked against the chamber for a stuck
/// sensor, s (no chamber moves 5 °C in less: that is 30 °C/min).
pub const STUCK_MIN_S: f64 = 10.0;

/// A reading counts when it is finite and within [`VALID_TEMPERATURE_C`].
fn valid_temperature(t: f64) -> bool {
    t.is_finite() && (VALID_TEMPERATURE_C[0]..=VALID_TEMPERATURE_C[1]).contains(&t)
}

/// Checks the temperature channel: the error says what is wrong. Returns the number of
/// invalid readings (NaN or outside [`VALID_TEMPERATURE_C`]).
pub fn check_temperature(
    temperature: &[f32],
    tau0: f64,
    chamber: Option<&dyn Fn(f64) -> f64>,
) -> Result<usize, String> {
    let valid = |t: f32| valid_temperature(f64::from(t));
    let invalid = temperature.iter().filter(|&&t| !valid(t)).count();
    if invalid == temperature.len() {
        let example = temperature.first().copied().unwrap_or(f32::NAN);
        return Err(format!(
            "no valid temperature reading in {} samples (first: {example}; valid is {} to {} °C): \
             the device reports no temperature, or its readings are broken; thermal analysis needs the sensor's own temperature per sample",
            temperature.len(),
            VALID_TEMPERATURE_C[0],
            VALID_TEMPERATURE_C[1]
        ));
    }
    if invalid * 2 > temperature.len() {
        return Err(format!(
            "{invalid} of {} temperature readings are NaN or outside {} to {} °C: too many to analyse",
            temperature.len(),
            VALID_TEMPERATURE_C[0],
            VALID_TEMPERATURE_C[1]
        ));
    }
    let first = temperature
        .iter()
        .copied()
        .find(|&t| valid(t))
        .unwrap_or(0.0);
    if temperature.iter().all(|&t| !valid(t) || t == first) {
        return Err(format!(
            "the temperature reads {first} °C in every sample: a constant chamber or a stuck sensor; \
             bias against temperature needs the temperature to change (a chamber ramp or steps)"
        ));
    }
    if let Some(chamber) = chamber {
        // Stuck: the reading does not change while the chamber moves by more than 5 °C.
        let mut run_start = 0;
        for i in 1..=temperature.len() {
            if i < temperature.len() && temperature[i] == temperature[run_start] {
                continue;
            }
            let (t0, t1) = (run_start as f64 * tau0, (i - 1) as f64 * tau0);
            if t1 - t0 < STUCK_MIN_S {
                run_start = i;
                continue;
            }
            let (c0, c1) = (chamber(t0), chamber(t1));
            let (lo, hi) = sample_range(chamber, t0, t1);
            if hi - lo > 5.0 {
                return Err(format!(
                    "the temperature sensor is stuck at {} °C from {t0:.0} s to {t1:.0} s while the chamber went from {c0:.1} to {c1:.1} °C (range {lo:.1} to {hi:.1} °C)",
                    temperature[run_start]
                ));
            }
            run_start = i;
        }
    }
    Ok(invalid)
}

fn sample_range(f: &dyn Fn(f64) -> f64, t0: f64, t1: f64) -> (f64, f64) {
    let steps = 64;
    (0..=steps)
        .map(|k| f(t0 + (t1 - t0) * k as f64 / steps as f64))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        })
}

fn block_means(
    rate: &[f64],
    temperature: &[f32],
    tau0: f64,
    block_s: f64,
    chamber: Option<&dyn Fn(f64) -> f64>,
) -> Blocks {
    let len = ((block_s / tau0).round() as usize).max(1);
    let mut b = Blocks {
        t_s: Vec::new(),
        temp_c: Vec::new(),
        chamber_c: Vec::new(),
        bias: Vec::new(),
        start: Vec::new(),
    };
    for (k, (r, t)) in rate.chunks(len).zip(temperature.chunks(len)).enumerate() {
        let (mut n, mut sr, mut st) = (0usize, 0.0, 0.0);
        for (&y, &temp) in r.iter().zip(t) {
            let temp = f64::from(temp);
            if y.is_finite() && valid_temperature(temp) {
                n += 1;
                sr += y;
                st += temp;
            }
        }
        if n * 2 < r.len() {
            continue;
        }
        let mid = (k * len) as f64 * tau0 + r.len() as f64 * tau0 / 2.0;
        b.t_s.push(mid);
        b.temp_c.push(st / n as f64);
        b.bias.push(sr / n as f64);
        b.start.push(k * len);
        if let Some(c) = chamber {
            b.chamber_c.push(c(mid));
        }
    }
    b
}

/// Sensor temperature rate per block, °C/min, over ±`half_window_s`.
fn temperature_rate(b: &Blocks, half_window_s: f64) -> Vec<f64> {
    let n = b.t_s.len();
    let mut out = vec![0.0; n];
    let (mut lo, mut hi) = (0, 0);
    for (i, rate) in out.iter_mut().enumerate() {
        while b.t_s[i] - b.t_s[lo] > half_window_s {
            lo += 1;
        }
        while hi + 1 < n && b.t_s[hi + 1] - b.t_s[i] <= half_window_s {
            hi += 1;
        }
        if hi > lo {
            *rate = (b.temp_c[hi] - b.temp_c[lo]) / (b.t_s[hi] - b.t_s[lo]) * 60.0;
        }
    }
    out
}

/// The first-order time constant and offset of `sensor` following `chamber` (block series),
/// with the RMS misfit: (τ, offset, rms).
pub fn fit_lag(t_s: &[f64], chamber: &[f64], sensor: &[f64]) -> Option<(f64, f64, f64)> {
    if t_s.len() < 10 {
        return None;
    }
    let misfit = |tau: f64| -> (f64, f64) {
        let mut f = sensor[0];
        let mut diffs = Vec::with_capacity(t_s.len());
        for i in 0..t_s.len() {
            if i > 0 {
                let dt = t_s[i] - t_s[i - 1];
                let gain = -(-dt / tau).exp_m1();
                f += gain * (chamber[i] - f);
            }
            diffs.push(sensor[i] - f);
        }
        let offset = diffs.iter().sum::<f64>() / diffs.len() as f64;
        let rss = diffs.iter().map(|d| (d - offset).powi(2)).sum::<f64>();
        (offset, rss)
    };
    let span = t_s[t_s.len() - 1] - t_s[0];
    let (mut lo, mut hi) = (0.1f64.ln(), span.max(1.0).ln());
    let grid = 40;
    let best = (0..=grid)
        .map(|k| lo + (hi - lo) * k as f64 / grid as f64)
        .min_by(|a, b| misfit(a.exp()).1.total_cmp(&misfit(b.exp()).1))?;
    let step = (hi - lo) / grid as f64;
    (lo, hi) = (best - step, best + step);
    let g = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..50 {
        let a = hi - g * (hi - lo);
        let b = lo + g * (hi - lo);
        if misfit(a.exp()).1 < misfit(b.exp()).1 {
            hi = b;
        } else {
            lo = a;
        }
    }
    let tau = ((lo + hi) / 2.0).exp();
    let (offset, rss) = misfit(tau);
    Some((tau, offset, (rss / t_s.len() as f64).sqrt()))
}

/// A block holds gravity along the axis when its mean is within this fraction of 1 g.
pub const POSE_GRAVITY_FRACTION: f64 = 0.1;
/// Blocks next to a pose are left out too (the rotation into and out of it), blocks.
pub const POSE_MARGIN_BLOCKS: usize = 3;
/// Poses whose temperatures lie within this of each other form one scale-factor point, °C.
pub const POSE_GROUP_C: f64 = 1.0;

/// Per block: +1 when an accelerometer axis reads +1 g (within [`POSE_GRAVITY_FRACTION`]),
/// −1 for −1 g, else 0; all 0 for a gyro, and for an axis that never holds both signs (it
/// stays along gravity: no tumble).
fn gravity_poses(bias: &[f64], sensor: SensorKind, unit: RateUnit) -> Vec<i8> {
    let g = imulab_allan::units::STANDARD_GRAVITY / unit.to_si();
    let pose: Vec<i8> = bias
        .iter()
        .map(|&b| {
            if sensor != SensorKind::Accel || ((b.abs() - g) / g).abs() > POSE_GRAVITY_FRACTION {
                0
            } else if b > 0.0 {
                1
            } else {
                -1
            }
        })
        .collect();
    if pose.contains(&1) && pose.contains(&-1) {
        pose
    } else {
        vec![0; bias.len()]
    }
}

/// Where the IMU was turned, by block number (first sample / block length), as the
/// accelerometer axes analysed so far found it: every axis leaves these blocks out of its
/// bias fits, so neither a gyro's rotation into a pose and the earth rate's other
/// projection there, nor an accelerometer axis's tilt, enter a bias against temperature.
/// Analyse the accelerometer axes of a device first and pass the same value to all its axes.
#[derive(Debug, Clone, Default)]
pub struct DeviceMotion {
    turned: Vec<bool>,
}

impl DeviceMotion {
    fn turned(&self, block: usize) -> bool {
        self.turned.get(block).copied().unwrap_or(false)
    }

    fn mark(&mut self, block: usize) {
        if self.turned.len() <= block {
            self.turned.resize(block + 1, false);
        }
        self.turned[block] = true;
    }
}

/// Per block: `true` where an accelerometer axis reads more than [`POSE_GRAVITY_FRACTION`]
/// of 1 g away from its usual (median) value: the IMU was turned. All `false` for a gyro.
fn turned_blocks(bias: &[f64], sensor: SensorKind, unit: RateUnit) -> Vec<bool> {
    if sensor != SensorKind::Accel || bias.is_empty() {
        return vec![false; bias.len()];
    }
    let g = imulab_allan::units::STANDARD_GRAVITY / unit.to_si();
    let mut sorted = bias.to_vec();
    let mid = sorted.len() / 2;
    let usual = *sorted.select_nth_unstable_by(mid, f64::total_cmp).1;
    bias.iter()
        .map(|&b| (b - usual).abs() > POSE_GRAVITY_FRACTION * g)
        .collect()
}

/// `true` within `margin` blocks of a non-zero entry.
fn dilate(pose: &[i8], margin: usize) -> Vec<bool> {
    let mut out = vec![false; pose.len()];
    for (i, _) in pose.iter().enumerate().filter(|(_, &p)| p != 0) {
        let (lo, hi) = (i.saturating_sub(margin), (i + margin + 1).min(pose.len()));
        out[lo..hi].iter_mut().for_each(|o| *o = true);
    }
    out
}

/// The scale factor per group of poses at one temperature, and its polynomial in temperature.
/// Each pose is a run of blocks of one sign, less [`POSE_MARGIN_BLOCKS`] at either end.
fn scale_from_gravity(
    b: &Blocks,
    pose: &[i8],
    fit_from: f64,
    unit: RateUnit,
    options: &ThermalOptions,
) -> Result<ScaleFactor, String> {
    let g = imulab_allan::units::STANDARD_GRAVITY / unit.to_si();
    // Runs: (sign, first, end).
    let mut runs = Vec::new();
    let mut i = 0;
    while i < pose.len() {
        let sign = pose[i];
        let mut end = i + 1;
        while end < pose.len() && pose[end] == sign {
            end += 1;
        }
        let (s, e) = (
            i + POSE_MARGIN_BLOCKS,
            end.saturating_sub(POSE_MARGIN_BLOCKS),
        );
        if sign != 0 && e >= s + 5 && b.t_s[s] >= fit_from {
            runs.push((sign, s, e));
        }
        i = end;
    }
    // Groups of consecutive poses at one temperature, each needing both signs.
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let mut points = Vec::new();
    let mut k = 0;
    while k < runs.len() {
        let t_first = mean(&b.temp_c[runs[k].1..runs[k].2]);
        let mut end = k + 1;
        while end < runs.len()
            && (mean(&b.temp_c[runs[end].1..runs[end].2]) - t_first).abs() <= POSE_GROUP_C
        {
            end += 1;
        }
        let (mut up, mut down) = ((0.0, 0usize, 0.0), (0.0, 0usize, 0.0));
        let mut temp = (0.0, 0usize);
        for &(sign, s, e) in &runs[k..end] {
            let acc = if sign > 0 { &mut up } else { &mut down };
            acc.0 += b.bias[s..e].iter().sum::<f64>();
            acc.1 += e - s;
            acc.2 += b.t_s[e - 1] - b.t_s[s] + (b.t_s[e - 1] - b.t_s[s]) / (e - s - 1) as f64;
            temp.0 += b.temp_c[s..e].iter().sum::<f64>();
            temp.1 += e - s;
        }
        if up.1 > 0 && down.1 > 0 {
            let (m_up, m_down) = (up.0 / up.1 as f64, down.0 / down.1 as f64);
            points.push(ScalePoint {
                temperature_c: temp.0 / temp.1 as f64,
                scale_ppm: ((m_up - m_down) / (2.0 * g) - 1.0) * 1e6,
                up_s: up.2,
                down_s: down.2,
            });
        }
        k = end;
    }
    let temps: Vec<f64> = points.iter().map(|p| p.temperature_c).collect();
    let ppm: Vec<f64> = points.iter().map(|p| p.scale_ppm).collect();
    if points.is_empty() {
        return Err(
            "the ±1 g poses never hold both the up and the down direction at one temperature"
                .into(),
        );
    }
    let fit = fit_polynomial(
        &temps,
        &ppm,
        options.reference_c,
        None,
        options.max_order.min(2),
    )
    .map_err(|e| {
        format!(
            "{} temperatures with up and down poses ({}): {e}",
            points.len(),
            temps
                .iter()
                .map(|t| format!("{t:.1} °C"))
                .collect::<Vec<_>>()
                .join(", ")
        )
    })?;
    let coefficients = (0..=fit.order)
        .map(|k| Coefficient {
            order: k,
            value: fit.coefficients[k],
            low: fit.coefficients[k] - fit.ci95[k],
            high: fit.coefficients[k] + fit.ci95[k],
            unit: coefficient_unit("ppm", k),
        })
        .collect();
    Ok(ScaleFactor {
        points,
        fit,
        coefficients,
    })
}

/// Runs of blocks whose temperature stays in a band of ±`tolerance` (highest minus lowest
/// at most 2·`tolerance`) and that last at least `min_s`: (first block, end block).
fn plateaus(b: &Blocks, tolerance: f64, min_s: f64) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = 0;
    while start < b.t_s.len() {
        let mut end = start + 1;
        let (mut lo, mut hi) = (b.temp_c[start], b.temp_c[start]);
        while end < b.t_s.len() {
            let t = b.temp_c[end];
            if t.max(hi) - t.min(lo) > 2.0 * tolerance {
                break;
            }
            (lo, hi) = (t.min(lo), t.max(hi));
            end += 1;
        }
        if b.t_s[end - 1] - b.t_s[start] >= min_s {
            out.push((start, end));
        }
        start = end;
    }
    out
}

/// The sensor's temperature per block and the chamber's, for the device-level lag.
pub struct TemperatureTrace {
    pub t_s: Vec<f64>,
    pub sensor_c: Vec<f64>,
    pub chamber_c: Vec<f64>,
}

/// Analyses one axis. `series` holds one uniform segment; `chamber` gives the chamber
/// temperature at a time (s from the first sample) where the session has it; `motion` is
/// where the device was turned, shared by its axes (see [`DeviceMotion`]).
pub fn analyse_axis_thermal(
    device: &str,
    mut series: AxisSeries,
    sensor: SensorKind,
    unit: RateUnit,
    chamber: Option<&dyn Fn(f64) -> f64>,
    options: &ThermalOptions,
    motion: &mut DeviceMotion,
) -> Result<(AxisThermal, TemperatureTrace), String> {
    let tau0 = series.tau0;
    let axis = series.name.clone();
    let temperature = series
        .temperature
        .as_ref()
        .ok_or_else(|| format!("{device} {axis}: no temperature channel was read"))?;
    // One segment is taken as it is (no copy); several are joined.
    let rate: Vec<f64> = if series.segments.len() == 1 {
        series.segments.pop().unwrap_or_default()
    } else {
        std::mem::take(&mut series.segments).concat()
    };
    let mut notes = Vec::new();
    let invalid = check_temperature(temperature, tau0, chamber)
        .map_err(|e| format!("{device} {axis}: {e}"))?;
    if invalid > 0 {
        notes.push(format!(
            "{invalid} samples with a NaN or out-of-range temperature were left out"
        ));
    }
    let (ds_unit, to_ds) = datasheet_unit(sensor, unit);
    let blocks = block_means(&rate, temperature, tau0, options.block_s, chamber);
    if blocks.t_s.len() < 10 {
        return Err(format!(
            "{device} {axis}: only {} valid {} s blocks: too short for a thermal analysis",
            blocks.t_s.len(),
            options.block_s
        ));
    }

    // Accelerometer poses that hold gravity along the axis (a tumble at each soak): they give
    // the scale factor against temperature and stay out of the bias fits.
    let pose = gravity_poses(&blocks.bias, sensor, unit);
    let block_len = ((options.block_s / tau0).round() as usize).max(1);
    for (i, turned) in turned_blocks(&blocks.bias, sensor, unit)
        .into_iter()
        .enumerate()
    {
        if turned {
            motion.mark(blocks.start[i] / block_len);
        }
    }
    let moved: Vec<i8> = (0..pose.len())
        .map(|i| i8::from(pose[i] != 0 || motion.turned(blocks.start[i] / block_len)))
        .collect();
    let in_pose = dilate(&moved, POSE_MARGIN_BLOCKS);
    let before_pose = |(s, e): (usize, usize)| -> (usize, usize) {
        (s, (s..e).find(|&i| in_pose[i]).unwrap_or(e))
    };
    // Warm-up: the first soak, if the run starts with one (up to its first pose).
    let soak = plateaus(&blocks, options.plateau_tolerance_c, 0.0)
        .first()
        .copied()
        .map(before_pose)
        .filter(|&(s, e)| s == 0 && e > s + 1 && blocks.t_s[e - 1] - blocks.t_s[0] >= 300.0);
    // A first fit of the transient sets how much of the soak the temperature fit skips;
    // the reported one is refitted after removing the fitted temperature dependence.
    let fit_from = soak
        .and_then(|(s, e)| {
            let t0 = blocks.t_s[s];
            let t: Vec<f64> = blocks.t_s[s..e].iter().map(|t| t - t0).collect();
            fit_exponential(&t, &blocks.bias[s..e])
                .filter(|f| transient_found(f, t[t.len() - 1], 0.0))
                .map(|f| t0 + 5.0 * f.tau)
        })
        .unwrap_or(0.0);
    let keep: Vec<usize> = (0..blocks.t_s.len())
        .filter(|&i| blocks.t_s[i] >= fit_from && !in_pose[i])
        .collect();
    let pick = |v: &[f64]| keep.iter().map(|&i| v[i]).collect::<Vec<f64>>();
    let (temps, bias) = (pick(&blocks.temp_c), pick(&blocks.bias));
    let fit = fit_polynomial(
        &temps,
        &bias,
        options.reference_c,
        options.order,
        options.max_order,
    )
    .map_err(|e| format!("{device} {axis}: {e}"))?;
    // Noise terms per plateau (the warm-up part excluded), on the rate less the fitted
    // bias(T): they also give the slow bias drift the warm-up and hysteresis intervals hold.
    let mut plateau_noise = Vec::new();
    let mut plateau_fits = Vec::new();
    for (s, e) in plateaus(&blocks, options.plateau_tolerance_c, options.plateau_min_s) {
        let (s, e) = before_pose((s, e));
        if e <= s {
            continue;
        }
        let first = blocks.start[s].max((fit_from / tau0) as usize);
        let last = (blocks.start[e - 1] + block_len).min(rate.len());
        if last <= first || (last - first) as f64 * tau0 < options.plateau_min_s {
            continue;
        }
        let piece: Vec<f64> = rate[first..last]
            .iter()
            .zip(&temperature[first..last])
            .filter_map(|(&y, &temp)| {
                let temp = f64::from(temp);
                (y.is_finite() && valid_temperature(temp)).then(|| y - fit.eval(temp))
            })
            .collect();
        let duration = piece.len() as f64 * tau0;
        let result = analyse_axis(
            device,
            AxisSeries::one_segment(axis.clone(), tau0, piece),
            &AnalysisOptions {
                kind: DeviationKind::Oadev,
                grid: TauGrid::Octave,
                fit: true,
                unit,
                sensor: Some(sensor),
            },
        );
        let temperature_c = blocks.temp_c[s..e].iter().sum::<f64>() / (e - s) as f64;
        plateau_noise.push(PlateauNoise {
            temperature_c,
            start_s: first as f64 * tau0,
            duration_s: duration,
            terms: result.terms,
            fit_error: result.fit_error,
        });
        if let Some(noise_fit) = result.fit {
            plateau_fits.push((result.curve, noise_fit, duration));
        }
    }
    if plateau_noise.is_empty() {
        notes.push(format!(
            "no plateau of at least {:.0} s within ±{} °C: no noise terms against temperature",
            options.plateau_min_s, options.plateau_tolerance_c
        ));
    }
    let drift = Drift::from_plateaus(
        &plateau_fits
            .iter()
            .map(|(curve, fit, duration_s)| PlateauCurve {
                curve,
                fit,
                duration_s: *duration_s,
            })
            .collect::<Vec<_>>(),
    );
    if drift.is_none() {
        notes.push(
            "the warm-up and hysteresis intervals leave out the slow bias drift: no plateau noise fit measures it"
                .into(),
        );
    }
    // Standard deviation of the drift in a combination of block means.
    let drift_sigma = |times: &[f64], weights: &[f64]| {
        drift.map_or(0.0, |d| d.sigma(times, weights, options.block_s))
    };

    let mut warmup_detection_limit = None;
    let warmup = match soak {
        None => {
            notes.push(
                "no warm-up fit: the run does not start with a soak of at least 5 minutes".into(),
            );
            None
        }
        Some((s, e)) => {
            let t0 = blocks.t_s[s];
            let t: Vec<f64> = blocks.t_s[s..e].iter().map(|t| t - t0).collect();
            let soak_s = t[t.len() - 1];
            let base = fit.eval(blocks.temp_c[s]);
            let corrected: Vec<f64> = (s..e)
                .map(|i| blocks.bias[i] - (fit.eval(blocks.temp_c[i]) - base))
                .collect();
            // Found against the white noise of the blocks and the slow drift, as the detection
            // limit is stated; the intervals add the drift too.
            let times = &blocks.t_s[s..e];
            let fitted = fit_exponential(&t, &corrected).map(|f| {
                let drift_amplitude = drift_sigma(times, &f.amplitude_weights);
                (f, drift_amplitude)
            });
            match fitted {
                Some((f, drift_amplitude)) if transient_found(&f, soak_s, drift_amplitude) => {
                    let drift_tau = drift_sigma(times, &f.tau_weights);
                    // The drift's share of each estimate's variance at the solution.
                    let inflation = |se: f64, drift: f64| {
                        if se > 0.0 {
                            1.0 + (drift / se).powi(2)
                        } else {
                            1.0
                        }
                    };
                    let tau_ci = tau_interval(&t, &corrected, &f, inflation(f.se_tau, drift_tau));
                    if tau_at_bound(&f, soak_s) {
                        notes.push(format!(
                            "the warm-up's τ reached half the {soak_s:.0} s first soak, the most the soak can show: τ is at least {:.0} s (95 %) and not bounded above; a longer first soak pins it",
                            tau_ci[0]
                        ));
                    }
                    let [a_lo, a_hi] = amplitude_interval(
                        &t,
                        &corrected,
                        &f,
                        inflation(f.se_amplitude, drift_amplitude),
                    );
                    let a = f.amplitude;
                    let tolerance = options.warmup_tolerance.unwrap_or(0.05 * a.abs());
                    let to_tol = if a.abs() > tolerance {
                        f.tau * (a.abs() / tolerance).ln()
                    } else {
                        0.0
                    };
                    Some(Warmup {
                        time_constant_s: f.tau,
                        time_constant_ci95_s: tau_ci,
                        time_constant_relative_sigma: f.se_tau.hypot(drift_tau) / f.tau,
                        amplitude: a * to_ds,
                        amplitude_ci95: [a_lo * to_ds, a_hi * to_ds],
                        settled: f.settled * to_ds,
                        tolerance: tolerance * to_ds,
                        unit: ds_unit.to_string(),
                        time_to_tolerance_s: to_tol + t0,
                        soak_s,
                    })
                }
                Some((f, _)) => {
                    let limits: Vec<DetectionLimit> = DETECTION_LIMIT_SOAK_FRACTIONS
                        .iter()
                        .filter_map(|&share| {
                            let tau = share * soak_s;
                            let drift = |weights: &[f64]| drift_sigma(&blocks.t_s[s..e], weights);
                            detection_limit(&t, f.sigma2, tau, &drift).map(|a| DetectionLimit {
                                time_constant_s: tau,
                                amplitude: a * to_ds,
                            })
                        })
                        .collect();
                    notes.push(format!(
                        "no warm-up transient on the first soak (fitted amplitude {:.3} ± {:.3} {ds_unit}, τ {:.0} s on a {soak_s:.0} s soak); detectable: {}",
                        f.amplitude * to_ds,
                        f.se_amplitude * to_ds,
                        f.tau,
                        limits
                            .iter()
                            .map(|l| format!("{:.3} {ds_unit} at τ {:.0} s", l.amplitude, l.time_constant_s))
                            .collect::<Vec<_>>()
                            .join(", ")
                    ));
                    warmup_detection_limit = Some(WarmupLimit {
                        soak_s,
                        unit: ds_unit.to_string(),
                        limits,
                    });
                    None
                }
                None => {
                    notes.push(format!(
                        "no warm-up fit: the {soak_s:.0} s first soak has too few blocks"
                    ));
                    None
                }
            }
        }
    };
    let coefficients = (0..=fit.order)
        .map(|k| Coefficient {
            order: k,
            value: fit.coefficients[k] * to_ds,
            low: (fit.coefficients[k] - fit.ci95[k]) * to_ds,
            high: (fit.coefficients[k] + fit.ci95[k]) * to_ds,
            unit: coefficient_unit(ds_unit, k),
        })
        .collect();
    let chamber_fit = if blocks.chamber_c.is_empty() {
        None
    } else {
        fit_polynomial(
            &pick(&blocks.chamber_c),
            &bias,
            options.reference_c,
            Some(fit.order),
            options.max_order,
        )
        .map_err(|e| notes.push(format!("no fit against the chamber temperature: {e}")))
        .ok()
    };

    // Hysteresis: blocks on a rising or falling sensor temperature, fitted jointly.
    let rates = temperature_rate(&blocks, 60.0);
    let branch: Vec<i8> = rates
        .iter()
        .map(|&r| {
            if r > BRANCH_RATE_C_PER_MIN {
                1
            } else if r < -BRANCH_RATE_C_PER_MIN {
                -1
            } else {
                0
            }
        })
        .collect();
    // Right after a turn the bias moves from one branch to the other: a block counts once
    // the temperature has moved BRANCH_SETTLE_C from where its ramp started.
    let mut start_c = f64::NAN;
    let ramp_start_c: Vec<f64> = (0..branch.len())
        .map(|i| {
            if i == 0 || branch[i] != branch[i - 1] {
                start_c = blocks.temp_c[i];
            }
            start_c
        })
        .collect();
    let on_branch: Vec<usize> = keep
        .iter()
        .copied()
        .filter(|&i| {
            branch[i] != 0 && (blocks.temp_c[i] - ramp_start_c[i]).abs() >= BRANCH_SETTLE_C
        })
        .collect();
    let branch_t: Vec<f64> = on_branch.iter().map(|&i| blocks.temp_c[i]).collect();
    let branch_b: Vec<f64> = on_branch.iter().map(|&i| blocks.bias[i]).collect();
    let branch_up: Vec<bool> = on_branch.iter().map(|&i| branch[i] > 0).collect();
    let branch_times: Vec<f64> = on_branch.iter().map(|&i| blocks.t_s[i]).collect();
    let fit_gap = |orders| {
        fit_branches(
            &branch_t,
            &branch_b,
            &branch_up,
            options.reference_c,
            fit.order,
            orders,
        )
    };
    let mut joint = fit_gap(0..=fit.order);
    // The gap order comes down while its top coefficient lies within its interval widened
    // by the drift (BIC sees only the white residuals).
    while let Ok(j) = &joint {
        let q = j.gap.order;
        if q == 0 {
            break;
        }
        let weights = j.gap_coefficient_weights(&branch_t, &branch_up, q);
        let bound = j.gap.ci95[q].hypot(1.96 * drift_sigma(&branch_times, &weights));
        if j.gap.coefficients[q].abs() >= bound {
            break;
        }
        joint = fit_gap(q - 1..=q - 1);
    }
    let hysteresis = match joint {
        Ok(joint) => {
            let [lo, hi] = joint.gap.range_c;
            let grid: Vec<f64> = (0..=200)
                .map(|k| lo + (hi - lo) * k as f64 / 200.0)
                .collect();
            let gaps: Vec<f64> = grid.iter().map(|&t| joint.gap.eval(t)).collect();
            let (i, &g) = gaps
                .iter()
                .enumerate()
                .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
                .unwrap_or((0, &0.0));
            Some(Hysteresis {
                largest_gap: g * to_ds,
                largest_gap_ci95: joint.gap.band(grid[i]).hypot(
                    1.96 * drift_sigma(
                        &branch_times,
                        &joint.gap_weights(&branch_t, &branch_up, grid[i]),
                    ),
                ) * to_ds,
                largest_gap_at_c: grid[i],
                mean_gap: gaps.iter().sum::<f64>() / gaps.len() as f64 * to_ds,
                unit: ds_unit.to_string(),
                rising: joint.rising,
                falling: joint.falling,
                gap: joint.gap,
            })
        }
        Err(e) => {
            notes.push(format!("no hysteresis: {e}"));
            None
        }
    };

    let scale_factor = if pose.iter().any(|&p| p != 0) {
        match scale_from_gravity(&blocks, &pose, fit_from, unit, options) {
            Ok(sf) => Some(sf),
            Err(e) => {
                notes.push(format!("no scale factor against temperature: {e}"));
                None
            }
        }
    } else {
        None
    };
    if scale_factor.is_some() {
        notes.push(
            "blocks holding gravity along the axis (±1 g poses) were left out of the bias fits"
                .into(),
        );
    }

    let step = (blocks.t_s.len() / 2000).max(1);
    let trace = Trace {
        t_s: blocks.t_s.iter().step_by(step).copied().collect(),
        temp_c: blocks.temp_c.iter().step_by(step).copied().collect(),
        bias: blocks
            .bias
            .iter()
            .step_by(step)
            .map(|b| b * to_ds)
            .collect(),
        branch: branch.iter().step_by(step).copied().collect(),
    };
    let temps_trace = TemperatureTrace {
        t_s: blocks.t_s.clone(),
        sensor_c: blocks.temp_c.clone(),
        chamber_c: blocks.chamber_c.clone(),
    };
    Ok((
        AxisThermal {
            device: device.to_string(),
            axis,
            sensor,
            unit,
            datasheet_unit: ds_unit.to_string(),
            samples: series.health.samples,
            duration_s: series.health.duration_s,
            fit,
            coefficients,
            chamber_fit,
            hysteresis,
            warmup,
            warmup_detection_limit,
            scale_factor,
            plateaus: plateau_noise,
            notes,
            trace,
        },
        temps_trace,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lag_fit_recovers_its_time_constant() {
        let t: Vec<f64> = (0..1800).map(|i| i as f64 + 0.5).collect();
        let chamber: Vec<f64> = t
            .iter()
            .map(|&t| if t < 100.0 { 20.0 } else { 40.0 })
            .collect();
        let mut s = 20.0;
        let sensor: Vec<f64> = chamber
            .iter()
            .map(|&c| {
                s += (1.0 - (-1.0f64 / 120.0).exp()) * (c - s);
                s
            })
            .collect();
        let (tau, offset, rms) = fit_lag(&t, &chamber, &sensor).unwrap();
        assert!((tau - 120.0).abs() < 1.0, "{tau}");
        assert!(offset.abs() < 0.05 && rms < 0.05, "{offset} {rms}");
    }

    #[test]
    fn a_plateau_is_a_band_of_twice_the_tolerance() {
        // 25.0 → 25.5 °C over 1000 s (within ±0.3 °C of its middle), then 30 °C for 500 s.
        let temp_c: Vec<f64> = (0..1500)
            .map(|i| {
                if i < 1000 {
                    25.0 + 0.5 * i as f64 / 1000.0
                } else {
                    30.0
                }
            })
            .collect();
        let blocks = Blocks {
            t_s: (0..1500).map(|i| i as f64 + 0.5).collect(),
            bias: vec![0.0; 1500],
            chamber_c: Vec::new(),
            start: (0..1500).collect(),
            temp_c,
        };
        assert_eq!(plateaus(&blocks, 0.3, 400.0), vec![(0, 1000), (1000, 1500)]);
        // ±0.2 °C: the band holds 0.4 °C of the 0.5 °C/1000 s drift, the first 801 blocks.
        assert_eq!(plateaus(&blocks, 0.2, 400.0), vec![(0, 801), (1000, 1500)]);
    }

    #[test]
    fn temperature_problems_are_named() {
        let nan = vec![f32::NAN; 100];
        assert!(check_temperature(&nan, 1.0, None)
            .unwrap_err()
            .contains("no valid temperature"));
        let constant = vec![25.0f32; 100];
        let e = check_temperature(&constant, 1.0, None).unwrap_err();
        assert!(e.contains("every sample") && e.contains("stuck"), "{e}");
        let mut mostly_bad = vec![999.0f32; 100];
        mostly_bad[0] = 20.0;
        mostly_bad[1] = 21.0;
        assert!(check_temperature(&mostly_bad, 1.0, None)
            .unwrap_err()
            .contains("outside"));
        // Stuck at 30 °C from sample 10 while the chamber ramps 20 → 60 °C.
        let temps: Vec<f32> = (0..100)
            .map(|i| if i < 10 { 20.0 + i as f32 } else { 30.0 })
            .collect();
        let ramp = |t: f64| 20.0 + 0.4 * t;
        let e = check_temperature(&temps, 1.0, Some(&ramp)).unwrap_err();
        assert!(e.contains("stuck at 30 °C from 10 s"), "{e}");
        let mut some_nan: Vec<f32> = (0..100).map(|i| 20.0 + i as f32 * 0.1).collect();
        some_nan[5] = f32::NAN;
        assert_eq!(check_temperature(&some_nan, 1.0, None).unwrap(), 1);
    }

    /// The thermal analysis of a 1 Hz accelerometer axis in m/s², with no plateau long
    /// enough for its own Allan curve.
    fn analyse_accel_without_plateaus(rate: Vec<f64>, temp: Vec<f32>) -> AxisThermal {
        let mut series = AxisSeries::one_segment("accel_x", 1.0, rate);
        series.temperature = Some(temp);
        let options = ThermalOptions {
            plateau_min_s: 1e9,
            ..ThermalOptions::default()
        };
        analyse_axis_thermal(
            "dut",
            series,
            SensorKind::Accel,
            RateUnit::MetrePerSecondSquared,
            None,
            &options,
            &mut DeviceMotion::default(),
        )
        .unwrap()
        .0
    }

    #[test]
    fn a_soak_without_a_transient_reports_what_it_could_have_detected() {
        // 1 Hz: 1200 s at 25 °C, a ramp to 45 °C, a hold; bias 0.01 + 0.001/°C, no warm-up.
        let mut noise = imulab_sim::rng::Stream::new(7, "no transient");
        let temp: Vec<f32> = (0..4000)
            .map(|i| (25.0 + (f64::from(i) - 1200.0).clamp(0.0, 2000.0) * 0.01) as f32)
            .collect();
        let rate: Vec<f64> = temp
            .iter()
            .map(|&t| 0.01 + 0.001 * (f64::from(t) - 25.0) + 0.01 * noise.normal())
            .collect();
        let a = analyse_accel_without_plateaus(rate, temp);
        assert!(a.warmup.is_none(), "{:?}", a.warmup);
        let limit = a.warmup_detection_limit.expect("no detection limit");
        assert_eq!(limit.limits.len(), DETECTION_LIMIT_SOAK_FRACTIONS.len());
        // 3 standard errors of an amplitude fitted on ~1200 blocks of 0.01 m/s² ≈ 1 mg:
        // a few tenths of a mg (most for the shortest τ, which few blocks see).
        let mg: Vec<f64> = limit.limits.iter().map(|l| l.amplitude).collect();
        assert!(mg.iter().all(|&m| m > 0.1 && m < 2.0), "{mg:?}");
        assert!(mg[0] > mg[2], "{mg:?}");
        assert!(
            a.notes
                .iter()
                .any(|n| n.contains("detectable") && n.contains("mg at τ")),
            "{:?}",
            a.notes
        );
    }

    #[test]
    fn scale_factor_comes_from_the_gravity_poses() {
        // 1 Hz accel in m/s²: soaks at 25, 60 and −10 °C, each ending in 100 s up and 100 s
        // down; scale 200 ppm/°C about 25 °C, bias 0.01 m/s² + 0.001 m/s²/°C.
        let g = imulab_allan::units::STANDARD_GRAVITY;
        let (mut rate, mut temp) = (Vec::new(), Vec::new());
        for (k, soak_c) in [25.0, 60.0, -10.0].into_iter().enumerate() {
            for i in 0..1000 {
                let t_c: f64 = soak_c;
                let pose = match i {
                    800..=899 => 1.0,
                    900..=999 => -1.0,
                    _ => 0.0,
                };
                let scale = 1.0 + 200e-6 * (t_c - 25.0);
                let wobble = if (i + k) % 2 == 0 { 1e-4 } else { -1e-4 };
                rate.push(0.01 + 0.001 * (t_c - 25.0) + scale * g * pose + wobble);
                temp.push(t_c as f32 + 0.001 * (i % 7) as f32);
            }
        }
        let a = analyse_accel_without_plateaus(rate, temp);
        let sf = a.scale_factor.expect("no scale factor");
        assert_eq!(sf.points.len(), 3, "{:?}", sf.points);
        assert_eq!(sf.fit.order, 1);
        assert!((sf.coefficients[1].value - 200.0).abs() < 1.0, "{sf:?}");
        assert_eq!(sf.coefficients[1].unit, "ppm/degC");
        // The poses stay out of the bias fit: its slope is the bias tempco.
        let c1 = a.fit.coefficients[1];
        assert!((c1 - 0.001).abs() < 1e-5, "bias c1 {c1}");
    }
}
