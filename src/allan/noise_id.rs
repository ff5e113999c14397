//! Dominant power-law noise type per averaging time from the lag-1 autocorrelation
//! (Riley & Greenhall, "Power law noise identification using the lag 1 autocorrelation",
//! 2004): decimate the phase by m, difference it until the lag-1 autocorrelation says
//! the result is close to white, and read α from the number of differences taken.
//!
//! Cost: the decimated phase z[k] = x[k·m] is contiguous (the caller's octave pyramid,
//! [`for_each_decimation`], or a gathered copy), and only the difference orders the
//! decision reaches are evaluated, two orders per pass: orders 0 and 1 (enough for every
//! noise from white PM to white FM), then 2 and 3 only when the first pair still looks
//! correlated. Each pass accumulates shifted sums (Σu, Σu², Σu·u_next with u = w − w₀)
//! in eight vector lanes and removes the mean algebraically afterwards, so one
//! vectorised pass replaces the textbook's mean pass plus product pass.

use super::edf::Alpha;
use super::numerics::{dispatch, for_each_decimation, CompensatedSum, Kernel, Simd};

/// Fewest decimated points the lag-1 estimate is trusted on; below it the caller keeps
/// the α found at the next shorter τ.
pub const MIN_POINTS: usize = 32;

/// Estimated noise exponent at averaging factor `m`, or `None` when too few points remain.
///
/// `max_differences` is 2 for Allan-type variances and 3 for Hadamard ones. The returned
/// value is the rounded α (2 white PM … −2 random-walk FM, −3/−4 for Hadamard).
pub fn identify_alpha(phase: &[f64], m: usize, max_differences: u32) -> Option<Alpha> {
    if m == 0 {
        return None;
    }
    let decimated: Vec<f64> = phase.iter().step_by(m).copied().collect();
    identify_alpha_decimated(&decimated, max_differences, Simd::detected())
}

/// [`identify_alpha`] at every factor of `factors` (ascending), from one octave pyramid of
/// the decimated phase.
pub fn identify_alphas(
    phase: &[f64],
    factors: &[usize],
    max_differences: u32,
    simd: Simd,
) -> Vec<Option<Alpha>> {
    let mut alphas = vec![None; factors.len()];
    for_each_decimation(phase, factors, |j, z| {
        alphas[j] = identify_alpha_decimated(z, max_differences, simd);
    });
    alphas
}

/// [`identify_alpha`] on the already decimated phase `z`.
pub fn identify_alpha_decimated(z: &[f64], max_differences: u32, simd: Simd) -> Option<Alpha> {
    // Orders are evaluated two per pass, only as far as the decision reaches.
    let mut pair: Option<(usize, [Option<f64>; 2])> = None;
    decide_alpha(z.len(), max_differences, |order| {
        let d = order & !1;
        let values = match pair {
            Some((held, values)) if held == d => values,
            _ => {
                let values = lag1_pair(z, d, simd);
                pair = Some((d, values));
                values
            }
        };
        values[order - d].map_or(Lag1::Undefined, Lag1::Value)
    })
}

/// What the decision of [`decide_alpha`] learns about one difference order.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Lag1 {
    /// The lag-1 autocorrelation.
    Value(f64),
    /// Zero variance or too few values: no noise type.
    Undefined,
    /// Proven to be at least 1/3 (δ ≥ 0.25) without its value: take the next order.
    /// Only valid below `max_differences`.
    Correlated,
}

/// The noise exponent from the lag-1 autocorrelations of the difference orders 0, 1, …
/// of a decimated phase of `points` points (`lag1(d)` is asked in ascending order and
/// only as far as the decision goes): the first order d whose δ = r/(1 + r) is below
/// 0.25, or the last allowed one, gives α = 2 − round(2δ) − 2d. Orders that would leave
/// fewer than [`MIN_POINTS`] values are not allowed.
pub fn decide_alpha(
    points: usize,
    max_differences: u32,
    mut lag1: impl FnMut(usize) -> Lag1,
) -> Option<Alpha> {
    let levels = (0..=max_differences.min(MAX_LEVEL as u32) as usize)
        .take_while(|&d| points.checked_sub(d).is_some_and(|len| len >= MIN_POINTS))
        .count();
    for order in 0..levels {
        let last = order as u32 >= max_differences;
        let r1 = match lag1(order) {
            Lag1::Value(r1) => r1,
            Lag1::Undefined => return None,
            Lag1::Correlated if !last => continue,
            // A caller error; no value to round.
            Lag1::Correlated => return None,
        };
        let delta = r1 / (1.0 + r1);
        if delta < 0.25 || last {
            let p = -(2.0 * delta).round() as i32 - 2 * order as i32;
            return Some(p + 2);
        }
    }
    // No order was allowed (too few points), or the next difference would have had fewer
    // than MIN_POINTS points.
    None
}

