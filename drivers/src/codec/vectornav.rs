//! VectorNav VN-100/VN-200/VN-300 serial output (facts from the VN-100 user manual UM001,
//! "Binary Output" and "Async Data Output" chapters).
//!
//! Binary output packet: sync `0xFA`, one group byte (bit 0 Common, 1 Time, 2 IMU, 3 GNSS,
//! 4 Attitude, 5 INS, 6 GNSS2, bit 7 extension), one little-endian 16-bit field word per
//! selected group (bit 15 extension), the selected fields in group then bit order
//! (little-endian, float32 unless noted), and a big-endian CRC16-CCITT (polynomial 0x1021,
//! initial value 0) over everything after the sync byte, so the CRC of the packet including
//! its CRC is 0. The packet carries no length: it follows from the field words and the
//! field sizes of the manual, so only groups whose sizes this decoder knows (Common, Time,
//! IMU, Attitude, first field word) can be framed; a packet selecting anything else is
//! rejected as malformed (counted, then resynchronised on the next sync byte).
//!
//! Async ASCII output: `$VNxxx,f1,f2,...*CC\r\n` where `CC` is the 8-bit XOR of the bytes
//! between `$` and `*` as two hex digits, or `*CCCC`, the same CRC16 as the binary packets
//! over the same bytes, as four hex digits. The register-value sentences `$VNYPR`,
//! `$VNQTN`, `$VNYMR`, `$VNQMR`, `$VNMAG`, `$VNACC`, `$VNGYR`, `$VNMAR`, `$VNIMU` and `$VNDTV`
//! are decoded; other `$VN` sentences (register read/write replies, errors) are kept as
//! text and are no samples.
//!
//! Units are the manual's: angles °, angular rate rad/s, acceleration m/s², magnetic field
//! gauss, temperature °C, pressure kPa, time ns, delta theta °, delta velocity m/s. A
//! sample without a rate (or acceleration) but with delta theta (or delta velocity) takes
//! the rate as the delta over the message's own integration interval (delta time): a sensor
//! set to output integrated motion logs the same gyro and accelerometer rows.

use crc::{Crc, Table, CRC_16_XMODEM};

use super::reading::DeviceClock;
use super::{
    accepted_frames, Decoder, EncodeError, Encoder, ImuOutput, Reject, RowsFrom, Scan, StreamBuffer,
};
use crate::types::{DecoderStats, ImuSample};

/// Binary packet sync byte.
pub const SYNC: u8 = 0xFA;
/// Longest async ASCII sentence accepted (the manual's longest register is well below).
pub const MAX_ASCII_LEN: usize = 256;
/// Auto-detection needs at least this many checksummed VectorNav frames in the sample.
pub const DETECT_MIN_FRAMES: u32 = 3;

/// CRC16-CCITT as the manual specifies it (the XMODEM parameters), slice-by-16 table.
static CRC16: Crc<u16, Table<16>> = Crc::<u16, Table<16>>::new(&CRC_16_XMODEM);

/// Group bits of the group byte.
pub mod group {
    pub const COMMON: u8 = 0x01;
    pub const TIME: u8 = 0x02;
    pub const IMU: u8 = 0x04;
    pub const ATTITUDE: u8 = 0x10;
}

/// Common group (group 1) field bits.
pub mod common {
    pub const TIME_STARTUP: u16 = 1 << 0;
    pub const TIME_GPS: u16 = 1 << 1;
    pub const TIME_SYNC_IN: u16 = 1 << 2;
    pub const YAW_PITCH_ROLL: u16 = 1 << 3;
    pub const QUATERNION: u16 = 1 << 4;
    pub const ANGULAR_RATE: u16 = 1 << 5;
    pub const POSITION: u16 = 1 << 6;
    pub const VELOCITY: u16 = 1 << 7;
    pub const ACCEL: u16 = 1 << 8;
    pub const IMU: u16 = 1 << 9;
    pub const MAG_PRES: u16 = 1 << 10;
    pub const DELTA_THETA_VEL: u16 = 1 << 11;
    pub const INS_STATUS: u16 = 1 << 12;
    pub const SYNC_IN_CNT: u16 = 1 << 13;
    pub const TIME_GPS_PPS: u16 = 1 << 14;
}

/// Time group (group 2) field bits.
pub mod time {
    pub const TIME_STARTUP: u16 = 1 << 0;
    pub const TIME_GPS: u16 = 1 << 1;
    pub const GPS_TOW: u16 = 1 << 2;
    pub const GPS_WEEK: u16 = 1 << 3;
    pub const TIME_SYNC_IN: u16 = 1 << 4;
    pub const TIME_GPS_PPS: u16 = 1 << 5;
    pub const TIME_UTC: u16 = 1 << 6;
    pub const SYNC_IN_CNT: u16 = 1 << 7;
    pub const SYNC_OUT_CNT: u16 = 1 << 8;
    pub const TIME_STATUS: u16 = 1 << 9;
}

/// IMU group (group 3) field bits.
pub mod imu {
    pub const IMU_STATUS: u16 = 1 << 0;
    pub const UNCOMP_MAG: u16 = 1 << 1;
    pub const UNCOMP_ACCEL: u16 = 1 << 2;
    pub const UNCOMP_GYRO: u16 = 1 << 3;
    pub const TEMP: u16 = 1 << 4;
    pub const PRES: u16 = 1 << 5;
    pub const DELTA_THETA: u16 = 1 << 6;
    pub const DELTA_VEL: u16 = 1 << 7;
    pub const MAG: u16 = 1 << 8;
    pub const ACCEL: u16 = 1 << 9;
    pub const ANGULAR_RATE: u16 = 1 << 10;
}

/// Attitude group (group 5) field bits.
pub mod attitude {
    pub const VPE_STATUS: u16 = 1 << 0;
    pub const YAW_PITCH_ROLL: u16 = 1 << 1;
    pub const QUATERNION: u16 = 1 << 2;
    pub const DCM: u16 = 1 << 3;
    pub const MAG_NED: u16 = 1 << 4;
    pub const ACCEL_NED: u16 = 1 << 5;
    pub const LINEAR_ACCEL_BODY: u16 = 1 << 6;
    pub const LINEAR_ACCEL_NED: u16 = 1 << 7;
    pub const YPR_U: u16 = 1 << 8;
}

/// The output configuration of a binary packet: the field word of each supported group
/// (0 = group not selected).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct VnOutputFields {
    pub common: u16,
    pub time: u16,
    pub imu: u16,
    pub attitude: u16,
}

