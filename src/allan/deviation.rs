//! The Allan-family deviations computed from phase in O(N) per averaging factor:
//! ADEV (non-overlapping), OADEV, MDEV, HDEV, OHDEV, TDEV and TOTDEV, with the
//! conventions of NIST SP 1065 and Stable32 (term counts included).
//!
//! [`variance_at`] evaluates one factor; [`variances`] a whole grid at once, which is how
//! curves are computed:
//! - OADEV and the interior of TOTDEV (whose stencil and term count equal OADEV's) in
//!   **one register-blocked sweep** over the phase for all factors of the grid
//!   ([`super::sweep`]: chains m, 2m, 4m, … share their loads, AVX-512/AVX2/portable
//!   paths with identical bits);
//! - OHDEV in one tiled sweep: the term range is cut into tiles of [`TILE`] terms and
//!   every factor's sum advances over a tile before the next one. The streams x[i + s·m]
//!   of neighbouring octave factors coincide (2m of m is m of 2m), so each tile reads
//!   about 22 distinct stretches of the phase once from memory and the rest from cache,
//!   instead of four full passes per factor. Tile sums are plain eight-lane sums,
//!   compensated across tiles; groups of tiles run on the rayon pool and are merged in a
//!   fixed order, so the result does not depend on the number of threads;
//! - the non-overlapping kinds (ADEV, HDEV) on the decimated phase z[k] = x[k·m], built
//!   as a pyramid (each octave level compacts the previous one in place), where the
//!   terms are contiguous second and third differences;
//! - MDEV/TDEV at power-of-two factors through a hierarchy of window sums, all octaves
//!   in one tiled pass plus one pass per column block ([`super::modified`]); other
//!   factors (and [`variance_at`]) with the sliding-window recurrence, factor by factor.
//!
//! The inner loops are compiled twice (portable and AVX2, [`Simd`]) and give the same
//! bits on both paths.

use super::modified::octave_window_sums;
use super::numerics::{
    blocked_sum, dispatch, for_each_decimation, sum_in_jobs, sum_streams, CompensatedSum, Kernel,
    Phase, Simd,
};
use super::sweep::{second_difference_sums, SweepPath};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Which deviation to compute.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum DeviationKind {
    /// Allan deviation, non-overlapping clusters.
    Adev,
    /// Overlapping Allan deviation.
    Oadev,
    /// Modified Allan deviation.
    Mdev,
    /// Hadamard deviation, non-overlapping.
    Hdev,
    /// Overlapping Hadamard deviation.
    Ohdev,
    /// Time deviation, τ·MDEV/√3 (phase units: input units × seconds).
    Tdev,
    /// Total deviation (doubly reflected, no bias correction).
    Totdev,
}

impl DeviationKind {
    pub const ALL: [DeviationKind; 7] = [
        DeviationKind::Adev,
        DeviationKind::Oadev,
        DeviationKind::Mdev,
        DeviationKind::Hdev,
        DeviationKind::Ohdev,
        DeviationKind::Tdev,
        DeviationKind::Totdev,
    ];

    pub fn name(self) -> &'static str {
        match self {
            DeviationKind::Adev => "adev",
            DeviationKind::Oadev => "oadev",
            DeviationKind::Mdev => "mdev",
            DeviationKind::Hdev => "hdev",
            DeviationKind::Ohdev => "ohdev",
            DeviationKind::Tdev => "tdev",
            DeviationKind::Totdev => "totdev",
        }
    }

    /// Human-readable name for plots and reports.
    pub fn title(self) -> &'static str {
        match self {
            DeviationKind::Adev => "Allan deviation",
            DeviationKind::Oadev => "Overlapping Allan deviation",
            DeviationKind::Mdev => "Modified Allan deviation",
            DeviationKind::Hdev => "Hadamard deviation",
            DeviationKind::Ohdev => "Overlapping Hadamard deviation",
            DeviationKind::Tdev => "Time deviation",
            DeviationKind::Totdev => "Total deviation",
        }
    }

    /// Stable32's stop ratio: octave/decade grids end at `m ≤ phase_points / ratio`.
    pub fn stop_ratio(self) -> usize {
        match self {
            DeviationKind::Adev | DeviationKind::Hdev => 5,
            DeviationKind::Totdev => 2,
            _ => 4,
        }
    }

    /// Whether the result is an Allan-variance-like quantity that the IMU noise model
    /// σ²(τ) applies to (TDEV is in phase units, Hadamard has other coefficients).
    pub fn is_allan_variance(self) -> bool {
        matches!(
            self,
            DeviationKind::Adev | DeviationKind::Oadev | DeviationKind::Totdev
        )
    }

    /// Number of terms averaged at averaging factor `m` from `n` phase points (0 when undefined).
    pub fn term_count(self, m: usize, n: usize) -> usize {
        if m == 0 || n < 2 {
            return 0;
        }
        match self {
            DeviationKind::Adev => ((n - 1) / m).saturating_sub(1),
            DeviationKind::Oadev => n.saturating_sub(2 * m),
            DeviationKind::Mdev | DeviationKind::Tdev => (n + 1).saturating_sub(3 * m),
            DeviationKind::Hdev => ((n - 1) / m).saturating_sub(2),
            DeviationKind::Ohdev => n.saturating_sub(3 * m),
            DeviationKind::Totdev => {
                if m < n - 1 {
                    n - 2
                } else {
                    0
                }
            }
        }
    }
}

