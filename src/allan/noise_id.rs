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
    let mut differences = 0u32;
    loop {
        let len = decimated.checked_sub(differences as usize)?;
        if len < MIN_POINTS {
            return None;
        }
        let value = |k: usize| differenced(phase, m, differences, k);
        let r1 = lag1_autocorrelation(len, value)?;
        let delta = r1 / (1.0 + r1);
        if delta < 0.25 || differences >= max_differences {
            let p = -(2.0 * delta).round() as i32 - 2 * differences as i32;
            return Some(p + 2);
        }
        differences += 1;
    }
}

/// The `d`-th difference of the phase decimated by `m`, at index `k`.
fn differenced(phase: &[f64], m: usize, d: u32, k: usize) -> f64 {
    let at = |i: usize| phase[(k + i) * m];
    match d {
        0 => at(0),
        1 => at(1) - at(0),
        2 => at(2) - 2.0 * at(1) + at(0),
        _ => at(3) - 3.0 * at(2) + 3.0 * at(1) - at(0),
    }
}

/// Lag-1 autocorrelation of `len` values produced by `value` (mean removed).
fn lag1_autocorrelation(len: usize, value: impl Fn(usize) -> f64) -> Option<f64> {
    let mean = (0..len).map(&value).sum::<f64>() / len as f64;
    let mut denominator = 0.0;
    let mut numerator = 0.0;
    let mut previous = value(0) - mean;
    denominator += previous * previous;
    for k in 1..len {
        let current = value(k) - mean;
        numerator += previous * current;
        denominator += current * current;
        previous = current;
    }
    (denominator > 0.0).then(|| numerator / denominator)
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
