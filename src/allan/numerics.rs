//! Careful floating-point building blocks: compensated (Neumaier) summation, mean
//! removal, the rate-to-phase prefix sum every deviation is computed from, and the
//! runtime choice of instruction set for the hot loops ([`Simd`], [`dispatch`]).
//!
//! Written by hand because the kernels must stay allocation-free and fused with the
//! deviation loops; no crate offers a compensated running sum over borrowed slices.
//! The SIMD dispatch is std's `#[target_feature]` plus runtime detection rather than a
//! crate such as `multiversion` or `pulp`: the kernels are plain Rust loops over
//! fixed-size lane arrays that LLVM vectorises by itself, so all they need is to be
//! compiled a second time with AVX2 enabled, which one small generic function does.

use rayon::prelude::*;

/// Instruction set the hot loops run with. The build targets baseline x86-64 (SSE2);
/// [`Simd::detected`] picks AVX2 + FMA when the CPU has them. Both paths evaluate the
/// same expressions in the same order (Rust never contracts `a * b + c` into an FMA on
/// its own), so they give bit-identical results; the tests check that.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Simd {
    /// Baseline code, any CPU.
    Portable,
    /// AVX2 + FMA (x86-64 only, chosen at run time).
    Avx2,
}

impl Simd {
    /// The fastest path this CPU supports.
    pub fn detected() -> Simd {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                return Simd::Avx2;
            }
        }
        Simd::Portable
    }

    /// Every path this CPU can run (the portable one first), for tests and benchmarks.
    pub fn available() -> Vec<Simd> {
        let mut paths = vec![Simd::Portable];
        if Simd::detected() == Simd::Avx2 {
            paths.push(Simd::Avx2);
        }
        paths
    }
}

/// A hot loop that [`dispatch`] can compile for several instruction sets: `run` must be
/// `#[inline(always)]` (as must the helpers it calls), so that it is inlined into the
/// AVX2-enabled wrapper and vectorised with 256-bit registers there. (A closure cannot
/// be forced inline, which is why the kernels are small structs.)
pub trait Kernel {
    type Output;
    fn run(self) -> Self::Output;
}

/// Runs `kernel` compiled for `simd`. `Simd::Avx2` on a CPU without AVX2 (only possible
/// by constructing it by hand) falls back to the portable path.
#[inline]
pub fn dispatch<K: Kernel>(simd: Simd, kernel: K) -> K::Output {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2,fma")]
        fn with_avx2<K: Kernel>(kernel: K) -> K::Output {
            kernel.run()
        }
        if simd == Simd::Avx2 && Simd::detected() == Simd::Avx2 {
            // SAFETY: the CPU supports AVX2 and FMA (checked at run time just above).
            return unsafe { with_avx2(kernel) };
        }
    }
    let _ = simd;
    kernel.run()
}

/// Compensated (Neumaier/Kahan–Babuška) accumulator: the running error of each addition is kept in
/// `compensation`, so summing millions of terms loses no more than a couple of ulps.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
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

    /// Adds another compensated sum (its value and its error term).
    #[inline]
    pub fn merge(&mut self, other: CompensatedSum) {
        self.add(other.sum);
        self.compensation += other.compensation;
    }

    #[inline]
    pub fn value(&self) -> f64 {
        self.sum + self.compensation
    }
}

/// Merges per-job partial sums into `totals` (one per factor) in job order, so the result
/// does not depend on how many threads ran the jobs.
pub fn merge_in_order(
    totals: &mut [CompensatedSum],
    jobs: impl IntoIterator<Item = Vec<CompensatedSum>>,
) {
    for job in jobs {
        for (total, part) in totals.iter_mut().zip(job) {
            total.merge(part);
        }
    }
}

/// Per-factor sums over the terms `0..terms`, cut into jobs of `job_terms` terms that run
/// on the rayon pool: `job(start, end)` returns one partial sum per factor (`factors` of
/// them), merged in job order (see [`merge_in_order`]).
pub fn sum_in_jobs(
    terms: usize,
    job_terms: usize,
    factors: usize,
    job: impl Fn(usize, usize) -> Vec<CompensatedSum> + Sync,
) -> Vec<f64> {
    let partials: Vec<Vec<CompensatedSum>> = (0..terms.div_ceil(job_terms))
        .into_par_iter()
        .map(|j| {
            let start = j * job_terms;
            job(start, (start + job_terms).min(terms))
        })
        .collect();
    let mut totals = vec![CompensatedSum::new(); factors];
    merge_in_order(&mut totals, partials);
    totals.iter().map(CompensatedSum::value).collect()
}

