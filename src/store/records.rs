//! Row types of the session format: what one IMU sample, GNSS fix or event is on disk.
//! Units and field meanings are the public contract documented in `docs/session-format.md`.

use imulab_drivers::types::FixType;
use serde::{Deserialize, Serialize};

/// One IMU sample with its host timestamps. Missing values are NaN.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ImuRecord {
    /// Host CLOCK_MONOTONIC at arrival, ns.
    pub t_mono_ns: i64,
    /// Host CLOCK_REALTIME at arrival, ns since the Unix epoch.
    pub t_wall_ns: i64,
    /// The device's own counter or time, as given (NaN when the device has none).
    pub t_sensor: f64,
    /// Angular rate in the device's axis frame, rad/s.
    pub gyro: [f64; 3],
    /// Specific force in the device's axis frame, m/s².
    pub accel: [f64; 3],
    /// Temperature, °C (NaN when the device gives none).
    pub temp: f64,
    /// Device status word.
    pub status: u32,
}

/// One GNSS navigation epoch with its host timestamps. Missing values are NaN (or 0 counts).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GnssRecord {
    pub t_mono_ns: i64,
    pub t_wall_ns: i64,
    /// GPS week (0 when unknown).
    pub week: u16,
    /// GPS time of week, s.
    pub tow_s: f64,
    /// UTC, ns since the Unix epoch (i64::MIN when unknown).
    pub utc_ns: i64,
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Height above the WGS-84 ellipsoid, m.
    pub height_m: f64,
    /// Velocity north/east/down, m/s.
    pub vel_ned: [f64; 3],
    pub h_acc_m: f64,
    pub v_acc_m: f64,
    pub s_acc_mps: f64,
    pub fix_type: FixType,
    pub num_sats: u8,
    pub pdop: f64,
    pub hdop: f64,
    pub vdop: f64,
    /// True heading, degrees clockwise from true north (NMEA HDT, a dual-antenna
    /// NAV-RELPOSNED, a dead-reckoning receiver's vehicle heading); NaN when none.
    pub heading_deg: f64,
}

/// What kind of thing an event records.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EventKind {
    SessionStart,
    SessionStop,
    Rotation,
    Connect,
    Disconnect,
    Reconnect,
    Resync,
    ChecksumError,
    Gap,
    QueueOverflow,
    DiskLow,
    Info,
}

/// One entry of `/events`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EventRecord {
    pub t_mono_ns: i64,
    pub t_wall_ns: i64,
    /// Device name, or empty for session-wide events.
    pub device: String,
    pub kind: EventKind,
    /// Free text: counts, durations, error messages.
    pub detail: String,
}

/// One epoch of the true trajectory (simulated sessions only), in `/truth/nav`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TruthNavRecord {
    /// Host-equivalent monotonic time of this epoch, ns (same clock as the IMU rows).
    pub t_mono_ns: i64,
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Height above the WGS-84 ellipsoid, m.
    pub height_m: f64,
    /// Velocity north/east/down, m/s.
    pub vel_ned: [f64; 3],
    /// Attitude body→NED as a unit quaternion, scalar first (w, x, y, z).
    pub quat_nb: [f64; 4],
}

/// The true error state of one simulated IMU at one epoch, in `/truth/imu/<name>`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TruthImuRecord {
    pub t_mono_ns: i64,
    /// Total gyro bias (constant + turn-on + instability + random walk + temperature), rad/s.
    pub gyro_bias: [f64; 3],
    /// Total accel bias, m/s².
    pub accel_bias: [f64; 3],
    /// Error-free angular rate and specific force in the sensor frame.
    pub gyro_true: [f64; 3],
    pub accel_true: [f64; 3],
}
