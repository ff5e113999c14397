//! MicroStrain MIP packets (3DM-GX5, 3DM-CV5/CV7; facts from the 3DM-GX5 DCP manuals).
//!
//! Packet: `0x75 0x65`, descriptor set, payload length (≤ 255), the payload as fields of
//! `length, descriptor, data` (the length counts its own two bytes), then a Fletcher-16
//! checksum over everything before it (two running 8-bit sums, the first sent first).
//! Values are big-endian.
//!
//! The IMU data set (0x80) is decoded: scaled accelerometer (0x04, g), scaled gyro (0x05,
//! rad/s), scaled magnetometer (0x06, gauss), delta theta (0x07, rad), delta velocity
//! (0x08, g·s), quaternion (0x0A), Euler angles (0x0C, rad), internal timestamp (0x0E,
//! ticks), GPS correlation timestamp (0x12: time of week s, week, valid flags), scaled
//! ambient pressure (0x17, mbar), and the shared GPS timestamp (0xD3, same layout as 0x12)
//! and reference timestamp (0xD5, ns). Other IMU fields are counted in `skipped_fields`.
//! The IMU data set defines no temperature field, so MIP samples carry none. A device set
//! to output delta theta / delta velocity instead of scaled gyro / accelerometer gives the
//! same gyro and accelerometer rows: [`MipSamples`] takes each delta over the device-time
//! interval since the previous IMU data packet. Command
//! replies (a command descriptor set whose first field is the ACK/NACK field 0xF1: echoed
//! command descriptor, error code) are [`MipPacket::Reply`]; other packets are kept whole
//! as [`MipPacket::Other`]. Neither is a sample.

use super::reading::DeviceClock;
use super::{
    accepted_frames, Decoder, EncodeError, Encoder, ImuOutput, Reject, RowsFrom, Scan, StreamBuffer,
};
use crate::types::{DecoderStats, ImuSample};

pub const SYNC1: u8 = 0x75;
pub const SYNC2: u8 = 0x65;
/// IMU data descriptor set.
pub const IMU_DATA_SET: u8 = 0x80;
/// ACK/NACK reply field descriptor.
pub const ACK_NACK_FIELD: u8 = 0xF1;
/// 1 g as the manual defines it, m/s².
pub const STANDARD_GRAVITY: f64 = 9.806_65;
/// Auto-detection needs at least this many checksummed MIP packets in the sample.
pub const DETECT_MIN_FRAMES: u32 = 2;

/// IMU data set field descriptors.
pub mod field {
    pub const SCALED_ACCEL: u8 = 0x04;
    pub const SCALED_GYRO: u8 = 0x05;
    pub const SCALED_MAG: u8 = 0x06;
    pub const DELTA_THETA: u8 = 0x07;
    pub const DELTA_VELOCITY: u8 = 0x08;
    pub const QUATERNION: u8 = 0x0A;
    pub const EULER_ANGLES: u8 = 0x0C;
    pub const INTERNAL_TIMESTAMP: u8 = 0x0E;
    pub const GPS_CORRELATION_TIMESTAMP: u8 = 0x12;
    pub const SCALED_PRESSURE: u8 = 0x17;
    pub const SHARED_GPS_TIMESTAMP: u8 = 0xD3;
    pub const SHARED_REFERENCE_TIMESTAMP: u8 = 0xD5;
}

/// A GPS time stamp (fields 0x12 and 0xD3).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct MipGpsTime {
    /// GPS time of week, s.
    pub tow_s: f64,
    pub week: u16,
    pub valid_flags: u16,
}

