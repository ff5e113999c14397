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
//!
//! [`HandoverTimer`] is what a device task waits on for its next grid point.

use std::io;
use std::os::fd::{AsFd, AsRawFd, RawFd};
use std::task::{ready, Context, Poll};
use std::time::{Duration, Instant};

use nix::errno::Errno;
use nix::sys::time::TimeSpec;
use nix::sys::timerfd::{ClockId, Expiration, TimerFd, TimerFlags, TimerSetTimeFlags};
use tokio::io::unix::AsyncFd;
use tokio::io::Interest;

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

/// A timerfd as tokio's [`AsyncFd`] wants it.
struct Timer(TimerFd);

impl AsRawFd for Timer {
    fn as_raw_fd(&self) -> RawFd {
        self.0.as_fd().as_raw_fd()
    }
}

/// A device task's hand-over timer: a timerfd on CLOCK_MONOTONIC (the clock of the grid and
/// of the arrival times), armed at an absolute grid point and waited for through the
/// runtime's epoll set.
///
/// Not a tokio timer, because of what one costs while it is pending, which at the nominal
/// rate is nearly always (a device's first read of a period arms it): every park of the
/// device thread then carries a timeout, so the time driver reads the clock for it and the
/// kernel arms and cancels a high-resolution timer in each `epoll_wait`, i.e. at every
/// frame's wake-up. The timerfd's kernel timer is set once per period (one
/// `timerfd_settime`), and the device thread's `epoll_wait` blocks without a timeout
/// (docs/bench/daemon.md, "Where a wake-up's cost goes").
pub struct HandoverTimer {
    fd: AsyncFd<Timer>,
}

impl HandoverTimer {
    /// An unarmed timer. Must be called inside a tokio runtime with I/O enabled.
    pub fn new() -> io::Result<Self> {
        let timer = TimerFd::new(
            ClockId::CLOCK_MONOTONIC,
            TimerFlags::TFD_NONBLOCK | TimerFlags::TFD_CLOEXEC,
        )?;
        // SAFETY: the timerfd is owned by the `Timer` that the AsyncFd owns, stays open until
        // it is dropped, and `as_raw_fd` always returns it.
        let fd = unsafe { AsyncFd::register_with_interest(Timer(timer), Interest::READABLE) }
            .map_err(|e| e.into_parts().1)?;
        Ok(HandoverTimer { fd })
    }

    /// Fires at `at_mono_ns` (CLOCK_MONOTONIC, ns), replacing an earlier setting; a point
    /// already passed fires at once.
    pub fn arm(&self, at_mono_ns: i64) -> io::Result<()> {
        // (A zero time would disarm the timer instead.)
        let at = at_mono_ns.max(1);
        let at = TimeSpec::new(at.div_euclid(1_000_000_000), at.rem_euclid(1_000_000_000));
        self.fd.get_ref().0.set(
            Expiration::OneShot(at),
            TimerSetTimeFlags::TFD_TIMER_ABSTIME,
        )?;
        Ok(())
    }

    /// `Ready` once the armed point has passed (taking the expiry, so the next poll waits for
    /// the next arming); `Pending` registers `cx`'s waker.
    pub fn poll_fired(&self, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        loop {
            let mut guard = ready!(self.fd.poll_read_ready(cx))?;
            // Reads the expiry count without blocking (the fd is non-blocking).
            match guard.get_inner().0.wait() {
                Ok(()) => return Poll::Ready(Ok(())),
                // Readiness left from an expiry taken before a re-arming.
                Err(Errno::EAGAIN) => guard.clear_ready(),
                Err(e) => return Poll::Ready(Err(e.into())),
            }
        }
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

    #[tokio::test]
    async fn handover_timer_fires_at_the_armed_point_and_once() {
        let timer = HandoverTimer::new().unwrap();
        let now = crate::clock::mono_ns();
        timer.arm(now + 30_000_000).unwrap();
        std::future::poll_fn(|cx| timer.poll_fired(cx))
            .await
            .unwrap();
        let fired = crate::clock::mono_ns();
        assert!(
            fired >= now + 30_000_000,
            "fired {} ns early",
            now + 30_000_000 - fired
        );
        // The expiry was taken: the next wait lasts until the next arming.
        let again = tokio::time::timeout(
            Duration::from_millis(50),
            std::future::poll_fn(|cx| timer.poll_fired(cx)),
        )
        .await;
        assert!(again.is_err(), "fired again without being armed");
        // Re-armed (a point already passed fires at once), and replaced by a later arming.
        timer.arm(fired).unwrap();
        std::future::poll_fn(|cx| timer.poll_fired(cx))
            .await
            .unwrap();
        timer.arm(fired).unwrap();
        let later = crate::clock::mono_ns() + 40_000_000;
        timer.arm(later).unwrap();
        std::future::poll_fn(|cx| timer.poll_fired(cx))
            .await
            .unwrap();
        assert!(crate::clock::mono_ns() >= later);
    }
}
