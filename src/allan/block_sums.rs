//! ADEV and HDEV with their noise identification straight from the rate samples, without
//! building the phase: one read of the input, everything else in cache.
//!
//! The non-overlapping deviations and the lag-1 noise identification at factor m only
//! see the phase at multiples of m, z_m[k] = x[k·m], whose first difference is the block
//! sum s_m[k] = Σ_{i<m} (y[k·m + i] − mean). So ADEV's terms are the first differences
//! of s_m, HDEV's the second differences, the noise identification's difference orders
//! 1…3 are s_m and its differences, and order 0 is the running sum of s_m. The block
//! sums of 2m are pairwise sums of those of m, so all octave levels together cost about
//! 2N element steps, and nothing but the input is read from memory.
//!
//! Layout: the input is cut into super-blocks of [`LANES`] × S samples (S =
//! [`LANE_LEN`]), each lane a contiguous stretch of S samples. A super-block is
//! transposed once into a step-major scratch array (step t holds sample t of every
//! lane), and every octave level up to m = S is then a pass of plain vertical vector
//! operations: the pairwise sums of the next level go to a second scratch array, and the
//! few terms that straddle two lanes are added afterwards from each lane's first and
//! last values. Levels above S (from the lane totals, N/S values) and the samples after
//! the last full super-block go through the same accumulators one value at a time
//! ([`LevelSums::push`], the sequential definition the passes equal).
//!
//! Two cores: the super-blocks are cut into a fixed number of contiguous jobs
//! ([`job_count`], from the length alone) that run on the rayon pool, each summing its
//! levels up to S from zero into its own part of the level-S and stored block sums. The
//! jobs are joined in order ([`LevelSums::append`]): the terms whose blocks lie on both
//! sides of a seam are added from the last two values before it and the first two after
//! it, and the later job's order-0 moments are shifted by the phase and count before the
//! seam, as lanes are joined inside a super-block. The levels above S and the tail run
//! after the join, so the result is the same on any number of threads.
//!
//! A constant c (the mean of the first samples) is subtracted from every sample instead
//! of the exact mean, which is only known after the pass. The difference terms do not
//! depend on c, the lag-1 autocorrelation of the block sums neither (it removes their
//! mean), and the order-0 moments are corrected algebraically for the linear phase ramp
//! k·m·(mean − c) that c leaves ([`LevelSums::lag1`]). A constant near the mean keeps a
//! large offset (1 g on an accelerometer axis) from eating the significant digits, as
//! the mean removal of the phase does.
//!
//! Order 0 (the decimated phase itself) needs running sums at every level, which would
//! double the cost of the passes, yet for most data its answer is known: the noise
//! identification only asks whether its lag-1 autocorrelation r is below 1/3, and
//! r ≥ ½ − Σ(Δz)²/(2D) with D the phase's spread about its mean, which is at least the
//! spread D' of the coarser (exactly evaluated) level 2S, whose points are a subset. So
//! when Σ(Δz)² ≤ D'/3 (a little less: the decision scales r by (L − 1)/L for L points)
//! the fast pass proves r ≥ 1/3 (the phase wanders far more than it
//! steps, as for every frequency noise on a long record); otherwise the passes are run
//! again with the order-0 moments ([`pyramid_with_lane`] with `phase_moments`).
//!
//! Hand-written: no crate offers these fused multi-level estimators.

use super::deviation::{normalise, DeviationKind};
use super::edf::Alpha;
use super::noise_id::{decide_alpha, lag1_pair, Lag1};
use super::numerics::{dispatch, sum_streams, CompensatedSum, Kernel, Simd};
use rayon::prelude::*;

/// Lanes of the vertical passes (two AVX2 vectors).
pub const LANES: usize = 8;

/// Samples per lane of a super-block (the two scratch arrays hold 2 × LANES × S f64,
/// 64 KiB).
pub const LANE_LEN: usize = 512;

/// Samples whose mean is the constant subtracted from every sample.
pub const OFFSET_SAMPLES: usize = 4096;

/// Level whose block sums (m = 16) are kept for the difference orders 2 and 3, which
/// the noise identification needs wherever the block sums look correlated.
const STORED_LEVEL: usize = 4;

/// Jobs the super-block passes are cut into (see [`pyramid_in_jobs`]): a fixed count,
/// independent of the thread count.
const JOBS: usize = 2;

/// Fewest super-blocks per job (shorter series are not cut).
const MIN_JOB_BLOCKS: usize = 8;

/// Safety margin of the order-0 bound against the rounding of its two sides.
const BOUND_MARGIN: f64 = 1e-6;

type V = [f64; LANES];

/// What one octave level accumulated: the deviation sum of squared differences and the
/// raw moments of the noise identification's orders 0 and 1.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LevelSums {
    /// Averaging factor.
    pub m: usize,
    /// Number of block sums K = ⌊N/m⌋ (the decimated phase has K + 1 points).
    pub count: usize,
    /// Σ (Δs)² (ADEV) or Σ (Δ²s)² (HDEV) over the block sums.
    deviation: CompensatedSum,
    /// Σ s², Σ s_k·s_{k+1} of the block sums s' = s + m·(mean − c).
    squares: CompensatedSum,
    lag1: CompensatedSum,
    /// Running sum of s': the phase z'_K after the last block.
    phase: CompensatedSum,
    /// Σ_{k=1}^{K} z'_k, Σ z'_k², Σ k·z'_k (only with the order-0 moments).
    phase_sum: CompensatedSum,
    phase_squares: CompensatedSum,
    phase_moment: CompensatedSum,
    /// First two block sums (s'_0, s'_1), last two (s'_{K−1}, s'_{K−2}); 0 where the
    /// level has fewer values.
    first: [f64; 2],
    last: [f64; 2],
}

impl LevelSums {
    pub fn new(m: usize) -> Self {
        LevelSums {
            m,
            ..Self::default()
        }
    }

    /// Σ of the squared differences (first for ADEV, second for HDEV).
    pub fn deviation_sum(&self) -> f64 {
        self.deviation.value()
    }

    /// Appends one block sum: the sequential definition the vector passes equal.
    pub fn push<const HADAMARD: bool>(&mut self, s: f64) {
        let k = self.count;
        let [p1, p2] = self.last;
        if k < 2 {
            self.first[k] = s;
        }
        if k > 0 {
            let d1 = s - p1;
            if !HADAMARD {
                self.deviation.add(d1 * d1);
            } else if k >= 2 {
                let d2 = d1 - (p1 - p2);
                self.deviation.add(d2 * d2);
            }
            self.lag1.add(p1 * s);
        }
        self.squares.add(s * s);
        self.phase.add(s);
        let z = self.phase.value();
        self.phase_sum.add(z);
        self.phase_squares.add(z * z);
        self.phase_moment.add((k + 1) as f64 * z);
        self.last = [s, p1];
        self.count += 1;
    }

