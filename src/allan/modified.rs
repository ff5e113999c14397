//! MDEV/TDEV at power-of-two averaging factors through a hierarchy of window sums.
//!
//! With W_m[j] = Σ_{i=j}^{j+m−1} x[i] (x the phase), the MDEV window of factor m is
//! S_j(m) = W_m[j] − 2·W_m[j+m] + W_m[j+2m] (an OADEV-like stencil on W_m), and the next
//! octave's window sums are W_{2m}[j] = W_m[j] + W_m[j+m]. One pass over W_m therefore
//! sums S_j(m)² and overwrites W_m[j] with W_{2m}[j] in ascending j (position j + m is
//! read before it is overwritten): three loads, one store and four additions per term,
//! every W a pairwise sum of phase points (no running sum, so no drift). Σ S² for all
//! octave factors m = 1, 2, 4, … costs one such pass per factor.
//!
//! Done over the whole phase, each pass would stream 26 MB in and out for 6 h at 150 Hz
//! (≈ 1 GB of traffic for 20 factors). Instead, two phases:
//! - **tiles** (m < [`M`]): the phase is cut into tiles of [`T`] positions; each tile is
//!   copied with a halo of 3M/2 points (the dependency cone of the highest small factor)
//!   into an L2-resident scratch where all small factors are passed in turn;
//! - **columns** (m ≥ M): with j = q·M + r, the column r of W_M, V_r[q] = W_M[q·M + r],
//!   holds everything the large factors need: W_{M·2^s}[q·M + r] is a sum of 2^s
//!   consecutive V_r, so the same hierarchy runs on each column with strides 1, 2, 4, …
//!   in rows. [`B`] neighbouring columns form a block of rows of B lanes (one cache line,
//!   a vector loop over lanes), a few hundred KB that stays in L2 while all large factors
//!   are passed. The blocks are not stored for the whole phase: the tiles write W_M only
//!   at the first block of each of [`CHAINS`] chains of blocks, and each next block of a
//!   chain slides the previous one by B positions, W_M[j + B] = W_M[j] + W_B[j + M] −
//!   W_B[j], with B-point window sums of the phase (a few roundings of |W_M| per step, at
//!   most B·(blocks per chain − 1) positions from an exact start).
//!
//! Each term is evaluated as (S/2)² = (½(a + c) − b)², then × 4: the scaling by powers of
//! two is exact, so this equals (a + c − 2b)² bit for bit, with one addition fewer (LLVM
//! turns 2b into b + b). Tiles and chains are independent jobs on the rayon pool; their
//! partial sums are merged in a fixed order, so any number of threads gives the same
//! bits, and the loops run through [`dispatch`] (portable and AVX2 paths, same bits: no
//! FMA).
//!
//! Memory: W_M at the chains' first blocks, one f64 per M/(B·CHAINS) = 8 phase points,
//! plus two column blocks (≈ 1.6 MB for 6 h at 150 Hz) per chain in flight.

use super::numerics::{dispatch, merge_in_order, CompensatedSum, Kernel, Simd};
use rayon::prelude::*;
use std::mem::MaybeUninit;

