//! imulab: bench characterisation of inertial sensors.
//!
//! - [`store`]: the session format (manifest + rotating HDF5 chunk files), writer and reader.
//! - [`daemon`]: `imulogd`, the acquisition daemon.
//! - [`allan`]: Allan-family deviations, confidence intervals, noise-term fit and reports.
//! - [`fusion`]: strapdown INS, error-state Kalman filter, replay and sensor-grade studies.
//! - [`sim`]: IMU/GNSS error models, scenes and byte-stream serving.
//! - [`cli`]: the `imulab` subcommands.

pub mod allan;
pub mod cli;
pub mod daemon;
pub mod fusion;
pub mod sim;
pub mod store;
