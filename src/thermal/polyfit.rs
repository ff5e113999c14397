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

/// Least squares of `y` on the powers 0..=`order` of `(x - reference) / scale`.
fn solve(x: &[f64], y: &[f64], reference: f64, scale: f64, order: usize) -> Option<Solved> {
    let scales: Vec<f64> = (0..=order).map(|k| scale.powi(k as i32)).collect();
    let fill = |i: usize, row: &mut [f64]| {
        let u = (x[i] - reference) / scale;
        let mut power = 1.0;
        for r in row.iter_mut() {
            *r = power;
            power *= u;
        }
    };
    solve_design(x.len().min(y.len()), order + 1, fill, y, &scales)
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

/// The rising and falling branches fitted jointly: one shared curve plus a gap polynomial,
/// rising = shared + gap/2, falling = shared − gap/2.
#[derive(Debug, Clone, PartialEq)]
pub struct BranchFit {
    /// Rising minus falling, with its covariance and 95 % factor.
    pub gap: PolyFit,
    pub rising: PolyFit,
    pub falling: PolyFit,
    /// (XᵀX)⁻¹ of the joint design (shared coefficients, then gap coefficients; unscaled).
    inverse: Vec<Vec<f64>>,
}

/// Fits `y` against temperature `x` on two branches at once (`rising[i]`: point `i` is on the
/// rising branch, else on the falling one; time order): a shared polynomial of `shared_order`
/// and a gap polynomial of the order in `gap_orders` (at most `shared_order`) with the lowest
/// BIC (a single order: `q..=q`). The common temperature range of the branches is each fit's
/// `range_c`. Standard errors are inflated for the lag-1 correlation of the residuals as in
/// [`fit_polynomial`].
pub fn fit_branches(
    x: &[f64],
    y: &[f64],
    rising: &[bool],
    reference_c: f64,
    shared_order: usize,
    gap_orders: std::ops::RangeInclusive<usize>,
) -> Result<BranchFit, String> {
    let n = x.len().min(y.len()).min(rising.len());
    let (x, y, rising) = (&x[..n], &y[..n], &rising[..n]);
    let ups = rising.iter().filter(|&&r| r).count();
    if ups == 0 || ups == n {
        return Err(format!(
            "the hysteresis fit needs both rising and falling ramps ({ups} rising, {} falling points)",
            n - ups
        ));
    }
    let side_range = |up: bool| {
        x.iter()
            .zip(rising)
            .filter(|(_, &r)| r == up)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (&t, _)| {
                (lo.min(t), hi.max(t))
            })
    };
    let (up_lo, up_hi) = side_range(true);
    let (down_lo, down_hi) = side_range(false);
    let (lo, hi) = (up_lo.max(down_lo), up_hi.min(down_hi));
    if hi <= lo || hi.is_nan() || lo.is_nan() {
        return Err(format!(
            "the rising ({up_lo:.1} to {up_hi:.1} °C) and falling ({down_lo:.1} to {down_hi:.1} °C) branches share no temperature range"
        ));
    }
    let distinct = |up: bool| {
        let t: Vec<f64> = x
            .iter()
            .zip(rising)
            .filter(|(_, &r)| r == up)
            .map(|(&t, _)| t)
            .collect();
        distinct_temperatures(&t)
    };
    let (d_up, d_down) = (distinct(true), distinct(false));
    if d_up.min(d_down) < shared_order + 2 {
        return Err(format!(
            "an order-{shared_order} fit of each branch needs {} distinct temperatures ({DISTINCT_BIN_C} °C apart) on both; rising has {d_up}, falling {d_down}",
            shared_order + 2
        ));
    }
    let (all_lo, all_hi) = x
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &t| {
            (lo.min(t), hi.max(t))
        });
    let scale = ((all_hi - all_lo) / 2.0).max(1e-6);
    let lowest_gap_order = (*gap_orders.start()).min(shared_order);
    let highest_gap_order = (*gap_orders.end()).min(shared_order);
    let solved: Vec<(usize, Solved)> = (lowest_gap_order..=highest_gap_order)
        .filter_map(|q| {
            let p = shared_order + 1;
            let columns = p + q + 1;
            let fill = |i: usize, row: &mut [f64]| {
                let u = (x[i] - reference_c) / scale;
                let half = if rising[i] { 0.5 } else { -0.5 };
                let mut power = 1.0;
                for k in 0..p {
                    row[k] = power;
                    if k <= q {
                        row[p + k] = half * power;
                    }
                    power *= u;
                }
            };
            let scales: Vec<f64> = (0..p).chain(0..=q).map(|k| scale.powi(k as i32)).collect();
            solve_design(n, columns, fill, y, &scales).map(|s| (q, s))
        })
        .collect();
    let Some((_, highest)) = solved.last() else {
        return Err("the branch fit's normal equations are singular".into());
    };
    let rho = lag1(&highest.residuals);
    let n_eff = (n as f64 * (1.0 - rho) / (1.0 + rho)).max(2.0);
    let chosen = solved
        .iter()
        .enumerate()
        .map(|(i, (q, s))| {
            let mean_sq = (s.rss / n as f64).max(f64::MIN_POSITIVE);
            let params = shared_order + 1 + q + 1;
            (i, n_eff * mean_sq.ln() + params as f64 * n_eff.ln(), *q)
        })
        .collect::<Vec<_>>();
    let bic: Vec<(usize, f64)> = chosen.iter().map(|&(_, b, q)| (q, b)).collect();
    let best = chosen
        .iter()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map_or(0, |c| c.0);
    let (q, s) = &solved[best];
    let p = shared_order + 1;
    let columns = p + q + 1;
    let rho_k = lag1(&s.residuals);
    let inflation = (1.0 + rho_k) / (1.0 - rho_k);
    let n_eff_k = (n as f64 / inflation).max(columns as f64 + 1.0);
    let sigma2 = s.rss / n.saturating_sub(columns).max(1) as f64;
    let cov: Vec<Vec<f64>> = s
        .inverse
        .iter()
        .map(|row| row.iter().map(|v| v * sigma2 * inflation).collect())
        .collect();
    let dof = (n_eff_k - columns as f64).max(1.0);
    let t95 = StudentsT::new(0.0, 1.0, dof)
        .map(|d| d.inverse_cdf(0.975))
        .unwrap_or(1.96);
    // Each reported curve is a linear map of the parameters: curve_k = Σ_j m[k][j] θ_j.
    let curve = |map: Vec<Vec<f64>>, order: usize, bic: Vec<(usize, f64)>| -> PolyFit {
        let coefficients: Vec<f64> = map
            .iter()
            .map(|m| m.iter().zip(&s.coefficients).map(|(a, b)| a * b).sum())
            .collect();
        let covariance: Vec<Vec<f64>> = map
            .iter()
            .map(|mj| {
                map.iter()
                    .map(|mk| {
                        let mut v = 0.0;
                        for (a, ca) in mj.iter().zip(&cov) {
                            for (b, cab) in mk.iter().zip(ca) {
                                v += a * b * cab;
                            }
                        }
                        v
                    })
                    .collect()
            })
            .collect();
        let ci95 = (0..=order).map(|k| t95 * covariance[k][k].sqrt()).collect();
        PolyFit {
            reference_c,
            order,
            coefficients,
            ci95,
            covariance,
            residual_rms: (s.rss / n as f64).sqrt(),
            points: n,
            effective_points: n_eff_k,
            residual_lag1: rho_k,
            range_c: [lo, hi],
            bic,
            t95,
        }
    };
    let unit = |k: usize| -> Vec<f64> {
        let mut v = vec![0.0; columns];
        v[k] = 1.0;
        v
    };
    let gap_map: Vec<Vec<f64>> = (0..=*q).map(|k| unit(p + k)).collect();
    let branch_map = |sign: f64| -> Vec<Vec<f64>> {
        (0..p)
            .map(|k| {
                let mut v = unit(k);
                if k <= *q {
                    v[p + k] = sign * 0.5;
                }
                v
            })
            .collect()
    };
    Ok(BranchFit {
        gap: curve(gap_map, *q, bic),
        rising: curve(branch_map(1.0), shared_order, Vec::new()),
        falling: curve(branch_map(-1.0), shared_order, Vec::new()),
        inverse: s.inverse.clone(),
    })
}