/// One deviation value with the number of terms behind it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawPoint {
    pub m: usize,
    pub tau: f64,
    pub deviation: f64,
    pub count: usize,
}

/// Computes `kind` at averaging factor `m` (τ = m·tau0). `None` when no term is defined.
pub fn deviation_at(kind: DeviationKind, phase: &Phase, m: usize, tau0: f64) -> Option<RawPoint> {
    let (variance, count) = variance_at(kind, phase, m)?;
    Some(RawPoint {
        m,
        tau: m as f64 * tau0,
        deviation: deviation_from_variance(kind, variance, m as f64 * tau0),
        count,
    })
}

/// The variance (for TDEV: the MDEV variance) at factor `m` and its number of terms.
/// Variances of several uniform segments pool as Σ variance·count / Σ count.
pub fn variance_at(kind: DeviationKind, phase: &Phase, m: usize) -> Option<(f64, usize)> {
    let x = phase.points.as_slice();
    let n = x.len();
    let count = kind.term_count(m, n);
    if count == 0 {
        return None;
    }
    let mf = m as f64;
    let c = count as f64;
    let variance = match kind {
        DeviationKind::Adev => second_difference_sum(x, m, m, count) / (2.0 * mf * mf * c),
        DeviationKind::Oadev => second_difference_sum(x, m, 1, count) / (2.0 * mf * mf * c),
        DeviationKind::Hdev => third_difference_sum(x, m, m, count) / (6.0 * mf * mf * c),
        DeviationKind::Ohdev => third_difference_sum(x, m, 1, count) / (6.0 * mf * mf * c),
        DeviationKind::Mdev | DeviationKind::Tdev => {
            modified_sum(x, m, count) / (2.0 * mf.powi(4) * c)
        }
        DeviationKind::Totdev => total_sum(x, m) / (2.0 * mf * mf * c),
    };
    Some((variance.max(0.0), count))
}

/// Variances (as [`variance_at`]) at every factor of `factors` (ascending), on the
/// fastest instruction set of this CPU.
pub fn variances(
    kind: DeviationKind,
    phase: &Phase,
    factors: &[usize],
) -> Vec<Option<(f64, usize)>> {
    variances_with(kind, phase, factors, Simd::detected())
}

/// [`variances`] on the given instruction-set path.
pub fn variances_with(
    kind: DeviationKind,
    phase: &Phase,
    factors: &[usize],
    simd: Simd,
) -> Vec<Option<(f64, usize)>> {
    let x = phase.points.as_slice();
    let n = x.len();
    let counts: Vec<usize> = factors.iter().map(|&m| kind.term_count(m, n)).collect();
    let sums: Vec<f64> = match kind {
        DeviationKind::Oadev => {
            second_difference_sums(x, factors, &counts, SweepPath::for_simd(simd))
        }
        DeviationKind::Ohdev => overlapping_sums(x, factors, &counts, simd, third_difference),
        DeviationKind::Totdev => {
            // Interior: the OADEV stencil over i − m … i + m for m ≤ i ≤ n − 1 − m, i.e.
            // OADEV's n − 2m terms; the reflected edges are added per factor.
            let interior: Vec<usize> = factors
                .iter()
                .zip(&counts)
                .map(|(&m, &c)| if c > 0 { n.saturating_sub(2 * m) } else { 0 })
                .collect();
            let inner = second_difference_sums(x, factors, &interior, SweepPath::for_simd(simd));
            factors
                .par_iter()
                .zip(inner)
                .zip(&counts)
                .map(|((&m, inner), &c)| {
                    if c == 0 {
                        0.0
                    } else {
                        let mut total = CompensatedSum::new();
                        total.add(inner);
                        total.add(dispatch(simd, TotalEdges { x, m }));
                        total.value()
                    }
                })
                .collect()
        }
        DeviationKind::Adev | DeviationKind::Hdev => {
            let mut out = vec![None; factors.len()];
            for_each_decimation(x, factors, |j, z| {
                out[j] = decimated_variance(kind, z, factors[j], n, simd);
            });
            return out;
        }
        DeviationKind::Mdev | DeviationKind::Tdev => modified_sums(x, factors, &counts, simd),
    };
    factors
        .iter()
        .zip(counts)
        .zip(sums)
        .map(|((&m, count), sum)| (count > 0).then(|| (normalise(kind, sum, m, count), count)))
        .collect()
}

