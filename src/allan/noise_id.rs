//! Dominant power-law noise type per averaging time from the lag-1 autocorrelation
//! (Riley & Greenhall, "Power law noise identification using the lag 1 autocorrelation",
//! 2004): decimate the phase by m, difference it until the lag-1 autocorrelation says
//! the result is close to white, and read α from the number of differences taken.
//!
//! Cost: only the difference orders the decision reaches are evaluated, two orders per
//! pass: orders 0 and 1 (enough for every noise from white PM to white FM), then 2 and 3
//! only when the first pair still looks correlated. For a whole grid on a long phase
//! ([`identify_alphas`]) orders 0 and 1 of every factor below 32 are summed in one tiled
//! pass over the phase while each tile is in cache, and the larger factors copy their
//! decimation in the same pass ([`identify_alphas_fused`]); otherwise the decimated phase
//! z[k] = x[k·m] comes from the octave pyramid ([`for_each_decimation`]) or a gathered
//! copy. Each pass accumulates shifted sums (Σu, Σu², Σu·u_next with u = w − w₀)
//! in eight vector lanes and removes the mean algebraically afterwards, so one
//! vectorised pass replaces the textbook's mean pass plus product pass.
//!
//! Where fewer than [`MIN_AVERAGES`] averages remain (the last τ of every curve), the
//! lag-1 estimate is not trusted and [`b1_alpha`] decides instead, as Stable32 does: the
//! B1 bias ratio (Barnes; Howe 2000) between the standard and the Allan variance of the
//! averages gives the τ exponent μ of the Allan variance, and for the phase noises
//! (μ = −2) the ratio R(n) of the modified to the Allan variance separates white from
//! flicker PM; with fewer than [`b1_min_averages`] averages the noise type of the next
//! shorter τ is kept. The normalisations and bounds are Stable32's: with them every α of
//! the Stable32 tables in `tests/allan/stable32.rs` is reproduced.

use super::deviation::DeviationKind;
use super::edf::Alpha;
use super::numerics::{dispatch, for_each_decimation, CompensatedSum, Kernel, Simd};

/// Fewest averages (first differences of the decimated phase, ⌊(n − 1)/m⌋) the lag-1
/// estimate is trusted on, Stable32's bound; below it [`b1_alpha`] decides.
pub const MIN_AVERAGES: usize = 30;

/// Estimated noise exponent at averaging factor `m`, or `None` when too few points remain.
///
/// `max_differences` is 2 for Allan-type variances and 3 for Hadamard ones. The returned
/// value is the rounded α (2 white PM … −2 random-walk FM, −3/−4 for Hadamard).
pub fn identify_alpha(phase: &[f64], m: usize, max_differences: u32) -> Option<Alpha> {
    if m == 0 {
        return None;
    }
    identify_alpha_of(
        &Decimated { x: phase, m },
        max_differences,
        Simd::detected(),
    )
}

/// [`identify_alpha`] at every factor of `factors` (ascending): one tiled pass over the
/// phase when it is long enough (see [`identify_alphas_fused`]), otherwise from one octave
/// pyramid of the decimated phase. Both give the same bits.
pub fn identify_alphas(
    phase: &[f64],
    factors: &[usize],
    max_differences: u32,
    simd: Simd,
) -> Vec<Option<Alpha>> {
    identify_alphas_fused(phase, factors, max_differences, simd)
        .unwrap_or_else(|| identify_alphas_by_decimation(phase, factors, max_differences, simd))
}

