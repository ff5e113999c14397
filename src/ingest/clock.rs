//! Host timestamps taken at byte arrival: CLOCK_MONOTONIC (ordering, rates, gaps) and
//! CLOCK_REALTIME (wall time), both in integer nanoseconds.

use nix::time::{clock_gettime, ClockId};

/// The pair of host clocks read together at one arrival.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Arrival {
    pub mono_ns: i64,
    pub wall_ns: i64,
}

fn read_ns(clock: ClockId) -> i64 {
    // clock_gettime on these two clocks cannot fail on Linux (valid id, valid pointer);
    // 0 is returned rather than panicking if it ever did.
    clock_gettime(clock)
        .map(|t| t.tv_sec() * 1_000_000_000 + t.tv_nsec())
        .unwrap_or(0)
}

/// CLOCK_MONOTONIC now, ns.
pub fn mono_ns() -> i64 {
    read_ns(ClockId::CLOCK_MONOTONIC)
}

/// CLOCK_REALTIME now, ns since the Unix epoch.
pub fn wall_ns() -> i64 {
    read_ns(ClockId::CLOCK_REALTIME)
}

/// Both clocks, monotonic first.
pub fn now() -> Arrival {
    let mono_ns = mono_ns();
    Arrival {
        mono_ns,
        wall_ns: wall_ns(),
    }
}
