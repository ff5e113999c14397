//! The turn-on transient y = settled + A·e^(−t/τ) of a soak: the least-squares fit, its
//! detection test, profile-likelihood 95 % intervals of τ and A, and the smallest amplitude
//! the data could have detected (white noise and drift).
//!
//! At the relative uncertainty of τ a short soak leaves (tens of per cent) the residual sum
//! of squares is far from a parabola in τ (flat towards long τ, steep towards short), so a
//! symmetric interval from the Jacobian misses on the long side. The profile interval is the
//! set of values whose best fit with the other parameters free raises the residual sum of
//! squares by at most χ²₁(0.95)·σ², σ² the residual variance (AR(1)-inflated). The slow bias
//! drift enters by scaling that threshold by (σ²_white + σ²_drift)/σ²_white of the estimate
//! at the solution: in the linear limit the interval is then the drift-widened Wald one,
//! and it keeps the profile's asymmetry. Bounds that the data never reach are 0 (τ's lower)
//! or ±∞.

use nalgebra::{Matrix3, Vector3};

/// χ²₁ at 95 %.
pub const CHI2_1_95: f64 = 3.841_458_820_694_124;
/// A transient counts as found when its amplitude exceeds this many standard errors.
pub const DETECTION_SIGMAS: f64 = 3.0;

/// A fitted transient, with standard errors from the Jacobian at the solution (the
/// Cramér–Rao bound for the residual noise, inflated for its lag-1 correlation), and the
/// linearised weights of τ̂ and Â in the observations (d τ̂ / d yᵢ, rows of (JᵀJ)⁻¹Jᵀ: they
/// sum to 0, the settled value taking any offset).
#[derive(Debug, Clone, PartialEq)]
pub struct ExponentialFit {
    pub tau: f64,
    pub amplitude: f64,
    pub settled: f64,
    pub se_tau: f64,
    pub se_amplitude: f64,
    pub tau_weights: Vec<f64>,
    pub amplitude_weights: Vec<f64>,
    /// Residual sum of squares at the solution.
    pub rss: f64,
    /// Residual variance, AR(1)-inflated.
    pub sigma2: f64,
}

/// Best settled value and amplitude for a fixed τ: (A, settled, residual sum of squares).
fn best_linear(t: &[f64], y: &[f64], tau: f64) -> (f64, f64, f64) {
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
    if det.abs() <= 1e-12 * n * see.max(f64::MIN_POSITIVE) {
        let c = sy / n;
        return (0.0, c, y.iter().map(|v| (v - c).powi(2)).sum());
    }
    let a = (n * sey - se * sy) / det;
    let c = (sy - a * se) / n;
    let rss = t
        .iter()
        .zip(y)
        .map(|(&ti, &yi)| (yi - c - a * (-ti / tau).exp()).powi(2))
        .sum();
    (a, c, rss)
}

/// Residual sum of squares for a fixed amplitude and τ, the settled value at its best.
fn rss_fixed(t: &[f64], y: &[f64], amplitude: f64, tau: f64) -> f64 {
    // One pass, no allocation (the profile intervals call this thousands of times); the
    // residuals are taken relative to the first one, so the settled value cancels exactly.
    let rate = -1.0 / tau;
    let residual = |ti: f64, yi: f64| yi - amplitude * (ti * rate).exp();
    let Some((&t0, &y0)) = t.first().zip(y.first()) else {
        return 0.0;
    };
    let shift = residual(t0, y0);
    let (sum, sum_sq) = t.iter().zip(y).fold((0.0, 0.0), |(s, q), (&ti, &yi)| {
        let d = residual(ti, yi) - shift;
        (s + d, q + d * d)
    });
    (sum_sq - sum * sum / t.len() as f64).max(0.0)
}

/// The range of ln τ the fits look at: a thousandth of the span to a hundred spans.
fn log_tau_range(span: f64) -> (f64, f64) {
    ((span / 1000.0).max(1e-3).ln(), (100.0 * span).ln())
}

