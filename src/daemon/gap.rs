//! Gap detection: a pause between samples longer than `gap_factor` nominal periods, and
//! never shorter than [`MIN_GAP_NS`] (USB-serial adapters deliver in bursts: an FTDI chip's
//! latency timer alone holds bytes for up to 16 ms, so arrival times jitter by that much).

/// The shortest pause reported as a gap, ns.
pub const MIN_GAP_NS: i64 = 50_000_000;

/// A detected gap between two consecutive samples of one device.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gap {
    /// Arrival of the last sample before the gap, ns (CLOCK_MONOTONIC).
    pub from_mono_ns: i64,
    /// Arrival of the first sample after it.
    pub to_mono_ns: i64,
    /// Samples the nominal rate expects in between (rounded).
    pub missing_estimate: u64,
}

impl Gap {
    pub fn duration_s(&self) -> f64 {
        (self.to_mono_ns - self.from_mono_ns) as f64 * 1e-9
    }
}

/// Watches arrival times of one device's samples.
#[derive(Debug, Clone)]
pub struct GapDetector {
    period_ns: f64,
    threshold_ns: i64,
    last_mono_ns: Option<i64>,
}

impl GapDetector {
    /// `rate_hz` > 0 and `gap_factor` > 1 (checked by the config).
    pub fn new(rate_hz: f64, gap_factor: f64) -> Self {
        let period_ns = 1e9 / rate_hz;
        GapDetector {
            period_ns,
            threshold_ns: ((period_ns * gap_factor).round() as i64).max(MIN_GAP_NS),
            last_mono_ns: None,
        }
    }

    /// Feeds one sample's arrival time; returns the gap that ended with it, if any.
    pub fn observe(&mut self, mono_ns: i64) -> Option<Gap> {
        let previous = self.last_mono_ns.replace(mono_ns)?;
        let delta = mono_ns - previous;
        (delta > self.threshold_ns).then(|| Gap {
            from_mono_ns: previous,
            to_mono_ns: mono_ns,
            missing_estimate: ((delta as f64 / self.period_ns).round() as u64).saturating_sub(1),
        })
    }

    /// Forget the last arrival, so the next gap is measured from the next sample. (Not used
    /// on a reconnect: there the outage is reported as a gap too.)
    pub fn restart(&mut self) {
        self.last_mono_ns = None;
    }

    /// Arrival of the last sample seen.
    pub fn last_mono_ns(&self) -> Option<i64> {
        self.last_mono_ns
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steady_stream_has_no_gap_and_a_pause_is_one() {
        let mut d = GapDetector::new(100.0, 3.0); // 10 ms period, 50 ms threshold (floor)
        let ms = 1_000_000;
        for k in 0..10 {
            assert_eq!(d.observe(k * 10 * ms), None);
        }
        // Jitter below the threshold is not a gap.
        assert_eq!(d.observe(90 * ms + 29 * ms), None);
        assert_eq!(d.observe(119 * ms), None);
        // 200 ms pause at 100 Hz: 19 samples missing.
        let gap = d.observe(119 * ms + 200 * ms).expect("gap");
        assert_eq!(gap.missing_estimate, 19);
        assert!((gap.duration_s() - 0.2).abs() < 1e-12);
        d.restart();
        assert_eq!(d.observe(10_000 * ms), None);
    }
}
