//! u-blox UBX binary codec: framing (`B5 62`, class, id, little-endian length, payload,
//! Fletcher-8 checksum) and the messages NAV-PVT, NAV-STATUS, NAV-SAT, NAV-POSLLH, NAV-VELNED,
//! NAV-TIMEUTC, NAV-DOP, NAV-SOL, NAV-POSECEF, NAV-VELECEF, NAV-TIMEGPS, NAV-HPPOSLLH, NAV-RELPOSNED
//! (versions 0 and 1), NAV-COV, HNR-PVT, RXM-RAWX, MON-HW, ESF-RAW, ESF-MEAS and ACK-ACK/NAK. Every other
//! message, and a known message whose length does not match its layout, is kept raw with
//! class and id.
//!
//! Scaled integers are converted to SI at the edge (degrees for lat/lon and angles, m, m/s,
//! rad/s, m/s², °C) and stored as f64; the raw integer is recovered exactly by the encoder
//! (`round(value × scale)`: every raw value is far below 2^53, so the round trip is exact).
//! Times (iTOW, nanoseconds) and flags stay integers.
//!
//! Framing rule: a frame starts at `B5 62`. A payload longer than [`MAX_PAYLOAD`] is rejected
//! as too long and a bad checksum as a checksum error; in both cases only the two sync bytes
//! are dropped and the search resumes right after them, so a corrupt length field never
//! swallows the good frames behind it.

use serde::Serialize;

use super::{accepted_frames, Decoder, EncodeError, Encoder, Reject, Scan, StreamBuffer};
use crate::types::{DecoderStats, FixType, GnssFix, ImuSample};

/// Largest payload accepted (RXM-RAWX with 255 measurements is 8176 bytes).
pub const MAX_PAYLOAD: usize = 8192;
const SYNC: [u8; 2] = [0xB5, 0x62];
const DEG_TO_RAD: f64 = std::f64::consts::PI / 180.0;

/// NAV-PVT (0x01 0x07): navigation position velocity time solution.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NavPvt {
    pub itow_ms: u32,
    pub year: u16,
    pub month: u8,
    pub day: u8,
    pub hour: u8,
    pub min: u8,
    pub sec: u8,
    pub valid: u8,
    pub t_acc_ns: u32,
    pub nano_ns: i32,
    /// 0 no fix, 1 DR, 2 2D, 3 3D, 4 GNSS+DR, 5 time only.
    pub fix_type: u8,
    pub flags: u8,
    pub flags2: u8,
    pub num_sv: u8,
    pub lon_deg: f64,
    pub lat_deg: f64,
    pub height_m: f64,
    pub height_msl_m: f64,
    pub h_acc_m: f64,
    pub v_acc_m: f64,
    pub vel_n_mps: f64,
    pub vel_e_mps: f64,
    pub vel_d_mps: f64,
    pub ground_speed_mps: f64,
    pub head_mot_deg: f64,
    pub s_acc_mps: f64,
    pub head_acc_deg: f64,
    pub pdop: f64,
    pub flags3: u16,
    /// Present in the 92-byte layout (protocol ≥ 15), absent in the older 84-byte one.
    pub head_veh_deg: Option<f64>,
    pub mag_dec_deg: Option<f64>,
    pub mag_acc_deg: Option<f64>,
}

/// NAV-STATUS (0x01 0x03): receiver navigation status.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct NavStatus {
    pub itow_ms: u32,
    pub gps_fix: u8,
    pub flags: u8,
    pub fix_stat: u8,
    pub flags2: u8,
    pub ttff_ms: u32,
    pub msss_ms: u32,
}

/// One satellite of NAV-SAT.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NavSatSv {
    pub gnss_id: u8,
    pub sv_id: u8,
    pub cno_dbhz: u8,
    pub elev_deg: i8,
    pub azim_deg: i16,
    /// Pseudorange residual, m.
    pub pr_res_m: f64,
    pub flags: u32,
}

/// NAV-SAT (0x01 0x35): satellite information.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NavSat {
    pub itow_ms: u32,
    pub version: u8,
    pub svs: Vec<NavSatSv>,
}

/// NAV-POSLLH (0x01 0x02): geodetic position.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NavPosllh {
    pub itow_ms: u32,
    pub lon_deg: f64,
    pub lat_deg: f64,
    pub height_m: f64,
    pub height_msl_m: f64,
    pub h_acc_m: f64,
    pub v_acc_m: f64,
}

/// NAV-VELNED (0x01 0x12): velocity in NED.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NavVelned {
    pub itow_ms: u32,
    pub vel_n_mps: f64,
    pub vel_e_mps: f64,
    pub vel_d_mps: f64,
    pub speed_mps: f64,
    pub ground_speed_mps: f64,
    pub heading_deg: f64,
    pub s_acc_mps: f64,
    pub c_acc_deg: f64,
}

/// NAV-SOL (0x01 0x06): ECEF position and velocity solution (kept by receivers for backward
/// compatibility; u-blox 6 and older send it instead of NAV-PVT).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NavSol {
    pub itow_ms: u32,
    /// Remainder of the rounded iTOW, ns (−500 000 … 500 000).
    pub ftow_ns: i32,
    pub week: i16,
    /// 0 no fix, 1 DR, 2 2D, 3 3D, 4 GNSS+DR, 5 time only.
    pub gps_fix: u8,
    /// Bits: 0 gpsFixOk, 1 diffSoln, 2 week valid, 3 time of week valid.
    pub flags: u8,
    /// ECEF X, Y, Z, m (sent in cm).
    pub ecef_m: [f64; 3],
    /// 3D position accuracy, m.
    pub p_acc_m: f64,
    /// ECEF velocity, m/s (sent in cm/s).
    pub ecef_vel_mps: [f64; 3],
    pub s_acc_mps: f64,
    pub pdop: f64,
    pub num_sv: u8,
}

/// NAV-POSECEF (0x01 0x01): position in ECEF.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NavPosecef {
    pub itow_ms: u32,
    /// ECEF X, Y, Z, m (sent in cm).
    pub ecef_m: [f64; 3],
    /// 3D position accuracy, m.
    pub p_acc_m: f64,
}

/// NAV-VELECEF (0x01 0x11): velocity in ECEF.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NavVelecef {
    pub itow_ms: u32,
    /// ECEF velocity, m/s (sent in cm/s).
    pub ecef_vel_mps: [f64; 3],
    pub s_acc_mps: f64,
}

/// NAV-TIMEGPS (0x01 0x20): GPS time and the GPS−UTC leap seconds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct NavTimegps {
    pub itow_ms: u32,
    pub ftow_ns: i32,
    pub week: i16,
    /// GPS − UTC, s.
    pub leap_s: i8,
    /// Bits: 0 time of week valid, 1 week valid, 2 leap seconds valid.
    pub valid: u8,
    pub t_acc_ns: u32,
}

/// NAV-HPPOSLLH (0x01 0x14): geodetic position to 0.1 mm (the standard and high-precision
/// parts of each value are added up here; the encoder splits them again).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NavHpposllh {
    pub version: u8,
    /// Bit 0: invalidLlh (the position is not valid).
    pub flags: u8,
    pub itow_ms: u32,
    pub lon_deg: f64,
    pub lat_deg: f64,
    pub height_m: f64,
    pub height_msl_m: f64,
    pub h_acc_m: f64,
    pub v_acc_m: f64,
}

/// NAV-RELPOSNED (0x01 0x3C): position of this receiver relative to a reference (an RTK
/// base, or the other antenna of a dual-antenna heading setup), NED. Version 0 (u-blox 8,
/// 40 bytes) has no length or heading; version 1 (u-blox 9, 64 bytes) has both.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NavRelposned {
    pub version: u8,
    pub ref_station_id: u16,
    pub itow_ms: u32,
    /// Relative position north, east, down, m (cm plus 0.1 mm parts, added up).
    pub rel_pos_ned_m: [f64; 3],
    /// Baseline length, m (version 1).
    pub rel_pos_length_m: Option<f64>,
    /// Heading of the baseline, degrees from true north (version 1; valid when flags bit 8).
    pub rel_pos_heading_deg: Option<f64>,
    /// Accuracy of the relative position north, east, down, m.
    pub acc_ned_m: [f64; 3],
    pub acc_length_m: Option<f64>,
    pub acc_heading_deg: Option<f64>,
    /// Bits: 0 gnssFixOK, 1 diffSoln, 2 relPosValid, 3–4 carrier solution, 5 isMoving,
    /// 6 refPosMiss, 7 refObsMiss, 8 relPosHeadingValid, 9 relPosNormalized.
    pub flags: u32,
}

impl NavRelposned {
    /// The baseline heading when the receiver marks it valid (and the relative position too).
    pub fn valid_heading_deg(&self) -> Option<f64> {
        let valid = self.flags & 0x104 == 0x104;
        self.rel_pos_heading_deg.filter(|_| valid)
    }
}

