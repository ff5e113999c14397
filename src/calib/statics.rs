//! Static-interval detection: a sample is still when, over a window centred on it, the
//! accelerometer's and the gyro's variances (summed over the axes) stay below a multiple of
//! those of the initial still period and the mean rate stays near that period's mean. The
//! threshold thus comes from the data (the approach of Tedaldi, Pretto and Menegatti, ICRA
//! 2014); runs of still samples long enough are the poses.

use super::recording::Recording;
use anyhow::{bail, Result};

/// How still intervals are found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectorOptions {
    /// The still period at the start the thresholds come from, s.
    pub init_s: f64,
    /// Variance window, s.
    pub window_s: f64,
    /// A window is still below this many times the initial period's variance.
    pub threshold: f64,
    /// Largest mean rate away from the initial period's mean that counts as still, rad/s
    /// (a slow turn about the vertical leaves the accelerometer unchanged).
    pub max_rate: f64,
    /// Shortest still interval kept as a pose, s.
    pub min_static_s: f64,
}

impl Default for DetectorOptions {
    fn default() -> Self {
        DetectorOptions {
            init_s: 30.0,
            window_s: 1.0,
            threshold: 4.0,
            max_rate: 0.5f64.to_radians(),
            min_static_s: 2.0,
        }
    }
}

/// One still interval.
#[derive(Debug, Clone, PartialEq)]
pub struct StaticInterval {
    /// First sample and one past the last.
    pub start: usize,
    pub end: usize,
    pub t_start: f64,
    pub t_end: f64,
    pub accel_mean: [f64; 3],
    pub gyro_mean: [f64; 3],
    /// Standard deviation of the accelerometer samples, per axis.
    pub accel_std: [f64; 3],
}

impl StaticInterval {
    pub fn samples(&self) -> usize {
        self.end - self.start
    }
}

/// What the detector found and the thresholds it used.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    pub intervals: Vec<StaticInterval>,
    /// Summed per-axis variance of the initial period: accelerometer (m/s²)², gyro (rad/s)².
    pub init_accel_var: f64,
    pub init_gyro_var: f64,
    /// Variance thresholds used.
    pub accel_threshold: f64,
    pub gyro_threshold: f64,
    pub window: usize,
}

/// Prefix sums of x and x² of one column, for window means and variances in O(1).
struct Prefix {
    s: Vec<f64>,
    s2: Vec<f64>,
}

impl Prefix {
    fn new(x: impl Iterator<Item = f64>) -> Prefix {
        let (mut s, mut s2) = (vec![0.0], vec![0.0]);
        // Sums of values relative to the first keep the variance exact for large offsets.
        let mut x = x.peekable();
        let origin = x.peek().copied().unwrap_or(0.0);
        let (mut a, mut b) = (0.0, 0.0);
        for v in x {
            let d = v - origin;
            a += d;
            b += d * d;
            s.push(a);
            s2.push(b);
        }
        Prefix { s, s2 }
    }

    /// Mean offset from the first value and variance over rows [i, j).
    fn stats(&self, i: usize, j: usize) -> (f64, f64) {
        let n = (j - i) as f64;
        let m = (self.s[j] - self.s[i]) / n;
        let v = ((self.s2[j] - self.s2[i]) / n - m * m).max(0.0);
        (m, v)
    }
}

fn mean_std(rows: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    let n = rows.len() as f64;
    let mut mean = [0.0; 3];
    for r in rows {
        for k in 0..3 {
            mean[k] += r[k] / n;
        }
    }
    let mut var = [0.0; 3];
    for r in rows {
        for k in 0..3 {
            var[k] += (r[k] - mean[k]).powi(2) / n;
        }
    }
    (mean, var.map(f64::sqrt))
}

