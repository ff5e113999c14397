//! Incremental Allan deviation of one axis: the octave block sums (m = 1, 2, 4, …) are
//! extended as samples arrive, so a refresh costs the levels, not the hours of data behind
//! them.
//!
//! Each level keeps the accumulators of [`LevelSums`] (the same ones the full computation
//! of [`crate::allan::block_sums`] fills): Σ(Δs)² for the non-overlapping ADEV, the moments
//! of the lag-1 noise identification's orders 0 and 1, plus here the moments of order 2
//! (the first differences of the block sums; the full computation takes them from stored
//! block sums). A sample completes a block of level 0; every second block of level j
//! completes one of level j + 1 (the pairwise sum). Memory is a few hundred bytes per
//! level, about 25 levels for a day at 150 Hz.
//!
//! Like the full computation, a constant (the mean of the first
//! [`OFFSET_SAMPLES`] samples) is taken off every sample: until that many have arrived the
//! samples are held and the curve is computed from them in full.
//!
//! The noise type at a τ with too few averages for the lag-1 method comes from the B1
//! ratio of the last block sums of that level (at most [`MIN_AVERAGES`] + 1 are kept per
//! level); where B1 points at a phase noise, which needs the modified Allan variance of
//! the whole record, the τ takes the noise type of the τ below, as the full curve does for
//! a τ it cannot identify.

use crate::allan::block_sums::{LevelSums, OFFSET_SAMPLES};
use crate::allan::curve::{assign_alpha, compute_curve_from_rate, point_with_interval, Curve};
use crate::allan::deviation::{deviation_from_variance, normalise, DeviationKind};
use crate::allan::noise_id::{b1_alpha, decide_alpha, Lag1, MIN_AVERAGES};
use crate::allan::numerics::CompensatedSum;
use crate::allan::TauGrid;

const KIND: DeviationKind = DeviationKind::Adev;
/// ADEV's noise identification looks at difference orders 0 to 2.
const MAX_DIFFERENCES: u32 = 2;

/// Moments of the first differences d_k = s_{k+1} − s_k of a level's block sums, for the
/// lag-1 autocorrelation of difference order 2.
#[derive(Debug, Clone, Copy, Default)]
struct DiffMoments {
    len: usize,
    sum: CompensatedSum,
    squares: CompensatedSum,
    lag1: CompensatedSum,
    first: f64,
    last: f64,
}

impl DiffMoments {
    fn add(&mut self, d: f64) {
        if self.len == 0 {
            self.first = d;
        } else {
            self.lag1.add(self.last * d);
        }
        self.sum.add(d);
        self.squares.add(d * d);
        self.last = d;
        self.len += 1;
    }

    /// Lag-1 autocorrelation with the mean removed (`None` for zero variance or fewer
    /// than two values): Σ(d − μ)² = Σd² − n·μ² and
    /// Σ(d_k − μ)(d_{k+1} − μ) = Σd_k·d_{k+1} − μ(2Σd − d_0 − d_last) + (n − 1)·μ².
    fn lag1(&self) -> Option<f64> {
        if self.len < 2 {
            return None;
        }
        let n = self.len as f64;
        let total = self.sum.value();
        let mean = total / n;
        let spread = self.squares.value() - n * mean * mean;
        let numerator = self.lag1.value() - mean * (2.0 * total - self.first - self.last)
            + (n - 1.0) * mean * mean;
        (spread > 0.0).then(|| numerator / spread)
    }
}

/// One octave level.
#[derive(Debug, Clone)]
struct Level {
    sums: LevelSums,
    diffs: DiffMoments,
    /// The last block sum (for the next difference).
    last: Option<f64>,
    /// The first half of the next level's block being built.
    half: Option<f64>,
    /// The first block sums while there are at most `MIN_AVERAGES + 1` (for B1).
    early: Vec<f64>,
}

impl Level {
    fn new(m: usize) -> Self {
        Level {
            sums: LevelSums::new(m),
            diffs: DiffMoments::default(),
            last: None,
            half: None,
            early: Vec::new(),
        }
    }
}

/// The incremental ADEV state of one axis.
#[derive(Debug, Clone, Default)]
pub struct AxisAllan {
    /// Samples held until the offset is known.
    head: Vec<f64>,
    offset: Option<f64>,
    /// Σ (y − offset) of the samples pushed through the levels.
    total: CompensatedSum,
    samples: u64,
    levels: Vec<Level>,
}

impl AxisAllan {
    pub fn new() -> Self {
        Self::default()
    }

    /// Samples taken in so far.
    pub fn samples(&self) -> u64 {
        self.samples
    }

    /// Mean of the samples (the bias the deviation is taken about).
    pub fn mean(&self) -> f64 {
        match self.offset {
            None if self.head.is_empty() => 0.0,
            None => self.head.iter().sum::<f64>() / self.head.len() as f64,
            Some(c) => c + self.total.value() / self.samples.max(1) as f64,
        }
    }

    /// Bytes held, for the memory bound (the head buffer and the levels).
    pub fn held_bytes(&self) -> usize {
        self.head.capacity() * 8
            + self
                .levels
                .iter()
                .map(|l| std::mem::size_of::<Level>() + l.early.capacity() * 8)
                .sum::<usize>()
    }