    /// Appends the level of the block sums that follow this level's (`later`, summed
    /// from its own start: its running phase begins at 0): the same sums as pushing
    /// `later`'s values one by one after this level's. Adds the terms that straddle the
    /// seam from this level's last two values and `later`'s first two, and shifts
    /// `later`'s order-0 moments by the phase Z and the count k₀ before the seam:
    /// Σ(Z + z) = Σz + K·Z, Σ(Z + z)² = Σz² + 2Z·Σz + K·Z², and
    /// Σ(k₀ + k)(Z + z_k) = Σk·z_k + k₀·Σz + Z·(k₀·K + K(K + 1)/2) for k = 1…K.
    fn append<const HADAMARD: bool>(&mut self, later: &LevelSums) {
        if later.count == 0 {
            return;
        }
        if self.count == 0 {
            *self = *later;
            return;
        }
        let k0 = self.count;
        let [p1, _] = self.last;
        let [f0, _] = later.first;
        self.deviation.add(seam_terms::<HADAMARD>(
            self.last,
            k0,
            later.first,
            later.count,
        ));
        self.deviation.merge(later.deviation);
        self.lag1.add(p1 * f0);
        self.lag1.merge(later.lag1);
        self.squares.merge(later.squares);
        let z = self.phase.value();
        let (before, count) = (k0 as f64, later.count as f64);
        let sum = later.phase_sum.value();
        self.phase_sum.merge(later.phase_sum);
        self.phase_sum.add(count * z);
        self.phase_squares.merge(later.phase_squares);
        self.phase_squares.add(2.0 * z * sum);
        self.phase_squares.add(count * z * z);
        self.phase_moment.merge(later.phase_moment);
        self.phase_moment.add(before * sum);
        self.phase_moment
            .add(z * (before * count + count * (count + 1.0) / 2.0));
        self.phase.merge(later.phase);
        if k0 == 1 {
            self.first[1] = f0;
        }
        self.last = if later.count >= 2 {
            later.last
        } else {
            [f0, p1]
        };
        self.count += later.count;
    }

    /// Lag-1 autocorrelation of the block sums (difference order 1); `None` for zero
    /// variance or fewer than two values. Invariant to the constant in s'.
    pub fn lag1_of_sums(&self) -> Option<f64> {
        if self.count < 2 {
            return None;
        }
        let k = self.count as f64;
        let total = self.phase.value();
        let mean = total / k;
        let d = self.squares.value() - k * mean * mean;
        let numerator = self.lag1.value() - mean * (2.0 * total - self.first[0] - self.last[0])
            + (k - 1.0) * mean * mean;
        (d > 0.0).then(|| numerator / d)
    }

    /// Σ(Δz)² = Σ s² of the decimated phase with the exact mean removed (s = s' − m·δ).
    fn increments(&self, delta: f64) -> f64 {
        let a = self.m as f64 * delta;
        self.squares.value() - 2.0 * a * self.phase.value() + self.count as f64 * a * a
    }

    /// The decimated phase z_k = z'_k − k·m·δ over its K + 1 points (z_0 = 0): its mean
    /// μ, spread D = Σ(z − μ)² and last point z_K, from the order-0 moments.
    fn phase_spread(&self, delta: f64) -> (f64, f64, f64) {
        let k = self.count as f64;
        let a = self.m as f64 * delta;
        let sum_k = k * (k + 1.0) / 2.0;
        let sum_k2 = k * (k + 1.0) * (2.0 * k + 1.0) / 6.0;
        let sum = self.phase_sum.value() - a * sum_k;
        let squares =
            self.phase_squares.value() - 2.0 * a * self.phase_moment.value() + a * a * sum_k2;
        let mean = sum / (k + 1.0);
        (
            mean,
            squares - (k + 1.0) * mean * mean,
            self.phase.value() - k * a,
        )
    }

    /// Lag-1 autocorrelation of the decimated phase (difference order 0), exact mean
    /// removed, given δ = mean − c; `None` for zero variance or no block sum.
    ///
    /// With μ the mean of z and D = Σ(z − μ)², the lag-1 numerator is
    /// Σ(z_k − μ)(z_{k+1} − μ) = D − ½[(z_0 − μ)² + (z_K − μ)² + Σ(z_{k+1} − z_k)²]
    /// (expand the squared first differences).
    pub fn lag1(&self, delta: f64) -> Option<f64> {
        if self.count == 0 {
            return None;
        }
        let (mean, d, end) = self.phase_spread(delta);
        let ends = mean * mean + (end - mean) * (end - mean);
        (d > 0.0).then(|| (d - 0.5 * (ends + self.increments(delta))) / d)
    }
}

/// The octave levels m = 1, 2, 4, … of one rate series.
#[derive(Debug, Clone)]
pub struct Pyramid {
    /// Level j has m = 2^j: every requested factor with a block sum, and at least the
    /// levels up to 2S.
    pub levels: Vec<LevelSums>,
    /// Block sums s' of level `stored_level` (m = 2^stored_level), for the orders 2 and 3
    /// of the levels from there up.
    stored: Vec<f64>,
    stored_level: usize,
    /// Levels evaluated by the super-block passes (m ≤ S): j < inner.
    inner: usize,
    /// Whether those levels have their order-0 moments.
    phase_moments: bool,
    /// The constant subtracted from every sample.
    pub offset: f64,
    /// Mean of the samples (c + δ), compensated.
    pub mean: f64,
}

impl Pyramid {
    /// δ = mean − c.
    pub fn delta(&self) -> f64 {
        self.mean - self.offset
    }

    /// Whether level `j` has exact order-0 moments.
    fn exact_phase(&self, j: usize) -> bool {
        self.phase_moments || j >= self.inner
    }

    /// Whether the bound of the module docs proves that the lag-1 autocorrelation of
    /// level `j`'s decimated phase of `points` points is at least 1/3 after the
    /// normalisation r·(points − 1)/points of [`decide_alpha`], i.e. r ≥ points/(3(points − 1)):
    /// Σ(Δz)² ≤ D'·(points − 3)/(3(points − 1)).
    fn order0_correlated(&self, j: usize, points: usize) -> bool {
        let (Some(level), Some(coarse)) = (self.levels.get(j), self.levels.get(self.inner)) else {
            return false;
        };
        if coarse.count == 0 || level.count == 0 {
            return false;
        }
        if points < 4 {
            return false;
        }
        let (_, spread, _) = coarse.phase_spread(self.delta());
        let p = points as f64;
        spread > 0.0
            && level.increments(self.delta())
                <= spread * (p - 3.0) / (3.0 * (p - 1.0)) * (1.0 - BOUND_MARGIN)
    }