/// HNR-PVT (0x28 0x00): the high-rate navigation solution of dead-reckoning receivers
/// (up to 30 Hz, between and independent of the NAV epochs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct HnrPvt {
    pub itow_ms: u32,
    pub year: u16,
    pub month: u8,
    pub day: u8,
    pub hour: u8,
    pub min: u8,
    pub sec: u8,
    /// Bits: 0 valid date, 1 valid time, 2 fully resolved.
    pub valid: u8,
    pub nano_ns: i32,
    /// 0 no fix, 1 DR, 2 2D, 3 3D, 4 GNSS+DR, 5 time only.
    pub gps_fix: u8,
    /// Bits: 0 gpsFixOk, 1 diffSoln, 2 week set, 3 time of week set, 4 headVeh valid.
    pub flags: u8,
    pub lon_deg: f64,
    pub lat_deg: f64,
    pub height_m: f64,
    pub height_msl_m: f64,
    pub ground_speed_mps: f64,
    /// 3D speed, m/s.
    pub speed_mps: f64,
    pub head_mot_deg: f64,
    pub head_veh_deg: f64,
    pub h_acc_m: f64,
    pub v_acc_m: f64,
    pub s_acc_mps: f64,
    pub head_acc_deg: f64,
}

/// NAV-DOP (0x01 0x04): dilutions of precision.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NavDop {
    pub itow_ms: u32,
    pub gdop: f64,
    pub pdop: f64,
    pub tdop: f64,
    pub vdop: f64,
    pub hdop: f64,
    pub ndop: f64,
    pub edop: f64,
}

/// NAV-TIMEUTC (0x01 0x21): UTC time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct NavTimeutc {
    pub itow_ms: u32,
    pub t_acc_ns: u32,
    pub nano_ns: i32,
    pub year: u16,
    pub month: u8,
    pub day: u8,
    pub hour: u8,
    pub min: u8,
    pub sec: u8,
    pub valid: u8,
}

/// NAV-COV (0x01 0x36): position (m²) and velocity ((m/s)²) covariance, NED, upper triangle
/// in the order NN, NE, ND, EE, ED, DD.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NavCov {
    pub itow_ms: u32,
    pub version: u8,
    pub pos_cov_valid: u8,
    pub vel_cov_valid: u8,
    pub pos_cov: [f32; 6],
    pub vel_cov: [f32; 6],
}

/// One measurement of RXM-RAWX.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RawxMeas {
    /// Pseudorange, m.
    pub pr_mes_m: f64,
    /// Carrier phase, cycles.
    pub cp_mes_cycles: f64,
    /// Doppler, Hz.
    pub do_mes_hz: f32,
    pub gnss_id: u8,
    pub sv_id: u8,
    pub sig_id: u8,
    pub freq_id: u8,
    pub locktime_ms: u16,
    pub cno_dbhz: u8,
    /// Raw standard-deviation codes (pseudorange 0.01·2^n m, phase 0.004 cycles, Doppler 0.002·2^n Hz).
    pub pr_stdev: u8,
    pub cp_stdev: u8,
    pub do_stdev: u8,
    pub trk_stat: u8,
}

/// RXM-RAWX (0x02 0x15): multi-GNSS raw measurements.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RxmRawx {
    /// Receiver time of week, s.
    pub rcv_tow_s: f64,
    pub week: u16,
    pub leap_s: i8,
    pub rec_stat: u8,
    pub version: u8,
    pub meas: Vec<RawxMeas>,
}

/// MON-HW (0x0A 0x09): hardware status (60-byte layout).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct MonHw {
    pub pin_sel: u32,
    pub pin_bank: u32,
    pub pin_dir: u32,
    pub pin_val: u32,
    pub noise_per_ms: u16,
    pub agc_cnt: u16,
    pub a_status: u8,
    pub a_power: u8,
    pub flags: u8,
    pub used_mask: u32,
    pub vp: [u8; 17],
    pub jam_ind: u8,
    pub pin_irq: u32,
    pub pull_h: u32,
    pub pull_l: u32,
}

/// One 32-bit ESF data word: 24-bit value and 6-bit data type.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct EsfData {
    /// Data type (5 gyro z, 12 gyro temperature, 13 gyro y, 14 gyro x, 16/17/18 accel x/y/z,
    /// 6–11 wheel/speed ticks, …).
    pub data_type: u8,
    /// The 24-bit field as sent.
    pub raw: u32,
    /// The value in SI (rad/s, m/s², °C) for gyro, accelerometer and temperature types.
    pub si: Option<f64>,
}

impl EsfData {
    fn from_word(word: u32) -> EsfData {
        let raw = word & 0x00FF_FFFF;
        let data_type = ((word >> 24) & 0x3F) as u8;
        // Sign-extend the 24-bit field.
        let signed = f64::from(((raw << 8) as i32) >> 8);
        let si = match data_type {
            5 | 13 | 14 => Some(signed / 4096.0 * DEG_TO_RAD),
            16..=18 => Some(signed / 1024.0),
            12 => Some(signed / 100.0),
            _ => None,
        };
        EsfData { data_type, raw, si }
    }

    fn word(&self) -> u32 {
        (self.raw & 0x00FF_FFFF) | (u32::from(self.data_type & 0x3F) << 24)
    }
}

/// One sample of ESF-RAW.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct EsfRawSample {
    pub data: EsfData,
    pub s_ttag: u32,
}

/// ESF-RAW (0x10 0x03): raw sensor measurements.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EsfRaw {
    pub samples: Vec<EsfRawSample>,
}

/// The data words of one ESF-MEAS, stored inline as sent (numMeas is 5 bits, so at most 31)
/// so the IMU hot path allocates nothing per message; [`EsfData`] (type, raw, SI) is derived
/// on access and in JSON. Unused slots stay zero.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct EsfWords {
    len: u8,
    words: [u32; 31],
}

impl EsfWords {
    /// Builds from at most 31 data words (`None` if more).
    pub fn from_data(data: &[EsfData]) -> Option<EsfWords> {
        let mut out = EsfWords {
            len: u8::try_from(data.len()).ok().filter(|&n| n <= 31)?,
            words: [0; 31],
        };
        for (slot, d) in out.words.iter_mut().zip(data) {
            *slot = d.word();
        }
        Some(out)
    }

    pub fn len(&self) -> usize {
        usize::from(self.len.min(31))
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn get(&self, i: usize) -> Option<EsfData> {
        self.raw_words().get(i).map(|&w| EsfData::from_word(w))
    }

    pub fn iter(&self) -> impl Iterator<Item = EsfData> + '_ {
        self.raw_words().iter().map(|&w| EsfData::from_word(w))
    }

    /// The 32-bit words as sent (type in bits 24–29, value in bits 0–23).
    pub fn raw_words(&self) -> &[u32] {
        &self.words[..self.len()]
    }
}

impl std::fmt::Debug for EsfWords {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

impl Serialize for EsfWords {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(self.iter())
    }
}

/// ESF-MEAS (0x10 0x02): external sensor fusion measurements.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EsfMeas {
    pub time_tag: u32,
    pub flags: u16,
    pub id: u16,
    pub data: EsfWords,
    pub calib_ttag: Option<u32>,
}

/// Collects ESF data words of one measurement epoch into an [`ImuSample`] (sensor frame):
/// gyro x/y/z (types 14, 13, 5), accelerometer x/y/z (16, 17, 18), gyro temperature (12).
/// An axis the message did not carry is NaN; wheel ticks and speed are not IMU data.
#[derive(Default)]
struct EsfEpoch {
    gyro: [Option<f64>; 3],
    accel: [Option<f64>; 3],
    temp_c: Option<f64>,
}

impl EsfEpoch {
    fn add(&mut self, d: EsfData) {
        let slot = match d.data_type {
            14 => &mut self.gyro[0],
            13 => &mut self.gyro[1],
            5 => &mut self.gyro[2],
            16 => &mut self.accel[0],
            17 => &mut self.accel[1],
            18 => &mut self.accel[2],
            12 => &mut self.temp_c,
            _ => return,
        };
        *slot = d.si;
    }

    fn triad(axes: [Option<f64>; 3]) -> Option<[f64; 3]> {
        axes.iter()
            .any(Option::is_some)
            .then(|| axes.map(|a| a.unwrap_or(f64::NAN)))
    }

    fn sample(&self, sensor_time: f64) -> Option<ImuSample> {
        let gyro = Self::triad(self.gyro);
        let accel = Self::triad(self.accel);
        (gyro.is_some() || accel.is_some()).then_some(ImuSample {
            sensor_time: Some(sensor_time),
            gyro,
            accel,
            temp_c: self.temp_c,
            status: 0,
        })
    }
}

impl EsfRaw {
    /// The IMU samples of this message: consecutive data words with the same sensor time tag
    /// are one sample (`sensor_time` is that tag as sent). Messages with wheel ticks or speed
    /// only give none.
    pub fn to_imu_samples(&self) -> Vec<ImuSample> {
        let mut out = Vec::new();
        let mut epoch = EsfEpoch::default();
        let mut tag = None;
        for s in &self.samples {
            if tag.is_some_and(|t| t != s.s_ttag) {
                out.extend(epoch.sample(f64::from(tag.unwrap_or(0))));
                epoch = EsfEpoch::default();
            }
            tag = Some(s.s_ttag);
            epoch.add(s.data);
        }
        if let Some(t) = tag {
            out.extend(epoch.sample(f64::from(t)));
        }
        out
    }
}