/// The Gauss–Newton normal matrix at (settled, A, τ).
fn normal_matrix(t: &[f64], amplitude: f64, tau: f64) -> Matrix3<f64> {
    let mut jtj = Matrix3::zeros();
    for &ti in t {
        let j = jacobian_row(ti, amplitude, tau);
        jtj += j * j.transpose();
    }
    jtj
}

fn jacobian_row(t: f64, amplitude: f64, tau: f64) -> Vector3<f64> {
    let e = (-t / tau).exp();
    Vector3::new(1.0, e, amplitude * t / (tau * tau) * e)
}

/// Fits settled + A e^(−t/τ) to `(t, y)` by Levenberg–Marquardt on (settled, A, τ), started
/// from the best τ of a log-spaced scan (settled and A linear for each τ), with τ kept at
/// most half the span: a warm-up settles within its soak (what [`transient_found`] asks),
/// and a longer τ is a slope the soak's drift fits as well, whose A and τ run off together.
pub fn fit_exponential(t: &[f64], y: &[f64]) -> Option<ExponentialFit> {
    let span = t.last()? - t.first()?;
    if t.len() < 6 || span <= 0.0 {
        return None;
    }
    let n = t.len() as f64;
    let tau_max = span / 2.0;
    let (lo, hi) = ((span / 1000.0).max(1e-3).ln(), tau_max.ln());
    let grid = 60;
    let start = (0..=grid)
        .map(|k| (lo + (hi - lo) * k as f64 / grid as f64).exp())
        .min_by(|a, b| best_linear(t, y, *a).2.total_cmp(&best_linear(t, y, *b).2))?;
    let (a0, c0, _) = best_linear(t, y, start);
    let rss_of = |p: &Vector3<f64>| -> f64 {
        t.iter()
            .zip(y)
            .map(|(&ti, &yi)| (yi - p[0] - p[1] * (-ti / p[2]).exp()).powi(2))
            .sum()
    };
    let gradient = |p: &Vector3<f64>| -> Vector3<f64> {
        t.iter()
            .zip(y)
            .map(|(&ti, &yi)| {
                let r = yi - p[0] - p[1] * (-ti / p[2]).exp();
                jacobian_row(ti, p[1], p[2]) * r
            })
            .fold(Vector3::zeros(), |acc, v| acc + v)
    };
    let mut p = Vector3::new(c0, a0, start);
    let mut rss = rss_of(&p);
    let mut lambda = 1e-3;
    for _ in 0..100 {
        let jtj = normal_matrix(t, p[1], p[2]);
        let jtr = gradient(&p);
        let mut damped = jtj;
        for k in 0..3 {
            damped[(k, k)] += lambda * jtj[(k, k)].max(1e-300);
        }
        let Some(step) = damped.cholesky().map(|c| c.solve(&jtr)) else {
            lambda *= 10.0;
            continue;
        };
        let trial = p + step;
        let trial_rss = if trial[2] > 0.0 && trial[2] <= tau_max {
            rss_of(&trial)
        } else {
            f64::INFINITY
        };
        if trial_rss < rss {
            let converged = (rss - trial_rss) <= 1e-12 * rss;
            p = trial;
            rss = trial_rss;
            lambda = (lambda / 10.0).max(1e-12);
            if converged {
                break;
            }
        } else {
            lambda *= 10.0;
            if lambda > 1e12 {
                break;
            }
        }
    }
    let residuals: Vec<f64> = t
        .iter()
        .zip(y)
        .map(|(&ti, &yi)| yi - p[0] - p[1] * (-ti / p[2]).exp())
        .collect();
    let den: f64 = residuals.iter().map(|r| r * r).sum();
    let rho = if den > 0.0 {
        (residuals.windows(2).map(|w| w[0] * w[1]).sum::<f64>() / den).clamp(0.0, 0.999)
    } else {
        0.0
    };
    let sigma2 = rss / (n - 3.0).max(1.0) * (1.0 + rho) / (1.0 - rho);
    let inverse = normal_matrix(t, p[1], p[2]).try_inverse()?;
    let cov = inverse * sigma2;
    let (mut tau_weights, mut amplitude_weights) = (Vec::with_capacity(t.len()), Vec::new());
    for &ti in t {
        let row = inverse * jacobian_row(ti, p[1], p[2]);
        amplitude_weights.push(row[1]);
        tau_weights.push(row[2]);
    }
    Some(ExponentialFit {
        tau: p[2],
        amplitude: p[1],
        settled: p[0],
        se_tau: cov[(2, 2)].max(0.0).sqrt(),
        se_amplitude: cov[(1, 1)].max(0.0).sqrt(),
        tau_weights,
        amplitude_weights,
        rss,
        sigma2,
    })
}

