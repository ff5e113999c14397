//! WitMotion standard serial protocol (WT901, HWT905, JY901 family): 11-byte packets
//! `0x55, type, 8 data bytes, sum`, where `sum` is the low byte of the sum of the ten bytes
//! before it. Data words are int16 little-endian. Scales (datasheet): acceleration ±16 g,
//! angular rate ±2000 °/s, angle ±180° over ±32768, temperature in 1/100 °C.
//!
//! The device sends acceleration, angular rate and angle as separate packets;
//! [`WitAssembler`] groups the packets of one output cycle into an [`ImuSample`]. After one
//! whole cycle it knows which packet type closes a cycle and emits each sample on that
//! closing packet (not when the next cycle starts); a cycle missing a packet is dropped and
//! the cycle learned again (see [`WitAssembler`]).
//!
//! Converted values use standard gravity 9.80665 m/s² for "g" (the datasheet writes 9.8);
//! the raw int16 words stay in the [`WitPacket`] so nothing is lost.

use super::cycle::{Action, CycleGrouper};
use super::reading::DeviceClock;
use super::{accepted_frames, Decoder, EncodeError, Encoder, Reject, StreamBuffer};
use crate::types::{DecoderStats, ImuSample};

/// Packet header byte.
pub const HEADER: u8 = 0x55;
/// Length of every packet on the wire.
pub const PACKET_LEN: usize = 11;
/// Standard gravity used to convert g to m/s².
pub const STANDARD_GRAVITY: f64 = 9.806_65;
/// Full-scale acceleration, g, for ±32768 counts.
pub const ACCEL_FULL_SCALE_G: f64 = 16.0;
/// Full-scale angular rate, °/s, for ±32768 counts.
pub const GYRO_FULL_SCALE_DPS: f64 = 2000.0;
/// Full-scale angle, °, for ±32768 counts.
pub const ANGLE_FULL_SCALE_DEG: f64 = 180.0;

/// Packet type bytes.
pub mod kind {
    pub const TIME: u8 = 0x50;
    pub const ACCEL: u8 = 0x51;
    pub const GYRO: u8 = 0x52;
    pub const ANGLE: u8 = 0x53;
}

/// One WitMotion packet, raw words kept. Types other than time/accel/gyro/angle (magnetic
/// field, pressure, quaternion, ...) are kept as [`WitPacket::Other`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum WitPacket {
    /// 0x50: on-chip clock. `year` is years after 2000.
    Time {
        year: u8,
        month: u8,
        day: u8,
        hour: u8,
        minute: u8,
        second: u8,
        millisecond: u16,
    },
    /// 0x51: acceleration counts and temperature counts (1/100 °C).
    Accel { raw: [i16; 3], temp_raw: i16 },
    /// 0x52: angular rate counts and temperature counts (1/100 °C).
    Gyro { raw: [i16; 3], temp_raw: i16 },
    /// 0x53: roll, pitch, yaw counts and the firmware version word.
    Angle { raw: [i16; 3], version: u16 },
    /// Any other type byte in 0x50..=0x5F with its 8 data bytes.
    Other { kind: u8, data: [u8; 8] },
}

impl WitPacket {
    /// The type byte on the wire.
    pub fn kind(&self) -> u8 {
        match self {
            WitPacket::Time { .. } => kind::TIME,
            WitPacket::Accel { .. } => kind::ACCEL,
            WitPacket::Gyro { .. } => kind::GYRO,
            WitPacket::Angle { .. } => kind::ANGLE,
            WitPacket::Other { kind, .. } => *kind,
        }
    }

    /// Acceleration in m/s² (accel packets only).
    pub fn accel_mps2(&self) -> Option<[f64; 3]> {
        match self {
            WitPacket::Accel { raw, .. } => {
                Some(raw.map(|c| f64::from(c) / 32768.0 * ACCEL_FULL_SCALE_G * STANDARD_GRAVITY))
            }
            _ => None,
        }
    }

    /// Angular rate in rad/s (gyro packets only).
    pub fn gyro_radps(&self) -> Option<[f64; 3]> {
        match self {
            WitPacket::Gyro { raw, .. } => {
                Some(raw.map(|c| (f64::from(c) / 32768.0 * GYRO_FULL_SCALE_DPS).to_radians()))
            }
            _ => None,
        }
    }

    /// Roll, pitch, yaw in degrees (angle packets only).
    pub fn angle_deg(&self) -> Option<[f64; 3]> {
        match self {
            WitPacket::Angle { raw, .. } => {
                Some(raw.map(|c| f64::from(c) / 32768.0 * ANGLE_FULL_SCALE_DEG))
            }
            _ => None,
        }
    }

