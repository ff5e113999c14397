//! IMU over CAN through a DBC file: a small mapping (TOML or struct) names, for each of gyro
//! x/y/z, accel x/y/z, temperature, time and status, the DBC message and signal that carries
//! it, with an optional extra scale/offset and unit. The DBC is parsed with `can-dbc`; the
//! bit extraction (Intel and Motorola order, signed and unsigned) is done here because
//! `can-dbc` only parses the file.
//!
//! Conversion: DBC physical = raw × factor + offset (from the DBC);
//! SI = unit_factor(unit) × (physical × scale + offset) (scale/offset from the mapping,
//! unit from the mapping or else the DBC). Units are checked against the quantity: gyro
//! accepts rad/s, deg/s (°/s, dps), mrad/s; accel m/s² (m/s^2, m/s2), g, mg; temp °C (degC,
//! C); time s, ms, us. A gyro or accel signal without a unit is refused rather than guessed.
//! The raw CAN frames stay available to the caller, so raw values are recoverable.
//!
//! Grouping: the mapping names every message of a sample, so nothing needs learning (unlike
//! [`super::cycle`], which has to learn a device's cycle): a sample is complete on the
//! message that closes the mapped set (the group then holds every mapped message) and is
//! emitted with that message, not one message late. A mapped message arriving that the group
//! already holds (a message of the set lost, or one sent at a lower rate) ends the group
//! early: it is emitted as it is, axes of the missing messages NaN, before the new message
//! starts the next group. `finish()` emits a partial group at the end of the input.

use std::collections::BTreeMap;

use can_dbc::{ByteOrder, Dbc, MessageId, ValueType};
use serde::{Deserialize, Serialize};

use super::can::CanFrame;
use super::candump::{CandumpDecoder, CandumpRecord};
use super::reading::{
    byte_readings, imu_encoder, Input, Reading, ReadingDecoder, ReadingDecoderFactory,
    ReadingEncoder,
};
use super::slcan::{SlcanDecoder, SlcanEncoder, SlcanMessage};
use super::{Decoder, DecoderOptions, EncodeError, Encoder, JsonDecoder, OpenError};
use crate::types::{DecoderStats, ImuSample};

/// Where one quantity lives in the DBC, and any extra scaling.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SignalMap {
    /// DBC message name (`BO_ <id> <name>: ...`).
    pub message: String,
    /// DBC signal name (`SG_ <name> : ...`).
    pub signal: String,
    /// Extra factor applied to the DBC physical value (default 1).
    #[serde(default = "one")]
    pub scale: f64,
    /// Extra offset added after `scale` (default 0), in the signal's unit.
    #[serde(default)]
    pub offset: f64,
    /// Unit of the (scaled) value; overrides the DBC unit when given.
    #[serde(default)]
    pub unit: Option<String>,
}

fn one() -> f64 {
    1.0
}

/// Which DBC signals carry the IMU quantities. Example (TOML):
///
/// ```toml
/// gyro = [ { message = "IMU_Rate", signal = "RateX" },
///          { message = "IMU_Rate", signal = "RateY" },
///          { message = "IMU_Rate", signal = "RateZ" } ]
/// accel = [ { message = "IMU_Accel", signal = "AccX" },
///           { message = "IMU_Accel", signal = "AccY" },
///           { message = "IMU_Accel", signal = "AccZ" } ]
/// temp = { message = "IMU_Accel", signal = "Temp" }
/// ```
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DbcImuMapping {
    #[serde(default)]
    pub gyro: Option<[SignalMap; 3]>,
    #[serde(default)]
    pub accel: Option<[SignalMap; 3]>,
    #[serde(default)]
    pub temp: Option<SignalMap>,
    #[serde(default)]
    pub time: Option<SignalMap>,
    #[serde(default)]
    pub status: Option<SignalMap>,
}

impl DbcImuMapping {
    /// Parses the mapping from TOML; the error names the line and key.
    pub fn from_toml_str(text: &str) -> Result<Self, String> {
        toml::from_str(text).map_err(|e| format!("DBC mapping: {e}"))
    }
}

/// What a signal means, to check its unit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Quantity {
    Gyro(usize),
    Accel(usize),
    Temp,
    Time,
    Status,
}