    /// The block sums s' of level `j` into `held` (which may hold a lower level from the
    /// stored one up, as the noise identification walks the factors upwards): pairwise
    /// sums from the stored level up, summed again from `rate` below it (slow, and only
    /// for data correlated from sample to sample).
    fn block_sums_into(&self, j: usize, rate: &[f64], held: &mut Option<(usize, Vec<f64>)>) {
        if j < self.stored_level {
            let sums = rate
                .chunks_exact(1 << j)
                .map(|block| block.iter().map(|v| v - self.offset).sum())
                .collect();
            *held = Some((j, sums));
            return;
        }
        let (mut at, mut sums) = match held.take() {
            Some((at, sums)) if at >= self.stored_level && at <= j => (at, sums),
            // Above the stored level the first halving reads it in place (no copy of it).
            _ if j > self.stored_level => (
                self.stored_level + 1,
                self.stored.chunks_exact(2).map(|p| p[0] + p[1]).collect(),
            ),
            _ => (self.stored_level, self.stored.clone()),
        };
        while at < j {
            let half = sums.len() / 2;
            for i in 0..half {
                sums[i] = sums[2 * i] + sums[2 * i + 1];
            }
            sums.truncate(half);
            at += 1;
        }
        *held = Some((j, sums));
    }
}

/// ADEV or HDEV with noise types, from the rate samples: see [`non_overlapping_from_rate`].
#[derive(Debug, Clone, PartialEq)]
pub struct RateAnalysis {
    /// Per factor: the variance and term count of
    /// [`variance_at`](super::deviation::variance_at), `None` where undefined.
    pub variances: Vec<Option<(f64, usize)>>,
    /// Per factor: the noise exponent of
    /// [`identify_alpha`](super::noise_id::identify_alpha).
    pub alphas: Vec<Option<Alpha>>,
    /// Mean of the samples (what the phase removes).
    pub mean: f64,
}

/// ADEV or HDEV (`kind`) and the lag-1 noise type at every factor of `factors` straight
/// from the rate samples (see the module docs); the same values as the phase-based
/// [`variances`](super::deviation::variances) and
/// [`identify_alphas`](super::noise_id::identify_alphas) to rounding. `None` for
/// other kinds or when a factor is not a power of two.
pub fn non_overlapping_from_rate(
    rate: &[f64],
    kind: DeviationKind,
    factors: &[usize],
    simd: Simd,
) -> Option<RateAnalysis> {
    non_overlapping_with_lane(rate, kind, factors, simd, LANE_LEN)
}

/// [`non_overlapping_from_rate`] with `lane_len` samples per lane.
pub fn non_overlapping_with_lane(
    rate: &[f64],
    kind: DeviationKind,
    factors: &[usize],
    simd: Simd,
    lane_len: usize,
) -> Option<RateAnalysis> {
    let hadamard = match kind {
        DeviationKind::Adev => false,
        DeviationKind::Hdev => true,
        _ => return None,
    };
    if !factors.iter().all(|m| m.is_power_of_two()) {
        return None;
    }
    let max_differences = if hadamard { 3 } else { 2 };
    let max_factor = factors.iter().copied().max().unwrap_or(1);
    let n_phase = rate.len() + 1;
    let mut pyramid = pyramid_with_lane(rate, max_factor, hadamard, false, simd, lane_len);
    let mut alphas = identify(&pyramid, rate, factors, max_differences, simd);
    if alphas.is_none() {
        // An order-0 answer the bound could not give: run the passes with the moments.
        pyramid = pyramid_with_lane(rate, max_factor, hadamard, true, simd, lane_len);
        alphas = identify(&pyramid, rate, factors, max_differences, simd);
    }
    let variances = factors
        .iter()
        .map(|&m| {
            let count = kind.term_count(m, n_phase);
            let level = pyramid.levels.get(m.trailing_zeros() as usize)?;
            (count > 0).then(|| (normalise(kind, level.deviation_sum(), m, count), count))
        })
        .collect();
    Some(RateAnalysis {
        variances,
        alphas: alphas?,
        mean: pyramid.mean,
    })
}

/// The noise type per factor, or `None` when some level's order 0 is needed and neither
/// exact nor settled by the bound.
fn identify(
    pyramid: &Pyramid,
    rate: &[f64],
    factors: &[usize],
    max_differences: u32,
    simd: Simd,
) -> Option<Vec<Option<Alpha>>> {
    let delta = pyramid.delta();
    let n = rate.len();
    let mut out = Vec::with_capacity(factors.len());
    // Block sums of the last level whose orders 2 and 3 were needed.
    let mut held: Option<(usize, Vec<f64>)> = None;
    for &m in factors {
        let j = m.trailing_zeros() as usize;
        let Some(level) = pyramid.levels.get(j) else {
            out.push(None);
            continue;
        };
        let mut unsettled = false;
        let mut high: Option<[Option<f64>; 2]> = None;
        let held = &mut held;
        let points = n / m + 1;
        let alpha = decide_alpha(points, max_differences, |order| {
            let r = match order {
                0 if pyramid.exact_phase(j) => level.lag1(delta),
                0 if pyramid.order0_correlated(j, points) => return Lag1::Correlated,
                0 => {
                    unsettled = true;
                    return Lag1::Undefined;
                }
                1 => level.lag1_of_sums(),
                // Orders 2 and 3 of the phase are orders 1 and 2 of its block sums.
                _ => high.get_or_insert_with(|| {
                    pyramid.block_sums_into(j, rate, held);
                    let sums = held.as_ref().map_or(&[][..], |(_, s)| s.as_slice());
                    lag1_pair(sums, 1, simd)
                })[order - 2],
            };
            r.map_or(Lag1::Undefined, Lag1::Value)
        });
        if unsettled {
            return None;
        }
        out.push(alpha);
    }
    Some(out)
}

/// The octave pyramid of `rate` for ADEV (`hadamard` false) or HDEV, levels up to factor
/// `max_factor` (and at least up to 2S), with the order-0 moments of the levels in the
/// super-block passes if `phase_moments`; `lane_len` (a power of two) samples per lane.
/// The super-blocks are cut into [`job_count`] jobs (see [`pyramid_in_jobs`]).
pub fn pyramid_with_lane(
    rate: &[f64],
    max_factor: usize,
    hadamard: bool,
    phase_moments: bool,
    simd: Simd,
    lane_len: usize,
) -> Pyramid {
    let jobs = job_count(rate.len() / (LANES * lane_len.max(1)));
    pyramid_in_jobs(
        rate,
        max_factor,
        hadamard,
        phase_moments,
        simd,
        lane_len,
        jobs,
    )
}