impl EsfMeas {
    /// The IMU sample of this message (`sensor_time` is timeTag, ms), or `None` when it carries
    /// no gyro or accelerometer data (wheel ticks, speed).
    pub fn to_imu_sample(&self) -> Option<ImuSample> {
        let mut epoch = EsfEpoch::default();
        self.data.iter().for_each(|d| epoch.add(d));
        epoch.sample(f64::from(self.time_tag) * 1e-3)
    }
}

/// ACK-ACK / ACK-NAK: which message was (not) acknowledged.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Ack {
    pub class: u8,
    pub id: u8,
}

/// A message kept as class, id and payload bytes.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct RawMessage {
    pub class: u8,
    pub id: u8,
    /// Serialised as a lower-case hex string.
    #[serde(serialize_with = "hex_string")]
    pub payload: Vec<u8>,
}

fn hex_string<S: serde::Serializer>(bytes: &[u8], s: S) -> Result<S::Ok, S::Error> {
    const DIGITS: &[u8; 16] = b"0123456789abcdef";
    let text: String = bytes
        .iter()
        .flat_map(|b| [DIGITS[usize::from(b >> 4)], DIGITS[usize::from(b & 0x0F)]])
        .map(char::from)
        .collect();
    s.serialize_str(&text)
}

/// One decoded UBX message.
// Fixed-size messages (NAV-PVT, inline ESF-MEAS words) make this enum a few hundred bytes;
// moving that is cheaper than boxing, which would allocate per message.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "msg")]
pub enum UbxMessage {
    #[serde(rename = "NAV-PVT")]
    NavPvt(NavPvt),
    #[serde(rename = "NAV-STATUS")]
    NavStatus(NavStatus),
    #[serde(rename = "NAV-SAT")]
    NavSat(NavSat),
    #[serde(rename = "NAV-POSLLH")]
    NavPosllh(NavPosllh),
    #[serde(rename = "NAV-VELNED")]
    NavVelned(NavVelned),
    #[serde(rename = "NAV-TIMEUTC")]
    NavTimeutc(NavTimeutc),
    #[serde(rename = "NAV-DOP")]
    NavDop(NavDop),
    #[serde(rename = "NAV-SOL")]
    NavSol(NavSol),
    #[serde(rename = "NAV-POSECEF")]
    NavPosecef(NavPosecef),
    #[serde(rename = "NAV-VELECEF")]
    NavVelecef(NavVelecef),
    #[serde(rename = "NAV-TIMEGPS")]
    NavTimegps(NavTimegps),
    #[serde(rename = "NAV-HPPOSLLH")]
    NavHpposllh(NavHpposllh),
    #[serde(rename = "NAV-RELPOSNED")]
    NavRelposned(NavRelposned),
    #[serde(rename = "HNR-PVT")]
    HnrPvt(HnrPvt),
    #[serde(rename = "NAV-COV")]
    NavCov(NavCov),
    #[serde(rename = "RXM-RAWX")]
    RxmRawx(RxmRawx),
    #[serde(rename = "MON-HW")]
    MonHw(MonHw),
    #[serde(rename = "ESF-RAW")]
    EsfRaw(EsfRaw),
    #[serde(rename = "ESF-MEAS")]
    EsfMeas(EsfMeas),
    #[serde(rename = "ACK-ACK")]
    AckAck(Ack),
    #[serde(rename = "ACK-NAK")]
    AckNak(Ack),
    #[serde(rename = "raw")]
    Other(RawMessage),
}

impl UbxMessage {
    /// Class and id of this message on the wire.
    pub fn class_id(&self) -> (u8, u8) {
        match self {
            UbxMessage::NavPvt(_) => (0x01, 0x07),
            UbxMessage::NavStatus(_) => (0x01, 0x03),
            UbxMessage::NavSat(_) => (0x01, 0x35),
            UbxMessage::NavPosllh(_) => (0x01, 0x02),
            UbxMessage::NavVelned(_) => (0x01, 0x12),
            UbxMessage::NavTimeutc(_) => (0x01, 0x21),
            UbxMessage::NavDop(_) => (0x01, 0x04),
            UbxMessage::NavSol(_) => (0x01, 0x06),
            UbxMessage::NavPosecef(_) => (0x01, 0x01),
            UbxMessage::NavVelecef(_) => (0x01, 0x11),
            UbxMessage::NavTimegps(_) => (0x01, 0x20),
            UbxMessage::NavHpposllh(_) => (0x01, 0x14),
            UbxMessage::NavRelposned(_) => (0x01, 0x3C),
            UbxMessage::HnrPvt(_) => (0x28, 0x00),
            UbxMessage::NavCov(_) => (0x01, 0x36),
            UbxMessage::RxmRawx(_) => (0x02, 0x15),
            UbxMessage::MonHw(_) => (0x0A, 0x09),
            UbxMessage::EsfRaw(_) => (0x10, 0x03),
            UbxMessage::EsfMeas(_) => (0x10, 0x02),
            UbxMessage::AckAck(_) => (0x05, 0x01),
            UbxMessage::AckNak(_) => (0x05, 0x00),
            UbxMessage::Other(raw) => (raw.class, raw.id),
        }
    }
}

/// Little-endian reads from a payload whose length was checked beforehand; out-of-range
/// reads (impossible after that check) give zero instead of panicking.
struct Le<'a>(&'a [u8]);

impl Le<'_> {
    fn bytes<const N: usize>(&self, off: usize) -> [u8; N] {
        self.0
            .get(off..off + N)
            .and_then(|s| s.try_into().ok())
            .unwrap_or([0; N])
    }
    fn u8(&self, off: usize) -> u8 {
        self.bytes::<1>(off)[0]
    }
    fn i8(&self, off: usize) -> i8 {
        self.u8(off) as i8
    }
    fn u16(&self, off: usize) -> u16 {
        u16::from_le_bytes(self.bytes(off))
    }
    fn i16(&self, off: usize) -> i16 {
        i16::from_le_bytes(self.bytes(off))
    }
    fn u32(&self, off: usize) -> u32 {
        u32::from_le_bytes(self.bytes(off))
    }
    fn i32(&self, off: usize) -> i32 {
        i32::from_le_bytes(self.bytes(off))
    }
    fn f32(&self, off: usize) -> f32 {
        f32::from_le_bytes(self.bytes(off))
    }
    fn f64(&self, off: usize) -> f64 {
        f64::from_le_bytes(self.bytes(off))
    }
    /// Signed integer divided by `scale`.
    fn si32(&self, off: usize, scale: f64) -> f64 {
        f64::from(self.i32(off)) / scale
    }
    fn su32(&self, off: usize, scale: f64) -> f64 {
        f64::from(self.u32(off)) / scale
    }
    /// Three consecutive signed integers (an ECEF or NED vector) divided by `scale`.
    fn si32x3(&self, off: usize, scale: f64) -> [f64; 3] {
        std::array::from_fn(|i| self.si32(off + 4 * i, scale))
    }
    /// A standard-precision integer at `off` and its high-precision part at `hp_off`
    /// (`parts` of them make one standard unit), added up and divided by `scale`.
    fn hp(&self, off: usize, hp_off: usize, parts: i64, scale: f64) -> f64 {
        (i64::from(self.i32(off)) * parts + i64::from(self.i8(hp_off))) as f64 / scale
    }
}

/// Fletcher-8 over class, id, length and payload.
pub fn checksum(bytes: &[u8]) -> [u8; 2] {
    let (mut a, mut b) = (0u8, 0u8);
    for &x in bytes {
        a = a.wrapping_add(x);
        b = b.wrapping_add(a);
    }
    [a, b]
}

/// Scans one frame at `buf[0]` (which must be 0xB5).
pub(crate) fn scan_frame(buf: &[u8]) -> Scan<UbxMessage> {
    if buf.len() < 6 {
        // A second byte other than 0x62 already rules the frame out.
        if buf.len() >= 2 && buf[1] != SYNC[1] {
            return Scan::Reject {
                len: 1,
                reject: Reject::NoSync,
            };
        }
        return Scan::Incomplete;
    }
    if buf[1] != SYNC[1] {
        return Scan::Reject {
            len: 1,
            reject: Reject::NoSync,
        };
    }
    let payload_len = usize::from(u16::from_le_bytes([buf[4], buf[5]]));
    if payload_len > MAX_PAYLOAD {
        return Scan::Reject {
            len: 2,
            reject: Reject::TooLong,
        };
    }
    let total = payload_len + 8;
    if buf.len() < total {
        return Scan::Incomplete;
    }
    if checksum(&buf[2..6 + payload_len]) != [buf[total - 2], buf[total - 1]] {
        return Scan::Reject {
            len: 2,
            reject: Reject::Checksum,
        };
    }
    Scan::Frame {
        len: total,
        frame: parse_message(buf[2], buf[3], &buf[6..6 + payload_len]),
    }
}