/// [`identify_alphas`] from [`for_each_decimation`]: every factor reads its own decimated
/// copy of the phase (the path for short phases and for `all`-like grids).
pub fn identify_alphas_by_decimation(
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

/// Phase points per tile of the fused pass: 64 KiB, so a tile and the gathered decimation
/// of it stay in L2 while every small factor reads them.
const TILE: usize = 8192;

/// Factors below this bound get their order-0/1 lag-1 sums accumulated tile by tile
/// ([`PairSums`]); factors from it up collect their decimated phase (at most n/32 points
/// each) during the same pass and are identified from it afterwards.
const ON_THE_FLY_BELOW: usize = 32;

/// Shortest phase the fused pass runs on (below it the per-factor copies are cheap).
const FUSED_MIN_POINTS: usize = 1 << 16;

/// [`identify_alphas`] in one pass over the phase, cut into [`TILE`]s: while a tile is in
/// cache, every factor m < [`ON_THE_FLY_BELOW`] adds the lag-1 sums of orders 0 and 1 of
/// its decimation z[k] = x[k·m] for the terms that start in the tile (m = 1 straight from
/// the phase, the others from a gathered copy of the tile's z values, a few KiB), and
/// every larger factor appends its z values to its own decimated copy (while the copies
/// hold at most n/4 points in all; the factors beyond, in `all`-like grids, are gathered
/// one at a time afterwards). The phase is read from memory once instead of once per
/// factor (plus once per pyramid level).
///
/// The sums are those of [`lag1_pair`] on the gathered z, bit for bit: the same shifts,
/// the same blocks of 4096 terms, the same lane of each term, the same order of
/// additions ([`PairSums`]). Orders 2 and 3 (asked only when orders 0 and 1 still look
/// correlated, rare at small m) gather z from the phase as before.
///
/// `None` when the phase is shorter than [`FUSED_MIN_POINTS`]: the caller takes
/// [`identify_alphas_by_decimation`].
pub fn identify_alphas_fused(
    x: &[f64],
    factors: &[usize],
    max_differences: u32,
    simd: Simd,
) -> Option<Vec<Option<Alpha>>> {
    let n = x.len();
    if n < FUSED_MIN_POINTS {
        return None;
    }
    let mut small: Vec<(usize, PairSums)> = Vec::new();
    let mut large: Vec<(usize, usize, Vec<f64>)> = Vec::new();
    let mut late: Vec<(usize, usize)> = Vec::new();
    let mut copied = 0;
    for (j, &m) in factors.iter().enumerate() {
        if m == 0 {
            continue;
        }
        if m < ON_THE_FLY_BELOW {
            small.push((j, PairSums::new(x, m)));
        } else if copied + n.div_ceil(m) <= n / 4 {
            copied += n.div_ceil(m);
            large.push((j, m, Vec::with_capacity(n.div_ceil(m))));
        } else {
            late.push((j, m));
        }
    }
    run_tiles(x, &mut small, &mut large, FeedPath::fastest(simd));
    let mut alphas = vec![None; factors.len()];
    for (j, sums) in &small {
        let low = sums.finish(x);
        let m = sums.m;
        let mut high: Option<[Option<f64>; 2]> = None;
        alphas[*j] = decide_alpha(n.div_ceil(m), max_differences, |order| {
            let value = if order < 2 {
                low[order]
            } else {
                // Orders 2 and 3: the decimated phase, read a block at a time (a copy of it
                // would be as large as the phase itself at m = 1).
                let pair = *high.get_or_insert_with(|| lag1_pair_of(&Decimated { x, m }, 2, simd));
                pair[order - 2]
            };
            value.map_or(Lag1::Undefined, Lag1::Value)
        });
    }
    for (j, _, z) in &large {
        alphas[*j] = identify_alpha_decimated(z, max_differences, simd);
    }
    // Dense grids beyond the copy budget (`all`, dense:N with large N): one gathered copy
    // at a time, as the pyramid path gathers them.
    let mut z = Vec::new();
    for (j, m) in late {
        z.clear();
        z.extend(x.iter().step_by(m));
        alphas[j] = identify_alpha_decimated(&z, max_differences, simd);
    }
    Some(alphas)
}

/// The tile loop of [`identify_alphas_fused`]: feeds every `small` factor's sums and fills
/// every `large` factor's decimated copy (`(index, m, copy)`), one [`TILE`] at a time.
fn run_tiles(
    x: &[f64],
    small: &mut [(usize, PairSums)],
    large: &mut [(usize, usize, Vec<f64>)],
    path: FeedPath,
) {
    let n = x.len();
    let mut buffer = Vec::with_capacity(TILE + 2 * LANES);
    let mut t0 = 0;
    while t0 < n {
        let t1 = (t0 + TILE).min(n);
        for (_, sums) in small.iter_mut() {
            sums.advance(x, t1, &mut buffer, path);
        }
        for (_, m, z) in large.iter_mut() {
            let first = t0.div_ceil(*m) * *m;
            if first < t1 {
                z.extend(x[first..t1].iter().step_by(*m));
            }
        }
        t0 = t1;
    }
}

/// The running sums of [`lag1_orders::<0, 3>`] on z[k] = x[k·m] (orders 0 and 1 of the
/// decimated phase), fed a stretch of terms at a time by the tiled pass of
/// [`identify_alphas_fused`]. Terms k = 0 … bulk − 1 (bulk = len − 2) go into eight lanes
/// (term k into lane k mod 8) within blocks of 4096 terms, each block's lane total and
/// tail compensated into `totals` when the block is complete: exactly the additions of
/// [`bulk_moments`], so the sums are the same bits.
struct PairSums {
    m: usize,
    /// Points of the decimated phase, ⌈n/m⌉ (at least 3: the phase is long).
    len: usize,
    /// Terms of the bulk, `len − 2`.
    bulk: usize,
    /// Next term to add (a multiple of 8 until the last stretch).
    next: usize,
    low_shift: f64,
    high_shift: f64,
    lanes: [[f64; LANES]; 6],
    totals: [CompensatedSum; 6],
}

impl PairSums {
    fn new(x: &[f64], m: usize) -> Self {
        let len = x.len().div_ceil(m);
        debug_assert!(len >= 3, "the fused pass runs on long phases only");
        PairSums {
            m,
            len,
            bulk: len - 2,
            next: 0,
            // The first value of each order, as `lag1_orders` takes them.
            low_shift: x[0],
            high_shift: x[m] - x[0],
            lanes: [[0.0; LANES]; 6],
            totals: [CompensatedSum::new(); 6],
        }
    }

    /// Adds the terms whose first point lies before phase index `t1` (all remaining ones
    /// when `t1` is the end of the phase), cut down to a multiple of 8 terms so the lanes
    /// stay aligned; the rest waits for the next tile.
    fn advance(&mut self, x: &[f64], t1: usize, buffer: &mut Vec<f64>, path: FeedPath) {
        let m = self.m;
        let target = if t1 == x.len() {
            self.bulk
        } else {
            t1.div_ceil(m).min(self.bulk) & !(LANES - 1)
        };
        if target <= self.next {
            return;
        }
        // Terms next … target − 1 read z[next … target + 1]; (target + 1)·m < n.
        let z: &[f64] = if m == 1 {
            &x[self.next..target + 2]
        } else {
            buffer.clear();
            gather(
                &x[self.next * m..=(target + 1) * m],
                m,
                target + 2 - self.next,
                buffer,
            );
            buffer
        };
        path.feed(self, z, target);
    }

    /// Adds terms `next … end − 1`, z[i] being the decimated phase at `next + i`, `W`
    /// lanes at a time (see [`add_chunks`]).
    #[inline(always)]
    fn feed<const W: usize>(&mut self, z: &[f64], end: usize) {
        const BLOCK: usize = 4096;
        let first = self.next;
        let mut k = first;
        while k < end {
            let block_end = ((k / BLOCK + 1) * BLOCK).min(self.bulk);
            let stop = block_end.min(end);
            let full = (stop - k) / LANES;
            let at = k - first;
            add_chunks::<W>(
                &mut self.lanes,
                &z[at..at + full * LANES + 2],
                full,
                self.low_shift,
                self.high_shift,
            );
            k += full * LANES;
            if stop < block_end {
                // `end` is a multiple of 8 here: nothing is left over.
                continue;
            }
            // The block is complete: the terms after its last full chunk (the last block
            // only), then its lane totals and tail into the compensated totals.
            let mut tail = [0.0f64; 6];
            for t in k..block_end {
                let a0 = difference_at(z, t - first, 0) - self.low_shift;
                let a1 = difference_at(z, t - first + 1, 0) - self.low_shift;
                let b0 = difference_at(z, t - first, 1) - self.high_shift;
                let b1 = difference_at(z, t - first + 1, 1) - self.high_shift;
                for (s, v) in tail
                    .iter_mut()
                    .zip([a0, a0 * a0, a0 * a1, b0, b0 * b0, b0 * b1])
                {
                    *s += v;
                }
            }
            for (total, lanes) in self.totals.iter_mut().zip(&self.lanes) {
                total.add(lanes.iter().sum());
            }
            for (total, t) in self.totals.iter_mut().zip(tail) {
                total.add(t);
            }
            self.lanes = [[0.0; LANES]; 6];
            k = block_end;
        }
        self.next = end;
    }

    /// The lag-1 autocorrelations of orders 0 and 1 once every term is in, as
    /// [`lag1_orders`] finishes them (its last two order-0 values and last order-1 value
    /// point by point).
    fn finish(&self, x: &[f64]) -> [Option<f64>; 2] {
        debug_assert_eq!(self.next, self.bulk, "every term fed");
        let (m, len) = (self.m, self.len);
        let z_last = x[(len - 1) * m];
        let z_before = x[(len - 2) * m];
        let totals = self.totals.map(|t| t.value());
        let a0 = z_before - self.low_shift;
        let a1 = z_last - self.low_shift;
        let b0 = (z_last - z_before) - self.high_shift;
        let low = Moments {
            len,
            sum: totals[0] + a0 + a1,
            squares: totals[1] + a0 * a0 + a1 * a1,
            lag1: totals[2] + a0 * a1,
            last: a1,
        };
        let high = Moments {
            len: len - 1,
            sum: totals[3] + b0,
            squares: totals[4] + b0 * b0,
            lag1: totals[5],
            last: b0,
        };
        [low.lag1(), high.lag1()]
    }
}

/// Instruction set of the tiled lag-1 sums ([`PairSums::feed`]), with the lanes each
/// sub-pass keeps in registers: six accumulators of 8 lanes are 6 AVX-512 registers, but
/// 12 of AVX2's 16 (24 of SSE2's 16) before the streams and temporaries, which made the
/// compiler spill them in the loop. So AVX2 runs the eight lanes as two sub-passes of
/// four over the (cache-resident) stretch, the baseline as four of two. Every lane sees
/// the same terms in the same order on every path, so all give the same bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FeedPath {
    Portable,
    Avx2,
    Avx512,
}

