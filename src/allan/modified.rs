//! MDEV/TDEV at power-of-two averaging factors through a hierarchy of window sums.
//!
//! With W_m[j] = Σ_{i=j}^{j+m−1} x[i] (x the phase), the MDEV window of factor m is
//! S_j(m) = W_m[j] − 2·W_m[j+m] + W_m[j+2m] (an OADEV-like stencil on W_m), and the next
//! octave's window sums are W_{2m}[j] = W_m[j] + W_m[j+m]. One pass over W_m therefore
//! sums S_j(m)² and overwrites W_m[j] with W_{2m}[j] in ascending j (position j + m is
//! read before it is overwritten): three loads, one store and four floating-point
//! operations per term (a + c, then − 2b as one FMA, the square added as one FMA,
//! W_2m), every W a pairwise sum of phase points (no running sum, so no drift). Σ S² for
//! all octave factors m = 1, 2, 4, … costs one such pass per factor.
//!
//! Done over the whole phase, each pass would stream 26 MB in and out for 6 h at 150 Hz
//! (≈ 1 GB of traffic for 20 factors). Instead, two phases:
//! - **tiles** (m < [`M`]): the phase is cut into tiles of [`T`] positions plus a halo
//!   of 3M/2 points (the dependency cone of the highest small factor); the pass of m = 1
//!   reads the phase and writes W_2 into an L2-resident scratch, where the other small
//!   factors are passed in turn;
//! - **columns** (m ≥ M): with j = q·M + r, the column r of W_M, V_r[q] = W_M[q·M + r],
//!   holds everything the large factors need: W_{M·2^s}[q·M + r] is a sum of 2^s
//!   consecutive V_r, so the same hierarchy runs on each column with strides 1, 2, 4, …
//!   in rows. [`B`] neighbouring columns form a block of rows (four cache lines per row,
//!   vector loops over the lanes), ≈ 800 KB for 6 h that stays in L2 while all large
//!   factors are passed. The blocks are not stored for the whole phase: the tiles keep
//!   W_M only at every eighth column (n/8 values), and a block's row is rebuilt from
//!   those exact starts and the phase itself: W_M[j + l] = W_M[j] + Σ_{i<l} (x[j + M + i]
//!   − x[j + i]) for the seven columns after a start, the differences summed by an
//!   in-register prefix scan (three shift-and-add steps). So building a block reads
//!   256 contiguous bytes of the phase per row (prefetched ahead: the stride of M·8 bytes
//!   is one the hardware prefetchers do not follow), and each lane is at most seven
//!   small slides from an exact pairwise sum.
//!
//! Each term is (a + c − 2b)²; on the SIMD paths c − 2b is one fused multiply-add, which
//! gives the same bits as the portable subtraction (2b is exact, so the single rounding
//! is that of the subtraction), and the square is added to its accumulator by a second
//! one (acc + h², rounded once; `f64::mul_add` on the portable path): two additions and
//! two multiply-adds per term, one pipe pair of each kind on Zen 4. The loops are written once over a small eight-lane
//! vector trait ([`Lanes`]) with portable, AVX2 + FMA and AVX-512F implementations,
//! chosen at run time as for the OADEV sweep ([`SweepPath`]): explicit `std::arch`
//! intrinsics because the auto-vectorised version of these loops spilled its
//! accumulators and scan shuffles to the stack. All paths evaluate the same operations
//! in the same order, so they give the same bits. Tiles and column blocks are
//! independent jobs on the rayon pool; their partial sums are merged in a fixed order,
//! so any number of threads gives the same bits too.
//!
//! Memory: W_M at every eighth column (one f64 per 8 phase points) plus one column
//! block (≈ 800 KB for 6 h at 150 Hz) per job in flight.

use super::lanes::{run_on, LaneJob, Lanes, Portable, LANES};
use super::numerics::{merge_in_order, CompensatedSum, Simd};
use super::sweep::SweepPath;
use rayon::prelude::*;
use std::mem::MaybeUninit;