/// Octave factors handled in tiles: m = 1, 2, …, 2^(SMALL−1).
const SMALL: usize = 8;
/// First factor of the column phase (2^SMALL).
const M: usize = 1 << SMALL;
/// Positions per tile (a multiple of [`M`]); with its halo ≈ 68 KB of scratch.
const T: usize = 8 * 1024;
/// Halo of a tile: the highest small factor M/2 reads up to 3·M/2 − 1 points ahead.
const H: usize = 3 * M / 2;
/// Rows of W_M that one tile contributes to each column block.
const ROWS_PER_TILE: usize = T / M;
/// Lanes (neighbouring columns) per column block: one 64-byte row ([`window_sums`]
/// is written for 8).
const B: usize = 8;
const _: () = assert!(B == 8 && BLOCKS.is_multiple_of(CHAINS));
/// Column blocks.
const BLOCKS: usize = M / B;
/// Chains of neighbouring column blocks: the first block of a chain starts from W_M as
/// the tiles computed it, each next one slides the previous by B positions.
const CHAINS: usize = 4;
/// Column blocks per chain.
const BLOCKS_PER_CHAIN: usize = BLOCKS / CHAINS;
/// Values of W_M one tile writes: the first block of every chain, for each of its rows.
const TILE_OUT: usize = ROWS_PER_TILE * CHAINS * B;
/// Tiles per parallel job.
const TILES_PER_JOB: usize = 16;

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
    let mut columns: Vec<f64> = Vec::new();
    let tile_sums: Vec<Vec<CompensatedSum>> = if big == 0 {
        (0..jobs)
            .into_par_iter()
            .map(|job| {
                dispatch(
                    simd,
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
        columns.reserve_exact(tiles * TILE_OUT);
        let spare = &mut columns.spare_capacity_mut()[..tiles * TILE_OUT];
        let sums = spare
            .par_chunks_mut(TILES_PER_JOB * TILE_OUT)
            .enumerate()
            .map(|(job, out)| {
                dispatch(
                    simd,
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
        // SAFETY: every tile wrote all TILE_OUT values of its chunk (`write_columns`
        // writes each one, zero past the end of W_M), and the chunks cover the first
        // tiles·TILE_OUT elements of the reserved capacity.
        unsafe { columns.set_len(tiles * TILE_OUT) };
        sums
    };
    let mut totals = vec![CompensatedSum::new(); levels];
    merge_in_order(&mut totals, tile_sums);
    if big > 0 {
        let chain_sums: Vec<Vec<CompensatedSum>> = (0..CHAINS)
            .into_par_iter()
            .map(|chain| {
                dispatch(
                    simd,
                    ChainJob {
                        x,
                        columns: &columns,
                        tiles,
                        chain,
                        big,
                    },
                )
            })
            .collect();
        merge_in_order(&mut totals[small..], chain_sums);
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
    /// This job's share of the transposed W_M (tiles × T values), when columns follow.
    out: Option<&'a mut [MaybeUninit<f64>]>,
}

impl Kernel for TileJob<'_> {
    type Output = Vec<CompensatedSum>;
    #[inline(always)]
    fn run(self) -> Vec<CompensatedSum> {
        let mut sums = vec![CompensatedSum::new(); self.small];
        let mut scratch = Vec::with_capacity(T + H);
        let mut out = self.out;
        for t in 0..self.tiles {
            let tile_out = out
                .as_deref_mut()
                .map(|o| &mut o[t * TILE_OUT..(t + 1) * TILE_OUT]);
            tile(
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
/// and W_M of the tile's positions written to `out` (row-major per column block) if given.
#[inline(always)]
fn tile(
    x: &[f64],
    t0: usize,
    small: usize,
    scratch: &mut Vec<f64>,
    sums: &mut [CompensatedSum],
    out: Option<&mut [MaybeUninit<f64>]>,
) {
    let n = x.len();
    let len0 = (T + H).min(n - t0);
    scratch.clear();
    scratch.extend_from_slice(&x[t0..t0 + len0]);
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
        sums[k].add(level_pass(scratch, m, term_end, next_end));
    }
    if let Some(out) = out {
        write_columns(scratch, (len0 + 1).saturating_sub(M).min(T), out);
    }
}

/// Writes the tile's W_M at the lanes of each chain's first column block (the first
/// `valid` positions of `scratch` are W_M, zero after) into `out` in the layout
/// [chain][row][lane].
#[inline(always)]
fn write_columns(scratch: &[f64], valid: usize, out: &mut [MaybeUninit<f64>]) {
    for chain in 0..CHAINS {
        for row in 0..ROWS_PER_TILE {
            let from = row * M + chain * BLOCKS_PER_CHAIN * B;
            let to = (chain * ROWS_PER_TILE + row) * B;
            let dst = &mut out[to..to + B];
            if from + B <= valid {
                for (d, s) in dst.iter_mut().zip(&scratch[from..from + B]) {
                    d.write(*s);
                }
            } else {
                for (l, d) in dst.iter_mut().enumerate() {
                    d.write(if from + l < valid {
                        scratch[from + l]
                    } else {
                        0.0
                    });
                }
            }
        }
    }
}

/// One factor m over `s` = W_m in place: returns Σ S_j² for j < `term_end` and writes
/// s[j] = W_{2m}[j] = s[j] + s[j + m] for j < `next_end`.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // one index walks the three streams in lock-step
fn level_pass(s: &mut [f64], m: usize, term_end: usize, next_end: usize) -> f64 {
    // 16 lanes: four vector accumulators, so the additions into them do not wait on
    // each other's latency.
    const L: usize = 16;
    let mut acc = [0.0f64; L];
    let both = term_end.min(next_end);
    let mut j = 0;
    while j + L <= both {
        let a: [f64; L] = s[j..j + L].try_into().expect("L values");
        let b: [f64; L] = s[j + m..j + m + L].try_into().expect("L values");
        let c: [f64; L] = s[j + 2 * m..j + 2 * m + L].try_into().expect("L values");
        let mut next = [0.0f64; L];
        for i in 0..L {
            let half = 0.5 * (a[i] + c[i]) - b[i];
            acc[i] += half * half;
            next[i] = a[i] + b[i];
        }
        // Stored after all loads: for m < L the loads above read positions of this
        // chunk that are overwritten here, and must see W_m.
        s[j..j + L].copy_from_slice(&next);
        j += L;
    }
    let mut tail = 0.0;
    while j < both {
        let half = 0.5 * (s[j] + s[j + 2 * m]) - s[j + m];
        tail += half * half;
        s[j] += s[j + m];
        j += 1;
    }
    // Whichever of the two ranges is longer goes on alone.
    let mut i = j;
    while i + L <= term_end {
        let a: [f64; L] = s[i..i + L].try_into().expect("L values");
        let b: [f64; L] = s[i + m..i + m + L].try_into().expect("L values");
        let c: [f64; L] = s[i + 2 * m..i + 2 * m + L].try_into().expect("L values");
        for l in 0..L {
            let half = 0.5 * (a[l] + c[l]) - b[l];
            acc[l] += half * half;
        }
        i += L;
    }
    while i < term_end {
        let half = 0.5 * (s[i] + s[i + 2 * m]) - s[i + m];
        tail += half * half;
        i += 1;
    }
    let mut i = j;
    while i + L <= next_end {
        let a: [f64; L] = s[i..i + L].try_into().expect("L values");
        let b: [f64; L] = s[i + m..i + m + L].try_into().expect("L values");
        let mut next = [0.0f64; L];
        for l in 0..L {
            next[l] = a[l] + b[l];
        }
        s[i..i + L].copy_from_slice(&next);
        i += L;
    }
    while i < next_end {
        s[i] += s[i + m];
        i += 1;
    }
    4.0 * (acc.iter().sum::<f64>() + tail)
}

/// One chain of column blocks through the large factors m = M·2^s, s < `big`: Σ S² per
/// factor.
struct ChainJob<'a> {
    /// The phase.
    x: &'a [f64],
    /// W_M at each chain's first column block: [tile][chain][row of the tile][lane].
    columns: &'a [f64],
    tiles: usize,
    chain: usize,
    big: usize,
}

impl Kernel for ChainJob<'_> {
    type Output = Vec<CompensatedSum>;
    #[inline(always)]
    #[allow(clippy::needless_range_loop)] // one index walks the lanes of a row
    fn run(self) -> Vec<CompensatedSum> {
        let ChainJob {
            x,
            columns,
            tiles,
            chain,
            big,
        } = self;
        // V[q][l] = W_M[q·M + block·B + l] for the current block, starting exact.
        let mut column: Vec<Row> = Vec::with_capacity(tiles * ROWS_PER_TILE);
        for tile in 0..tiles {
            let at = (tile * CHAINS + chain) * ROWS_PER_TILE * B;
            let chunk = &columns[at..at + ROWS_PER_TILE * B];
            column.extend(chunk.as_chunks::<B>().0.iter().map(|r| Row(*r)));
        }
        let mut sums = vec![CompensatedSum::new(); big];
        let mut rows: Vec<Row> = Vec::with_capacity(column.len());
        for step in 0..BLOCKS_PER_CHAIN {
            let block = chain * BLOCKS_PER_CHAIN + step;
            if step > 0 {
                // W_M[j + B] = W_M[j] + W_B[j + M] − W_B[j] at j = q·M + (block − 1)·B + l:
                // the previous block's V plus a difference of two B-point window sums
                // of the phase (rows q + 1 and q), so no full-length W_M is stored.
                let from = (block - 1) * B;
                let mut here = window_sums(x, from);
                for (q, v) in column.iter_mut().enumerate() {
                    let next = window_sums(x, (q + 1) * M + from);
                    for l in 0..B {
                        v.0[l] += next[l] - here[l];
                    }
                    here = next;
                }
            }
            rows.clear();
            rows.extend_from_slice(&column);
            column_levels(&mut rows, block, x.len(), &mut sums);
        }
        sums
    }
}

/// The B window sums W_B[p + l] = Σ_{i<B} x[p + l + i] (pairwise, l < B), 0 for windows
/// that run past the end of `x`.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // one index walks the lanes and their windows
fn window_sums(x: &[f64], p: usize) -> [f64; B] {
    let mut out = [0.0; B];
    if p + 2 * B - 1 <= x.len() {
        // One expression per lane over a borrowed slice: vectorised across the lanes
        // (unaligned loads at offsets 0 … 7), the same association as the slow path.
        let w: &[f64; 2 * B - 1] = x[p..p + 2 * B - 1].try_into().expect("2B − 1 values");
        for l in 0..B {
            out[l] = ((w[l] + w[l + 1]) + (w[l + 2] + w[l + 3]))
                + ((w[l + 4] + w[l + 5]) + (w[l + 6] + w[l + 7]));
        }
    } else {
        for (l, o) in out.iter_mut().enumerate() {
            if let Some(w) = x.get(p + l..p + l + B) {
                *o = ((w[0] + w[1]) + (w[2] + w[3])) + ((w[4] + w[5]) + (w[6] + w[7]));
            }
        }
    }
    out
}

/// The large factors m = M·2^s over one column block's rows (`rows[q]` = W_M at
/// q·M + block·B + lane, destroyed): Σ S² added to `sums[s]`.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // one index walks the lanes of three rows
fn column_levels(rows: &mut [Row], block: usize, n: usize, sums: &mut [CompensatedSum]) {
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
        let both = full.min(next_rows);
        // Two rows per step into two accumulators, so their additions overlap.
        let mut acc = [[0.0f64; B]; 2];
        let mut q = 0;
        while q + 2 <= both {
            for u in 0..2 {
                let a = rows[q + u].0;
                let b = rows[q + u + d].0;
                let c = rows[q + u + 2 * d].0;
                let mut next = [0.0; B];
                for l in 0..B {
                    let half = 0.5 * (a[l] + c[l]) - b[l];
                    acc[u][l] += half * half;
                    next[l] = a[l] + b[l];
                }
                rows[q + u].0 = next;
            }
            q += 2;
        }
        while q < both {
            let (a, b, c) = (rows[q].0, rows[q + d].0, rows[q + 2 * d].0);
            for l in 0..B {
                let half = 0.5 * (a[l] + c[l]) - b[l];
                acc[0][l] += half * half;
                rows[q].0[l] = a[l] + b[l];
            }
            q += 1;
        }
        for q in both..full {
            let (a, b, c) = (rows[q].0, rows[q + d].0, rows[q + 2 * d].0);
            for l in 0..B {
                let half = 0.5 * (a[l] + c[l]) - b[l];
                acc[1][l] += half * half;
            }
        }
        // The row where the terms end part-way through the lanes.
        let mut tail = 0.0;
        for l in 0..B {
            if full * M + r0 + l < count {
                let half = 0.5 * (rows[full].0[l] + rows[full + 2 * d].0[l]) - rows[full + d].0[l];
                tail += half * half;
            }
        }
        for q in both..next_rows {
            let b = rows[q + d].0;
            for l in 0..B {
                rows[q].0[l] += b[l];
            }
        }
        let lanes: f64 = acc[0].iter().sum::<f64>() + acc[1].iter().sum::<f64>();
        sum.add(4.0 * (lanes + tail));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::allan::deviation::modified_sum;
    use crate::allan::numerics::Phase;

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
        // Lengths around the tile (T + H), column-block and row boundaries, and tiny ones.
        for n in [
            3,
            4,
            5,
            8,
            100,
            767,
            768,
            769,
            1_000,
            3_001,
            T + H - 1,
            T + H + 1,
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
        let reference = octave_window_sums(x, levels, Simd::Portable);
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            for simd in Simd::available() {
                let sums = pool.install(|| octave_window_sums(x, levels, simd));
                assert_eq!(sums, reference, "{simd:?}, {threads} threads");
            }
        }
    }
}