impl FeedPath {
    /// The fastest path for `simd` on this CPU (AVX-512F when `simd` allows vector code
    /// and the CPU has it).
    fn fastest(simd: Simd) -> FeedPath {
        match simd {
            Simd::Portable => FeedPath::Portable,
            Simd::Avx2 if FeedPath::has_avx512() => FeedPath::Avx512,
            Simd::Avx2 => FeedPath::Avx2,
        }
    }

    fn has_avx512() -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            if Simd::detected() == Simd::Avx2 && std::arch::is_x86_feature_detected!("avx512f") {
                return true;
            }
        }
        false
    }

    /// Every path this CPU runs, for the tests.
    #[cfg(test)]
    fn available() -> Vec<FeedPath> {
        let mut paths = vec![FeedPath::Portable];
        if Simd::detected() == Simd::Avx2 {
            paths.push(FeedPath::Avx2);
        }
        if FeedPath::has_avx512() {
            paths.push(FeedPath::Avx512);
        }
        paths
    }

    /// [`PairSums::feed`] compiled for this path.
    fn feed(self, sums: &mut PairSums, z: &[f64], end: usize) {
        match self {
            FeedPath::Portable => sums.feed::<2>(z, end),
            FeedPath::Avx2 => dispatch(Simd::Avx2, Feed::<4> { sums, z, end }),
            FeedPath::Avx512 => {
                #[cfg(target_arch = "x86_64")]
                {
                    #[target_feature(enable = "avx512f,avx2,fma")]
                    fn with_avx512(kernel: Feed<'_, 8>) {
                        kernel.run()
                    }
                    if FeedPath::has_avx512() {
                        // SAFETY: the CPU supports AVX-512F (checked at run time just above).
                        return unsafe { with_avx512(Feed::<8> { sums, z, end }) };
                    }
                }
                sums.feed::<8>(z, end)
            }
        }
    }
}

