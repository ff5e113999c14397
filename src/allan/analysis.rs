//! One axis from input to results: phase per segment, the deviation curve with intervals,
//! the noise-term fit and slope-line readings in engineering units. [`AllanReport`] is
//! the document `--json` writes (schema in docs/allan.md).

use super::curve::{compute_curve_from_rate, compute_curve_segments, Curve};
use super::deviation::DeviationKind;
use super::fit::{fit_noise_terms, slope_readings, NoiseFit, SlopeReadings};
use super::input::{AxisSeries, Health};
use super::numerics::Phase;
use super::taus::TauGrid;
use super::thermal::ThermalSummary;
use super::units::{fit_in_units, RateUnit, SensorKind, TermInUnits};
use serde::{Deserialize, Serialize};

/// Version of the JSON document layout.
pub const SCHEMA_VERSION: u32 = 1;

/// Everything computed for one axis.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AxisResult {
    /// Device name (session device or input file stem).
    pub device: String,
    /// Axis / channel name.
    pub axis: String,
    pub sensor: Option<SensorKind>,
    /// Unit of the input samples (deviations are in this unit, TDEV in unit·s).
    pub unit: RateUnit,
    pub tau0: f64,
    /// Mean of the rate that was removed before integration (the bias), input units.
    pub mean: f64,
    pub health: Health,
    pub curve: Curve,
    /// Weighted NNLS fit (ADEV/OADEV/TOTDEV only, when requested).
    pub fit: Option<NoiseFit>,
    /// The fit in engineering units.
    pub terms: Vec<TermInUnits>,
    /// Why there is no fit, if one was requested but not possible.
    pub fit_error: Option<String>,
    /// Classic slope-line readings in base units (N, B, K as in the fit).
    pub slopes: Option<SlopeReadings>,
    pub thermal: Option<ThermalSummary>,
}

/// Options for [`analyse_axis`].
#[derive(Debug, Clone)]
pub struct AnalysisOptions {
    pub kind: DeviationKind,
    pub grid: TauGrid,
    pub fit: bool,
    pub unit: RateUnit,
    pub sensor: Option<SensorKind>,
}

/// Runs the analysis of one axis; the series is consumed so its memory is reused for phase.
pub fn analyse_axis(device: &str, series: AxisSeries, options: &AnalysisOptions) -> AxisResult {
    let _whole = super::timings::Stage::start(|| format!("analyse {}", series.name));
    let total: usize = series.sample_count();
    // ADEV and HDEV on an octave grid need no phase (one read of the samples).
    let direct = match series.segments.as_slice() {
        [rate] => compute_curve_from_rate(rate, series.tau0, options.kind, &options.grid),
        _ => None,
    };
    let (curve, mean) = match direct {
        Some(done) => {
            drop(series.segments);
            done
        }
        None => {
            let phase_stage = super::timings::Stage::start(|| format!("phase {}", series.name));
            let phases: Vec<Phase> = series.segments.into_iter().map(Phase::from_rate).collect();
            drop(phase_stage);
            // Each phase removed its segment's mean; the axis mean weighs them by length.
            let mean = phases
                .iter()
                .map(|p| p.removed_mean * (p.len() - 1) as f64)
                .sum::<f64>()
                / total.max(1) as f64;
            let curve = compute_curve_segments(&phases, series.tau0, options.kind, &options.grid);
            (curve, mean)
        }
    };
    let fit_stage = super::timings::Stage::start(|| format!("fit {}", series.name));
    let (fit, fit_error) = if options.fit {
        match fit_noise_terms(&curve) {
            Ok(f) => (Some(f), None),
            Err(e) => (None, Some(e.to_string())),
        }
    } else {
        (None, None)
    };
    let terms = fit
        .as_ref()
        .map(|f| fit_in_units(f, options.sensor, options.unit))
        .unwrap_or_default();
    drop(fit_stage);
    let slopes = options
        .kind
        .is_allan_variance()
        .then(|| slope_readings(&curve));
    AxisResult {
        device: device.to_string(),
        axis: series.name,
        sensor: options.sensor,
        unit: options.unit,
        tau0: series.tau0,
        mean,
        health: series.health,
        curve,
        fit,
        terms,
        fit_error,
        slopes,
        thermal: None,
    }
}

/// The `--json` document.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AllanReport {
    pub schema_version: u32,
    pub generator: String,
    pub input: Vec<String>,
    pub kind: DeviationKind,
    pub grid: String,
    /// Coverage of the intervals on the curve points.
    pub confidence: f64,
    pub axes: Vec<AxisResult>,
}

impl AllanReport {
    pub fn new(input: Vec<String>, kind: DeviationKind, grid: &str, axes: Vec<AxisResult>) -> Self {
        AllanReport {
            schema_version: SCHEMA_VERSION,
            generator: format!("imulab {}", env!("CARGO_PKG_VERSION")),
            input,
            kind,
            grid: grid.to_string(),
            confidence: super::edf::ONE_SIGMA_COVERAGE,
            axes,
        }
    }
}
