//! Polynomial fit of bias against temperature with the order chosen from the data.
//!
//! Least squares on the normal equations of the scaled temperature (orders up to 4 keep them
//! well conditioned; nalgebra's Cholesky solves them). The residuals of a bias series are
//! correlated in time (bias instability, random walk), so the standard errors are inflated by
//! the AR(1) factor (1 + ρ)/(1 − ρ) of the residuals in time order, and the order is chosen by
//! the Bayesian information criterion on that effective number of points. Intervals are 95 %
//! (Student t with the effective degrees of freedom).

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use statrs::distribution::{ContinuousCDF, StudentsT};

/// Width of the temperature bins that count as distinct temperatures, °C.
pub const DISTINCT_BIN_C: f64 = 0.5;
/// Highest order the fit considers.
pub const HIGHEST_ORDER: usize = 4;

/// A fitted polynomial y = Σ c_k (T − reference)^k.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PolyFit {
    pub reference_c: f64,
    pub order: usize,
    /// c_0 … c_order in the input unit per °C^k.
    pub coefficients: Vec<f64>,
    /// 95 % half-widths of the coefficients.
    pub ci95: Vec<f64>,
    /// Covariance of the coefficients (AR(1)-inflated).
    pub covariance: Vec<Vec<f64>>,
    /// RMS of the residuals, input unit.
    pub residual_rms: f64,
    pub points: usize,
    /// Points after the correction for correlated residuals.
    pub effective_points: f64,
    /// Lag-1 autocorrelation of the residuals.
    pub residual_lag1: f64,
    /// Temperature range of the data, °C.
    pub range_c: [f64; 2],
    /// BIC of each order tried (order, BIC), lowest chosen unless the order was given.
    pub bic: Vec<(usize, f64)>,
    /// Student t factor for the 95 % intervals.
    t95: f64,
}

impl PolyFit {
    /// Fitted value at `t_c`.
    pub fn eval(&self, t_c: f64) -> f64 {
        let u = t_c - self.reference_c;
        self.coefficients
            .iter()
            .rev()
            .fold(0.0, |acc, c| acc * u + c)
    }

    /// 95 % half-width of the fitted curve at `t_c`.
    pub fn band(&self, t_c: f64) -> f64 {
        let u = t_c - self.reference_c;
        let powers: Vec<f64> = (0..=self.order).map(|k| u.powi(k as i32)).collect();
        let mut var = 0.0;
        for (j, pj) in powers.iter().enumerate() {
            for (k, pk) in powers.iter().enumerate() {
                var += pj * pk * self.covariance[j][k];
            }
        }
        self.t95 * var.max(0.0).sqrt()
    }
}

/// Number of occupied [`DISTINCT_BIN_C`] bins among `temps`.
pub fn distinct_temperatures(temps: &[f64]) -> usize {
    let mut keys: Vec<i64> = temps
        .iter()
        .filter(|t| t.is_finite())
        .map(|t| (t / DISTINCT_BIN_C).floor() as i64)
        .collect();
    keys.sort_unstable();
    keys.dedup();
    keys.len()
}

struct Solved {
    coefficients: Vec<f64>,
    /// (XᵀX)⁻¹ in unscaled coefficients.
    inverse: Vec<Vec<f64>>,
    rss: f64,
    residuals: Vec<f64>,
}

fn solve(x: &[f64], y: &[f64], reference: f64, scale: f64, order: usize) -> Option<Solved> {
    let p = order + 1;
    let mut ata = DMatrix::<f64>::zeros(p, p);
    let mut aty = DVector::<f64>::zeros(p);
    let mut row = vec![0.0; p];
    for (&t, &v) in x.iter().zip(y) {
        let u = (t - reference) / scale;
        let mut power = 1.0;
        for r in row.iter_mut() {
            *r = power;
            power *= u;
        }
        for j in 0..p {
            aty[j] += row[j] * v;
            for k in 0..=j {
                ata[(j, k)] += row[j] * row[k];
            }
        }
    }
    for j in 0..p {
        for k in 0..j {
            ata[(k, j)] = ata[(j, k)];
        }
    }
    let chol = ata.cholesky()?;
    let b = chol.solve(&aty);
    let inv = chol.inverse();
    let coefficients: Vec<f64> = (0..p).map(|k| b[k] / scale.powi(k as i32)).collect();
    let inverse = (0..p)
        .map(|j| {
            (0..p)
                .map(|k| inv[(j, k)] / scale.powi((j + k) as i32))
                .collect()
        })
        .collect();
    let residuals: Vec<f64> = x
        .iter()
        .zip(y)
        .map(|(&t, &v)| {
            let u = t - reference;
            v - coefficients.iter().rev().fold(0.0, |acc, c| acc * u + c)
        })
        .collect();
    let rss = residuals.iter().map(|r| r * r).sum();
    Some(Solved {
        coefficients,
        inverse,
        rss,
        residuals,
    })
}

fn lag1(residuals: &[f64]) -> f64 {
    let den: f64 = residuals.iter().map(|r| r * r).sum();
    if den <= 0.0 {
        return 0.0;
    }
    let num: f64 = residuals.windows(2).map(|w| w[0] * w[1]).sum();
    (num / den).clamp(0.0, 0.999)
}

