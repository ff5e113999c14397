//! From a decoded frame to a session row, shared by `imulogd` and the simulator's server so
//! both stamp and map samples the same way.
//!
//! - [`clock`]: host timestamps taken at arrival (monotonic and wall clock).
//! - [`mapping`]: frames to rows, units and the axis rotation into the body frame.

pub mod clock;
pub mod mapping;
