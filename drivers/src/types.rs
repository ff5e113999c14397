//! Device-independent frame types every codec converts to, in SI units, and the counters
//! every decoder keeps.

use serde::{Deserialize, Serialize};

/// Counters every decoder keeps. Monotonic over the decoder's lifetime.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct DecoderStats {
    /// Frames decoded and accepted.
    pub frames_ok: u64,
    /// Frames whose checksum did not match (dropped).
    pub checksum_errors: u64,
    /// Bytes that ended up in no accepted frame (garbage and rejected frames), line framing
    /// of text protocols excepted.
    pub bytes_skipped: u64,
    /// Frames rejected for exceeding the protocol's maximum length.
    pub frames_too_long: u64,
    /// Frames rejected for being shorter than their header says or malformed.
    pub frames_malformed: u64,
    /// Number of times the decoder lost frame sync after having accepted a frame (see
    /// `codec::StreamBuffer` for the rule).
    pub resyncs: u64,
}

impl DecoderStats {
    /// Adds another decoder's counters into this one (for a multiplexed port).
    pub fn add(&mut self, other: &DecoderStats) {
        self.frames_ok += other.frames_ok;
        self.checksum_errors += other.checksum_errors;
        self.bytes_skipped += other.bytes_skipped;
        self.frames_too_long += other.frames_too_long;
        self.frames_malformed += other.frames_malformed;
        self.resyncs += other.resyncs;
    }
}

/// One inertial measurement in SI units, as the device reported it (sensor frame).
///
/// A field the device did not send is `None`. `sensor_time` is the device's own counter or
/// time as given (ticks, seconds, or GNSS time of week), converted to f64 without rescaling
/// unless the protocol defines the unit.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ImuSample {
    pub sensor_time: Option<f64>,
    /// Angular rate, rad/s.
    pub gyro: Option<[f64; 3]>,
    /// Specific force, m/s².
    pub accel: Option<[f64; 3]>,
    /// Temperature, °C.
    pub temp_c: Option<f64>,
    /// Device status word, protocol specific (0 when the device has none).
    pub status: u32,
}

/// GNSS fix type, in the ordering of NMEA GSA / UBX NAV-PVT.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[repr(u8)]
pub enum FixType {
    #[default]
    NoFix = 0,
    DeadReckoning = 1,
    Fix2D = 2,
    Fix3D = 3,
    GnssDeadReckoning = 4,
    TimeOnly = 5,
    Dgnss = 6,
    RtkFloat = 7,
    RtkFixed = 8,
}

/// One navigation epoch from a receiver, merged from whatever messages carried it.
/// Absent values are `None`; units are SI except lat/lon (degrees).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct GnssFix {
    /// GPS week number, when known.
    pub week: Option<u16>,
    /// GPS time of week, seconds.
    pub tow_s: Option<f64>,
    /// UTC time, nanoseconds since the Unix epoch, when known.
    pub utc_ns: Option<i64>,
    pub lat_deg: Option<f64>,
    pub lon_deg: Option<f64>,
    /// Height above the WGS-84 ellipsoid, m.
    pub height_m: Option<f64>,
    /// Height above mean sea level, m.
    pub height_msl_m: Option<f64>,
    /// Velocity north, east, down, m/s.
    pub vel_ned: Option<[f64; 3]>,
    /// Ground speed, m/s.
    pub speed_mps: Option<f64>,
    /// Course over ground, degrees from true north.
    pub track_deg: Option<f64>,
    /// Heading of the vehicle (where it points, not where it moves), degrees from true
    /// north: NMEA HDT, a dual-antenna NAV-RELPOSNED, or a dead-reckoning receiver's headVeh.
    pub heading_deg: Option<f64>,
    /// Horizontal, vertical and speed accuracy (1σ), m and m/s.
    pub h_acc_m: Option<f64>,
    pub v_acc_m: Option<f64>,
    pub s_acc_mps: Option<f64>,
    pub fix: FixType,
    pub num_sats: Option<u8>,
    pub pdop: Option<f64>,
    pub hdop: Option<f64>,
    pub vdop: Option<f64>,
}

impl GnssFix {
    /// Whether the fix has a position (a fix type other than no fix, latitude and longitude).
    pub fn has_position(&self) -> bool {
        self.fix != FixType::NoFix && self.lat_deg.is_some() && self.lon_deg.is_some()
    }
}