/// Octave factors handled in tiles: m = 1, 2, …, 2^(SMALL−1).
const SMALL: usize = 10;
/// First factor of the column phase (2^SMALL).
const M: usize = 1 << SMALL;
/// Positions per tile (a multiple of [`M`]); with its halo ≈ 140 KB of scratch.
const T: usize = 16 * 1024;
/// Halo of a tile: the highest small factor M/2 reads up to 3·M/2 − 1 points ahead.
const H: usize = 3 * M / 2;
/// Rows of W_M that one tile contributes to each column block.
const ROWS_PER_TILE: usize = T / M;
/// Lanes (neighbouring columns) per column block: four 64-byte lines per row, so that
/// building a block reads 256 contiguous bytes of the phase per row.
const B: usize = 32;
/// Vectors per row.
const GROUPS: usize = B / LANES;
const _: () = assert!(BLOCKS.is_multiple_of(BLOCK_JOBS) && B.is_multiple_of(LANES));
/// Column blocks.
const BLOCKS: usize = M / B;
/// Values of W_M one tile writes: the first lane of every vector of every column block,
/// for each of its rows.
const TILE_OUT: usize = ROWS_PER_TILE * BLOCKS * GROUPS;
/// Parallel jobs of the column phase, each [`BLOCKS_PER_JOB`] neighbouring blocks.
const BLOCK_JOBS: usize = 4;
const BLOCKS_PER_JOB: usize = BLOCKS / BLOCK_JOBS;
/// Tiles per parallel job.
const TILES_PER_JOB: usize = 8;
/// Rows ahead that [`column_rows`] asks the memory system for: a block reads 256 bytes
/// of every M·8 bytes of the phase, a stride the hardware prefetchers do not follow far
/// enough to hide the latency of main memory.
const PREFETCH_ROWS: usize = 8;

/// One row of a column block, aligned to a cache line.
#[derive(Clone, Copy)]
#[repr(align(64))]
struct Row([f64; B]);

/// Number of MDEV terms at factor `m` on `n` phase points (n + 1 − 3m, or 0).
fn term_count(m: usize, n: usize) -> usize {
    (n + 1).saturating_sub(3 * m)
}

/// Σ_j S_j(m)² (S the MDEV window sum, see the module docs) for every m = 2^k, k <
/// `levels`, on the phase `x`; 0 where a factor has no term.
pub(super) fn octave_window_sums(x: &[f64], levels: usize, simd: Simd) -> Vec<f64> {
    octave_window_sums_on(x, levels, SweepPath::for_simd(simd))
}

/// [`octave_window_sums`] on the given instruction-set path.
fn octave_window_sums_on(x: &[f64], levels: usize, path: SweepPath) -> Vec<f64> {
    let n = x.len();
    // Factors without a single term need no pass.
    let levels = (0..levels)
        .take_while(|&k| term_count(1 << k, n) > 0)
        .count();
    let mut out = vec![0.0; levels];
    if levels == 0 {
        return out;
    }
    let small = levels.min(SMALL);
    let big = levels - small;
    // Tiles cover every term of m = 1 and, when columns follow, every position of W_M.
    let mut span = term_count(1, n);
    if big > 0 {
        span = span.max(n + 1 - M);
    }
    let tiles = span.div_ceil(T);
    let jobs = tiles.div_ceil(TILES_PER_JOB);
    let mut starts: Vec<f64> = Vec::new();
    let tile_sums: Vec<Vec<CompensatedSum>> = if big == 0 {
        (0..jobs)
            .into_par_iter()
            .map(|job| {
                run_on(
                    path,
                    TileJob {
                        x,
                        first_tile: job * TILES_PER_JOB,
                        tiles: TILES_PER_JOB.min(tiles - job * TILES_PER_JOB),
                        small,
                        out: None,
                    },
                )
            })
            .collect()
    } else {
        starts.reserve_exact(tiles * TILE_OUT);
        let spare = &mut starts.spare_capacity_mut()[..tiles * TILE_OUT];
        let sums = spare
            .par_chunks_mut(TILES_PER_JOB * TILE_OUT)
            .enumerate()
            .map(|(job, out)| {
                run_on(
                    path,
                    TileJob {
                        x,
                        first_tile: job * TILES_PER_JOB,
                        tiles: out.len() / TILE_OUT,
                        small,
                        out: Some(out),
                    },
                )
            })
            .collect();
        // SAFETY: every tile wrote all TILE_OUT values of its chunk (`write_starts`
        // writes each one, zero past the end of W_M), and the chunks cover the first
        // tiles·TILE_OUT elements of the reserved capacity.
        unsafe { starts.set_len(tiles * TILE_OUT) };
        sums
    };
    let mut totals = vec![CompensatedSum::new(); levels];
    merge_in_order(&mut totals, tile_sums);
    if big > 0 {
        let block_sums: Vec<Vec<CompensatedSum>> = (0..BLOCK_JOBS)
            .into_par_iter()
            .map(|job| {
                run_on(
                    path,
                    BlockJob {
                        x,
                        starts: &starts,
                        tiles,
                        blocks: job * BLOCKS_PER_JOB..(job + 1) * BLOCKS_PER_JOB,
                        big,
                    },
                )
            })
            .collect();
        merge_in_order(&mut totals[small..], block_sums);
    }
    for (o, total) in out.iter_mut().zip(&totals) {
        *o = total.value();
    }
    out
}

