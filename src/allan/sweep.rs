//! The overlapping second-difference sweep behind OADEV and the interior of TOTDEV:
//! S_j = Σ_{i < count_j} (x[i + 2m_j] − 2x[i + m_j] + x[i])² for every factor m_j of a
//! grid, in one pass over the phase x.
//!
//! How (figures in docs/bench/allan.md, "Round 5" and "Session 7, sweep and window
//! sums"):
//! - The term range is cut into jobs of [`TILES_PER_JOB`] tiles of [`TILE`] terms (512 KB
//!   of phase per job, which stays in L2). Within a tile the factors are processed in
//!   **register-blocked groups** of up to [`GROUP`] factors whose eight-lane
//!   accumulators stay in registers over the whole tile:
//!   - a *chain* m, 2m, 4m, … (every octave grid; a few runs inside dense grids): the
//!     outer point x[i + 2m] of one factor is the middle point of the next, so G terms
//!     take G + 2 loads instead of 3G;
//!   - other factors share the load of x[i]: 2G + 1 loads for G terms.
//! - Factors outside chains from [`LANES`] to [`WALK_MAX`] (most of a dense grid below
//!   4096) instead **walk the job's rows** of m terms ([`walk`]): x[i + m] and x[i + 2m]
//!   of term i are x[i′] and x[i′ + m] of term i′ = i + m, so a strip of vectors walking
//!   down the rows loads one vector per eight terms (the two rows before stay in
//!   registers) where a shared group loads more than two, from L2.
//! - Each term is (c − 2b + a)² added to its lane by one fused multiply-add (acc + d²,
//!   rounded once); c − 2b is one fused negative multiply-add, or (c − (b + b)) on the
//!   adders for every third member of a group, which is the same rounding (2b is exact).
//!   So a group of four takes 6 additions and 7 multiply-adds on Zen 4's two pipes of
//!   each kind, instead of 8 and 8.
//! - Lanes of a tile (of a strip) accumulate plain sums; a tile's (a strip's) lanes are
//!   added in lane order and these partial sums are compensated ([`CompensatedSum`]);
//!   jobs run on the rayon pool and are merged in a fixed order. So each S_j has the
//!   same bits whatever the number of threads and the instruction-set path, and whether
//!   a factor is swept shared or alone; a factor of the walk range that a grid chains
//!   and another does not is summed in another order there (a few ulps apart).
//! - Three paths ([`SweepPath`]): portable (plain arrays, vectorised by the compiler with
//!   SSE2, `f64::mul_add` for the fused operations), AVX2 + FMA and AVX-512F (explicit
//!   `std::arch` intrinsics, chosen at run time). The large factors' far streams
//!   (x[i + m], x[i + 2m] for m beyond a tile: about one pass over the phase from L3 or
//!   memory per factor) bound dense grids; see the benchmark notes.
//!
//! Written with intrinsics rather than left to the auto-vectoriser (as the other kernels
//! in this module tree are): register-blocked loops over several factors were vectorised
//! unpredictably (13 to 130 ms for the same octave sweep depending on the group size, in
//! a scratch comparison), and `std::arch` gives AVX-512 with runtime detection without a
//! new dependency. No crate offering portable SIMD on stable Rust (e.g. `wide`) does the
//! runtime dispatch to AVX-512, and the few operations needed fit in one small trait
//! ([`super::lanes`], shared with the MDEV/TDEV window sums).

use super::lanes::{run_on, LaneJob, Lanes, LANES};
use super::numerics::{sum_in_jobs, CompensatedSum, Simd};

/// Terms per tile (32 KiB per stream). Measured flat between 1024 and 32 768 terms on
/// the 6 h bench data; 4096 keeps a shared group's 2G + 1 streams within L2.
pub const TILE: usize = 4096;

/// Tiles per parallel job (and per entry of the fixed-order merge): 512 KB of phase, so
/// that the job's span stays in L2 while the factors of [`walk`] pass over it.
pub const TILES_PER_JOB: usize = 16;