/// A transient stands out: its amplitude is at least [`DETECTION_SIGMAS`] standard errors of
/// the white noise and `drift` (the slow bias drift's σ of the amplitude estimate, 0 for white
/// noise alone), with a time constant of at most half the soak (the fit's bound; at the bound
/// the soak gives τ a lower limit only, see [`tau_at_bound`]).
pub fn transient_found(f: &ExponentialFit, soak_s: f64, drift: f64) -> bool {
    f.amplitude.abs() > DETECTION_SIGMAS * f.se_amplitude.hypot(drift)
        && f.tau <= soak_s / 2.0 * (1.0 + 1e-9)
}

/// Whether the fitted τ sits at its bound, half the soak: the soak is too short to show the
/// transient settle, and τ is at least the interval's lower end, not bounded above.
pub fn tau_at_bound(f: &ExponentialFit, soak_s: f64) -> bool {
    f.tau >= soak_s / 2.0 * (1.0 - 1e-6)
}

/// From `x0`, where `excess(x0) < 0`, steps by `step` at most `steps` times until
/// `excess ≥ 0`, then bisects: the crossing, or `None` when it is not reached.
fn crossing(excess: impl Fn(f64) -> f64, x0: f64, step: f64, steps: usize) -> Option<f64> {
    let mut inside = x0;
    for k in 1..=steps {
        let x = x0 + step * k as f64;
        if excess(x) >= 0.0 {
            let mut outside = x;
            for _ in 0..30 {
                let mid = 0.5 * (inside + outside);
                if excess(mid) >= 0.0 {
                    outside = mid;
                } else {
                    inside = mid;
                }
            }
            return Some(0.5 * (inside + outside));
        }
        inside = x;
    }
    None
}

/// Profile-likelihood 95 % interval of τ: the τ whose best settled value and amplitude raise
/// the residual sum of squares by at most χ²₁(0.95)·σ²·`inflation`. `[0, ∞]` ends where
/// the data never reach the threshold (within a hundred-thousandth of the span and a
/// hundred spans).
pub fn tau_interval(t: &[f64], y: &[f64], f: &ExponentialFit, inflation: f64) -> [f64; 2] {
    let span = t[t.len() - 1] - t[0];
    let u0 = f.tau.ln();
    let floor = f.rss.min(best_linear(t, y, f.tau).2);
    let threshold = CHI2_1_95 * f.sigma2 * inflation.max(1.0);
    let excess = |u: f64| best_linear(t, y, u.exp()).2 - floor - threshold;
    let step = 0.02;
    let (lo_u, _) = log_tau_range(span);
    let down = ((u0 - (lo_u - 4.6)) / step).ceil().max(0.0) as usize;
    let up = (((100.0 * span).ln() - u0) / step).ceil().max(0.0) as usize;
    [
        crossing(excess, u0, -step, down).map_or(0.0, f64::exp),
        crossing(excess, u0, step, up).map_or(f64::INFINITY, f64::exp),
    ]
}