/// Consecutive tiles as one job: their Σ S² per small factor.
struct TileJob<'a> {
    x: &'a [f64],
    first_tile: usize,
    tiles: usize,
    small: usize,
    /// This job's share of W_M at the first lane of every vector of the column blocks
    /// (tiles × [`TILE_OUT`] values), when columns follow.
    out: Option<&'a mut [MaybeUninit<f64>]>,
}

impl LaneJob for TileJob<'_> {
    type Output = Vec<CompensatedSum>;
    #[inline(always)]
    unsafe fn run<V: Lanes>(self) -> Vec<CompensatedSum> {
        let mut sums = vec![CompensatedSum::new(); self.small];
        let mut scratch = Vec::with_capacity(T + H);
        let mut out = self.out;
        for t in 0..self.tiles {
            let tile_out = out
                .as_deref_mut()
                .map(|o| &mut o[t * TILE_OUT..(t + 1) * TILE_OUT]);
            tile::<V>(
                self.x,
                (self.first_tile + t) * T,
                self.small,
                &mut scratch,
                &mut sums,
                tile_out,
            );
        }
        sums
    }
}

/// The small factors over the tile starting at `t0`: Σ S² added to `sums[k]` for m = 2^k,
/// and W_M at the first lane of every vector of every column block written to `out` if
/// given.
#[inline(always)]
unsafe fn tile<V: Lanes>(
    x: &[f64],
    t0: usize,
    small: usize,
    scratch: &mut Vec<f64>,
    sums: &mut [CompensatedSum],
    out: Option<&mut [MaybeUninit<f64>]>,
) {
    let n = x.len();
    let len0 = (T + H).min(n - t0);
    // The first factor reads the phase itself; W_2 and above live in the scratch. A
    // pass reads only positions the previous one wrote (see `need`), so the scratch is
    // sized once and not cleared between tiles.
    if scratch.len() != len0 {
        scratch.resize(len0, 0.0);
    }
    // Positions of W_{2^k} the tile needs, from the top factor down: its own terms
    // (T + 2m) and what the next factor needs (its need + m).
    let mut need = [0usize; SMALL + 1];
    need[small] = if out.is_some() { T } else { 0 };
    for k in (0..small).rev() {
        let m = 1 << k;
        need[k] = (T + 2 * m).max(need[k + 1] + m);
    }
    for k in 0..small {
        let m = 1usize << k;
        // W_m is valid at positions < len0 + 1 − m, W_{2m} at < len0 + 1 − 2m.
        let term_end = T.min(term_count(m, n).saturating_sub(t0));
        let next_end = if k + 1 < small || out.is_some() {
            need[k + 1].min((len0 + 1).saturating_sub(2 * m))
        } else {
            0
        };
        sums[k].add(if k == 0 {
            let src = &x[t0..t0 + len0];
            level_pass_from::<V>(
                src.as_ptr(),
                scratch.as_mut_ptr(),
                len0,
                m,
                term_end,
                next_end,
            )
        } else {
            level_pass::<V>(scratch, m, term_end, next_end)
        });
    }
    if let Some(out) = out {
        write_starts(scratch, (len0 + 1).saturating_sub(M).min(T), out);
    }
}

