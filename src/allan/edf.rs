//! Equivalent degrees of freedom and chi-squared confidence intervals.
//!
//! ADEV, OADEV, MDEV/TDEV, HDEV and OHDEV use the general algorithm of Greenhall &
//! Riley, "Uncertainty of stability variances based on finite differences" (2003/2004),
//! which is noise-type aware and the one Stable32 uses; TOTDEV uses the NIST SP 1065
//! (Riley 2008) empirical formula edf = b·T/τ − c. The chi-squared quantiles come from
//! `statrs`.

use super::deviation::DeviationKind;
use statrs::distribution::{ChiSquared, ContinuousCDF};

/// Two-sided coverage of the "1 σ" interval.
pub const ONE_SIGMA_COVERAGE: f64 = 0.682_689_492_137_085_9;

/// Power-law noise exponent α of S_y(f) ∝ f^α: 2 white PM, 1 flicker PM, 0 white FM
/// (angle/velocity random walk), −1 flicker FM (bias instability), −2 random-walk FM
/// (rate random walk), −3 flicker walk FM, −4 random-run FM.
pub type Alpha = i32;

/// EDF of `kind` at averaging factor `m` with `n` phase points, for dominant noise `alpha`.
/// Returns `None` where the method has no formula (e.g. α outside the range it covers).
pub fn edf(kind: DeviationKind, alpha: Alpha, m: usize, n: usize) -> Option<f64> {
    let value = match kind {
        DeviationKind::Adev => greenhall(alpha, 2, m, n, false, false),
        DeviationKind::Oadev => greenhall(alpha, 2, m, n, true, false),
        DeviationKind::Mdev | DeviationKind::Tdev => greenhall(alpha, 2, m, n, true, true),
        DeviationKind::Hdev => greenhall(alpha, 3, m, n, false, false),
        DeviationKind::Ohdev => greenhall(alpha, 3, m, n, true, false),
        DeviationKind::Totdev => totdev_edf(alpha, m, n),
    }?;
    (value.is_finite() && value > 0.0).then_some(value)
}

/// SP 1065 TOTDEV: edf = b·(T/τ) − c with T = (n−1)·τ0; (b, c) per noise type. For the PM
/// noises, which TOTDEV is not meant for, the white-FM coefficients are used.
fn totdev_edf(alpha: Alpha, m: usize, n: usize) -> Option<f64> {
    let (b, c) = match alpha {
        -1 => (1.168, 0.222),
        a if a <= -2 => (0.927, -0.358),
        _ => (1.5, 0.0),
    };
    Some(b * ((n - 1) as f64 / m as f64) - c)
}

/// Two-sided confidence interval `(low, high)` of a deviation with `edf` degrees of freedom.
pub fn confidence_interval(deviation: f64, edf: f64, coverage: f64) -> Option<(f64, f64)> {
    if !(edf > 0.0 && edf.is_finite() && deviation.is_finite()) {
        return None;
    }
    let tail = (1.0 - coverage) / 2.0;
    let chi_low = chi_squared_quantile(edf, tail)?;
    let chi_high = chi_squared_quantile(edf, 1.0 - tail)?;
    if !(chi_low > 0.0 && chi_high.is_finite()) {
        return None;
    }
    let variance = deviation * deviation;
    Some((
        (variance * edf / chi_high).sqrt(),
        (variance * edf / chi_low).sqrt(),
    ))
}

