//! imulab: bench characterisation of inertial sensors.
//!
//! - [`store`]: the session format (manifest + rotating HDF5 chunk files), writer and reader.
//! - [`bag`]: ROS 1 bags and ROS 2 bags / MCAP files: topics, messages, decoding.
//! - [`daemon`]: `imulogd`, the acquisition daemon.
//! - [`allan`]: Allan-family deviations, confidence intervals and the noise-term fit.
//! - [`report`]: the HTML page, plots, CSV and datasheet table of an analysis, with outage
//!   answers and the data's health.
//! - [`fusion`]: strapdown INS, error-state Kalman filter, replay, metrics and the KF-GINS formats.
//! - [`study`]: the sensor-grade study and the simulator-to-filter noise mapping it uses.
//! - [`earth`]: the WGS-84 earth model (gravity, radii, rotation) shared by sim and fusion.
//! - [`noise`]: the IMU noise model's terms, shared by the Allan fit, the simulator and fusion.
//! - [`sim`]: IMU/GNSS error models, scenes and byte-stream serving.
//! - [`thermal`]: thermal-chamber characterisation and the compensation model.
//! - [`calib`]: multi-position, six-position and rate-table calibration and its file.
//! - [`watch`]: `imulab watch`, the live page of a session being recorded.
//! - [`cli`]: the `imulab` subcommands.

pub use imulab_allan as allan;
pub use imulab_bag as bag;
pub use imulab_calib as calib;
pub mod cli;
pub use imulab_daemon as daemon;
pub use imulab_earth as earth;
pub use imulab_fusion as fusion;
pub use imulab_noise as noise;
pub mod report;
pub use imulab_sim as sim;
pub use imulab_store as store;
pub use imulab_study as study;
pub use imulab_thermal as thermal;
pub mod watch;