/// Largest factor that walks rows ([`walk`]): a sixteenth of a job, so that a strip's
/// two rows of start-up cost little.
pub const WALK_MAX: usize = TILE * TILES_PER_JOB / 16;

/// Most factors one register-blocked group holds: 4 eight-lane accumulators are 8 ymm
/// registers on the AVX2 path, leaving room for the loaded streams.
pub const GROUP: usize = 4;

/// Instruction-set path of the sweep. All give identical bits (tested).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SweepPath {
    /// Plain arrays; any CPU.
    Portable,
    /// AVX2 and FMA.
    Avx2,
    /// AVX-512F (with AVX2 and FMA).
    Avx512,
}

impl SweepPath {
    /// The fastest path this CPU supports.
    pub fn detected() -> SweepPath {
        #[cfg(target_arch = "x86_64")]
        {
            let avx2 = std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma");
            if avx2 && std::arch::is_x86_feature_detected!("avx512f") {
                return SweepPath::Avx512;
            }
            if avx2 {
                return SweepPath::Avx2;
            }
        }
        SweepPath::Portable
    }

    /// The path for the module-wide choice `simd`: portable stays portable, otherwise the
    /// fastest this CPU has.
    pub fn for_simd(simd: Simd) -> SweepPath {
        match simd {
            Simd::Portable => SweepPath::Portable,
            Simd::Avx2 => SweepPath::detected(),
        }
    }

    /// Every path this CPU can run, portable first (for tests and benchmarks).
    pub fn available() -> Vec<SweepPath> {
        match SweepPath::detected() {
            SweepPath::Portable => vec![SweepPath::Portable],
            SweepPath::Avx2 => vec![SweepPath::Portable, SweepPath::Avx2],
            SweepPath::Avx512 => vec![SweepPath::Portable, SweepPath::Avx2, SweepPath::Avx512],
        }
    }
}

/// S_j for every factor (see the module docs); `counts[j]` terms for `factors[j]`, each
/// needing `counts[j] + 2·factors[j] ≤ x.len()` (the caller's term counts guarantee it;
/// a factor that breaks it gets 0 rather than reading out of bounds).
pub fn second_difference_sums(
    x: &[f64],
    factors: &[usize],
    counts: &[usize],
    path: SweepPath,
) -> Vec<f64> {
    let counts: Vec<usize> = factors
        .iter()
        .zip(counts)
        .map(|(&m, &c)| {
            if m == 0 || c.saturating_add(m.saturating_mul(2)) > x.len() {
                0
            } else {
                c
            }
        })
        .collect();
    let longest = counts.iter().copied().max().unwrap_or(0);
    sum_in_jobs(
        longest,
        TILE * TILES_PER_JOB,
        factors.len(),
        |start, end| {
            let job = Job {
                x,
                factors,
                counts: &counts,
                start,
                end,
            };
            run_on(path, &job)
        },
    )
}

/// The terms `start..end` (a multiple of [`TILE`] apart from the last job) of every factor.
struct Job<'a> {
    x: &'a [f64],
    factors: &'a [usize],
    counts: &'a [usize],
    start: usize,
    end: usize,
}

impl LaneJob for &Job<'_> {
    type Output = Vec<CompensatedSum>;
    #[inline(always)]
    unsafe fn run<V: Lanes>(self) -> Vec<CompensatedSum> {
        job_lanes::<V>(self)
    }
}

/// How a group's factors share their loads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Sharing {
    /// m, 2m, 4m, …: factor k + 1's middle stream is factor k's outer one.
    Chain,
    /// Only x[i] is shared.
    Shared,
}

/// Factors (indices into the grid) swept together.
#[derive(Debug, Clone, Copy)]
struct Group {
    sharing: Sharing,
    members: [usize; GROUP],
    len: usize,
}