/// The fields of one IMU data set packet. Absent = not in the packet.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct MipImuData {
    /// Scaled acceleration, g.
    pub scaled_accel_g: Option<[f32; 3]>,
    /// Scaled angular rate, rad/s.
    pub scaled_gyro: Option<[f32; 3]>,
    /// Scaled magnetic field, gauss.
    pub scaled_mag: Option<[f32; 3]>,
    /// Delta theta, rad.
    pub delta_theta: Option<[f32; 3]>,
    /// Delta velocity, g·s.
    pub delta_velocity_gs: Option<[f32; 3]>,
    pub quaternion: Option<[f32; 4]>,
    /// Roll, pitch, yaw, rad.
    pub euler_rad: Option<[f32; 3]>,
    pub internal_timestamp: Option<u32>,
    pub gps_correlation_time: Option<MipGpsTime>,
    /// Ambient pressure, mbar.
    pub pressure_mbar: Option<f32>,
    pub shared_gps_time: Option<MipGpsTime>,
    /// Shared reference timestamp, ns.
    pub reference_time_ns: Option<u64>,
    /// Fields of the IMU data set not kept.
    pub skipped_fields: u16,
}

/// Longest device-time interval between two IMU data packets over which a delta is taken
/// as a rate, s (a longer one is a gap or a lost packet).
pub const MAX_DELTA_INTERVAL_S: f64 = 1.0;

impl MipImuData {
    /// The SI sample, or `None` without accelerometer or gyro. Device time: the GPS
    /// correlation time of week (s), else the shared GPS time of week, else the reference
    /// timestamp (s), else the internal timestamp in its ticks. Without scaled gyro (or
    /// accelerometer), delta theta (or delta velocity) over `delta_interval_s`, the
    /// device-time interval since the previous IMU data packet ([`MipSamples`]), gives it;
    /// with [`RowsFrom::Deltas`] the deltas come first.
    pub fn to_imu_sample(
        &self,
        delta_interval_s: Option<f64>,
        rows_from: RowsFrom,
    ) -> Option<ImuSample> {
        let interval = delta_interval_s.filter(|dt| dt.is_finite() && *dt > 0.0);
        let per_second = |delta: Option<[f32; 3]>, scale: f64| {
            let dt = interval?;
            delta.map(|d| d.map(|x| f64::from(x) * scale / dt))
        };
        let rate = self.scaled_gyro.map(|v| v.map(f64::from));
        let from_delta = per_second(self.delta_theta, 1.0);
        let accel = self
            .scaled_accel_g
            .map(|v| v.map(|g| f64::from(g) * STANDARD_GRAVITY));
        let accel_from_delta = per_second(self.delta_velocity_gs, STANDARD_GRAVITY);
        let (gyro, accel) = match rows_from {
            RowsFrom::Rates => (rate.or(from_delta), accel.or(accel_from_delta)),
            RowsFrom::Deltas => (from_delta.or(rate), accel_from_delta.or(accel)),
        };
        if gyro.is_none() && accel.is_none() {
            return None;
        }
        let sensor_time = self.seconds().or(self.internal_timestamp.map(f64::from));
        Some(ImuSample {
            sensor_time,
            gyro,
            accel,
            temp_c: None,
            status: 0,
        })
    }

    /// The device time in seconds: GPS correlation time of week, else shared GPS time of
    /// week, else the reference timestamp.
    fn seconds(&self) -> Option<f64> {
        self.gps_correlation_time
            .or(self.shared_gps_time)
            .map(|t| t.tow_s)
            .or(self.reference_time_ns.map(|ns| ns as f64 / 1e9))
    }
}

/// One MIP packet.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum MipPacket {
    /// IMU data set (0x80).
    Imu(MipImuData),
    /// A command reply: ACK (`error_code` 0) or NACK, and any reply fields after it.
    Reply {
        descriptor_set: u8,
        command: u8,
        error_code: u8,
        more_fields: Vec<u8>,
    },
    /// Any other packet, payload kept as is.
    Other {
        descriptor_set: u8,
        payload: Vec<u8>,
    },
}

impl MipPacket {
    /// The sample of this packet alone: its scaled gyro and accelerometer (deltas need the
    /// interval since the previous packet: [`MipSamples`]).
    pub fn to_imu_sample(&self) -> Option<ImuSample> {
        match self {
            MipPacket::Imu(data) => data.to_imu_sample(None, RowsFrom::Rates),
            _ => None,
        }
    }
}

/// The Fletcher-16 checksum of the manual: (first sum, sum of first sums), each mod 256.
pub fn fletcher16(bytes: &[u8]) -> [u8; 2] {
    let (mut a, mut b) = (0u8, 0u8);
    for &x in bytes {
        a = a.wrapping_add(x);
        b = b.wrapping_add(a);
    }
    [a, b]
}

