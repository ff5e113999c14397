//! The systemd watchdog (`WatchdogSec=`, seen as `WATCHDOG_USEC`), fed without a timer of its
//! own: `WATCHDOG=1` goes out only while both of the daemon's threads turn over.
//!
//! - The writer thread wakes at every point of the hand-over grid anyway
//!   ([`super::cadence`]); at the first of its turns that comes half the watchdog interval
//!   (less half a grid period) after the last feed, it asks [`Watchdog::writer_turn`].
//! - The device thread shows it is alive by handing batches over ([`Watchdog::device_alive`],
//!   one clock read and an atomic store per hand-over). If it did so within the last half
//!   interval, the writer feeds the watchdog itself. Otherwise (every device silent or absent)
//!   the writer nudges the device thread, and a task there feeds it
//!   ([`Watchdog::answer_nudges`]): a wake-up of the device thread only when nothing else woke
//!   it.
//!
//! A wedged writer never turns, a wedged device thread never answers: either way the feeding
//! stops and systemd restarts the service. The device thread carries no pending timer for
//! this: a pending tokio timer would give every park of that thread a timeout, i.e. cost at
//! every frame's wake-up (docs/bench/daemon.md, "Where a wake-up's cost goes").

use std::sync::atomic::{AtomicI64, Ordering};
use std::time::Duration;

use tokio::sync::Notify;

use super::clock;

/// What the writer's turn decided.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Turn {
    /// Not due yet.
    Wait,
    /// Both threads alive: `WATCHDOG=1` now.
    Feed,
    /// The device thread showed no sign of life lately: ask it to answer.
    Nudge,
    /// A nudge went unanswered for half an interval: the device thread is stuck; no feeding.
    Stalled { since_ns: i64 },
}

/// The watchdog state shared by the writer thread and the device thread.
#[derive(Debug)]
pub struct Watchdog {
    /// Feed at least this often, ns: half of the watchdog timeout.
    interval_ns: i64,
    /// CLOCK_MONOTONIC of the last `WATCHDOG=1`.
    last_feed_ns: AtomicI64,
    /// CLOCK_MONOTONIC of the device thread's last sign of life.
    device_alive_ns: AtomicI64,
    /// When the pending nudge was sent; `i64::MIN`: none pending.
    nudged_ns: AtomicI64,
    nudge: Notify,
}

impl Watchdog {
    /// The watchdog systemd asked for (`WATCHDOG_USEC`, and `WATCHDOG_PID` if set naming this
    /// process), or None.
    pub fn from_env() -> Option<Watchdog> {
        sd_notify::watchdog_enabled().map(|timeout| Watchdog::new(timeout, clock::mono_ns()))
    }

    /// A watchdog of `timeout`, both threads taken as alive and fed at `now_ns`.
    pub fn new(timeout: Duration, now_ns: i64) -> Watchdog {
        let interval_ns = i64::try_from(timeout.as_nanos() / 2).unwrap_or(i64::MAX);
        Watchdog {
            interval_ns: interval_ns.max(1),
            last_feed_ns: AtomicI64::new(now_ns),
            device_alive_ns: AtomicI64::new(now_ns),
            nudged_ns: AtomicI64::new(i64::MIN),
            nudge: Notify::new(),
        }
    }

    /// How often it is fed: half the timeout.
    pub fn interval(&self) -> Duration {
        Duration::from_nanos(u64::try_from(self.interval_ns).unwrap_or(0))
    }

    /// The device thread is alive at `now_ns` (a device task handed a batch over).
    pub fn device_alive(&self, now_ns: i64) {
        self.device_alive_ns.store(now_ns, Ordering::Relaxed);
    }

    /// What the writer's turn at `now_ns` should do; `early_ns`: how much before the due time
    /// a turn may already feed (half the writer's wake-up period, so that the feed is not
    /// up to one period late).
    pub fn decide(&self, now_ns: i64, early_ns: i64) -> Turn {
        let last_feed = self.last_feed_ns.load(Ordering::Relaxed);
        if now_ns.saturating_sub(last_feed).saturating_add(early_ns) < self.interval_ns {
            return Turn::Wait;
        }
        let alive = self.device_alive_ns.load(Ordering::Relaxed);
        if now_ns.saturating_sub(alive) < self.interval_ns {
            return Turn::Feed;
        }
        let nudged = self.nudged_ns.load(Ordering::Relaxed);
        if nudged != i64::MIN && now_ns.saturating_sub(nudged) >= self.interval_ns {
            Turn::Stalled { since_ns: nudged }
        } else {
            Turn::Nudge
        }
    }