/// Quantile `p` of the chi-squared distribution with `nu` degrees of freedom: `statrs`'
/// inversion (above 10⁴ the Wilson–Hilferty cube approximation, relative error below
/// 1e-7 there, where the incomplete-gamma inversion loses accuracy), then Newton steps on
/// `statrs`' CDF. The steps matter: the inversion alone is off by 1.6e-3 relative at
/// ν ≈ 300 (a 68 % bound of PHASE.DAT's OADEV at τ = 4 s missed Stable32's by 1.06e-3).
pub fn chi_squared_quantile(nu: f64, p: f64) -> Option<f64> {
    if !(nu > 0.0 && nu.is_finite() && p > 0.0 && p < 1.0) {
        return None;
    }
    let distribution = ChiSquared::new(nu).ok()?;
    let mut q = if nu > 1e4 {
        use statrs::distribution::Normal;
        let z = Normal::new(0.0, 1.0).ok()?.inverse_cdf(p);
        let c = 2.0 / (9.0 * nu);
        nu * (1.0 - c + z * c.sqrt()).powi(3)
    } else {
        distribution.inverse_cdf(p)
    };
    if nu <= 1e4 {
        // The density from its logarithm: `statrs`' pdf gives steps that do not converge
        // at large ν.
        let half = nu / 2.0;
        let log_norm = half * std::f64::consts::LN_2 + statrs::function::gamma::ln_gamma(half);
        for _ in 0..6 {
            let density = ((half - 1.0) * q.ln() - q / 2.0 - log_norm).exp();
            if !(density > 0.0 && density.is_finite()) {
                break;
            }
            let step = (distribution.cdf(q) - p) / density;
            let next = q - step;
            if !(next > 0.0 && next.is_finite()) {
                break;
            }
            q = next;
            if step.abs() <= 1e-14 * q {
                break;
            }
        }
    }
    q.is_finite().then_some(q)
}

// --- Greenhall & Riley's algorithm -------------------------------------------------------

/// Eq. (7): the generalized autocovariance kernel of the power-law noise.
fn sw(t: f64, alpha: i32) -> f64 {
    let log_term = |p: i32| {
        if t == 0.0 {
            0.0
        } else {
            t.powi(p) * t.abs().ln()
        }
    };
    match alpha {
        2 => -t.abs(),
        1 => log_term(2),
        0 => t.abs().powi(3),
        -1 => log_term(4),
        -2 => t.abs().powi(5),
        -3 => log_term(6),
        _ => t.abs().powi(7),
    }
}

/// Kernel after the averaging filter with factor `f` (`None` = infinite, the limit form).
fn sx(t: f64, f: Option<f64>, alpha: i32) -> f64 {
    match f {
        None => sw(t, alpha + 2),
        Some(f) => f * f * (2.0 * sw(t, alpha) - sw(t - 1.0 / f, alpha) - sw(t + 1.0 / f, alpha)),
    }
}

/// Kernel after the d-th difference (binomial weights).
fn sz(t: f64, f: Option<f64>, alpha: i32, d: u32) -> f64 {
    let weights: &[f64] = match d {
        1 => &[2.0, -1.0],
        2 => &[6.0, -4.0, 1.0],
        _ => &[20.0, -15.0, 6.0, -1.0],
    };
    let mut acc = weights[0] * sx(t, f, alpha);
    for (k, w) in weights.iter().enumerate().skip(1) {
        let k = k as f64;
        acc += w * (sx(t - k, f, alpha) + sx(t + k, f, alpha));
    }
    acc
}

fn basic_sum(j: f64, big_m: f64, s: f64, f: Option<f64>, alpha: i32, d: u32) -> f64 {
    let z0 = sz(0.0, f, alpha, d);
    let mut acc = z0 * z0;
    let zj = sz(j / s, f, alpha, d);
    acc += (1.0 - j / big_m) * zj * zj;
    let mut i = 1.0;
    while i < j {
        let z = sz(i / s, f, alpha, d);
        acc += 2.0 * (1.0 - i / big_m) * z * z;
        i += 1.0;
    }
    acc
}

/// Table 1 (modified variances): (a0, a1) by α (rows +2…−4) and d (columns 1…3).
fn table1(alpha: i32, d: u32) -> Option<(f64, f64)> {
    const T: [[(f64, f64); 3]; 7] = [
        [
            (2.0 / 3.0, 1.0 / 3.0),
            (7.0 / 9.0, 0.5),
            (22.0 / 25.0, 2.0 / 3.0),
        ],
        [(0.840, 0.345), (0.997, 0.616), (1.141, 0.843)],
        [(1.079, 0.368), (1.033, 0.607), (1.184, 0.848)],
        [(f64::NAN, f64::NAN), (1.048, 0.534), (1.180, 0.816)],
        [(f64::NAN, f64::NAN), (1.302, 0.535), (1.175, 0.777)],
        [(f64::NAN, f64::NAN), (f64::NAN, f64::NAN), (1.194, 0.703)],
        [(f64::NAN, f64::NAN), (f64::NAN, f64::NAN), (1.489, 0.702)],
    ];
    table_lookup(&T, alpha, d)
}