    /// Temperature in °C (accel and gyro packets).
    pub fn temp_c(&self) -> Option<f64> {
        match self {
            WitPacket::Accel { temp_raw, .. } | WitPacket::Gyro { temp_raw, .. } => {
                Some(f64::from(*temp_raw) / 100.0)
            }
            _ => None,
        }
    }

    /// Seconds since midnight of the on-chip clock (time packets only).
    pub fn time_of_day_s(&self) -> Option<f64> {
        match self {
            WitPacket::Time {
                hour,
                minute,
                second,
                millisecond,
                ..
            } => Some(
                f64::from(*hour) * 3600.0
                    + f64::from(*minute) * 60.0
                    + f64::from(*second)
                    + f64::from(*millisecond) / 1000.0,
            ),
            _ => None,
        }
    }

    /// An accel packet from m/s² and °C, rounded to the nearest count.
    pub fn accel_from_si(accel_mps2: [f64; 3], temp_c: f64) -> Result<Self, EncodeError> {
        let scale = 32768.0 / (ACCEL_FULL_SCALE_G * STANDARD_GRAVITY);
        Ok(WitPacket::Accel {
            raw: counts3("witmotion accel", accel_mps2, scale)?,
            temp_raw: counts("witmotion temperature", temp_c, 100.0)?,
        })
    }

    /// A gyro packet from rad/s and °C, rounded to the nearest count.
    pub fn gyro_from_si(gyro_radps: [f64; 3], temp_c: f64) -> Result<Self, EncodeError> {
        let scale = 32768.0 / GYRO_FULL_SCALE_DPS.to_radians();
        Ok(WitPacket::Gyro {
            raw: counts3("witmotion gyro", gyro_radps, scale)?,
            temp_raw: counts("witmotion temperature", temp_c, 100.0)?,
        })
    }

    fn data_bytes(&self) -> [u8; 8] {
        fn words(w: [i16; 4]) -> [u8; 8] {
            let mut out = [0u8; 8];
            for (chunk, word) in out.chunks_exact_mut(2).zip(w) {
                chunk.copy_from_slice(&word.to_le_bytes());
            }
            out
        }
        match *self {
            WitPacket::Time {
                year,
                month,
                day,
                hour,
                minute,
                second,
                millisecond,
            } => {
                let ms = millisecond.to_le_bytes();
                [year, month, day, hour, minute, second, ms[0], ms[1]]
            }
            WitPacket::Accel { raw, temp_raw } | WitPacket::Gyro { raw, temp_raw } => {
                words([raw[0], raw[1], raw[2], temp_raw])
            }
            WitPacket::Angle { raw, version } => words([raw[0], raw[1], raw[2], version as i16]),
            WitPacket::Other { data, .. } => data,
        }
    }

    fn from_wire(kind_byte: u8, d: &[u8; 8]) -> Self {
        let w = |i: usize| i16::from_le_bytes([d[2 * i], d[2 * i + 1]]);
        match kind_byte {
            kind::TIME => WitPacket::Time {
                year: d[0],
                month: d[1],
                day: d[2],
                hour: d[3],
                minute: d[4],
                second: d[5],
                millisecond: u16::from_le_bytes([d[6], d[7]]),
            },
            kind::ACCEL => WitPacket::Accel {
                raw: [w(0), w(1), w(2)],
                temp_raw: w(3),
            },
            kind::GYRO => WitPacket::Gyro {
                raw: [w(0), w(1), w(2)],
                temp_raw: w(3),
            },
            kind::ANGLE => WitPacket::Angle {
                raw: [w(0), w(1), w(2)],
                version: u16::from_le_bytes([d[6], d[7]]),
            },
            other => WitPacket::Other {
                kind: other,
                data: *d,
            },
        }
    }
}

fn counts(field: &'static str, value: f64, scale: f64) -> Result<i16, EncodeError> {
    let c = (value * scale).round();
    if !c.is_finite() || c < f64::from(i16::MIN) || c > f64::from(i16::MAX) {
        return Err(EncodeError::OutOfRange { field, value });
    }
    Ok(c as i16)
}

fn counts3(field: &'static str, v: [f64; 3], scale: f64) -> Result<[i16; 3], EncodeError> {
    Ok([
        counts(field, v[0], scale)?,
        counts(field, v[1], scale)?,
        counts(field, v[2], scale)?,
    ])
}

fn is_packet_kind(b: u8) -> bool {
    (0x50..=0x5F).contains(&b)
}

