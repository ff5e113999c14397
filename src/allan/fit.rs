//! Noise-term fit of the IMU model
//! σ²(τ) = 3Q²/τ² + N²/τ + (2 ln2/π)B² + K²τ/3 + R²τ²/2
//! by weighted, non-negative least squares on an Allan-variance curve, plus the classic
//! slope-line readings (N at τ = 1 s on the −1/2 line, B = min/0.664, K at τ = 3 s on the
//! +1/2 line) of MATLAB's `allanvar` workflow.
//!
//! NNLS is done by hand: with five parameters, solving every subset of free parameters and
//! keeping the best feasible solution is exact and simpler than any iterative solver; no
//! crate in the dependency set provides NNLS.

use super::curve::{Curve, CurvePoint};
use super::deviation::DeviationKind;
use super::edf::edf;
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

pub use imulab_noise::{Term, BIAS_INSTABILITY_FACTOR};

/// One fitted term.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TermEstimate {
    pub term: Term,
    /// Fitted coefficient (base units), `None` when the curve cannot identify the term.
    pub value: Option<f64>,
    /// 95 % interval of the coefficient; for an unidentified term, `low` is 0 and `high`
    /// the largest value the data still allow.
    pub low: f64,
    pub high: f64,
}

/// Result of the weighted NNLS fit.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct NoiseFit {
    pub terms: Vec<TermEstimate>,
    /// Reduced chi-squared of the fit (≈1 when the model and the EDFs agree).
    pub reduced_chi_squared: f64,
    /// Points used.
    pub points: usize,
}

impl NoiseFit {
    pub fn get(&self, term: Term) -> Option<&TermEstimate> {
        self.terms.iter().find(|t| t.term == term)
    }

    /// Model deviation σ(τ) with the fitted coefficients (unidentified terms count as 0).
    pub fn model_deviation(&self, tau: f64) -> f64 {
        self.terms
            .iter()
            .filter_map(|t| t.value.map(|v| v * v * t.term.allan_variance(tau)))
            .sum::<f64>()
            .sqrt()
    }

    /// σ(τ) contribution of one term alone (for plotting the fitted lines).
    pub fn term_deviation(&self, term: Term, tau: f64) -> Option<f64> {
        let v = self.get(term)?.value?;
        Some(v * term.allan_variance(tau).sqrt())
    }
}

/// Errors of the fit.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FitError {
    #[error("the noise fit needs at least 3 points with confidence intervals, got {0}")]
    TooFewPoints(usize),
    #[error("the noise model applies to ADEV/OADEV/TOTDEV curves, not {0}")]
    WrongKind(&'static str),
}

