//! Simulated records to device bytes: each served sensor's records encoded in its device
//! protocol through the drivers' encoders, and each frame decoded back with the drivers'
//! decoders, so a caller knows exactly what a reader of the stream will get.
//!
//! IMU protocols (`protocol` key of an `[[imu]]` table): `wit` (default; WitMotion TIME,
//! ACCEL and GYRO packets per sample), `xbus` (Xsens MTData2: PacketCounter,
//! SampleTimeFine, temperature, acceleration, rate of turn, status word; float32), `csv`
//! (the drivers' default line layout `time,gx,gy,gz,ax,ay,az,temp`, time = the device
//! counter), `vectornav` (VectorNav binary output: Common group TimeStartup, AngularRate,
//! Accel, IMU group ImuStatus and Temp), `mip` (MicroStrain MIP IMU data set: scaled
//! accelerometer in g, scaled gyro, shared reference timestamp; MIP carries no
//! temperature), `slcan` (the CAN frames of `fixtures/imu_can.dbc` through the mapping
//! `fixtures/imu_can_mapping.toml`, as slcan lines). GNSS protocols (`[[gnss]]`): `gnss`
//! (default; NMEA GGA and RMC followed by UBX NAV-PVT and NAV-EOE, all for the same
//! epoch, as a u-blox receiver sends them), `nmea` (GGA and RMC only), `ubx` (NAV-PVT and
//! NAV-EOE only).
//!
//! Device clocks: the sample index `k` is recovered from the arrival time (jitter is far
//! below half a period), so device time is `k / rate` exactly: WitMotion's TIME packet
//! carries the wall-clock time of the sample (ms resolution), Xbus SampleTimeFine is
//! `k / rate` in 0.1 ms ticks (wrapping at 2^32), VectorNav TimeStartup and the MIP
//! reference timestamp `k / rate` in ns, the CAN `TimeUs` signal `k / rate` in µs
//! wrapping at 2^32 µs, and the csv time column the device counter as simulated.
//!
//! Values a protocol cannot carry: a triad the scene does not simulate is left out of the
//! frame (no ACCEL packet, no Xbus item, a csv/CAN layout without it), an axis not simulated
//! in a triad that is goes out as 0; a GNSS epoch without
//! a fix is sent as receivers do: empty NMEA fields with quality 0 / status `V`, and a
//! NAV-PVT with fix type 0, zero position and velocity and maximal accuracy values.
//! The geoid is taken as the ellipsoid (height above MSL = ellipsoidal height, separation 0).

use anyhow::{anyhow, bail, Result};
use chrono::{DateTime, Datelike, Timelike};
use imulab_drivers::codec::csv_line::{CsvColumn, CsvLineConfig, CsvLineDecoder, CsvLineEncoder};
use imulab_drivers::codec::dbc::{DbcImu, DbcImuMapping};
use imulab_drivers::codec::gnss::{EpochFix, GnssDecoder, GnssFrame};
use imulab_drivers::codec::mip::{MipDecoder, MipEncoder, MipImuData, MipPacket};
use imulab_drivers::codec::nmea::{
    Coordinate, Date, Decimal, Gga, NmeaEncoder, NmeaSentence, Rmc, Talker, TimeOfDay,
};
use imulab_drivers::codec::slcan::{SlcanDecoder, SlcanEncoder, SlcanMessage};
use imulab_drivers::codec::ubx::{NavPvt, RawMessage, UbxEncoder, UbxMessage};
use imulab_drivers::codec::vectornav::{
    common as vn_common, imu as vn_imu, VnBinary, VnDecoder, VnEncoder, VnFrame, VnOutputFields,
    VnValues,
};
use imulab_drivers::codec::witmotion::{WitEncoder, WitImuDecoder, WitPacket};
use imulab_drivers::codec::xbus::{
    data_id, MtData2, XbusDecoder, XbusEncoder, XbusMessage, XbusValue, BUS_ID_MASTER,
};
use imulab_drivers::codec::{Decoder, EncodeError, Encoder, Protocol};
use imulab_drivers::types::{FixType, ImuSample};