/// Measurement values of one VectorNav output, binary or ASCII. Absent = not in the output.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct VnValues {
    /// Time since startup, ns.
    pub time_startup_ns: Option<u64>,
    /// GPS time (since the GPS epoch), ns.
    pub time_gps_ns: Option<u64>,
    /// Time since the last SyncIn trigger, ns.
    pub time_sync_in_ns: Option<u64>,
    /// GPS time of week, ns.
    pub gps_tow_ns: Option<u64>,
    pub gps_week: Option<u16>,
    pub sync_in_count: Option<u32>,
    /// Yaw, pitch, roll, °.
    pub ypr_deg: Option<[f32; 3]>,
    /// Attitude quaternion, scalar last.
    pub quaternion: Option<[f32; 4]>,
    /// Bias-compensated angular rate, rad/s.
    pub angular_rate: Option<[f32; 3]>,
    /// Compensated acceleration, m/s².
    pub accel: Option<[f32; 3]>,
    /// Compensated magnetic field, gauss.
    pub mag: Option<[f32; 3]>,
    /// Uncompensated (calibrated only) acceleration, m/s².
    pub uncomp_accel: Option<[f32; 3]>,
    /// Uncompensated angular rate, rad/s.
    pub uncomp_gyro: Option<[f32; 3]>,
    /// Uncompensated magnetic field, gauss.
    pub uncomp_mag: Option<[f32; 3]>,
    /// IMU temperature, °C.
    pub temp_c: Option<f32>,
    /// Barometric pressure, kPa.
    pub pressure_kpa: Option<f32>,
    /// Integration interval of the deltas, s.
    pub delta_time_s: Option<f32>,
    /// Delta theta, °.
    pub delta_theta_deg: Option<[f32; 3]>,
    /// Delta velocity, m/s.
    pub delta_velocity: Option<[f32; 3]>,
    pub ins_status: Option<u16>,
    pub imu_status: Option<u16>,
    pub vpe_status: Option<u16>,
}

impl VnValues {
    /// The SI sample: time since startup (s, else GPS time of week), compensated rate and
    /// acceleration (the uncompensated ones when only those are output; without either,
    /// delta theta and delta velocity over their own integration interval, `delta_time_s`;
    /// with [`RowsFrom::Deltas`] the deltas first), temperature, and the IMU status word
    /// (else the INS status).
    pub fn to_imu_sample(&self, rows_from: RowsFrom) -> Option<ImuSample> {
        let f64s = |v: [f32; 3]| v.map(f64::from);
        // A rate from a delta needs a positive, finite integration interval.
        let interval = self
            .delta_time_s
            .map(f64::from)
            .filter(|dt| dt.is_finite() && *dt > 0.0);
        let per_second = |delta: Option<[f32; 3]>, scale: f64| {
            let dt = interval?;
            delta.map(|d| d.map(|x| f64::from(x) * scale / dt))
        };
        let rate = self.angular_rate.or(self.uncomp_gyro).map(f64s);
        let from_delta = per_second(self.delta_theta_deg, std::f64::consts::PI / 180.0);
        let accel = self.accel.or(self.uncomp_accel).map(f64s);
        let accel_from_delta = per_second(self.delta_velocity, 1.0);
        let (gyro, accel) = match rows_from {
            RowsFrom::Rates => (rate.or(from_delta), accel.or(accel_from_delta)),
            RowsFrom::Deltas => (from_delta.or(rate), accel_from_delta.or(accel)),
        };
        if gyro.is_none() && accel.is_none() {
            return None;
        }
        let sensor_time = self
            .time_startup_ns
            .or(self.gps_tow_ns)
            .map(|ns| ns as f64 / 1e9);
        Some(ImuSample {
            sensor_time,
            gyro,
            accel,
            temp_c: self.temp_c.map(f64::from),
            status: u32::from(self.imu_status.or(self.ins_status).unwrap_or(0)),
        })
    }
}

/// One binary output packet.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct VnBinary {
    pub fields: VnOutputFields,
    pub values: VnValues,
    /// Selected fields whose size is known but whose content is not kept (position,
    /// velocity, DCM, NED vectors, UTC time, ...).
    pub skipped_fields: u16,
}

/// Async ASCII sentences decoded into values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "UPPERCASE")]
pub enum VnAsciiKind {
    /// Yaw, pitch, roll.
    Ypr,
    /// Quaternion.
    Qtn,
    /// Yaw, pitch, roll, magnetic, acceleration, angular rate.
    Ymr,
    /// Quaternion, magnetic, acceleration, angular rate.
    Qmr,
    Mag,
    Acc,
    Gyr,
    /// Magnetic, acceleration, angular rate.
    Mar,
    /// Uncompensated magnetic, acceleration, angular rate, temperature, pressure.
    Imu,
    /// Delta time, delta theta, delta velocity.
    Dtv,
}

/// What one comma-separated group of ASCII fields is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Quantity {
    Ypr,
    Quaternion,
    Mag,
    Accel,
    Gyro,
    UncompMag,
    UncompAccel,
    UncompGyro,
    Temp,
    Pressure,
    DeltaTime,
    DeltaTheta,
    DeltaVel,
}

impl Quantity {
    fn count(self) -> usize {
        match self {
            Quantity::Quaternion => 4,
            Quantity::Temp | Quantity::Pressure | Quantity::DeltaTime => 1,
            _ => 3,
        }
    }

    /// Decimals the encoder writes (the manual's example outputs).
    fn decimals(self) -> usize {
        match self {
            Quantity::Ypr | Quantity::Accel | Quantity::UncompAccel => 3,
            Quantity::Pressure | Quantity::DeltaTheta | Quantity::DeltaVel => 3,
            Quantity::Mag | Quantity::UncompMag => 4,
            Quantity::Quaternion | Quantity::Gyro | Quantity::UncompGyro => 6,
            Quantity::DeltaTime => 6,
            Quantity::Temp => 1,
        }
    }
}

impl VnAsciiKind {
    const ALL: [VnAsciiKind; 10] = [
        VnAsciiKind::Ypr,
        VnAsciiKind::Qtn,
        VnAsciiKind::Ymr,
        VnAsciiKind::Qmr,
        VnAsciiKind::Mag,
        VnAsciiKind::Acc,
        VnAsciiKind::Gyr,
        VnAsciiKind::Mar,
        VnAsciiKind::Imu,
        VnAsciiKind::Dtv,
    ];

    /// The header after `$VN`.
    pub fn header(self) -> &'static str {
        match self {
            VnAsciiKind::Ypr => "YPR",
            VnAsciiKind::Qtn => "QTN",
            VnAsciiKind::Ymr => "YMR",
            VnAsciiKind::Qmr => "QMR",
            VnAsciiKind::Mag => "MAG",
            VnAsciiKind::Acc => "ACC",
            VnAsciiKind::Gyr => "GYR",
            VnAsciiKind::Mar => "MAR",
            VnAsciiKind::Imu => "IMU",
            VnAsciiKind::Dtv => "DTV",
        }
    }

    fn layout(self) -> &'static [Quantity] {
        use Quantity::*;
        match self {
            VnAsciiKind::Ypr => &[Ypr],
            VnAsciiKind::Qtn => &[Quaternion],
            VnAsciiKind::Ymr => &[Ypr, Mag, Accel, Gyro],
            VnAsciiKind::Qmr => &[Quaternion, Mag, Accel, Gyro],
            VnAsciiKind::Mag => &[Mag],
            VnAsciiKind::Acc => &[Accel],
            VnAsciiKind::Gyr => &[Gyro],
            VnAsciiKind::Mar => &[Mag, Accel, Gyro],
            VnAsciiKind::Imu => &[UncompMag, UncompAccel, UncompGyro, Temp, Pressure],
            VnAsciiKind::Dtv => &[DeltaTime, DeltaTheta, DeltaVel],
        }
    }

    fn from_header(header: &[u8]) -> Option<VnAsciiKind> {
        Self::ALL
            .into_iter()
            .find(|k| k.header().as_bytes() == header)
    }
}

