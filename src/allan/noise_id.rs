//! Dominant power-law noise type per averaging time from the lag-1 autocorrelation
//! (Riley & Greenhall, "Power law noise identification using the lag 1 autocorrelation",
//! 2004): decimate the phase by m, difference it until the lag-1 autocorrelation says
//! the result is close to white, and read α from the number of differences taken.

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
    if levels == 0 {
        return None;
    }
    let r1 = lag1_of_differences(phase, m, levels);
    for (d, r1) in r1.iter().take(levels).enumerate() {
        let r1 = (*r1)?;
        let delta = r1 / (1.0 + r1);
        if delta < 0.25 || d as u32 >= max_differences {
            let p = -(2.0 * delta).round() as i32 - 2 * d as i32;
            return Some(p + 2);
        }
    }
    // The next difference would have had fewer than MIN_POINTS points.
    None
}

/// Highest difference order considered (Hadamard variances: 3).
const MAX_LEVEL: usize = 3;

/// Lag-1 autocorrelation (mean removed) of the 0th … `levels − 1`-th difference of the phase
/// decimated by `m`, all from the same two passes over the decimated points: the first
/// pass sums each difference series for its mean, the second accumulates the centred
/// lag-1 products and squares. `None` for a series with zero variance.
fn lag1_of_differences(phase: &[f64], m: usize, levels: usize) -> [Option<f64>; MAX_LEVEL + 1] {
    // Differences of order 0…3 at decimated index k from the last four points.
    fn differences(history: &[f64; 4]) -> [f64; 4] {
        let [v0, v1, v2, v3] = *history; // v0 newest
        [
            v0,
            v0 - v1,
            v0 - 2.0 * v1 + v2,
            v0 - 3.0 * v1 + 3.0 * v2 - v3,
        ]
    }
    let decimated = || phase.iter().step_by(m).copied();
    let mut sums = [0.0f64; MAX_LEVEL + 1];
    let mut history = [0.0f64; 4];
    for (k, v) in decimated().enumerate() {
        history = [v, history[0], history[1], history[2]];
        let diff = differences(&history);
        for d in 0..levels.min(k + 1) {
            sums[d] += diff[d];
        }
    }
    let total = phase.len().div_ceil(m);
    let means: [f64; MAX_LEVEL + 1] =
        std::array::from_fn(|d| sums[d] / total.saturating_sub(d).max(1) as f64);
    let mut numerator = [0.0f64; MAX_LEVEL + 1];
    let mut denominator = [0.0f64; MAX_LEVEL + 1];
    let mut previous = [0.0f64; MAX_LEVEL + 1];
    history = [0.0; 4];
    for (k, v) in decimated().enumerate() {
        history = [v, history[0], history[1], history[2]];
        let diff = differences(&history);
        for d in 0..levels.min(k + 1) {
            let current = diff[d] - means[d];
            if k > d {
                numerator[d] += previous[d] * current;
            }
            denominator[d] += current * current;
            previous[d] = current;
        }
    }
    std::array::from_fn(|d| (denominator[d] > 0.0).then(|| numerator[d] / denominator[d]))
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
}
