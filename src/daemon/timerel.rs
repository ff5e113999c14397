//! The relation between GNSS time and host time, so an analysis can put every device on GNSS
//! time. Each fix arrives some latency after its epoch, and latency is never negative, so over
//! a window the largest `gnss − host` difference is the one least delayed: that is the offset
//! estimate. Each window ends in an `info` event whose detail is `time_relation {json}`.

use serde::Serialize;

/// Seconds between the Unix epoch and the GPS epoch (1980-01-06 00:00:00 UTC).
const GPS_EPOCH_UNIX_S: i64 = 315_964_800;
const NS_PER_WEEK: i64 = 604_800 * 1_000_000_000;

/// GPS time (no leap seconds) as ns since the GPS epoch, from week and time of week.
pub fn gps_time_ns(week: u16, tow_s: f64) -> Option<i64> {
    if !tow_s.is_finite() || !(0.0..604_800.0).contains(&tow_s) {
        return None;
    }
    Some(i64::from(week) * NS_PER_WEEK + (tow_s * 1e9).round() as i64)
}

/// One window's estimate, written into the event detail.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TimeRelation {
    /// GPS time (ns since 1980-01-06, no leap seconds) minus host CLOCK_MONOTONIC, ns.
    pub gps_minus_mono_ns: i64,
    /// GPS time minus host CLOCK_REALTIME (as ns since the GPS epoch), ns. Includes the
    /// GPS−UTC leap seconds and the host clock's error.
    pub gps_minus_wall_ns: i64,
    /// Spread of `gps − mono` over the window (arrival-latency jitter), ns.
    pub spread_ns: i64,
    /// Fixes in the window.
    pub fixes: u64,
    /// Host monotonic clock rate error against GNSS since the previous window, ppm.
    pub drift_ppm: Option<f64>,
    /// Host monotonic arrival of the least delayed fix (where the offset holds), ns.
    pub at_mono_ns: i64,
}

impl TimeRelation {
    pub fn event_detail(&self) -> String {
        format!(
            "time_relation {}",
            serde_json::to_string(self).unwrap_or_default()
        )
    }
}

/// Accumulates fixes and yields one [`TimeRelation`] per window.
#[derive(Debug, Clone)]
pub struct TimeRelationTracker {
    window_ns: i64,
    window_start_mono_ns: Option<i64>,
    best: Option<(i64, i64, i64)>, // (gps − mono, gps − wall, mono) of the least delayed fix
    min_offset: i64,
    fixes: u64,
    previous: Option<TimeRelation>,
}

impl TimeRelationTracker {
    pub fn new(window_s: f64) -> Self {
        TimeRelationTracker {
            window_ns: (window_s * 1e9) as i64,
            window_start_mono_ns: None,
            best: None,
            min_offset: i64::MAX,
            fixes: 0,
            previous: None,
        }
    }

    /// Feeds one fix's GNSS time and arrival; returns a relation when a window completes.
    pub fn observe(&mut self, gps_ns: i64, mono_ns: i64, wall_ns: i64) -> Option<TimeRelation> {
        let start = *self.window_start_mono_ns.get_or_insert(mono_ns);
        let offset = gps_ns - mono_ns;
        let wall_offset = gps_ns - (wall_ns - GPS_EPOCH_UNIX_S * 1_000_000_000);
        if self.best.is_none_or(|(best, _, _)| offset > best) {
            self.best = Some((offset, wall_offset, mono_ns));
        }
        self.min_offset = self.min_offset.min(offset);
        self.fixes += 1;
        if mono_ns - start < self.window_ns {
            return None;
        }
        let (best, best_wall, best_mono) = self.best?;
        let drift_ppm = self.previous.and_then(|p| {
            let dt = (best_mono - p.at_mono_ns) as f64;
            (dt > 0.0).then(|| (best - p.gps_minus_mono_ns) as f64 / dt * 1e6)
        });
        let relation = TimeRelation {
            gps_minus_mono_ns: best,
            gps_minus_wall_ns: best_wall,
            spread_ns: best - self.min_offset,
            fixes: self.fixes,
            drift_ppm,
            at_mono_ns: best_mono,
        };
        self.previous = Some(relation);
        self.window_start_mono_ns = None;
        self.best = None;
        self.min_offset = i64::MAX;
        self.fixes = 0;
        Some(relation)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn least_delayed_fix_gives_the_offset_and_drift_is_measured() {
        let mut t = TimeRelationTracker::new(1.0);
        let true_offset = 1_400_000_000_000_000_000i64;
        // 10 Hz fixes; latencies 30..70 ms; the host clock runs 10 ppm fast.
        let mut out = Vec::new();
        for k in 0..25i64 {
            let gps = true_offset + k * 100_000_000;
            let latency = 30_000_000 + (k * 7 % 5) * 10_000_000;
            let mono = (k * 100_000_000) as f64 * (1.0 + 10e-6);
            if let Some(r) = t.observe(gps, mono as i64 + latency, 0) {
                out.push(r);
            }
        }
        assert_eq!(out.len(), 2);
        // Minimum latency is 30 ms: offset = true − 30 ms − (clock gain, ≤ 10 µs).
        let err = (out[0].gps_minus_mono_ns - (true_offset - 30_000_000)).abs();
        assert!(err <= 10_000, "offset error {err} ns");
        assert!((out[0].spread_ns - 40_000_000).abs() < 20_000);
        assert_eq!(out[0].fixes, 11);
        let drift = out[1].drift_ppm.expect("drift");
        assert!((drift + 10.0).abs() < 0.5, "drift {drift} ppm");
    }

    #[test]
    fn gps_time_rejects_nonsense() {
        assert_eq!(gps_time_ns(2000, f64::NAN), None);
        assert_eq!(gps_time_ns(2000, 604_800.0), None);
        assert_eq!(gps_time_ns(1, 1.5), Some(NS_PER_WEEK + 1_500_000_000));
    }
}