/// Jobs the super-block passes of `blocks` super-blocks are cut into: [`JOBS`], fewer when
/// a job would get less than [`MIN_JOB_BLOCKS`]. It depends on the length only, never on
/// the size of the thread pool, so the sums are the same on any number of threads.
pub fn job_count(blocks: usize) -> usize {
    (blocks / MIN_JOB_BLOCKS).clamp(1, JOBS)
}

/// [`pyramid_with_lane`] with the super-blocks cut into `jobs` contiguous runs (at most
/// one per super-block) that run on the rayon pool, each with its own level sums from
/// zero; they are joined in order by [`LevelSums::append`], which adds the terms that
/// straddle each seam. The levels above S and the samples after the last super-block
/// go through [`LevelSums::push`] after the join, so they have no seams.
pub fn pyramid_in_jobs(
    rate: &[f64],
    max_factor: usize,
    hadamard: bool,
    phase_moments: bool,
    simd: Simd,
    lane_len: usize,
    jobs: usize,
) -> Pyramid {
    assert!(
        lane_len.is_power_of_two(),
        "lane length must be a power of two"
    );
    let n = rate.len();
    let head = &rate[..n.min(OFFSET_SAMPLES)];
    let offset = if head.is_empty() {
        0.0
    } else {
        sum_streams([head], |[v]| v) / head.len() as f64
    };
    let inner = lane_len.trailing_zeros() as usize + 1;
    let count = std::iter::successors(Some(1usize), |m| m.checked_mul(2))
        .take_while(|&m| m <= max_factor.max(2 * lane_len) && m <= n.max(1))
        .count()
        .max(inner);
    let mut levels: Vec<LevelSums> = (0..count).map(|j| LevelSums::new(1 << j)).collect();
    let mut total = CompensatedSum::new();
    let stored_level = STORED_LEVEL.min(inner - 1);
    let width = LANES * lane_len;
    let blocks = n / width;
    // Exactly as long as their levels (level S: n/S sums; the stored level: n >> j),
    // zeroed by the allocator so that the jobs fault their pages in, in parallel.
    let mut top: Vec<f64> = vec![0.0; n / lane_len];
    let mut stored: Vec<f64> = vec![0.0; n >> stored_level];
    if blocks > 0 {
        let jobs = jobs.clamp(1, blocks);
        let stored_width = width >> stored_level;
        let mut tasks = Vec::with_capacity(jobs);
        let (mut top_rest, mut stored_rest) = (&mut top[..], &mut stored[..]);
        for i in 0..jobs {
            let (first, last) = (i * blocks / jobs, (i + 1) * blocks / jobs);
            let (top_part, rest) = top_rest.split_at_mut((last - first) * LANES);
            top_rest = rest;
            let (stored_part, rest) = stored_rest.split_at_mut((last - first) * stored_width);
            stored_rest = rest;
            tasks.push((&rate[first * width..last * width], top_part, stored_part));
        }
        let avx = simd == Simd::Avx2 && Simd::detected() == Simd::Avx2;
        let parts: Vec<(Vec<LevelSums>, CompensatedSum)> = tasks
            .into_par_iter()
            .map(|(rate, top, stored)| {
                let mut levels: Vec<LevelSums> =
                    (0..inner).map(|j| LevelSums::new(1 << j)).collect();
                let mut total = CompensatedSum::new();
                let pass = SuperBlocks {
                    rate,
                    avx,
                    offset,
                    lane_len,
                    levels: &mut levels,
                    top,
                    stored,
                    stored_level,
                    total: &mut total,
                };
                match (hadamard, phase_moments) {
                    (true, true) => dispatch(simd, Passes::<true, true>(pass)),
                    (true, false) => dispatch(simd, Passes::<true, false>(pass)),
                    (false, true) => dispatch(simd, Passes::<false, true>(pass)),
                    (false, false) => dispatch(simd, Passes::<false, false>(pass)),
                }
                (levels, total)
            })
            .collect();
        // Joined in job order: the same sums on any number of threads.
        for (part, sum) in &parts {
            for (level, later) in levels.iter_mut().zip(part) {
                if hadamard {
                    level.append::<true>(later);
                } else {
                    level.append::<false>(later);
                }
            }
            total.merge(*sum);
        }
    }
    // The rest, one value at a time: levels up to S from the samples after the last
    // super-block, then the levels above from the lane totals (the level-S sums).
    let mut values: Vec<f64> = rate[blocks * width..].iter().map(|v| v - offset).collect();
    for v in &values {
        total.add(*v);
    }
    for (j, level) in levels.iter_mut().enumerate() {
        if j == inner {
            values = std::mem::take(&mut top);
        }
        if j > 0 {
            values = values.chunks_exact(2).map(|p| p[0] + p[1]).collect();
        }
        for &v in &values {
            if hadamard {
                level.push::<true>(v);
            } else {
                level.push::<false>(v);
            }
        }
        if j + 1 == inner {
            top[blocks * LANES..].copy_from_slice(&values);
        }
        if j == stored_level {
            stored[(blocks * width) >> stored_level..].copy_from_slice(&values);
        }
    }
    Pyramid {
        levels,
        stored,
        stored_level,
        inner,
        phase_moments: phase_moments || blocks == 0,
        offset,
        mean: if n == 0 {
            0.0
        } else {
            offset + total.value() / n as f64
        },
    }
}

/// The super-block passes over `rate` (a whole number of super-blocks).
struct SuperBlocks<'a> {
    rate: &'a [f64],
    /// Whether the AVX2 transpose may run (the path is AVX2 and the CPU has it).
    avx: bool,
    offset: f64,
    lane_len: usize,
    levels: &'a mut [LevelSums],
    /// Receives the lane totals (level S) in sequence order, LANES per super-block.
    top: &'a mut [f64],
    /// Receives the block sums of level `stored_level` in sequence order.
    stored: &'a mut [f64],
    stored_level: usize,
    total: &'a mut CompensatedSum,
}

/// [`super_blocks`] as a [`Kernel`], monomorphised for ADEV or HDEV and with or without
/// the order-0 (phase) moments.
struct Passes<'a, const HADAMARD: bool, const PHASE: bool>(SuperBlocks<'a>);

impl<const HADAMARD: bool, const PHASE: bool> Kernel for Passes<'_, HADAMARD, PHASE> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        super_blocks::<HADAMARD, PHASE>(self.0)
    }
}