/// Interprets a checksum-verified payload.
pub fn parse_message(class: u8, id: u8, payload: &[u8]) -> UbxMessage {
    parse_known(class, id, payload).unwrap_or_else(|| {
        UbxMessage::Other(RawMessage {
            class,
            id,
            payload: payload.to_vec(),
        })
    })
}

fn parse_known(class: u8, id: u8, p: &[u8]) -> Option<UbxMessage> {
    let r = Le(p);
    let n = p.len();
    Some(match (class, id) {
        (0x01, 0x07) if n == 92 || n == 84 => {
            let long = n == 92;
            UbxMessage::NavPvt(NavPvt {
                itow_ms: r.u32(0),
                year: r.u16(4),
                month: r.u8(6),
                day: r.u8(7),
                hour: r.u8(8),
                min: r.u8(9),
                sec: r.u8(10),
                valid: r.u8(11),
                t_acc_ns: r.u32(12),
                nano_ns: r.i32(16),
                fix_type: r.u8(20),
                flags: r.u8(21),
                flags2: r.u8(22),
                num_sv: r.u8(23),
                lon_deg: r.si32(24, 1e7),
                lat_deg: r.si32(28, 1e7),
                height_m: r.si32(32, 1e3),
                height_msl_m: r.si32(36, 1e3),
                h_acc_m: r.su32(40, 1e3),
                v_acc_m: r.su32(44, 1e3),
                vel_n_mps: r.si32(48, 1e3),
                vel_e_mps: r.si32(52, 1e3),
                vel_d_mps: r.si32(56, 1e3),
                ground_speed_mps: r.si32(60, 1e3),
                head_mot_deg: r.si32(64, 1e5),
                s_acc_mps: r.su32(68, 1e3),
                head_acc_deg: r.su32(72, 1e5),
                pdop: f64::from(r.u16(76)) / 100.0,
                flags3: r.u16(78),
                head_veh_deg: long.then(|| r.si32(84, 1e5)),
                mag_dec_deg: long.then(|| f64::from(r.i16(88)) / 100.0),
                mag_acc_deg: long.then(|| f64::from(r.u16(90)) / 100.0),
            })
        }
        (0x01, 0x03) if n == 16 => UbxMessage::NavStatus(NavStatus {
            itow_ms: r.u32(0),
            gps_fix: r.u8(4),
            flags: r.u8(5),
            fix_stat: r.u8(6),
            flags2: r.u8(7),
            ttff_ms: r.u32(8),
            msss_ms: r.u32(12),
        }),
        (0x01, 0x35) if n >= 8 && n == 8 + 12 * usize::from(r.u8(5)) => {
            let svs = (0..usize::from(r.u8(5)))
                .map(|i| {
                    let o = 8 + 12 * i;
                    NavSatSv {
                        gnss_id: r.u8(o),
                        sv_id: r.u8(o + 1),
                        cno_dbhz: r.u8(o + 2),
                        elev_deg: r.i8(o + 3),
                        azim_deg: r.i16(o + 4),
                        pr_res_m: f64::from(r.i16(o + 6)) / 10.0,
                        flags: r.u32(o + 8),
                    }
                })
                .collect();
            UbxMessage::NavSat(NavSat {
                itow_ms: r.u32(0),
                version: r.u8(4),
                svs,
            })
        }
        (0x01, 0x02) if n == 28 => UbxMessage::NavPosllh(NavPosllh {
            itow_ms: r.u32(0),
            lon_deg: r.si32(4, 1e7),
            lat_deg: r.si32(8, 1e7),
            height_m: r.si32(12, 1e3),
            height_msl_m: r.si32(16, 1e3),
            h_acc_m: r.su32(20, 1e3),
            v_acc_m: r.su32(24, 1e3),
        }),
        (0x01, 0x12) if n == 36 => UbxMessage::NavVelned(NavVelned {
            itow_ms: r.u32(0),
            vel_n_mps: r.si32(4, 1e2),
            vel_e_mps: r.si32(8, 1e2),
            vel_d_mps: r.si32(12, 1e2),
            speed_mps: r.su32(16, 1e2),
            ground_speed_mps: r.su32(20, 1e2),
            heading_deg: r.si32(24, 1e5),
            s_acc_mps: r.su32(28, 1e2),
            c_acc_deg: r.su32(32, 1e5),
        }),
        (0x01, 0x21) if n == 20 => UbxMessage::NavTimeutc(NavTimeutc {
            itow_ms: r.u32(0),
            t_acc_ns: r.u32(4),
            nano_ns: r.i32(8),
            year: r.u16(12),
            month: r.u8(14),
            day: r.u8(15),
            hour: r.u8(16),
            min: r.u8(17),
            sec: r.u8(18),
            valid: r.u8(19),
        }),
        (0x01, 0x04) if n == 18 => {
            let dop = |off: usize| f64::from(r.u16(off)) / 100.0;
            UbxMessage::NavDop(NavDop {
                itow_ms: r.u32(0),
                gdop: dop(4),
                pdop: dop(6),
                tdop: dop(8),
                vdop: dop(10),
                hdop: dop(12),
                ndop: dop(14),
                edop: dop(16),
            })
        }
        (0x01, 0x06) if n == 52 => UbxMessage::NavSol(NavSol {
            itow_ms: r.u32(0),
            ftow_ns: r.i32(4),
            week: r.i16(8),
            gps_fix: r.u8(10),
            flags: r.u8(11),
            ecef_m: r.si32x3(12, 1e2),
            p_acc_m: r.su32(24, 1e2),
            ecef_vel_mps: r.si32x3(28, 1e2),
            s_acc_mps: r.su32(40, 1e2),
            pdop: f64::from(r.u16(44)) / 100.0,
            num_sv: r.u8(47),
        }),
        (0x01, 0x01) if n == 20 => UbxMessage::NavPosecef(NavPosecef {
            itow_ms: r.u32(0),
            ecef_m: r.si32x3(4, 1e2),
            p_acc_m: r.su32(16, 1e2),
        }),
        (0x01, 0x11) if n == 20 => UbxMessage::NavVelecef(NavVelecef {
            itow_ms: r.u32(0),
            ecef_vel_mps: r.si32x3(4, 1e2),
            s_acc_mps: r.su32(16, 1e2),
        }),
        (0x01, 0x20) if n == 16 => UbxMessage::NavTimegps(NavTimegps {
            itow_ms: r.u32(0),
            ftow_ns: r.i32(4),
            week: r.i16(8),
            leap_s: r.i8(10),
            valid: r.u8(11),
            t_acc_ns: r.u32(12),
        }),
        (0x01, 0x14) if n == 36 => UbxMessage::NavHpposllh(NavHpposllh {
            version: r.u8(0),
            flags: r.u8(3),
            itow_ms: r.u32(4),
            lon_deg: r.hp(8, 24, 100, 1e9),
            lat_deg: r.hp(12, 25, 100, 1e9),
            height_m: r.hp(16, 26, 10, 1e4),
            height_msl_m: r.hp(20, 27, 10, 1e4),
            h_acc_m: r.su32(28, 1e4),
            v_acc_m: r.su32(32, 1e4),
        }),
        (0x01, 0x3C) if n == 40 => UbxMessage::NavRelposned(NavRelposned {
            version: r.u8(0),
            ref_station_id: r.u16(2),
            itow_ms: r.u32(4),
            rel_pos_ned_m: std::array::from_fn(|i| r.hp(8 + 4 * i, 20 + i, 100, 1e4)),
            rel_pos_length_m: None,
            rel_pos_heading_deg: None,
            acc_ned_m: std::array::from_fn(|i| r.su32(24 + 4 * i, 1e4)),
            acc_length_m: None,
            acc_heading_deg: None,
            flags: r.u32(36),
        }),
        (0x01, 0x3C) if n == 64 => UbxMessage::NavRelposned(NavRelposned {
            version: r.u8(0),
            ref_station_id: r.u16(2),
            itow_ms: r.u32(4),
            rel_pos_ned_m: std::array::from_fn(|i| r.hp(8 + 4 * i, 32 + i, 100, 1e4)),
            rel_pos_length_m: Some(r.hp(20, 35, 100, 1e4)),
            rel_pos_heading_deg: Some(r.si32(24, 1e5)),
            acc_ned_m: std::array::from_fn(|i| r.su32(36 + 4 * i, 1e4)),
            acc_length_m: Some(r.su32(48, 1e4)),
            acc_heading_deg: Some(r.su32(52, 1e5)),
            flags: r.u32(60),
        }),
        (0x28, 0x00) if n == 72 => UbxMessage::HnrPvt(HnrPvt {
            itow_ms: r.u32(0),
            year: r.u16(4),
            month: r.u8(6),
            day: r.u8(7),
            hour: r.u8(8),
            min: r.u8(9),
            sec: r.u8(10),
            valid: r.u8(11),
            nano_ns: r.i32(12),
            gps_fix: r.u8(16),
            flags: r.u8(17),
            lon_deg: r.si32(20, 1e7),
            lat_deg: r.si32(24, 1e7),
            height_m: r.si32(28, 1e3),
            height_msl_m: r.si32(32, 1e3),
            ground_speed_mps: r.si32(36, 1e3),
            speed_mps: r.si32(40, 1e3),
            head_mot_deg: r.si32(44, 1e5),
            head_veh_deg: r.si32(48, 1e5),
            h_acc_m: r.su32(52, 1e3),
            v_acc_m: r.su32(56, 1e3),
            s_acc_mps: r.su32(60, 1e3),
            head_acc_deg: r.su32(64, 1e5),
        }),
        (0x01, 0x36) if n == 64 => UbxMessage::NavCov(NavCov {
            itow_ms: r.u32(0),
            version: r.u8(4),
            pos_cov_valid: r.u8(5),
            vel_cov_valid: r.u8(6),
            pos_cov: std::array::from_fn(|i| r.f32(16 + 4 * i)),
            vel_cov: std::array::from_fn(|i| r.f32(40 + 4 * i)),
        }),
        (0x02, 0x15) if n >= 16 && n == 16 + 32 * usize::from(r.u8(11)) => {
            let meas = (0..usize::from(r.u8(11)))
                .map(|i| {
                    let o = 16 + 32 * i;
                    RawxMeas {
                        pr_mes_m: r.f64(o),
                        cp_mes_cycles: r.f64(o + 8),
                        do_mes_hz: r.f32(o + 16),
                        gnss_id: r.u8(o + 20),
                        sv_id: r.u8(o + 21),
                        sig_id: r.u8(o + 22),
                        freq_id: r.u8(o + 23),
                        locktime_ms: r.u16(o + 24),
                        cno_dbhz: r.u8(o + 26),
                        pr_stdev: r.u8(o + 27),
                        cp_stdev: r.u8(o + 28),
                        do_stdev: r.u8(o + 29),
                        trk_stat: r.u8(o + 30),
                    }
                })
                .collect();
            UbxMessage::RxmRawx(RxmRawx {
                rcv_tow_s: r.f64(0),
                week: r.u16(8),
                leap_s: r.i8(10),
                rec_stat: r.u8(12),
                version: r.u8(13),
                meas,
            })
        }
        (0x0A, 0x09) if n == 60 => UbxMessage::MonHw(MonHw {
            pin_sel: r.u32(0),
            pin_bank: r.u32(4),
            pin_dir: r.u32(8),
            pin_val: r.u32(12),
            noise_per_ms: r.u16(16),
            agc_cnt: r.u16(18),
            a_status: r.u8(20),
            a_power: r.u8(21),
            flags: r.u8(22),
            used_mask: r.u32(24),
            vp: r.bytes(28),
            jam_ind: r.u8(45),
            pin_irq: r.u32(48),
            pull_h: r.u32(52),
            pull_l: r.u32(56),
        }),
        (0x10, 0x03) if n >= 4 && (n - 4).is_multiple_of(8) => UbxMessage::EsfRaw(EsfRaw {
            samples: (0..(n - 4) / 8)
                .map(|i| EsfRawSample {
                    data: EsfData::from_word(r.u32(4 + 8 * i)),
                    s_ttag: r.u32(8 + 8 * i),
                })
                .collect(),
        }),
        (0x10, 0x02) if n >= 8 => {
            let flags = r.u16(4);
            // numMeas is 5 bits, so it always fits EsfWords.
            let num_meas = usize::from((flags >> 11) & 0x1F);
            let has_calib = flags & 0x08 != 0;
            if n != 8 + 4 * num_meas + if has_calib { 4 } else { 0 } {
                return None;
            }
            UbxMessage::EsfMeas(EsfMeas {
                time_tag: r.u32(0),
                flags,
                id: r.u16(6),
                data: {
                    let mut words = EsfWords {
                        len: num_meas as u8,
                        words: [0; 31],
                    };
                    for (i, slot) in words.words.iter_mut().take(num_meas).enumerate() {
                        *slot = r.u32(8 + 4 * i) & 0x3FFF_FFFF;
                    }
                    words
                },
                calib_ttag: has_calib.then(|| r.u32(8 + 4 * num_meas)),
            })
        }
        (0x05, 0x01) if n == 2 => UbxMessage::AckAck(Ack {
            class: r.u8(0),
            id: r.u8(1),
        }),
        (0x05, 0x00) if n == 2 => UbxMessage::AckNak(Ack {
            class: r.u8(0),
            id: r.u8(1),
        }),
        _ => return None,
    })
}