/// Which checksum an ASCII sentence carries.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum VnChecksum {
    /// `*CC`: 8-bit XOR.
    #[default]
    Xor8,
    /// `*CCCC`: CRC16-CCITT.
    Crc16,
}

/// One decoded async ASCII sentence.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct VnAscii {
    pub kind: VnAsciiKind,
    pub checksum: VnChecksum,
    pub values: VnValues,
}

/// One VectorNav frame.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum VnFrame {
    Binary(VnBinary),
    Ascii(VnAscii),
    /// Any other `$VN` sentence with a valid checksum (register replies, `$VNERR`), as
    /// the text between `$` and `*`.
    AsciiOther {
        checksum: VnChecksum,
        body: String,
    },
}

impl VnFrame {
    /// The IMU sample this frame carries, if it has angular rate, acceleration or their
    /// deltas ([`VnValues::to_imu_sample`]).
    pub fn to_imu_sample(&self, rows_from: RowsFrom) -> Option<ImuSample> {
        match self {
            VnFrame::Binary(b) => b.values.to_imu_sample(rows_from),
            VnFrame::Ascii(a) => a.values.to_imu_sample(rows_from),
            VnFrame::AsciiOther { .. } => None,
        }
    }
}

/// How a binary field is stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Field {
    TimeStartup,
    TimeGps,
    TimeSyncIn,
    GpsTow,
    GpsWeek,
    SyncInCnt,
    Ypr,
    Quaternion,
    AngularRate,
    Accel,
    /// Common group `Imu`: uncompensated acceleration then angular rate.
    ImuUncomp,
    /// Common group `MagPres`: magnetic, temperature, pressure.
    MagPres,
    /// Common group `DeltaThetaVel`: delta time, delta theta, delta velocity.
    DeltaThetaVel,
    InsStatus,
    ImuStatus,
    UncompMag,
    UncompAccel,
    UncompGyro,
    Temp,
    Pres,
    /// IMU group `DeltaTheta`: delta time then delta theta.
    DeltaTheta,
    DeltaVel,
    Mag,
    VpeStatus,
    /// Known size, content not kept.
    Skip,
}

/// Field kind and size in bytes of bit `bit` of group `g` (0 Common, 1 Time, 2 IMU,
/// 3 Attitude); `None` for a field whose size this decoder does not know.
const fn field(g: usize, bit: u32) -> Option<(Field, usize)> {
    use Field::*;
    Some(match (g, bit) {
        (0, 0) | (1, 0) => (TimeStartup, 8),
        (0, 1) | (1, 1) => (TimeGps, 8),
        (0, 2) | (1, 4) => (TimeSyncIn, 8),
        (0, 3) | (3, 1) => (Ypr, 12),
        (0, 4) | (3, 2) => (Quaternion, 16),
        (0, 5) | (2, 10) => (AngularRate, 12),
        (0, 6) => (Skip, 24),
        (0, 7) => (Skip, 12),
        (0, 8) | (2, 9) => (Accel, 12),
        (0, 9) => (ImuUncomp, 24),
        (0, 10) => (MagPres, 20),
        (0, 11) => (DeltaThetaVel, 28),
        (0, 12) => (InsStatus, 2),
        (0, 13) | (1, 7) => (SyncInCnt, 4),
        (0, 14) | (1, 5) => (Skip, 8),
        (1, 2) => (GpsTow, 8),
        (1, 3) => (GpsWeek, 2),
        (1, 6) => (Skip, 8),
        (1, 8) => (Skip, 4),
        (1, 9) => (Skip, 1),
        (2, 0) => (ImuStatus, 2),
        (2, 1) => (UncompMag, 12),
        (2, 2) => (UncompAccel, 12),
        (2, 3) => (UncompGyro, 12),
        (2, 4) => (Temp, 4),
        (2, 5) => (Pres, 4),
        (2, 6) => (DeltaTheta, 16),
        (2, 7) => (DeltaVel, 12),
        (2, 8) => (Mag, 12),
        (3, 0) => (VpeStatus, 2),
        (3, 3) => (Skip, 36),
        (3, 4..=8) => (Skip, 12),
        _ => return None,
    })
}

/// [`field`] as a lookup table, `[group][bit]`.
static FIELDS: [[Option<(Field, usize)>; 16]; 4] = {
    let mut table = [[None; 16]; 4];
    let mut g = 0;
    while g < 4 {
        let mut bit = 0;
        while bit < 16 {
            table[g][bit] = field(g, bit as u32);
            bit += 1;
        }
        g += 1;
    }
    table
};

/// Group byte bits of the groups in [`VnOutputFields`] order.
const GROUP_BITS: [u8; 4] = [group::COMMON, group::TIME, group::IMU, group::ATTITUDE];

fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn f32s<const N: usize>(b: &[u8], at: usize) -> [f32; N] {
    std::array::from_fn(|i| f32_at(b, at + 4 * i))
}

fn u64_at(b: &[u8]) -> u64 {
    u64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]])
}

fn store(field: Field, b: &[u8], v: &mut VnValues, skipped: &mut u16) {
    match field {
        Field::TimeStartup => v.time_startup_ns = Some(u64_at(b)),
        Field::TimeGps => v.time_gps_ns = Some(u64_at(b)),
        Field::TimeSyncIn => v.time_sync_in_ns = Some(u64_at(b)),
        Field::GpsTow => v.gps_tow_ns = Some(u64_at(b)),
        Field::GpsWeek => v.gps_week = Some(u16::from_le_bytes([b[0], b[1]])),
        Field::SyncInCnt => v.sync_in_count = Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        Field::Ypr => v.ypr_deg = Some(f32s(b, 0)),
        Field::Quaternion => v.quaternion = Some(f32s(b, 0)),
        Field::AngularRate => v.angular_rate = Some(f32s(b, 0)),
        Field::Accel => v.accel = Some(f32s(b, 0)),
        Field::ImuUncomp => {
            v.uncomp_accel = Some(f32s(b, 0));
            v.uncomp_gyro = Some(f32s(b, 12));
        }
        Field::MagPres => {
            v.mag = Some(f32s(b, 0));
            v.temp_c = Some(f32_at(b, 12));
            v.pressure_kpa = Some(f32_at(b, 16));
        }
        Field::DeltaThetaVel => {
            v.delta_time_s = Some(f32_at(b, 0));
            v.delta_theta_deg = Some(f32s(b, 4));
            v.delta_velocity = Some(f32s(b, 16));
        }
        Field::InsStatus => v.ins_status = Some(u16::from_le_bytes([b[0], b[1]])),
        Field::ImuStatus => v.imu_status = Some(u16::from_le_bytes([b[0], b[1]])),
        Field::VpeStatus => v.vpe_status = Some(u16::from_le_bytes([b[0], b[1]])),
        Field::UncompMag => v.uncomp_mag = Some(f32s(b, 0)),
        Field::UncompAccel => v.uncomp_accel = Some(f32s(b, 0)),
        Field::UncompGyro => v.uncomp_gyro = Some(f32s(b, 0)),
        Field::Temp => v.temp_c = Some(f32_at(b, 0)),
        Field::Pres => v.pressure_kpa = Some(f32_at(b, 0)),
        Field::DeltaTheta => {
            v.delta_time_s = Some(f32_at(b, 0));
            v.delta_theta_deg = Some(f32s(b, 4));
        }
        Field::DeltaVel => v.delta_velocity = Some(f32s(b, 0)),
        Field::Mag => v.mag = Some(f32s(b, 0)),
        Field::Skip => *skipped = skipped.saturating_add(1),
    }
}

