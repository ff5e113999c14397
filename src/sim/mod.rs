//! Sensor simulator: IMU and GNSS error models, scenes, presets, byte-stream serving.
//!
//! - [`rng`]: deterministic per-sensor, per-axis random streams.
//! - [`flicker`]: bias instability as a sum of Gauss-Markov processes.
//! - [`imu_model`]: the IMU error model and its per-sample simulator.
//! - [`temperature`]: temperature profiles.

pub mod flicker;
pub mod imu_model;
pub mod rng;
pub mod temperature;
