//! Xsens Xbus framing and MTData2 payloads (MTi 1/10/100/600 series).
//!
//! Frame: `0xFA` preamble, bus id (0xFF for the device's own port), message id (MID),
//! length (one byte; `0xFF` means a 2-byte big-endian extended length follows), payload,
//! checksum chosen so the sum of all bytes after the preamble is 0 mod 256.
//!
//! MTData2 (MID 0x36) payload: items of `data id (u16 BE), size (u8), data`. The low two
//! bits of a float data id select the precision: 0 float32, 1 fixed 12.20 (4 bytes),
//! 2 fixed 16.32 (6 bytes: 4-byte fraction then 2-byte integer part), 3 float64; bits 2–3
//! the coordinate frame. Values are big-endian and already SI (m/s², rad/s, m/s, °C).
//! The data id is kept with each value, so the wire form is recoverable exactly.

use super::reading::{DeviceClock, Reading, ToReading};
use super::{accepted_frames, Decoder, EncodeError, Encoder, Reject, StreamBuffer};
use crate::types::{DecoderStats, ImuSample};

/// Frame preamble.
pub const PREAMBLE: u8 = 0xFA;
/// Bus id of the device's own port ("master").
pub const BUS_ID_MASTER: u8 = 0xFF;
/// MID of an MTData2 message.
pub const MID_MTDATA2: u8 = 0x36;
/// Largest payload we accept; the Xbus extended length allows up to this much.
pub const MAX_PAYLOAD: usize = 2048;
/// SampleTimeFine counts per second.
pub const SAMPLE_TIME_FINE_HZ: f64 = 10_000.0;

/// MTData2 data identifiers (type part, precision/frame bits zero).
pub mod data_id {
    pub const TEMPERATURE: u16 = 0x0810;
    pub const PACKET_COUNTER: u16 = 0x1020;
    pub const SAMPLE_TIME_FINE: u16 = 0x1060;
    pub const DELTA_V: u16 = 0x4010;
    pub const ACCELERATION: u16 = 0x4020;
    pub const RATE_OF_TURN: u16 = 0x8020;
    pub const DELTA_Q: u16 = 0x8030;
    pub const STATUS_WORD: u16 = 0xE020;
    /// Precision bits: float32.
    pub const FLOAT32: u16 = 0x0;
    /// Precision bits: fixed point 12.20.
    pub const FP1220: u16 = 0x1;
    /// Precision bits: fixed point 16.32.
    pub const FP1632: u16 = 0x2;
    /// Precision bits: float64.
    pub const FLOAT64: u16 = 0x3;
}

/// A value with the full data id it came with (type, coordinate frame and precision bits).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct XbusValue<V> {
    pub data_id: u16,
    pub value: V,
}

/// The inertial content of one MTData2 message. Items this decoder does not interpret are
/// counted in `skipped_items`.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct MtData2 {
    pub packet_counter: Option<u16>,
    /// Sample time in 1/10000 s ticks.
    pub sample_time_fine: Option<u32>,
    /// Temperature, °C.
    pub temperature: Option<XbusValue<f64>>,
    /// Calibrated acceleration, m/s².
    pub acceleration: Option<XbusValue<[f64; 3]>>,
    /// Velocity increment over the output interval, m/s.
    pub delta_v: Option<XbusValue<[f64; 3]>>,
    /// Calibrated rate of turn, rad/s.
    pub rate_of_turn: Option<XbusValue<[f64; 3]>>,
    /// Orientation increment quaternion (q0, q1, q2, q3).
    pub delta_q: Option<XbusValue<[f64; 4]>>,
    pub status_word: Option<u32>,
    pub skipped_items: u16,
}

impl MtData2 {
    /// The SI sample: time from SampleTimeFine (s), gyro, accel, temperature, status word.
    pub fn to_imu_sample(&self) -> ImuSample {
        ImuSample {
            sensor_time: self
                .sample_time_fine
                .map(|t| f64::from(t) / SAMPLE_TIME_FINE_HZ),
            gyro: self.rate_of_turn.map(|v| v.value),
            accel: self.acceleration.map(|v| v.value),
            temp_c: self.temperature.map(|v| v.value),
            status: self.status_word.unwrap_or(0),
        }
    }
}

/// One Xbus message.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum XbusMessage {
    MtData2 {
        bus_id: u8,
        data: MtData2,
    },
    /// Any other MID, payload kept as is.
    Other {
        bus_id: u8,
        mid: u8,
        payload: Vec<u8>,
    },
}