fn f32s<const N: usize>(d: &[u8]) -> [f32; N] {
    std::array::from_fn(|i| {
        f32::from_be_bytes([d[4 * i], d[4 * i + 1], d[4 * i + 2], d[4 * i + 3]])
    })
}

fn gps_time(d: &[u8]) -> MipGpsTime {
    MipGpsTime {
        tow_s: f64::from_be_bytes([d[0], d[1], d[2], d[3], d[4], d[5], d[6], d[7]]),
        week: u16::from_be_bytes([d[8], d[9]]),
        valid_flags: u16::from_be_bytes([d[10], d[11]]),
    }
}

/// Parses an IMU data set payload; `Err` with the reason when the fields do not add up.
pub fn parse_imu_data(payload: &[u8]) -> Result<MipImuData, String> {
    let mut out = MipImuData::default();
    let mut rest = payload;
    while !rest.is_empty() {
        let len = usize::from(rest[0]);
        if len < 2 || len > rest.len() {
            return Err(format!(
                "field length {len} at payload offset {} ({} bytes left)",
                payload.len() - rest.len(),
                rest.len()
            ));
        }
        let (descriptor, data) = (rest[1], &rest[2..len]);
        match (descriptor, data.len()) {
            (field::SCALED_ACCEL, 12) => {
                out.scaled_accel_g = Some(f32s(data));
            }
            (field::SCALED_GYRO, 12) => {
                out.scaled_gyro = Some(f32s(data));
            }
            (field::SCALED_MAG, 12) => {
                out.scaled_mag = Some(f32s(data));
            }
            (field::DELTA_THETA, 12) => {
                out.delta_theta = Some(f32s(data));
            }
            (field::DELTA_VELOCITY, 12) => {
                out.delta_velocity_gs = Some(f32s(data));
            }
            (field::QUATERNION, 16) => {
                out.quaternion = Some(f32s(data));
            }
            (field::EULER_ANGLES, 12) => {
                out.euler_rad = Some(f32s(data));
            }
            (field::INTERNAL_TIMESTAMP, 4) => {
                out.internal_timestamp =
                    Some(u32::from_be_bytes([data[0], data[1], data[2], data[3]]));
            }
            (field::GPS_CORRELATION_TIMESTAMP, 12) => {
                out.gps_correlation_time = Some(gps_time(data));
            }
            (field::SCALED_PRESSURE, 4) => {
                out.pressure_mbar = Some(f32s::<1>(data)[0]);
            }
            (field::SHARED_GPS_TIMESTAMP, 12) => {
                out.shared_gps_time = Some(gps_time(data));
            }
            (field::SHARED_REFERENCE_TIMESTAMP, 8) => {
                out.reference_time_ns = Some(u64::from_be_bytes([
                    data[0], data[1], data[2], data[3], data[4], data[5], data[6], data[7],
                ]));
            }
            (
                field::SCALED_ACCEL
                | field::SCALED_GYRO
                | field::SCALED_MAG
                | field::DELTA_THETA
                | field::DELTA_VELOCITY
                | field::QUATERNION
                | field::EULER_ANGLES
                | field::INTERNAL_TIMESTAMP
                | field::GPS_CORRELATION_TIMESTAMP
                | field::SCALED_PRESSURE
                | field::SHARED_GPS_TIMESTAMP
                | field::SHARED_REFERENCE_TIMESTAMP,
                n,
            ) => return Err(format!("field {descriptor:#04x} has {n} data bytes")),
            _ => {
                out.skipped_fields = out.skipped_fields.saturating_add(1);
            }
        }
        rest = &rest[len..];
    }
    Ok(out)
}

/// Checks that a payload is a whole number of fields.
fn fields_add_up(payload: &[u8]) -> bool {
    let mut rest = payload;
    while let Some(&len) = rest.first() {
        let len = usize::from(len);
        if len < 2 || len > rest.len() {
            return false;
        }
        rest = &rest[len..];
    }
    true
}