/// Groups for the factors `live` (indices into `factors`): greedy chains m, 2m, 4m, … of
/// at least two factors from the smallest factor up; of the rest, those in `walks` go
/// to the row walk (second list: a chain shares more loads than a walk saves), the
/// others into shared groups. O(F log F) for F factors (the `all` grid has one per m).
fn plan(
    factors: &[usize],
    live: &[usize],
    walks: std::ops::RangeInclusive<usize>,
) -> (Vec<Group>, Vec<usize>) {
    let mut order: Vec<usize> = live.to_vec();
    order.sort_by_key(|&j| factors[j]);
    let sorted: Vec<usize> = order.iter().map(|&j| factors[j]).collect();
    let mut taken = vec![false; order.len()];
    let mut groups = Vec::new();
    let mut singles = Vec::new();
    for start in 0..order.len() {
        if taken[start] {
            continue;
        }
        taken[start] = true;
        let mut members = [0usize; GROUP];
        members[0] = order[start];
        let mut len = 1;
        let mut at = start;
        while len < GROUP {
            let want = sorted[at].saturating_mul(2);
            let first = sorted.partition_point(|&m| m < want).max(at + 1);
            match (first..sorted.len())
                .take_while(|&k| sorted[k] == want)
                .find(|&k| !taken[k])
            {
                Some(k) => {
                    taken[k] = true;
                    members[len] = order[k];
                    len += 1;
                    at = k;
                }
                None => break,
            }
        }
        if len >= 2 {
            groups.push(Group {
                sharing: Sharing::Chain,
                members,
                len,
            });
        } else {
            singles.push(members[0]);
        }
    }
    let (walkers, singles): (Vec<usize>, Vec<usize>) = singles
        .into_iter()
        .partition(|&j| walks.contains(&factors[j]));
    for chunk in singles.chunks(GROUP) {
        let mut members = [0usize; GROUP];
        members[..chunk.len()].copy_from_slice(chunk);
        groups.push(Group {
            sharing: Sharing::Shared,
            members,
            len: chunk.len(),
        });
    }
    (groups, walkers)
}

/// The job's terms on lanes `V`. Factors whose terms cover the whole job are swept tile by
/// tile in the groups of [`plan`], or walk the job's rows ([`walk`]) when [`plan`] says
/// so; a factor whose terms end inside the job walks up to its end if it is between
/// [`LANES`] and [`WALK_MAX`], else is swept alone tile by tile.
///
/// Safety: `V`'s instructions must be available.
#[inline(always)]
unsafe fn job_lanes<V: Lanes>(job: &Job) -> Vec<CompensatedSum> {
    let Job {
        x,
        factors,
        counts,
        start,
        end,
    } = *job;
    let walks = LANES..=WALK_MAX;
    let full: Vec<usize> = (0..factors.len()).filter(|&j| counts[j] >= end).collect();
    let (groups, mut walkers) = plan(factors, &full, walks.clone());
    let mut ending = Vec::new();
    for j in (0..factors.len()).filter(|&j| counts[j] > start && counts[j] < end) {
        if walks.contains(&factors[j]) {
            walkers.push(j);
        } else {
            ending.push(j);
        }
    }
    let mut sums = vec![CompensatedSum::new(); factors.len()];
    for &j in &walkers {
        sums[j].add(walk::<V>(x, factors[j], start, end.min(counts[j])));
    }
    let mut t0 = start;
    while t0 < end {
        let t1 = (t0 + TILE).min(end);
        for group in &groups {
            let lanes = sweep_group::<V>(x, factors, group, t0, t1);
            for (k, lane) in lanes.iter().enumerate().take(group.len) {
                sums[group.members[k]].add(lane_total(lane));
            }
        }
        for &j in &ending {
            if counts[j] > t0 {
                let single = Group {
                    sharing: Sharing::Shared,
                    members: [j; GROUP],
                    len: 1,
                };
                let lanes = sweep_group::<V>(x, factors, &single, t0, t1.min(counts[j]));
                sums[j].add(lane_total(&lanes[0]));
            }
        }
        t0 = t1;
    }
    sums
}

