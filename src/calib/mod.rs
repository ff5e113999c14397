//! IMU calibration without a rate table, and with one: still poses found in the data, the
//! accelerometer fitted to gravity magnitude, the gyro to the rotations between poses, a
//! six-position mode, a rate-table mode, and the calibration file applied everywhere with
//! `--calibration` (docs/calibration.md).
//!
//! - [`recording`]: a session device or a file read into memory.
//! - [`statics`]: the still-interval detector.
//! - [`lsq`]: nonlinear least squares (the `levenberg-marquardt` crate) with uncertainties.
//! - [`accel`]: bias, scale factors and misalignment from gravity magnitude.
//! - [`gyro`]: scale factors and misalignment from the rotations between poses.
//! - [`six_position`]: the six-position test with known orientations.
//! - [`rate_table`]: gyro scale factors, misalignment and non-linearity from table rates
//!   (one mounting, or x, y and z on the spindle in turn).
//! - [`file`]: the calibration document, its Kalibr and MATLAB forms, and the [`file::Corrector`]
//!   that applies it.
//! - [`source`]: a sample source whose gyro and accel channels are corrected on the way in.
//! - [`truth`]: the true calibration of a simulated IMU, to score a fit against.
//! - [`run`]: what `imulab calibrate` does, from a recording to a document.

pub mod accel;
pub mod file;
pub mod gyro;
pub mod lsq;
pub mod rate_table;
pub mod recording;
pub mod run;
pub mod six_position;
pub mod source;
pub mod statics;
pub mod truth;

pub use file::{Calibration, Corrector, TriadModel};