fn packet_of(descriptor_set: u8, payload: &[u8]) -> Option<MipPacket> {
    if descriptor_set == IMU_DATA_SET {
        return match parse_imu_data(payload) {
            Ok(data) => Some(MipPacket::Imu(data)),
            Err(reason) => {
                tracing::debug!("mip: dropping malformed IMU data packet: {reason}");
                None
            }
        };
    }
    if !fields_add_up(payload) {
        return None;
    }
    if descriptor_set < 0x80
        && payload.len() >= 4
        && payload[0] == 4
        && payload[1] == ACK_NACK_FIELD
    {
        return Some(MipPacket::Reply {
            descriptor_set,
            command: payload[2],
            error_code: payload[3],
            more_fields: payload[4..].to_vec(),
        });
    }
    Some(MipPacket::Other {
        descriptor_set,
        payload: payload.to_vec(),
    })
}

fn scan(data: &[u8]) -> Scan<MipPacket> {
    if data.len() < 4 {
        // The second sync byte is checked as soon as it is there.
        if data.len() >= 2 && data[1] != SYNC2 {
            return Scan::Reject {
                len: 1,
                reject: Reject::NoSync,
            };
        }
        return Scan::Incomplete;
    }
    if data[1] != SYNC2 {
        return Scan::Reject {
            len: 1,
            reject: Reject::NoSync,
        };
    }
    let payload_len = usize::from(data[3]);
    let total = 4 + payload_len + 2;
    if data.len() < total {
        return Scan::Incomplete;
    }
    if fletcher16(&data[..total - 2]) != [data[total - 2], data[total - 1]] {
        return Scan::Reject {
            len: 1,
            reject: Reject::Checksum,
        };
    }
    match packet_of(data[2], &data[4..4 + payload_len]) {
        Some(frame) => Scan::Frame { len: total, frame },
        None => Scan::Reject {
            len: total,
            reject: Reject::BadContent,
        },
    }
}

/// Streaming MIP decoder.
///
/// Framing rule: look for `0x75 0x65`; a packet whose checksum fails costs its first sync
/// byte and the search goes on from the next byte, so a real packet inside a false one is
/// still found. A packet whose checksum is right but whose fields do not add up is dropped
/// whole, counted as malformed, without losing sync. Counting follows the one rule of
/// [`StreamBuffer`].
#[derive(Debug, Default, Clone)]
pub struct MipDecoder {
    buf: StreamBuffer,
}

impl MipDecoder {
    pub fn new() -> Self {
        Self::default()
    }
}

impl Decoder for MipDecoder {
    type Frame = MipPacket;

    fn push(&mut self, bytes: &[u8]) {
        self.buf.push(bytes);
    }

    fn poll(&mut self) -> Option<MipPacket> {
        self.buf.next_scanned(&[SYNC1], scan)
    }

    fn stats(&self) -> DecoderStats {
        self.buf.stats()
    }
}

/// MIP encoder: IMU data fields in ascending descriptor order.
#[derive(Debug, Default, Clone, Copy)]
pub struct MipEncoder;

fn put_field(descriptor: u8, data: &[u8], out: &mut Vec<u8>) {
    out.push(data.len() as u8 + 2);
    out.push(descriptor);
    out.extend_from_slice(data);
}

fn be_f32s(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_be_bytes()).collect()
}

fn gps_time_bytes(t: &MipGpsTime) -> Vec<u8> {
    let mut b = t.tow_s.to_be_bytes().to_vec();
    b.extend_from_slice(&t.week.to_be_bytes());
    b.extend_from_slice(&t.valid_flags.to_be_bytes());
    b
}