/// MDEV window sums Σ_j S_j(m)² for every factor of a grid (0 where `counts` is 0): the
/// powers of two through the octave hierarchy of [`super::modified`] when at least a
/// third of the octaves it passes through are in the grid (each octave costs about a
/// third of a sliding-window factor), every other factor with the sliding window.
fn modified_sums(x: &[f64], factors: &[usize], counts: &[usize], simd: Simd) -> Vec<f64> {
    let octaves: Vec<u32> = factors
        .iter()
        .zip(counts)
        .filter(|&(&m, &c)| c > 0 && m.is_power_of_two())
        .map(|(&m, _)| m.trailing_zeros())
        .collect();
    let levels = octaves.iter().max().map_or(0, |&k| k as usize + 1);
    let by_octave = if !octaves.is_empty() && 3 * octaves.len() >= levels {
        octave_window_sums(x, levels, simd)
    } else {
        Vec::new()
    };
    factors
        .par_iter()
        .zip(counts)
        .map(|(&m, &c)| {
            let octave = m.trailing_zeros() as usize;
            if c == 0 {
                0.0
            } else if m.is_power_of_two() && octave < by_octave.len() {
                by_octave[octave]
            } else {
                dispatch(simd, ModifiedSum { x, m, count: c })
            }
        })
        .collect()
}

/// ADEV or HDEV (`kind`) at factor `m` of a phase of `n` points, from its decimation
/// z[k] = x[k·m] (as [`for_each_decimation`] gives it): the variance and count of
/// [`variance_at`], `None` for other kinds or when no term is defined.
pub fn decimated_variance(
    kind: DeviationKind,
    z: &[f64],
    m: usize,
    n: usize,
    simd: Simd,
) -> Option<(f64, usize)> {
    if !matches!(kind, DeviationKind::Adev | DeviationKind::Hdev) || z.len() != n.div_ceil(m.max(1))
    {
        return None;
    }
    let count = kind.term_count(m, n);
    (count > 0).then(|| {
        let sum = dispatch(simd, DecimatedSum { kind, z });
        (normalise(kind, sum, m, count), count)
    })
}

/// The variance from the sum of squared terms (see [`variance_at`]).
pub fn normalise(kind: DeviationKind, sum: f64, m: usize, count: usize) -> f64 {
    let mf = m as f64;
    let c = count as f64;
    let variance = match kind {
        DeviationKind::Adev | DeviationKind::Oadev | DeviationKind::Totdev => {
            sum / (2.0 * mf * mf * c)
        }
        DeviationKind::Hdev | DeviationKind::Ohdev => sum / (6.0 * mf * mf * c),
        DeviationKind::Mdev | DeviationKind::Tdev => sum / (2.0 * mf.powi(4) * c),
    };
    variance.max(0.0)
}

/// Squared second difference c − 2b + a of three stream values.
#[inline(always)]
fn second_difference([a, b, c]: [f64; 3]) -> f64 {
    let d = c - 2.0 * b + a;
    d * d
}

/// Squared third difference d − 3c + 3b − a of four stream values.
#[inline(always)]
fn third_difference([a, b, c, d]: [f64; 4]) -> f64 {
    let v = d - 3.0 * c + 3.0 * b - a;
    v * v
}

/// Terms per tile of the overlapping sweep: 16 KiB per stream, so the ≈ 22 distinct
/// streams of an octave grid (≈ 350 KiB) stay in the 2 MiB L2 while a tile is swept.
pub const TILE: usize = 2048;

/// Tiles per parallel job (and per entry of the fixed-order merge).
const TILES_PER_JOB: usize = 32;

