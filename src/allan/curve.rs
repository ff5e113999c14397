//! One deviation curve: for every averaging factor of a grid, the deviation, its count of
//! terms, the dominant noise type, the EDF and the chi-squared confidence interval.

use super::block_sums::non_overlapping_from_rate;
use super::deviation::{
    decimated_variance, deviation_from_variance, variance_at, variances_with, DeviationKind,
};
use super::edf::{confidence_interval, edf, Alpha, ONE_SIGMA_COVERAGE};
use super::noise_id::{b1_alpha, identify_alpha_decimated, identify_alphas};
use super::numerics::{for_each_decimation, Phase, Simd};
use super::taus::TauGrid;
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

/// Computes `kind` on `phase` over `grid`: the deviations of all τ in one sweep (in
/// parallel over the data) while the noise identification walks the decimated phase.
pub fn compute_curve(phase: &Phase, tau0: f64, kind: DeviationKind, grid: &TauGrid) -> Curve {
    compute_curve_segments(std::slice::from_ref(phase), tau0, kind, grid)
}

/// Computes `kind` over several uniform segments of one axis (the `split` gap policy):
/// the variances pool as Σ variance·count / Σ count, the EDFs add, and the noise type is
/// identified on the longest segment. The grid follows the longest segment.
pub fn compute_curve_segments(
    phases: &[Phase],
    tau0: f64,
    kind: DeviationKind,
    grid: &TauGrid,
) -> Curve {
    let Some(longest) = phases.iter().max_by_key(|p| p.len()) else {
        return Curve {
            kind,
            tau0,
            points: Vec::new(),
        };
    };
    let factors = grid.factors(kind, longest.len(), tau0);
    let simd = Simd::detected();
    let max_differences = match kind {
        DeviationKind::Hdev | DeviationKind::Ohdev => 3,
        _ => 2,
    };
    let (per_segment, identified) = match kind {
        DeviationKind::Adev | DeviationKind::Hdev if phases.len() == 1 => {
            // Both the non-overlapping sums and the noise identification read the
            // decimated phase: one pyramid serves the two.
            let n = longest.len();
            let mut variances = vec![None; factors.len()];
            let mut alphas = vec![None; factors.len()];
            for_each_decimation(&longest.points, &factors, |j, z| {
                variances[j] = decimated_variance(kind, z, factors[j], n, simd);
                alphas[j] = identify_alpha_decimated(z, max_differences, simd);
            });
            (vec![variances], alphas)
        }
        _ => rayon::join(
            || {
                phases
                    .iter()
                    .map(|phase| variances_with(kind, phase, &factors, simd))
                    .collect::<Vec<_>>()
            },
            || identify_alphas(&longest.points, &factors, max_differences, simd),
        ),
    };
    let mut pooled: Vec<(usize, f64, usize)> = Vec::with_capacity(factors.len());
    let mut kept: Vec<Option<Alpha>> = Vec::with_capacity(factors.len());
    for (j, &m) in factors.iter().enumerate() {
        let mut weighted = 0.0;
        let mut total = 0usize;
        for (variance, count) in per_segment.iter().filter_map(|v| v[j]) {
            weighted += variance * count as f64;
            total += count;
        }
        if total > 0 {
            pooled.push((m, weighted / total as f64, total));
            kept.push(identified[j]);
        }
    }
    for ((m, _, count), alpha) in pooled.iter().zip(kept.iter_mut()) {
        if alpha.is_none() {
            *alpha = b1_alpha_from_phase(longest, *m, *count, kind);
        }
    }
    let identified = kept;
    let points = assign_alpha(&identified, kind)
        .into_iter()
        .zip(pooled)
        .map(|(alpha, (m, variance, count))| {
            let tau = m as f64 * tau0;
            let deviation = deviation_from_variance(kind, variance, tau);
            let mut point =
                point_with_interval(kind, alpha, m, tau, deviation, count, longest.len());
            if phases.len() > 1 {
                // EDFs of independent segments add.
                let edf: f64 = phases
                    .iter()
                    .filter_map(|p| edf(kind, alpha, m, p.len()))
                    .sum();
                let interval = (edf > 0.0)
                    .then(|| confidence_interval(deviation, edf, ONE_SIGMA_COVERAGE))
                    .flatten();
                point.edf = (edf > 0.0).then_some(edf);
                point.low = interval.map(|i| i.0);
                point.high = interval.map(|i| i.1);
            }
            point
        })
        .collect();
    Curve { kind, tau0, points }
}

/// [`compute_curve`] straight from one uniform series of rate samples, without building
/// the phase, where that is possible: ADEV and HDEV on grids whose factors are all
/// powers of two (octave), see [`super::block_sums`]. Returns the curve and the mean
/// that the phase would have removed, or `None` for other kinds and grids.
pub fn compute_curve_from_rate(
    rate: &[f64],
    tau0: f64,
    kind: DeviationKind,
    grid: &TauGrid,
) -> Option<(Curve, f64)> {
    let phase_points = rate.len() + 1;
    let factors = grid.factors(kind, phase_points, tau0);
    let analysis = non_overlapping_from_rate(rate, kind, &factors, Simd::detected())?;
    let mut kept = Vec::with_capacity(factors.len());
    let mut defined = Vec::with_capacity(factors.len());
    // The phase, built only if R(n) is asked for (phase noise at the longest τ).
    let mut phase: Option<Phase> = None;
    for ((&m, variance), alpha) in factors
        .iter()
        .zip(&analysis.variances)
        .zip(&analysis.alphas)
    {
        if let Some((variance, count)) = *variance {
            defined.push((m, variance, count));
            let alpha = alpha.or_else(|| {
                let averages: Vec<f64> = rate
                    .chunks_exact(m)
                    .map(|c| c.iter().sum::<f64>() / m as f64)
                    .collect();
                b1_alpha(&averages, m, count, kind, || {
                    let phase = phase.get_or_insert_with(|| Phase::from_rate(rate.to_vec()));
                    variance_at(DeviationKind::Mdev, phase, m).map(|v| v.0)
                })
            });
            kept.push(alpha);
        }
    }
    let points = assign_alpha(&kept, kind)
        .into_iter()
        .zip(defined)
        .map(|(alpha, (m, variance, count))| {
            let tau = m as f64 * tau0;
            let deviation = deviation_from_variance(kind, variance, tau);
            point_with_interval(kind, alpha, m, tau, deviation, count, phase_points)
        })
        .collect();
    Some((Curve { kind, tau0, points }, analysis.mean))
}

/// [`b1_alpha`] at factor `m` of `phase` for a `kind` estimate of `terms` terms: the
/// averages are the first differences of the decimated phase.
fn b1_alpha_from_phase(
    phase: &Phase,
    m: usize,
    terms: usize,
    kind: DeviationKind,
) -> Option<Alpha> {
    let averages: Vec<f64> = phase
        .points
        .iter()
        .step_by(m)
        .collect::<Vec<_>>()
        .windows(2)
        .map(|w| (w[1] - w[0]) / m as f64)
        .collect();
    b1_alpha(&averages, m, terms, kind, || {
        variance_at(DeviationKind::Mdev, phase, m).map(|v| v.0)
    })
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

/// Fills τ where neither the lag-1 method nor B1 gave a noise type (too few averages,
/// see [`super::noise_id::b1_min_averages`]) with the α of the nearest shorter τ (white
/// FM when nothing was identified), and clamps α into the range the variance
/// converges for (α ≥ −2 for Allan types, ≥ −4 for Hadamard).
pub fn assign_alpha(identified: &[Option<Alpha>], kind: DeviationKind) -> Vec<Alpha> {
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