/// Appends the IMU data set payload of `data` to `out`.
pub fn write_imu_data(data: &MipImuData, out: &mut Vec<u8>) {
    let vectors = [
        (field::SCALED_ACCEL, data.scaled_accel_g),
        (field::SCALED_GYRO, data.scaled_gyro),
        (field::SCALED_MAG, data.scaled_mag),
        (field::DELTA_THETA, data.delta_theta),
        (field::DELTA_VELOCITY, data.delta_velocity_gs),
    ];
    for (descriptor, v) in vectors {
        if let Some(v) = v {
            put_field(descriptor, &be_f32s(&v), out);
        }
    }
    if let Some(q) = data.quaternion {
        put_field(field::QUATERNION, &be_f32s(&q), out);
    }
    if let Some(e) = data.euler_rad {
        put_field(field::EULER_ANGLES, &be_f32s(&e), out);
    }
    if let Some(t) = data.internal_timestamp {
        put_field(field::INTERNAL_TIMESTAMP, &t.to_be_bytes(), out);
    }
    if let Some(t) = &data.gps_correlation_time {
        put_field(field::GPS_CORRELATION_TIMESTAMP, &gps_time_bytes(t), out);
    }
    if let Some(p) = data.pressure_mbar {
        put_field(field::SCALED_PRESSURE, &p.to_be_bytes(), out);
    }
    if let Some(t) = &data.shared_gps_time {
        put_field(field::SHARED_GPS_TIMESTAMP, &gps_time_bytes(t), out);
    }
    if let Some(ns) = data.reference_time_ns {
        put_field(field::SHARED_REFERENCE_TIMESTAMP, &ns.to_be_bytes(), out);
    }
}

impl Encoder for MipEncoder {
    type Frame = MipPacket;

    fn encode(&self, frame: &MipPacket, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        let mut payload = Vec::with_capacity(64);
        let descriptor_set = match frame {
            MipPacket::Imu(data) => {
                if data.skipped_fields > 0 {
                    return Err(EncodeError::Invalid {
                        field: "skipped_fields",
                        reason: "fields not kept cannot be encoded",
                    });
                }
                write_imu_data(data, &mut payload);
                IMU_DATA_SET
            }
            MipPacket::Reply {
                descriptor_set,
                command,
                error_code,
                more_fields,
            } => {
                put_field(ACK_NACK_FIELD, &[*command, *error_code], &mut payload);
                payload.extend_from_slice(more_fields);
                *descriptor_set
            }
            MipPacket::Other {
                descriptor_set,
                payload: p,
            } => {
                payload.extend_from_slice(p);
                *descriptor_set
            }
        };
        if payload.len() > 255 {
            return Err(EncodeError::TooLong {
                len: payload.len(),
                max: 255,
            });
        }
        let start = out.len();
        out.extend_from_slice(&[SYNC1, SYNC2, descriptor_set, payload.len() as u8]);
        out.extend_from_slice(&payload);
        let ck = fletcher16(&out[start..]);
        out.extend_from_slice(&ck);
        Ok(())
    }
}

/// IMU data packets with accelerometer or gyro are readings; command replies are not.
/// The IMU samples of a MIP stream (what `imulogd` logs): [`MipDecoder`]'s IMU data packets
/// as SI samples, a delta taken over the device-time interval since the previous IMU data
/// packet when nothing was lost between the two (no checksum error, malformed or too long
/// frame, or skipped byte) and the interval is positive and at most
/// [`MAX_DELTA_INTERVAL_S`]. Replies and other packets are no samples.
#[derive(Debug, Default, Clone)]
pub struct MipSamples {
    packets: MipDecoder,
    rows_from: RowsFrom,
    /// Device time (s) of the previous IMU data packet and [`loss`] of the stream then.
    previous: Option<(f64, u64)>,
}

impl MipSamples {
    pub fn new(rows_from: RowsFrom) -> Self {
        MipSamples {
            rows_from,
            ..Self::default()
        }
    }
}

/// Evidence of lost bytes in a stream: every count of bytes or frames not accepted.
fn loss(stats: &DecoderStats) -> u64 {
    stats.checksum_errors + stats.frames_malformed + stats.frames_too_long + stats.bytes_skipped
}

impl Decoder for MipSamples {
    type Frame = ImuSample;

    fn push(&mut self, bytes: &[u8]) {
        self.packets.push(bytes);
    }