/// Streaming UBX decoder (see the module docs for the framing rule and
/// [`StreamBuffer`] for the counting rule).
#[derive(Debug, Default)]
pub struct UbxDecoder {
    buffer: StreamBuffer,
}

impl UbxDecoder {
    /// Bytes held waiting for the rest of a frame (bounded by the longest frame).
    pub fn buffered_len(&self) -> usize {
        self.buffer.len()
    }

    pub fn new() -> Self {
        Self::default()
    }
}

impl Decoder for UbxDecoder {
    type Frame = UbxMessage;

    fn push(&mut self, bytes: &[u8]) {
        self.buffer.push(bytes);
    }

    fn poll(&mut self) -> Option<UbxMessage> {
        self.buffer.next_scanned(&[SYNC[0]], scan_frame)
    }

    fn stats(&self) -> DecoderStats {
        self.buffer.stats()
    }
}

/// UBX-NAV-EOE: class 0x01, id 0x61, payload iTOW.
const NAV_EOE: (u8, u8) = (0x01, 0x61);

/// The messages a u-blox receiver sends for one epoch: NAV-PVT then NAV-EOE. Without a
/// position NAV-PVT has fix type 0, zero position and velocity and the largest accuracy
/// values, as receivers send it.
pub fn encode_fix(fix: &GnssFix, out: &mut Vec<u8>) -> Result<(), EncodeError> {
    let pvt = nav_pvt_of(fix)?;
    UbxEncoder.encode(&UbxMessage::NavPvt(pvt), out)?;
    UbxEncoder.encode(
        &UbxMessage::Other(RawMessage {
            class: NAV_EOE.0,
            id: NAV_EOE.1,
            payload: pvt.itow_ms.to_le_bytes().to_vec(),
        }),
        out,
    )
}

fn nav_pvt_of(fix: &GnssFix) -> Result<NavPvt, EncodeError> {
    use chrono::{Datelike, Timelike};
    let utc_ns = fix.utc_ns.ok_or(EncodeError::Invalid {
        field: "utc_ns",
        reason: "a NAV-PVT needs its UTC time",
    })?;
    let utc = chrono::DateTime::from_timestamp_nanos(utc_ns);
    let valid = fix.has_position();
    let (fix_type, carrier_flags) = match fix.fix {
        _ if !valid => (0, 0),
        FixType::DeadReckoning => (1, 0),
        FixType::Fix2D => (2, 0),
        FixType::GnssDeadReckoning => (4, 0),
        FixType::TimeOnly => (5, 0),
        FixType::Dgnss => (3, 0x02),
        FixType::RtkFloat => (3, 0x02 | 0x40),
        FixType::RtkFixed => (3, 0x02 | 0x80),
        _ => (3, 0),
    };
    let or = |v: Option<f64>, other: f64| match v {
        Some(v) if valid => v,
        _ => other,
    };
    let vel = match fix.vel_ned {
        Some(v) if valid => v,
        _ => [0.0; 3],
    };
    let speed = vel[0].hypot(vel[1]);
    let heading = vel[1].atan2(vel[0]).to_degrees().rem_euclid(360.0);
    // Largest accuracy the u32 mm field holds: what receivers report without a fix.
    let no_accuracy = f64::from(u32::MAX) / 1e3;
    let s_acc = or(fix.s_acc_mps, no_accuracy);
    let head_acc = if valid && speed > 0.0 {
        (s_acc / speed).atan().to_degrees().min(180.0)
    } else {
        180.0
    };
    let height = or(fix.height_m, 0.0);
    Ok(NavPvt {
        itow_ms: (fix.tow_s.unwrap_or(0.0) * 1000.0).round().max(0.0) as u32,
        year: utc.year() as u16,
        month: utc.month() as u8,
        day: utc.day() as u8,
        hour: utc.hour() as u8,
        min: utc.minute() as u8,
        sec: utc.second() as u8,
        // validDate, validTime, fullyResolved.
        valid: 0x07,
        t_acc_ns: 20,
        nano_ns: utc.nanosecond().min(999_999_999) as i32,
        fix_type,
        // gnssFixOK when there is a fix, plus the differential/carrier bits.
        flags: if valid { 0x01 | carrier_flags } else { 0 },
        flags2: 0,
        num_sv: fix.num_sats.unwrap_or(0),
        lon_deg: or(fix.lon_deg, 0.0),
        lat_deg: or(fix.lat_deg, 0.0),
        height_m: height,
        height_msl_m: or(fix.height_msl_m, height),
        h_acc_m: or(fix.h_acc_m, no_accuracy),
        v_acc_m: or(fix.v_acc_m, no_accuracy),
        vel_n_mps: vel[0],
        vel_e_mps: vel[1],
        vel_d_mps: vel[2],
        ground_speed_mps: speed,
        head_mot_deg: heading,
        s_acc_mps: s_acc,
        head_acc_deg: head_acc,
        pdop: or(fix.pdop, 99.99),
        flags3: 0,
        head_veh_deg: Some(heading),
        mag_dec_deg: Some(0.0),
        mag_acc_deg: Some(0.0),
    })
}