impl Quantity {
    fn field(self) -> &'static str {
        match self {
            Quantity::Gyro(_) => "gyro",
            Quantity::Accel(_) => "accel",
            Quantity::Temp => "temp_c",
            Quantity::Time => "sensor_time",
            Quantity::Status => "status",
        }
    }

    fn key(self) -> String {
        match self {
            Quantity::Gyro(i) => format!("gyro[{i}]"),
            Quantity::Accel(i) => format!("accel[{i}]"),
            Quantity::Temp => "temp".into(),
            Quantity::Time => "time".into(),
            Quantity::Status => "status".into(),
        }
    }
}

fn unit_factor(q: Quantity, unit: &str) -> Result<f64, String> {
    let u = unit.trim();
    let factor = match q {
        Quantity::Gyro(_) => match u {
            "rad/s" => Some(1.0),
            "mrad/s" => Some(1e-3),
            "deg/s" | "°/s" | "dps" | "degree/s" => Some(std::f64::consts::PI / 180.0),
            _ => None,
        },
        Quantity::Accel(_) => match u {
            "m/s^2" | "m/s2" | "m/s²" | "mps2" => Some(1.0),
            "g" => Some(9.806_65),
            "mg" => Some(9.806_65e-3),
            _ => None,
        },
        Quantity::Temp => match u {
            "degC" | "°C" | "C" | "deg C" | "celsius" => Some(1.0),
            _ => None,
        },
        Quantity::Time => match u {
            "s" => Some(1.0),
            "ms" => Some(1e-3),
            "us" | "µs" => Some(1e-6),
            _ => None,
        },
        Quantity::Status => Some(1.0),
    };
    factor.ok_or_else(|| {
        format!(
            "{}: unit {u:?} is not a known unit for this quantity (gyro: rad/s, mrad/s, deg/s; \
             accel: m/s^2, g, mg; temp: degC; time: s, ms, us)",
            q.key()
        )
    })
}

/// Bit layout of one signal, resolved from the DBC.
#[derive(Debug, Clone)]
struct Layout {
    start_bit: u32,
    size: u32,
    little_endian: bool,
    signed: bool,
    factor: f64,
    offset: f64,
}

impl Layout {
    /// Frame bit positions from the signal's most significant bit to its least.
    fn bit_positions(&self) -> impl Iterator<Item = u32> + '_ {
        let mut motorola_pos = self.start_bit;
        (0..self.size).map(move |i| {
            if self.little_endian {
                self.start_bit + (self.size - 1 - i)
            } else {
                let p = motorola_pos;
                motorola_pos = if p.is_multiple_of(8) { p + 15 } else { p - 1 };
                p
            }
        })
    }

    fn end_byte(&self) -> usize {
        self.bit_positions()
            .map(|p| p as usize / 8)
            .max()
            .unwrap_or(0)
            + 1
    }

    /// The raw value (unsigned signals as u64, signed sign-extended), widened to i128.
    fn extract(&self, data: &[u8]) -> Option<i128> {
        let mut raw: u64 = 0;
        for p in self.bit_positions() {
            let byte = *data.get(p as usize / 8)?;
            raw = (raw << 1) | u64::from((byte >> (p % 8)) & 1);
        }
        if !self.signed {
            return Some(i128::from(raw));
        }
        if self.size < 64 && raw & (1 << (self.size - 1)) != 0 {
            raw |= u64::MAX << self.size;
        }
        Some(i128::from(raw as i64))
    }

    fn insert(&self, raw: i128, data: &mut [u8]) {
        let bits = raw as u64;
        for (i, p) in self.bit_positions().enumerate() {
            let bit = (bits >> (self.size as usize - 1 - i)) & 1;
            if let Some(byte) = data.get_mut(p as usize / 8) {
                let mask = 1u8 << (p % 8);
                *byte = (*byte & !mask) | (bit as u8 * mask);
            }
        }
    }

    fn raw_range(&self) -> (f64, f64) {
        if self.signed {
            let half = 2f64.powi(self.size as i32 - 1);
            (-half, half - 1.0)
        } else {
            (0.0, 2f64.powi(self.size as i32) - 1.0)
        }
    }
}

#[derive(Debug, Clone)]
struct ResolvedSignal {
    quantity: Quantity,
    message_index: usize,
    layout: Layout,
    scale: f64,
    offset: f64,
    unit_factor: f64,
}