/// Fits the model to an Allan-variance curve, weighting each point by its EDF.
///
/// The variance estimate at each τ has relative standard error √(2/edf), so point i gets
/// weight √(edf_i/2)/σ²_i. Weighting by the *measured* σ² biases the fit low (points that
/// happen to fall low get more weight), so the weights use the *model* σ² and the fit is
/// iterated (IRLS, 6 rounds; the first round uses the measured values). Each round solves
/// the non-negative least-squares problem exactly.
///
/// Intervals (95 %): the weighted covariance gives a relative standard error s of each
/// squared coefficient, inflated by √(reduced χ²) when above 1 and by a factor 2 for the
/// correlation between neighbouring τ; the squared coefficient then gets a chi-squared
/// interval with ν = 2/s² degrees of freedom (asymmetric, as for any variance). A term is
/// identified when its NNLS value is positive and 1.96·s < 1; otherwise it is reported as
/// not identified, with the largest value the data allow as `high` (a term the model choice
/// left out is fitted together with the chosen ones for that bound).
pub fn fit_noise_terms(curve: &Curve) -> Result<NoiseFit, FitError> {
    if !curve.kind.is_allan_variance() {
        return Err(FitError::WrongKind(curve.kind.name()));
    }
    let usable: Vec<&CurvePoint> = curve
        .points
        .iter()
        .filter(|p| p.deviation > 0.0 && p.deviation.is_finite() && p.edf.is_some_and(|e| e > 0.0))
        .collect();
    if usable.len() < 3 {
        return Err(FitError::TooFewPoints(usable.len()));
    }
    let rows = usable.len();
    let weights: Vec<f64> = usable
        .iter()
        .map(|p| weighting_edf(curve.kind, p))
        .collect();
    let measured: Vec<f64> = usable.iter().map(|p| p.deviation * p.deviation).collect();
    let mut reference = measured.clone();
    let mut outcome = None;
    for _round in 0..6 {
        let (design, target, scales) = weighted_system(&usable, &weights, &measured, &reference);
        let (free, solution, residual) = best_nonnegative_subset(&design, &target);
        // Model variances for the next round's weights (fall back to measured where ≤ 0).
        for (i, p) in usable.iter().enumerate() {
            let model: f64 = free
                .iter()
                .zip(solution.iter())
                .map(|(&j, &v)| v / scales[j] * Term::ALL[j].allan_variance(p.tau))
                .sum();
            reference[i] = if model > 0.0 { model } else { measured[i] };
        }
        outcome = Some((design, target, scales, free, solution, residual));
    }
    let Some((design, target, scales, free, solution, residual)) = outcome else {
        return Err(FitError::TooFewPoints(rows));
    };
    let dof = rows.saturating_sub(free.len()).max(1);
    let reduced_chi_squared = residual / dof as f64;
    let inflation = reduced_chi_squared.max(1.0).sqrt() * CORRELATION_INFLATION;
    let covariance = covariance_on(&design, &free);
    let terms = Term::ALL
        .iter()
        .enumerate()
        .map(|(j, &term)| {
            let scale = scales[j];
            let position = free.iter().position(|&f| f == j);
            let (squared, sd) = match (position, &covariance) {
                (Some(k), Some(cov)) => (solution[k] / scale, cov[(k, k)].max(0.0).sqrt() / scale),
                _ => {
                    let (value, sd) = with_term_added(&design, &target, &free, j);
                    (value / scale, sd / scale)
                }
            };
            let sd = sd * inflation;
            let relative = if squared > 0.0 {
                sd / squared
            } else {
                f64::INFINITY
            };
            if position.is_some() && 1.96 * relative < 1.0 {
                let (low_factor, high_factor) = chi_squared_factors(2.0 / (relative * relative));
                TermEstimate {
                    term,
                    value: Some(squared.sqrt()),
                    low: (squared * low_factor).sqrt(),
                    high: (squared * high_factor).sqrt(),
                }
            } else {
                TermEstimate {
                    term,
                    value: None,
                    low: 0.0,
                    high: (squared.max(0.0) + 1.96 * sd).sqrt(),
                }
            }
        })
        .collect();
    Ok(NoiseFit {
        terms,
        reduced_chi_squared,
        points: rows,
    })
}

/// The 95 % interval of a variance-like quantity with `nu` degrees of freedom, as factors
/// on the estimate: (ν/χ²₀.₉₇₅, ν/χ²₀.₀₂₅).
fn chi_squared_factors(nu: f64) -> (f64, f64) {
    use super::edf::chi_squared_quantile;
    match (
        chi_squared_quantile(nu, 0.975),
        chi_squared_quantile(nu, 0.025),
    ) {
        (Some(high), Some(low)) if low > 0.0 => (nu / high, nu / low),
        _ => (0.0, f64::INFINITY),
    }
}

/// The EDF a point is weighted with: the smallest of its own and those the frequency
/// noises (white, flicker and random-walk FM) would give at its τ. At the last τ the
/// noise type rests on a handful of averages (B1); a phase noise read there has an EDF
/// tens of times the random walk's, and one such point outweighed the whole curve (a
/// rate ramp fitted to random-walk data).
fn weighting_edf(kind: DeviationKind, p: &CurvePoint) -> f64 {
    let phase_points = match kind {
        DeviationKind::Oadev => p.count + 2 * p.m,
        DeviationKind::Totdev => p.count + 2,
        // ADEV (the only other Allan variance): ⌊(n − 1)/m⌋ − 1 terms.
        _ => (p.count + 1) * p.m + 1,
    };
    (-2..=0)
        .filter_map(|alpha| edf(kind, alpha, p.m, phase_points))
        .chain(p.edf)
        .fold(f64::INFINITY, f64::min)
}