/// Auto-detection score: number of checksum-valid frames in the sample.
pub fn detect_score(sample: &[u8]) -> u32 {
    accepted_frames(UbxDecoder::new(), sample)
}

/// UBX encoder: writes sync, class, id, length, payload and checksum.
#[derive(Debug, Default, Clone, Copy)]
pub struct UbxEncoder;

/// Little-endian writer that checks scaled values fit their wire type.
struct Put<'a>(&'a mut Vec<u8>);

impl Put<'_> {
    fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    fn u16(&mut self, v: u16) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn i32(&mut self, v: i32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn i16(&mut self, v: i16) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn zeros(&mut self, n: usize) {
        self.0.resize(self.0.len() + n, 0);
    }
    fn scaled(
        &mut self,
        value: f64,
        scale: f64,
        min: f64,
        max: f64,
        field: &'static str,
    ) -> Result<i64, EncodeError> {
        let raw = (value * scale).round();
        if !raw.is_finite() || raw < min || raw > max {
            return Err(EncodeError::OutOfRange { field, value });
        }
        Ok(raw as i64)
    }
    fn si32(&mut self, value: f64, scale: f64, field: &'static str) -> Result<(), EncodeError> {
        let raw = self.scaled(
            value,
            scale,
            f64::from(i32::MIN),
            f64::from(i32::MAX),
            field,
        )?;
        self.i32(raw as i32);
        Ok(())
    }
    fn su32(&mut self, value: f64, scale: f64, field: &'static str) -> Result<(), EncodeError> {
        let raw = self.scaled(value, scale, 0.0, f64::from(u32::MAX), field)?;
        self.u32(raw as u32);
        Ok(())
    }
    fn su16(&mut self, value: f64, scale: f64, field: &'static str) -> Result<(), EncodeError> {
        let raw = self.scaled(value, scale, 0.0, f64::from(u16::MAX), field)?;
        self.u16(raw as u16);
        Ok(())
    }
    fn si16(&mut self, value: f64, scale: f64, field: &'static str) -> Result<(), EncodeError> {
        let raw = self.scaled(
            value,
            scale,
            f64::from(i16::MIN),
            f64::from(i16::MAX),
            field,
        )?;
        self.0.extend_from_slice(&(raw as i16).to_le_bytes());
        Ok(())
    }
}

/// Splits a value into its standard-precision integer and high-precision part (`parts` of
/// them make one standard unit; the part is kept within ±parts/2, inside the ±(parts−1) the
/// protocol allows).
fn split_hp(
    value: f64,
    scale: f64,
    parts: i64,
    field: &'static str,
) -> Result<(i32, i8), EncodeError> {
    let total = (value * scale).round();
    let out_of_range = EncodeError::OutOfRange { field, value };
    if !total.is_finite() || total.abs() > 2f64.powi(62) {
        return Err(out_of_range);
    }
    let total = total as i64;
    let coarse = (total as f64 / parts as f64).round() as i64;
    let fine = total - coarse * parts;
    match (i32::try_from(coarse), i8::try_from(fine)) {
        (Ok(c), Ok(f)) => Ok((c, f)),
        _ => Err(out_of_range),
    }
}

fn count_u8(n: usize, field: &'static str) -> Result<u8, EncodeError> {
    u8::try_from(n).map_err(|_| EncodeError::OutOfRange {
        field,
        value: n as f64,
    })
}