impl ResolvedSignal {
    fn to_si(&self, raw: i128) -> f64 {
        let physical = raw as f64 * self.layout.factor + self.layout.offset;
        self.unit_factor * (physical * self.scale + self.offset)
    }

    fn to_raw(&self, si: f64) -> Result<i128, EncodeError> {
        let physical = (si / self.unit_factor - self.offset) / self.scale;
        let raw = ((physical - self.layout.offset) / self.layout.factor).round();
        let (lo, hi) = self.layout.raw_range();
        if !(raw >= lo && raw <= hi) {
            return Err(EncodeError::OutOfRange {
                field: self.quantity.field(),
                value: si,
            });
        }
        Ok(raw as i128)
    }
}

#[derive(Debug, Clone)]
struct MappedMessage {
    id: u32,
    extended: bool,
    size: usize,
}

/// Decodes IMU samples from CAN frames using a DBC and a [`DbcImuMapping`], and encodes
/// samples back into the same frames.
#[derive(Debug, Clone)]
pub struct DbcImu {
    messages: Vec<MappedMessage>,
    signals: Vec<ResolvedSignal>,
    current: ImuSample,
    seen: u64,
    stats: DecoderStats,
    frames_ignored: u64,
}

impl DbcImu {
    /// Resolves `mapping` against the DBC text. Errors name the mapping key and what is
    /// wrong (unknown message or signal, unusable unit, bad scale).
    pub fn new(dbc_text: &str, mapping: &DbcImuMapping) -> Result<Self, String> {
        let dbc = Dbc::try_from(dbc_text).map_err(|e| format!("DBC parse error: {e}"))?;
        let mut wanted: Vec<(Quantity, &SignalMap)> = Vec::new();
        if let Some(g) = &mapping.gyro {
            wanted.extend(g.iter().enumerate().map(|(i, s)| (Quantity::Gyro(i), s)));
        }
        if let Some(a) = &mapping.accel {
            wanted.extend(a.iter().enumerate().map(|(i, s)| (Quantity::Accel(i), s)));
        }
        wanted.extend(mapping.temp.iter().map(|s| (Quantity::Temp, s)));
        wanted.extend(mapping.time.iter().map(|s| (Quantity::Time, s)));
        wanted.extend(mapping.status.iter().map(|s| (Quantity::Status, s)));
        if wanted.is_empty() {
            return Err("DBC mapping maps no quantity".into());
        }
        let mut messages: Vec<MappedMessage> = Vec::new();
        let mut message_index: BTreeMap<String, usize> = BTreeMap::new();
        let mut signals = Vec::new();
        for (q, map) in wanted {
            let key = q.key();
            let message = dbc
                .messages
                .iter()
                .find(|m| m.name == map.message)
                .ok_or_else(|| format!("{key}: message {:?} is not in the DBC", map.message))?;
            let signal = message
                .signals
                .iter()
                .find(|s| s.name == map.signal)
                .ok_or_else(|| {
                    format!(
                        "{key}: signal {:?} is not in message {:?}",
                        map.signal, map.message
                    )
                })?;
            if !(map.scale.is_finite() && map.scale != 0.0 && map.offset.is_finite()) {
                return Err(format!(
                    "{key}: scale must be finite and non-zero, offset finite"
                ));
            }
            if signal.size == 0
                || signal.size > 64
                || !signal.factor.is_finite()
                || signal.factor == 0.0
            {
                return Err(format!(
                    "{key}: signal {:?} has size {} and factor {}, not decodable",
                    signal.name, signal.size, signal.factor
                ));
            }
            let unit = map.unit.clone().unwrap_or_else(|| signal.unit.clone());
            let unit_factor = if unit.trim().is_empty() {
                match q {
                    Quantity::Gyro(_) | Quantity::Accel(_) => {
                        return Err(format!(
                            "{key}: signal {:?} has no unit in the DBC; set `unit` in the mapping",
                            signal.name
                        ))
                    }
                    _ => 1.0,
                }
            } else {
                unit_factor(q, &unit)?
            };
            let size = usize::try_from(message.size).unwrap_or(usize::MAX);
            if size > 64 {
                return Err(format!(
                    "{key}: message {:?} is longer than 64 bytes",
                    message.name
                ));
            }
            let layout = Layout {
                start_bit: signal.start_bit as u32,
                size: signal.size as u32,
                little_endian: signal.byte_order == ByteOrder::LittleEndian,
                signed: signal.value_type == ValueType::Signed,
                factor: signal.factor,
                offset: signal.offset,
            };
            if signal.start_bit >= 512 || layout.end_byte() > size {
                return Err(format!(
                    "{key}: signal {:?} does not fit in the {size}-byte message {:?}",
                    signal.name, message.name
                ));
            }
            let index = *message_index
                .entry(message.name.clone())
                .or_insert_with(|| {
                    let (id, extended) = match message.id {
                        MessageId::Standard(id) => (u32::from(id), false),
                        MessageId::Extended(id) => (id, true),
                    };
                    messages.push(MappedMessage { id, extended, size });
                    messages.len() - 1
                });
            signals.push(ResolvedSignal {
                quantity: q,
                message_index: index,
                layout,
                scale: map.scale,
                offset: map.offset,
                unit_factor,
            });
        }
        if messages.len() > 64 {
            return Err("DBC mapping uses more than 64 messages".into());
        }
        Ok(DbcImu {
            messages,
            signals,
            current: ImuSample::default(),
            seen: 0,
            stats: DecoderStats::default(),
            frames_ignored: 0,
        })
    }

