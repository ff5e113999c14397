//! Allan-family deviations, confidence intervals and the noise-term fit (crate `imulab-allan`,
//! on the store and the bag reader only; the main crate re-exports it as `imulab::allan`).
//!
//! Pipeline: [`input`] reads per-axis rate series (CSV/TSV, .npy, sessions, bags; [`columns`]
//! tells the roles and units of a file's columns) →
//! [`numerics::Phase`] integrates one axis into phase with the mean removed →
//! [`curve::compute_curve`] evaluates a [`deviation::DeviationKind`] over a
//! [`taus::TauGrid`] with [`edf`] confidence intervals and [`noise_id`] noise types →
//! [`fit`] fits the IMU noise model → [`export`] writes the results (the report page, in the
//! main crate's `report` module, is built from them).

pub mod analysis;
pub mod bag_source;
pub mod block_sums;
pub mod columns;
pub mod curve;
pub mod deviation;
pub mod edf;
pub mod export;
pub mod fit;
pub mod input;
mod lanes;
pub mod memory;
mod modified;
pub mod noise_id;
pub mod numerics;
pub mod pipeline;
pub mod session_source;
pub mod sweep;
pub mod taus;
pub mod thermal;
pub mod timings;
pub mod units;

pub use curve::{compute_curve, Curve, CurvePoint};
pub use deviation::DeviationKind;
pub use numerics::Phase;
pub use taus::TauGrid;