/// Writes the tile's W_M at the first lane of every vector of every column block (the
/// first `valid` positions of `scratch` are W_M; zero after) into `out` in the layout
/// [block][row][vector].
#[inline(always)]
fn write_starts(scratch: &[f64], valid: usize, out: &mut [MaybeUninit<f64>]) {
    for block in 0..BLOCKS {
        let dst = &mut out[block * ROWS_PER_TILE * GROUPS..(block + 1) * ROWS_PER_TILE * GROUPS];
        for (i, d) in dst.iter_mut().enumerate() {
            let from = (i / GROUPS) * M + block * B + (i % GROUPS) * LANES;
            d.write(if from < valid { scratch[from] } else { 0.0 });
        }
    }
}

/// acc + (a + c − 2b)², the square of one MDEV window sum added by one fused
/// multiply-add, lane by lane.
#[inline(always)]
unsafe fn term<V: Lanes>(acc: V, a: V, b: V, c: V) -> V {
    a.add(c).minus_twice(b).square_add(acc)
}

/// acc + (a + c − 2b)² for one value, as [`term`] computes each lane.
#[inline(always)]
fn term1(acc: f64, a: f64, b: f64, c: f64) -> f64 {
    let h = (a + c) - 2.0 * b;
    h.mul_add(h, acc)
}

/// One factor m over `s` = W_m in place: returns Σ S_j² for j < `term_end` and writes
/// s[j] = W_{2m}[j] = s[j] + s[j + m] for j < `next_end`.
#[inline(always)]
unsafe fn level_pass<V: Lanes>(s: &mut [f64], m: usize, term_end: usize, next_end: usize) -> f64 {
    let len = s.len();
    let p = s.as_mut_ptr();
    level_pass_from::<V>(p, p, len, m, term_end, next_end)
}

/// [`level_pass`] reading W_m from `src` and writing W_{2m} to `dst` (both at least
/// `len` long; the same pointer for the pass in place): the loads of a step all come
/// before its stores, so in place each position j + m is still W_m when it is read.
///
/// Safety: `src` must be readable and `dst` writable for `len` values.
#[inline(always)]
unsafe fn level_pass_from<V: Lanes>(
    src: *const f64,
    dst: *mut f64,
    len: usize,
    m: usize,
    term_end: usize,
    next_end: usize,
) -> f64 {
    // Two vectors per step into two accumulators, so their additions overlap.
    const L: usize = 2 * LANES;
    assert!(
        (term_end == 0 || term_end + 2 * m <= len) && (next_end == 0 || next_end + m <= len),
        "level pass out of range"
    );
    let mut acc = [V::zero(); 2];
    let both = term_end.min(next_end);
    let mut j = 0;
    while j + L <= both {
        let q = src.add(j);
        let (a0, a1) = (V::load(q), V::load(q.add(LANES)));
        let (b0, b1) = (V::load(q.add(m)), V::load(q.add(m + LANES)));
        let (c0, c1) = (V::load(q.add(2 * m)), V::load(q.add(2 * m + LANES)));
        acc[0] = term(acc[0], a0, b0, c0);
        acc[1] = term(acc[1], a1, b1, c1);
        // Stored after all loads: in place, for m < L the loads above read positions
        // of this step that are overwritten here, and must see W_m.
        a0.add(b0).store(dst.add(j));
        a1.add(b1).store(dst.add(j + LANES));
        j += L;
    }
    let mut tail = 0.0;
    while j < both {
        let (a, b) = (*src.add(j), *src.add(j + m));
        tail = term1(tail, a, b, *src.add(j + 2 * m));
        *dst.add(j) = a + b;
        j += 1;
    }
    // Whichever of the two ranges is longer goes on alone.
    let mut i = j;
    while i + L <= term_end {
        let q = src.add(i);
        let (a0, a1) = (V::load(q), V::load(q.add(LANES)));
        let (b0, b1) = (V::load(q.add(m)), V::load(q.add(m + LANES)));
        let (c0, c1) = (V::load(q.add(2 * m)), V::load(q.add(2 * m + LANES)));
        acc[0] = term(acc[0], a0, b0, c0);
        acc[1] = term(acc[1], a1, b1, c1);
        i += L;
    }
    while i < term_end {
        tail = term1(tail, *src.add(i), *src.add(i + m), *src.add(i + 2 * m));
        i += 1;
    }
    let mut i = j;
    while i + L <= next_end {
        let q = src.add(i);
        let (a0, a1) = (V::load(q), V::load(q.add(LANES)));
        let (b0, b1) = (V::load(q.add(m)), V::load(q.add(m + LANES)));
        a0.add(b0).store(dst.add(i));
        a1.add(b1).store(dst.add(i + LANES));
        i += L;
    }
    while i < next_end {
        *dst.add(i) = *src.add(i) + *src.add(i + m);
        i += 1;
    }
    lane_total(acc[0]) + lane_total(acc[1]) + tail
}