/// Mean of a slice (0 for an empty slice): eight-lane plain sums per block of 4096 values,
/// compensated across blocks (see [`blocked_sum`]); vectorised, and exact to a few ulps.
#[inline(always)]
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

/// Calls `visit(j, z)` with the phase decimated by `factors[j]`, z[k] = x[k·m] for
/// k < ⌈n/m⌉, for every factor in ascending order. m = 1 is `x` itself; a factor that is
/// a multiple of the previous one compacts the previous level in place (the octave
/// pyramid: each level reads the one before, contiguously), any other is gathered from
/// `x`. One buffer of ⌈n/2⌉ values at most.
pub fn for_each_decimation(x: &[f64], factors: &[usize], mut visit: impl FnMut(usize, &[f64])) {
    let mut level: Vec<f64> = Vec::new();
    let mut held = 0usize;
    for (j, &m) in factors.iter().enumerate() {
        if m == 0 {
            continue;
        }
        if m == 1 {
            visit(j, x);
            continue;
        }
        if held > 1 && m % held == 0 && m > held {
            let ratio = m / held;
            let len = level.len().div_ceil(ratio);
            for k in 1..len {
                level[k] = level[k * ratio];
            }
            level.truncate(len);
        } else if m != held {
            level.clear();
            level.extend(x.iter().step_by(m).copied());
        }
        held = m;
        visit(j, &level);
    }
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
    pub fn from_rate(rate: Vec<f64>) -> Self {
        Self::from_rate_with(rate, Simd::detected())
    }

    /// [`Phase::from_rate`] on the given instruction-set path.
    pub fn from_rate_with(mut rate: Vec<f64>, simd: Simd) -> Self {
        let mut mean = 0.0;
        // One more slot for the leading zero without doubling the capacity (for a large
        // vector the allocator grows the mapping in place).
        rate.reserve_exact(1);
        rate.push(0.0);
        dispatch(
            simd,
            Integrate {
                values: &mut rate,
                mean: &mut mean,
            },
        );
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

/// Turns `values` = [y₀ … y_{N−1}, _] into the phase [0, S₀, S₀+S₁, …] with
/// S = y − mean(y), each point a compensated running sum (Knuth's TwoSum per addition),
/// and returns the mean.
///
/// A single running sum is one long chain of dependent additions (≈ 4 cycles per
/// sample). Here the samples are cut into [`SCAN_LANES`] equal chunks, and the chunks are
/// scanned in lock-step, one lane each, so the additions of different chunks fill the
/// vector lanes; blocks of eight samples per lane are copied in and out, transposed into
/// step-major order (8 × 8), so the loads and stores stay contiguous and each step of the
/// scan is one vector operation over the lanes. Each chunk's scan starts from the exact running state (sum and
/// compensation) at its start, which needs the chunk totals of y − mean before the mean
/// is known: the first pass sums y − y₀ per chunk (small values, eight-lane blocks,
/// compensated), which gives the mean, and each chunk's total of y − mean is then its
/// total of y − y₀ minus len·(mean − y₀), a small correction. Two passes over the data
/// in all, as the sequential scan needed.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // one index walks the lanes in lock-step
fn integrate_in_place(values: &mut [f64]) -> f64 {
    const L: usize = SCAN_LANES;
    const B: usize = 8;
    let Some(n) = values.len().checked_sub(1) else {
        return 0.0;
    };
    if n == 0 {
        return 0.0;
    }
    let chunk = n / L;
    let first = values[0];
    // Chunk totals of y − y₀ (the last chunk takes the remainder), then the mean.
    let mut shifted = [CompensatedSum::new(); L];
    let mut all = CompensatedSum::new();
    for (l, total) in shifted.iter_mut().enumerate() {
        let end = if l + 1 == L { n } else { (l + 1) * chunk };
        total.add(sum_streams([&values[l * chunk..end]], |[v]| v - first));
        all.merge(*total);
    }
    let offset = all.value() / n as f64;
    let mean = first + offset;
    // Running state at each chunk start: Σ over earlier chunks of (y − y₀) − len·(mean − y₀).
    let mut sum = [0.0f64; L];
    let mut compensation = [0.0f64; L];
    let mut running = CompensatedSum::new();
    let correction = mean - first;
    for l in 0..L {
        sum[l] = running.sum;
        compensation[l] = running.compensation;
        running.merge(shifted[l]);
        running.add(-(chunk as f64) * correction);
    }
    let step = |sum: &mut f64, compensation: &mut f64, slot: &mut f64| {
        let v = *slot - mean;
        *slot = *sum + *compensation;
        let t = *sum + v;
        let back = t - *sum;
        *compensation += (*sum - (t - back)) + (v - back);
        *sum = t;
    };
    let blocks = chunk / B;
    for b in 0..blocks {
        // Transposed (step-major: tile[j] holds step j of every lane), so each step is
        // one vector operation across the lanes instead of L scalar ones.
        let mut tile = [[0.0f64; L]; B];
        for l in 0..L {
            let at = l * chunk + b * B;
            let row: &[f64; B] = values[at..at + B].try_into().expect("B values");
            for j in 0..B {
                tile[j][l] = row[j];
            }
        }
        for row in &mut tile {
            for l in 0..L {
                step(&mut sum[l], &mut compensation[l], &mut row[l]);
            }
        }
        for l in 0..L {
            let at = l * chunk + b * B;
            let row: &mut [f64; B] = (&mut values[at..at + B]).try_into().expect("B values");
            for j in 0..B {
                row[j] = tile[j][l];
            }
        }
    }
    for l in 0..L {
        for i in blocks * B..chunk {
            step(
                &mut sum[l],
                &mut compensation[l],
                &mut values[l * chunk + i],
            );
        }
    }
    // The last lane carries on over the samples the equal chunks left (fewer than L) and
    // writes the final point into the extra slot.
    let (mut s, mut c) = (sum[L - 1], compensation[L - 1]);
    for slot in &mut values[L * chunk..] {
        step(&mut s, &mut c, slot);
    }
    mean
}

/// [`integrate_in_place`] as a [`Kernel`] (writes the mean).
struct Integrate<'a> {
    values: &'a mut [f64],
    mean: &'a mut f64,
}

impl Kernel for Integrate<'_> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        *self.mean = integrate_in_place(self.values);
    }
}