/// Per-lane results of one level's pass over a super-block.
struct LaneSums {
    deviation: V,
    squares: V,
    lag1: V,
    /// Σ_t R_t, Σ_t R_t², Σ_t Σ_{u≤t} R_u with R_t the lane's running sum.
    running: V,
    running_squares: V,
    running_running: V,
    first: [V; 2],
    last: [V; 2],
}

#[inline(always)]
fn add(a: V, b: V) -> V {
    std::array::from_fn(|l| a[l] + b[l])
}

#[inline(always)]
fn sub(a: V, b: V) -> V {
    std::array::from_fn(|l| a[l] - b[l])
}

#[inline(always)]
fn mul(a: V, b: V) -> V {
    std::array::from_fn(|l| a[l] * b[l])
}

/// One level's pass over the step-major values `a` (T steps of LANES lanes), writing the
/// pairwise sums of the next level into `next` (T/2 steps).
#[inline(always)]
fn lane_pass<const HADAMARD: bool, const PHASE: bool>(a: &[V], next: &mut [V]) -> LaneSums {
    let zero = [0.0; LANES];
    let steps = a.len();
    let s = a[0];
    let mut squares = mul(s, s);
    let zero_if = |v: V| if PHASE { v } else { zero };
    let mut running = zero_if(s);
    let mut running_sum = zero_if(s);
    let mut running_squares = zero_if(mul(s, s));
    let mut running_running = zero_if(s);
    let mut deviation = zero;
    let mut lag1 = zero;
    if steps == 1 {
        return LaneSums {
            deviation,
            squares,
            lag1,
            running: running_sum,
            running_squares,
            running_running,
            first: [s, zero],
            last: [s, zero],
        };
    }
    let s1 = a[1];
    let d1 = sub(s1, s);
    if !HADAMARD {
        deviation = mul(d1, d1);
    }
    lag1 = mul(s, s1);
    squares = add(squares, mul(s1, s1));
    if PHASE {
        running = add(running, s1);
        running_sum = add(running_sum, running);
        running_squares = add(running_squares, mul(running, running));
        running_running = add(running_running, running_sum);
    }
    next[0] = add(s, s1);
    let mut previous = s1;
    let mut before = s;
    let mut difference = d1;
    for (pair, out) in a[2..].chunks_exact(2).zip(next[1..].iter_mut()) {
        for &s in pair {
            let d1 = sub(s, previous);
            if HADAMARD {
                let d2 = sub(d1, difference);
                deviation = add(deviation, mul(d2, d2));
            } else {
                deviation = add(deviation, mul(d1, d1));
            }
            lag1 = add(lag1, mul(previous, s));
            squares = add(squares, mul(s, s));
            if PHASE {
                running = add(running, s);
                running_sum = add(running_sum, running);
                running_squares = add(running_squares, mul(running, running));
                running_running = add(running_running, running_sum);
            }
            difference = d1;
            before = previous;
            previous = s;
        }
        *out = add(pair[0], pair[1]);
    }
    LaneSums {
        deviation,
        squares,
        lag1,
        running: running_sum,
        running_squares,
        running_running,
        first: [s, s1],
        last: [previous, before],
    }
}

#[inline(always)]
fn super_blocks<const HADAMARD: bool, const PHASE: bool>(pass: SuperBlocks<'_>) {
    let SuperBlocks {
        rate,
        avx,
        offset,
        lane_len,
        levels,
        top,
        stored,
        stored_level,
        total,
    } = pass;
    let mut current: Vec<V> = vec![[0.0; LANES]; lane_len];
    let mut next: Vec<V> = vec![[0.0; LANES]; lane_len];
    let mut sums: Vec<LaneSums> = Vec::with_capacity(levels.len());
    let width = LANES * lane_len;
    for ((block, top), stored) in rate
        .chunks_exact(width)
        .zip(top.chunks_exact_mut(LANES))
        .zip(stored.chunks_exact_mut(width >> stored_level))
    {
        transpose(block, lane_len, offset, &mut current, avx);
        sums.clear();
        let mut steps = lane_len;
        while steps > 0 {
            if sums.len() == stored_level {
                for (l, lane) in stored.chunks_exact_mut(steps).enumerate() {
                    for (out, row) in lane.iter_mut().zip(&current[..steps]) {
                        *out = row[l];
                    }
                }
            }
            sums.push(lane_pass::<HADAMARD, PHASE>(
                &current[..steps],
                &mut next[..steps / 2],
            ));
            std::mem::swap(&mut current, &mut next);
            steps /= 2;
        }
        // The last level has one value per lane: the lane totals.
        let totals = sums[sums.len() - 1].first[0];
        total.add(totals.iter().sum());
        top.copy_from_slice(&totals);
        let mut steps = lane_len;
        for (level, sums) in levels.iter_mut().zip(&sums) {
            merge_lanes::<HADAMARD, PHASE>(level, sums, steps, &totals);
            steps /= 2;
        }
    }
}

/// The difference terms that straddle a seam between two runs of block sums: the earlier
/// run's last two values `last` = [s_{k0−1}, s_{k0−2}] (of `before` values) and the later
/// run's first two `first` (of `after` values). ADEV: the first difference across the
/// seam; HDEV: the two second differences that take values from both sides. Shared by the
/// lane join inside a super-block and the job join of whole passes.
#[inline(always)]
fn seam_terms<const HADAMARD: bool>(
    last: [f64; 2],
    before: usize,
    first: [f64; 2],
    after: usize,
) -> f64 {
    let ([p1, p2], [f0, f1]) = (last, first);
    let d1 = f0 - p1;
    if !HADAMARD {
        return d1 * d1;
    }
    let mut seam = 0.0;
    if before >= 2 {
        let d2 = d1 - (p1 - p2);
        seam += d2 * d2;
    }
    if after >= 2 {
        let d2 = (f1 - f0) - d1;
        seam += d2 * d2;
    }
    seam
}

