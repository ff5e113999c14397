//! The Allan-family deviations computed from phase in O(N) per averaging factor:
//! ADEV (non-overlapping), OADEV, MDEV, HDEV, OHDEV, TDEV and TOTDEV, with the
//! conventions of NIST SP 1065 and Stable32 (term counts included).

use super::numerics::{blocked_sum, CompensatedSum, Phase};
use serde::{Deserialize, Serialize};

/// Which deviation to compute.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum DeviationKind {
    /// Allan deviation, non-overlapping clusters.
    Adev,
    /// Overlapping Allan deviation.
    Oadev,
    /// Modified Allan deviation.
    Mdev,
    /// Hadamard deviation, non-overlapping.
    Hdev,
    /// Overlapping Hadamard deviation.
    Ohdev,
    /// Time deviation, τ·MDEV/√3 (phase units: input units × seconds).
    Tdev,
    /// Total deviation (doubly reflected, no bias correction).
    Totdev,
}

impl DeviationKind {
    pub const ALL: [DeviationKind; 7] = [
        DeviationKind::Adev,
        DeviationKind::Oadev,
        DeviationKind::Mdev,
        DeviationKind::Hdev,
        DeviationKind::Ohdev,
        DeviationKind::Tdev,
        DeviationKind::Totdev,
    ];

    pub fn name(self) -> &'static str {
        match self {
            DeviationKind::Adev => "adev",
            DeviationKind::Oadev => "oadev",
            DeviationKind::Mdev => "mdev",
            DeviationKind::Hdev => "hdev",
            DeviationKind::Ohdev => "ohdev",
            DeviationKind::Tdev => "tdev",
            DeviationKind::Totdev => "totdev",
        }
    }

    /// Human-readable name for plots and reports.
    pub fn title(self) -> &'static str {
        match self {
            DeviationKind::Adev => "Allan deviation",
            DeviationKind::Oadev => "Overlapping Allan deviation",
            DeviationKind::Mdev => "Modified Allan deviation",
            DeviationKind::Hdev => "Hadamard deviation",
            DeviationKind::Ohdev => "Overlapping Hadamard deviation",
            DeviationKind::Tdev => "Time deviation",
            DeviationKind::Totdev => "Total deviation",
        }
    }

    /// Stable32's stop ratio: octave/decade grids end at `m ≤ phase_points / ratio`.
    pub fn stop_ratio(self) -> usize {
        match self {
            DeviationKind::Adev | DeviationKind::Hdev => 5,
            DeviationKind::Totdev => 2,
            _ => 4,
        }
    }

    /// Whether the result is an Allan-variance-like quantity that the IMU noise model
    /// σ²(τ) applies to (TDEV is in phase units, Hadamard has other coefficients).
    pub fn is_allan_variance(self) -> bool {
        matches!(
            self,
            DeviationKind::Adev | DeviationKind::Oadev | DeviationKind::Totdev
        )
    }

    /// Number of terms averaged at averaging factor `m` from `n` phase points (0 when undefined).
    pub fn term_count(self, m: usize, n: usize) -> usize {
        if m == 0 || n < 2 {
            return 0;
        }
        match self {
            DeviationKind::Adev => ((n - 1) / m).saturating_sub(1),
            DeviationKind::Oadev => n.saturating_sub(2 * m),
            DeviationKind::Mdev | DeviationKind::Tdev => (n + 1).saturating_sub(3 * m),
            DeviationKind::Hdev => ((n - 1) / m).saturating_sub(2),
            DeviationKind::Ohdev => n.saturating_sub(3 * m),
            DeviationKind::Totdev => {
                if m < n - 1 {
                    n - 2
                } else {
                    0
                }
            }
        }
    }
}

/// One deviation value with the number of terms behind it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawPoint {
    pub m: usize,
    pub tau: f64,
    pub deviation: f64,
    pub count: usize,
}

/// Computes `kind` at averaging factor `m` (τ = m·tau0). `None` when no term is defined.
pub fn deviation_at(kind: DeviationKind, phase: &Phase, m: usize, tau0: f64) -> Option<RawPoint> {
    let (variance, count) = variance_at(kind, phase, m)?;
    Some(RawPoint {
        m,
        tau: m as f64 * tau0,
        deviation: deviation_from_variance(kind, variance, m as f64 * tau0),
        count,
    })
}