/// Σ_{i < counts[j]} term(x[i], x[i + m], …, x[i + (K−1)m]) for every factor m = factors[j],
/// in one tiled sweep (see the module docs).
fn overlapping_sums<const K: usize>(
    x: &[f64],
    factors: &[usize],
    counts: &[usize],
    simd: Simd,
    term: impl Fn([f64; K]) -> f64 + Copy + Sync,
) -> Vec<f64> {
    let longest = counts.iter().copied().max().unwrap_or(0);
    sum_in_jobs(
        longest,
        TILE * TILES_PER_JOB,
        factors.len(),
        |start, end| {
            dispatch(
                simd,
                SweepTiles::<K, _> {
                    x,
                    factors,
                    counts,
                    start,
                    end,
                    term,
                },
            )
        },
    )
}

/// [`sweep_tiles`] as a [`Kernel`].
struct SweepTiles<'a, const K: usize, T> {
    x: &'a [f64],
    factors: &'a [usize],
    counts: &'a [usize],
    start: usize,
    end: usize,
    term: T,
}

impl<const K: usize, T: Fn([f64; K]) -> f64 + Copy> Kernel for SweepTiles<'_, K, T> {
    type Output = Vec<CompensatedSum>;
    #[inline(always)]
    fn run(self) -> Vec<CompensatedSum> {
        sweep_tiles(
            self.x,
            self.factors,
            self.counts,
            self.start,
            self.end,
            self.term,
        )
    }
}

/// [`total_edges`] as a [`Kernel`].
struct TotalEdges<'a> {
    x: &'a [f64],
    m: usize,
}

impl Kernel for TotalEdges<'_> {
    type Output = f64;
    #[inline(always)]
    fn run(self) -> f64 {
        total_edges(self.x, self.m)
    }
}

/// The ADEV or HDEV sum over the decimated phase `z` (second or third differences of
/// consecutive points), as a [`Kernel`].
struct DecimatedSum<'a> {
    kind: DeviationKind,
    z: &'a [f64],
}

impl Kernel for DecimatedSum<'_> {
    type Output = f64;
    #[inline(always)]
    fn run(self) -> f64 {
        let z = self.z;
        if self.kind == DeviationKind::Adev {
            sum_streams([z, &z[1..], &z[2..]], second_difference)
        } else {
            sum_streams([z, &z[1..], &z[2..], &z[3..]], third_difference)
        }
    }
}

/// [`modified_sum`] as a [`Kernel`].
struct ModifiedSum<'a> {
    x: &'a [f64],
    m: usize,
    count: usize,
}

impl Kernel for ModifiedSum<'_> {
    type Output = f64;
    #[inline(always)]
    fn run(self) -> f64 {
        modified_sum(self.x, self.m, self.count)
    }
}

/// The tiles of terms `start..end` of [`overlapping_sums`], every factor per tile.
#[inline(always)]
fn sweep_tiles<const K: usize>(
    x: &[f64],
    factors: &[usize],
    counts: &[usize],
    start: usize,
    end: usize,
    term: impl Fn([f64; K]) -> f64 + Copy,
) -> Vec<CompensatedSum> {
    let mut sums = vec![CompensatedSum::new(); factors.len()];
    let mut t0 = start;
    while t0 < end {
        let t1 = (t0 + TILE).min(end);
        for ((&m, &count), sum) in factors.iter().zip(counts).zip(sums.iter_mut()) {
            if t0 >= count {
                continue;
            }
            let len = t1.min(count) - t0;
            let streams: [&[f64]; K] = std::array::from_fn(|s| &x[t0 + s * m..t0 + s * m + len]);
            sum.add(sum_streams(streams, term));
        }
        t0 = t1;
    }
    sums
}