fn write_payload(msg: &UbxMessage, w: &mut Put) -> Result<(), EncodeError> {
    match msg {
        UbxMessage::NavPvt(m) => {
            w.u32(m.itow_ms);
            w.u16(m.year);
            for v in [m.month, m.day, m.hour, m.min, m.sec, m.valid] {
                w.u8(v);
            }
            w.u32(m.t_acc_ns);
            w.i32(m.nano_ns);
            for v in [m.fix_type, m.flags, m.flags2, m.num_sv] {
                w.u8(v);
            }
            w.si32(m.lon_deg, 1e7, "lon_deg")?;
            w.si32(m.lat_deg, 1e7, "lat_deg")?;
            w.si32(m.height_m, 1e3, "height_m")?;
            w.si32(m.height_msl_m, 1e3, "height_msl_m")?;
            w.su32(m.h_acc_m, 1e3, "h_acc_m")?;
            w.su32(m.v_acc_m, 1e3, "v_acc_m")?;
            w.si32(m.vel_n_mps, 1e3, "vel_n_mps")?;
            w.si32(m.vel_e_mps, 1e3, "vel_e_mps")?;
            w.si32(m.vel_d_mps, 1e3, "vel_d_mps")?;
            w.si32(m.ground_speed_mps, 1e3, "ground_speed_mps")?;
            w.si32(m.head_mot_deg, 1e5, "head_mot_deg")?;
            w.su32(m.s_acc_mps, 1e3, "s_acc_mps")?;
            w.su32(m.head_acc_deg, 1e5, "head_acc_deg")?;
            w.su16(m.pdop, 1e2, "pdop")?;
            w.u16(m.flags3);
            w.zeros(4);
            match (m.head_veh_deg, m.mag_dec_deg, m.mag_acc_deg) {
                (Some(head_veh), Some(mag_dec), Some(mag_acc)) => {
                    w.si32(head_veh, 1e5, "head_veh_deg")?;
                    w.si16(mag_dec, 1e2, "mag_dec_deg")?;
                    w.su16(mag_acc, 1e2, "mag_acc_deg")?;
                }
                (None, None, None) => {}
                _ => {
                    return Err(EncodeError::Invalid {
                        field: "head_veh_deg",
                        reason: "head_veh, mag_dec and mag_acc must be all present or all absent",
                    })
                }
            }
        }
        UbxMessage::NavStatus(m) => {
            w.u32(m.itow_ms);
            for v in [m.gps_fix, m.flags, m.fix_stat, m.flags2] {
                w.u8(v);
            }
            w.u32(m.ttff_ms);
            w.u32(m.msss_ms);
        }
        UbxMessage::NavSat(m) => {
            w.u32(m.itow_ms);
            w.u8(m.version);
            w.u8(count_u8(m.svs.len(), "svs")?);
            w.zeros(2);
            for sv in &m.svs {
                w.u8(sv.gnss_id);
                w.u8(sv.sv_id);
                w.u8(sv.cno_dbhz);
                w.u8(sv.elev_deg as u8);
                w.0.extend_from_slice(&sv.azim_deg.to_le_bytes());
                w.si16(sv.pr_res_m, 10.0, "pr_res_m")?;
                w.u32(sv.flags);
            }
        }
        UbxMessage::NavPosllh(m) => {
            w.u32(m.itow_ms);
            w.si32(m.lon_deg, 1e7, "lon_deg")?;
            w.si32(m.lat_deg, 1e7, "lat_deg")?;
            w.si32(m.height_m, 1e3, "height_m")?;
            w.si32(m.height_msl_m, 1e3, "height_msl_m")?;
            w.su32(m.h_acc_m, 1e3, "h_acc_m")?;
            w.su32(m.v_acc_m, 1e3, "v_acc_m")?;
        }
        UbxMessage::NavVelned(m) => {
            w.u32(m.itow_ms);
            w.si32(m.vel_n_mps, 1e2, "vel_n_mps")?;
            w.si32(m.vel_e_mps, 1e2, "vel_e_mps")?;
            w.si32(m.vel_d_mps, 1e2, "vel_d_mps")?;
            w.su32(m.speed_mps, 1e2, "speed_mps")?;
            w.su32(m.ground_speed_mps, 1e2, "ground_speed_mps")?;
            w.si32(m.heading_deg, 1e5, "heading_deg")?;
            w.su32(m.s_acc_mps, 1e2, "s_acc_mps")?;
            w.su32(m.c_acc_deg, 1e5, "c_acc_deg")?;
        }
        UbxMessage::NavTimeutc(m) => {
            w.u32(m.itow_ms);
            w.u32(m.t_acc_ns);
            w.i32(m.nano_ns);
            w.u16(m.year);
            for v in [m.month, m.day, m.hour, m.min, m.sec, m.valid] {
                w.u8(v);
            }
        }
        UbxMessage::NavDop(m) => {
            w.u32(m.itow_ms);
            let dops = [m.gdop, m.pdop, m.tdop, m.vdop, m.hdop, m.ndop, m.edop];
            let fields = ["gdop", "pdop", "tdop", "vdop", "hdop", "ndop", "edop"];
            for (v, field) in dops.into_iter().zip(fields) {
                w.su16(v, 1e2, field)?;
            }
        }
        UbxMessage::NavSol(m) => {
            w.u32(m.itow_ms);
            w.i32(m.ftow_ns);
            w.i16(m.week);
            w.u8(m.gps_fix);
            w.u8(m.flags);
            for (v, field) in m.ecef_m.iter().zip(["ecef_x_m", "ecef_y_m", "ecef_z_m"]) {
                w.si32(*v, 1e2, field)?;
            }
            w.su32(m.p_acc_m, 1e2, "p_acc_m")?;
            for (v, field) in m.ecef_vel_mps.iter().zip(["ecef_vx", "ecef_vy", "ecef_vz"]) {
                w.si32(*v, 1e2, field)?;
            }
            w.su32(m.s_acc_mps, 1e2, "s_acc_mps")?;
            w.su16(m.pdop, 1e2, "pdop")?;
            w.zeros(1);
            w.u8(m.num_sv);
            w.zeros(4);
        }
        UbxMessage::NavPosecef(m) => {
            w.u32(m.itow_ms);
            for (v, field) in m.ecef_m.iter().zip(["ecef_x_m", "ecef_y_m", "ecef_z_m"]) {
                w.si32(*v, 1e2, field)?;
            }
            w.su32(m.p_acc_m, 1e2, "p_acc_m")?;
        }
        UbxMessage::NavVelecef(m) => {
            w.u32(m.itow_ms);
            for (v, field) in m.ecef_vel_mps.iter().zip(["ecef_vx", "ecef_vy", "ecef_vz"]) {
                w.si32(*v, 1e2, field)?;
            }
            w.su32(m.s_acc_mps, 1e2, "s_acc_mps")?;
        }
        UbxMessage::NavTimegps(m) => {
            w.u32(m.itow_ms);
            w.i32(m.ftow_ns);
            w.i16(m.week);
            w.u8(m.leap_s as u8);
            w.u8(m.valid);
            w.u32(m.t_acc_ns);
        }
        UbxMessage::NavHpposllh(m) => {
            let lon = split_hp(m.lon_deg, 1e9, 100, "lon_deg")?;
            let lat = split_hp(m.lat_deg, 1e9, 100, "lat_deg")?;
            let height = split_hp(m.height_m, 1e4, 10, "height_m")?;
            let msl = split_hp(m.height_msl_m, 1e4, 10, "height_msl_m")?;
            w.u8(m.version);
            w.zeros(2);
            w.u8(m.flags);
            w.u32(m.itow_ms);
            for (coarse, _) in [lon, lat, height, msl] {
                w.i32(coarse);
            }
            for (_, fine) in [lon, lat, height, msl] {
                w.u8(fine as u8);
            }
            w.su32(m.h_acc_m, 1e4, "h_acc_m")?;
            w.su32(m.v_acc_m, 1e4, "v_acc_m")?;
        }
        UbxMessage::NavRelposned(m) => {
            let ned: Vec<(i32, i8)> = m
                .rel_pos_ned_m
                .iter()
                .zip(["rel_pos_n_m", "rel_pos_e_m", "rel_pos_d_m"])
                .map(|(v, field)| split_hp(*v, 1e4, 100, field))
                .collect::<Result<_, _>>()?;
            w.u8(m.version);
            w.zeros(1);
            w.u16(m.ref_station_id);
            w.u32(m.itow_ms);
            for &(coarse, _) in &ned {
                w.i32(coarse);
            }
            let acc_fields = ["acc_n_m", "acc_e_m", "acc_d_m"];
            match (
                m.rel_pos_length_m,
                m.rel_pos_heading_deg,
                m.acc_length_m,
                m.acc_heading_deg,
            ) {
                (None, None, None, None) => {
                    for &(_, fine) in &ned {
                        w.u8(fine as u8);
                    }
                    w.zeros(1);
                    for (v, field) in m.acc_ned_m.iter().zip(acc_fields) {
                        w.su32(*v, 1e4, field)?;
                    }
                }
                (Some(length), Some(heading), Some(acc_length), Some(acc_heading)) => {
                    let length = split_hp(length, 1e4, 100, "rel_pos_length_m")?;
                    w.i32(length.0);
                    w.si32(heading, 1e5, "rel_pos_heading_deg")?;
                    w.zeros(4);
                    for &(_, fine) in &ned {
                        w.u8(fine as u8);
                    }
                    w.u8(length.1 as u8);
                    for (v, field) in m.acc_ned_m.iter().zip(acc_fields) {
                        w.su32(*v, 1e4, field)?;
                    }
                    w.su32(acc_length, 1e4, "acc_length_m")?;
                    w.su32(acc_heading, 1e5, "acc_heading_deg")?;
                    w.zeros(4);
                }
                _ => {
                    return Err(EncodeError::Invalid {
                        field: "rel_pos_length_m",
                        reason: "length, heading and their accuracies must be all present \
                                 (version 1 layout) or all absent (version 0)",
                    })
                }
            }
            w.u32(m.flags);
        }
        UbxMessage::HnrPvt(m) => {
            w.u32(m.itow_ms);
            w.u16(m.year);
            for v in [m.month, m.day, m.hour, m.min, m.sec, m.valid] {
                w.u8(v);
            }
            w.i32(m.nano_ns);
            w.u8(m.gps_fix);
            w.u8(m.flags);
            w.zeros(2);
            w.si32(m.lon_deg, 1e7, "lon_deg")?;
            w.si32(m.lat_deg, 1e7, "lat_deg")?;
            w.si32(m.height_m, 1e3, "height_m")?;
            w.si32(m.height_msl_m, 1e3, "height_msl_m")?;
            w.si32(m.ground_speed_mps, 1e3, "ground_speed_mps")?;
            w.si32(m.speed_mps, 1e3, "speed_mps")?;
            w.si32(m.head_mot_deg, 1e5, "head_mot_deg")?;
            w.si32(m.head_veh_deg, 1e5, "head_veh_deg")?;
            w.su32(m.h_acc_m, 1e3, "h_acc_m")?;
            w.su32(m.v_acc_m, 1e3, "v_acc_m")?;
            w.su32(m.s_acc_mps, 1e3, "s_acc_mps")?;
            w.su32(m.head_acc_deg, 1e5, "head_acc_deg")?;
            w.zeros(4);
        }
        UbxMessage::NavCov(m) => {
            w.u32(m.itow_ms);
            w.u8(m.version);
            w.u8(m.pos_cov_valid);
            w.u8(m.vel_cov_valid);
            w.zeros(9);
            for v in m.pos_cov.iter().chain(&m.vel_cov) {
                w.0.extend_from_slice(&v.to_le_bytes());
            }
        }
        UbxMessage::RxmRawx(m) => {
            w.0.extend_from_slice(&m.rcv_tow_s.to_le_bytes());
            w.u16(m.week);
            w.u8(m.leap_s as u8);
            w.u8(count_u8(m.meas.len(), "meas")?);
            w.u8(m.rec_stat);
            w.u8(m.version);
            w.zeros(2);
            for x in &m.meas {
                w.0.extend_from_slice(&x.pr_mes_m.to_le_bytes());
                w.0.extend_from_slice(&x.cp_mes_cycles.to_le_bytes());
                w.0.extend_from_slice(&x.do_mes_hz.to_le_bytes());
                for v in [x.gnss_id, x.sv_id, x.sig_id, x.freq_id] {
                    w.u8(v);
                }
                w.u16(x.locktime_ms);
                for v in [x.cno_dbhz, x.pr_stdev, x.cp_stdev, x.do_stdev, x.trk_stat] {
                    w.u8(v);
                }
                w.zeros(1);
            }
        }
        UbxMessage::MonHw(m) => {
            for v in [m.pin_sel, m.pin_bank, m.pin_dir, m.pin_val] {
                w.u32(v);
            }
            w.u16(m.noise_per_ms);
            w.u16(m.agc_cnt);
            w.u8(m.a_status);
            w.u8(m.a_power);
            w.u8(m.flags);
            w.zeros(1);
            w.u32(m.used_mask);
            w.0.extend_from_slice(&m.vp);
            w.u8(m.jam_ind);
            w.zeros(2);
            for v in [m.pin_irq, m.pull_h, m.pull_l] {
                w.u32(v);
            }
        }
        UbxMessage::EsfRaw(m) => {
            w.zeros(4);
            for s in &m.samples {
                w.u32(s.data.word());
                w.u32(s.s_ttag);
            }
        }
        UbxMessage::EsfMeas(m) => {
            let expected = usize::from((m.flags >> 11) & 0x1F);
            if expected != m.data.len() || (m.flags & 0x08 != 0) != m.calib_ttag.is_some() {
                return Err(EncodeError::Invalid {
                    field: "flags",
                    reason: "numMeas and calibTtagValid bits must match data and calib_ttag",
                });
            }
            w.u32(m.time_tag);
            w.u16(m.flags);
            w.u16(m.id);
            for &word in m.data.raw_words() {
                w.u32(word);
            }
            if let Some(t) = m.calib_ttag {
                w.u32(t);
            }
        }
        UbxMessage::AckAck(a) | UbxMessage::AckNak(a) => {
            w.u8(a.class);
            w.u8(a.id);
        }
        UbxMessage::Other(raw) => w.0.extend_from_slice(&raw.payload),
    }
    Ok(())
}