fn checksum(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0u8, |s, &b| s.wrapping_add(b))
}

/// Streaming decoder for WitMotion packets.
///
/// Framing rule: look for `0x55` followed by a type byte in 0x50..=0x5F; if the checksum
/// fails, count it, drop only the `0x55` and search again from the next byte, so a real
/// packet that starts inside a corrupt one is still found. Counting follows the one rule of
/// [`StreamBuffer`].
#[derive(Debug, Default, Clone)]
pub struct WitDecoder {
    buf: StreamBuffer,
}

impl WitDecoder {
    pub fn new() -> Self {
        Self::default()
    }
}

impl Decoder for WitDecoder {
    type Frame = WitPacket;

    fn push(&mut self, bytes: &[u8]) {
        self.buf.push(bytes);
    }

    fn poll(&mut self) -> Option<WitPacket> {
        loop {
            if !self.buf.skip_to_start(&[HEADER]) {
                return None;
            }
            let data = self.buf.data();
            if data.len() < 2 {
                return None;
            }
            if !is_packet_kind(data[1]) {
                self.buf.reject(1, Reject::NoSync);
                continue;
            }
            if data.len() < PACKET_LEN {
                return None;
            }
            let frame = &data[..PACKET_LEN];
            if checksum(&frame[..PACKET_LEN - 1]) != frame[PACKET_LEN - 1] {
                self.buf.reject(1, Reject::Checksum);
                continue;
            }
            let mut payload = [0u8; 8];
            payload.copy_from_slice(&frame[2..10]);
            let packet = WitPacket::from_wire(frame[1], &payload);
            self.buf.accept(PACKET_LEN);
            return Some(packet);
        }
    }

    fn stats(&self) -> DecoderStats {
        self.buf.stats()
    }
}

/// Encoder for WitMotion packets.
#[derive(Debug, Default, Clone, Copy)]
pub struct WitEncoder;

impl Encoder for WitEncoder {
    type Frame = WitPacket;

    fn encode(&self, frame: &WitPacket, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        let kind_byte = frame.kind();
        if !is_packet_kind(kind_byte) {
            return Err(EncodeError::Invalid {
                field: "kind",
                reason: "WitMotion type byte must be in 0x50..=0x5F",
            });
        }
        let start = out.len();
        out.push(HEADER);
        out.push(kind_byte);
        out.extend_from_slice(&frame.data_bytes());
        let sum = checksum(&out[start..]);
        out.push(sum);
        Ok(())
    }
}

/// Groups one output cycle's packets into an [`ImuSample`].
///
/// Rule ([`super::cycle`]): while learning, a cycle ends when a packet type arrives that the
/// current group already holds (emitted one packet late); once one whole cycle has been seen
/// (the group's first type repeated), the type before that repeat is the *closing* type and
/// each later sample is emitted on its closing packet, so it is stamped on arrival of its
/// last byte. A group that misses a type of the learned cycle (a packet lost, the device
/// reconfigured) is dropped, never emitted as whole, and the cycle is learned again. This
/// works whatever outputs are enabled and in whatever order. [`WitAssembler::finish`]
/// flushes a group held at the end of input while still learning.
///
/// `sensor_time` is the time-of-day of a 0x50 packet in the cycle (seconds), if enabled.
/// Temperature comes from the gyro packet, else the accel packet. Angles are not part of
/// `ImuSample`; read them from the packets.
#[derive(Debug, Default, Clone)]
pub struct WitAssembler {
    current: ImuSample,
    cycle: CycleGrouper,
    dropped: u64,
}

/// The samples one packet completes: at most two (while learning a one-type cycle, the
/// packet that closes the learning group also closes its own).
pub type Completed = [Option<ImuSample>; 2];

impl WitAssembler {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a packet; returns the samples it completes, in order.
    pub fn push(&mut self, packet: &WitPacket) -> Completed {
        let step = self.cycle.push(u32::from(packet.kind() & 0x0F));
        let first = self.settle(step.before);
        match packet {
            WitPacket::Time { .. } => self.current.sensor_time = packet.time_of_day_s(),
            WitPacket::Accel { .. } => {
                self.current.accel = packet.accel_mps2();
                if self.current.temp_c.is_none() {
                    self.current.temp_c = packet.temp_c();
                }
            }
            WitPacket::Gyro { .. } => {
                self.current.gyro = packet.gyro_radps();
                self.current.temp_c = packet.temp_c();
            }
            WitPacket::Angle { .. } | WitPacket::Other { .. } => {}
        }
        let second = self.settle(step.after);
        match first {
            Some(_) => [first, second],
            None => [second, None],
        }
    }