/// The reflected edge terms of TOTDEV at factor `m` (1 ≤ i < m and n − m ≤ i ≤ n − 2 of
/// [`total_sum`]), vectorised when one reflection suffices (2m ≤ n − 1, every generated
/// grid), else point by point.
///
/// The reflected values run backwards through the phase; they are copied reversed into a
/// stack buffer one block of [`EDGE_BLOCK`] terms at a time (a heap copy of all m − 1 of
/// them cost fresh pages, i.e. page faults, for every large factor), and each block is
/// one [`sum_streams`] block, compensated across blocks.
#[inline(always)]
fn total_edges(x: &[f64], m: usize) -> f64 {
    let n = x.len();
    let last = n - 1;
    if m < 2 || 2 * m > last {
        return total_edges_pointwise(x, m);
    }
    let mut reversed = [0.0f64; EDGE_BLOCK];
    let mut total = CompensatedSum::new();
    // Leading: i = 1 … m−1, x*[i − m] = 2x[0] − x[m − i].
    let first = 2.0 * x[0];
    let mut i = 1;
    while i < m {
        let len = EDGE_BLOCK.min(m - i);
        for (k, slot) in reversed[..len].iter_mut().enumerate() {
            *slot = x[m - i - k];
        }
        total.add(sum_streams(
            [&reversed[..len], &x[i..i + len], &x[i + m..i + m + len]],
            |[r, b, c]| {
                let d = (first - r) - 2.0 * b + c;
                d * d
            },
        ));
        i += len;
    }
    // Trailing: i = n−m … n−2, x*[i + m] = 2x[last] − x[2·last − i − m].
    let end = 2.0 * x[last];
    let mut i = n - m;
    while i < last {
        let len = EDGE_BLOCK.min(last - i);
        for (k, slot) in reversed[..len].iter_mut().enumerate() {
            *slot = x[2 * last - i - m - k];
        }
        total.add(sum_streams(
            [&x[i - m..i - m + len], &x[i..i + len], &reversed[..len]],
            |[a, b, r]| {
                let d = a - 2.0 * b + (end - r);
                d * d
            },
        ));
        i += len;
    }
    total.value()
}

/// Edge terms per reversed block of [`total_edges`] (sum_streams' own block length, so
/// the result has the same bits as one pass over a reversed copy).
const EDGE_BLOCK: usize = 4096;

/// [`total_edges`] point by point, for any `m < n − 1`.
fn total_edges_pointwise(x: &[f64], m: usize) -> f64 {
    let n = x.len();
    let last = n - 1;
    let extended = |k: isize| -> f64 {
        if k < 0 {
            2.0 * x[0] - x[(-k) as usize]
        } else if (k as usize) > last {
            2.0 * x[last] - x[2 * last - k as usize]
        } else {
            x[k as usize]
        }
    };
    let inner_start = m.max(1);
    let inner_end = (last.saturating_sub(m)).min(n - 2);
    let mi = m as isize;
    let leading_edge_end = inner_start.min(n - 1);
    let trailing_edge_start = (inner_end + 1).max(leading_edge_end);
    let mut total = CompensatedSum::new();
    for i in (1..leading_edge_end).chain(trailing_edge_start..n - 1) {
        let ii = i as isize;
        let d = extended(ii - mi) - 2.0 * x[i] + extended(ii + mi);
        total.add(d * d);
    }
    total.value()
}

/// σ from the variance; TDEV is τ·MDEV/√3.
pub fn deviation_from_variance(kind: DeviationKind, variance: f64, tau: f64) -> f64 {
    let deviation = variance.max(0.0).sqrt();
    if kind == DeviationKind::Tdev {
        deviation * tau / 3f64.sqrt()
    } else {
        deviation
    }
}

/// Σ (x[i+2m] − 2x[i+m] + x[i])² over `count` terms with `i` stepping by `stride`.
fn second_difference_sum(x: &[f64], m: usize, stride: usize, count: usize) -> f64 {
    if stride == 1 {
        let a = &x[..count];
        let b = &x[m..m + count];
        let c = &x[2 * m..2 * m + count];
        sum_streams([a, b, c], |[a, b, c]| {
            let d = c - 2.0 * b + a;
            d * d
        })
    } else {
        blocked_sum(count, |k| {
            let i = k * stride;
            let d = x[i + 2 * m] - 2.0 * x[i + m] + x[i];
            d * d
        })
    }
}

/// Σ (x[i+3m] − 3x[i+2m] + 3x[i+m] − x[i])² over `count` terms with `i` stepping by `stride`.
fn third_difference_sum(x: &[f64], m: usize, stride: usize, count: usize) -> f64 {
    if stride == 1 {
        let a = &x[..count];
        let b = &x[m..m + count];
        let c = &x[2 * m..2 * m + count];
        let d = &x[3 * m..3 * m + count];
        sum_streams([a, b, c, d], |[a, b, c, d]| {
            let v = d - 3.0 * c + 3.0 * b - a;
            v * v
        })
    } else {
        blocked_sum(count, |k| {
            let i = k * stride;
            let v = x[i + 3 * m] - 3.0 * x[i + 2 * m] + 3.0 * x[i + m] - x[i];
            v * v
        })
    }
}