/// Σ (x[i + 2m] − 2x[i + m] + x[i])² over the terms `start..end` of one factor m ≥
/// [`LANES`], by rows of m terms: term i + m reads x[i + m] and x[i + 2m] again, so a
/// strip of vectors walking down the rows loads one new row per step and keeps the two
/// before it in registers (one load per eight terms instead of three). The job's span
/// of the phase stays in L2 while its factors walk it. Strips of `V::WALK` vectors, then
/// of one, the last one masked to the lanes the others left; the terms after the last
/// whole row are swept straight.
#[inline(always)]
unsafe fn walk<V: Lanes>(x: &[f64], m: usize, start: usize, end: usize) -> f64 {
    let rows = (end - start) / m;
    assert!(
        m >= LANES && start + (rows + 2) * m <= x.len() && end + 2 * m <= x.len(),
        "sweep walk out of range"
    );
    let base = x.as_ptr().add(start);
    let mut total = 0.0;
    if rows > 0 {
        let mut r = 0;
        if V::WALK >= 4 {
            while r + 4 * LANES <= m {
                for v in strip::<V, 4, false>(base.add(r), m, rows, 0) {
                    total += v;
                }
                r += 4 * LANES;
            }
        }
        if V::WALK >= 2 {
            while r + 2 * LANES <= m {
                for v in strip::<V, 2, false>(base.add(r), m, rows, 0) {
                    total += v;
                }
                r += 2 * LANES;
            }
        }
        while r + LANES <= m {
            total += strip::<V, 1, false>(base.add(r), m, rows, 0)[0];
            r += LANES;
        }
        if r < m {
            // The last m − r columns: a strip ending at column m, its first lanes (done
            // by the strip before) masked out.
            total += strip::<V, 1, true>(base.add(m - LANES), m, rows, LANES - (m - r))[0];
        }
    }
    let t0 = start + rows * m;
    let steps = (end - t0) / LANES;
    let mut lanes = shared::<V, 1>(x, t0, steps, [m])[0];
    for (l, i) in (t0 + steps * LANES..end).enumerate() {
        let d = x[i + 2 * m] - 2.0 * x[i + m] + x[i];
        lanes[l] = d.mul_add(d, lanes[l]);
    }
    total + lane_total(&lanes)
}

/// The terms of `rows` rows of m (row q at `p + q·m`) in a strip of `K` vectors, lanes
/// below `skip` left out when `MASKED` (then K = 1): one sum per vector. Two sets of accumulators take
/// alternate rows, so that the additions of neighbouring rows overlap.
///
/// Safety: `p` must be readable for rows + 2 rows of the strip.
#[inline(always)]
unsafe fn strip<V: Lanes, const K: usize, const MASKED: bool>(
    p: *const f64,
    m: usize,
    rows: usize,
    skip: usize,
) -> [f64; K] {
    let row = |q: usize| -> [V; K] { std::array::from_fn(|k| V::load(p.add(q * m + k * LANES))) };
    let mask = if MASKED {
        let keep: [f64; LANES] = std::array::from_fn(|l| if l < skip { 0.0 } else { 1.0 });
        V::load(keep.as_ptr())
    } else {
        V::zero()
    };
    let square = |acc: V, a: V, b: V, c: V| {
        let d = c.minus_twice(b).add(a);
        // × 1 or × 0: exact (d is finite).
        let d = if MASKED { d.mul(mask) } else { d };
        d.square_add(acc)
    };
    let mut acc = [[V::zero(); K]; 2];
    let mut a = row(0);
    let mut b = row(1);
    let mut q = 0;
    while q + 2 <= rows {
        let c = row(q + 2);
        let d = row(q + 3);
        for k in 0..K {
            acc[0][k] = square(acc[0][k], a[k], b[k], c[k]);
            acc[1][k] = square(acc[1][k], b[k], c[k], d[k]);
        }
        (a, b) = (c, d);
        q += 2;
    }
    if q < rows {
        let c = row(q + 2);
        for k in 0..K {
            acc[0][k] = square(acc[0][k], a[k], b[k], c[k]);
        }
    }
    // Per vector of the strip, as if each had walked alone: the same bits for any K.
    std::array::from_fn(|k| lane_total(&acc[0][k].to_array()) + lane_total(&acc[1][k].to_array()))
}