impl BranchFit {
    /// The weights wᵢ with Σ wᵢ yᵢ = the fitted gap at `t_c`, for the points `x`, `rising`
    /// the fit was made on. They sum to 0 (the shared curve's constant absorbs any offset).
    pub fn gap_weights(&self, x: &[f64], rising: &[bool], t_c: f64) -> Vec<f64> {
        let u = t_c - self.gap.reference_c;
        let gap: Vec<f64> = (0..=self.gap.order).map(|k| u.powi(k as i32)).collect();
        self.weights_of(x, rising, &gap)
    }

    /// The weights wᵢ with Σ wᵢ yᵢ = the gap polynomial's coefficient of order `k`; they sum
    /// to 0.
    pub fn gap_coefficient_weights(&self, x: &[f64], rising: &[bool], k: usize) -> Vec<f64> {
        let mut gap = vec![0.0; self.gap.order + 1];
        if let Some(g) = gap.get_mut(k) {
            *g = 1.0;
        }
        self.weights_of(x, rising, &gap)
    }

    /// Weights of the gap combination Σ_k gap[k]·c_k: row aᵀ(XᵀX)⁻¹Xᵀ of the design.
    fn weights_of(&self, x: &[f64], rising: &[bool], gap: &[f64]) -> Vec<f64> {
        let p = self.rising.order + 1;
        let columns = self.inverse.len();
        let mut a = vec![0.0; columns];
        for (k, g) in gap.iter().enumerate() {
            if let Some(slot) = a.get_mut(p + k) {
                *slot = *g;
            }
        }
        let v: Vec<f64> = (0..columns)
            .map(|j| (0..columns).map(|l| a[l] * self.inverse[l][j]).sum())
            .collect();
        x.iter()
            .zip(rising)
            .map(|(&t, &up)| {
                let u = t - self.gap.reference_c;
                let half = if up { 0.5 } else { -0.5 };
                let mut power = 1.0;
                let mut w = 0.0;
                for k in 0..p {
                    w += v[k] * power;
                    if p + k < columns {
                        w += v[p + k] * half * power;
                    }
                    power *= u;
                }
                w
            })
            .collect()
    }
}