/// Weighted, column-scaled design matrix and target for one IRLS round.
fn weighted_system(
    points: &[&CurvePoint],
    edfs: &[f64],
    measured: &[f64],
    reference: &[f64],
) -> (DMatrix<f64>, DVector<f64>, Vec<f64>) {
    let rows = points.len();
    let mut design = DMatrix::<f64>::zeros(rows, 5);
    let mut target = DVector::<f64>::zeros(rows);
    for (i, p) in points.iter().enumerate() {
        let weight = (edfs[i] / 2.0).sqrt() / reference[i];
        for (j, term) in Term::ALL.iter().enumerate() {
            design[(i, j)] = term.allan_variance(p.tau) * weight;
        }
        target[i] = measured[i] * weight;
    }
    // Scale each column to unit norm so coefficients that differ by many orders of
    // magnitude stay well conditioned.
    let scales: Vec<f64> = (0..5)
        .map(|j| design.column(j).norm().max(f64::MIN_POSITIVE))
        .collect();
    for (j, s) in scales.iter().enumerate() {
        design.column_mut(j).scale_mut(1.0 / s);
    }
    (design, target, scales)
}

/// Neighbouring points of overlapping estimators are strongly correlated, so the
/// independent-point covariance understates the uncertainty; doubling it covers the
/// simulated cases in `tests/allan/fit.rs`.
const CORRELATION_INFLATION: f64 = 2.0;

/// Exact NNLS with model selection for few parameters: least squares on every subset of
/// free columns, keeping the feasible (all ≥ 0) solution with the smallest Akaike score
/// (residual χ² + 2 per free term), so a term enters only when it explains the curve
/// better than chance — otherwise nearly degenerate pairs (B with K) would both enter
/// and blur each other's intervals.
fn best_nonnegative_subset(a: &DMatrix<f64>, b: &DVector<f64>) -> (Vec<usize>, DVector<f64>, f64) {
    let columns = a.ncols();
    let mut best: (Vec<usize>, DVector<f64>, f64) =
        (Vec::new(), DVector::zeros(0), b.norm_squared());
    let mut best_score = best.2;
    for mask in 1u32..(1 << columns) {
        let free: Vec<usize> = (0..columns).filter(|j| mask & (1 << j) != 0).collect();
        if free.len() > a.nrows() {
            continue;
        }
        let sub = a.select_columns(free.iter());
        let Ok(solution) = sub.clone().svd(true, true).solve(b, 1e-12) else {
            continue;
        };
        if solution.iter().any(|v| *v < 0.0 || !v.is_finite()) {
            continue;
        }
        let residual = (&sub * &solution - b).norm_squared();
        let score = residual + 2.0 * free.len() as f64;
        if score < best_score {
            best_score = score;
            best = (free, solution, residual);
        }
    }
    best
}

/// (AᵀA)⁻¹ on the free columns, `None` if singular.
fn covariance_on(a: &DMatrix<f64>, free: &[usize]) -> Option<DMatrix<f64>> {
    if free.is_empty() {
        return None;
    }
    let sub = a.select_columns(free.iter());
    (sub.transpose() * sub).try_inverse()
}

/// An excluded term's coefficient (clamped at 0) and its standard deviation when it is fitted
/// together with the chosen terms: the basis of "not identified, below X". Fitting it with
/// the others, not alone, matters: a rate random walk that the Akaike choice left out while it
/// rises through the tail is partly absorbed by B, and the bound of K alone (0 + 1.96·sd)
/// fell below the simulated K in 6 of 29 such runs; with the other terms free it carries its
/// own share.
fn with_term_added(a: &DMatrix<f64>, b: &DVector<f64>, free: &[usize], j: usize) -> (f64, f64) {
    let mut columns: Vec<usize> = free.to_vec();
    columns.push(j);
    columns.sort_unstable();
    let k = columns.iter().position(|&c| c == j).unwrap_or(0);
    let sub = a.select_columns(columns.iter());
    let value = sub
        .clone()
        .svd(true, true)
        .solve(b, 1e-12)
        .ok()
        .map_or(0.0, |x| x[k].max(0.0));
    let sd = covariance_on(a, &columns)
        .map(|cov| cov[(k, k)].max(0.0).sqrt())
        .filter(|sd| sd.is_finite())
        .unwrap_or_else(|| {
            // Degenerate with the chosen terms: fall back to the column fitted alone.
            let norm_sq = a.column(j).norm_squared();
            if norm_sq > 0.0 {
                1.0 / norm_sq.sqrt()
            } else {
                f64::INFINITY
            }
        });
    (if value.is_finite() { value } else { 0.0 }, sd)
}

/// The classic graphical readings from a log-log Allan deviation curve.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SlopeReadings {
    /// σ at τ = 1 s on the slope −1/2 line through the point whose local slope is closest to −1/2.
    pub random_walk: Option<f64>,
    /// Minimum of the curve divided by 0.664.
    pub bias_instability: Option<f64>,
    /// τ of that minimum.
    pub bias_instability_tau: Option<f64>,
    /// σ at τ = 3 s on the slope +1/2 line through the point whose local slope is closest to +1/2.
    pub rate_random_walk: Option<f64>,
}