/// The header of a binary packet at the front of `data`: output fields, header length and
/// payload length; `Err` with the reject when it cannot be a packet this decoder frames.
fn binary_layout(data: &[u8]) -> Result<Option<(VnOutputFields, usize, usize)>, Reject> {
    let Some(&groups) = data.get(1) else {
        return Ok(None);
    };
    // Extension groups, GNSS, INS, GNSS2, or no group at all: not framed here.
    if groups & !(group::COMMON | group::TIME | group::IMU | group::ATTITUDE) != 0 || groups == 0 {
        return Err(Reject::Malformed);
    }
    let header_len = 2 + 2 * groups.count_ones() as usize;
    if data.len() < header_len {
        return Ok(None);
    }
    let mut words = [0u16; 4];
    let mut at = 2;
    let mut payload = 0usize;
    for (g, &bit) in GROUP_BITS.iter().enumerate() {
        if groups & bit == 0 {
            continue;
        }
        let word = u16::from_le_bytes([data[at], data[at + 1]]);
        at += 2;
        if word == 0 || word & 0x8000 != 0 {
            return Err(Reject::Malformed);
        }
        let mut rest = word;
        while rest != 0 {
            let b = rest.trailing_zeros();
            rest &= rest - 1;
            let (_, size) = FIELDS[g][b as usize].ok_or(Reject::Malformed)?;
            payload += size;
        }
        words[g] = word;
    }
    let fields = VnOutputFields {
        common: words[0],
        time: words[1],
        imu: words[2],
        attitude: words[3],
    };
    Ok(Some((fields, header_len, payload)))
}

/// The layout of the last binary packet: a device sends one configuration until it is
/// changed, so the field sizes are summed once per configuration, not once per packet.
#[derive(Debug, Clone, Copy)]
struct Layout {
    /// Group byte and field words as on the wire.
    header: [u8; 9],
    header_len: usize,
    payload_len: usize,
    fields: VnOutputFields,
}

fn scan_binary(data: &[u8], cache: &mut Option<Layout>) -> Scan<VnFrame> {
    let layout = match cache {
        Some(c) if data.get(1..c.header_len) == Some(&c.header[..c.header_len - 1]) => *c,
        _ => match binary_layout(data) {
            Ok(Some((fields, header_len, payload_len))) => {
                let mut header = [0u8; 9];
                header[..header_len - 1].copy_from_slice(&data[1..header_len]);
                let layout = Layout {
                    header,
                    header_len,
                    payload_len,
                    fields,
                };
                *cache = Some(layout);
                layout
            }
            Ok(None) => return Scan::Incomplete,
            Err(reject) => return Scan::Reject { len: 1, reject },
        },
    };
    let (fields, header_len, payload_len) = (layout.fields, layout.header_len, layout.payload_len);
    let total = header_len + payload_len + 2;
    if data.len() < total {
        return Scan::Incomplete;
    }
    if CRC16.checksum(&data[1..total]) != 0 {
        return Scan::Reject {
            len: 1,
            reject: Reject::Checksum,
        };
    }
    let payload = &data[header_len..header_len + payload_len];
    let mut packet = VnBinary {
        fields,
        ..VnBinary::default()
    };
    let mut at = 0;
    let words = [fields.common, fields.time, fields.imu, fields.attitude];
    for (g, &word) in words.iter().enumerate() {
        let mut rest = word;
        while rest != 0 {
            let b = rest.trailing_zeros();
            rest &= rest - 1;
            // Every bit was checked when the layout was made.
            if let Some((kind, size)) = FIELDS[g][b as usize] {
                store(
                    kind,
                    &payload[at..at + size],
                    &mut packet.values,
                    &mut packet.skipped_fields,
                );
                at += size;
            }
        }
    }
    Scan::Frame {
        len: total,
        frame: VnFrame::Binary(packet),
    }
}

fn hex_value(digits: &[u8]) -> Option<u16> {
    digits.iter().try_fold(0u16, |acc, &d| {
        let v = (d as char).to_digit(16)?;
        Some(acc << 4 | v as u16)
    })
}

fn xor8(body: &[u8]) -> u8 {
    body.iter().fold(0u8, |a, &b| a ^ b)
}

/// Parses the fields of a known sentence into values; `None` when they do not match.
fn parse_ascii_values(kind: VnAsciiKind, fields: &[u8]) -> Option<VnValues> {
    let mut values = VnValues::default();
    let mut parts = fields.split(|&b| b == b',');
    let mut next = || -> Option<f32> {
        let text = std::str::from_utf8(parts.next()?).ok()?;
        text.trim().parse::<f32>().ok().filter(|v| v.is_finite())
    };
    for &q in kind.layout() {
        let mut v = [0f32; 4];
        for slot in v.iter_mut().take(q.count()) {
            *slot = next()?;
        }
        let v3 = [v[0], v[1], v[2]];
        match q {
            Quantity::Ypr => values.ypr_deg = Some(v3),
            Quantity::Quaternion => values.quaternion = Some(v),
            Quantity::Mag => values.mag = Some(v3),
            Quantity::Accel => values.accel = Some(v3),
            Quantity::Gyro => values.angular_rate = Some(v3),
            Quantity::UncompMag => values.uncomp_mag = Some(v3),
            Quantity::UncompAccel => values.uncomp_accel = Some(v3),
            Quantity::UncompGyro => values.uncomp_gyro = Some(v3),
            Quantity::Temp => values.temp_c = Some(v[0]),
            Quantity::Pressure => values.pressure_kpa = Some(v[0]),
            Quantity::DeltaTime => values.delta_time_s = Some(v[0]),
            Quantity::DeltaTheta => values.delta_theta_deg = Some(v3),
            Quantity::DeltaVel => values.delta_velocity = Some(v3),
        }
    }
    parts.next().is_none().then_some(values)
}