/// Sum of the lanes in lane order.
#[inline(always)]
unsafe fn lane_total<V: Lanes>(v: V) -> f64 {
    v.to_array().iter().fold(0.0, |s, x| s + x)
}

/// Column blocks `blocks` through the large factors m = M·2^s, s < `big`: Σ S² per
/// factor.
struct BlockJob<'a> {
    /// The phase.
    x: &'a [f64],
    /// W_M at the first lane of each vector: [tile][block][row of the tile][vector].
    starts: &'a [f64],
    tiles: usize,
    blocks: std::ops::Range<usize>,
    big: usize,
}

impl LaneJob for BlockJob<'_> {
    type Output = Vec<CompensatedSum>;
    #[inline(always)]
    unsafe fn run<V: Lanes>(self) -> Vec<CompensatedSum> {
        let mut sums = vec![CompensatedSum::new(); self.big];
        let total = self.tiles * ROWS_PER_TILE;
        let mut rows: Vec<Row> = Vec::with_capacity(total);
        for block in self.blocks.clone() {
            rows.clear();
            let spare = &mut rows.spare_capacity_mut()[..total];
            for (tile, out) in spare.chunks_exact_mut(ROWS_PER_TILE).enumerate() {
                let at = (tile * BLOCKS + block) * ROWS_PER_TILE * GROUPS;
                column_rows::<V>(
                    self.x,
                    &self.starts[at..at + ROWS_PER_TILE * GROUPS],
                    tile * T + block * B,
                    out,
                );
            }
            // SAFETY: `column_rows` wrote every lane of each of the `total` rows.
            rows.set_len(total);
            column_levels::<V>(&mut rows, block, self.x.len(), &mut sums);
        }
        sums
    }
}

/// Writes the rows V[q][l] = W_M[p + q·M + l] (l < B) for the rows of `starts` to `rows`
/// (W_M[p + q·M + g·8] for each vector g of the row, zero past the end of W_M): each
/// lane slides its vector's first one by single positions, W_M[j + l] = W_M[j] +
/// Σ_{i<l} (x[j + M + i] − x[j + i]), the differences summed by the in-register scan
/// [`Lanes::exclusive_scan`]. Lanes past the end of W_M are 0.
#[inline(always)]
unsafe fn column_rows<V: Lanes>(
    x: &[f64],
    starts: &[f64],
    p: usize,
    rows: &mut [MaybeUninit<Row>],
) {
    let n = x.len();
    let count = starts.len() / GROUPS;
    assert_eq!(rows.len(), count, "one row per start");
    let out = rows.as_mut_ptr().cast::<f64>();
    let mut j = p;
    let mut q = 0;
    // Rows whose B lanes are all valid and readable: j + M + B − 1 ≤ n − 1.
    if q < count && j + M + B - 1 < n {
        let mut lo: [V; GROUPS] = std::array::from_fn(|g| V::load(x[j + g * LANES..].as_ptr()));
        while q < count && j + M + B - 1 < n {
            prefetch(x, j + PREFETCH_ROWS * M);
            let hi: [V; GROUPS] = std::array::from_fn(|g| V::load(x[j + M + g * LANES..].as_ptr()));
            for g in 0..GROUPS {
                let e = hi[g].sub(lo[g]).exclusive_scan();
                V::splat(starts[q * GROUPS + g])
                    .add(e)
                    .store(out.add(q * B + g * LANES));
            }
            lo = hi;
            q += 1;
            j += M;
        }
    }
    // The rest: the same expressions lane by lane, 0 where the window runs past the end.
    while q < count {
        let at = |i: usize| x.get(i).copied().unwrap_or(0.0);
        let mut row = [0.0; B];
        for g in 0..GROUPS {
            let k = j + g * LANES;
            let d: [f64; LANES] = std::array::from_fn(|i| at(k + M + i) - at(k + i));
            let e = Portable(d).exclusive_scan().0;
            let w = starts[q * GROUPS + g];
            for (l, (v, e)) in row[g * LANES..(g + 1) * LANES]
                .iter_mut()
                .zip(e)
                .enumerate()
            {
                if k + l + M <= n {
                    *v = w + e;
                }
            }
        }
        rows[q].write(Row(row));
        q += 1;
        j += M;
    }
}