/// Highest difference order considered (Hadamard variances: 3).
const MAX_LEVEL: usize = 3;

/// Shifted sums of one difference series u_k = w_k − w_0 (k = 0 … len − 1).
#[derive(Default, Clone, Copy)]
struct Moments {
    len: usize,
    sum: f64,
    squares: f64,
    lag1: f64,
    last: f64,
}

impl Moments {
    /// Adds the value u_k that follows `last` (the lag-1 product pairs the two).
    fn add(&mut self, u: f64) {
        self.sum += u;
        self.squares += u * u;
        self.lag1 += self.last * u;
        self.last = u;
        self.len += 1;
    }

    /// Lag-1 autocorrelation with the mean removed; `None` for zero variance or fewer than
    /// two values.
    ///
    /// With μ = Σu/len: Σ(u−μ)² = Σu² − len·μ², and
    /// Σ(u_k−μ)(u_{k+1}−μ) = Σu_k·u_{k+1} − μ·(2Σu − u_0 − u_last) + (len−1)·μ², where
    /// u_0 = 0 by the choice of the shift.
    fn lag1(&self) -> Option<f64> {
        if self.len < 2 {
            return None;
        }
        let n = self.len as f64;
        let mean = self.sum / n;
        let denominator = self.squares - n * mean * mean;
        let numerator = self.lag1 - mean * (2.0 * self.sum - self.last) + (n - 1.0) * mean * mean;
        (denominator > 0.0).then(|| numerator / denominator)
    }
}

/// Lag-1 autocorrelations of the difference orders `d` and `d + 1` (`d` is 0, 1 or 2) of
/// the series `z` (the decimated phase, or for d = 1 its first difference), in one pass
/// (`None` for an order with zero variance or fewer than two values).
pub(super) fn lag1_pair(z: &[f64], d: usize, simd: Simd) -> [Option<f64>; 2] {
    debug_assert!(d <= 2, "difference orders 0 to 3");
    // Monomorphised per pair so the difference cascade lives in registers.
    match d {
        0 => dispatch(simd, Lag1Orders::<0, 3>(z)),
        1 => dispatch(simd, Lag1Orders::<1, 4>(z)),
        _ => dispatch(simd, Lag1Orders::<2, 5>(z)),
    }
}

/// [`lag1_orders`] as a [`Kernel`].
struct Lag1Orders<'a, const D: usize, const K: usize>(&'a [f64]);

impl<const D: usize, const K: usize> Kernel for Lag1Orders<'_, D, K> {
    type Output = [Option<f64>; 2];
    #[inline(always)]
    fn run(self) -> [Option<f64>; 2] {
        lag1_orders::<D, K>(self.0)
    }
}