    fn poll(&mut self) -> Option<ImuSample> {
        loop {
            let MipPacket::Imu(data) = self.packets.poll()? else {
                continue;
            };
            let lost = loss(&self.packets.stats());
            let now = data.seconds();
            let interval = match (self.previous, now) {
                (Some((before, lost_before)), Some(now)) if lost_before == lost => {
                    Some(now - before).filter(|dt| *dt <= MAX_DELTA_INTERVAL_S)
                }
                _ => None,
            };
            self.previous = now.map(|t| (t, lost));
            if let Some(sample) = data.to_imu_sample(interval, self.rows_from) {
                return Some(sample);
            }
        }
    }

    fn stats(&self) -> DecoderStats {
        self.packets.stats()
    }
}

/// The IMU data packet a MicroStrain sensor sends for one sample: scaled accelerometer (g),
/// scaled gyro and the shared reference timestamp (the clock, ns). MIP carries no
/// temperature or status in this data set.
pub fn encode_sample(
    sample: &ImuSample,
    clock: &DeviceClock,
    out: &mut Vec<u8>,
) -> Result<(), EncodeError> {
    encode_output(sample, clock, ImuOutput::Rates, out)
}

/// The IMU data packet of a device set to output integrated motion: delta theta (rad) and
/// delta velocity (g·s) of the sample's rate and acceleration over `interval_s`, the output
/// period, and the reference timestamp of [`encode_sample`].
pub fn encode_delta_sample(
    sample: &ImuSample,
    clock: &DeviceClock,
    interval_s: f64,
    out: &mut Vec<u8>,
) -> Result<(), EncodeError> {
    let clock = DeviceClock {
        interval_s,
        ..*clock
    };
    encode_output(sample, &clock, ImuOutput::Deltas, out)
}

/// The IMU data packet of a device set to `output`: [`encode_sample`]'s fields, the deltas of
/// [`encode_delta_sample`] over the clock's `interval_s`, or both in one packet.
pub fn encode_output(
    sample: &ImuSample,
    clock: &DeviceClock,
    output: ImuOutput,
    out: &mut Vec<u8>,
) -> Result<(), EncodeError> {
    let rates = output != ImuOutput::Deltas;
    let deltas = output != ImuOutput::Rates;
    let interval_s = clock.interval_s;
    if deltas && !(interval_s.is_finite() && interval_s > 0.0) {
        return Err(EncodeError::Invalid {
            field: "interval_s",
            reason: "the output period must be positive",
        });
    }
    let data = MipImuData {
        scaled_accel_g: sample
            .accel
            .filter(|_| rates)
            .map(|v| v.map(|x| (x / STANDARD_GRAVITY) as f32)),
        scaled_gyro: sample.gyro.filter(|_| rates).map(|v| v.map(|x| x as f32)),
        delta_theta: sample
            .gyro
            .filter(|_| deltas)
            .map(|v| v.map(|x| (x * interval_s) as f32)),
        delta_velocity_gs: sample
            .accel
            .filter(|_| deltas)
            .map(|v| v.map(|x| (x / STANDARD_GRAVITY * interval_s) as f32)),
        reference_time_ns: Some((clock.time_s * 1e9).round().max(0.0) as u64),
        ..MipImuData::default()
    };
    MipEncoder.encode(&MipPacket::Imu(data), out)
}