fn element_size(id: u16) -> usize {
    match id & 0x3 {
        data_id::FLOAT32 | data_id::FP1220 => 4,
        data_id::FP1632 => 6,
        _ => 8,
    }
}

fn read_real(id: u16, b: &[u8]) -> f64 {
    match id & 0x3 {
        data_id::FLOAT32 => f64::from(f32::from_be_bytes([b[0], b[1], b[2], b[3]])),
        data_id::FP1220 => f64::from(i32::from_be_bytes([b[0], b[1], b[2], b[3]])) / 1048576.0,
        data_id::FP1632 => {
            let frac = u32::from_be_bytes([b[0], b[1], b[2], b[3]]);
            let int = i16::from_be_bytes([b[4], b[5]]);
            let fixed = (i64::from(int) << 32) | i64::from(frac);
            fixed as f64 / 4294967296.0
        }
        _ => f64::from_be_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]),
    }
}

fn write_real(field: &'static str, id: u16, v: f64, out: &mut Vec<u8>) -> Result<(), EncodeError> {
    let bad = |_reason: &str| EncodeError::OutOfRange { field, value: v };
    match id & 0x3 {
        data_id::FLOAT32 => out.extend_from_slice(&(v as f32).to_be_bytes()),
        data_id::FP1220 => {
            let c = (v * 1048576.0).round();
            if !(c >= f64::from(i32::MIN) && c <= f64::from(i32::MAX)) {
                return Err(bad("outside fixed point 12.20 range"));
            }
            out.extend_from_slice(&(c as i32).to_be_bytes());
        }
        data_id::FP1632 => {
            let c = (v * 4294967296.0).round();
            if !(c >= -(2f64.powi(47)) && c < 2f64.powi(47)) {
                return Err(bad("outside fixed point 16.32 range"));
            }
            let fixed = c as i64;
            out.extend_from_slice(&(fixed as u32).to_be_bytes());
            out.extend_from_slice(&((fixed >> 32) as i16).to_be_bytes());
        }
        _ => out.extend_from_slice(&v.to_be_bytes()),
    }
    Ok(())
}

fn read_reals<const N: usize>(id: u16, data: &[u8]) -> Option<XbusValue<[f64; N]>> {
    let size = element_size(id);
    if data.len() != N * size {
        return None;
    }
    let mut value = [0.0; N];
    for (v, chunk) in value.iter_mut().zip(data.chunks_exact(size)) {
        *v = read_real(id, chunk);
    }
    Some(XbusValue { data_id: id, value })
}

/// Parses an MTData2 payload. Returns a description of the first structural error.
pub fn parse_mtdata2(payload: &[u8]) -> Result<MtData2, String> {
    let mut out = MtData2::default();
    let mut rest = payload;
    let mut offset = 0usize;
    while !rest.is_empty() {
        if rest.len() < 3 {
            return Err(format!(
                "MTData2 item header truncated at payload offset {offset}"
            ));
        }
        let id = u16::from_be_bytes([rest[0], rest[1]]);
        let size = usize::from(rest[2]);
        if rest.len() < 3 + size {
            return Err(format!(
                "MTData2 item {id:#06x} at offset {offset} declares {size} bytes, {} left",
                rest.len() - 3
            ));
        }
        let data = &rest[3..3 + size];
        let known = match id & 0xFFF0 {
            data_id::PACKET_COUNTER if size == 2 => {
                out.packet_counter = Some(u16::from_be_bytes([data[0], data[1]]));
                true
            }
            data_id::SAMPLE_TIME_FINE if size == 4 => {
                out.sample_time_fine =
                    Some(u32::from_be_bytes([data[0], data[1], data[2], data[3]]));
                true
            }
            data_id::STATUS_WORD if size == 4 => {
                out.status_word = Some(u32::from_be_bytes([data[0], data[1], data[2], data[3]]));
                true
            }
            data_id::TEMPERATURE => read_reals::<1>(id, data)
                .map(|v| {
                    out.temperature = Some(XbusValue {
                        data_id: v.data_id,
                        value: v.value[0],
                    })
                })
                .is_some(),
            data_id::ACCELERATION => read_reals(id, data)
                .map(|v| out.acceleration = Some(v))
                .is_some(),
            data_id::DELTA_V => read_reals(id, data)
                .map(|v| out.delta_v = Some(v))
                .is_some(),
            data_id::RATE_OF_TURN => read_reals(id, data)
                .map(|v| out.rate_of_turn = Some(v))
                .is_some(),
            data_id::DELTA_Q => read_reals(id, data)
                .map(|v| out.delta_q = Some(v))
                .is_some(),
            _ => false,
        };
        if !known {
            out.skipped_items = out.skipped_items.saturating_add(1);
        }
        rest = &rest[3 + size..];
        offset += 3 + size;
    }
    Ok(out)
}