/// Σa, Σa², Σa_k·a_{k+1}, Σb, Σb², Σb_k·b_{k+1} over k < `bulk`, with a_k the difference
/// of order `D` of `z` at k minus `low_shift` and b_k that of order D + 1 minus
/// `high_shift`: [`LANES`] lanes as arrays (struct of arrays, so every step is a plain
/// vector operation), plain sums within blocks of 4096, compensated across blocks.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // one index walks the lane arrays in lock-step
fn bulk_moments<const D: usize, const K: usize>(
    z: &[f64],
    bulk: usize,
    low_shift: f64,
    high_shift: f64,
) -> [f64; 6] {
    const BLOCK: usize = 4096;
    let mut totals = [CompensatedSum::new(); 6];
    let mut start = 0;
    while start < bulk {
        let end = (start + BLOCK).min(bulk);
        let chunks: [&[[f64; LANES]]; K] =
            std::array::from_fn(|s| z[start + s..end + s].as_chunks::<LANES>().0);
        let full = (end - start) / LANES;
        let mut acc = [[0.0f64; LANES]; 6];
        for j in 0..full {
            let mut v: [[f64; LANES]; K] = std::array::from_fn(|s| chunks[s][j]);
            // Order D in v[0..K−D], then order D + 1 in h[0..2].
            for q in 0..D {
                for p in 0..K - 1 - q {
                    for l in 0..LANES {
                        v[p][l] = v[p + 1][l] - v[p][l];
                    }
                }
            }
            for l in 0..LANES {
                let a0 = v[0][l] - low_shift;
                let a1 = v[1][l] - low_shift;
                let b0 = (v[1][l] - v[0][l]) - high_shift;
                let b1 = (v[2][l] - v[1][l]) - high_shift;
                acc[0][l] += a0;
                acc[1][l] += a0 * a0;
                acc[2][l] += a0 * a1;
                acc[3][l] += b0;
                acc[4][l] += b0 * b0;
                acc[5][l] += b0 * b1;
            }
        }
        for (total, lanes) in totals.iter_mut().zip(&acc) {
            total.add(lanes.iter().sum());
        }
        // The few terms after the last full chunk, point by point.
        let mut tail = [0.0f64; 6];
        for k in start + full * LANES..end {
            let a0 = difference_at(z, k, D) - low_shift;
            let a1 = difference_at(z, k + 1, D) - low_shift;
            let b0 = difference_at(z, k, D + 1) - high_shift;
            let b1 = difference_at(z, k + 1, D + 1) - high_shift;
            for (t, v) in tail
                .iter_mut()
                .zip([a0, a0 * a0, a0 * a1, b0, b0 * b0, b0 * b1])
            {
                *t += v;
            }
        }
        for (total, t) in totals.iter_mut().zip(tail) {
            total.add(t);
        }
        start = end;
    }
    totals.map(|t| t.value())
}

/// Lanes of the vectorised sums.
const LANES: usize = 8;

/// The difference of order `order` of `z` at `k`, in the cascade form
/// w_q[p] = w_{q−1}[p+1] − w_{q−1}[p] (the same operations as the bulk of [`bulk_moments`]).
fn difference_at(z: &[f64], k: usize, order: usize) -> f64 {
    let mut v = [0.0f64; MAX_LEVEL + 2];
    v[..=order].copy_from_slice(&z[k..=k + order]);
    for q in 0..order {
        for p in 0..order - q {
            v[p] = v[p + 1] - v[p];
        }
    }
    v[0]
}