/// Adds one super-block's lane sums (lanes in sequence order, `steps` values each) to
/// the level: the terms inside lanes, the terms that straddle a lane boundary (from the
/// previous values in sequence order), and the order-0 moments of the running phase.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // one index walks the lanes of several arrays
fn merge_lanes<const HADAMARD: bool, const PHASE: bool>(
    level: &mut LevelSums,
    sums: &LaneSums,
    steps: usize,
    totals: &V,
) {
    let t = steps as f64;
    let mut deviation = 0.0;
    let mut lag1 = 0.0;
    let mut phase_sum = 0.0;
    let mut phase_squares = 0.0;
    let mut phase_moment = 0.0;
    let base = level.phase.value();
    let mut offset = 0.0;
    for l in 0..LANES {
        let k0 = level.count;
        let [p1, _] = level.last;
        let f0 = sums.first[0][l];
        if k0 == 0 {
            level.first = [f0, sums.first[1][l]];
        } else {
            if k0 == 1 {
                level.first[1] = f0;
            }
            lag1 += p1 * f0;
            deviation += seam_terms::<HADAMARD>(level.last, k0, [f0, sums.first[1][l]], steps);
        }
        deviation += sums.deviation[l];
        lag1 += sums.lag1[l];
        if PHASE {
            // z' at this lane's values: Z + R_t with Z the phase before the lane.
            let z = base + offset;
            let r = sums.running[l];
            phase_sum += t * z + r;
            phase_squares += t * z * z + 2.0 * z * r + sums.running_squares[l];
            let weighted = t * r - sums.running_running[l];
            phase_moment += (k0 + 1) as f64 * (t * z + r) + z * (t * (t - 1.0) / 2.0) + weighted;
        }
        offset += totals[l];
        level.last = if steps >= 2 {
            [sums.last[0][l], sums.last[1][l]]
        } else {
            [f0, p1]
        };
        level.count += steps;
    }
    level.deviation.add(deviation);
    level.lag1.add(lag1);
    level.squares.add(sums.squares.iter().sum());
    level.phase.add(offset);
    if PHASE {
        level.phase_sum.add(phase_sum);
        level.phase_squares.add(phase_squares);
        level.phase_moment.add(phase_moment);
    }
}

/// Writes the super-block `block` (LANES lanes of `lane_len` samples) step-major into
/// `out`: out[t][l] = block[l·lane_len + t] − offset. With `avx` (the caller checked the
/// CPU has AVX2) in 4 × 4 tiles of vector unpacks and lane permutes; the compiler turns
/// the portable loop into scalar loads. Both give the same values (only the subtraction
/// is arithmetic).
#[inline(always)]
fn transpose(block: &[f64], lane_len: usize, offset: f64, out: &mut [V], avx: bool) {
    #[cfg(target_arch = "x86_64")]
    if avx && lane_len.is_multiple_of(4) {
        // SAFETY: `avx` is only true when the CPU supports AVX2 (see `pyramid_with_lane`);
        // every access is bounds-checked by the slicing inside.
        unsafe { transpose_avx(block, lane_len, offset, out) };
        return;
    }
    let _ = avx;
    for (t, row) in out[..lane_len].iter_mut().enumerate() {
        *row = std::array::from_fn(|l| block[l * lane_len + t] - offset);
    }
}