/// Hints that the cache lines of x[i..i + B] will be read soon (nothing past the end).
#[inline(always)]
fn prefetch(x: &[f64], i: usize) {
    #[cfg(target_arch = "x86_64")]
    if let Some(v) = x.get(i..i + B) {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        // One hint per 64-byte line the B values touch (the last one may start a line).
        for k in (0..B).step_by(LANES).chain([B - 1]) {
            // SAFETY: SSE is part of the x86-64 baseline; a prefetch never faults, and
            // the address lies inside `x`.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(v[k..].as_ptr().cast()) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (x, i);
}

/// The large factors m = M·2^s over one column block's rows (`rows[q]` = W_M at
/// q·M + block·B + lane, destroyed): Σ S² added to `sums[s]`.
#[inline(always)]
unsafe fn column_levels<V: Lanes>(
    rows: &mut [Row],
    block: usize,
    n: usize,
    sums: &mut [CompensatedSum],
) {
    let big = sums.len();
    let total_rows = rows.len();
    let r0 = block * B;
    for (s, sum) in sums.iter_mut().enumerate() {
        let d = 1usize << s;
        let m = M << s;
        let count = term_count(m, n);
        // Rows whose B lanes all carry a term: q·M + r0 + B − 1 < count.
        let full = if count >= r0 + B {
            (count - r0 - B) / M + 1
        } else {
            0
        };
        // W_{2m} is needed only for a further factor.
        let next_rows = if s + 1 < big {
            total_rows.saturating_sub(d)
        } else {
            0
        };
        assert!(
            (full == 0 || full + 2 * d <= total_rows)
                && (next_rows == 0 || next_rows + d <= total_rows),
            "column level out of range"
        );
        let both = full.min(next_rows);
        // The row where the terms end part-way through the lanes (read before any row
        // is overwritten).
        let mut tail = 0.0;
        for l in 0..B {
            if full * M + r0 + l < count {
                tail = term1(
                    tail,
                    rows[full].0[l],
                    rows[full + d].0[l],
                    rows[full + 2 * d].0[l],
                );
            }
        }
        let p = rows.as_mut_ptr().cast::<f64>();
        let load = |q: usize| -> [V; GROUPS] {
            std::array::from_fn(|g| V::load(p.add(q * B + g * LANES)))
        };
        let store = |q: usize, v: [V; GROUPS]| {
            for (g, v) in v.into_iter().enumerate() {
                v.store(p.add(q * B + g * LANES));
            }
        };
        // One accumulator per vector of the row: independent additions.
        let mut acc = [V::zero(); GROUPS];
        for q in 0..both {
            let (a, b, c) = (load(q), load(q + d), load(q + 2 * d));
            for g in 0..GROUPS {
                acc[g] = term(acc[g], a[g], b[g], c[g]);
            }
            store(q, std::array::from_fn(|g| a[g].add(b[g])));
        }
        for q in both..full {
            let (a, b, c) = (load(q), load(q + d), load(q + 2 * d));
            for g in 0..GROUPS {
                acc[g] = term(acc[g], a[g], b[g], c[g]);
            }
        }
        for q in both..next_rows {
            let (a, b) = (load(q), load(q + d));
            store(q, std::array::from_fn(|g| a[g].add(b[g])));
        }
        let mut lanes = 0.0;
        for v in acc {
            lanes += lane_total(v);
        }
        sum.add(lanes + tail);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deviation::modified_sum;
    use crate::numerics::Phase;

    /// Deterministic white plus random-walk rate noise on a large offset.
    fn phase(n: usize, seed: u64) -> Phase {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut walk = 0.0;
        let rate = (0..n)
            .map(|_| {
                let w: f64 = StandardNormal.sample(&mut rng);
                let s: f64 = StandardNormal.sample(&mut rng);
                walk += 0.02 * s;
                9.80665 + w + walk
            })
            .collect();
        Phase::from_rate(rate)
    }

    /// Σ_j S_j(m)² straight from the definition, each window a compensated sum.
    fn direct(x: &[f64], m: usize) -> f64 {
        let mut total = CompensatedSum::new();
        for j in 0..term_count(m, x.len()) {
            let mut window = CompensatedSum::new();
            for i in j..j + m {
                window.add(x[i + 2 * m] - 2.0 * x[i + m] + x[i]);
            }
            total.add(window.value() * window.value());
        }
        total.value()
    }

    fn levels_for(n: usize) -> usize {
        (0..usize::BITS as usize)
            .take_while(|&k| term_count(1 << k, n) > 0)
            .count()
    }

    #[test]
    fn octave_sums_equal_the_definition() {
        // Lengths around the first column factor (3M terms), a full row of a block, the
        // tile (T + H) and the rows a tile contributes, and tiny ones.
        for n in [
            3,
            4,
            5,
            8,
            100,
            3 * M - 1,
            3 * M,
            3 * M + 1,
            3 * M + B + 7,
            4 * M + 13,
            T + H - 1,
            T + H + 1,
            T + 2 * M + B - 1,
        ] {
            let p = phase(n, n as u64);
            let x = &p.points;
            let levels = levels_for(x.len());
            let sums = octave_window_sums(x, levels + 2, Simd::detected());
            assert_eq!(sums.len(), levels, "n={n}");
            for (k, &sum) in sums.iter().enumerate() {
                let want = direct(x, 1 << k);
                assert!(
                    (sum - want).abs() <= 1e-12 * want,
                    "n={n} m={}: {sum:e} vs {want:e}",
                    1 << k
                );
            }
        }
    }

    #[test]
    fn octave_sums_equal_the_sliding_window_over_many_tiles_and_columns() {
        // More than one job of tiles, all column blocks, a partial last row.
        let p = phase(3 * TILES_PER_JOB * T + 12_345, 9);
        let x = &p.points;
        let levels = levels_for(x.len());
        assert!(levels > SMALL + 3, "the column phase runs several factors");
        let sums = octave_window_sums(x, levels, Simd::detected());
        for (k, &sum) in sums.iter().enumerate() {
            let m = 1 << k;
            let want = modified_sum(x, m, term_count(m, x.len()));
            assert!(
                (sum - want).abs() <= 1e-12 * want,
                "m={m}: {sum:e} vs {want:e}"
            );
        }
    }

    #[test]
    fn same_bits_on_every_path_and_thread_count() {
        let p = phase(2 * TILES_PER_JOB * T + 777, 3);
        let x = &p.points;
        let levels = levels_for(x.len());
        let reference = octave_window_sums_on(x, levels, SweepPath::Portable);
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            for path in SweepPath::available() {
                let sums = pool.install(|| octave_window_sums_on(x, levels, path));
                assert_eq!(sums, reference, "{path:?}, {threads} threads");
            }
        }
    }

    /// Runs `f` on the lanes of every path this CPU has (portable first).
    fn on_every_path(f: impl Fn(SweepPath, [f64; LANES]) -> [f64; LANES], d: [f64; LANES]) {
        let want = f(SweepPath::Portable, d);
        for path in SweepPath::available() {
            assert_eq!(f(path, d), want, "{path:?}");
        }
    }

    /// The exclusive scan of `d` on `path`.
    fn scan_on(path: SweepPath, d: [f64; LANES]) -> [f64; LANES] {
        struct Scan([f64; LANES]);
        impl LaneJob for Scan {
            type Output = [f64; LANES];
            unsafe fn run<V: Lanes>(self) -> [f64; LANES] {
                V::load(self.0.as_ptr()).exclusive_scan().to_array()
            }
        }
        run_on(path, Scan(d))
    }

    #[test]
    fn exclusive_scan_is_the_sum_of_the_lanes_below_on_every_path() {
        // Powers of two: every partial sum is exact, so any misplaced lane shows.
        let d: [f64; LANES] = std::array::from_fn(|i| f64::from(1u32 << i));
        for path in SweepPath::available() {
            let e = scan_on(path, d);
            for (l, &e) in e.iter().enumerate() {
                assert_eq!(e, d[..l].iter().sum::<f64>(), "{path:?} lane {l}");
            }
        }
        // Rounding included, the same bits everywhere.
        on_every_path(
            scan_on,
            std::array::from_fn(|i| 0.1 * (i as f64 + 1.0) - 0.37),
        );
    }
}