/// The least residual sum of squares for a fixed amplitude, τ and the settled value free: a
/// log-spaced scan of τ refined by golden section around its best point.
fn rss_for_amplitude(t: &[f64], y: &[f64], amplitude: f64) -> f64 {
    let span = t[t.len() - 1] - t[0];
    let (lo, hi) = log_tau_range(span);
    let grid = 32;
    let u = |k: usize| lo + (hi - lo) * k as f64 / grid as f64;
    let rss = |u: f64| rss_fixed(t, y, amplitude, u.exp());
    let (best, best_rss) = (0..=grid)
        .map(|k| (k, rss(u(k))))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap_or((0, f64::INFINITY));
    // Golden section on the bracket around the best grid point, one evaluation per step.
    let (mut a, mut b) = (u(best.saturating_sub(1)), u((best + 1).min(grid)));
    let g = (5f64.sqrt() - 1.0) / 2.0;
    let (mut x1, mut x2) = (b - g * (b - a), a + g * (b - a));
    let (mut f1, mut f2) = (rss(x1), rss(x2));
    for _ in 0..30 {
        if f1 < f2 {
            b = x2;
            (x2, f2) = (x1, f1);
            x1 = b - g * (b - a);
            f1 = rss(x1);
        } else {
            a = x1;
            (x1, f1) = (x2, f2);
            x2 = a + g * (b - a);
            f2 = rss(x2);
        }
    }
    f1.min(f2).min(best_rss)
}

/// Profile-likelihood 95 % interval of the amplitude (τ and the settled value free), in the
/// unit of `y`, with the threshold of [`tau_interval`]; ±∞ where it is not reached within
/// 100 standard errors.
pub fn amplitude_interval(t: &[f64], y: &[f64], f: &ExponentialFit, inflation: f64) -> [f64; 2] {
    let floor = f.rss.min(rss_for_amplitude(t, y, f.amplitude));
    let threshold = CHI2_1_95 * f.sigma2 * inflation.max(1.0);
    let excess = |a: f64| rss_for_amplitude(t, y, a) - floor - threshold;
    let scale = f.se_amplitude * inflation.max(1.0).sqrt();
    let step = if scale > 0.0 {
        scale / 4.0
    } else {
        f.amplitude.abs().max(f64::MIN_POSITIVE) / 20.0
    };
    [
        crossing(excess, f.amplitude, -step, 400).unwrap_or(f64::NEG_INFINITY),
        crossing(excess, f.amplitude, step, 400).unwrap_or(f64::INFINITY),
    ]
}