    /// Sends `WATCHDOG=1` and notes the time.
    fn feed(&self, now_ns: i64) {
        self.last_feed_ns.store(now_ns, Ordering::Relaxed);
        if let Err(e) = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]) {
            tracing::debug!("sd_notify WATCHDOG=1 failed: {e}");
        }
    }

    /// The writer's turn: feeds, nudges the device thread, or (stuck device thread) warns.
    pub fn writer_turn(&self, now_ns: i64, early_ns: i64) {
        match self.decide(now_ns, early_ns) {
            Turn::Wait => {}
            Turn::Feed => self.feed(now_ns),
            Turn::Nudge => {
                // The first nudge of an episode starts its clock; repeated ones keep it.
                let _ = self.nudged_ns.compare_exchange(
                    i64::MIN,
                    now_ns,
                    Ordering::Relaxed,
                    Ordering::Relaxed,
                );
                self.nudge.notify_one();
            }
            Turn::Stalled { since_ns } => {
                tracing::warn!(
                    "the device thread has not answered for {} ms: not feeding the watchdog",
                    now_ns.saturating_sub(since_ns) / 1_000_000
                );
                // Said once per interval.
                self.nudged_ns.store(now_ns, Ordering::Relaxed);
            }
        }
    }

    /// The device thread's side, run as a task on its runtime: answers each nudge by
    /// feeding the watchdog. Never returns (abort it at shutdown).
    pub async fn answer_nudges(&self) {
        loop {
            self.nudge.notified().await;
            let now = clock::mono_ns();
            self.nudged_ns.store(i64::MIN, Ordering::Relaxed);
            self.device_alive(now);
            self.feed(now);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: i64 = 1_000_000;

    #[test]
    fn fed_at_half_the_timeout_while_the_device_thread_hands_over() {
        let w = Watchdog::new(Duration::from_millis(400), 0);
        assert_eq!(w.interval(), Duration::from_millis(200));
        assert_eq!(w.decide(100 * MS, 0), Turn::Wait);
        // Half a writer period early counts.
        assert_eq!(w.decide(190 * MS, 0), Turn::Wait);
        assert_eq!(w.decide(190 * MS, 10 * MS), Turn::Feed);
        w.device_alive(150 * MS);
        w.writer_turn(200 * MS, 0);
        assert_eq!(w.decide(300 * MS, 0), Turn::Wait, "just fed");
        // Hand-overs keep coming: fed again an interval later, no nudge.
        w.device_alive(390 * MS);
        assert_eq!(w.decide(400 * MS, 0), Turn::Feed);
    }

    #[test]
    fn a_silent_device_thread_is_nudged_and_a_stuck_one_stops_the_feeding() {
        let w = Watchdog::new(Duration::from_millis(400), 0);
        // No hand-over since the start: nudge, not feed.
        assert_eq!(w.decide(250 * MS, 0), Turn::Nudge);
        w.writer_turn(250 * MS, 0);
        // Unanswered for less than an interval: nudged again, never fed.
        assert_eq!(w.decide(400 * MS, 0), Turn::Nudge);
        w.writer_turn(400 * MS, 0);
        // Unanswered for an interval since the first nudge: stalled, still no feed.
        assert_eq!(w.decide(450 * MS, 0), Turn::Stalled { since_ns: 250 * MS });
        w.writer_turn(450 * MS, 0);
        assert_eq!(w.last_feed_ns.load(Ordering::Relaxed), 0, "never fed");
        // The thread comes back (a hand-over): fed at the next turn.
        w.device_alive(460 * MS);
        assert_eq!(w.decide(470 * MS, 0), Turn::Feed);
    }

    #[tokio::test]
    async fn a_nudge_is_answered_by_the_device_thread_task() {
        let w = std::sync::Arc::new(Watchdog::new(Duration::from_millis(400), 0));
        let answering = {
            let w = w.clone();
            tokio::spawn(async move { w.answer_nudges().await })
        };
        let now = clock::mono_ns();
        assert_eq!(w.decide(now, 0), Turn::Nudge);
        w.writer_turn(now, 0);
        // The answer marks the thread alive and feeds (with no NOTIFY_SOCKET: no message).
        for _ in 0..100 {
            if w.last_feed_ns.load(Ordering::Relaxed) >= now {
                break;
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        assert!(
            w.last_feed_ns.load(Ordering::Relaxed) >= now,
            "not answered"
        );
        assert!(w.device_alive_ns.load(Ordering::Relaxed) >= now);
        assert_eq!(w.nudged_ns.load(Ordering::Relaxed), i64::MIN);
        answering.abort();
    }
}