use super::imu_model::Channels;
use super::scene::START_MONO_NS;
use crate::store::{GnssRecord, ImuRecord};

/// The DBC every `slcan` IMU is served through (the project's IMU-over-CAN layout).
const IMU_CAN_DBC: &str = include_str!("../../fixtures/imu_can.dbc");
/// Its signal mapping.
const IMU_CAN_MAPPING: &str = include_str!("../../fixtures/imu_can_mapping.toml");

/// Protocols an IMU can be served in.
pub const IMU_PROTOCOLS: &[Protocol] = &[
    Protocol::Wit,
    Protocol::Xbus,
    Protocol::Vectornav,
    Protocol::Mip,
    Protocol::Csv,
    Protocol::Slcan,
];
/// Protocols a GNSS receiver can be served in.
pub const GNSS_PROTOCOLS: &[Protocol] = &[Protocol::Gnss, Protocol::Nmea, Protocol::Ubx];

/// Checks a protocol name for a sensor kind; `None` gives the kind's default.
pub fn protocol_for(name: Option<&str>, gnss: bool) -> Result<Protocol> {
    let allowed = if gnss { GNSS_PROTOCOLS } else { IMU_PROTOCOLS };
    let Some(name) = name else {
        return Ok(allowed[0]);
    };
    let protocol = Protocol::from_name(name).map_err(|e| anyhow!("protocol: {e}"))?;
    if !allowed.contains(&protocol) {
        let names: Vec<&str> = allowed.iter().map(|p| p.name()).collect();
        bail!(
            "protocol: a{} cannot be served as `{name}` (served: {})",
            if gnss { " GNSS receiver" } else { "n IMU" },
            names.join(", ")
        );
    }
    Ok(protocol)
}

/// Encodes one IMU's records in its protocol and decodes each frame back.
pub struct ImuWire {
    protocol: Protocol,
    rate_hz: f64,
    format: ImuFormat,
}

enum ImuFormat {
    Wit,
    Xbus,
    Vectornav,
    Mip,
    /// The encoder and a fresh decoder of the same layout.
    Csv(Box<(CsvLineEncoder, CsvLineDecoder)>),
    Slcan(Box<DbcImu>),
}

impl ImuWire {
    /// The wire format of an IMU with `channels` sampled at `rate_hz`.
    pub fn new(protocol: Protocol, channels: Channels, rate_hz: f64) -> Result<Self> {
        let format = match protocol {
            Protocol::Wit => ImuFormat::Wit,
            Protocol::Xbus => ImuFormat::Xbus,
            Protocol::Vectornav => ImuFormat::Vectornav,
            Protocol::Mip => ImuFormat::Mip,
            Protocol::Csv => {
                let config = csv_layout(channels);
                let encoder = CsvLineEncoder::new(config.clone()).map_err(|e| anyhow!("{e}"))?;
                let decoder = CsvLineDecoder::new(config).map_err(|e| anyhow!("{e}"))?;
                ImuFormat::Csv(Box::new((encoder, decoder)))
            }
            Protocol::Slcan => {
                let mut mapping =
                    DbcImuMapping::from_toml_str(IMU_CAN_MAPPING).map_err(|e| anyhow!("{e}"))?;
                if !channels.has_gyro() {
                    mapping.gyro = None;
                    // The status byte travels in the rate message.
                    mapping.status = None;
                }
                if !channels.has_accel() {
                    mapping.accel = None;
                }
                ImuFormat::Slcan(Box::new(
                    DbcImu::new(IMU_CAN_DBC, &mapping).map_err(|e| anyhow!("{e}"))?,
                ))
            }
            other => bail!("an IMU cannot be served as `{}`", other.name()),
        };
        Ok(ImuWire {
            protocol,
            rate_hz,
            format,
        })
    }

    pub fn protocol(&self) -> Protocol {
        self.protocol
    }

    /// Appends the frame(s) of one record to `out`; on error `out` is unchanged.
    pub fn encode(&self, record: &ImuRecord, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        let start = out.len();
        let result = self.encode_into(record, out);
        if result.is_err() {
            out.truncate(start);
        }
        result
    }

