//! Careful floating-point building blocks: compensated (Neumaier) summation, mean
//! removal and the rate-to-phase prefix sum every deviation is computed from.
//!
//! Written by hand because the kernels must stay allocation-free and fused with the
//! deviation loops; no crate offers a compensated running sum over borrowed slices.

/// Compensated (Neumaier/Kahan–Babuška) accumulator: the running error of each addition is kept in
/// `compensation`, so summing millions of terms loses no more than a couple of ulps.
#[derive(Debug, Clone, Copy, Default)]
pub struct CompensatedSum {
    sum: f64,
    compensation: f64,
}

impl CompensatedSum {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds `value`, keeping the exact rounding error of the addition (Knuth's branch-free
    /// TwoSum, which gives the same error term as Neumaier's comparison without a
    /// data-dependent branch the CPU would mispredict on noise).
    #[inline]
    pub fn add(&mut self, value: f64) {
        let t = self.sum + value;
        let back = t - self.sum;
        self.compensation += (self.sum - (t - back)) + (value - back);
        self.sum = t;
    }

    #[inline]
    pub fn value(&self) -> f64 {
        self.sum + self.compensation
    }
}

/// Mean of a slice (0 for an empty slice): eight-lane plain sums per block of 4096 values,
/// compensated across blocks (see [`blocked_sum`]); vectorised, and exact to a few ulps.
pub fn compensated_mean(values: &[f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    sum_streams([values], |[v]| v) / values.len() as f64
}

/// Sums `f(i)` for `i in 0..count` with eight independent lanes per block of 4096 terms
/// (so the compiler can vectorise) and compensated accumulation across blocks.
#[inline]
pub fn blocked_sum(count: usize, mut term: impl FnMut(usize) -> f64) -> f64 {
    const BLOCK: usize = 4096;
    let mut total = CompensatedSum::new();
    let mut start = 0;
    while start < count {
        let end = (start + BLOCK).min(count);
        let mut lanes = [0.0f64; 8];
        let mut i = start;
        while i + 8 <= end {
            for (lane, slot) in lanes.iter_mut().enumerate() {
                *slot += term(i + lane);
            }
            i += 8;
        }
        let mut block: f64 = lanes.iter().sum();
        while i < end {
            block += term(i);
            i += 1;
        }
        total.add(block);
        start = end;
    }
    total.value()
}

/// Sums `term([s₀[i], s₁[i], …])` over the equally long slices `streams` (the caller
/// cuts them to the same length): eight independent lanes over fixed-size chunks, which
/// the compiler turns into SIMD without bounds checks, plain sums within blocks of 4096
/// terms and compensated accumulation across blocks, like [`blocked_sum`].
#[inline(always)]
#[allow(clippy::needless_range_loop)] // one index walks the K streams in lock-step
pub fn sum_streams<const K: usize>(streams: [&[f64]; K], term: impl Fn([f64; K]) -> f64) -> f64 {
    const LANES: usize = 8;
    const BLOCK: usize = 4096;
    let len = streams.iter().map(|s| s.len()).min().unwrap_or(0);
    let mut total = CompensatedSum::new();
    let mut start = 0;
    while start < len {
        let end = (start + BLOCK).min(len);
        let chunks: [&[[f64; LANES]]; K] =
            std::array::from_fn(|s| streams[s][start..end].as_chunks::<LANES>().0);
        let full = (end - start) / LANES;
        let mut lanes = [0.0f64; LANES];
        for j in 0..full {
            let rows: [&[f64; LANES]; K] = std::array::from_fn(|s| &chunks[s][j]);
            for (lane, slot) in lanes.iter_mut().enumerate() {
                *slot += term(std::array::from_fn(|s| rows[s][lane]));
            }
        }
        let mut block: f64 = lanes.iter().sum();
        for i in start + full * LANES..end {
            block += term(std::array::from_fn(|s| streams[s][i]));
        }
        total.add(block);
        start = end;
    }
    total.value()
}

/// Phase (integrated rate) in units of "samples × rate": `x[0] = 0`,
/// `x[k] = Σ_{i<k} (y[i] − mean(y))`, so `N` rate samples give `N + 1` phase points.
///
/// The mean is removed first (it only adds a linear phase ramp, which every Allan-family
/// estimator cancels exactly) so the phase stays near zero and a large constant offset,
/// such as 1 g on an accelerometer axis, cannot eat the significant digits. The prefix
/// sum itself is compensated. The conversion happens in place: the rate vector is
/// turned into the phase vector, so memory stays at one axis.
#[derive(Debug, Clone)]
pub struct Phase {
    /// `N + 1` phase points in rate-units × samples (multiply by `tau0` for seconds).
    pub points: Vec<f64>,
    /// The mean rate that was removed, in the input's units.
    pub removed_mean: f64,
}

impl Phase {
    /// Integrates rate (frequency) samples into phase; consumes the vector to reuse its memory.
    pub fn from_rate(mut rate: Vec<f64>) -> Self {
        let mean = compensated_mean(&rate);
        // One more slot for the leading zero without doubling the capacity (for a large
        // vector the allocator grows the mapping in place).
        rate.reserve_exact(1);
        rate.push(0.0);
        let mut acc = CompensatedSum::new();
        let mut carried = 0.0;
        for slot in rate.iter_mut() {
            let next = *slot - mean;
            *slot = carried;
            acc.add(next);
            carried = acc.value();
        }
        Phase {
            points: rate,
            removed_mean: mean,
        }
    }

    /// Converts phase samples (e.g. clock time error in seconds) taken every `tau0`
    /// into the same representation: first differences divided by `tau0` are the
    /// fractional frequency, then integrated again with the mean removed.
    pub fn from_phase(phase: &[f64], tau0: f64) -> Self {
        let rate: Vec<f64> = phase.windows(2).map(|w| (w[1] - w[0]) / tau0).collect();
        Self::from_rate(rate)
    }

    /// Number of phase points (`N + 1` for `N` rate samples).
    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compensated_sum_keeps_small_terms_next_to_large_ones() {
        let mut acc = CompensatedSum::new();
        acc.add(1e16);
        for _ in 0..1000 {
            acc.add(1.0);
        }
        acc.add(-1e16);
        assert_eq!(acc.value(), 1000.0);
    }

    #[test]
    fn blocked_sum_matches_closed_form() {
        let n = 10_007;
        let s = blocked_sum(n, |i| i as f64);
        assert_eq!(s, (n * (n - 1) / 2) as f64);
    }

    #[test]
    fn phase_has_leading_zero_and_mean_removed() {
        let phase = Phase::from_rate(vec![1.0, 2.0, 3.0]);
        assert_eq!(phase.len(), 4);
        assert_eq!(phase.points[0], 0.0);
        assert!((phase.points[1] + 1.0).abs() < 1e-15);
        assert!((phase.points[2] + 1.0).abs() < 1e-15);
        assert!(phase.points[3].abs() < 1e-15);
        assert_eq!(phase.removed_mean, 2.0);
    }
}