/// Chunks the phase integration scans in lock-step (see [`integrate_in_place`]).
const SCAN_LANES: usize = 8;

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

    /// The textbook sequential compensated running sum, for comparison.
    fn sequential_phase(y: &[f64], mean: f64) -> Vec<f64> {
        let mut acc = CompensatedSum::new();
        let mut out = vec![0.0];
        for v in y {
            acc.add(v - mean);
            out.push(acc.value());
        }
        out
    }

    #[test]
    fn lane_scan_equals_the_sequential_compensated_sum() {
        for n in [0, 1, 7, 8, 9, 63, 64, 65, 1_000, 4_099] {
            let y: Vec<f64> = (0..n)
                .map(|i| 9.80665 + (((i * 7919) % 1013) as f64 / 500.0 - 1.0))
                .collect();
            for simd in Simd::available() {
                let phase = Phase::from_rate_with(y.clone(), simd);
                let want = sequential_phase(&y, phase.removed_mean);
                assert_eq!(phase.len(), n + 1);
                for (k, (got, want)) in phase.points.iter().zip(&want).enumerate() {
                    assert!(
                        (got - want).abs() <= 1e-12 * (1.0 + want.abs()),
                        "n={n} {simd:?} k={k}: {got} vs {want}"
                    );
                }
            }
        }
    }

    #[test]
    fn both_instruction_set_paths_give_identical_phase() {
        let y: Vec<f64> = (0..10_001)
            .map(|i| ((i * 31 % 97) as f64).sin() + 1e3)
            .collect();
        let paths = Simd::available();
        let first = Phase::from_rate_with(y.clone(), paths[0]);
        for simd in &paths[1..] {
            let other = Phase::from_rate_with(y.clone(), *simd);
            assert_eq!(first.points, other.points, "{simd:?}");
            assert_eq!(first.removed_mean, other.removed_mean);
        }
    }
}