/// Least squares of `y` on `columns` regressors (`fill(i, row)` writes point `i`'s row, in
/// scaled units; `scales[j]` converts coefficient `j` back).
fn solve_design(
    n: usize,
    columns: usize,
    fill: impl Fn(usize, &mut [f64]),
    y: &[f64],
    scales: &[f64],
) -> Option<Solved> {
    let mut ata = DMatrix::<f64>::zeros(columns, columns);
    let mut aty = DVector::<f64>::zeros(columns);
    let mut row = vec![0.0; columns];
    for (i, &v) in y.iter().enumerate().take(n) {
        fill(i, &mut row);
        for j in 0..columns {
            aty[j] += row[j] * v;
            for k in 0..=j {
                ata[(j, k)] += row[j] * row[k];
            }
        }
    }
    for j in 0..columns {
        for k in 0..j {
            ata[(k, j)] = ata[(j, k)];
        }
    }
    let chol = ata.cholesky()?;
    let b = chol.solve(&aty);
    let inv = chol.inverse();
    let coefficients: Vec<f64> = (0..columns).map(|k| b[k] / scales[k]).collect();
    let inverse = (0..columns)
        .map(|j| {
            (0..columns)
                .map(|k| inv[(j, k)] / (scales[j] * scales[k]))
                .collect()
        })
        .collect();
    let residuals: Vec<f64> = (0..n)
        .map(|i| {
            fill(i, &mut row);
            y[i] - row.iter().zip(b.iter()).map(|(r, c)| r * c).sum::<f64>()
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

    #[test]
    fn joint_branches_recover_a_constant_gap_with_its_interval() {
        // Up −10 → 60 °C, down 60 → −10 °C; rising lies 0.5 above falling.
        let mut x = Vec::new();
        let mut y = Vec::new();
        let mut up = Vec::new();
        for i in 0..7000 {
            let (t, r) = if i < 3500 {
                (-10.0 + 70.0 * i as f64 / 3500.0, true)
            } else {
                (60.0 - 70.0 * (i - 3500) as f64 / 3500.0, false)
            };
            let base = 0.8 * (t - 25.0) + 0.004 * (t - 25.0).powi(2);
            x.push(t);
            y.push(base + if r { 0.25 } else { -0.25 } + 0.05 * noise(i));
            up.push(r);
        }
        let f = fit_branches(&x, &y, &up, 25.0, 2, 0..=2).unwrap();
        assert_eq!(f.gap.order, 0, "{:?}", f.gap.bic);
        assert!((f.gap.coefficients[0] - 0.5).abs() < 0.01, "{:?}", f.gap);
        assert!((f.gap.coefficients[0] - 0.5).abs() <= f.gap.ci95[0] * 3.0);
        assert!((f.rising.eval(40.0) - f.falling.eval(40.0) - 0.5).abs() < 0.01);
        assert!((f.rising.coefficients[1] - 0.8).abs() < 1e-3);
        // The linear weights reproduce the fitted gap and cancel a constant offset.
        for at in [0.0, 40.0] {
            let w = f.gap_weights(&x, &up, at);
            let by_weights: f64 = w.iter().zip(&y).map(|(a, b)| a * b).sum();
            assert!((by_weights - f.gap.eval(at)).abs() < 1e-9, "{by_weights}");
            assert!(w.iter().sum::<f64>().abs() < 1e-9);
        }
        let c0 = f.gap_coefficient_weights(&x, &up, 0);
        let by_weights: f64 = c0.iter().zip(&y).map(|(a, b)| a * b).sum();
        assert!((by_weights - f.gap.coefficients[0]).abs() < 1e-9);
        let quadratic = fit_branches(&x, &y, &up, 25.0, 2, 2..=2).unwrap();
        assert_eq!(quadratic.gap.order, 2);
        let w = quadratic.gap_weights(&x, &up, 50.0);
        let by_weights: f64 = w.iter().zip(&y).map(|(a, b)| a * b).sum();
        assert!((by_weights - quadratic.gap.eval(50.0)).abs() < 1e-9);
        assert!(w.iter().sum::<f64>().abs() < 1e-9);
        let only_up = vec![true; x.len()];
        assert!(fit_branches(&x, &y, &only_up, 25.0, 2, 0..=2)
            .unwrap_err()
            .contains("0 falling points"));
    }
}