/// Σ_j (Σ_{i=j}^{j+m−1} (x[i+2m] − 2x[i+m] + x[i]))² for `count = n − 3m + 1` values of `j`.
///
/// The inner window sum W_j slides in O(1) per step: W_j − W_{j−1} is the third difference
/// x[k+3m] − 3x[k+2m] + 3x[k+m] − x[k] at k = j − 1, so MDEV costs O(N) per τ. The range
/// of `j` is cut into segments of at least 65 536 steps (and at least `m`, so restarting
/// costs no more than the scan); every segment starts from a window summed from scratch,
/// which bounds the rounding drift of the recurrence to about √65 536 ulps. Four segments
/// are scanned in lock-step so their independent additions overlap in the CPU.
#[inline(always)]
pub(super) fn modified_sum(x: &[f64], m: usize, count: usize) -> f64 {
    modified_sum_in_segments(x, m, count, SEGMENT_STEPS)
}

#[inline(always)]
fn modified_sum_in_segments(x: &[f64], m: usize, count: usize, segment_steps: usize) -> f64 {
    const LANES: usize = 4;
    let segment = segment_steps.max(m).min(count).max(1);
    let full = count / segment;
    let mut total = CompensatedSum::new();
    let mut s = 0;
    while s + LANES <= full {
        let starts = std::array::from_fn(|l| (s + l) * segment);
        total.add(scan_windows::<LANES>(x, m, starts, segment));
        s += LANES;
    }
    while s < full {
        total.add(scan_windows::<1>(x, m, [s * segment], segment));
        s += 1;
    }
    let rest = count - full * segment;
    if rest > 0 {
        total.add(scan_windows::<1>(x, m, [full * segment], rest));
    }
    total.value()
}

/// Steps after which the MDEV window is summed again from scratch.
const SEGMENT_STEPS: usize = 1 << 16;

/// Σ W_j² for `j` in `start..start + len` of each lane (see [`modified_sum`]).
#[inline(always)]
#[allow(clippy::needless_range_loop)] // one index walks the L lane arrays in lock-step
fn scan_windows<const L: usize>(x: &[f64], m: usize, starts: [usize; L], len: usize) -> f64 {
    const BLOCK: usize = 256;
    let mut window: [f64; L] = starts.map(|j| {
        sum_streams(
            [&x[j..j + m], &x[j + m..j + 2 * m], &x[j + 2 * m..j + 3 * m]],
            |[a, b, c]| c - 2.0 * b + a,
        )
    });
    let mut total = CompensatedSum::new();
    let mut squares: [f64; L] = window.map(|w| w * w);
    // Lane-major, so each lane's steps are one contiguous, vectorised pass over x.
    let mut steps = [[0.0f64; BLOCK]; L];
    let mut done = 1;
    while done < len {
        let n = BLOCK.min(len - done);
        for (lane, &start) in starts.iter().enumerate() {
            let k = start + done - 1;
            let a = &x[k..k + n];
            let b = &x[k + m..k + m + n];
            let c = &x[k + 2 * m..k + 2 * m + n];
            let d = &x[k + 3 * m..k + 3 * m + n];
            for (slot, (((a, b), c), d)) in steps[lane][..n]
                .iter_mut()
                .zip(a.iter().zip(b).zip(c).zip(d))
            {
                *slot = (d - a) + 3.0 * (b - c);
            }
        }
        for i in 0..n {
            for lane in 0..L {
                window[lane] += steps[lane][i];
                squares[lane] += window[lane] * window[lane];
            }
        }
        for square in squares.iter_mut() {
            total.add(*square);
            *square = 0.0;
        }
        done += n;
    }
    for square in squares {
        total.add(square);
    }
    total.value()
}