/// The variance (for TDEV: the MDEV variance) at factor `m` and its number of terms.
/// Variances of several uniform segments pool as Σ variance·count / Σ count.
pub fn variance_at(kind: DeviationKind, phase: &Phase, m: usize) -> Option<(f64, usize)> {
    let x = phase.points.as_slice();
    let n = x.len();
    let count = kind.term_count(m, n);
    if count == 0 {
        return None;
    }
    let mf = m as f64;
    let c = count as f64;
    let variance = match kind {
        DeviationKind::Adev => second_difference_sum(x, m, m, count) / (2.0 * mf * mf * c),
        DeviationKind::Oadev => second_difference_sum(x, m, 1, count) / (2.0 * mf * mf * c),
        DeviationKind::Hdev => third_difference_sum(x, m, m, count) / (6.0 * mf * mf * c),
        DeviationKind::Ohdev => third_difference_sum(x, m, 1, count) / (6.0 * mf * mf * c),
        DeviationKind::Mdev | DeviationKind::Tdev => {
            modified_sum(x, m, count) / (2.0 * mf.powi(4) * c)
        }
        DeviationKind::Totdev => total_sum(x, m) / (2.0 * mf * mf * c),
    };
    Some((variance.max(0.0), count))
}

/// σ from the variance; TDEV is τ·MDEV/√3.
pub fn deviation_from_variance(kind: DeviationKind, variance: f64, tau: f64) -> f64 {
    let deviation = variance.max(0.0).sqrt();
    if kind == DeviationKind::Tdev {
        deviation * tau / 3f64.sqrt()
    } else {
        deviation
    }
}

/// Σ (x[i+2m] − 2x[i+m] + x[i])² over `count` terms with `i` stepping by `stride`.
fn second_difference_sum(x: &[f64], m: usize, stride: usize, count: usize) -> f64 {
    if stride == 1 {
        let a = &x[..count];
        let b = &x[m..m + count];
        let c = &x[2 * m..2 * m + count];
        blocked_sum(count, |i| {
            let d = c[i] - 2.0 * b[i] + a[i];
            d * d
        })
    } else {
        blocked_sum(count, |k| {
            let i = k * stride;
            let d = x[i + 2 * m] - 2.0 * x[i + m] + x[i];
            d * d
        })
    }
}

/// Σ (x[i+3m] − 3x[i+2m] + 3x[i+m] − x[i])² over `count` terms with `i` stepping by `stride`.
fn third_difference_sum(x: &[f64], m: usize, stride: usize, count: usize) -> f64 {
    if stride == 1 {
        let a = &x[..count];
        let b = &x[m..m + count];
        let c = &x[2 * m..2 * m + count];
        let d = &x[3 * m..3 * m + count];
        blocked_sum(count, |i| {
            let v = d[i] - 3.0 * c[i] + 3.0 * b[i] - a[i];
            v * v
        })
    } else {
        blocked_sum(count, |k| {
            let i = k * stride;
            let v = x[i + 3 * m] - 3.0 * x[i + 2 * m] + 3.0 * x[i + m] - x[i];
            v * v
        })
    }
}

/// Σ_j (Σ_{i=j}^{j+m−1} (x[i+2m] − 2x[i+m] + x[i]))² for `count = n − 3m + 1` values of `j`.
///
/// The inner window sum slides in O(1) per step (add the entering second difference,
/// drop the leaving one) with compensated accumulation, so MDEV costs O(N) per τ; the
/// window is recomputed from scratch every 65 536 steps to bound any residual drift.
fn modified_sum(x: &[f64], m: usize, count: usize) -> f64 {
    let second = |i: usize| x[i + 2 * m] - 2.0 * x[i + m] + x[i];
    let window_from_scratch = |j: usize| {
        let mut acc = CompensatedSum::new();
        for i in j..j + m {
            acc.add(second(i));
        }
        acc
    };
    const REFRESH: usize = 65_536;
    let mut window = window_from_scratch(0);
    let mut total = CompensatedSum::new();
    let mut block = 0.0;
    for j in 0..count {
        if j > 0 {
            if j % REFRESH == 0 && m > 1 {
                window = window_from_scratch(j);
            } else {
                window.add(second(j + m - 1));
                window.add(-second(j - 1));
            }
        }
        let s = window.value();
        block += s * s;
        if j % 1024 == 1023 {
            total.add(block);
            block = 0.0;
        }
    }
    total.add(block);
    total.value()
}