/// Appends the `count` values x[0], x[m], x[2m], … to `out` (`x` ends on the last one).
/// Strides 2 and 4 (octave and decade factors) go through fixed-size chunks, which the
/// compiler turns into vector shuffles instead of a scalar load and store per value.
fn gather(x: &[f64], m: usize, count: usize, out: &mut Vec<f64>) {
    fn fixed<const S: usize>(x: &[f64], count: usize, out: &mut Vec<f64>) {
        let (chunks, rest) = x.as_chunks::<S>();
        let full = chunks.len().min(count);
        out.extend(chunks[..full].iter().map(|c| c[0]));
        out.extend(rest.iter().take(count - full).copied());
    }
    match m {
        2 => fixed::<2>(x, count, out),
        4 => fixed::<4>(x, count, out),
        _ => out.extend(x.iter().step_by(m).take(count)),
    }
    debug_assert_eq!(out.len(), count);
}

/// [`PairSums::feed`] as a [`Kernel`], `W` lanes per sub-pass.
struct Feed<'a, const W: usize> {
    sums: &'a mut PairSums,
    z: &'a [f64],
    end: usize,
}

impl<const W: usize> Kernel for Feed<'_, W> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        self.sums.feed::<W>(self.z, self.end);
    }
}

/// The lane step of [`bulk_moments`] for orders 0 and 1 over `chunks` chunks of eight
/// terms, z holding the chunks' points and the two after them: term i adds
/// a = z[i] − low_shift, a·a, a·a_next, b = (z[i+1] − z[i]) − high_shift, b·b, b·b_next
/// to lane i mod 8, the same operations in the same order as there. The lanes run in
/// sub-passes of `W` (a divisor of 8) over all chunks, so that their accumulators stay in
/// registers; a lane's sum does not depend on `W`.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // one index walks the lane arrays in lock-step
fn add_chunks<const W: usize>(
    acc: &mut [[f64; LANES]; 6],
    z: &[f64],
    chunks: usize,
    low_shift: f64,
    high_shift: f64,
) {
    debug_assert!(LANES.is_multiple_of(W));
    let streams: [&[[f64; LANES]]; 3] = std::array::from_fn(|s| z[s..].as_chunks::<LANES>().0);
    for group in 0..LANES / W {
        let mut local: [[f64; W]; 6] =
            std::array::from_fn(|i| std::array::from_fn(|l| acc[i][group * W + l]));
        for j in 0..chunks {
            let v: [[f64; W]; 3] =
                std::array::from_fn(|s| std::array::from_fn(|l| streams[s][j][group * W + l]));
            for l in 0..W {
                let a0 = v[0][l] - low_shift;
                let a1 = v[1][l] - low_shift;
                let b0 = (v[1][l] - v[0][l]) - high_shift;
                let b1 = (v[2][l] - v[1][l]) - high_shift;
                local[0][l] += a0;
                local[1][l] += a0 * a0;
                local[2][l] += a0 * a1;
                local[3][l] += b0;
                local[4][l] += b0 * b0;
                local[5][l] += b0 * b1;
            }
        }
        for (i, lanes) in local.iter().enumerate() {
            acc[i][group * W..group * W + W].copy_from_slice(lanes);
        }
    }
}