/// Table 2 (unmodified variances).
fn table2(alpha: i32, d: u32) -> Option<(f64, f64)> {
    const T: [[(f64, f64); 3]; 7] = [
        [(1.5, 0.5), (35.0 / 18.0, 1.0), (231.0 / 100.0, 1.5)],
        [(78.6, 25.2), (790.0, 410.0), (9950.0, 6520.0)],
        [
            (2.0 / 3.0, 1.0 / 6.0),
            (2.0 / 3.0, 1.0 / 3.0),
            (7.0 / 9.0, 0.5),
        ],
        [(f64::NAN, f64::NAN), (0.852, 0.375), (0.997, 0.617)],
        [(f64::NAN, f64::NAN), (1.079, 0.368), (1.033, 0.607)],
        [(f64::NAN, f64::NAN), (f64::NAN, f64::NAN), (1.053, 0.553)],
        [(f64::NAN, f64::NAN), (f64::NAN, f64::NAN), (1.302, 0.535)],
    ];
    table_lookup(&T, alpha, d)
}

/// Table 3 (unmodified variances, flicker PM): (b0, b1) by d.
fn table3(d: u32) -> (f64, f64) {
    match d {
        1 => (6.0, 4.0),
        2 => (15.23, 12.0),
        _ => (47.8, 40.0),
    }
}

fn table_lookup(t: &[[(f64, f64); 3]; 7], alpha: i32, d: u32) -> Option<(f64, f64)> {
    let row = usize::try_from(2 - alpha).ok()?;
    let entry = *t.get(row)?.get(usize::try_from(d).ok()?.checked_sub(1)?)?;
    (!entry.0.is_nan()).then_some(entry)
}

fn binomial(n: u32, k: u32) -> f64 {
    (0..k).fold(1.0, |acc, i| acc * (n - i) as f64 / (i + 1) as f64)
}