    /// Feeds one received frame; returns the sample it completes (the group then holds
    /// every mapped message), or the partial sample held before it when the group already
    /// held this message (see the module doc). Frames of unmapped ids are ignored (counted
    /// in [`DbcImu::frames_ignored`]).
    pub fn push_frame(&mut self, frame: &CanFrame) -> Option<ImuSample> {
        let Some(index) = self
            .messages
            .iter()
            .position(|m| m.id == frame.id() && m.extended == frame.is_extended())
        else {
            self.frames_ignored += 1;
            return None;
        };
        let payload = frame.payload();
        if payload.len() < self.messages[index].size {
            self.stats.frames_malformed += 1;
            return None;
        }
        let bit = 1u64 << index;
        let finished = if self.seen & bit != 0 {
            self.finish()
        } else {
            None
        };
        self.seen |= bit;
        self.stats.frames_ok += 1;
        for s in self.signals.iter().filter(|s| s.message_index == index) {
            let Some(raw) = s.layout.extract(payload) else {
                continue;
            };
            let v = s.to_si(raw);
            let c = &mut self.current;
            match s.quantity {
                Quantity::Gyro(i) => c.gyro.get_or_insert([f64::NAN; 3])[i] = v,
                Quantity::Accel(i) => c.accel.get_or_insert([f64::NAN; 3])[i] = v,
                Quantity::Temp => c.temp_c = Some(v),
                Quantity::Time => c.sensor_time = Some(v),
                Quantity::Status => c.status = raw as u32,
            }
        }
        if finished.is_none() && self.seen == self.all_messages() {
            return self.finish();
        }
        finished
    }

    /// The mask of every mapped message (at most 64, checked in [`DbcImu::new`]).
    fn all_messages(&self) -> u64 {
        match self.messages.len() {
            64 => u64::MAX,
            n => (1u64 << n) - 1,
        }
    }

    /// Emits the group collected so far, if it holds any IMU data. Axes whose message did
    /// not arrive are NaN.
    pub fn finish(&mut self) -> Option<ImuSample> {
        let sample = std::mem::take(&mut self.current);
        self.seen = 0;
        (sample.gyro.is_some() || sample.accel.is_some()).then_some(sample)
    }

    /// Counters: `frames_ok` mapped frames used, `frames_malformed` mapped frames too short.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Frames whose id is not in the mapping.
    pub fn frames_ignored(&self) -> u64 {
        self.frames_ignored
    }

