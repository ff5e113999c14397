//! Dominant power-law noise type per averaging time from the lag-1 autocorrelation
//! (Riley & Greenhall, "Power law noise identification using the lag 1 autocorrelation",
//! 2004): decimate the phase by m, difference it until the lag-1 autocorrelation says
//! the result is close to white, and read α from the number of differences taken.
//!
//! Cost: the decimated points are read in place (a stride of m through the phase, no
//! copy), and only the difference orders the decision reaches are evaluated, two orders
//! per pass: orders 0 and 1 (enough for every noise from white PM to white FM), then 2
//! and 3 only when the first pair still looks correlated. Each pass accumulates shifted
//! sums (Σu, Σu², Σu·u_next with u = w − w₀) and removes the mean algebraically
//! afterwards, so one pass replaces the textbook's mean pass plus product pass.

use super::edf::Alpha;

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
    let decimated = phase.len().div_ceil(m);
    let levels = (0..=max_differences.min(MAX_LEVEL as u32) as usize)
        .take_while(|&d| {
            decimated
                .checked_sub(d)
                .is_some_and(|len| len >= MIN_POINTS)
        })
        .count();
    let mut d = 0;
    while d < levels {
        let pair = lag1_pair(phase, m, d, d + 1 < levels);
        for (offset, r1) in pair.into_iter().enumerate() {
            let order = d + offset;
            if order >= levels {
                break;
            }
            let r1 = r1?;
            let delta = r1 / (1.0 + r1);
            if delta < 0.25 || order as u32 >= max_differences {
                let p = -(2.0 * delta).round() as i32 - 2 * order as i32;
                return Some(p + 2);
            }
        }
        d += 2;
    }
    // No order was allowed (too few points), or the next difference would have had fewer
    // than MIN_POINTS points.
    None
}

/// Highest difference order considered (Hadamard variances: 3).
const MAX_LEVEL: usize = 3;

/// Shifted running sums of one difference series u_k = w_k − w_0 (k = 0 … len − 1).
#[derive(Default, Clone, Copy)]
struct Moments {
    len: usize,
    sum: f64,
    squares: f64,
    lag1: f64,
    last: f64,
}

impl Moments {
    /// Adds the next value u_k (the lag-1 product pairs it with u_{k−1}, 0 before the first).
    fn add(&mut self, u: f64) {
        self.sum += u;
        self.squares += u * u;
        self.lag1 += self.last * u;
        self.last = u;
        self.len += 1;
    }

    /// Lag-1 autocorrelation with the mean removed; `None` for zero variance.
    ///
    /// With μ = Σu/len: Σ(u−μ)² = Σu² − len·μ², and
    /// Σ(u_k−μ)(u_{k+1}−μ) = Σu_k·u_{k+1} − μ·(2Σu − u_0 − u_last) + (len−1)·μ², where
    /// u_0 = 0 by the choice of the shift.
    fn lag1(&self) -> Option<f64> {
        let n = self.len as f64;
        let mean = self.sum / n;
        let denominator = self.squares - n * mean * mean;
        let numerator = self.lag1 - mean * (2.0 * self.sum - self.last) + (n - 1.0) * mean * mean;
        (denominator > 0.0).then(|| numerator / denominator)
    }
}

/// Lag-1 autocorrelations of the difference orders `d` and (when `both`) `d + 1` of the
/// phase decimated by `m`, in one pass over the decimated points (`None` for an order
/// with zero variance or fewer than two points). `d` is 0 or 2.
fn lag1_pair(phase: &[f64], m: usize, d: usize, both: bool) -> [Option<f64>; 2] {
    debug_assert!(d == 0 || d == 2, "difference orders are taken in pairs");
    // Monomorphised per pair so the difference cascade lives in registers.
    match (d, both) {
        (0, false) => lag1_orders::<0, false>(phase, m),
        (0, true) => lag1_orders::<0, true>(phase, m),
        (_, false) => lag1_orders::<2, false>(phase, m),
        (_, true) => lag1_orders::<2, true>(phase, m),
    }
}

/// [`lag1_pair`] for the orders `D` and (with `BOTH`) `D + 1`.
fn lag1_orders<const D: usize, const BOTH: bool>(phase: &[f64], m: usize) -> [Option<f64>; 2] {
    let top = D + usize::from(BOTH);
    let mut points = phase.iter().step_by(m).copied();
    // newest[q]: the latest value of the q-th difference of the decimated phase. A new
    // point z extends every order: w_0 ← z, w_q ← (new w_{q−1}) − (old w_{q−1}).
    let mut newest = [0.0f64; MAX_LEVEL + 1];
    let push = |newest: &mut [f64; MAX_LEVEL + 1], z: f64, valid: usize| {
        let mut value = z;
        for slot in newest.iter_mut().take(valid) {
            let previous = *slot;
            *slot = value;
            value -= previous;
        }
    };
    // Prime: after D + 1 points, order D has its first value, the shift of its sums.
    for k in 0..=D {
        let Some(z) = points.next() else {
            return [None, None];
        };
        push(&mut newest, z, k + 1);
    }
    let shift = newest[D];
    let mut low = Moments {
        len: 1,
        ..Moments::default()
    };
    let mut high = Moments::default();
    let mut high_shift = 0.0;
    if BOTH {
        // One more point starts order D + 1 (and gives order D its second value).
        let Some(z) = points.next() else {
            return [None, None];
        };
        push(&mut newest, z, D + 2);
        // u_0 = 0 is `low`'s initial `last`, so the lag-1 product of this pair is 0.
        low.add(newest[D] - shift);
        high.len = 1;
        high_shift = newest[D + 1];
    }
    for z in points {
        push(&mut newest, z, top + 1);
        low.add(newest[D] - shift);
        if BOTH {
            high.add(newest[top] - high_shift);
        }
    }
    [low.lag1(), high.lag1()]
}

#[cfg(test)]
mod tests {
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
    fn too_few_points_gives_none() {
        let w = white(100, 2);
        assert_eq!(identify_alpha(&w, 10, 2), None);
    }

    /// Textbook lag-1 autocorrelation of the d-th difference of the decimated phase: the
    /// series is built explicitly, its mean removed in a first pass.
    fn direct_lag1(phase: &[f64], m: usize, d: usize) -> Option<f64> {
        let mut w: Vec<f64> = phase.iter().step_by(m).copied().collect();
        for _ in 0..d {
            w = w.windows(2).map(|p| p[1] - p[0]).collect();
        }
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
                for d in [0, 2] {
                    for both in [false, true] {
                        let pair = lag1_pair(phase, m, d, both);
                        for (offset, got) in pair.iter().enumerate().take(1 + both as usize) {
                            let want = direct_lag1(phase, m, d + offset).unwrap();
                            let got = got.unwrap();
                            assert!(
                                (got - want).abs() < 1e-9,
                                "m={m} d={} both={both}: {got} vs {want}",
                                d + offset
                            );
                        }
                        if !both {
                            assert!(pair[1].is_none());
                        }
                    }
                }
            }
        }
        let constant = vec![5.0; 100];
        assert_eq!(lag1_pair(&constant, 1, 0, true), [None, None]);
    }
}