/// TOTDEV numerator: Σ_{i=1}^{n−2} (x*[i−m] − 2x*[i] + x*[i+m])² over the phase extended
/// by reflection at both ends (x*[−j] = 2x[0] − x[j], x*[n−1+j] = 2x[n−1] − x[n−1−j]).
fn total_sum(x: &[f64], m: usize) -> f64 {
    let n = x.len();
    let last = n - 1;
    let extended = |k: isize| -> f64 {
        if k < 0 {
            2.0 * x[0] - x[(-k) as usize]
        } else if (k as usize) > last {
            2.0 * x[last] - x[2 * last - k as usize]
        } else {
            x[k as usize]
        }
    };
    let mut total = CompensatedSum::new();
    // Interior where no reflection is needed: m <= i <= last - m.
    let inner_start = m.max(1);
    let inner_end = (last.saturating_sub(m)).min(n - 2); // inclusive
    let mi = m as isize;
    // Edges (reflection) handled point by point: 1 ≤ i < inner_start and inner_end < i ≤ n − 2.
    let edge_term = |i: usize| {
        let ii = i as isize;
        let d = extended(ii - mi) - 2.0 * x[i] + extended(ii + mi);
        d * d
    };
    let leading_edge_end = inner_start.min(n - 1);
    let trailing_edge_start = (inner_end + 1).max(leading_edge_end);
    for i in (1..leading_edge_end).chain(trailing_edge_start..n - 1) {
        total.add(edge_term(i));
    }
    if inner_start <= inner_end {
        let count = inner_end - inner_start + 1;
        let a = &x[inner_start - m..inner_start - m + count];
        let b = &x[inner_start..inner_start + count];
        let c = &x[inner_start + m..inner_start + m + count];
        total.add(blocked_sum(count, |i| {
            let d = c[i] - 2.0 * b[i] + a[i];
            d * d
        }));
    }
    total.value()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn direct_oadev(y: &[f64], m: usize) -> f64 {
        // Textbook definition over averaged frequencies, no phase involved.
        let n = y.len();
        let avg = |k: usize| y[k..k + m].iter().sum::<f64>() / m as f64;
        let terms = n + 1 - 2 * m;
        let s: f64 = (0..terms).map(|k| (avg(k + m) - avg(k)).powi(2)).sum();
        (s / (2.0 * terms as f64)).sqrt()
    }

    #[test]
    fn oadev_matches_frequency_average_definition() {
        let y: Vec<f64> = (0..200)
            .map(|i| ((i * 7919) % 101) as f64 / 50.0 - 1.0)
            .collect();
        let phase = Phase::from_rate(y.clone());
        for m in [1, 2, 5, 17, 60] {
            let p = deviation_at(DeviationKind::Oadev, &phase, m, 1.0).unwrap();
            let expected = direct_oadev(&y, m);
            assert!((p.deviation - expected).abs() < 1e-12 * expected, "m={m}");
        }
    }

    #[test]
    fn totdev_at_unit_factor_equals_oadev() {
        let y: Vec<f64> = (0..300).map(|i| ((i * 31) % 17) as f64).collect();
        let phase = Phase::from_rate(y);
        let o = deviation_at(DeviationKind::Oadev, &phase, 1, 1.0).unwrap();
        let t = deviation_at(DeviationKind::Totdev, &phase, 1, 1.0).unwrap();
        assert!((o.deviation - t.deviation).abs() < 1e-12 * o.deviation);
    }

    #[test]
    fn mdev_sliding_window_matches_direct_sum() {
        let y: Vec<f64> = (0..400).map(|i| (((i * 7) % 13) as f64).sin()).collect();
        let phase = Phase::from_rate(y);
        let x = &phase.points;
        for m in [1, 3, 10, 33] {
            let count = DeviationKind::Mdev.term_count(m, x.len());
            let mut direct = 0.0;
            for j in 0..count {
                let s: f64 = (j..j + m)
                    .map(|i| x[i + 2 * m] - 2.0 * x[i + m] + x[i])
                    .sum();
                direct += s * s;
            }
            let fast = modified_sum(x, m, count);
            assert!((fast - direct).abs() < 1e-10 * direct, "m={m}");
        }
    }

    #[test]
    fn undefined_factors_give_none() {
        let phase = Phase::from_rate(vec![1.0, 2.0, 3.0]);
        assert!(deviation_at(DeviationKind::Adev, &phase, 2, 1.0).is_none());
        assert!(deviation_at(DeviationKind::Hdev, &phase, 1, 1.0).is_some());
        assert!(deviation_at(DeviationKind::Oadev, &phase, 0, 1.0).is_none());
    }
}