    /// Encodes a sample as the mapped messages, in mapping order. A mapped quantity missing
    /// from the sample, or a value outside a signal's range, is an error.
    pub fn encode(&self, sample: &ImuSample) -> Result<Vec<CanFrame>, EncodeError> {
        let mut payloads: Vec<[u8; 64]> = vec![[0u8; 64]; self.messages.len()];
        for s in &self.signals {
            let missing = || EncodeError::Invalid {
                field: s.quantity.field(),
                reason: "mapped in the DBC mapping but missing from the sample",
            };
            let raw = match s.quantity {
                Quantity::Gyro(i) => s.to_raw(sample.gyro.ok_or_else(missing)?[i])?,
                Quantity::Accel(i) => s.to_raw(sample.accel.ok_or_else(missing)?[i])?,
                Quantity::Temp => s.to_raw(sample.temp_c.ok_or_else(missing)?)?,
                Quantity::Time => s.to_raw(sample.sensor_time.ok_or_else(missing)?)?,
                Quantity::Status => i128::from(sample.status),
            };
            s.layout.insert(raw, &mut payloads[s.message_index]);
        }
        self.messages
            .iter()
            .zip(&payloads)
            .map(|(m, p)| {
                let data = &p[..m.size];
                let frame = if m.size <= 8 {
                    CanFrame::data(m.id, m.extended, data)
                } else {
                    CanFrame::fd(m.id, m.extended, true, false, data)
                };
                frame.map_err(|_| EncodeError::Invalid {
                    field: "message",
                    reason: "DBC message id or size is not a valid CAN frame",
                })
            })
            .collect()
    }
}

/// A byte decoder of CAN frames (slcan, candump) followed by a [`DbcImu`]: bytes in,
/// [`ImuSample`]s out. Counters are the byte decoder's plus the DBC stage's malformed frames.
pub struct DbcStreamDecoder<D: Decoder> {
    inner: D,
    extract: fn(&D::Frame) -> Option<CanFrame>,
    imu: DbcImu,
}

impl<D: Decoder> DbcStreamDecoder<D> {
    /// `extract` picks the CAN frame out of the inner decoder's frame (`None` to skip it).
    pub fn new(inner: D, extract: fn(&D::Frame) -> Option<CanFrame>, imu: DbcImu) -> Self {
        DbcStreamDecoder {
            inner,
            extract,
            imu,
        }
    }
}

impl<D: Decoder> Decoder for DbcStreamDecoder<D> {
    type Frame = ImuSample;

    fn push(&mut self, bytes: &[u8]) {
        self.inner.push(bytes);
    }

    fn poll(&mut self) -> Option<ImuSample> {
        while let Some(frame) = self.inner.poll() {
            if let Some(can) = (self.extract)(&frame) {
                if let Some(sample) = self.imu.push_frame(&can) {
                    return Some(sample);
                }
            }
        }
        None
    }

    fn stats(&self) -> DecoderStats {
        let mut stats = self.inner.stats();
        stats.frames_malformed += self.imu.stats().frames_malformed;
        stats
    }

    fn finish(&mut self) -> Option<ImuSample> {
        self.imu.finish()
    }
}

fn slcan_frame(m: &SlcanMessage) -> Option<CanFrame> {
    match m {
        SlcanMessage::Frame { frame, .. } => Some(*frame),
        _ => None,
    }
}

fn candump_frame(r: &CandumpRecord) -> Option<CanFrame> {
    Some(r.frame)
}

/// A CAN IMU: CAN frames through the DBC mapping into samples (protocol `can-dbc`).
struct CanImuReadings {
    imu: DbcImu,
    ready: Option<ImuSample>,
    /// Bytes pushed to this CAN decoder.
    wrong_input: u64,
}

impl ReadingDecoder for CanImuReadings {
    fn push(&mut self, input: Input<'_>) {
        match input {
            Input::Can(frame) => {
                if let Some(sample) = self.imu.push_frame(frame) {
                    // A frame completes at most one sample, polled before the next push.
                    self.ready = Some(sample);
                }
            }
            Input::Bytes(_) => self.wrong_input += 1,
        }
    }

    fn poll(&mut self) -> Option<Reading> {
        self.ready.take().map(Reading::Imu)
    }

    fn stats(&self) -> DecoderStats {
        let mut stats = self.imu.stats();
        stats.frames_malformed += self.wrong_input;
        stats
    }

    fn finish(&mut self) -> Option<Reading> {
        self.ready
            .take()
            .or_else(|| self.imu.finish())
            .map(Reading::Imu)
    }
}

/// The DBC and mapping of a protocol that cannot do without them.
fn require_dbc(protocol: &'static str, options: &DecoderOptions) -> Result<DbcImu, OpenError> {
    load_dbc(protocol, options)?.ok_or_else(|| OpenError {
        protocol,
        reason: "needs a DBC file and its signal mapping (TOML, see docs/protocols-imu-can.md)"
            .into(),
    })
}

