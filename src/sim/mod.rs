//! Sensor simulator: IMU and GNSS error models, scenes, presets, byte-stream serving (crate
//! `imulab-sim`, on the drivers, the store, ingest, the earth model and the noise model only;
//! the main crate re-exports it as `imulab::sim`).
//!
//! - [`rng`]: deterministic per-sensor, per-axis random streams.
//! - [`flicker`]: bias instability as a sum of Gauss-Markov processes.
//! - [`imu_model`]: the IMU error model and its per-sample simulator.
//! - [`gnss_model`]: the GNSS receiver model and its presets.
//! - [`presets`]: named IMUs (the bench pair, consumer, industrial, tactical).
//! - [`scene`]: scene files (TOML) and their checks.
//! - [`runner`]: runs a scene into a sink; [`outputs`]: the sink trait and in-memory sinks.
//! - [`temperature`]: temperature profiles.
//! - [`truth_file`]: truth trajectories read from CSV.
//! - [`motion`]: the truth trajectory generator (segments) and the static truth.
//! - [`attitude`]: tumbles and rate tables at a fixed place.
//! - [`wire`]: records to device protocol bytes (and back, for the reference).
//! - [`serve`]: a scene served as byte streams on ptys (`imulab sim --serve`).

pub mod attitude;
pub mod flicker;
pub mod gnss_model;
pub mod imu_model;
pub mod motion;
pub mod outputs;
pub mod presets;
pub mod rng;
pub mod runner;
pub mod scene;
pub mod serve;
pub mod temperature;
pub mod truth_file;
pub mod wire;
