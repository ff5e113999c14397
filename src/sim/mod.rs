//! Sensor simulator: IMU and GNSS error models, scenes, presets, byte-stream serving.
//!
//! - [`rng`]: deterministic per-sensor, per-axis random streams.
//! - [`flicker`]: bias instability as a sum of Gauss-Markov processes.
//! - [`imu_model`]: the IMU error model and its per-sample simulator.
//! - [`presets`]: named IMUs (the bench pair, consumer, industrial, tactical).
//! - [`temperature`]: temperature profiles.
//! - [`motion`]: the truth trajectory generator (segments) and the static truth.

pub mod flicker;
pub mod imu_model;
pub mod motion;
pub mod presets;
pub mod rng;
pub mod temperature;