    fn settle(&mut self, action: Action) -> Option<ImuSample> {
        match action {
            Action::Keep => None,
            Action::Emit => take_if_imu(&mut self.current),
            Action::Drop => {
                self.current = ImuSample::default();
                self.dropped += 1;
                None
            }
        }
    }

    /// Groups dropped because they lacked a packet of the learned cycle.
    pub fn dropped_groups(&self) -> u64 {
        self.dropped
    }

    /// Ends the input: emits the held group if it may be whole and holds IMU data (see the
    /// type's rule: with a learned cycle a held group lacks its closing packet).
    pub fn finish(&mut self) -> Option<ImuSample> {
        if self.cycle.finish() {
            take_if_imu(&mut self.current)
        } else {
            self.current = ImuSample::default();
            None
        }
    }
}

fn take_if_imu(current: &mut ImuSample) -> Option<ImuSample> {
    let sample = std::mem::take(current);
    (sample.gyro.is_some() || sample.accel.is_some()).then_some(sample)
}

/// WitMotion bytes to [`ImuSample`]s: [`WitDecoder`] plus [`WitAssembler`]. This is what
/// `imulab decode --protocol wit` and the daemon use; the packets themselves (raw counts,
/// angles) come from [`WitDecoder`].
#[derive(Debug, Default, Clone)]
pub struct WitImuDecoder {
    packets: WitDecoder,
    assembler: WitAssembler,
    /// The second sample of a packet that completed two.
    pending: Option<ImuSample>,
}

impl WitImuDecoder {
    pub fn new() -> Self {
        Self::default()
    }
}

impl Decoder for WitImuDecoder {
    type Frame = ImuSample;

    fn push(&mut self, bytes: &[u8]) {
        self.packets.push(bytes);
    }

    fn poll(&mut self) -> Option<ImuSample> {
        if let Some(sample) = self.pending.take() {
            return Some(sample);
        }
        while let Some(packet) = self.packets.poll() {
            let [first, second] = self.assembler.push(&packet);
            if let Some(sample) = first {
                self.pending = second;
                return Some(sample);
            }
        }
        None
    }

    /// The packet decoder's counters, plus the groups dropped for a missing packet of the
    /// learned cycle in `frames_malformed`.
    fn stats(&self) -> DecoderStats {
        let mut stats = self.packets.stats();
        stats.frames_malformed += self.assembler.dropped_groups();
        stats
    }

    fn finish(&mut self) -> Option<ImuSample> {
        self.pending.take().or_else(|| self.assembler.finish())
    }
}

/// The packets a WitMotion IMU sends for one sample: TIME (the wall-clock time of
/// `clock`, ms resolution), then ACCEL and GYRO for the triads the sample has. Both data
/// packets carry the temperature, so a sample without one cannot be sent.
pub fn encode_sample(
    sample: &ImuSample,
    clock: &DeviceClock,
    out: &mut Vec<u8>,
) -> Result<(), EncodeError> {
    let temp = sample.temp_c.unwrap_or(f64::NAN);
    WitEncoder.encode(&time_packet(clock.wall_ns)?, out)?;
    if let Some(a) = sample.accel {
        WitEncoder.encode(&WitPacket::accel_from_si(a, temp)?, out)?;
    }
    if let Some(g) = sample.gyro {
        WitEncoder.encode(&WitPacket::gyro_from_si(g, temp)?, out)?;
    }
    Ok(())
}

/// The TIME packet of a wall-clock time (ns since the Unix epoch; years 2000 to 2255).
fn time_packet(wall_ns: i64) -> Result<WitPacket, EncodeError> {
    use chrono::{Datelike, Timelike};
    let t = chrono::DateTime::from_timestamp_nanos(wall_ns);
    let year = t.year() - 2000;
    if !(0..=255).contains(&year) {
        return Err(EncodeError::OutOfRange {
            field: "witmotion year",
            value: f64::from(t.year()),
        });
    }
    Ok(WitPacket::Time {
        year: year as u8,
        month: t.month() as u8,
        day: t.day() as u8,
        hour: t.hour() as u8,
        minute: t.minute() as u8,
        second: t.second() as u8,
        millisecond: (t.nanosecond() / 1_000_000).min(999) as u16,
    })
}

/// Auto-detection score: packets with a valid checksum in `sample`.
pub fn detect_score(sample: &[u8]) -> u32 {
    accepted_frames(WitDecoder::new(), sample)
}