fn write_item_header(id: u16, size: usize, out: &mut Vec<u8>) {
    out.extend_from_slice(&id.to_be_bytes());
    out.push(size as u8);
}

fn write_reals(
    field: &'static str,
    id: u16,
    values: &[f64],
    out: &mut Vec<u8>,
) -> Result<(), EncodeError> {
    write_item_header(id, values.len() * element_size(id), out);
    values
        .iter()
        .try_for_each(|&v| write_real(field, id, v, out))
}

fn check_type(field: &'static str, id: u16, expected: u16) -> Result<(), EncodeError> {
    if id & 0xFFF0 != expected {
        return Err(EncodeError::Invalid {
            field,
            reason: "data id does not match the field's MTData2 type",
        });
    }
    Ok(())
}

/// Appends the MTData2 payload of `data` (items in a fixed order) to `out`.
pub fn write_mtdata2(data: &MtData2, out: &mut Vec<u8>) -> Result<(), EncodeError> {
    if let Some(c) = data.packet_counter {
        write_item_header(data_id::PACKET_COUNTER, 2, out);
        out.extend_from_slice(&c.to_be_bytes());
    }
    if let Some(t) = data.sample_time_fine {
        write_item_header(data_id::SAMPLE_TIME_FINE, 4, out);
        out.extend_from_slice(&t.to_be_bytes());
    }
    if let Some(v) = data.temperature {
        check_type("temperature", v.data_id, data_id::TEMPERATURE)?;
        write_reals("temperature", v.data_id, &[v.value], out)?;
    }
    if let Some(v) = data.acceleration {
        check_type("acceleration", v.data_id, data_id::ACCELERATION)?;
        write_reals("acceleration", v.data_id, &v.value, out)?;
    }
    if let Some(v) = data.delta_v {
        check_type("delta_v", v.data_id, data_id::DELTA_V)?;
        write_reals("delta_v", v.data_id, &v.value, out)?;
    }
    if let Some(v) = data.rate_of_turn {
        check_type("rate_of_turn", v.data_id, data_id::RATE_OF_TURN)?;
        write_reals("rate_of_turn", v.data_id, &v.value, out)?;
    }
    if let Some(v) = data.delta_q {
        check_type("delta_q", v.data_id, data_id::DELTA_Q)?;
        write_reals("delta_q", v.data_id, &v.value, out)?;
    }
    if let Some(s) = data.status_word {
        write_item_header(data_id::STATUS_WORD, 4, out);
        out.extend_from_slice(&s.to_be_bytes());
    }
    Ok(())
}

/// Streaming Xbus decoder.
///
/// Framing rule: look for `0xFA`; if the declared length exceeds [`MAX_PAYLOAD`] or the
/// checksum fails, count it, drop only the preamble byte and search again, so a real frame
/// inside a false one is still found. A frame whose checksum is right but whose MTData2
/// items do not add up is dropped whole and counted as malformed, without losing sync.
/// Counting follows the one rule of [`StreamBuffer`].
#[derive(Debug, Default, Clone)]
pub struct XbusDecoder {
    buf: StreamBuffer,
}

impl XbusDecoder {
    pub fn new() -> Self {
        Self::default()
    }
}

impl Decoder for XbusDecoder {
    type Frame = XbusMessage;

    fn push(&mut self, bytes: &[u8]) {
        self.buf.push(bytes);
    }

    fn poll(&mut self) -> Option<XbusMessage> {
        loop {
            if !self.buf.skip_to_start(&[PREAMBLE]) {
                return None;
            }
            let data = self.buf.data();
            if data.len() < 4 {
                return None;
            }
            let (header_len, len) = if data[3] == 0xFF {
                if data.len() < 6 {
                    return None;
                }
                (6, usize::from(u16::from_be_bytes([data[4], data[5]])))
            } else {
                (4, usize::from(data[3]))
            };
            if len > MAX_PAYLOAD {
                self.buf.reject(1, Reject::TooLong);
                continue;
            }
            let total = header_len + len + 1;
            if data.len() < total {
                return None;
            }
            let sum = data[1..total].iter().fold(0u8, |s, &b| s.wrapping_add(b));
            if sum != 0 {
                self.buf.reject(1, Reject::Checksum);
                continue;
            }
            let (bus_id, mid) = (data[1], data[2]);
            let payload = &data[header_len..header_len + len];
            let message = if mid == MID_MTDATA2 {
                match parse_mtdata2(payload) {
                    Ok(parsed) => Some(XbusMessage::MtData2 {
                        bus_id,
                        data: parsed,
                    }),
                    Err(reason) => {
                        tracing::debug!("xbus: dropping malformed MTData2: {reason}");
                        None
                    }
                }
            } else {
                Some(XbusMessage::Other {
                    bus_id,
                    mid,
                    payload: payload.to_vec(),
                })
            };
            match message {
                Some(m) => {
                    self.buf.accept(total);
                    return Some(m);
                }
                None => self.buf.reject(total, Reject::BadContent),
            }
        }
    }

