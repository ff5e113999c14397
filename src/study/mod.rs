//! The bridge from the simulator to the filter, and the sensor-grade study built on it:
//! which IMU grade keeps the position error within a requirement for a GNSS outage of a
//! given length. It stands above both `imulab-sim` and `imulab-fusion`, neither of which
//! knows the other.
//!
//! - [`noise`]: the filter's IMU noise model from a simulator preset or an Allan fit, and the
//!   receiver error model of a simulator GNSS spec.
//! - [`grades`]: the Monte Carlo study (grades × runs × outages), its bisected longest outage
//!   within each requirement and its report.
//! - [`nav_state`] and [`simulated_imu_preset`]: a simulated truth sample as a navigation
//!   state, and the preset a simulated session's IMU was made with.

pub mod grades;
pub mod noise;

use imulab_fusion::mechanisation::NavState;
use imulab_sim::motion::TruthSample;
use imulab_store::Session;

/// The simulator's true state as a navigation state (same time, position, velocity and
/// attitude): a mechanisation started from it follows the truth.
pub fn nav_state(t: &TruthSample) -> NavState {
    NavState {
        t_s: t.t_s,
        lat_rad: t.lat_rad,
        lon_rad: t.lon_rad,
        height_m: t.height_m,
        vel_ned: t.vel_ned,
        quat_nb: t.quat_nb,
    }
}

/// The simulator preset an IMU of a simulated session was made with: the device model
/// `simulated <preset>` that `imulab sim` writes into the manifest (None for real devices
/// and for custom simulated IMUs).
pub fn simulated_imu_preset(session: &Session, device: &str) -> Option<String> {
    let d = session.devices().iter().find(|d| d.name == device)?;
    let preset = d.model.strip_prefix("simulated ")?;
    imulab_sim::presets::imu_preset(preset).map(|_| preset.to_string())
}
