//! Simulated records to device bytes: each served sensor's records encoded in its device
//! protocol by the encoder of its row in the drivers' protocol table, and each frame decoded
//! back by the same row's reading decoder, so a caller knows exactly what a reader of the
//! stream will get.
//!
//! IMU protocols (`protocol` key of an `[[imu]]` table): `wit` (default; WitMotion TIME,
//! ACCEL and GYRO packets per sample), `xbus` (Xsens MTData2: PacketCounter,
//! SampleTimeFine, temperature, acceleration, rate of turn, status word; float32), `csv`
//! (the drivers' default line layout `time,gx,gy,gz,ax,ay,az,temp`, time = the device
//! counter), `vectornav` (VectorNav binary output: Common group TimeStartup, AngularRate,
//! Accel, IMU group ImuStatus and Temp), `mip` (MicroStrain MIP IMU data set: scaled
//! accelerometer in g, scaled gyro, shared reference timestamp; MIP carries no
//! temperature; with the scene's `output`, VectorNav DeltaThetaVel and MIP delta theta /
//! delta velocity over the sample interval instead of or beside the rates), `slcan` (the
//! CAN frames of `fixtures/imu_can.dbc` through the mapping
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
use imulab_drivers::codec::csv_line::{CsvColumn, CsvLineConfig};
use imulab_drivers::codec::dbc::DbcImuMapping;
use imulab_drivers::codec::gnss::{EpochFix, GnssDecoder, GnssFrame};
use imulab_drivers::codec::reading::{
    DeviceClock, Input, Kind, Reading, ReadingDecoder, ReadingDecoderFactory, ReadingEncoder,
};
use imulab_drivers::codec::{
    Decoder, DecoderOptions, EncodeError, ImuOutput, NamedText, Protocol, RowsFrom, PROTOCOLS,
};
use imulab_drivers::types::{DecoderStats, GnssFix, ImuSample};

use super::imu_model::Channels;
use super::scene::START_MONO_NS;
use imulab_store::{GnssRecord, ImuRecord};

/// The DBC every `slcan` IMU is served through (the project's IMU-over-CAN layout).
const IMU_CAN_DBC: &str = include_str!("../../fixtures/imu_can.dbc");
/// Its signal mapping.
const IMU_CAN_MAPPING: &str = include_str!("../../fixtures/imu_can_mapping.toml");

/// The protocol an IMU is served in when its table gives none.
pub const DEFAULT_IMU_PROTOCOL: Protocol = Protocol::Wit;
/// The protocol a GNSS receiver is served in when its table gives none.
pub const DEFAULT_GNSS_PROTOCOL: Protocol = Protocol::Gnss;

/// The protocols a sensor kind can be served in: the table's rows of that kind with an
/// encoder.
pub fn served(kind: Kind) -> impl Iterator<Item = Protocol> {
    PROTOCOLS
        .iter()
        .filter(move |e| e.kind == kind && e.encoder.is_some())
        .map(|e| e.protocol)
}

/// Checks a protocol name for a sensor kind; `None` gives the kind's default.
pub fn protocol_for(name: Option<&str>, gnss: bool) -> Result<Protocol> {
    let kind = if gnss { Kind::Gnss } else { Kind::Imu };
    let Some(name) = name else {
        return Ok(if gnss {
            DEFAULT_GNSS_PROTOCOL
        } else {
            DEFAULT_IMU_PROTOCOL
        });
    };
    let protocol = Protocol::from_name(name).map_err(|e| anyhow!("protocol: {e}"))?;
    if !served(kind).any(|p| p == protocol) {
        let names: Vec<&str> = served(kind).map(|p| p.name()).collect();
        bail!(
            "protocol: a{} cannot be served as `{name}` (served: {})",
            if gnss { " GNSS receiver" } else { "n IMU" },
            names.join(", ")
        );
    }
    Ok(protocol)
}

/// Encodes one IMU's records in its protocol and decodes each frame back, both through the
/// protocol's row of the drivers' table.
pub struct ImuWire {
    protocol: Protocol,
    rate_hz: f64,
    encoder: Box<dyn ReadingEncoder>,
    decoders: ReadingDecoderFactory,
}

impl ImuWire {
    /// The wire format of an IMU with `channels` sampled at `rate_hz`, sending its rates.
    pub fn new(protocol: Protocol, channels: Channels, rate_hz: f64) -> Result<Self> {
        Self::with_output(protocol, channels, rate_hz, ImuOutput::Rates)
    }

    /// The wire format of an IMU that sends `output` (rates, deltas over the sample interval,
    /// or both: VectorNav, MIP). Frames with deltas are decoded back with rows from the
    /// deltas.
    pub fn with_output(
        protocol: Protocol,
        channels: Channels,
        rate_hz: f64,
        output: ImuOutput,
    ) -> Result<Self> {
        if protocol.kind() != Kind::Imu {
            bail!("an IMU cannot be served as `{}`", protocol.name());
        }
        let mut options = options_for(protocol, channels)?;
        options.imu_output = output;
        if output != ImuOutput::Rates {
            options.rows_from = RowsFrom::Deltas;
        }
        Ok(ImuWire {
            protocol,
            rate_hz,
            encoder: protocol.encoder(&options)?,
            decoders: protocol.readings(&options)?,
        })
    }