    fn stats(&self) -> DecoderStats {
        self.buf.stats()
    }
}

/// Xbus encoder: uses the extended length when the payload exceeds 254 bytes.
#[derive(Debug, Default, Clone, Copy)]
pub struct XbusEncoder;

impl Encoder for XbusEncoder {
    type Frame = XbusMessage;

    fn encode(&self, frame: &XbusMessage, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        let start = out.len();
        let result = encode_into(frame, out);
        if result.is_err() {
            out.truncate(start);
        }
        result
    }
}

fn encode_into(frame: &XbusMessage, out: &mut Vec<u8>) -> Result<(), EncodeError> {
    let mut payload = Vec::new();
    let (bus_id, mid, payload) = match frame {
        XbusMessage::MtData2 { bus_id, data } => {
            write_mtdata2(data, &mut payload)?;
            (*bus_id, MID_MTDATA2, payload.as_slice())
        }
        XbusMessage::Other {
            bus_id,
            mid,
            payload,
        } => (*bus_id, *mid, payload.as_slice()),
    };
    if payload.len() > MAX_PAYLOAD {
        return Err(EncodeError::TooLong {
            len: payload.len(),
            max: MAX_PAYLOAD,
        });
    }
    let start = out.len();
    out.push(PREAMBLE);
    out.push(bus_id);
    out.push(mid);
    if payload.len() >= 0xFF {
        out.push(0xFF);
        out.extend_from_slice(&(payload.len() as u16).to_be_bytes());
    } else {
        out.push(payload.len() as u8);
    }
    out.extend_from_slice(payload);
    let sum = out[start + 1..].iter().fold(0u8, |s, &b| s.wrapping_add(b));
    out.push(sum.wrapping_neg());
    Ok(())
}

/// MTData2 messages are readings; other messages (acks, errors) are not.
impl ToReading for XbusMessage {
    fn to_reading(self) -> Option<Reading> {
        match self {
            XbusMessage::MtData2 { data, .. } => Some(Reading::Imu(data.to_imu_sample())),
            XbusMessage::Other { .. } => None,
        }
    }
}

/// The MTData2 message an MTi sends for one sample (float32): PacketCounter (the low 16
/// bits of the sample's `sensor_time`, the device counter), SampleTimeFine (the clock in
/// 0.1 ms ticks, wrapping at 2^32), temperature, acceleration, rate of turn and status word,
/// each when the sample has it.
pub fn encode_sample(
    sample: &ImuSample,
    clock: &DeviceClock,
    out: &mut Vec<u8>,
) -> Result<(), EncodeError> {
    let ticks = (clock.time_s * SAMPLE_TIME_FINE_HZ).round().max(0.0) as u64;
    let real = |id: u16| id | data_id::FLOAT32;
    let data = MtData2 {
        packet_counter: Some((sample.sensor_time.unwrap_or(0.0) as u64 & 0xFFFF) as u16),
        sample_time_fine: Some((ticks & 0xFFFF_FFFF) as u32),
        temperature: sample.temp_c.map(|value| XbusValue {
            data_id: real(data_id::TEMPERATURE),
            value,
        }),
        acceleration: sample.accel.map(|value| XbusValue {
            data_id: real(data_id::ACCELERATION),
            value,
        }),
        rate_of_turn: sample.gyro.map(|value| XbusValue {
            data_id: real(data_id::RATE_OF_TURN),
            value,
        }),
        status_word: Some(sample.status),
        ..MtData2::default()
    };
    XbusEncoder.encode(
        &XbusMessage::MtData2 {
            bus_id: BUS_ID_MASTER,
            data,
        },
        out,
    )
}

/// Auto-detection score: frames with a valid checksum in `sample`.
pub fn detect_score(sample: &[u8]) -> u32 {
    accepted_frames(XbusDecoder::new(), sample)
}