/// Readings of `can-dbc`: CAN frames through the DBC and mapping of `options`.
pub fn can_readings(options: &DecoderOptions) -> Result<ReadingDecoderFactory, OpenError> {
    let imu = require_dbc("can-dbc", options)?;
    Ok(Box::new(move || {
        Box::new(CanImuReadings {
            imu: imu.clone(),
            ready: None,
            wrong_input: 0,
        })
    }))
}

/// Readings of an slcan byte stream through the DBC and mapping of `options`.
pub fn slcan_readings(options: &DecoderOptions) -> Result<ReadingDecoderFactory, OpenError> {
    let imu = require_dbc("slcan", options)?;
    Ok(byte_readings(move || {
        DbcStreamDecoder::new(SlcanDecoder::new(), slcan_frame, imu.clone())
    }))
}

/// Readings of a candump log through the DBC and mapping of `options`.
pub fn candump_readings(options: &DecoderOptions) -> Result<ReadingDecoderFactory, OpenError> {
    let imu = require_dbc("candump", options)?;
    Ok(byte_readings(move || {
        DbcStreamDecoder::new(CandumpDecoder::new(), candump_frame, imu.clone())
    }))
}

/// The slcan lines an IMU on a CAN bus sends for one sample, through the DBC and mapping of
/// `options`: its mapped messages as `t`/`T` lines. The time signal carries the clock in µs
/// wrapping at 2^32 and the status signal the low byte of the status word (the layout of
/// `fixtures/imu_can.dbc`).
pub fn slcan_encoder(options: &DecoderOptions) -> Result<Box<dyn ReadingEncoder>, OpenError> {
    let imu = require_dbc("slcan", options)?;
    Ok(imu_encoder(move |sample, clock, out| {
        let us = ((clock.time_s * 1e6).round().max(0.0) as u64) & 0xFFFF_FFFF;
        let mut sample = *sample;
        sample.sensor_time = Some(us as f64 * 1e-6);
        sample.status &= 0xFF;
        for frame in imu.encode(&sample)? {
            SlcanEncoder.encode(
                &SlcanMessage::Frame {
                    frame,
                    timestamp_ms: None,
                },
                out,
            )?;
        }
        Ok(())
    }))
}

/// Loads the DBC (`options.dbc`) and its mapping (`options.config`, TOML), if a DBC is given.
fn load_dbc(protocol: &'static str, options: &DecoderOptions) -> Result<Option<DbcImu>, OpenError> {
    let fail = |reason: String| OpenError { protocol, reason };
    let Some(dbc) = &options.dbc else {
        return Ok(None);
    };
    let mapping_file = options.config.as_ref().ok_or_else(|| {
        fail("--dbc needs a signal mapping file (TOML, see docs/protocols-imu-can.md)".into())
    })?;
    let mapping = DbcImuMapping::from_toml_str(&mapping_file.text)
        .map_err(|e| fail(format!("{}: {e}", mapping_file.name)))?;
    DbcImu::new(&dbc.text, &mapping)
        .map(Some)
        .map_err(|e| fail(format!("{}: {e}", dbc.name)))
}

/// Builds the decoder for `imulab decode --protocol slcan`: CAN messages as JSON, or
/// [`ImuSample`]s when a DBC and mapping are given.
pub fn open_slcan_json(options: &DecoderOptions) -> Result<Box<dyn JsonDecoder>, OpenError> {
    Ok(match load_dbc("slcan", options)? {
        Some(imu) => Box::new(DbcStreamDecoder::new(SlcanDecoder::new(), slcan_frame, imu)),
        None => Box::new(SlcanDecoder::new()),
    })
}

/// Builds the decoder for `imulab decode --protocol candump`: records as JSON, or
/// [`ImuSample`]s when a DBC and mapping are given.
pub fn open_candump_json(options: &DecoderOptions) -> Result<Box<dyn JsonDecoder>, OpenError> {
    Ok(match load_dbc("candump", options)? {
        Some(imu) => Box::new(DbcStreamDecoder::new(
            CandumpDecoder::new(),
            candump_frame,
            imu,
        )),
        None => Box::new(CandumpDecoder::new()),
    })
}