/// The smallest amplitude that stands [`DETECTION_SIGMAS`] standard errors out for a
/// transient of time constant `tau` on samples at `t` with residual variance `sigma2`: the
/// standard error of A with (settled, A, τ) fitted (it does not depend on A), its white part
/// from the Jacobian and `drift_sigma` of its linearised weights added. Without drift it is
/// the amplitude the detection test finds half the time.
pub fn detection_limit(
    t: &[f64],
    sigma2: f64,
    tau: f64,
    drift_sigma: &dyn Fn(&[f64]) -> f64,
) -> Option<f64> {
    let inverse = normal_matrix(t, 1.0, tau).try_inverse()?;
    let weights: Vec<f64> = t
        .iter()
        .map(|&ti| (inverse * jacobian_row(ti, 1.0, tau))[1])
        .collect();
    let white = (inverse[(1, 1)] * sigma2).max(0.0).sqrt();
    Some(DETECTION_SIGMAS * white.hypot(drift_sigma(&weights)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drift::Drift;
    use imulab_sim::rng::Stream;

    #[test]
    fn the_exponential_fit_recovers_its_time_constant() {
        let t: Vec<f64> = (0..1800).map(|i| i as f64 + 0.5).collect();
        let y: Vec<f64> = t
            .iter()
            .enumerate()
            .map(|(i, t)| 1.0 + 2.0 * (-t / 300.0).exp() + if i % 2 == 0 { 0.01 } else { -0.01 })
            .collect();
        let f = fit_exponential(&t, &y).unwrap();
        assert!((f.tau - 300.0).abs() < 3.0, "{f:?}");
        assert!((f.amplitude - 2.0).abs() < 0.01 && (f.settled - 1.0).abs() < 0.01);
        assert!(
            f.se_amplitude < 0.01 && f.se_tau > 0.0 && f.se_tau < 3.0,
            "{f:?}"
        );
        let [lo, hi] = tau_interval(&t, &y, &f, 1.0);
        assert!(lo < f.tau && f.tau < hi && hi - lo < 12.0, "{lo} {hi}");
    }

    /// White noise of the 1 s blocks: τ's linearised standard error is about 32 % of τ.
    const NOISE: f64 = 0.8;

    /// Transients of τ 100 s, A 1 on a 600 s soak of 1 s blocks, [`NOISE`] and, with `walk`
    /// (per block), a rate random walk whose drift the intervals are given: (found, τ inside
    /// its interval, A inside its interval).
    fn coverage(walk: f64, seeds: u64) -> (usize, usize, usize) {
        let t: Vec<f64> = (0..600).map(|i| i as f64).collect();
        let drift = Drift {
            flicker: 0.0,
            random_walk: walk * walk,
        };
        let (mut found, mut tau_in, mut amplitude_in) = (0, 0, 0);
        for seed in 0..seeds {
            let mut noise = Stream::new(seed, "warm-up coverage");
            let mut level = 0.0;
            let y: Vec<f64> = t
                .iter()
                .map(|&ti| {
                    level += walk * noise.normal();
                    level + (-ti / 100.0).exp() + NOISE * noise.normal()
                })
                .collect();
            let Some(f) = fit_exponential(&t, &y) else {
                continue;
            };
            if !transient_found(&f, 600.0, 0.0) {
                continue;
            }
            found += 1;
            let inflation = |se: f64, weights: &[f64]| {
                let d = drift.sigma(&t, weights, 1.0);
                (se * se + d * d) / (se * se)
            };
            let [lo, hi] = tau_interval(&t, &y, &f, inflation(f.se_tau, &f.tau_weights));
            tau_in += usize::from((lo..=hi).contains(&100.0));
            let [lo, hi] =
                amplitude_interval(&t, &y, &f, inflation(f.se_amplitude, &f.amplitude_weights));
            amplitude_in += usize::from((lo..=hi).contains(&1.0));
        }
        (found, tau_in, amplitude_in)
    }

    #[test]
    fn profile_intervals_cover_a_known_transient_in_95_percent() {
        for walk in [0.0, 0.015] {
            let (found, tau_in, amplitude_in) = coverage(walk, 160);
            assert!(found >= 100, "walk {walk}: found in {found} of 160");
            let share = |k: usize| k as f64 / found as f64;
            assert!(
                share(tau_in) >= 0.90 && share(tau_in) <= 0.99,
                "walk {walk}: τ covered in {tau_in} of {found}"
            );
            assert!(
                share(amplitude_in) >= 0.90 && share(amplitude_in) <= 0.99,
                "walk {walk}: A covered in {amplitude_in} of {found}"
            );
        }
    }

    #[test]
    fn a_slope_is_fitted_with_tau_at_its_bound_not_run_off() {
        // A drift over the soak and no transient: the exponential that fits it best has
        // ever longer τ and larger A; the fit stops at τ = half the span.
        let t: Vec<f64> = (0..600).map(|i| i as f64).collect();
        let mut noise = Stream::new(3, "slope");
        let y: Vec<f64> = t
            .iter()
            .map(|&ti| 1e-3 * ti + 0.01 * noise.normal())
            .collect();
        let f = fit_exponential(&t, &y).unwrap();
        assert!(f.tau <= 299.5 * (1.0 + 1e-9), "τ {}", f.tau);
        assert!(tau_at_bound(&f, 599.0), "τ {}", f.tau);
        assert!(f.amplitude.abs() < 10.0, "A {}", f.amplitude);
    }

    #[test]
    fn the_detection_limit_is_what_the_test_finds() {
        // A transient at the limit passes the test in about half the cases.
        let t: Vec<f64> = (0..600).map(|i| i as f64).collect();
        let limit = detection_limit(&t, 0.12 * 0.12, 100.0, &|_| 0.0).unwrap();
        let found = (0..200)
            .filter(|&seed| {
                let mut noise = Stream::new(seed, "detection limit");
                let y: Vec<f64> = t
                    .iter()
                    .map(|&ti| limit * (-ti / 100.0).exp() + 0.12 * noise.normal())
                    .collect();
                fit_exponential(&t, &y).is_some_and(|f| transient_found(&f, 600.0, 0.0))
            })
            .count();
        assert!(
            (60..=140).contains(&found),
            "{found} of 200 at the limit {limit}"
        );
    }
}