/// Finds the still intervals of `rec`.
pub fn detect(rec: &Recording, opts: &DetectorOptions) -> Result<Detection> {
    let n = rec.len();
    let dt = rec.dt();
    if !(dt.is_finite() && dt > 0.0) {
        bail!("{}: too few samples to calibrate ({n})", rec.source);
    }
    let window = ((opts.window_s / dt).round() as usize).max(3) | 1;
    let half = window / 2;
    let init_end = rec.t.partition_point(|&t| t < opts.init_s);
    if init_end < 2 * window || rec.t[n - 1] < opts.init_s {
        bail!(
            "{}: the recording ({:.1} s) must start with a still period of --init-static {} s and go on after it; record at least {} s still first, then the poses",
            rec.source,
            rec.t[n - 1],
            opts.init_s,
            opts.init_s
        );
    }
    let accel: Vec<Prefix> = (0..3)
        .map(|k| Prefix::new(rec.accel.iter().map(|r| r[k])))
        .collect();
    let gyro: Vec<Prefix> = (0..3)
        .map(|k| Prefix::new(rec.gyro.iter().map(|r| r[k])))
        .collect();
    let summed = |p: &[Prefix], i: usize, j: usize| -> ([f64; 3], f64) {
        let mut mean = [0.0; 3];
        let mut var = 0.0;
        for k in 0..3 {
            let (m, v) = p[k].stats(i, j);
            mean[k] = m;
            var += v;
        }
        (mean, var)
    };
    // The initial period's variance as the median of its window variances: a twitch in it
    // does not raise the threshold.
    let median_var = |p: &[Prefix]| {
        let mut v: Vec<f64> = (0..=init_end - window)
            .step_by(half.max(1))
            .map(|i| summed(p, i, i + window).1)
            .collect();
        let mid = v.len() / 2;
        *v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
    };
    // Floors keep noise-free (simulated or quantised) data workable.
    let init_accel_var = median_var(&accel).max(1e-12);
    let init_gyro_var = median_var(&gyro).max(1e-14);
    let (gyro_init_mean, _) = summed(&gyro, 0, init_end);
    let accel_threshold = opts.threshold * init_accel_var;
    let gyro_threshold = opts.threshold * init_gyro_var;
    let mut still = vec![false; n];
    for (i, s) in still
        .iter_mut()
        .enumerate()
        .take(n.saturating_sub(half))
        .skip(half)
    {
        let (lo, hi) = (i - half, i + half + 1);
        let (_, va) = summed(&accel, lo, hi);
        if va > accel_threshold {
            continue;
        }
        let (gm, vg) = summed(&gyro, lo, hi);
        if vg > gyro_threshold {
            continue;
        }
        let offset = (0..3)
            .map(|k| (gm[k] - gyro_init_mean[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        *s = offset <= opts.max_rate;
    }
    let min_len = (opts.min_static_s / dt).round() as usize;
    let mut intervals = Vec::new();
    let mut i = 0;
    while i < n {
        if !still[i] {
            i += 1;
            continue;
        }
        let start = i;
        while i < n && still[i] {
            i += 1;
        }
        // The centred window reaches half a window into the motion on each side; the
        // samples kept are the ones whose whole window was still.
        if i - start >= min_len.max(1) {
            let (accel_mean, accel_std) = mean_std(&rec.accel[start..i]);
            let (gyro_mean, _) = mean_std(&rec.gyro[start..i]);
            intervals.push(StaticInterval {
                start,
                end: i,
                t_start: rec.t[start],
                t_end: rec.t[i - 1],
                accel_mean,
                gyro_mean,
                accel_std,
            });
        }
    }
    Ok(Detection {
        intervals,
        init_accel_var,
        init_gyro_var,
        accel_threshold,
        gyro_threshold,
        window,
    })
}

/// Unit vector of `v` and its length.
pub fn unit(v: [f64; 3]) -> ([f64; 3], f64) {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    ([v[0] / n, v[1] / n, v[2] / n], n)
}

/// The largest angle between any two of the poses' accelerometer directions, and the
/// smallest eigenvalue of their direction scatter (0 when every pose shares a plane or an
/// axis): how well the poses cover the sphere.
pub fn pose_spread(intervals: &[StaticInterval]) -> (f64, f64) {
    let dirs: Vec<[f64; 3]> = intervals.iter().map(|s| unit(s.accel_mean).0).collect();
    let mut widest = 0.0f64;
    for (i, a) in dirs.iter().enumerate() {
        for b in &dirs[i + 1..] {
            let c = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).clamp(-1.0, 1.0);
            widest = widest.max(c.acos());
        }
    }
    let mut scatter = nalgebra::Matrix3::zeros();
    for d in &dirs {
        let v = nalgebra::Vector3::from(*d);
        scatter += v * v.transpose();
    }
    scatter /= dirs.len().max(1) as f64;
    let smallest = scatter.symmetric_eigenvalues().min();
    (widest, smallest)
}
