//! What the imulab tests and benchmarks share, as a crate of its own rather than files
//! included with `#[path]`:
//! - [`allan_check`]: an overlapping Allan deviation, EDF approximations and a noise-term fit
//!   written apart from `imulab::allan`, so the simulator is checked independently;
//! - [`gyro_noise`]: the Allan benchmark's seeded gyro series (white noise + rate random walk);
//! - [`fusion_data`]: truth, IMU increments and GNSS fixes for the fusion tests;
//! - [`live_session`]: a live session written in steps as imulogd does, and `imulab watch`
//!   serving it;
//! - [`space`]: the bytes of an HDF5 chunk file outside its datasets' chunks;
//! - [`browser`]: headless Chromium for the tests that render a page;
//! - [`daemon_support`]: the daemon tests' line protocol, in-memory connectors, daemon builder, ptys
//!   and device byte streams.

pub mod allan_check;
pub mod browser;
pub mod daemon_support;
pub mod fusion_data;
pub mod gyro_noise;
pub mod live_session;
pub mod space;