/// Local slopes must be within this of the target for a line reading to count.
const SLOPE_TOLERANCE: f64 = 0.15;

pub fn slope_readings(curve: &Curve) -> SlopeReadings {
    let pts: Vec<&CurvePoint> = curve.points.iter().filter(|p| p.deviation > 0.0).collect();
    let slopes: Vec<(f64, &CurvePoint)> = pts
        .windows(2)
        .map(|w| {
            let s = (w[1].deviation.ln() - w[0].deviation.ln()) / (w[1].tau.ln() - w[0].tau.ln());
            (s, w[0])
        })
        .collect();
    let closest = |target: f64| {
        slopes
            .iter()
            .filter(|(s, _)| (s - target).abs() < SLOPE_TOLERANCE)
            .min_by(|a, b| (a.0 - target).abs().total_cmp(&(b.0 - target).abs()))
            .map(|(_, p)| *p)
    };
    let minimum = pts
        .iter()
        .min_by(|a, b| a.deviation.total_cmp(&b.deviation));
    // The minimum only reads as bias instability if the curve actually turns there.
    let interior_minimum = minimum.filter(|m| {
        pts.first().is_some_and(|f| f.tau < m.tau) && pts.last().is_some_and(|l| l.tau > m.tau)
    });
    SlopeReadings {
        random_walk: closest(-0.5).map(|p| p.deviation * p.tau.sqrt()),
        bias_instability: interior_minimum.map(|p| p.deviation / BIAS_INSTABILITY_FACTOR),
        bias_instability_tau: interior_minimum.map(|p| p.tau),
        rate_random_walk: closest(0.5).map(|p| p.deviation * (3.0 / p.tau).sqrt()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::curve::point_with_interval;
    use crate::DeviationKind;

    fn synthetic_curve(n: f64, b: f64, k: f64) -> Curve {
        let points = (0..24)
            .map(|i| {
                let m = 1usize << i;
                let tau = m as f64 * 0.01;
                let var = n * n / tau + BIAS_INSTABILITY_FACTOR.powi(2) * b * b + k * k * tau / 3.0;
                point_with_interval(
                    DeviationKind::Oadev,
                    0,
                    m,
                    tau,
                    var.sqrt(),
                    1 << 34,
                    1 << 34,
                )
            })
            .collect();
        Curve {
            kind: DeviationKind::Oadev,
            tau0: 0.01,
            points,
        }
    }

    #[test]
    fn exact_model_curve_is_recovered() {
        let curve = synthetic_curve(1e-3, 2e-5, 1e-6);
        let fit = fit_noise_terms(&curve).unwrap();
        let n = fit.get(Term::RandomWalk).unwrap().value.unwrap();
        let b = fit.get(Term::BiasInstability).unwrap().value.unwrap();
        let k = fit.get(Term::RateRandomWalk).unwrap().value.unwrap();
        assert!((n / 1e-3 - 1.0).abs() < 1e-6, "{n}");
        assert!((b / 2e-5 - 1.0).abs() < 1e-5, "{b}");
        assert!((k / 1e-6 - 1.0).abs() < 1e-5, "{k}");
        assert!(fit.get(Term::Quantization).unwrap().value.is_none());
        assert!(fit.get(Term::RateRamp).unwrap().value.is_none());
    }

    #[test]
    fn slope_lines_read_white_noise() {
        let curve = synthetic_curve(1e-3, 0.0, 0.0);
        let r = slope_readings(&curve);
        assert!((r.random_walk.unwrap() / 1e-3 - 1.0).abs() < 1e-9);
        assert!(r.rate_random_walk.is_none());
        assert!(r.bias_instability.is_none());
    }

    #[test]
    fn refuses_non_allan_curves_and_short_curves() {
        let mut curve = synthetic_curve(1e-3, 0.0, 0.0);
        curve.kind = DeviationKind::Mdev;
        assert_eq!(
            fit_noise_terms(&curve).unwrap_err(),
            FitError::WrongKind("mdev")
        );
        curve.kind = DeviationKind::Adev;
        curve.points.truncate(2);
        assert_eq!(
            fit_noise_terms(&curve).unwrap_err(),
            FitError::TooFewPoints(2)
        );
    }
}