/// Greenhall & Riley EDF for a d-th difference variance (d = 2 Allan, d = 3 Hadamard).
fn greenhall(
    alpha: i32,
    d: u32,
    m: usize,
    n: usize,
    overlapping: bool,
    modified: bool,
) -> Option<f64> {
    // The noise must be one the d-th difference converges for: α > 1 − 2d.
    if !(-4..=2).contains(&alpha) || alpha <= 1 - 2 * d as i32 {
        return None;
    }
    let mf = m as f64;
    let f = if modified { 1.0 } else { mf };
    let s = if overlapping { mf } else { 1.0 };
    let l = mf / f + mf * d as f64;
    if (n as f64) < l {
        return None;
    }
    let big_m = 1.0 + (s * (n as f64 - l) / mf).floor();
    let j = big_m.min((d as f64 + 1.0) * s);
    const J_MAX: f64 = 100.0;
    let r = big_m / s;
    let inv = if modified {
        if j <= J_MAX {
            let z0 = sz(0.0, Some(1.0), alpha, d);
            basic_sum(j, big_m, s, Some(1.0), alpha, d) / (z0 * z0 * big_m)
        } else if r > d as f64 + 1.0 {
            let (a0, a1) = table1(alpha, d)?;
            (a0 - a1 / r) / r
        } else {
            let z0 = sz(0.0, Some(1.0), alpha, d);
            basic_sum(J_MAX, J_MAX, J_MAX / r, Some(1.0), alpha, d) / (z0 * z0 * J_MAX)
        }
    } else if alpha <= 0 {
        if j <= J_MAX {
            let fm = if mf * (d as f64 + 1.0) <= J_MAX {
                Some(mf)
            } else {
                None
            };
            let z0 = sz(0.0, fm, alpha, d);
            basic_sum(j, big_m, s, fm, alpha, d) / (z0 * z0 * big_m)
        } else if r > d as f64 + 1.0 {
            let (a0, a1) = table2(alpha, d)?;
            (a0 - a1 / r) / r
        } else {
            let z0 = sz(0.0, None, alpha, d);
            basic_sum(J_MAX, J_MAX, J_MAX / r, None, alpha, d) / (z0 * z0 * J_MAX)
        }
    } else if alpha == 1 {
        if j <= J_MAX {
            let z0 = sz(0.0, Some(mf), alpha, d);
            basic_sum(j, big_m, s, Some(mf), alpha, d) / (z0 * z0 * big_m)
        } else if r > d as f64 + 1.0 {
            let (a0, a1) = table2(alpha, d)?;
            let (b0, b1) = table3(d);
            (a0 - a1 / r) / ((b0 + b1 * mf.ln()).powi(2) * r)
        } else {
            let (b0, b1) = table3(d);
            let mp = J_MAX / r;
            basic_sum(J_MAX, J_MAX, mp, Some(mp), alpha, d) / ((b0 + b1 * mf.ln()).powi(2) * J_MAX)
        }
    } else {
        // α = 2, unmodified.
        let k = r.ceil();
        if k <= d as f64 {
            // Short records: fall back to the exact basic sum with the finite filter.
            let z0 = sz(0.0, Some(mf), alpha, d);
            basic_sum(j.min(J_MAX), big_m, s, Some(mf), alpha, d) / (z0 * z0 * big_m)
        } else {
            let a0 = binomial(4 * d, 2 * d) / binomial(2 * d, d).powi(2);
            let a1 = d as f64 / 2.0;
            (a0 - a1 / r) / big_m
        }
    };
    (inv > 0.0).then(|| 1.0 / inv)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overlapping_estimators_have_more_degrees_of_freedom() {
        // Stable32's PHASE.DAT tables (see tests/allan/reference.rs) pin the absolute values;
        // here the structure: equal at m = 1, overlapping ≫ non-overlapping at m > 1.
        let adev1 = edf(DeviationKind::Adev, 0, 1, 1001).unwrap();
        let oadev1 = edf(DeviationKind::Oadev, 0, 1, 1001).unwrap();
        assert!((adev1 - oadev1).abs() < 1e-9);
        assert!((adev1 - 782.03).abs() < 0.01, "{adev1}");
        for m in [2, 8, 32] {
            let a = edf(DeviationKind::Adev, 0, m, 1001).unwrap();
            let o = edf(DeviationKind::Oadev, 0, m, 1001).unwrap();
            assert!(o > 1.5 * a, "m={m}: {o} vs {a}");
        }
    }

    #[test]
    fn interval_brackets_the_estimate() {
        let (lo, hi) = confidence_interval(1.0, 50.0, ONE_SIGMA_COVERAGE).unwrap();
        assert!(lo < 1.0 && hi > 1.0 && lo > 0.8 && hi < 1.2);
        assert!(confidence_interval(1.0, 0.0, ONE_SIGMA_COVERAGE).is_none());
    }

    #[test]
    fn chi_squared_quantiles_are_continuous_across_the_switch() {
        for p in [0.025, 0.1587, 0.8413, 0.975] {
            let below = chi_squared_quantile(9_999.0, p).unwrap() / 9_999.0;
            let above = chi_squared_quantile(10_001.0, p).unwrap() / 10_001.0;
            assert!((below - above).abs() < 1e-5, "p={p}: {below} vs {above}");
        }
        // Known values: the 97.5 % point of chi-squared with 10 dof is 20.483177; the
        // 84.13 % point with 306 dof has a CDF of p to 1e-12.
        assert!((chi_squared_quantile(10.0, 0.975).unwrap() - 20.483_177).abs() < 1e-5);
        let q = chi_squared_quantile(306.0, 0.841_344_746).unwrap();
        let cdf = ChiSquared::new(306.0).unwrap().cdf(q);
        assert!((cdf - 0.841_344_746).abs() < 1e-12, "{q}: {cdf}");
        assert!(chi_squared_quantile(1e9, 0.5).unwrap().is_finite());
    }

    #[test]
    fn unsupported_noise_gives_none() {
        assert!(edf(DeviationKind::Oadev, -3, 4, 1000).is_none());
        assert!(edf(DeviationKind::Hdev, -4, 4, 1000).is_some());
    }
}