fn scan_ascii(data: &[u8]) -> Scan<VnFrame> {
    // A `$` that cannot start a `$VN` sentence is garbage right away (decided on the first
    // three bytes only, so the outcome does not depend on how much has arrived).
    let known = data.len().min(3);
    if data[..known] != b"$VN"[..known] {
        return Scan::Reject {
            len: 1,
            reject: Reject::NoSync,
        };
    }
    let window = &data[..data.len().min(MAX_ASCII_LEN + 1)];
    let Some(newline) = memchr::memchr(b'\n', window) else {
        if data.len() > MAX_ASCII_LEN {
            return Scan::Reject {
                len: 1,
                reject: Reject::TooLong,
            };
        }
        return Scan::Incomplete;
    };
    let line = &data[..newline];
    let line = line.strip_suffix(b"\r").unwrap_or(line);
    let Some(star) = memchr::memrchr(b'*', line) else {
        return Scan::Reject {
            len: 1,
            reject: Reject::Malformed,
        };
    };
    let body = &line[1..star];
    let digits = &line[star + 1..];
    let (checksum, matches) = match (digits.len(), hex_value(digits)) {
        (2, Some(ck)) => (VnChecksum::Xor8, u16::from(xor8(body)) == ck),
        (4, Some(ck)) => (VnChecksum::Crc16, CRC16.checksum(body) == ck),
        _ => {
            return Scan::Reject {
                len: 1,
                reject: Reject::Malformed,
            }
        }
    };
    let len = newline + 1;
    if !matches {
        // A sentence cut short by the next one: keep the next one.
        let len = memchr::memchr(b'$', &line[1..]).map_or(len, |at| at + 1);
        return Scan::Reject {
            len,
            reject: Reject::Checksum,
        };
    }
    let header = body.get(2..5).unwrap_or_default();
    let fields_start = body.iter().position(|&b| b == b',');
    let frame = match (VnAsciiKind::from_header(header), fields_start) {
        (Some(kind), Some(5)) => match parse_ascii_values(kind, &body[6..]) {
            Some(values) => VnFrame::Ascii(VnAscii {
                kind,
                checksum,
                values,
            }),
            None => {
                return Scan::Reject {
                    len,
                    reject: Reject::BadContent,
                }
            }
        },
        _ => VnFrame::AsciiOther {
            checksum,
            body: String::from_utf8_lossy(body).into_owned(),
        },
    };
    Scan::Frame { len, frame }
}

/// Streaming VectorNav decoder: binary packets and async ASCII sentences, interleaved as
/// the device may send them.
///
/// Framing rule: look for `0xFA` or `$`. A binary packet whose configuration this decoder
/// cannot size, or whose CRC fails, costs its sync byte; the search goes on from the next
/// byte, so a real packet inside a false one is still found. An ASCII sentence with a wrong
/// checksum is dropped up to its line end; one whose fields do not parse is dropped without
/// losing sync. Counting follows the one rule of [`StreamBuffer`].
#[derive(Debug, Clone)]
pub struct VnDecoder {
    buf: StreamBuffer,
    layout: Option<Layout>,
}

impl Default for VnDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl VnDecoder {
    pub fn new() -> Self {
        // ASCII sentences end in CR LF, which is framing between frames.
        VnDecoder {
            buf: StreamBuffer::text(),
            layout: None,
        }
    }
}

impl Decoder for VnDecoder {
    type Frame = VnFrame;

    fn push(&mut self, bytes: &[u8]) {
        self.buf.push(bytes);
    }

    fn poll(&mut self) -> Option<VnFrame> {
        loop {
            if !self.buf.skip_to_start(&[SYNC, b'$']) {
                return None;
            }
            let data = self.buf.data();
            let scan = if data[0] == SYNC {
                scan_binary(data, &mut self.layout)
            } else {
                scan_ascii(data)
            };
            match scan {
                Scan::Incomplete => return None,
                Scan::Frame { len, frame } => {
                    self.buf.accept(len);
                    return Some(frame);
                }
                Scan::Reject { len, reject } => self.buf.reject(len, reject),
            }
        }
    }

    fn stats(&self) -> DecoderStats {
        self.buf.stats()
    }
}

/// VectorNav encoder: binary packets with exactly the selected fields, ASCII sentences with
/// the manual's number formats.
#[derive(Debug, Default, Clone, Copy)]
pub struct VnEncoder;

impl Encoder for VnEncoder {
    type Frame = VnFrame;

    fn encode(&self, frame: &VnFrame, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        let start = out.len();
        let result = match frame {
            VnFrame::Binary(packet) => encode_binary(packet, out),
            VnFrame::Ascii(sentence) => encode_ascii(sentence, out),
            VnFrame::AsciiOther { checksum, body } => encode_text(body.as_bytes(), *checksum, out),
        };
        if result.is_err() {
            out.truncate(start);
        }
        result
    }
}

fn missing(field: &'static str) -> EncodeError {
    EncodeError::Invalid {
        field,
        reason: "selected in the output fields but has no value",
    }
}