/// [`identify_alpha`] on the already decimated phase `z`.
pub fn identify_alpha_decimated(z: &[f64], max_differences: u32, simd: Simd) -> Option<Alpha> {
    identify_alpha_of(&z, max_differences, simd)
}

/// [`identify_alpha_decimated`] of any [`Series`].
fn identify_alpha_of<S: Series>(z: &S, max_differences: u32, simd: Simd) -> Option<Alpha> {
    // Orders are evaluated two per pass, only as far as the decision reaches.
    let mut pair: Option<(usize, [Option<f64>; 2])> = None;
    decide_alpha(z.len(), max_differences, |order| {
        let d = order & !1;
        let values = match pair {
            Some((held, values)) if held == d => values,
            _ => {
                let values = lag1_pair_of(z, d, simd);
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
    /// Proven to be at least 1/3 after the normalisation of [`decide_alpha`] (δ ≥ 0.25)
    /// without its value: take the next order. Only valid below `max_differences`.
    Correlated,
}

/// The noise exponent from the lag-1 autocorrelations of the difference orders 0, 1, …
/// of a decimated phase of `points` points (`lag1(d)` is asked in ascending order and
/// only as far as the decision goes): the first order d whose δ = r/(1 + r) is below
/// 0.25, or the last allowed one, gives α = 2 − round(2δ) − 2d. `None` (the caller
/// takes [`b1_alpha`]) when the phase has fewer than [`MIN_AVERAGES`] + 1 points.
///
/// `lag1(d)` is the textbook r (autocovariance and variance sums over the same series);
/// the decision takes r·(L − 1)/L, L = points − d values, which is Stable32's
/// normalisation (the lag-1 autocovariance over L, the variance over L − 1): with it
/// every α of the Stable32 tables in the lag-1 range is reproduced, without it two
/// OCXO factors per table fall on the other side of δ = −0.25.
pub fn decide_alpha(
    points: usize,
    max_differences: u32,
    mut lag1: impl FnMut(usize) -> Lag1,
) -> Option<Alpha> {
    let levels = if points > MIN_AVERAGES {
        max_differences.min(MAX_LEVEL as u32) as usize + 1
    } else {
        0
    };
    for order in 0..levels {
        let last = order as u32 >= max_differences;
        let values = points - order;
        let r1 = match lag1(order) {
            Lag1::Value(r1) => r1 * (values - 1) as f64 / values as f64,
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
    // Too few points for the lag-1 method.
    None
}

/// Noise exponent at averaging factor `m` from the B1 bias ratio and R(n), for the τ
/// where the lag-1 method has too few averages (Stable32's method, NIST SP 1065 §5.6).
///
/// `averages` are the ⌊(n − 1)/m⌋ non-overlapping averages of the rate at `m` (any
/// scale); `terms` is the number of terms of the `kind` estimate at `m` (the "#" column
/// of Stable32's tables), the N of the expected ratios, as in Stable32: for ADEV it is
/// the averages less one, for the overlapping estimators far more. `modified_variance`
/// gives the modified Allan variance at `m` in the units of `averages` squared (asked only
/// when B1 points at a phase noise). Hadamard kinds also allow α = −3.
///
/// `None` with fewer than [`b1_min_averages`] averages: there the caller keeps the noise
/// type of the next shorter τ, as Stable32 does.
pub fn b1_alpha(
    averages: &[f64],
    m: usize,
    terms: usize,
    kind: DeviationKind,
    modified_variance: impl FnOnce() -> Option<f64>,
) -> Option<Alpha> {
    let count = averages.len();
    if count < b1_min_averages(kind).max(2) || terms < 2 {
        return None;
    }
    let n = count as f64;
    let mean = averages.iter().sum::<f64>() / n;
    let standard = averages.iter().map(|y| (y - mean).powi(2)).sum::<f64>() / (n - 1.0);
    let allan = averages
        .windows(2)
        .map(|w| (w[1] - w[0]).powi(2))
        .sum::<f64>()
        / (2.0 * (n - 1.0));
    if !(allan > 0.0 && standard.is_finite()) {
        return None;
    }
    let ratio = standard / allan;
    // μ from −2 (phase noises) up; α = −μ − 1 for μ ≥ −1. The boundary between two
    // neighbouring μ is the geometric mean of their expected ratios.
    let highest_mu = match kind {
        DeviationKind::Hdev | DeviationKind::Ohdev => 2,
        _ => 1,
    };
    let mut mu = -2;
    while mu < highest_mu {
        let boundary = (b1_expected(terms, mu) * b1_expected(terms, mu + 1)).sqrt();
        if ratio <= boundary {
            break;
        }
        mu += 1;
    }
    if mu > -2 {
        return Some(-mu - 1);
    }
    // White or flicker PM: R(n) = Mod σ²/σ², 1/n for white PM and about
    // 3 ln(256/27)/(2(1.038 + 3 ln(πn))) for flicker PM (IEEE 1139, f_h = 1/(2τ0)).
    let modified = modified_variance()?;
    let r = modified / allan;
    let white = 1.0 / m as f64;
    let flicker = 3.0 * (256.0f64 / 27.0).ln()
        / (2.0 * (1.038 + 3.0 * (std::f64::consts::PI * m as f64).ln()));
    Some(if r <= (white * flicker).sqrt() { 2 } else { 1 })
}

/// Fewest averages the B1 ratio decides on: 10 for the non-overlapping ADEV and HDEV, 8
/// for the overlapping estimators. These are Stable32's bounds as its tables show them
/// (PHASE.DAT and the OCXO set, every τ): one average fewer or more on either side
/// changes rows of the tables.
pub fn b1_min_averages(kind: DeviationKind) -> usize {
    match kind {
        DeviationKind::Adev | DeviationKind::Hdev => 10,
        _ => 8,
    }
}

/// Expected B1 ratio of `n` terms for an Allan variance ∝ τ^μ (Barnes):
/// n(1 − n^μ) / (2(n − 1)(1 − 2^μ)), with its limit n·ln n / (2(n − 1)·ln 2) at μ = 0.
fn b1_expected(n: usize, mu: i32) -> f64 {
    let n = n as f64;
    if mu == 0 {
        n * n.ln() / (2.0 * (n - 1.0) * std::f64::consts::LN_2)
    } else {
        let mu = mu as f64;
        n * (1.0 - n.powf(mu)) / (2.0 * (n - 1.0) * (1.0 - 2f64.powf(mu)))
    }
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
    lag1_pair_of(&z, d, simd)
}

/// [`lag1_pair`] of any [`Series`]: the same sums, bit for bit, whether the series is a slice
/// or read a block at a time.
fn lag1_pair_of<S: Series>(z: &S, d: usize, simd: Simd) -> [Option<f64>; 2] {
    debug_assert!(d <= 2, "difference orders 0 to 3");
    // Monomorphised per pair so the difference cascade lives in registers.
    match d {
        0 => dispatch(simd, Lag1Orders::<S, 0, 3>(z)),
        1 => dispatch(simd, Lag1Orders::<S, 1, 4>(z)),
        _ => dispatch(simd, Lag1Orders::<S, 2, 5>(z)),
    }
}

/// A series the lag-1 sums read window by window: a slice lends its windows, a decimated
/// phase gathers each into a buffer.
trait Series {
    fn len(&self) -> usize;
    /// Values `start .. start + len` (within the series).
    fn window<'a>(&'a self, start: usize, len: usize, buf: &'a mut Vec<f64>) -> &'a [f64];
}

impl Series for &[f64] {
    fn len(&self) -> usize {
        <[f64]>::len(self)
    }
    fn window<'a>(&'a self, start: usize, len: usize, _: &'a mut Vec<f64>) -> &'a [f64] {
        &self[start..start + len]
    }
}

/// Every `m`-th value of `x` from the first: the phase decimated by m, never copied whole.
struct Decimated<'a> {
    x: &'a [f64],
    m: usize,
}

impl Series for Decimated<'_> {
    fn len(&self) -> usize {
        self.x.len().div_ceil(self.m)
    }
    fn window<'a>(&'a self, start: usize, len: usize, buf: &'a mut Vec<f64>) -> &'a [f64] {
        buf.clear();
        buf.extend(self.x[start * self.m..].iter().step_by(self.m).take(len));
        buf
    }
}

/// [`lag1_orders`] as a [`Kernel`].
struct Lag1Orders<'a, S, const D: usize, const K: usize>(&'a S);

impl<S: Series, const D: usize, const K: usize> Kernel for Lag1Orders<'_, S, D, K> {
    type Output = [Option<f64>; 2];
    #[inline(always)]
    fn run(self) -> [Option<f64>; 2] {
        lag1_orders::<S, D, K>(self.0)
    }
}

/// Σa, Σa², Σa_k·a_{k+1}, Σb, Σb², Σb_k·b_{k+1} over k < `bulk`, with a_k the difference
/// of order `D` of `z` at k minus `low_shift` and b_k that of order D + 1 minus
/// `high_shift`: [`LANES`] lanes as arrays (struct of arrays, so every step is a plain
/// vector operation), plain sums within blocks of 4096, compensated across blocks.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // one index walks the lane arrays in lock-step
fn bulk_moments<S: Series, const D: usize, const K: usize>(
    series: &S,
    bulk: usize,
    low_shift: f64,
    high_shift: f64,
) -> [f64; 6] {
    const BLOCK: usize = 4096;
    let mut totals = [CompensatedSum::new(); 6];
    let mut buf = Vec::new();
    let mut start = 0;
    while start < bulk {
        let end = (start + BLOCK).min(bulk);
        // This block's values and the K − 1 after them; indices below are from `start`.
        let z = series.window(start, end - start + K - 1, &mut buf);
        let chunks: [&[[f64; LANES]]; K] =
            std::array::from_fn(|s| z[s..end - start + s].as_chunks::<LANES>().0);
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
        for k in full * LANES..end - start {
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
fn lag1_orders<S: Series, const D: usize, const K: usize>(series: &S) -> [Option<f64>; 2] {
    let len = series.len();
    if len <= D {
        return [None, None];
    }
    let mut buf = Vec::new();
    if len < K {
        // Too short for the pair: order D alone, point by point.
        let z = series.window(0, len, &mut buf);
        // Shift: the first value of the order, so u_0 = 0 exactly.
        let low_shift = difference_at(z, 0, D);
        let mut low = Moments::default();
        for k in 0..len - D {
            low.add(difference_at(z, k, D) - low_shift);
        }
        return [low.lag1(), None];
    }
    // Shifts: the first value of each order, so u_0 = 0 exactly.
    let head = series.window(0, D + 2, &mut buf);
    let (low_shift, high_shift) = (difference_at(head, 0, D), difference_at(head, 0, D + 1));
    // Bulk, k = 0 … len − D − 3: order D at k (a_k, and its lag-1 product a_k·a_{k+1})
    // and order D + 1 at k (b_k and b_k·b_{k+1}), from z[k … k + D + 2].
    let bulk = len - K + 1;
    let [s_low, q_low, l_low, s_high, q_high, l_high] =
        bulk_moments::<S, D, K>(series, bulk, low_shift, high_shift);
    // Order D has len − D values: its last two (k = len − D − 2, len − D − 1) and their
    // product are left. Order D + 1 has len − D − 1: its last value (k = len − D − 2) is
    // left, its products are all in the bulk. They read z[len − D − 2 …], the last D + 2.
    let tail = series.window(len - D - 2, D + 2, &mut buf);
    let a0 = difference_at(tail, 0, D) - low_shift;
    let a1 = difference_at(tail, 1, D) - low_shift;
    let b0 = difference_at(tail, 0, D + 1) - high_shift;
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

    /// Phase of a simulated IMU rate: white rate noise, rate random walk and white phase
    /// noise with weights varied by the seed (so the noise type changes at different τ),
    /// on a large constant offset, built as the analysis builds it.
    fn imu_phase(n: usize, seed: u64) -> Vec<f64> {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut normal = move || -> f64 { StandardNormal.sample(&mut rng) };
        let white_fm = [1e-3, 2e-3, 5e-4][seed as usize % 3];
        let walk = [0.0, 2e-6, 5e-5, 1e-4][seed as usize % 4];
        let white_pm = [0.0, 0.0, 3e-3, 1e-2, 5e-2][seed as usize % 5];
        let mut drift = 0.0;
        let mut previous = 0.0;
        let rate: Vec<f64> = (0..n)
            .map(|_| {
                drift += walk * normal();
                let pm = white_pm * normal();
                let y = 9.80665 + white_fm * normal() + drift + pm - previous;
                previous = pm;
                y
            })
            .collect();
        crate::numerics::Phase::from_rate(rate).points
    }

    #[test]
    fn fused_sums_equal_the_gathered_pair_bit_for_bit() {
        for (n, seed) in [(FUSED_MIN_POINTS, 7), (3 * TILE + 4_101, 8), (100_003, 9)] {
            let x = imu_phase(n, seed);
            for path in FeedPath::available() {
                let mut small: Vec<(usize, PairSums)> = (1..ON_THE_FLY_BELOW)
                    .map(|m| (m, PairSums::new(&x, m)))
                    .collect();
                let mut large = vec![(0, 40, Vec::new()), (1, 97, Vec::new())];
                run_tiles(&x, &mut small, &mut large, path);
                for (m, sums) in &small {
                    let z: Vec<f64> = x.iter().step_by(*m).copied().collect();
                    let want = lag1_pair(&z, 0, Simd::Portable);
                    let got = sums.finish(&x);
                    for order in 0..2 {
                        assert_eq!(
                            got[order].map(f64::to_bits),
                            want[order].map(f64::to_bits),
                            "n={n} m={m} order {order} {path:?}: {got:?} vs {want:?}"
                        );
                    }
                }
                for (_, m, copy) in &large {
                    let z: Vec<f64> = x.iter().step_by(*m).copied().collect();
                    assert_eq!(copy, &z, "n={n} m={m}");
                }
            }
        }
    }

    #[test]
    fn fused_alphas_equal_the_per_factor_alphas_on_simulated_imu_series() {
        use crate::deviation::DeviationKind;
        use crate::taus::TauGrid;
        let grids = [
            TauGrid::Octave,
            TauGrid::Decade,
            TauGrid::Dense(10),
            TauGrid::Dense(40),
            TauGrid::List(vec![0.03, 0.05, 0.07, 1.1, 13.0]),
        ];
        let mut changes = 0;
        for seed in 0..20u64 {
            let n = FUSED_MIN_POINTS + 977 * seed as usize;
            let x = imu_phase(n, seed);
            for grid in &grids {
                for (kind, differences) in [(DeviationKind::Oadev, 2), (DeviationKind::Ohdev, 3)] {
                    let factors = grid.factors(kind, x.len(), 0.01);
                    let want =
                        identify_alphas_by_decimation(&x, &factors, differences, Simd::Portable);
                    for simd in Simd::available() {
                        let got = identify_alphas_fused(&x, &factors, differences, simd)
                            .expect("the fused pass runs on this length");
                        assert_eq!(got, want, "seed {seed} {grid:?} {kind:?} {simd:?}");
                    }
                    changes += want.windows(2).filter(|w| w[0] != w[1]).count();
                }
            }
        }
        // The series must exercise the decision, not only one noise type.
        assert!(changes > 50, "{changes} changes of α along the grids");
    }

    #[test]
    fn fused_pass_declines_short_phases_and_gathers_beyond_its_copy_budget() {
        let x = imu_phase(FUSED_MIN_POINTS, 3);
        let short = &x[..FUSED_MIN_POINTS - 1];
        assert!(identify_alphas_fused(short, &[1, 2], 2, Simd::Portable).is_none());
        // Σ n/m over these factors is about n, four times the copy budget.
        let many: Vec<usize> = [0, 1, 5]
            .into_iter()
            .chain((32..x.len() / 4).step_by(7))
            .collect();
        assert_eq!(
            identify_alphas_fused(&x, &many, 3, Simd::detected()),
            Some(identify_alphas_by_decimation(&x, &many, 3, Simd::Portable))
        );
    }

    /// The decimated phase read a block at a time gives the gathered copy's sums bit for
    /// bit: across several of the kernel's 4096-value blocks, on both sides of the kernel's
    /// shortest input, on every path.
    #[test]
    fn decimated_lag1_equals_the_gathered_copy() {
        let walk = integrate(&white(20_011, 9));
        for len in [3, 4, 5, 6, 7, 1_000, 20_011] {
            let x = &walk[..len];
            for m in [1, 2, 3, 5, 31] {
                let z: Vec<f64> = x.iter().step_by(m).copied().collect();
                for d in 0..=2 {
                    for simd in [Simd::Portable, Simd::detected()] {
                        assert_eq!(
                            lag1_pair_of(&Decimated { x, m }, d, simd),
                            lag1_pair(&z, d, simd),
                            "len {len}, m {m}, d {d}, {simd:?}"
                        );
                    }
                }
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