/// Sum of the eight lanes in lane order.
#[inline(always)]
fn lane_total(lanes: &[f64; LANES]) -> f64 {
    lanes.iter().fold(0.0, |s, v| s + v)
}

/// The lanes of the terms `t0..t1` (t0 a multiple of 8) of `group`'s factors.
#[inline(always)]
unsafe fn sweep_group<V: Lanes>(
    x: &[f64],
    factors: &[usize],
    group: &Group,
    t0: usize,
    t1: usize,
) -> [[f64; LANES]; GROUP] {
    let steps = (t1 - t0) / LANES;
    let m: [usize; GROUP] = std::array::from_fn(|k| factors[group.members[k.min(group.len - 1)]]);
    let mut lanes = match (group.sharing, group.len) {
        (Sharing::Chain, 2) => widen(chain::<V, 2>(x, t0, steps, [m[0], m[1]])),
        (Sharing::Chain, 3) => widen(chain::<V, 3>(x, t0, steps, [m[0], m[1], m[2]])),
        (Sharing::Chain, 4) => widen(chain::<V, 4>(x, t0, steps, m)),
        (_, 1) => widen(shared::<V, 1>(x, t0, steps, [m[0]])),
        (_, 2) => widen(shared::<V, 2>(x, t0, steps, [m[0], m[1]])),
        (_, 3) => widen(shared::<V, 3>(x, t0, steps, [m[0], m[1], m[2]])),
        _ => widen(shared::<V, 4>(x, t0, steps, m)),
    };
    // The last (t1 − t0) mod 8 terms, each into its own lane.
    for (k, lane) in lanes.iter_mut().enumerate().take(group.len) {
        let m = m[k];
        for i in t0 + steps * LANES..t1 {
            let d = x[i + 2 * m] - 2.0 * x[i + m] + x[i];
            lane[i % LANES] = d.mul_add(d, lane[i % LANES]);
        }
    }
    lanes
}

/// `G` lane arrays padded to [`GROUP`].
#[inline(always)]
fn widen<const G: usize>(lanes: [[f64; LANES]; G]) -> [[f64; LANES]; GROUP] {
    std::array::from_fn(|k| if k < G { lanes[k] } else { [0.0; LANES] })
}

/// c − 2b + a for member `k` of a group, computed so that a group's operations spread
/// over both kinds of floating-point pipe: every third member as (c − (b + b)) + a on
/// the adders (three additions), the others as (c − 2b, one fused multiply-add) + a. Both
/// round c − 2b once (2b is exact), so they give the same bits; with the fused square-add
/// that follows, a group of four costs 6 additions and 7 multiply-adds instead of 8 and 8.
#[inline(always)]
unsafe fn second_difference<V: Lanes>(a: V, b: V, c: V, k: usize) -> V {
    if k % 3 == 2 {
        c.sub(b.add(b)).add(a)
    } else {
        c.minus_twice(b).add(a)
    }
}

/// Lanes of `steps` eight-term steps from `t0` for the chain `m` (m[k+1] = 2m[k]).
#[inline(always)]
unsafe fn chain<V: Lanes, const G: usize>(
    x: &[f64],
    t0: usize,
    steps: usize,
    m: [usize; G],
) -> [[f64; LANES]; G] {
    let outer = 2 * m[G - 1];
    assert!(
        (1..G).all(|k| m[k] == 2 * m[k - 1]) && t0 + steps * LANES + outer <= x.len(),
        "sweep chain out of range"
    );
    let base = x.as_ptr().add(t0);
    let mut acc = [V::zero(); G];
    for step in 0..steps {
        let p = base.add(step * LANES);
        let a = V::load(p);
        let mut b = V::load(p.add(m[0]));
        for k in 0..G {
            let c = V::load(p.add(if k + 1 < G { m[k + 1] } else { outer }));
            acc[k] = second_difference(a, b, c, k).square_add(acc[k]);
            b = c;
        }
    }
    acc.map(|v| v.to_array())
}