/// [`transpose`] with AVX intrinsics (4 × 4 tiles).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn transpose_avx(block: &[f64], lane_len: usize, offset: f64, out: &mut [V]) {
    use std::arch::x86_64::*;
    let lanes: [&[f64]; LANES] = std::array::from_fn(|l| &block[l * lane_len..(l + 1) * lane_len]);
    let shift = _mm256_set1_pd(offset);
    for (t4, rows) in out[..lane_len].chunks_exact_mut(4).enumerate() {
        let [o0, o1, o2, o3] = rows else {
            unreachable!()
        };
        for g in 0..LANES / 4 {
            let load = |i: usize| {
                let src: &[f64; 4] = lanes[4 * g + i][4 * t4..4 * t4 + 4].try_into().unwrap();
                // SAFETY: `src` is four readable f64.
                _mm256_sub_pd(unsafe { _mm256_loadu_pd(src.as_ptr()) }, shift)
            };
            let (r0, r1, r2, r3) = (load(0), load(1), load(2), load(3));
            let t0 = _mm256_unpacklo_pd(r0, r1);
            let t1 = _mm256_unpackhi_pd(r0, r1);
            let t2 = _mm256_unpacklo_pd(r2, r3);
            let t3 = _mm256_unpackhi_pd(r2, r3);
            let store = |row: &mut V, v: __m256d| {
                let dst: &mut [f64; 4] = (&mut row[4 * g..4 * g + 4]).try_into().unwrap();
                // SAFETY: `dst` is four writable f64.
                unsafe { _mm256_storeu_pd(dst.as_mut_ptr(), v) };
            };
            store(o0, _mm256_permute2f128_pd::<0x20>(t0, t2));
            store(o1, _mm256_permute2f128_pd::<0x20>(t1, t3));
            store(o2, _mm256_permute2f128_pd::<0x31>(t0, t2));
            store(o3, _mm256_permute2f128_pd::<0x31>(t1, t3));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deviation::variances_with;
    use crate::noise_id::identify_alphas;
    use crate::noise_id::tests::textbook_lag1;
    use crate::numerics::Phase;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// White noise plus a random walk (rate random walk) on a large offset.
    fn noisy_rate(n: usize, offset: f64, walk_step: f64, seed: u64) -> Vec<f64> {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut walk = 0.0;
        (0..n)
            .map(|_| {
                let w: f64 = StandardNormal.sample(&mut rng);
                let s: f64 = StandardNormal.sample(&mut rng);
                walk += walk_step * s;
                offset + w + walk
            })
            .collect()
    }

    /// Rate whose phase is white noise (white PM): the first difference of white noise.
    fn white_pm_rate(n: usize, seed: u64) -> Vec<f64> {
        let phase = noisy_rate(n + 1, 0.0, 0.0, seed);
        phase.windows(2).map(|w| w[1] - w[0]).collect()
    }

    /// Samples correlated from one to the next (a low-pass filter), so that the block
    /// sums of the lowest levels need the difference orders 2 and 3.
    fn low_passed_rate(n: usize, seed: u64) -> Vec<f64> {
        let white = noisy_rate(n, 0.0, 0.0, seed);
        let mut state = 0.0;
        white
            .iter()
            .map(|w| {
                state = 0.97 * state + w;
                3.0 + state
            })
            .collect()
    }

    #[test]
    fn levels_equal_the_decimated_phase_definitions() {
        for (n, lane_len) in [
            (10, 1),
            (1_000, 2),
            (5_003, 4),
            (40_000, 16),
            (100_003, 512),
        ] {
            for offset in [0.0, 9.806_65] {
                let y = noisy_rate(n, offset, 0.01, 3);
                let phase = Phase::from_rate(y.clone());
                let x = &phase.points;
                for hadamard in [false, true] {
                    let kind = if hadamard {
                        DeviationKind::Hdev
                    } else {
                        DeviationKind::Adev
                    };
                    for simd in Simd::available() {
                        let p = pyramid_with_lane(&y, n, hadamard, true, simd, lane_len);
                        assert!((p.mean - phase.removed_mean).abs() <= 1e-12 * offset.max(1.0));
                        for level in &p.levels {
                            let m = level.m;
                            assert_eq!(level.count, n / m, "n={n} m={m}");
                            let z: Vec<f64> = x.iter().step_by(m).copied().collect();
                            let label = format!("n={n} lane={lane_len} {kind:?} {simd:?} m={m}");
                            let count = kind.term_count(m, n + 1);
                            if count > 0 {
                                let want = variance_at(kind, &phase, m).unwrap().0;
                                let got = normalise(kind, level.deviation_sum(), m, count);
                                assert!(
                                    (got - want).abs() <= 1e-11 * want,
                                    "{label}: {got} {want}"
                                );
                            }
                            let s: Vec<f64> = z.windows(2).map(|w| w[1] - w[0]).collect();
                            for (got, want) in [
                                (level.lag1(p.delta()), textbook_lag1(&z)),
                                (
                                    level.lag1_of_sums(),
                                    (s.len() >= 2).then(|| textbook_lag1(&s)).flatten(),
                                ),
                            ] {
                                match (got, want) {
                                    (Some(g), Some(w)) => {
                                        assert!((g - w).abs() < 1e-9, "{label}: lag1 {g} vs {w}")
                                    }
                                    (None, None) => {}
                                    // One or two points: zero variance either way.
                                    _ if z.len() <= 2 => {}
                                    (g, w) => panic!("{label}: lag1 {g:?} vs {w:?}"),
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    use crate::deviation::variance_at;

    #[test]
    fn both_instruction_set_paths_give_identical_bits() {
        let y = noisy_rate(70_001, 9.8, 0.01, 5);
        for hadamard in [false, true] {
            for phase_moments in [false, true] {
                let paths = Simd::available();
                let first = pyramid_with_lane(&y, 1 << 14, hadamard, phase_moments, paths[0], 64);
                for &simd in &paths[1..] {
                    let other = pyramid_with_lane(&y, 1 << 14, hadamard, phase_moments, simd, 64);
                    assert_eq!(first.levels, other.levels, "{simd:?}");
                    assert_eq!(first.stored, other.stored);
                    assert_eq!(first.mean, other.mean);
                }
            }
        }
    }

    /// The rate path against the phase path (deviations, counts, noise types) on data
    /// that takes each branch: the order-0 bound, the exact order-0 pass (white PM), the
    /// orders 2 and 3 from the stored level and from the samples (low-passed), a short
    /// series and one with a remainder after the super-blocks.
    #[test]
    fn rate_analysis_equals_the_phase_path() {
        let factors: Vec<usize> = (0..18).map(|j| 1 << j).collect();
        let cases = [
            ("walk", noisy_rate(100_003, 9.806_65, 0.01, 7), 512),
            ("walk, short lanes", noisy_rate(30_001, 0.0, 0.01, 8), 8),
            ("white PM", white_pm_rate(50_000, 9), 16),
            ("low-passed", low_passed_rate(60_000, 10), 32),
            ("short", noisy_rate(50, 1.0, 0.1, 11), 4),
        ];
        for (label, y, lane_len) in &cases {
            let phase = Phase::from_rate(y.clone());
            for kind in [DeviationKind::Adev, DeviationKind::Hdev] {
                let max_differences = if kind == DeviationKind::Hdev { 3 } else { 2 };
                for simd in Simd::available() {
                    let got =
                        non_overlapping_with_lane(y, kind, &factors, simd, *lane_len).unwrap();
                    let variances = variances_with(kind, &phase, &factors, simd);
                    let alphas = identify_alphas(&phase.points, &factors, max_differences, simd);
                    assert_eq!(got.alphas, alphas, "{label} {kind:?} {simd:?}");
                    assert!(
                        (got.mean - phase.removed_mean).abs() <= 1e-12 * got.mean.abs().max(1.0)
                    );
                    for (j, (a, b)) in got.variances.iter().zip(&variances).enumerate() {
                        match (a, b) {
                            (Some((v, c)), Some((w, d))) => {
                                assert_eq!(c, d, "{label} {kind:?} m={}", factors[j]);
                                assert!(
                                    (v - w).abs() <= 1e-11 * w,
                                    "{label} {kind:?} m={}: {v} {w}",
                                    factors[j]
                                );
                            }
                            (None, None) => {}
                            _ => panic!("{label} {kind:?} m={}: {a:?} vs {b:?}", factors[j]),
                        }
                    }
                }
            }
        }
        // Not every factor defined: the grid's own factors only for other kinds.
        assert!(non_overlapping_from_rate(
            &cases[0].1,
            DeviationKind::Oadev,
            &factors,
            Simd::Portable
        )
        .is_none());
        assert!(non_overlapping_from_rate(
            &cases[0].1,
            DeviationKind::Hdev,
            &[1, 3],
            Simd::Portable
        )
        .is_none());
    }

    #[test]
    fn order0_bound_settles_long_frequency_noise_and_not_white_pm() {
        let walk = noisy_rate(100_000, 0.0, 0.01, 12);
        let fast = pyramid_with_lane(&walk, 1 << 12, true, false, Simd::detected(), 64);
        let exact = pyramid_with_lane(&walk, 1 << 12, true, true, Simd::detected(), 64);
        for j in 0..fast.inner {
            let points = 100_000 / (1 << j) + 1;
            assert!(!fast.exact_phase(j));
            assert!(fast.order0_correlated(j, points), "j={j}");
            // The bound is a true bound: the exact r, normalised as the decision takes it,
            // is at least 1/3.
            let r = exact.levels[j].lag1(exact.delta()).unwrap();
            assert!(r * (points - 1) as f64 / points as f64 >= 1.0 / 3.0);
        }
        let pm = white_pm_rate(100_000, 13);
        let fast = pyramid_with_lane(&pm, 1 << 12, true, false, Simd::detected(), 64);
        assert!(!fast.order0_correlated(0, 100_001));
        let factors: Vec<usize> = (0..10).map(|j| 1 << j).collect();
        assert!(identify(&fast, &pm, &factors, 3, Simd::detected()).is_none());
    }

    /// The sequential definition: every level's block sums (pairwise sums of the level
    /// below, from the samples minus `offset`) pushed one by one.
    fn pushed_levels(rate: &[f64], offset: f64, hadamard: bool, count: usize) -> Vec<LevelSums> {
        let mut values: Vec<f64> = rate.iter().map(|v| v - offset).collect();
        (0..count)
            .map(|j| {
                if j > 0 {
                    values = values.chunks_exact(2).map(|p| p[0] + p[1]).collect();
                }
                let mut level = LevelSums::new(1 << j);
                for &v in &values {
                    if hadamard {
                        level.push::<true>(v);
                    } else {
                        level.push::<false>(v);
                    }
                }
                level
            })
            .collect()
    }

    /// `got` equals `want` (the pushed definition): counts and end values exactly (the
    /// same additions), every sum to 1e-12 of a bound on the sum of its terms' magnitudes,
    /// far below one term of any level here (a dropped or doubled seam term shows).
    fn assert_level_matches(label: &str, got: &LevelSums, want: &LevelSums, phase: bool) {
        assert_eq!(
            (got.m, got.count, got.first, got.last),
            (want.m, want.count, want.first, want.last),
            "{label}"
        );
        let close = |name: &str, g: &CompensatedSum, w: &CompensatedSum, scale: f64| {
            let (g, w) = (g.value(), w.value());
            assert!(
                (g - w).abs() <= 1e-12 * scale,
                "{label}: {name} {g} vs {w} (scale {scale})"
            );
        };
        let squares = want.squares.value();
        // |Δs|² ≤ 2(s² + s'²), |Δ²s|² ≤ 6(s² + s'² + s''²), |s·s'| ≤ (s² + s'²)/2.
        close("deviation", &got.deviation, &want.deviation, 20.0 * squares);
        close("squares", &got.squares, &want.squares, squares);
        close("lag1", &got.lag1, &want.lag1, squares);
        let k = want.count as f64;
        close("phase", &got.phase, &want.phase, (k * squares).sqrt());
        if phase {
            let phase_squares = want.phase_squares.value();
            let spread = (k * phase_squares).sqrt();
            close("phase_sum", &got.phase_sum, &want.phase_sum, spread);
            close(
                "phase_squares",
                &got.phase_squares,
                &want.phase_squares,
                phase_squares,
            );
            close(
                "phase_moment",
                &got.phase_moment,
                &want.phase_moment,
                (k + 1.0) * spread,
            );
        }
    }

    /// Jobs joined at seams against the pushed definition, with seams at every level
    /// boundary up to S (a seam falls between super-blocks, where every level up to S
    /// has a block boundary): one to seven jobs, jobs of a single super-block, one-sample
    /// lanes (level S has one value per lane, so the seam meets a count of 1), tails of
    /// 0, 1, S + 3 and a whole super-block minus one samples, and every level up to m = N
    /// (m = N/4 has four block sums).
    #[test]
    fn jobs_join_to_the_sequential_definition() {
        for lane_len in [1, 2, 4, 16] {
            let width = LANES * lane_len;
            for blocks in [1, 2, 3, 7, 12] {
                for tail in [0, 1, lane_len + 3, width - 1] {
                    let n = blocks * width + tail;
                    let y = noisy_rate(n, 9.806_65, 0.01, (n * 31 + lane_len) as u64);
                    for hadamard in [false, true] {
                        for phase in [false, true] {
                            for jobs in [1, 2, 3, 5, 7] {
                                for simd in Simd::available() {
                                    let p = pyramid_in_jobs(
                                        &y, n, hadamard, phase, simd, lane_len, jobs,
                                    );
                                    let want =
                                        pushed_levels(&y, p.offset, hadamard, p.levels.len());
                                    for (j, (got, want)) in p.levels.iter().zip(&want).enumerate() {
                                        let label = format!(
                                            "lane={lane_len} blocks={blocks} tail={tail} \
                                             hadamard={hadamard} phase={phase} jobs={jobs} \
                                             {simd:?} m={}",
                                            1 << j
                                        );
                                        assert_level_matches(&label, got, want, p.exact_phase(j));
                                    }
                                    let stored: Vec<f64> =
                                        pushed_values(&y, p.offset, p.stored_level);
                                    assert_eq!(p.stored, stored);
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    /// The block sums of level `j` by pairwise sums from the samples minus `offset`.
    fn pushed_values(rate: &[f64], offset: f64, j: usize) -> Vec<f64> {
        let mut values: Vec<f64> = rate.iter().map(|v| v - offset).collect();
        for _ in 0..j {
            values = values.chunks_exact(2).map(|p| p[0] + p[1]).collect();
        }
        values
    }

    /// The job count depends on the length only: one and two threads give the same bits,
    /// and the two-job sums stay within 1e-13 of the one-job (sequential) ones.
    #[test]
    fn one_and_two_threads_give_identical_bits() {
        let lane_len = 64;
        // Two jobs for the analysis's own lane length too.
        let n = JOBS * MIN_JOB_BLOCKS * LANES * LANE_LEN + 777;
        assert_eq!(job_count(n / (LANES * LANE_LEN)), JOBS);
        let y = noisy_rate(n, 9.806_65, 0.001, 21);
        let factors: Vec<usize> = (0..16).map(|j| 1 << j).collect();
        let pool = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
        };
        let (one, two) = (pool(1), pool(2));
        for hadamard in [false, true] {
            for phase in [false, true] {
                let run = |pool: &rayon::ThreadPool| {
                    pool.install(|| {
                        pyramid_with_lane(&y, n, hadamard, phase, Simd::detected(), lane_len)
                    })
                };
                let (a, b) = (run(&one), run(&two));
                assert_eq!(a.levels, b.levels, "hadamard={hadamard} phase={phase}");
                assert_eq!((a.stored, a.mean), (b.stored, b.mean));
                let single = pyramid_in_jobs(&y, n, hadamard, phase, Simd::detected(), lane_len, 1);
                for (p, q) in b.levels.iter().zip(&single.levels) {
                    let (m, p, q) = (p.m, p.deviation_sum(), q.deviation_sum());
                    assert!((p - q).abs() <= 1e-13 * q, "m={m}: {p} vs {q}");
                }
            }
            let kind = if hadamard {
                DeviationKind::Hdev
            } else {
                DeviationKind::Adev
            };
            let analyse = |pool: &rayon::ThreadPool| {
                pool.install(|| {
                    non_overlapping_from_rate(&y, kind, &factors, Simd::detected()).unwrap()
                })
            };
            assert_eq!(analyse(&one), analyse(&two));
        }
    }

    #[test]
    fn one_g_offset_changes_nothing_beyond_1e9() {
        let y = noisy_rate(200_000, 0.0, 0.001, 14);
        let shifted: Vec<f64> = y.iter().map(|v| v + 9.806_65).collect();
        let factors: Vec<usize> = (0..16).map(|j| 1 << j).collect();
        for kind in [DeviationKind::Adev, DeviationKind::Hdev] {
            let a = non_overlapping_from_rate(&y, kind, &factors, Simd::detected()).unwrap();
            let b = non_overlapping_from_rate(&shifted, kind, &factors, Simd::detected()).unwrap();
            assert_eq!(a.alphas, b.alphas);
            for (p, q) in a.variances.iter().zip(&b.variances) {
                let (p, q) = (p.unwrap().0, q.unwrap().0);
                assert!((p - q).abs() <= 1e-9 * p, "{kind:?}: {p} {q}");
            }
        }
    }
}