/// TOTDEV numerator: Σ_{i=1}^{n−2} (x*[i−m] − 2x*[i] + x*[i+m])² over the phase extended
/// by reflection at both ends (x*[−j] = 2x[0] − x[j], x*[n−1+j] = 2x[n−1] − x[n−1−j]).
fn total_sum(x: &[f64], m: usize) -> f64 {
    let n = x.len();
    let mut total = CompensatedSum::new();
    total.add(total_edges_pointwise(x, m));
    // Interior where no reflection is needed: m ≤ i ≤ n − 1 − m.
    if m >= 1 && n > 2 * m {
        let count = n - 2 * m;
        total.add(sum_streams(
            [&x[..count], &x[m..m + count], &x[2 * m..2 * m + count]],
            second_difference,
        ));
    }
    total.value()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn direct_oadev(y: &[f64], m: usize) -> f64 {
        // Textbook definition over averaged frequencies, no phase involved.
        let n = y.len();
        let avg = |k: usize| y[k..k + m].iter().sum::<f64>() / m as f64;
        let terms = n + 1 - 2 * m;
        let s: f64 = (0..terms).map(|k| (avg(k + m) - avg(k)).powi(2)).sum();
        (s / (2.0 * terms as f64)).sqrt()
    }

    #[test]
    fn oadev_matches_frequency_average_definition() {
        let y: Vec<f64> = (0..200)
            .map(|i| ((i * 7919) % 101) as f64 / 50.0 - 1.0)
            .collect();
        let phase = Phase::from_rate(y.clone());
        for m in [1, 2, 5, 17, 60] {
            let p = deviation_at(DeviationKind::Oadev, &phase, m, 1.0).unwrap();
            let expected = direct_oadev(&y, m);
            assert!((p.deviation - expected).abs() < 1e-12 * expected, "m={m}");
        }
    }

    #[test]
    fn totdev_at_unit_factor_equals_oadev() {
        let y: Vec<f64> = (0..300).map(|i| ((i * 31) % 17) as f64).collect();
        let phase = Phase::from_rate(y);
        let o = deviation_at(DeviationKind::Oadev, &phase, 1, 1.0).unwrap();
        let t = deviation_at(DeviationKind::Totdev, &phase, 1, 1.0).unwrap();
        assert!((o.deviation - t.deviation).abs() < 1e-12 * o.deviation);
    }

    #[test]
    fn mdev_sliding_window_matches_direct_sum() {
        let y: Vec<f64> = (0..400).map(|i| (((i * 7) % 13) as f64).sin()).collect();
        let phase = Phase::from_rate(y);
        let x = &phase.points;
        for m in [1, 3, 10, 33] {
            let count = DeviationKind::Mdev.term_count(m, x.len());
            let mut direct = 0.0;
            for j in 0..count {
                let s: f64 = (j..j + m)
                    .map(|i| x[i + 2 * m] - 2.0 * x[i + m] + x[i])
                    .sum();
                direct += s * s;
            }
            let fast = modified_sum(x, m, count);
            assert!((fast - direct).abs() < 1e-10 * direct, "m={m}");
        }
    }

    /// Deterministic noise with a large offset, white and random-walk parts.
    fn noisy_rate(n: usize, seed: u64) -> Vec<f64> {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut walk = 0.0;
        (0..n)
            .map(|_| {
                let w: f64 = StandardNormal.sample(&mut rng);
                let s: f64 = StandardNormal.sample(&mut rng);
                walk += 0.02 * s;
                9.80665 + w + walk
            })
            .collect()
    }

    /// Textbook definitions written independently of the kernels: ADEV, HDEV from averaged
    /// frequencies, MDEV from its double sum, TOTDEV from an explicitly reflected phase.
    fn direct_variance(kind: DeviationKind, y: &[f64], x: &[f64], m: usize) -> Option<f64> {
        let n = x.len();
        let mf = m as f64;
        let avg = |k: usize| y[k..k + m].iter().sum::<f64>() / mf;
        let mean_of = |terms: Vec<f64>| {
            (!terms.is_empty()).then(|| terms.iter().sum::<f64>() / terms.len() as f64)
        };
        match kind {
            DeviationKind::Adev => {
                let blocks = y.len() / m;
                mean_of(
                    (0..blocks.saturating_sub(1))
                        .map(|b| (avg((b + 1) * m) - avg(b * m)).powi(2) / 2.0)
                        .collect(),
                )
            }
            DeviationKind::Oadev => mean_of(
                (0..(y.len() + 1).saturating_sub(2 * m))
                    .map(|k| (avg(k + m) - avg(k)).powi(2) / 2.0)
                    .collect(),
            ),
            DeviationKind::Hdev => {
                let blocks = y.len() / m;
                mean_of(
                    (0..blocks.saturating_sub(2))
                        .map(|b| {
                            (avg((b + 2) * m) - 2.0 * avg((b + 1) * m) + avg(b * m)).powi(2) / 6.0
                        })
                        .collect(),
                )
            }
            DeviationKind::Ohdev => mean_of(
                (0..(y.len() + 1).saturating_sub(3 * m))
                    .map(|k| (avg(k + 2 * m) - 2.0 * avg(k + m) + avg(k)).powi(2) / 6.0)
                    .collect(),
            ),
            DeviationKind::Mdev | DeviationKind::Tdev => mean_of(
                (0..(n + 1).saturating_sub(3 * m))
                    .map(|j| {
                        let s: f64 = (j..j + m)
                            .map(|i| x[i + 2 * m] - 2.0 * x[i + m] + x[i])
                            .sum();
                        s * s / (2.0 * mf.powi(4))
                    })
                    .collect(),
            ),
            DeviationKind::Totdev => {
                if m >= n - 1 {
                    return None;
                }
                // x* over indices −(n−1) … 2(n−1), offset by n−1.
                let last = n - 1;
                let mut ext = Vec::with_capacity(3 * n);
                for j in (1..=last).rev() {
                    ext.push(2.0 * x[0] - x[j]);
                }
                ext.extend_from_slice(x);
                for j in 1..=last {
                    ext.push(2.0 * x[last] - x[last - j]);
                }
                mean_of(
                    (1..=n - 2)
                        .map(|i| {
                            let c = i + last;
                            (ext[c - m] - 2.0 * ext[c] + ext[c + m]).powi(2) / (2.0 * mf * mf)
                        })
                        .collect(),
                )
            }
        }
    }

    #[test]
    fn every_kind_equals_its_direct_definition_on_random_data() {
        let y = noisy_rate(3_001, 7);
        let phase = Phase::from_rate(y.clone());
        let centred: Vec<f64> = y.iter().map(|v| v - phase.removed_mean).collect();
        for kind in DeviationKind::ALL {
            for m in [1, 2, 3, 7, 64, 333, 750, 999, 1_400] {
                let fast = variance_at(kind, &phase, m);
                let direct = direct_variance(kind, &centred, &phase.points, m);
                match (fast, direct) {
                    (Some((f, _)), Some(d)) => {
                        assert!(
                            (f - d).abs() <= 1e-12 * d,
                            "{kind:?} m={m}: fast {f:e} direct {d:e} (rel {:e})",
                            (f - d).abs() / d
                        );
                    }
                    (None, None) => {}
                    (f, d) => panic!("{kind:?} m={m}: fast {f:?} direct {d:?}"),
                }
            }
        }
    }

    #[test]
    fn modified_sum_is_independent_of_the_segmenting() {
        // Small segments exercise the four-lane scan, single lanes and the remainder.
        let phase = Phase::from_rate(noisy_rate(5_000, 11));
        let x = &phase.points;
        for m in [1, 2, 5, 40, 300, 1_200] {
            let count = DeviationKind::Mdev.term_count(m, x.len());
            let reference = modified_sum_in_segments(x, m, count, usize::MAX);
            for segment in [1, 7, 64, 1_000] {
                let v = modified_sum_in_segments(x, m, count, segment);
                assert!(
                    (v - reference).abs() <= 1e-12 * reference,
                    "m={m} segment={segment}: {v:e} vs {reference:e}"
                );
            }
        }
    }

    #[test]
    fn undefined_factors_give_none() {
        let phase = Phase::from_rate(vec![1.0, 2.0, 3.0]);
        assert!(deviation_at(DeviationKind::Adev, &phase, 2, 1.0).is_none());
        assert!(deviation_at(DeviationKind::Hdev, &phase, 1, 1.0).is_some());
        assert!(deviation_at(DeviationKind::Oadev, &phase, 0, 1.0).is_none());
    }

    #[test]
    fn grid_sweep_equals_factor_by_factor_on_both_paths() {
        // Longer than one parallel job (TILE × TILES_PER_JOB terms), so the merge of job
        // partials is exercised; factors cover octave, decade and odd values, and for
        // TOTDEV ones past n/2 (point-by-point edges).
        let phase = Phase::from_rate(noisy_rate(150_001, 5));
        let n = phase.len();
        let factors = [
            1, 2, 3, 4, 8, 10, 16, 20, 40, 64, 100, 1_000, 5_000, 37_000, 74_000, 80_000,
        ];
        for kind in DeviationKind::ALL {
            let mut first: Option<Vec<Option<(f64, usize)>>> = None;
            for simd in Simd::available() {
                let all = variances_with(kind, &phase, &factors, simd);
                for (j, &m) in factors.iter().enumerate() {
                    let single = variance_at(kind, &phase, m);
                    match (all[j], single) {
                        (Some((v, c)), Some((w, d))) => {
                            assert_eq!(c, d, "{kind:?} m={m} count");
                            assert!(
                                (v - w).abs() <= 1e-13 * w,
                                "{kind:?} m={m} {simd:?}: {v:e} vs {w:e}"
                            );
                        }
                        (None, None) => {}
                        (a, b) => panic!("{kind:?} m={m} n={n}: {a:?} vs {b:?}"),
                    }
                }
                match &first {
                    None => first = Some(all),
                    Some(f) => assert_eq!(f, &all, "{kind:?}: paths differ"),
                }
            }
        }
    }
}