/// Lanes of `steps` eight-term steps from `t0` for any factors `m` (x[i] shared).
#[inline(always)]
unsafe fn shared<V: Lanes, const G: usize>(
    x: &[f64],
    t0: usize,
    steps: usize,
    m: [usize; G],
) -> [[f64; LANES]; G] {
    assert!(
        m.iter().all(|&m| t0 + steps * LANES + 2 * m <= x.len()),
        "sweep group out of range"
    );
    let base = x.as_ptr().add(t0);
    let mut acc = [V::zero(); G];
    for step in 0..steps {
        let p = base.add(step * LANES);
        let a = V::load(p);
        for k in 0..G {
            let b = V::load(p.add(m[k]));
            let c = V::load(p.add(2 * m[k]));
            acc[k] = second_difference(a, b, c, k).square_add(acc[k]);
        }
    }
    acc.map(|v| v.to_array())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic random-walk phase of `n` points.
    fn phase(n: usize, seed: u64) -> Vec<f64> {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut x = 0.0;
        let mut walk = 0.0;
        (0..n)
            .map(|_| {
                let w: f64 = StandardNormal.sample(&mut rng);
                let s: f64 = StandardNormal.sample(&mut rng);
                walk += 0.01 * s;
                x += w + walk;
                x
            })
            .collect()
    }

    /// Compensated sum of the squared second differences, term by term.
    fn direct(x: &[f64], m: usize, count: usize) -> f64 {
        let mut total = CompensatedSum::new();
        for i in 0..count {
            let d = x[i + 2 * m] - 2.0 * x[i + m] + x[i];
            total.add(d * d);
        }
        total.value()
    }

    fn counts(factors: &[usize], n: usize) -> Vec<usize> {
        factors.iter().map(|&m| n.saturating_sub(2 * m)).collect()
    }

    /// Octave, dense (chains inside), decade and odd factors, unsorted and repeated; the
    /// phase spans several jobs with a partial last tile, and large factors end inside
    /// jobs and tiles.
    fn grids(n: usize) -> Vec<Vec<usize>> {
        let octave: Vec<usize> = (0..)
            .map(|k| 1usize << k)
            .take_while(|&m| m <= n / 4)
            .collect();
        let mut dense: Vec<usize> = (0..)
            .map(|k| 10f64.powf(k as f64 / 10.0).round() as usize)
            .take_while(|&m| m <= n / 3)
            .collect();
        dense.dedup();
        vec![
            octave,
            dense,
            vec![
                1, 2, 4, 10, 20, 40, 100, 200, 400, 1_000, 2_000, 4_000, 10_000,
            ],
            vec![7, 3, 3, 96, 48, 24, 12, 1, 50_001, 77_777, 1_000_000],
            // Row walks: whole strips of four, two and one vectors, masked last
            // strips, rows that do not divide the job, factors ending inside jobs.
            vec![8, 9, 17, 33, 100, 1_001, 4_095, WALK_MAX, 60_000, 70_001],
        ]
    }

    #[test]
    fn sweep_equals_the_direct_sums_on_every_path() {
        let n = 2 * TILE * TILES_PER_JOB + 3 * TILE + 5;
        let x = phase(n, 3);
        for factors in grids(n) {
            let counts = counts(&factors, n);
            let mut first: Option<Vec<f64>> = None;
            for path in SweepPath::available() {
                let sums = second_difference_sums(&x, &factors, &counts, path);
                for (j, (&m, &c)) in factors.iter().zip(&counts).enumerate() {
                    let want = direct(&x, m, c);
                    assert!(
                        (sums[j] - want).abs() <= 1e-13 * want,
                        "{path:?} m={m}: {:e} vs {want:e}",
                        sums[j]
                    );
                }
                match &first {
                    None => first = Some(sums),
                    Some(f) => assert_eq!(f, &sums, "{path:?} differs from the portable path"),
                }
            }
        }
    }

    #[test]
    fn each_sum_is_independent_of_the_other_factors_and_of_the_threads() {
        // Shared and single runs of a factor must give the same bits; a factor of the
        // walk range that a chain takes in the grid walks when alone (another order of
        // the same sums: a few ulps at most).
        let n = TILE * TILES_PER_JOB + 2 * TILE + 3;
        let x = phase(n, 9);
        let one_thread = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("pool");
        let two_threads = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .expect("pool");
        for factors in grids(n) {
            let counts = counts(&factors, n);
            for path in SweepPath::available() {
                let all = second_difference_sums(&x, &factors, &counts, path);
                for (j, &m) in factors.iter().enumerate() {
                    let alone = second_difference_sums(&x, &[m], &[counts[j]], path);
                    if (LANES..=WALK_MAX).contains(&m) {
                        assert!(
                            (alone[0] - all[j]).abs() <= 1e-14 * all[j],
                            "{path:?} m={m}: {:e} vs {:e}",
                            alone[0],
                            all[j]
                        );
                    } else {
                        assert_eq!(alone[0].to_bits(), all[j].to_bits(), "{path:?} m={m}");
                    }
                }
                let serial =
                    one_thread.install(|| second_difference_sums(&x, &factors, &counts, path));
                let parallel =
                    two_threads.install(|| second_difference_sums(&x, &factors, &counts, path));
                assert_eq!(serial, all, "{path:?}: one thread");
                assert_eq!(parallel, all, "{path:?}: two threads");
            }
        }
    }

    #[test]
    fn plans_chain_doubling_factors_and_share_the_rest() {
        let factors = [1, 2, 3, 4, 6, 8, 10, 16, 32];
        let live: Vec<usize> = (0..factors.len()).collect();
        let (groups, walkers) = plan(&factors, &live, 10..=10);
        assert_eq!(
            walkers.iter().map(|&j| factors[j]).collect::<Vec<_>>(),
            [10]
        );
        let described: Vec<(Sharing, Vec<usize>)> = groups
            .iter()
            .map(|g| {
                (
                    g.sharing,
                    g.members[..g.len].iter().map(|&j| factors[j]).collect(),
                )
            })
            .collect();
        assert_eq!(
            described,
            vec![
                (Sharing::Chain, vec![1, 2, 4, 8]),
                (Sharing::Chain, vec![3, 6]),
                (Sharing::Chain, vec![16, 32]),
            ]
        );
    }

    #[test]
    fn plan_of_the_all_grid_covers_every_factor_once() {
        // 50 000 factors (one per m): each in exactly one group, chains exact doublings.
        let factors: Vec<usize> = (1..=50_000).collect();
        let live: Vec<usize> = (0..factors.len()).collect();
        let mut seen = vec![0u8; factors.len()];
        let (groups, walkers) = plan(&factors, &live, LANES..=WALK_MAX);
        for &j in &walkers {
            assert!((LANES..=WALK_MAX).contains(&factors[j]));
            seen[j] += 1;
        }
        for group in groups {
            let members = &group.members[..group.len];
            if group.sharing == Sharing::Chain {
                assert!(members
                    .windows(2)
                    .all(|w| factors[w[1]] == 2 * factors[w[0]]));
            }
            for &j in members {
                seen[j] += 1;
            }
        }
        assert!(seen.iter().all(|&c| c == 1));
    }

    #[test]
    fn factors_that_do_not_fit_give_zero() {
        let x = phase(100, 1);
        let sums = second_difference_sums(&x, &[0, 10, 60], &[100, 80, 1], SweepPath::Portable);
        assert_eq!(sums[0], 0.0);
        let want = direct(&x, 10, 80);
        assert!((sums[1] - want).abs() <= 1e-13 * want);
        assert_eq!(sums[2], 0.0);
    }
}