/// Fits y against temperature x (both in time order). `order`: the order wanted, or `None`
/// to choose it (up to `max_order`) by BIC. The error says what the data lack.
pub fn fit_polynomial(
    x: &[f64],
    y: &[f64],
    reference_c: f64,
    order: Option<usize>,
    max_order: usize,
) -> Result<PolyFit, String> {
    let n = x.len().min(y.len());
    let (x, y) = (&x[..n], &y[..n]);
    let (lo, hi) = x
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &t| {
            (lo.min(t), hi.max(t))
        });
    let distinct = distinct_temperatures(x);
    let wanted_max = order.unwrap_or(max_order).min(HIGHEST_ORDER);
    // An order-k fit needs k + 1 distinct temperatures, plus one to leave a residual.
    if distinct < 3 {
        return Err(format!(
            "the temperature covers {distinct} distinct value(s) ({DISTINCT_BIN_C} °C apart; range {lo:.2} to {hi:.2} °C): \
             a bias-against-temperature fit needs at least 3 (a first-order fit plus one to check it), \
             e.g. a chamber ramp or steps"
        ));
    }
    if let Some(k) = order {
        if k > HIGHEST_ORDER {
            return Err(format!("--order {k}: at most {HIGHEST_ORDER}"));
        }
        if distinct < k + 2 {
            return Err(format!(
                "--order {k} needs at least {} distinct temperatures ({DISTINCT_BIN_C} °C apart), the data have {distinct} (range {lo:.2} to {hi:.2} °C)",
                k + 2
            ));
        }
    }
    let top = wanted_max.min(distinct - 2).max(1);
    let scale = ((hi - lo) / 2.0).max(1e-6);
    let orders: Vec<usize> = match order {
        Some(k) => vec![k],
        None => (1..=top).collect(),
    };
    let solved: Vec<(usize, Solved)> = orders
        .iter()
        .filter_map(|&k| solve(x, y, reference_c, scale, k).map(|s| (k, s)))
        .collect();
    let Some((_, highest)) = solved.last() else {
        return Err(
            "the fit's normal equations are singular (temperatures too close together)".into(),
        );
    };
    let rho = lag1(&highest.residuals);
    let n_eff = (n as f64 * (1.0 - rho) / (1.0 + rho)).max(2.0);
    let bic: Vec<(usize, f64)> = solved
        .iter()
        .map(|(k, s)| {
            let mean_sq = (s.rss / n as f64).max(f64::MIN_POSITIVE);
            (*k, n_eff * mean_sq.ln() + (*k + 1) as f64 * n_eff.ln())
        })
        .collect();
    let chosen = bic
        .iter()
        .enumerate()
        .min_by(|a, b| a.1 .1.total_cmp(&b.1 .1))
        .map(|(i, _)| i)
        .unwrap_or(0);
    let (k, s) = &solved[chosen];
    let p = k + 1;
    let rho_k = lag1(&s.residuals);
    let inflation = (1.0 + rho_k) / (1.0 - rho_k);
    let n_eff_k = (n as f64 / inflation).max(p as f64 + 1.0);
    let sigma2 = s.rss / (n.saturating_sub(p)).max(1) as f64;
    let covariance: Vec<Vec<f64>> = s
        .inverse
        .iter()
        .map(|row| row.iter().map(|v| v * sigma2 * inflation).collect())
        .collect();
    let dof = (n_eff_k - p as f64).max(1.0);
    let t95 = StudentsT::new(0.0, 1.0, dof)
        .map(|d| d.inverse_cdf(0.975))
        .unwrap_or(1.96);
    let ci95 = (0..p).map(|j| t95 * covariance[j][j].sqrt()).collect();
    Ok(PolyFit {
        reference_c,
        order: *k,
        coefficients: s.coefficients.clone(),
        ci95,
        covariance,
        residual_rms: (s.rss / n as f64).sqrt(),
        points: n,
        effective_points: n_eff_k,
        residual_lag1: rho_k,
        range_c: [lo, hi],
        bic,
        t95,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(i: usize) -> f64 {
        // A deterministic, uncorrelated ±1 sequence.
        if (i.wrapping_mul(2_654_435_761) >> 7) & 1 == 0 {
            1.0
        } else {
            -1.0
        }
    }

    #[test]
    fn chooses_the_true_order_and_recovers_coefficients() {
        let x: Vec<f64> = (0..4000)
            .map(|i| -10.0 + 70.0 * i as f64 / 4000.0)
            .collect();
        let y: Vec<f64> = x
            .iter()
            .enumerate()
            .map(|(i, t)| 0.3 + 0.8 * (t - 25.0) + 0.004 * (t - 25.0).powi(2) + 0.01 * noise(i))
            .collect();
        let f = fit_polynomial(&x, &y, 25.0, None, 3).unwrap();
        assert_eq!(f.order, 2, "{:?}", f.bic);
        assert!((f.coefficients[1] - 0.8).abs() < 1e-3);
        assert!((f.coefficients[2] - 0.004).abs() < 1e-4);
        assert!((f.coefficients[1] - 0.8).abs() <= f.ci95[1] * 3.0);
        assert!((f.eval(40.0) - (0.3 + 12.0 + 0.9)).abs() < 0.01);
        assert!(f.band(40.0) > 0.0 && f.band(40.0) < 0.01);
        let linear: Vec<f64> = x
            .iter()
            .enumerate()
            .map(|(i, t)| 2.0 * t + 0.01 * noise(i))
            .collect();
        assert_eq!(fit_polynomial(&x, &linear, 25.0, None, 3).unwrap().order, 1);
    }

    #[test]
    fn too_few_temperatures_say_what_is_needed() {
        let x = vec![25.0; 100];
        let y = vec![1.0; 100];
        let e = fit_polynomial(&x, &y, 25.0, None, 3).unwrap_err();
        assert!(e.contains("1 distinct") && e.contains("at least 3"), "{e}");
        let x: Vec<f64> = (0..100).map(|i| 25.0 + (i % 3) as f64).collect();
        let e = fit_polynomial(&x, &y, 25.0, Some(2), 3).unwrap_err();
        assert!(e.contains("--order 2 needs at least 4"), "{e}");
    }
}
