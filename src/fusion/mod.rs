//! Strapdown INS, loosely coupled error-state Kalman filter with GNSS, RTS smoother, replay
//! engine and accuracy metrics.
//!
//! - [`mechanisation`]: NED strapdown integration of rates or increments (WGS-84).
//! - [`models`]: error-state process model and GNSS / NHC / ZUPT measurement models.
//! - [`eskf`]: the filter (15 or 21 states), Joseph updates, PD watch, closed-loop feedback.
//! - [`align`]: static levelling and heading from the GNSS track.
//! - [`smoother`]: Rauch-Tung-Striebel backward pass.
//! - [`navigator`]: the replay engine (input checks, outages, alignment, output).
//! - [`session`]: replay of a recorded or simulated session from the store.
//! - [`metrics`]: errors against truth, NEES, RMS/p95/max, drift per outage.
//! - [`config`]: the TOML configuration.
//! - [`export`]: trajectory HDF5 / CSV / GeoJSON and error-summary JSON.
//! - [`kfgins`]: KF-GINS text formats (IMU increments, GNSS, .nav, YAML configuration).

pub mod align;
pub mod config;
pub mod eskf;
pub mod export;
pub mod kfgins;
pub mod mechanisation;
pub mod metrics;
pub mod models;
pub mod navigator;
pub mod session;
pub mod smoother;