    fn encode_into(&self, r: &ImuRecord, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        let gyro = finite3(r.gyro);
        let accel = finite3(r.accel);
        let k = sample_index(r.t_mono_ns, self.rate_hz);
        let device_time_s = k as f64 / self.rate_hz;
        match &self.format {
            ImuFormat::Wit => {
                let wall_ns = r.t_wall_ns - (r.t_mono_ns - START_MONO_NS)
                    + (device_time_s * 1e9).round() as i64;
                WitEncoder.encode(&wit_time(wall_ns)?, out)?;
                if let Some(a) = accel {
                    WitEncoder.encode(&WitPacket::accel_from_si(a, r.temp)?, out)?;
                }
                if let Some(g) = gyro {
                    WitEncoder.encode(&WitPacket::gyro_from_si(g, r.temp)?, out)?;
                }
                Ok(())
            }
            ImuFormat::Xbus => {
                let ticks = (k as f64 * 10_000.0 / self.rate_hz).round() as u64;
                let real = |id: u16| id | data_id::FLOAT32;
                let data = MtData2 {
                    packet_counter: Some((r.t_sensor as u64 & 0xFFFF) as u16),
                    sample_time_fine: Some((ticks & 0xFFFF_FFFF) as u32),
                    temperature: r.temp.is_finite().then_some(XbusValue {
                        data_id: real(data_id::TEMPERATURE),
                        value: r.temp,
                    }),
                    acceleration: accel.map(|value| XbusValue {
                        data_id: real(data_id::ACCELERATION),
                        value,
                    }),
                    rate_of_turn: gyro.map(|value| XbusValue {
                        data_id: real(data_id::RATE_OF_TURN),
                        value,
                    }),
                    status_word: Some(r.status),
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
            ImuFormat::Vectornav => {
                let f32s = |v: [f64; 3]| v.map(|x| x as f32);
                let temp = r.temp.is_finite().then_some(r.temp as f32);
                let mut common = vn_common::TIME_STARTUP;
                if gyro.is_some() {
                    common |= vn_common::ANGULAR_RATE;
                }
                if accel.is_some() {
                    common |= vn_common::ACCEL;
                }
                let imu = vn_imu::IMU_STATUS | if temp.is_some() { vn_imu::TEMP } else { 0 };
                let packet = VnBinary {
                    fields: VnOutputFields {
                        common,
                        imu,
                        ..VnOutputFields::default()
                    },
                    values: VnValues {
                        time_startup_ns: Some((device_time_s * 1e9).round() as u64),
                        angular_rate: gyro.map(f32s),
                        accel: accel.map(f32s),
                        temp_c: temp,
                        imu_status: Some((r.status & 0xFFFF) as u16),
                        ..VnValues::default()
                    },
                    skipped_fields: 0,
                };
                VnEncoder.encode(&VnFrame::Binary(packet), out)
            }
            ImuFormat::Mip => {
                let g = imulab_drivers::codec::mip::STANDARD_GRAVITY;
                let data = MipImuData {
                    scaled_accel_g: accel.map(|v| v.map(|x| (x / g) as f32)),
                    scaled_gyro: gyro.map(|v| v.map(|x| x as f32)),
                    reference_time_ns: Some((device_time_s * 1e9).round() as u64),
                    ..MipImuData::default()
                };
                MipEncoder.encode(&MipPacket::Imu(data), out)
            }
            ImuFormat::Csv(csv) => csv.0.encode(&imu_sample(r, gyro, accel, r.t_sensor), out),
            ImuFormat::Slcan(dbc) => {
                // TimeUs is a 32-bit microsecond count.
                let us = ((device_time_s * 1e6).round() as u64) & 0xFFFF_FFFF;
                let mut sample = imu_sample(r, gyro, accel, us as f64 * 1e-6);
                sample.status &= 0xFF;
                for frame in dbc.encode(&sample)? {
                    SlcanEncoder.encode(
                        &SlcanMessage::Frame {
                            frame,
                            timestamp_ms: None,
                        },
                        out,
                    )?;
                }
                Ok(())
            }
        }
    }

    /// Decodes the bytes of one encoded record with the drivers' decoder for this protocol:
    /// the sample a reader of the stream gets for it.
    pub fn decode_one(&self, bytes: &[u8]) -> Option<ImuSample> {
        let mut decoder = self.stream_decoder();
        let sample = decoder.poll_bytes(bytes);
        sample.or_else(|| decoder.finish_one())
    }

    /// A streaming decoder for this protocol (what a reader of the pty would run).
    pub fn stream_decoder(&self) -> ImuStreamDecoder {
        ImuStreamDecoder {
            inner: match &self.format {
                ImuFormat::Wit => ImuDecoderKind::Wit(WitImuDecoder::new()),
                ImuFormat::Xbus => ImuDecoderKind::Xbus(XbusDecoder::new()),
                ImuFormat::Vectornav => ImuDecoderKind::Vectornav(VnDecoder::new()),
                ImuFormat::Mip => ImuDecoderKind::Mip(MipDecoder::new()),
                ImuFormat::Csv(csv) => ImuDecoderKind::Csv(csv.1.clone()),
                ImuFormat::Slcan(dbc) => ImuDecoderKind::Slcan(SlcanDecoder::new(), dbc.clone()),
            },
        }
    }
}

/// The drivers' decoder for one served IMU protocol, bytes to [`ImuSample`]s.
pub struct ImuStreamDecoder {
    inner: ImuDecoderKind,
}

enum ImuDecoderKind {
    Wit(WitImuDecoder),
    Xbus(XbusDecoder),
    Vectornav(VnDecoder),
    Mip(MipDecoder),
    Csv(CsvLineDecoder),
    Slcan(SlcanDecoder, Box<DbcImu>),
}

impl ImuStreamDecoder {
    /// Pushes bytes and returns every sample they complete.
    pub fn push(&mut self, bytes: &[u8]) -> Vec<ImuSample> {
        let mut out = Vec::new();
        if let Some(s) = self.poll_bytes(bytes) {
            out.push(s);
            while let Some(s) = self.poll_bytes(&[]) {
                out.push(s);
            }
        }
        out
    }

    fn poll_bytes(&mut self, bytes: &[u8]) -> Option<ImuSample> {
        match &mut self.inner {
            ImuDecoderKind::Wit(d) => {
                d.push(bytes);
                d.poll()
            }
            ImuDecoderKind::Xbus(d) => {
                d.push(bytes);
                while let Some(m) = d.poll() {
                    if let XbusMessage::MtData2 { data, .. } = m {
                        return Some(data.to_imu_sample());
                    }
                }
                None
            }
            ImuDecoderKind::Vectornav(d) => {
                d.push(bytes);
                while let Some(frame) = d.poll() {
                    if let Some(sample) = frame.to_imu_sample() {
                        return Some(sample);
                    }
                }
                None
            }
            ImuDecoderKind::Mip(d) => {
                d.push(bytes);
                while let Some(packet) = d.poll() {
                    if let Some(sample) = packet.to_imu_sample() {
                        return Some(sample);
                    }
                }
                None
            }
            ImuDecoderKind::Csv(d) => {
                d.push(bytes);
                d.poll()
            }
            ImuDecoderKind::Slcan(d, dbc) => {
                d.push(bytes);
                while let Some(m) = d.poll() {
                    if let SlcanMessage::Frame { frame, .. } = m {
                        if let Some(s) = dbc.push_frame(&frame) {
                            return Some(s);
                        }
                    }
                }
                None
            }
        }
    }

    /// The sample held back until the input ends (a partial CAN group; WitMotion only while
    /// it has not yet seen one whole output cycle).
    pub fn finish_one(&mut self) -> Option<ImuSample> {
        match &mut self.inner {
            ImuDecoderKind::Wit(d) => d.finish(),
            ImuDecoderKind::Slcan(_, dbc) => dbc.finish(),
            ImuDecoderKind::Xbus(_)
            | ImuDecoderKind::Vectornav(_)
            | ImuDecoderKind::Mip(_)
            | ImuDecoderKind::Csv(_) => None,
        }
    }

    /// Bytes skipped and checksum errors so far.
    pub fn stats(&self) -> imulab_drivers::types::DecoderStats {
        match &self.inner {
            ImuDecoderKind::Wit(d) => d.stats(),
            ImuDecoderKind::Xbus(d) => d.stats(),
            ImuDecoderKind::Vectornav(d) => d.stats(),
            ImuDecoderKind::Mip(d) => d.stats(),
            ImuDecoderKind::Csv(d) => d.stats(),
            ImuDecoderKind::Slcan(d, _) => d.stats(),
        }
    }
}

/// The csv column layout for the simulated triads: time (the device counter), the gyro and
/// accel triads simulated (rad/s, m/s²), temperature (°C), status word.
fn csv_layout(channels: Channels) -> CsvLineConfig {
    let mut next = 0;
    let mut column = || {
        next += 1;
        CsvColumn::at(next - 1)
    };
    let time = Some(column());
    let gyro = channels.has_gyro().then(|| [column(), column(), column()]);
    let accel = channels.has_accel().then(|| [column(), column(), column()]);
    let temp = Some(column());
    let status = Some(column().index);
    CsvLineConfig {
        time,
        gyro,
        accel,
        temp,
        status,
        ..CsvLineConfig::default()
    }
}

/// A triad as sent: absent when no axis was simulated; an axis not simulated goes out as 0
/// (a device always fills every field of its frame).
fn finite3(v: [f64; 3]) -> Option<[f64; 3]> {
    v.iter()
        .any(|x| x.is_finite())
        .then(|| v.map(|x| if x.is_finite() { x } else { 0.0 }))
}

fn imu_sample(
    r: &ImuRecord,
    gyro: Option<[f64; 3]>,
    accel: Option<[f64; 3]>,
    sensor_time: f64,
) -> ImuSample {
    ImuSample {
        sensor_time: Some(sensor_time),
        gyro,
        accel,
        temp_c: r.temp.is_finite().then_some(r.temp),
        status: r.status,
    }
}

/// The sample index of a record: its arrival time rounded to the sample grid.
fn sample_index(t_mono_ns: i64, rate_hz: f64) -> u64 {
    let t = (t_mono_ns - START_MONO_NS) as f64 * 1e-9;
    (t * rate_hz).round().max(0.0) as u64
}

fn wit_time(wall_ns: i64) -> Result<WitPacket, EncodeError> {
    let t = DateTime::from_timestamp_nanos(wall_ns);
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

/// Encodes one receiver's epochs in its protocol and decodes each epoch back.
pub struct GnssWire {
    protocol: Protocol,
}

/// UBX-NAV-EOE: class 0x01, id 0x61, payload iTOW.
const NAV_EOE: (u8, u8) = (0x01, 0x61);

impl GnssWire {
    pub fn new(protocol: Protocol) -> Result<Self> {
        if !GNSS_PROTOCOLS.contains(&protocol) {
            bail!("a GNSS receiver cannot be served as `{}`", protocol.name());
        }
        Ok(GnssWire { protocol })
    }

    pub fn protocol(&self) -> Protocol {
        self.protocol
    }

    /// Appends the sentences/messages of one epoch to `out`; on error `out` is unchanged.
    pub fn encode(&self, record: &GnssRecord, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        let start = out.len();
        let result = self.encode_into(record, out);
        if result.is_err() {
            out.truncate(start);
        }
        result
    }

    fn encode_into(&self, r: &GnssRecord, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        let utc = DateTime::from_timestamp_nanos(r.utc_ns);
        if matches!(self.protocol, Protocol::Gnss | Protocol::Nmea) {
            let (gga, rmc) = nmea_epoch(r, &utc)?;
            NmeaEncoder.encode(&NmeaSentence::Gga(gga), out)?;
            NmeaEncoder.encode(&NmeaSentence::Rmc(rmc), out)?;
        }
        if matches!(self.protocol, Protocol::Gnss | Protocol::Ubx) {
            let pvt = nav_pvt(r, &utc);
            UbxEncoder.encode(&UbxMessage::NavPvt(pvt), out)?;
            UbxEncoder.encode(
                &UbxMessage::Other(RawMessage {
                    class: NAV_EOE.0,
                    id: NAV_EOE.1,
                    payload: pvt.itow_ms.to_le_bytes().to_vec(),
                }),
                out,
            )?;
        }
        Ok(())
    }

    /// Decodes the bytes of one encoded epoch with the drivers' mixed GNSS decoder: the
    /// merged fix a reader gets for it (one; with UBX closed by its NAV-EOE, without
    /// waiting for the next epoch).
    pub fn decode_one(&self, bytes: &[u8]) -> Vec<EpochFix> {
        let mut decoder = GnssDecoder::new();
        let mut fixes = Vec::new();
        decoder.decode(bytes, |f| {
            if let GnssFrame::Fix(fix) = f {
                fixes.push(fix);
            }
        });
        while let Some(f) = decoder.finish() {
            if let GnssFrame::Fix(fix) = f {
                fixes.push(fix);
            }
        }
        fixes
    }
}

fn has_fix(r: &GnssRecord) -> bool {
    r.fix_type != FixType::NoFix && r.lat_deg.is_finite() && r.lon_deg.is_finite()
}

/// `ddmm.mmmmmmm` with hemisphere (7 decimals of a minute: 0.2 mm).
fn coordinate(deg: f64, positive: char, negative: char) -> Coordinate {
    let hemisphere = if deg < 0.0 { negative } else { positive };
    let abs = deg.abs();
    let mut whole = abs.trunc() as i64;
    let mut minutes_e7 = ((abs - whole as f64) * 60.0 * 1e7).round() as i64;
    if minutes_e7 >= 60 * 10_000_000 {
        whole += 1;
        minutes_e7 -= 60 * 10_000_000;
    }
    Coordinate {
        ddmm: Decimal::new(whole * 100 * 10_000_000 + minutes_e7, 7),
        hemisphere,
    }
}

fn decimal(value: f64, scale: u8) -> Result<Decimal, EncodeError> {
    let m = (value * 10f64.powi(i32::from(scale))).round();
    if !m.is_finite() || m.abs() > 1e17 {
        return Err(EncodeError::OutOfRange {
            field: "nmea number",
            value,
        });
    }
    Ok(Decimal::new(m as i64, scale))
}

fn nmea_epoch(r: &GnssRecord, utc: &DateTime<chrono::Utc>) -> Result<(Gga, Rmc), EncodeError> {
    let talker = Talker(*b"GN");
    let centis = utc.nanosecond() / 10_000_000;
    let time = Some(TimeOfDay {
        hour: utc.hour() as u8,
        minute: utc.minute() as u8,
        second: Decimal::new(i64::from(utc.second() * 100 + centis.min(99)), 2),
    });
    let date = Some(Date {
        year: utc.year() as u16,
        month: utc.month() as u8,
        day: utc.day() as u8,
    });
    let fix = has_fix(r);
    let (lat, lon) = if fix {
        (
            Some(coordinate(r.lat_deg, 'N', 'S')),
            Some(coordinate(r.lon_deg, 'E', 'W')),
        )
    } else {
        (None, None)
    };
    let quality = match r.fix_type {
        _ if !fix => 0,
        FixType::Dgnss => 2,
        FixType::RtkFixed => 4,
        FixType::RtkFloat => 5,
        FixType::DeadReckoning | FixType::GnssDeadReckoning => 6,
        _ => 1,
    };
    let opt = |v: f64, scale| -> Result<Option<Decimal>, EncodeError> {
        if fix && v.is_finite() {
            Ok(Some(decimal(v, scale)?))
        } else {
            Ok(None)
        }
    };
    let gga = Gga {
        talker,
        time,
        lat,
        lon,
        quality: Some(quality),
        num_sats: Some(r.num_sats),
        hdop: opt(r.hdop, 2)?,
        alt_msl_m: opt(r.height_m, 3)?,
        geoid_sep_m: fix.then_some(Decimal::new(0, 1)),
        dgps_age_s: None,
        dgps_station: None,
    };
    let speed = r.vel_ned[0].hypot(r.vel_ned[1]);
    let track = r.vel_ned[1]
        .atan2(r.vel_ned[0])
        .to_degrees()
        .rem_euclid(360.0);
    let mode = match r.fix_type {
        _ if !fix => 'N',
        FixType::Dgnss => 'D',
        FixType::RtkFixed => 'R',
        FixType::RtkFloat => 'F',
        FixType::DeadReckoning | FixType::GnssDeadReckoning => 'E',
        _ => 'A',
    };
    let rmc = Rmc {
        talker,
        time,
        status: Some(if fix { 'A' } else { 'V' }),
        lat,
        lon,
        speed_knots: opt(speed / KNOT_MPS, 3)?,
        track_deg: opt(track, 2)?,
        date,
        mag_var_deg: None,
        mag_var_dir: None,
        mode: Some(mode),
        nav_status: None,
    };
    Ok((gga, rmc))
}

const KNOT_MPS: f64 = 1852.0 / 3600.0;

fn nav_pvt(r: &GnssRecord, utc: &DateTime<chrono::Utc>) -> NavPvt {
    let fix = has_fix(r);
    let (fix_type, carrier_flags) = match r.fix_type {
        _ if !fix => (0, 0),
        FixType::DeadReckoning => (1, 0),
        FixType::Fix2D => (2, 0),
        FixType::GnssDeadReckoning => (4, 0),
        FixType::TimeOnly => (5, 0),
        FixType::Dgnss => (3, 0x02),
        FixType::RtkFloat => (3, 0x02 | 0x40),
        FixType::RtkFixed => (3, 0x02 | 0x80),
        _ => (3, 0),
    };
    let or = |v: f64, other: f64| if fix && v.is_finite() { v } else { other };
    let vel = r.vel_ned.map(|v| or(v, 0.0));
    let speed = vel[0].hypot(vel[1]);
    let heading = vel[1].atan2(vel[0]).to_degrees().rem_euclid(360.0);
    // Largest accuracy the u32 mm field holds: what receivers report without a fix.
    let no_accuracy = f64::from(u32::MAX) / 1e3;
    let s_acc = or(r.s_acc_mps, no_accuracy);
    let head_acc = if fix && speed > 0.0 {
        (s_acc / speed).atan().to_degrees().min(180.0)
    } else {
        180.0
    };
    let nano = utc.nanosecond().min(999_999_999) as i32;
    NavPvt {
        itow_ms: (r.tow_s * 1000.0).round().max(0.0) as u32,
        year: utc.year() as u16,
        month: utc.month() as u8,
        day: utc.day() as u8,
        hour: utc.hour() as u8,
        min: utc.minute() as u8,
        sec: utc.second() as u8,
        // validDate, validTime, fullyResolved.
        valid: 0x07,
        t_acc_ns: 20,
        nano_ns: nano,
        fix_type,
        // gnssFixOK when there is a fix, plus the differential/carrier bits.
        flags: if fix { 0x01 | carrier_flags } else { 0 },
        flags2: 0,
        num_sv: r.num_sats,
        lon_deg: or(r.lon_deg, 0.0),
        lat_deg: or(r.lat_deg, 0.0),
        height_m: or(r.height_m, 0.0),
        height_msl_m: or(r.height_m, 0.0),
        h_acc_m: or(r.h_acc_m, no_accuracy),
        v_acc_m: or(r.v_acc_m, no_accuracy),
        vel_n_mps: vel[0],
        vel_e_mps: vel[1],
        vel_d_mps: vel[2],
        ground_speed_mps: speed,
        head_mot_deg: heading,
        s_acc_mps: s_acc,
        head_acc_deg: head_acc,
        pdop: or(r.pdop, 99.99),
        flags3: 0,
        head_veh_deg: Some(heading),
        mag_dec_deg: Some(0.0),
        mag_acc_deg: Some(0.0),
    }
}