/// Auto-detection score: checksummed MIP packets, at least [`DETECT_MIN_FRAMES`].
pub fn detect_score(sample: &[u8]) -> u32 {
    let frames = accepted_frames(MipDecoder::new(), sample);
    if frames < DETECT_MIN_FRAMES {
        0
    } else {
        frames
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encode_output_of_both_round_trips_through_either_rows_from() {
        let sample = |k: u32| ImuSample {
            sensor_time: None,
            gyro: Some([0.1 * f64::from(k), -0.2, 0.3]),
            accel: Some([0.5, -1.0, 9.8]),
            temp_c: None,
            status: 0,
        };
        let clock = |k: u32| DeviceClock {
            time_s: 100.0 + 0.01 * f64::from(k),
            interval_s: 0.01,
            ..DeviceClock::default()
        };
        let mut bytes = Vec::new();
        for k in 1..=3 {
            encode_output(&sample(k), &clock(k), ImuOutput::Both, &mut bytes).unwrap();
        }
        let mut packets = MipDecoder::new();
        let mut frames = Vec::new();
        packets.decode(&bytes, |f| frames.push(f));
        let MipPacket::Imu(first) = &frames[0] else {
            panic!("{frames:?}")
        };
        assert!(first.scaled_gyro.is_some() && first.delta_theta.is_some());
        assert!(first.scaled_accel_g.is_some() && first.delta_velocity_gs.is_some());
        let decode = |from: RowsFrom| {
            let mut d = MipSamples::new(from);
            let mut out = Vec::new();
            d.decode(&bytes, |s| out.push(s));
            out
        };
        let close = |got: [f64; 3], want: [f64; 3]| {
            got.iter()
                .zip(want)
                .all(|(g, w)| (g - w).abs() < 1e-5 * w.abs().max(1.0))
        };
        let (rates, deltas) = (decode(RowsFrom::Rates), decode(RowsFrom::Deltas));
        // Every packet carries its rates, so both give a row per packet: from the deltas
        // once an interval is known (the first packet has none before it).
        assert_eq!((rates.len(), deltas.len()), (3, 3));
        assert_eq!(deltas[0], rates[0]);
        for (k, (r, d)) in (1..=3).zip(rates.iter().zip(&deltas)) {
            for got in [r, d] {
                assert!(close(got.gyro.unwrap(), sample(k).gyro.unwrap()), "{got:?}");
                assert!(
                    close(got.accel.unwrap(), sample(k).accel.unwrap()),
                    "{got:?}"
                );
            }
        }
        assert_ne!(rates[1].accel, deltas[1].accel);
        // Deltas alone over the clock's interval are encode_delta_sample's packet.
        let (mut only, mut by_interval) = (Vec::new(), Vec::new());
        encode_output(&sample(2), &clock(2), ImuOutput::Deltas, &mut only).unwrap();
        encode_delta_sample(&sample(2), &clock(2), 0.01, &mut by_interval).unwrap();
        assert_eq!(only, by_interval);
        let unknown = DeviceClock {
            interval_s: f64::NAN,
            ..clock(1)
        };
        assert!(encode_output(&sample(1), &unknown, ImuOutput::Both, &mut Vec::new()).is_err());
    }

    #[test]
    fn delta_packets_give_rates_over_the_device_time_interval() {
        let sample = |k: u32| ImuSample {
            sensor_time: None,
            gyro: Some([0.1 * f64::from(k), -0.2, 0.3]),
            accel: Some([0.5, -1.0, 9.8]),
            temp_c: None,
            status: 0,
        };
        let clock = |k: u32| DeviceClock {
            time_s: 100.0 + 0.01 * f64::from(k),
            ..DeviceClock::default()
        };
        let mut bytes = Vec::new();
        for k in 1..=3 {
            encode_delta_sample(&sample(k), &clock(k), 0.01, &mut bytes).unwrap();
        }
        // The wire carries deltas only.
        let mut packets = MipDecoder::new();
        let mut frames = Vec::new();
        packets.decode(&bytes, |f| frames.push(f));
        let MipPacket::Imu(first) = &frames[0] else {
            panic!("{frames:?}")
        };
        assert_eq!((first.scaled_gyro, first.scaled_accel_g), (None, None));
        assert_eq!(frames[0].to_imu_sample(), None);
        // The first packet has no interval before it; the next two have 10 ms each.
        let mut samples = MipSamples::new(RowsFrom::Rates);
        let mut decoded = Vec::new();
        samples.decode(&bytes, |s| decoded.push(s));
        assert_eq!(decoded.len(), 2, "{decoded:?}");
        for (k, got) in (2..=3).zip(&decoded) {
            let want = sample(k);
            for (g, w) in got.gyro.unwrap().iter().zip(want.gyro.unwrap()) {
                assert!((g - w).abs() < 1e-5 * w.abs().max(1.0), "{g} vs {w}");
            }
            for (a, w) in got.accel.unwrap().iter().zip(want.accel.unwrap()) {
                assert!((a - w).abs() < 1e-5 * w.abs().max(1.0), "{a} vs {w}");
            }
            assert!((got.sensor_time.unwrap() - clock(k).time_s).abs() < 1e-9);
        }
        // A damaged packet between two: no interval across it.
        let mut damaged = bytes.clone();
        let second = bytes.len() / 3;
        damaged[second + 8] ^= 0xFF;
        let mut samples = MipSamples::new(RowsFrom::Rates);
        let mut decoded = Vec::new();
        samples.decode(&damaged, |s| decoded.push(s));
        assert_eq!(decoded.len(), 0, "{decoded:?}");
        assert_eq!(samples.stats().checksum_errors, 1);
        assert!(encode_delta_sample(&sample(1), &clock(1), 0.0, &mut Vec::new()).is_err());
        // A packet with both: the scaled values, or the deltas when they are asked for.
        let both = MipImuData {
            scaled_gyro: Some([1.0, 2.0, 3.0]),
            delta_theta: Some([0.01, 0.02, 0.04]),
            ..MipImuData::default()
        };
        let rates = both.to_imu_sample(Some(0.01), RowsFrom::Rates).unwrap();
        assert_eq!(rates.gyro, Some([1.0, 2.0, 3.0]));
        let deltas = both.to_imu_sample(Some(0.01), RowsFrom::Deltas).unwrap();
        let gyro = deltas.gyro.unwrap();
        assert!((gyro[2] - 4.0).abs() < 1e-6, "{gyro:?}");
        // Without an interval the deltas give nothing and the scaled values stand.
        let fallback = both.to_imu_sample(None, RowsFrom::Deltas).unwrap();
        assert_eq!(fallback.gyro, Some([1.0, 2.0, 3.0]));
    }

    #[test]
    fn manual_example_checksum() {
        // "Get Device Status" command of the 3DM-GX5 DCP manual: 7565 0C05 0564 186D 01DA 83.
        let packet = [
            0x75, 0x65, 0x0C, 0x05, 0x05, 0x64, 0x18, 0x6D, 0x01, 0xDA, 0x83,
        ];
        assert_eq!(fletcher16(&packet[..9]), [0xDA, 0x83]);
        let mut d = MipDecoder::new();
        let mut frames = Vec::new();
        d.decode(&packet, |f| frames.push(f));
        assert_eq!(
            frames,
            vec![MipPacket::Other {
                descriptor_set: 0x0C,
                payload: packet[4..9].to_vec()
            }]
        );
    }

    #[test]
    fn ack_reply_is_a_reply_not_a_sample() {
        let mut bytes = Vec::new();
        let reply = MipPacket::Reply {
            descriptor_set: 0x0C,
            command: 0x64,
            error_code: 0,
            more_fields: Vec::new(),
        };
        MipEncoder.encode(&reply, &mut bytes).unwrap();
        assert_eq!(&bytes[..6], &[0x75, 0x65, 0x0C, 0x04, 0x04, 0xF1]);
        let mut d = MipDecoder::new();
        let mut frames = Vec::new();
        d.decode(&bytes, |f| frames.push(f));
        assert_eq!(frames, vec![reply]);
        assert_eq!(frames[0].to_imu_sample(), None);
    }

    #[test]
    fn fields_that_do_not_add_up_are_malformed_without_losing_sync() {
        let mut good = Vec::new();
        let data = MipImuData {
            scaled_gyro: Some([0.1, 0.2, 0.3]),
            ..Default::default()
        };
        MipEncoder.encode(&MipPacket::Imu(data), &mut good).unwrap();
        // Accel field claiming 16 bytes in a 14-byte payload, checksum right.
        let mut bad = vec![0x75, 0x65, 0x80, 0x0E, 0x10, 0x04];
        bad.extend_from_slice(&[0; 12]);
        let ck = fletcher16(&bad);
        bad.extend_from_slice(&ck);
        let stream = [&good[..], &bad, &good].concat();
        let mut d = MipDecoder::new();
        let mut n = 0;
        d.decode(&stream, |_| n += 1);
        let s = d.stats();
        assert_eq!((n, s.frames_malformed, s.resyncs), (2, 1, 0), "{s:?}");
        assert_eq!(s.bytes_skipped, bad.len() as u64);
    }
}
