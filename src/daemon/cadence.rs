//! The hand-over grid: one clock, shared by the device tasks and the writer, on which rows
//! move towards the disk.
//!
//! Each device task collects what it reads into a batch and hands it to the writer at the
//! next point of the grid (`epoch + k × period`), or earlier when the batch is full; the
//! writer wakes for those hand-overs and flushes the store a little after each grid point,
//! once they are written. With every device on the same grid, a period costs the writer
//! one or two wake-ups however many devices there are, instead of one per device per
//! window, and the device thread one timer expiry. Every frame still carries the arrival time
//! of its own read: the grid only decides when rows are handed over, never when bytes are
//! read.

use std::time::{Duration, Instant};

/// Longest wait of the writer after a grid point for the device tasks' hand-overs there
/// ([`flush_lag`]).
pub const FLUSH_LAG_MAX: Duration = Duration::from_millis(10);

/// How long after a grid point the writer flushes if no hand-over woke it earlier: long
/// enough for the device thread's timer (rounded up to its 1 ms resolution) to fire first,
/// so that normally the hand-overs wake the writer and it flushes at once: one wake-up per
/// period. [`FLUSH_LAG_MAX`], or half the period when that is shorter.
pub fn flush_lag(period: Duration) -> Duration {
    FLUSH_LAG_MAX.min(period / 2)
}

/// Grid points `epoch + k × period`, k = 1, 2, ...
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cadence {
    epoch: Instant,
    period: Duration,
}

impl Cadence {
    /// A grid starting at `epoch`; a zero period is taken as 1 ms (the timer resolution).
    pub fn new(epoch: Instant, period: Duration) -> Self {
        Cadence {
            epoch,
            period: period.max(Duration::from_millis(1)),
        }
    }

    pub fn period(&self) -> Duration {
        self.period
    }

    /// The first grid point strictly after `now` (the epoch itself counts as point 0).
    pub fn next_after(&self, now: Instant) -> Instant {
        let since = now.saturating_duration_since(self.epoch).as_nanos();
        let period = self.period.as_nanos();
        let k = since / period + 1;
        // k × period is at most `since` + one period: it fits a Duration as long as `now` does.
        let offset = k.saturating_mul(period);
        self.epoch + Duration::from_nanos(u64::try_from(offset).unwrap_or(u64::MAX))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn next_point_is_strictly_later_and_on_the_grid() {
        let epoch = Instant::now();
        let grid = Cadence::new(epoch, Duration::from_millis(250));
        assert_eq!(grid.next_after(epoch), epoch + Duration::from_millis(250));
        assert_eq!(
            grid.next_after(epoch + Duration::from_millis(249)),
            epoch + Duration::from_millis(250)
        );
        assert_eq!(
            grid.next_after(epoch + Duration::from_millis(250)),
            epoch + Duration::from_millis(500)
        );
        assert_eq!(
            grid.next_after(epoch + Duration::from_millis(1001)),
            epoch + Duration::from_millis(1250)
        );
        // Before the epoch (a clock read earlier than the grid was made): the first point.
        let before = epoch.checked_sub(Duration::from_millis(5)).unwrap_or(epoch);
        assert_eq!(grid.next_after(before), epoch + Duration::from_millis(250));
    }

    #[test]
    fn zero_period_is_the_timer_resolution() {
        let epoch = Instant::now();
        let grid = Cadence::new(epoch, Duration::ZERO);
        assert_eq!(grid.period(), Duration::from_millis(1));
        assert_eq!(grid.next_after(epoch), epoch + Duration::from_millis(1));
    }
}