fn put_f32s(values: &[f32], out: &mut Vec<u8>) {
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

fn put_field(field: Field, v: &VnValues, out: &mut Vec<u8>) -> Result<(), EncodeError> {
    let u64v = |x: Option<u64>, name| x.map(u64::to_le_bytes).ok_or_else(|| missing(name));
    let arr = |x: Option<[f32; 3]>, name| x.ok_or_else(|| missing(name));
    let one = |x: Option<f32>, name| x.ok_or_else(|| missing(name));
    match field {
        Field::TimeStartup => out.extend_from_slice(&u64v(v.time_startup_ns, "time_startup_ns")?),
        Field::TimeGps => out.extend_from_slice(&u64v(v.time_gps_ns, "time_gps_ns")?),
        Field::TimeSyncIn => out.extend_from_slice(&u64v(v.time_sync_in_ns, "time_sync_in_ns")?),
        Field::GpsTow => out.extend_from_slice(&u64v(v.gps_tow_ns, "gps_tow_ns")?),
        Field::GpsWeek => {
            out.extend_from_slice(&v.gps_week.ok_or_else(|| missing("gps_week"))?.to_le_bytes())
        }
        Field::SyncInCnt => out.extend_from_slice(
            &v.sync_in_count
                .ok_or_else(|| missing("sync_in_count"))?
                .to_le_bytes(),
        ),
        Field::Ypr => put_f32s(&arr(v.ypr_deg, "ypr_deg")?, out),
        Field::Quaternion => put_f32s(&v.quaternion.ok_or_else(|| missing("quaternion"))?, out),
        Field::AngularRate => put_f32s(&arr(v.angular_rate, "angular_rate")?, out),
        Field::Accel => put_f32s(&arr(v.accel, "accel")?, out),
        Field::ImuUncomp => {
            put_f32s(&arr(v.uncomp_accel, "uncomp_accel")?, out);
            put_f32s(&arr(v.uncomp_gyro, "uncomp_gyro")?, out);
        }
        Field::MagPres => {
            put_f32s(&arr(v.mag, "mag")?, out);
            put_f32s(
                &[
                    one(v.temp_c, "temp_c")?,
                    one(v.pressure_kpa, "pressure_kpa")?,
                ],
                out,
            );
        }
        Field::DeltaThetaVel => {
            put_f32s(&[one(v.delta_time_s, "delta_time_s")?], out);
            put_f32s(&arr(v.delta_theta_deg, "delta_theta_deg")?, out);
            put_f32s(&arr(v.delta_velocity, "delta_velocity")?, out);
        }
        Field::InsStatus => out.extend_from_slice(
            &v.ins_status
                .ok_or_else(|| missing("ins_status"))?
                .to_le_bytes(),
        ),
        Field::ImuStatus => out.extend_from_slice(
            &v.imu_status
                .ok_or_else(|| missing("imu_status"))?
                .to_le_bytes(),
        ),
        Field::VpeStatus => out.extend_from_slice(
            &v.vpe_status
                .ok_or_else(|| missing("vpe_status"))?
                .to_le_bytes(),
        ),
        Field::UncompMag => put_f32s(&arr(v.uncomp_mag, "uncomp_mag")?, out),
        Field::UncompAccel => put_f32s(&arr(v.uncomp_accel, "uncomp_accel")?, out),
        Field::UncompGyro => put_f32s(&arr(v.uncomp_gyro, "uncomp_gyro")?, out),
        Field::Temp => put_f32s(&[one(v.temp_c, "temp_c")?], out),
        Field::Pres => put_f32s(&[one(v.pressure_kpa, "pressure_kpa")?], out),
        Field::DeltaTheta => {
            put_f32s(&[one(v.delta_time_s, "delta_time_s")?], out);
            put_f32s(&arr(v.delta_theta_deg, "delta_theta_deg")?, out);
        }
        Field::DeltaVel => put_f32s(&arr(v.delta_velocity, "delta_velocity")?, out),
        Field::Mag => put_f32s(&arr(v.mag, "mag")?, out),
        Field::Skip => {
            return Err(EncodeError::Invalid {
                field: "fields",
                reason: "selects a field whose content the encoder does not model",
            })
        }
    }
    Ok(())
}

fn encode_binary(packet: &VnBinary, out: &mut Vec<u8>) -> Result<(), EncodeError> {
    let f = packet.fields;
    let words = [f.common, f.time, f.imu, f.attitude];
    let start = out.len();
    out.push(SYNC);
    let groups = words
        .iter()
        .zip(GROUP_BITS)
        .filter(|(w, _)| **w != 0)
        .fold(0u8, |acc, (_, bit)| acc | bit);
    if groups == 0 {
        return Err(EncodeError::Invalid {
            field: "fields",
            reason: "no output field selected",
        });
    }
    out.push(groups);
    for &w in words.iter().filter(|w| **w != 0) {
        out.extend_from_slice(&w.to_le_bytes());
    }
    for (g, &word) in words.iter().enumerate() {
        let mut rest = word;
        while rest != 0 {
            let b = rest.trailing_zeros();
            rest &= rest - 1;
            let (kind, _) = FIELDS[g][b as usize].ok_or(EncodeError::Invalid {
                field: "fields",
                reason: "selects a field whose size is not known",
            })?;
            put_field(kind, &packet.values, out)?;
        }
    }
    let crc = CRC16.checksum(&out[start + 1..]);
    out.extend_from_slice(&crc.to_be_bytes());
    Ok(())
}

fn encode_ascii(sentence: &VnAscii, out: &mut Vec<u8>) -> Result<(), EncodeError> {
    use std::fmt::Write;
    let v = &sentence.values;
    let mut body = format!("VN{}", sentence.kind.header());
    for &q in sentence.kind.layout() {
        let (name, values): (&'static str, &[f32]) = match q {
            Quantity::Ypr => ("ypr_deg", v.ypr_deg.as_ref().map(|a| &a[..]).unwrap_or(&[])),
            Quantity::Quaternion => ("quaternion", v.quaternion.as_ref().map_or(&[], |a| &a[..])),
            Quantity::Mag => ("mag", v.mag.as_ref().map_or(&[], |a| &a[..])),
            Quantity::Accel => ("accel", v.accel.as_ref().map_or(&[], |a| &a[..])),
            Quantity::Gyro => (
                "angular_rate",
                v.angular_rate.as_ref().map_or(&[], |a| &a[..]),
            ),
            Quantity::UncompMag => ("uncomp_mag", v.uncomp_mag.as_ref().map_or(&[], |a| &a[..])),
            Quantity::UncompAccel => (
                "uncomp_accel",
                v.uncomp_accel.as_ref().map_or(&[], |a| &a[..]),
            ),
            Quantity::UncompGyro => (
                "uncomp_gyro",
                v.uncomp_gyro.as_ref().map_or(&[], |a| &a[..]),
            ),
            Quantity::Temp => ("temp_c", v.temp_c.as_slice()),
            Quantity::Pressure => ("pressure_kpa", v.pressure_kpa.as_slice()),
            Quantity::DeltaTime => ("delta_time_s", v.delta_time_s.as_slice()),
            Quantity::DeltaTheta => (
                "delta_theta_deg",
                v.delta_theta_deg.as_ref().map_or(&[], |a| &a[..]),
            ),
            Quantity::DeltaVel => (
                "delta_velocity",
                v.delta_velocity.as_ref().map_or(&[], |a| &a[..]),
            ),
        };
        if values.is_empty() {
            return Err(missing(name));
        }
        for &x in values {
            if !x.is_finite() {
                return Err(EncodeError::OutOfRange {
                    field: name,
                    value: f64::from(x),
                });
            }
            // Writing into a String cannot fail.
            let _ = write!(body, ",{:+.*}", q.decimals(), x);
        }
    }
    encode_text(body.as_bytes(), sentence.checksum, out)
}

fn encode_text(body: &[u8], checksum: VnChecksum, out: &mut Vec<u8>) -> Result<(), EncodeError> {
    if body
        .iter()
        .any(|&b| matches!(b, b'*' | b'$' | b'\r' | b'\n'))
        || !body.starts_with(b"VN")
    {
        return Err(EncodeError::Invalid {
            field: "body",
            reason: "must start with VN and hold no `*`, `$` or line end",
        });
    }
    let len = body.len() + if checksum == VnChecksum::Xor8 { 6 } else { 8 };
    if len > MAX_ASCII_LEN {
        return Err(EncodeError::TooLong {
            len,
            max: MAX_ASCII_LEN,
        });
    }
    out.push(b'$');
    out.extend_from_slice(body);
    let tail = match checksum {
        VnChecksum::Xor8 => format!("*{:02X}\r\n", xor8(body)),
        VnChecksum::Crc16 => format!("*{:04X}\r\n", CRC16.checksum(body)),
    };
    out.extend_from_slice(tail.as_bytes());
    Ok(())
}

/// The IMU samples of a VectorNav stream (what `imulogd` logs): binary packets and ASCII
/// sentences with angular rate, acceleration or their deltas, taken as
/// [`VnValues::to_imu_sample`] says; attitude-only output and register replies are none.
#[derive(Debug, Default, Clone)]
pub struct VnSamples {
    frames: VnDecoder,
    rows_from: RowsFrom,
}

impl VnSamples {
    pub fn new(rows_from: RowsFrom) -> Self {
        VnSamples {
            frames: VnDecoder::new(),
            rows_from,
        }
    }
}

impl Decoder for VnSamples {
    type Frame = ImuSample;

    fn push(&mut self, bytes: &[u8]) {
        self.frames.push(bytes);
    }

    fn poll(&mut self) -> Option<ImuSample> {
        loop {
            if let Some(sample) = self.frames.poll()?.to_imu_sample(self.rows_from) {
                return Some(sample);
            }
        }
    }

    fn stats(&self) -> DecoderStats {
        self.frames.stats()
    }
}

/// The binary output packet a VectorNav sends for one sample: Common group TimeStartup (the
/// clock, ns), AngularRate and Accel when the sample has them; IMU group ImuStatus (the low
/// 16 bits of the status word) and Temp when it has one.
pub fn encode_sample(
    sample: &ImuSample,
    clock: &DeviceClock,
    out: &mut Vec<u8>,
) -> Result<(), EncodeError> {
    let packet = binary_packet(sample, clock, true, None)?;
    VnEncoder.encode(&VnFrame::Binary(packet), out)
}

/// The binary output packet of a VectorNav set to output integrated motion instead of
/// rates: Common group TimeStartup and DeltaThetaVel (the integration interval
/// `interval_s`, the sample's rate and acceleration times it, angles in °), IMU group
/// ImuStatus and Temp as [`encode_sample`].
pub fn encode_delta_sample(
    sample: &ImuSample,
    clock: &DeviceClock,
    interval_s: f64,
    out: &mut Vec<u8>,
) -> Result<(), EncodeError> {
    let packet = binary_packet(sample, clock, false, Some(interval_s))?;
    VnEncoder.encode(&VnFrame::Binary(packet), out)
}

/// The packet of a VectorNav set to `output`: [`encode_sample`]'s, [`encode_delta_sample`]'s
/// over the clock's `interval_s`, or both in one packet (AngularRate, Accel and
/// DeltaThetaVel; DeltaThetaVel only when the sample has both triads, as it carries both).
pub fn encode_output(
    sample: &ImuSample,
    clock: &DeviceClock,
    output: ImuOutput,
    out: &mut Vec<u8>,
) -> Result<(), EncodeError> {
    let packet = match output {
        ImuOutput::Rates => binary_packet(sample, clock, true, None)?,
        ImuOutput::Deltas => binary_packet(sample, clock, false, Some(clock.interval_s))?,
        ImuOutput::Both => {
            let both = sample.gyro.is_some() && sample.accel.is_some();
            binary_packet(sample, clock, true, both.then_some(clock.interval_s))?
        }
    };
    VnEncoder.encode(&VnFrame::Binary(packet), out)
}

/// The binary packet of one sample: the rates when `rates`, DeltaThetaVel over
/// `delta_interval_s` when given (it needs both triads and a positive interval).
fn binary_packet(
    sample: &ImuSample,
    clock: &DeviceClock,
    rates: bool,
    delta_interval_s: Option<f64>,
) -> Result<VnBinary, EncodeError> {
    let f32s = |v: [f64; 3]| v.map(|x| x as f32);
    let temp = sample.temp_c.map(|t| t as f32);
    let mut common_fields = common::TIME_STARTUP;
    let mut values = VnValues {
        time_startup_ns: Some((clock.time_s * 1e9).round().max(0.0) as u64),
        temp_c: temp,
        imu_status: Some((sample.status & 0xFFFF) as u16),
        ..VnValues::default()
    };
    if rates {
        if sample.gyro.is_some() {
            common_fields |= common::ANGULAR_RATE;
        }
        if sample.accel.is_some() {
            common_fields |= common::ACCEL;
        }
        values.angular_rate = sample.gyro.map(f32s);
        values.accel = sample.accel.map(f32s);
    }
    if let Some(interval_s) = delta_interval_s {
        if !(interval_s.is_finite() && interval_s > 0.0) {
            return Err(EncodeError::Invalid {
                field: "interval_s",
                reason: "the integration interval must be positive",
            });
        }
        let (Some(gyro), Some(accel)) = (sample.gyro, sample.accel) else {
            return Err(EncodeError::Invalid {
                field: "sample",
                reason: "DeltaThetaVel carries both delta theta and delta velocity",
            });
        };
        let delta = |v: [f64; 3], scale: f64| v.map(|x| (x * scale * interval_s) as f32);
        common_fields |= common::DELTA_THETA_VEL;
        values.delta_time_s = Some(interval_s as f32);
        values.delta_theta_deg = Some(delta(gyro, 180.0 / std::f64::consts::PI));
        values.delta_velocity = Some(delta(accel, 1.0));
    }
    let imu_fields = imu::IMU_STATUS | if temp.is_some() { imu::TEMP } else { 0 };
    Ok(VnBinary {
        fields: VnOutputFields {
            common: common_fields,
            imu: imu_fields,
            ..VnOutputFields::default()
        },
        values,
        skipped_fields: 0,
    })
}

/// Auto-detection score. At least [`DETECT_MIN_FRAMES`] checksummed VectorNav frames, else
/// 0. Each counts twice: a `$VN` sentence is also a well-formed NMEA sentence of talker
/// `VN`, and VectorNav must win over NMEA on a VectorNav ASCII stream.
pub fn detect_score(sample: &[u8]) -> u32 {
    let frames = accepted_frames(VnDecoder::new(), sample);
    if frames < DETECT_MIN_FRAMES {
        0
    } else {
        frames.saturating_mul(2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode_all(bytes: &[u8]) -> (Vec<VnFrame>, DecoderStats) {
        let mut d = VnDecoder::new();
        let mut frames = Vec::new();
        d.decode(bytes, |f| frames.push(f));
        (frames, d.stats())
    }

    #[test]
    fn encode_output_of_both_round_trips_through_either_rows_from() {
        let sample = ImuSample {
            sensor_time: None,
            gyro: Some([0.1, -0.2, 0.3]),
            accel: Some([0.5, -1.0, 9.8]),
            temp_c: Some(25.0),
            status: 3,
        };
        let clock = DeviceClock {
            time_s: 12.5,
            interval_s: 0.005,
            ..DeviceClock::default()
        };
        let decode = |bytes: &[u8], from: RowsFrom| {
            let mut d = VnSamples::new(from);
            let mut out = Vec::new();
            d.decode(bytes, |s| out.push(s));
            assert_eq!(d.stats().frames_ok, 1, "{:?}", d.stats());
            out
        };
        let close = |got: [f64; 3], want: [f64; 3]| {
            got.iter()
                .zip(want)
                .all(|(g, w)| (g - w).abs() < 1e-6 * w.abs().max(1.0))
        };
        let mut both = Vec::new();
        encode_output(&sample, &clock, ImuOutput::Both, &mut both).unwrap();
        let (frames, _) = decode_all(&both);
        let VnFrame::Binary(packet) = &frames[0] else {
            panic!("{frames:?}")
        };
        assert!(packet.values.angular_rate.is_some() && packet.values.delta_theta_deg.is_some());
        let rates = decode(&both, RowsFrom::Rates);
        let deltas = decode(&both, RowsFrom::Deltas);
        for got in [&rates[0], &deltas[0]] {
            assert!(close(got.gyro.unwrap(), sample.gyro.unwrap()), "{got:?}");
            assert!(close(got.accel.unwrap(), sample.accel.unwrap()), "{got:?}");
            assert_eq!((got.sensor_time, got.temp_c), (Some(12.5), Some(25.0)));
        }
        // The rates are the f32 rates; the deltas' rows differ from them by the rounding.
        assert_eq!(rates[0].gyro, Some([0.1f32, -0.2, 0.3].map(f64::from)));
        assert_ne!(rates[0].gyro, deltas[0].gyro);
        // Deltas alone over the clock's interval are encode_delta_sample's packet; rates
        // alone encode_sample's.
        let (mut only, mut by_interval) = (Vec::new(), Vec::new());
        encode_output(&sample, &clock, ImuOutput::Deltas, &mut only).unwrap();
        encode_delta_sample(&sample, &clock, 0.005, &mut by_interval).unwrap();
        assert_eq!(only, by_interval);
        assert_eq!(decode(&only, RowsFrom::Rates), deltas);
        let (mut only, mut plain) = (Vec::new(), Vec::new());
        encode_output(&sample, &clock, ImuOutput::Rates, &mut only).unwrap();
        encode_sample(&sample, &clock, &mut plain).unwrap();
        assert_eq!(only, plain);
        // Without a known interval there is no delta to send; without both triads no
        // DeltaThetaVel, so `both` sends the rate alone.
        let unknown = DeviceClock {
            interval_s: 0.0,
            ..clock
        };
        assert!(encode_output(&sample, &unknown, ImuOutput::Deltas, &mut Vec::new()).is_err());
        let gyro_only = ImuSample {
            accel: None,
            ..sample
        };
        let mut out = Vec::new();
        encode_output(&gyro_only, &clock, ImuOutput::Both, &mut out).unwrap();
        assert_eq!(decode(&out, RowsFrom::Deltas)[0].gyro, rates[0].gyro);
    }

    #[test]
    fn delta_theta_and_velocity_give_rates_over_their_own_interval() {
        let sample = ImuSample {
            sensor_time: None,
            gyro: Some([0.1, -0.2, 0.3]),
            accel: Some([0.5, -1.0, 9.8]),
            temp_c: Some(25.0),
            status: 3,
        };
        let clock = DeviceClock {
            time_s: 12.5,
            ..DeviceClock::default()
        };
        let mut bytes = Vec::new();
        encode_delta_sample(&sample, &clock, 0.005, &mut bytes).unwrap();
        let (frames, stats) = decode_all(&bytes);
        assert_eq!(stats.frames_ok, 1, "{stats:?}");
        let VnFrame::Binary(packet) = &frames[0] else {
            panic!("{frames:?}")
        };
        // The wire carries deltas only: 0.005 s of 0.1 rad/s is 0.02865°.
        assert_eq!(packet.values.angular_rate, None);
        assert_eq!(packet.values.accel, None);
        let dtheta = packet.values.delta_theta_deg.unwrap();
        assert!((f64::from(dtheta[0]) - 0.1 * 0.005 * 180.0 / std::f64::consts::PI).abs() < 1e-7);
        let decoded = frames[0].to_imu_sample(RowsFrom::Rates).unwrap();
        for (got, want) in decoded.gyro.unwrap().iter().zip(sample.gyro.unwrap()) {
            assert!(
                (got - want).abs() < 1e-6 * want.abs().max(1.0),
                "{got} vs {want}"
            );
        }
        for (got, want) in decoded.accel.unwrap().iter().zip(sample.accel.unwrap()) {
            assert!(
                (got - want).abs() < 1e-5 * want.abs().max(1.0),
                "{got} vs {want}"
            );
        }
        assert_eq!(decoded.sensor_time, Some(12.5));
        assert_eq!(decoded.temp_c, Some(25.0));
        // Rates beside the deltas win unless the deltas are asked for; a zero interval gives
        // no rate from a delta.
        let mut values = packet.values;
        values.angular_rate = Some([1.0, 2.0, 3.0]);
        let rates = values.to_imu_sample(RowsFrom::Rates).unwrap();
        assert_eq!(rates.gyro, Some([1.0, 2.0, 3.0]));
        let deltas = values.to_imu_sample(RowsFrom::Deltas).unwrap();
        assert_eq!(deltas.gyro, decoded.gyro);
        values.angular_rate = None;
        values.delta_time_s = Some(0.0);
        assert_eq!(values.to_imu_sample(RowsFrom::Deltas), None);
        assert!(encode_delta_sample(&sample, &clock, 0.0, &mut Vec::new()).is_err());
    }

    #[test]
    fn crc_is_ccitt_with_zero_start() {
        // The standard check value of CRC-16/XMODEM.
        assert_eq!(CRC16.checksum(b"123456789"), 0x31C3);
    }

    #[test]
    fn manual_example_read_register_checksum() {
        // `$VNRRG,11*73` is the manual's example of the 8-bit checksum.
        let (frames, stats) = decode_all(b"$VNRRG,11*73\r\n");
        assert_eq!(stats.frames_ok, 1, "{stats:?}");
        assert_eq!(
            frames[0],
            VnFrame::AsciiOther {
                checksum: VnChecksum::Xor8,
                body: "VNRRG,11".into()
            }
        );
    }

    #[test]
    fn ymr_sentence_decodes_into_values() {
        let body = b"VNYMR,+010.071,-000.278,-000.636,+01.0267,-00.2052,+02.7264,-00.497,+00.154,-09.802,-00.003823,+00.000159,-00.000344";
        let line = format!(
            "${}*{:02X}\r\n",
            std::str::from_utf8(body).unwrap(),
            xor8(body)
        );
        let (frames, stats) = decode_all(line.as_bytes());
        assert_eq!(stats.frames_ok, 1);
        let sample = frames[0].to_imu_sample(RowsFrom::Rates).expect("a sample");
        let accel = sample.accel.unwrap();
        assert!((accel[2] + 9.802).abs() < 1e-5, "{accel:?}");
        let gyro = sample.gyro.unwrap();
        assert!((gyro[0] + 0.003823).abs() < 1e-8, "{gyro:?}");
        assert_eq!(sample.sensor_time, None);
    }

    #[test]
    fn counts_do_not_depend_on_how_a_long_line_arrives() {
        // Found by the fuzz target: a `$` that is no `$VN` start before a line just over the
        // length limit was counted as too long when the stream came in one piece.
        let mut stream = b"$$VN".to_vec();
        stream.extend_from_slice(&[b'x'; 253]);
        stream.extend_from_slice(b"\n$VN");
        stream.extend_from_slice(&[b'y'; 300]);
        let (_, whole) = decode_all(&stream);
        for split in 0..=stream.len() {
            let mut d = VnDecoder::new();
            d.decode(&stream[..split], |_| {});
            d.decode(&stream[split..], |_| {});
            assert_eq!(d.stats(), whole, "split at {split}");
        }
        assert_eq!(whole.frames_too_long, 1, "{whole:?}");
    }

    #[test]
    fn unsupported_configuration_is_malformed_and_resyncs() {
        let packet = VnBinary {
            fields: VnOutputFields {
                common: common::TIME_STARTUP | common::ANGULAR_RATE,
                ..Default::default()
            },
            values: VnValues {
                time_startup_ns: Some(5),
                angular_rate: Some([0.1, 0.2, 0.3]),
                ..Default::default()
            },
            skipped_fields: 0,
        };
        let mut good = Vec::new();
        VnEncoder
            .encode(&VnFrame::Binary(packet), &mut good)
            .unwrap();
        // A GNSS-group packet (group bit 3): its size is not known here.
        let bad = [SYNC, 0x08, 0x01, 0x00, 1, 2, 3, 4];
        let stream = [&good[..], &bad, &good].concat();
        let (frames, stats) = decode_all(&stream);
        assert_eq!(frames.len(), 2);
        assert_eq!(stats.frames_malformed, 1);
        assert_eq!(stats.bytes_skipped, bad.len() as u64);
        assert_eq!(stats.resyncs, 1);
    }
}