/// [`lag1_pair`] for the orders `D` and `D + 1`, reading `K = D + 3` streams z[k…].
#[inline(always)]
fn lag1_orders<const D: usize, const K: usize>(z: &[f64]) -> [Option<f64>; 2] {
    let len = z.len();
    if len <= D {
        return [None, None];
    }
    // Shifts: the first value of each order, so u_0 = 0 exactly.
    let low_shift = difference_at(z, 0, D);
    if len < K {
        // Too short for the pair: order D alone, point by point.
        let mut low = Moments::default();
        for k in 0..len - D {
            low.add(difference_at(z, k, D) - low_shift);
        }
        return [low.lag1(), None];
    }
    let high_shift = difference_at(z, 0, D + 1);
    // Bulk, k = 0 … len − D − 3: order D at k (a_k, and its lag-1 product a_k·a_{k+1})
    // and order D + 1 at k (b_k and b_k·b_{k+1}), from z[k … k + D + 2].
    let bulk = len - K + 1;
    let [s_low, q_low, l_low, s_high, q_high, l_high] =
        bulk_moments::<D, K>(z, bulk, low_shift, high_shift);
    // Order D has len − D values: its last two (k = len − D − 2, len − D − 1) and their
    // product are left. Order D + 1 has len − D − 1: its last value (k = len − D − 2) is
    // left, its products are all in the bulk.
    let a0 = difference_at(z, len - D - 2, D) - low_shift;
    let a1 = difference_at(z, len - D - 1, D) - low_shift;
    let b0 = difference_at(z, len - D - 2, D + 1) - high_shift;
    let low = Moments {
        len: len - D,
        sum: s_low + a0 + a1,
        squares: q_low + a0 * a0 + a1 * a1,
        lag1: l_low + a0 * a1,
        last: a1,
    };
    let high = Moments {
        len: len - D - 1,
        sum: s_high + b0,
        squares: q_high + b0 * b0,
        lag1: l_high,
        last: b0,
    };
    [low.lag1(), high.lag1()]
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    use rand_xoshiro::Xoshiro256PlusPlus;

    fn white(n: usize, seed: u64) -> Vec<f64> {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        (0..n).map(|_| StandardNormal.sample(&mut rng)).collect()
    }

    fn integrate(v: &[f64]) -> Vec<f64> {
        let mut acc = 0.0;
        std::iter::once(0.0)
            .chain(v.iter().map(|x| {
                acc += x;
                acc
            }))
            .collect()
    }

    #[test]
    fn recognises_white_pm_white_fm_and_random_walk_fm() {
        let w = white(20_000, 1);
        assert_eq!(identify_alpha(&w, 1, 2), Some(2));
        let white_fm_phase = integrate(&w);
        assert_eq!(identify_alpha(&white_fm_phase, 1, 2), Some(0));
        assert_eq!(identify_alpha(&white_fm_phase, 16, 2), Some(0));
        let rw_fm_phase = integrate(&integrate(&w));
        assert_eq!(identify_alpha(&rw_fm_phase, 4, 2), Some(-2));
    }

    #[test]
    fn pyramid_and_gathered_decimation_agree_on_both_paths() {
        let walk = integrate(&white(50_000, 4));
        let factors = [1, 2, 4, 8, 10, 16, 30, 64, 128, 1_000];
        for simd in Simd::available() {
            let all = identify_alphas(&walk, &factors, 3, simd);
            for (j, &m) in factors.iter().enumerate() {
                assert_eq!(all[j], identify_alpha(&walk, m, 3), "m={m} {simd:?}");
            }
        }
    }

    #[test]
    fn too_few_points_gives_none() {
        let w = white(100, 2);
        assert_eq!(identify_alpha(&w, 10, 2), None);
    }

    /// Textbook lag-1 autocorrelation of the d-th difference of the decimated phase: the
    /// series is built explicitly, then [`textbook_lag1`].
    fn direct_lag1(phase: &[f64], m: usize, d: usize) -> Option<f64> {
        let mut w: Vec<f64> = phase.iter().step_by(m).copied().collect();
        for _ in 0..d {
            w = w.windows(2).map(|p| p[1] - p[0]).collect();
        }
        textbook_lag1(&w)
    }

    /// Textbook lag-1 autocorrelation of `w` (mean removed in a first pass).
    pub(crate) fn textbook_lag1(w: &[f64]) -> Option<f64> {
        let mean = w.iter().sum::<f64>() / w.len() as f64;
        let c: Vec<f64> = w.iter().map(|v| v - mean).collect();
        let numerator: f64 = c.windows(2).map(|p| p[0] * p[1]).sum();
        let denominator: f64 = c.iter().map(|v| v * v).sum();
        (denominator > 0.0).then(|| numerator / denominator)
    }

    #[test]
    fn one_pass_lag1_equals_the_two_pass_definition() {
        let w = white(5_000, 3);
        let walk = integrate(&w);
        let series: Vec<f64> = walk.iter().map(|v| v + 1e3).collect();
        for phase in [&w, &walk, &series] {
            for m in [1, 2, 7, 40] {
                let z: Vec<f64> = phase.iter().step_by(m).copied().collect();
                for d in [0, 2] {
                    for simd in Simd::available() {
                        let pair = lag1_pair(&z, d, simd);
                        for (offset, got) in pair.iter().enumerate() {
                            let want = direct_lag1(phase, m, d + offset).unwrap();
                            let got = got.unwrap();
                            assert!(
                                (got - want).abs() < 1e-9,
                                "m={m} d={} {simd:?}: {got} vs {want}",
                                d + offset
                            );
                        }
                    }
                }
            }
        }
        let constant = vec![5.0; 100];
        assert_eq!(lag1_pair(&constant, 0, Simd::Portable), [None, None]);
        // Short series: every length around the bulk's minimum, both orders checked.
        for len in 1..12 {
            let z = &w[..len];
            for d in [0, 2] {
                let pair = lag1_pair(z, d, Simd::Portable);
                for (offset, got) in pair.iter().enumerate() {
                    let order = d + offset;
                    let want = (len > order + 1)
                        .then(|| direct_lag1(z, 1, order))
                        .flatten();
                    match (got, want) {
                        (Some(g), Some(w)) => assert!((g - w).abs() < 1e-9, "len={len} d={order}"),
                        (None, _) if len < d + 3 && offset == 1 => {}
                        (g, w) => assert_eq!(g.is_some(), w.is_some(), "len={len} d={order}"),
                    }
                }
            }
        }
    }
}
