//! One deviation curve: for every averaging factor of a grid, the deviation, its count of
//! terms, the dominant noise type, the EDF and the chi-squared confidence interval.

use super::deviation::{deviation_at, DeviationKind};
use super::edf::{confidence_interval, edf, Alpha, ONE_SIGMA_COVERAGE};
use super::noise_id::identify_alpha;
use super::numerics::Phase;
use super::taus::TauGrid;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// One point of a deviation curve.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CurvePoint {
    /// Averaging factor (τ = m·τ0).
    pub m: usize,
    /// Averaging time in seconds.
    pub tau: f64,
    pub deviation: f64,
    /// Lower and upper bound of the 68.3 % interval (`null` where no EDF is available).
    pub low: Option<f64>,
    pub high: Option<f64>,
    /// Equivalent degrees of freedom.
    pub edf: Option<f64>,
    /// Number of terms averaged.
    pub count: usize,
    /// Dominant power-law noise exponent α used for the EDF (2 white PM … −2 RW FM).
    pub alpha: Alpha,
}

/// A computed curve.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Curve {
    pub kind: DeviationKind,
    pub tau0: f64,
    pub points: Vec<CurvePoint>,
}

/// Computes `kind` on `phase` over `grid`, in parallel over τ.
pub fn compute_curve(phase: &Phase, tau0: f64, kind: DeviationKind, grid: &TauGrid) -> Curve {
    let factors = grid.factors(kind, phase.len(), tau0);
    let raw: Vec<_> = factors
        .par_iter()
        .filter_map(|&m| deviation_at(kind, phase, m, tau0))
        .collect();
    let max_differences = match kind {
        DeviationKind::Hdev | DeviationKind::Ohdev => 3,
        _ => 2,
    };
    let identified: Vec<Option<Alpha>> = raw
        .par_iter()
        .map(|p| identify_alpha(&phase.points, p.m, max_differences))
        .collect();
    let points = assign_alpha(&identified, kind)
        .into_iter()
        .zip(raw)
        .map(|(alpha, p)| {
            point_with_interval(kind, alpha, p.m, p.tau, p.deviation, p.count, phase.len())
        })
        .collect();
    Curve { kind, tau0, points }
}

/// Builds a point with EDF and interval for a known noise exponent.
pub fn point_with_interval(
    kind: DeviationKind,
    alpha: Alpha,
    m: usize,
    tau: f64,
    deviation: f64,
    count: usize,
    phase_points: usize,
) -> CurvePoint {
    let edf = edf(kind, alpha, m, phase_points);
    let interval = edf.and_then(|e| confidence_interval(deviation, e, ONE_SIGMA_COVERAGE));
    CurvePoint {
        m,
        tau,
        deviation,
        low: interval.map(|i| i.0),
        high: interval.map(|i| i.1),
        edf,
        count,
        alpha,
    }
}

/// Fills τ where the lag-1 method had too few points with the α of the nearest shorter τ
/// (white FM when nothing was identified), and clamps α into the range the variance
/// converges for (α ≥ −2 for Allan types, ≥ −4 for Hadamard).
fn assign_alpha(identified: &[Option<Alpha>], kind: DeviationKind) -> Vec<Alpha> {
    let lowest = match kind {
        DeviationKind::Hdev | DeviationKind::Ohdev => -4,
        _ => -2,
    };
    let mut last = 0;
    identified
        .iter()
        .map(|a| {
            if let Some(a) = a {
                last = *a;
            }
            last.clamp(lowest, 2)
        })
        .collect()
}
