//! Thermal characterisation of one axis: bias against the sensor temperature (polynomial,
//! order from the data, 95 % bands), the rising and falling branches fitted apart (largest
//! hysteresis gap), the warm-up transient of the first soak, and per-plateau Allan noise
//! terms; and of one device: the thermal lag of the sensor behind the chamber.
//!
//! Samples are reduced to block means (1 s by default) before the fits: the fits need the
//! bias level, not the white noise, and the means keep the work linear in the samples.

use super::polyfit::{fit_polynomial, PolyFit};
use crate::allan::analysis::{analyse_axis, AnalysisOptions};
use crate::allan::deviation::DeviationKind;
use crate::allan::input::AxisSeries;
use crate::allan::taus::TauGrid;
use crate::allan::units::{RateUnit, SensorKind, TermInUnits};
use serde::{Deserialize, Serialize};

/// Lowest and highest temperature a reading may have to count as valid, °C.
pub const VALID_TEMPERATURE_C: [f64; 2] = [-60.0, 150.0];
/// A temperature rate above this (°C/min) puts a block on the rising or falling branch.
pub const BRANCH_RATE_C_PER_MIN: f64 = 0.1;

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
    /// A plateau: the temperature stays within this of its first value, °C.
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

/// The rising and falling branches.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Hysteresis {
    pub rising: PolyFit,
    pub falling: PolyFit,
    /// Rising minus falling where their difference is largest in magnitude, datasheet unit.
    pub largest_gap: f64,
    pub largest_gap_at_c: f64,
    /// Mean of rising minus falling over the common range, datasheet unit.
    pub mean_gap: f64,
    pub unit: String,
}

/// The turn-on transient: bias(t) = settled + amplitude · e^(−t/τ) on the first soak.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Warmup {
    pub time_constant_s: f64,
    /// Datasheet unit.
    pub amplitude: f64,
    pub settled: f64,
    pub tolerance: f64,
    pub unit: String,
    /// When the transient is within `tolerance` of the settled value, s after the first sample.
    pub time_to_tolerance_s: f64,
    /// Length of the soak the fit used, s.
    pub soak_s: f64,
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
        SensorKind::Accel => ("mg", si / crate::allan::units::STANDARD_GRAVITY * 1000.0),
    }
}

fn coefficient_unit(base: &str, order: usize) -> String {
    match order {
        0 => base.to_string(),
        1 => format!("{base}/degC"),
        k => format!("{base}/degC^{k}"),
    }
}