impl Encoder for UbxEncoder {
    type Frame = UbxMessage;

    fn encode(&self, msg: &UbxMessage, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        let begin = out.len();
        let (class, id) = msg.class_id();
        out.extend_from_slice(&[SYNC[0], SYNC[1], class, id, 0, 0]);
        if let Err(e) = write_payload(msg, &mut Put(out)) {
            out.truncate(begin);
            return Err(e);
        }
        let payload_len = out.len() - begin - 6;
        if payload_len > MAX_PAYLOAD {
            out.truncate(begin);
            return Err(EncodeError::TooLong {
                len: payload_len,
                max: MAX_PAYLOAD,
            });
        }
        out[begin + 4..begin + 6].copy_from_slice(&(payload_len as u16).to_le_bytes());
        let ck = checksum(&out[begin + 2..]);
        out.extend_from_slice(&ck);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fletcher_checksum_of_known_poll_frame() {
        // UBX-CFG-PRT poll (class 06 id 00, empty payload) is B5 62 06 00 00 00 06 18.
        assert_eq!(checksum(&[0x06, 0x00, 0x00, 0x00]), [0x06, 0x18]);
    }

    #[test]
    fn nav_posllh_scales_to_si() {
        let mut payload = Vec::new();
        payload.extend_from_slice(&1000u32.to_le_bytes());
        payload.extend_from_slice(&(-1213100000i32).to_le_bytes());
        payload.extend_from_slice(&440600000i32.to_le_bytes());
        payload.extend_from_slice(&1234567i32.to_le_bytes());
        payload.extend_from_slice(&1200000i32.to_le_bytes());
        payload.extend_from_slice(&1500u32.to_le_bytes());
        payload.extend_from_slice(&2500u32.to_le_bytes());
        let UbxMessage::NavPosllh(m) = parse_message(0x01, 0x02, &payload) else {
            panic!("not POSLLH")
        };
        assert_eq!(m.lon_deg, -121.31);
        assert_eq!(m.lat_deg, 44.06);
        assert_eq!(m.height_m, 1234.567);
        assert_eq!(m.h_acc_m, 1.5);
    }

    #[test]
    fn corrupt_frames_are_counted_and_following_frames_survive() {
        let mut good = Vec::new();
        UbxEncoder
            .encode(&UbxMessage::AckAck(Ack { class: 6, id: 1 }), &mut good)
            .unwrap();
        let mut stream = Vec::new();
        stream.extend_from_slice(b"noise");
        let mut bad = good.clone();
        bad[7] ^= 0xFF; // break the checksum
        stream.extend_from_slice(&bad);
        stream.extend_from_slice(&[0xB5, 0x62, 0x01, 0x07, 0xFF, 0xFF]); // absurd length
        stream.extend_from_slice(&good);
        let mut d = UbxDecoder::new();
        let mut frames = Vec::new();
        d.decode(&stream, |f| frames.push(f));
        assert_eq!(frames, vec![UbxMessage::AckAck(Ack { class: 6, id: 1 })]);
        let stats = d.stats();
        assert_eq!(stats.checksum_errors, 1);
        assert_eq!(stats.frames_too_long, 1);
        assert!(stats.bytes_skipped >= 5, "{stats:?}");
    }

    #[test]
    fn esf_meas_gyro_and_accel_to_si() {
        let msg = UbxMessage::EsfMeas(EsfMeas {
            time_tag: 7,
            flags: 2 << 11,
            id: 0,
            data: EsfWords::from_data(&[
                EsfData::from_word((14 << 24) | 4096), // 1 deg/s about x
                EsfData::from_word((16 << 24) | (0x00FF_FFFF & (-1024i32 as u32))), // −1 m/s²
            ])
            .unwrap(),
            calib_ttag: None,
        });
        let UbxMessage::EsfMeas(m) = &msg else {
            unreachable!()
        };
        let first = m.data.get(0).and_then(|d| d.si).unwrap_or(0.0);
        assert!((first - DEG_TO_RAD).abs() < 1e-15);
        assert_eq!(m.data.get(1).and_then(|d| d.si), Some(-1.0));
        let mut bytes = Vec::new();
        UbxEncoder.encode(&msg, &mut bytes).unwrap();
        let mut d = UbxDecoder::new();
        let mut frames = Vec::new();
        d.decode(&bytes, |f| frames.push(f));
        assert_eq!(frames, vec![msg]);
    }

    /// An ESF-RAW payload built by hand: 4 reserved bytes, then (data word, sTtag) pairs.
    fn esf_raw_frame(pairs: &[(u8, i32, u32)]) -> Vec<u8> {
        let mut payload = vec![0u8; 4];
        for &(data_type, value, tag) in pairs {
            let word = (u32::from(data_type) << 24) | (value as u32 & 0x00FF_FFFF);
            payload.extend_from_slice(&word.to_le_bytes());
            payload.extend_from_slice(&tag.to_le_bytes());
        }
        let mut frame = vec![0xB5, 0x62, 0x10, 0x03];
        frame.extend_from_slice(&(payload.len() as u16).to_le_bytes());
        frame.extend_from_slice(&payload);
        // Fletcher-8 over class, id, length and payload, written out here independently of
        // `checksum`.
        let (mut a, mut b) = (0u8, 0u8);
        for &x in &frame[2..] {
            a = a.wrapping_add(x);
            b = b.wrapping_add(a);
        }
        frame.extend_from_slice(&[a, b]);
        frame
    }

    #[test]
    fn esf_raw_words_with_one_time_tag_are_one_imu_sample() {
        // Two epochs (tags 1000 and 1100) of gyro x/y/z, temperature, accel x/y/z, then a
        // wheel-tick word (type 8) alone under tag 1200.
        let mut pairs = Vec::new();
        for (tag, sign) in [(1000u32, 1i32), (1100, -1)] {
            pairs.extend_from_slice(&[
                (14, sign * 4096, tag),     // 1 deg/s
                (13, sign * 2 * 4096, tag), // 2 deg/s
                (5, sign * -8192, tag),     // -2 deg/s (24-bit negative)
                (12, 2550, tag),            // 25.5 °C
                (16, sign * 1024, tag),     // 1 m/s²
                (17, sign * -512, tag),     // -0.5 m/s²
                (18, sign * 10043, tag),    // 9.8076 m/s²
            ]);
        }
        pairs.push((8, 77, 1200));
        let mut bytes = b"\xB5garbage".to_vec();
        bytes.extend(esf_raw_frame(&pairs));
        let mut d = UbxDecoder::new();
        let mut frames = Vec::new();
        d.decode(&bytes, |f| frames.push(f));
        let [UbxMessage::EsfRaw(raw)] = frames.as_slice() else {
            panic!("expected one ESF-RAW, got {frames:?}");
        };
        let samples = raw.to_imu_samples();
        assert_eq!(samples.len(), 2, "{samples:?}");
        for (s, (tag, sign)) in samples.iter().zip([(1000.0, 1.0), (1100.0, -1.0)]) {
            assert_eq!(s.sensor_time, Some(tag));
            let g = s.gyro.unwrap();
            for (got, want) in g.iter().zip([1.0, 2.0, -2.0]) {
                assert!((got - sign * want * DEG_TO_RAD).abs() < 1e-15, "{g:?}");
            }
            let a = s.accel.unwrap();
            assert_eq!(a, [sign, -0.5 * sign, sign * 10043.0 / 1024.0]);
            assert_eq!(s.temp_c, Some(25.5));
        }
        assert!(d.stats().bytes_skipped >= 8);
        // Re-encoding gives the same bytes (checksum recomputed by the encoder).
        let mut again = Vec::new();
        UbxEncoder.encode(&frames[0], &mut again).unwrap();
        assert_eq!(again, esf_raw_frame(&pairs));
    }

    #[test]
    fn esf_meas_with_a_partial_triad_gives_nan_axes_and_wheel_ticks_give_no_sample() {
        let meas = |words: &[u32]| EsfMeas {
            time_tag: 2500,
            flags: (words.len() as u16) << 11,
            id: 0,
            data: EsfWords::from_data(
                &words
                    .iter()
                    .map(|&w| EsfData::from_word(w))
                    .collect::<Vec<_>>(),
            )
            .unwrap(),
            calib_ttag: None,
        };
        let s = meas(&[(5 << 24) | 4096]).to_imu_sample().unwrap();
        assert_eq!(s.sensor_time, Some(2.5));
        let g = s.gyro.unwrap();
        assert!(g[0].is_nan() && g[1].is_nan() && (g[2] - DEG_TO_RAD).abs() < 1e-15);
        assert_eq!(s.accel, None);
        assert_eq!(
            meas(&[(11 << 24) | 300, (10 << 24) | 12]).to_imu_sample(),
            None
        );
    }
}
