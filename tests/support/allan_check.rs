//! A small independent overlapping Allan deviation, the equivalent degrees of freedom of its
//! estimates (NIST SP 1065, section 5.2.4 simple approximations) and a weighted least-squares
//! fit of the classic noise terms, for the simulator's tests and benchmark. Written here
//! rather than taken from `imulab::allan` so the simulator is checked independently.

/// Overlapping Allan deviation of rate samples `y` (spacing `dt`) at τ = m·dt.
pub fn oadev(y: &[f64], dt: f64, m: usize) -> f64 {
    let mut x = Vec::with_capacity(y.len() + 1);
    let mut acc = 0.0;
    x.push(0.0);
    for v in y {
        acc += v * dt;
        x.push(acc);
    }
    let n = x.len();
    assert!(n > 2 * m, "too few samples for m = {m}");
    let tau = m as f64 * dt;
    let sum: f64 = (0..n - 2 * m)
        .map(|i| {
            let d = x[i + 2 * m] - 2.0 * x[i + m] + x[i];
            d * d
        })
        .sum();
    (sum / (2.0 * tau * tau * (n - 2 * m) as f64)).sqrt()
}

/// The noise types whose EDF approximations we use.
#[derive(Clone, Copy, Debug)]
pub enum Noise {
    /// White rate noise (ARW/VRW; "white FM").
    White,
    /// Flicker rate noise (bias instability; "flicker FM").
    Flicker,
    /// Random walk of rate (RRW; "random-walk FM").
    RandomWalk,
}

/// Equivalent degrees of freedom of an overlapping ADEV estimate from `n` rate samples at
/// averaging factor `m` (SP 1065 eq. for OADEV, N = n + 1 phase points).
pub fn edf(noise: Noise, n: usize, m: usize) -> f64 {
    let nn = (n + 1) as f64;
    let m = m as f64;
    match noise {
        Noise::White => {
            (3.0 * (nn - 1.0) / (2.0 * m) - 2.0 * (nn - 2.0) / nn) * 4.0 * m * m
                / (4.0 * m * m + 5.0)
        }
        Noise::Flicker => {
            if m < 1.5 {
                2.0 * (nn - 2.0).powi(2) / (2.3 * nn - 4.9)
            } else {
                5.0 * nn * nn / (4.0 * m * (nn + 3.0 * m))
            }
        }
        Noise::RandomWalk => {
            (nn - 2.0) / m * ((nn - 1.0).powi(2) - 3.0 * m * (nn - 1.0) + 4.0 * m * m)
                / (nn - 3.0).powi(2)
        }
    }
}

/// Relative tolerance for an ADEV estimate with `edf` degrees of freedom: `k` standard
/// errors of a deviation estimated from a χ² variable (σ_rel ≈ 1/√(2·edf)).
pub fn tolerance(edf: f64, k: f64) -> f64 {
    k / (2.0 * edf).sqrt()
}

/// Averaging factors spaced about `per_decade` per decade from 1 to n/`min_clusters`.
pub fn log_factors(n: usize, per_decade: f64, min_clusters: usize) -> Vec<usize> {
    let max = n / min_clusters;
    let mut out = Vec::new();
    let mut k = 0.0;
    loop {
        let m = 10f64.powf(k / per_decade).round() as usize;
        if m > max {
            break;
        }
        if out.last() != Some(&m) {
            out.push(m);
        }
        k += 1.0;
    }
    out
}

/// Coefficients of AVAR(τ) = n²/τ + b² + k²τ/3 + r²τ²/2 fitted to (τ, adev) points by
/// least squares on the relative error, returned as (n, b, k, r) (each ≥ 0 by clamping).
pub fn fit_terms(points: &[(f64, f64)]) -> (f64, f64, f64, f64) {
    use nalgebra::{DMatrix, DVector};
    let rows = points.len();
    let a = DMatrix::from_fn(rows, 4, |i, j| {
        let (tau, adev) = points[i];
        let basis = [1.0 / tau, 1.0, tau / 3.0, tau * tau / 2.0][j];
        basis / (adev * adev)
    });
    let b = DVector::from_element(rows, 1.0);
    let c = a
        .svd(true, true)
        .solve(&b, 1e-14)
        .expect("least squares solve");
    let root = |v: f64| v.max(0.0).sqrt();
    (root(c[0]), root(c[1]), root(c[2]), root(c[3]))
}