    pub fn protocol(&self) -> Protocol {
        self.protocol
    }

    /// Appends the frame(s) of one record to `out`; on error `out` is unchanged.
    pub fn encode(&self, r: &ImuRecord, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        let k = sample_index(r.t_mono_ns, self.rate_hz);
        let device_time_s = k as f64 / self.rate_hz;
        let clock = DeviceClock {
            time_s: device_time_s,
            wall_ns: r.t_wall_ns - (r.t_mono_ns - START_MONO_NS)
                + (device_time_s * 1e9).round() as i64,
            interval_s: 1.0 / self.rate_hz,
        };
        let sample = ImuSample {
            // The device counter as simulated: the Xbus PacketCounter, the csv time column.
            sensor_time: Some(r.t_sensor),
            gyro: finite3(r.gyro),
            accel: finite3(r.accel),
            temp_c: r.temp.is_finite().then_some(r.temp),
            status: r.status,
        };
        self.encoder.encode(&Reading::Imu(sample), &clock, out)
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
            inner: (self.decoders)(),
        }
    }
}

/// The options of a served IMU protocol: the csv column layout and the CAN signals of the
/// triads simulated.
fn options_for(protocol: Protocol, channels: Channels) -> Result<DecoderOptions> {
    let mut options = DecoderOptions::default();
    if protocol.entry().dbc {
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
        options.dbc = Some(NamedText {
            name: "fixtures/imu_can.dbc".into(),
            text: IMU_CAN_DBC.into(),
        });
        options.config = Some(NamedText {
            name: "fixtures/imu_can_mapping.toml".into(),
            text: toml::to_string(&mapping)?,
        });
    } else if protocol == Protocol::Csv {
        options.config = Some(NamedText {
            name: "the simulated csv layout".into(),
            text: toml::to_string(&csv_layout(channels))?,
        });
    }
    Ok(options)
}

/// The drivers' decoder for one served IMU protocol, bytes to [`ImuSample`]s.
pub struct ImuStreamDecoder {
    inner: Box<dyn ReadingDecoder>,
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
        self.inner.push(Input::Bytes(bytes));
        while let Some(reading) = self.inner.poll() {
            if let Reading::Imu(sample) = reading {
                return Some(sample);
            }
        }
        None
    }

    /// The sample held back until the input ends (a partial CAN group; WitMotion only while
    /// it has not yet seen one whole output cycle).
    pub fn finish_one(&mut self) -> Option<ImuSample> {
        while let Some(reading) = self.inner.finish() {
            if let Reading::Imu(sample) = reading {
                return Some(sample);
            }
        }
        None
    }

    /// Bytes skipped and checksum errors so far.
    pub fn stats(&self) -> DecoderStats {
        self.inner.stats()
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

/// The sample index of a record: its arrival time rounded to the sample grid.
fn sample_index(t_mono_ns: i64, rate_hz: f64) -> u64 {
    let t = (t_mono_ns - START_MONO_NS) as f64 * 1e-9;
    (t * rate_hz).round().max(0.0) as u64
}

/// Encodes one receiver's epochs in its protocol (through its row of the drivers' table)
/// and decodes each epoch back.
pub struct GnssWire {
    protocol: Protocol,
    encoder: Box<dyn ReadingEncoder>,
}

impl GnssWire {
    pub fn new(protocol: Protocol) -> Result<Self> {
        if protocol.kind() != Kind::Gnss {
            bail!("a GNSS receiver cannot be served as `{}`", protocol.name());
        }
        Ok(GnssWire {
            protocol,
            encoder: protocol.encoder(&DecoderOptions::default())?,
        })
    }

    pub fn protocol(&self) -> Protocol {
        self.protocol
    }

    /// Appends the sentences/messages of one epoch to `out`; on error `out` is unchanged.
    pub fn encode(&self, r: &GnssRecord, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        let reading = Reading::Gnss(gnss_fix(r));
        self.encoder.encode(&reading, &DeviceClock::default(), out)
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

/// A simulated epoch as the fix a receiver sends: NaN values absent, the geoid taken as the
/// ellipsoid (height above MSL = ellipsoidal height).
fn gnss_fix(r: &GnssRecord) -> GnssFix {
    let finite = |v: f64| v.is_finite().then_some(v);
    GnssFix {
        week: Some(r.week),
        tow_s: finite(r.tow_s),
        utc_ns: Some(r.utc_ns),
        lat_deg: finite(r.lat_deg),
        lon_deg: finite(r.lon_deg),
        height_m: finite(r.height_m),
        height_msl_m: finite(r.height_m),
        vel_ned: r.vel_ned.iter().all(|v| v.is_finite()).then_some(r.vel_ned),
        h_acc_m: finite(r.h_acc_m),
        v_acc_m: finite(r.v_acc_m),
        s_acc_mps: finite(r.s_acc_mps),
        fix: r.fix_type,
        num_sats: Some(r.num_sats),
        pdop: finite(r.pdop),
        hdop: finite(r.hdop),
        vdop: finite(r.vdop),
        ..GnssFix::default()
    }
}
