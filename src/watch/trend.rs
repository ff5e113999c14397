//! A time series of bounded size (temperature against time): values are averaged into
//! bins of equal length, and when there are too many bins, neighbouring pairs are merged
//! and the bin length doubles. A day holds the same number of points as a minute.

use serde::Serialize;

/// Most bins kept.
pub const MAX_BINS: usize = 512;

/// One bin: its time span and the mean, min and max of its values.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Bin {
    pub start_ns: i64,
    pub end_ns: i64,
    pub count: u64,
    sum: f64,
    pub min: f64,
    pub max: f64,
}

impl Bin {
    pub fn mean(&self) -> f64 {
        self.sum / self.count as f64
    }

    fn merge(&mut self, other: &Bin) {
        self.end_ns = other.end_ns;
        self.count += other.count;
        self.sum += other.sum;
        self.min = self.min.min(other.min);
        self.max = self.max.max(other.max);
    }
}

/// The bounded series.
#[derive(Debug, Clone, Serialize)]
pub struct Trend {
    /// Bin length, ns.
    pub bin_ns: i64,
    origin_ns: Option<i64>,
    pub bins: Vec<Bin>,
}

impl Trend {
    /// An empty series whose bins start `bin_ns` long.
    pub fn new(bin_ns: i64) -> Self {
        Trend {
            bin_ns: bin_ns.max(1),
            origin_ns: None,
            bins: Vec::new(),
        }
    }

    /// Adds value `v` at time `t_ns` (times non-decreasing; non-finite values are skipped).
    pub fn push(&mut self, t_ns: i64, v: f64) {
        if !v.is_finite() {
            return;
        }
        let origin = *self.origin_ns.get_or_insert(t_ns);
        let index = (t_ns - origin).max(0) / self.bin_ns;
        let start = origin + index * self.bin_ns;
        match self.bins.last_mut() {
            Some(last) if last.start_ns == start => {
                last.end_ns = t_ns;
                last.count += 1;
                last.sum += v;
                last.min = last.min.min(v);
                last.max = last.max.max(v);
            }
            _ => {
                self.bins.push(Bin {
                    start_ns: start,
                    end_ns: t_ns,
                    count: 1,
                    sum: v,
                    min: v,
                    max: v,
                });
                if self.bins.len() > MAX_BINS {
                    self.coarsen();
                }
            }
        }
    }

    /// Doubles the bin length, merging the bins that fall into one.
    fn coarsen(&mut self) {
        let origin = self.origin_ns.unwrap_or(0);
        self.bin_ns *= 2;
        let mut merged: Vec<Bin> = Vec::with_capacity(MAX_BINS / 2 + 1);
        for bin in &self.bins {
            let start = origin + (bin.start_ns - origin) / self.bin_ns * self.bin_ns;
            match merged.last_mut() {
                Some(last) if last.start_ns == start => last.merge(bin),
                _ => merged.push(Bin {
                    start_ns: start,
                    ..*bin
                }),
            }
        }
        self.bins = merged;
    }

    /// The latest value's bin mean, if any.
    pub fn last_mean(&self) -> Option<f64> {
        self.bins.last().map(Bin::mean)
    }

    /// Min and max over all bins.
    pub fn range(&self) -> Option<(f64, f64)> {
        let lo = self.bins.iter().map(|b| b.min).reduce(f64::min)?;
        let hi = self.bins.iter().map(|b| b.max).reduce(f64::max)?;
        Some((lo, hi))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stays_bounded_and_keeps_the_mean() {
        let mut t = Trend::new(1_000_000_000);
        let n = 200_000i64;
        for i in 0..n {
            // A day at ~2.3 Hz.
            t.push(i * 432_000_000, (i % 100) as f64);
        }
        assert!(t.bins.len() <= MAX_BINS, "{}", t.bins.len());
        assert!(t.bins.len() > MAX_BINS / 4, "{}", t.bins.len());
        let count: u64 = t.bins.iter().map(|b| b.count).sum();
        assert_eq!(count, n as u64);
        let mean = t
            .bins
            .iter()
            .map(|b| b.mean() * b.count as f64)
            .sum::<f64>()
            / n as f64;
        assert!((mean - 49.5).abs() < 1e-9, "{mean}");
        assert_eq!(t.range(), Some((0.0, 99.0)));
        for w in t.bins.windows(2) {
            assert!(w[0].end_ns < w[1].start_ns + t.bin_ns);
            assert!(w[0].start_ns < w[1].start_ns);
        }
    }
}
