//! Thermal-chamber characterisation (`imulab thermal`) and the compensation model it exports.
//!
//! - [`polyfit`]: bias against temperature, order from the data, 95 % intervals and bands.
//! - [`drift`]: the slow bias drift (bias instability, rate random walk) from the plateau noise
//!   terms and the variance it adds to a fitted quantity.
//! - [`analysis`]: one axis (fit, hysteresis, warm-up, per-plateau noise) and the thermal lag.
//! - [`warmup`]: the turn-on transient, its profile-likelihood intervals and detection limit.
//! - [`model`]: the versioned compensation model (JSON) and the one function that applies it.
//! - [`plot`]: the report section's SVG plots; [`report`]: the JSON document, text and HTML.

pub mod analysis;
pub mod drift;
pub mod model;
pub mod plot;
pub mod polyfit;
pub mod report;
pub mod warmup;