    /// Takes in the next samples of the axis (in time order).
    pub fn extend(&mut self, samples: &[f64]) {
        for &y in samples {
            self.samples += 1;
            match self.offset {
                Some(c) => self.push_level(0, y - c),
                None => {
                    self.head.push(y);
                    if self.head.len() == OFFSET_SAMPLES {
                        self.fix_offset();
                    }
                }
            }
        }
    }

    /// Fixes the offset as the full computation does and pushes the held samples.
    fn fix_offset(&mut self) {
        let head = std::mem::take(&mut self.head);
        let mut sum = CompensatedSum::new();
        head.iter().for_each(|&v| sum.add(v));
        let c = sum.value() / head.len() as f64;
        self.offset = Some(c);
        for y in head {
            self.push_level(0, y - c);
        }
    }

    /// A completed block sum `s` of level `j`, and what it completes above.
    fn push_level(&mut self, j: usize, s: f64) {
        if j == 0 {
            self.total.add(s);
        }
        let mut j = j;
        let mut s = s;
        loop {
            if self.levels.len() == j {
                self.levels.push(Level::new(1 << j));
            }
            let level = &mut self.levels[j];
            level.sums.push::<false>(s);
            if let Some(previous) = level.last {
                level.diffs.add(s - previous);
            }
            level.last = Some(s);
            if level.sums.count <= MIN_AVERAGES + 1 {
                level.early.push(s);
            } else if !level.early.is_empty() {
                level.early = Vec::new();
            }
            match level.half.take() {
                None => {
                    level.half = Some(s);
                    return;
                }
                Some(first) => {
                    s += first;
                    j += 1;
                }
            }
        }
    }

    /// The ADEV curve on the octave grid (the factors `imulab allan --grid octave` takes)
    /// with noise types, EDFs and 68 % intervals, for samples `tau0` seconds apart.
    pub fn curve(&self, tau0: f64) -> Curve {
        let Some(c) = self.offset else {
            return compute_curve_from_rate(&self.head, tau0, KIND, &TauGrid::Octave)
                .map(|(curve, _)| curve)
                .unwrap_or(Curve {
                    kind: KIND,
                    tau0,
                    points: Vec::new(),
                });
        };
        let n = self.samples as usize;
        let phase_points = n + 1;
        let delta = self.mean() - c;
        let factors = TauGrid::Octave.factors(KIND, phase_points, tau0);
        let mut defined = Vec::with_capacity(factors.len());
        let mut identified = Vec::with_capacity(factors.len());
        for &m in &factors {
            let j = m.trailing_zeros() as usize;
            let count = KIND.term_count(m, phase_points);
            let Some(level) = self.levels.get(j) else {
                continue;
            };
            if count == 0 {
                continue;
            }
            let variance = normalise(KIND, level.sums.deviation_sum(), m, count);
            defined.push((m, variance, count));
            identified.push(self.alpha(level, n / m + 1, delta));
        }
        let points = assign_alpha(&identified, KIND)
            .into_iter()
            .zip(defined)
            .map(|(alpha, (m, variance, count))| {
                let tau = m as f64 * tau0;
                let deviation = deviation_from_variance(KIND, variance, tau);
                point_with_interval(KIND, alpha, m, tau, deviation, count, phase_points)
            })
            .collect();
        Curve {
            kind: KIND,
            tau0,
            points,
        }
    }

    /// The noise exponent at one level: lag-1 method, else B1 on the early block sums.
    fn alpha(&self, level: &Level, points: usize, delta: f64) -> Option<i32> {
        let lag1 = decide_alpha(points, MAX_DIFFERENCES, |order| {
            let r = match order {
                0 => level.sums.lag1(delta),
                1 => level.sums.lag1_of_sums(),
                _ => level.diffs.lag1(),
            };
            r.map_or(Lag1::Undefined, Lag1::Value)
        });
        lag1.or_else(|| {
            let m = level.sums.m;
            let averages: Vec<f64> = level.early.iter().map(|s| s / m as f64).collect();
            // ADEV of non-overlapping averages: one term per adjacent pair.
            let terms = averages.len().saturating_sub(1);
            b1_alpha(&averages, m, terms, KIND, || None)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pushing in pieces of any size gives the same state as pushing at once.
    #[test]
    fn pieces_do_not_matter() {
        let data: Vec<f64> = (0..20_000)
            .map(|i| ((i as f64) * 0.37).sin() + 1e-3 * i as f64)
            .collect();
        let mut whole = AxisAllan::new();
        whole.extend(&data);
        let mut pieces = AxisAllan::new();
        for piece in data.chunks(777) {
            pieces.extend(piece);
        }
        let (a, b) = (whole.curve(0.01), pieces.curve(0.01));
        assert_eq!(a.points.len(), b.points.len());
        for (p, q) in a.points.iter().zip(&b.points) {
            assert_eq!(p.deviation, q.deviation);
            assert_eq!(p.alpha, q.alpha);
        }
    }
}