/// Checks the temperature channel: the error says what is wrong. Returns the number of
/// invalid readings (NaN or outside [`VALID_TEMPERATURE_C`]).
pub fn check_temperature(
    temperature: &[f32],
    tau0: f64,
    chamber: Option<&dyn Fn(f64) -> f64>,
) -> Result<usize, String> {
    let valid = |t: f32| {
        let t = f64::from(t);
        t.is_finite() && (VALID_TEMPERATURE_C[0]..=VALID_TEMPERATURE_C[1]).contains(&t)
    };
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
            if y.is_finite()
                && temp.is_finite()
                && (VALID_TEMPERATURE_C[0]..=VALID_TEMPERATURE_C[1]).contains(&temp)
            {
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

/// Fits settled + A e^(−t/τ) to `(t, y)`: τ by golden-section search on log τ, the others
/// by linear least squares. Returns (τ, A, settled, A's standard error, rms).
fn fit_exponential(t: &[f64], y: &[f64]) -> Option<(f64, f64, f64, f64, f64)> {
    let span = t.last()? - t.first()?;
    let linear = |tau: f64| -> (f64, f64, f64) {
        // y = c + A e; closed-form two-parameter least squares.
        let n = t.len() as f64;
        let (mut se, mut see, mut sy, mut sey) = (0.0, 0.0, 0.0, 0.0);
        for (&ti, &yi) in t.iter().zip(y) {
            let e = (-ti / tau).exp();
            se += e;
            see += e * e;
            sy += yi;
            sey += e * yi;
        }
        let det = n * see - se * se;
        if det.abs() < 1e-300 {
            return (0.0, sy / n, f64::INFINITY);
        }
        let a = (n * sey - se * sy) / det;
        let c = (sy - a * se) / n;
        let rss: f64 = t
            .iter()
            .zip(y)
            .map(|(&ti, &yi)| (yi - c - a * (-ti / tau).exp()).powi(2))
            .sum();
        (a, c, rss)
    };
    let (mut lo, mut hi) = ((span / 1000.0).max(1e-3).ln(), span.ln());
    // Coarse scan first: the RSS in τ need not be unimodal over the whole range.
    let grid = 40;
    let best = (0..=grid)
        .map(|k| lo + (hi - lo) * k as f64 / grid as f64)
        .min_by(|a, b| linear(a.exp()).2.total_cmp(&linear(b.exp()).2))?;
    let step = (hi - lo) / grid as f64;
    (lo, hi) = (best - step, best + step);
    let g = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..60 {
        let a = hi - g * (hi - lo);
        let b = lo + g * (hi - lo);
        if linear(a.exp()).2 < linear(b.exp()).2 {
            hi = b;
        } else {
            lo = a;
        }
    }
    let tau = ((lo + hi) / 2.0).exp();
    let (a, c, rss) = linear(tau);
    let n = t.len() as f64;
    let sigma2 = rss / (n - 3.0).max(1.0);
    let (mut se, mut see) = (0.0, 0.0);
    for &ti in t {
        let e = (-ti / tau).exp();
        se += e;
        see += e * e;
    }
    let var_a = sigma2 * n / (n * see - se * se).max(1e-300);
    Some((tau, a, c, var_a.sqrt(), (rss / n).sqrt()))
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

/// Runs of blocks whose temperature stays within `tolerance` of the run's first block and
/// that last at least `min_s`: (first block, end block).
fn plateaus(b: &Blocks, tolerance: f64, min_s: f64) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = 0;
    while start < b.t_s.len() {
        let mut end = start + 1;
        while end < b.t_s.len() && (b.temp_c[end] - b.temp_c[start]).abs() <= tolerance {
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
/// temperature at a time (s from the first sample) where the session has it.
pub fn analyse_axis_thermal(
    device: &str,
    series: AxisSeries,
    sensor: SensorKind,
    unit: RateUnit,
    chamber: Option<&dyn Fn(f64) -> f64>,
    options: &ThermalOptions,
) -> Result<(AxisThermal, TemperatureTrace), String> {
    let tau0 = series.tau0;
    let axis = series.name.clone();
    let temperature = series
        .temperature
        .as_ref()
        .ok_or_else(|| format!("{device} {axis}: no temperature channel was read"))?;
    let rate: Vec<f64> = series.segments.concat();
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

    // Warm-up: the first soak, if the run starts with one.
    let soak = plateaus(&blocks, options.plateau_tolerance_c, 0.0)
        .first()
        .copied()
        .filter(|&(s, e)| s == 0 && blocks.t_s[e - 1] - blocks.t_s[0] >= 300.0);
    // A first fit of the transient sets how much of the soak the temperature fit skips;
    // the reported one is refitted after removing the fitted temperature dependence.
    let fit_from = soak
        .and_then(|(s, e)| {
            let t0 = blocks.t_s[s];
            let t: Vec<f64> = blocks.t_s[s..e].iter().map(|t| t - t0).collect();
            fit_exponential(&t, &blocks.bias[s..e])
                .filter(|&(tau, a, _, se_a, _)| a.abs() > 5.0 * se_a && tau < t[t.len() - 1] / 2.0)
                .map(|(tau, ..)| t0 + 5.0 * tau)
        })
        .unwrap_or(0.0);
    let keep: Vec<usize> = (0..blocks.t_s.len())
        .filter(|&i| blocks.t_s[i] >= fit_from)
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
            let base = fit.eval(blocks.temp_c[s]);
            let corrected: Vec<f64> = (s..e)
                .map(|i| blocks.bias[i] - (fit.eval(blocks.temp_c[i]) - base))
                .collect();
            match fit_exponential(&t, &corrected) {
                Some((tau, a, c, se_a, _rms))
                    if a.abs() > 5.0 * se_a && tau < t[t.len() - 1] / 2.0 =>
                {
                    let tolerance = options.warmup_tolerance.unwrap_or(0.05 * a.abs());
                    let to_tol = if a.abs() > tolerance {
                        tau * (a.abs() / tolerance).ln()
                    } else {
                        0.0
                    };
                    Some(Warmup {
                        time_constant_s: tau,
                        amplitude: a * to_ds,
                        settled: c * to_ds,
                        tolerance: tolerance * to_ds,
                        unit: ds_unit.to_string(),
                        time_to_tolerance_s: to_tol + t0,
                        soak_s: t[t.len() - 1],
                    })
                }
                Some((_, a, _, se_a, _)) => {
                    notes.push(format!(
                        "no warm-up transient on the first soak (amplitude {:.3} ± {:.3} {ds_unit})",
                        a * to_ds,
                        se_a * to_ds
                    ));
                    None
                }
                None => None,
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

    // Hysteresis: blocks on a rising or falling sensor temperature, fitted apart.
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
    let side = |which: i8| -> (Vec<f64>, Vec<f64>) {
        keep.iter()
            .filter(|&&i| branch[i] == which)
            .map(|&i| (blocks.temp_c[i], blocks.bias[i]))
            .unzip()
    };
    let (up_t, up_b) = side(1);
    let (down_t, down_b) = side(-1);
    let hysteresis = match (
        fit_polynomial(
            &up_t,
            &up_b,
            options.reference_c,
            Some(fit.order),
            fit.order,
        ),
        fit_polynomial(
            &down_t,
            &down_b,
            options.reference_c,
            Some(fit.order),
            fit.order,
        ),
    ) {
        (Ok(rising), Ok(falling)) => {
            let lo = rising.range_c[0].max(falling.range_c[0]);
            let hi = rising.range_c[1].min(falling.range_c[1]);
            if hi > lo {
                let grid: Vec<f64> = (0..=200)
                    .map(|k| lo + (hi - lo) * k as f64 / 200.0)
                    .collect();
                let gaps: Vec<f64> = grid
                    .iter()
                    .map(|&t| rising.eval(t) - falling.eval(t))
                    .collect();
                let (i, &g) = gaps
                    .iter()
                    .enumerate()
                    .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
                    .unwrap_or((0, &0.0));
                Some(Hysteresis {
                    largest_gap: g * to_ds,
                    largest_gap_at_c: grid[i],
                    mean_gap: gaps.iter().sum::<f64>() / gaps.len() as f64 * to_ds,
                    unit: ds_unit.to_string(),
                    rising,
                    falling,
                })
            } else {
                notes.push(
                    "no hysteresis: the rising and falling branches share no temperature range"
                        .into(),
                );
                None
            }
        }
        (up, down) => {
            let why = up.err().or(down.err()).unwrap_or_default();
            notes.push(format!(
                "no hysteresis: the run needs both rising and falling ramps ({} rising, {} falling blocks; {why})",
                up_t.len(),
                down_t.len()
            ));
            None
        }
    };

    // Noise terms per plateau (the warm-up part excluded).
    let mut plateau_noise = Vec::new();
    let block_len = ((options.block_s / tau0).round() as usize).max(1);
    for (s, e) in plateaus(&blocks, options.plateau_tolerance_c, options.plateau_min_s) {
        let first = blocks.start[s].max((fit_from / tau0) as usize);
        let last = (blocks.start[e - 1] + block_len).min(rate.len());
        if last <= first || (last - first) as f64 * tau0 < options.plateau_min_s {
            continue;
        }
        let piece: Vec<f64> = rate[first..last]
            .iter()
            .copied()
            .filter(|v| v.is_finite())
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
    }
    if plateau_noise.is_empty() {
        notes.push(format!(
            "no plateau of at least {:.0} s within ±{} °C: no noise terms against temperature",
            options.plateau_min_s, options.plateau_tolerance_c
        ));
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
    fn exponential_and_lag_fits_recover_their_time_constants() {
        let t: Vec<f64> = (0..1800).map(|i| i as f64 + 0.5).collect();
        let y: Vec<f64> = t
            .iter()
            .enumerate()
            .map(|(i, t)| 1.0 + 2.0 * (-t / 300.0).exp() + if i % 2 == 0 { 0.01 } else { -0.01 })
            .collect();
        let (tau, a, c, se, _) = fit_exponential(&t, &y).unwrap();
        assert!((tau - 300.0).abs() < 3.0, "{tau}");
        assert!((a - 2.0).abs() < 0.01 && (c - 1.0).abs() < 0.01 && se < 0.01);
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
}
