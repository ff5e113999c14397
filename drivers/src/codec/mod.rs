//! Sans-IO codecs: bytes in, typed frames out, and the reverse.
//!
//! Every protocol implements [`Decoder`] (push bytes, poll frames, read counters) and
//! [`Encoder`] (frame to bytes). Decoders never panic on any input, keep a bounded buffer
//! (the unconsumed tail of the last push plus at most one partial frame), resynchronise after
//! garbage and count what they skip in [`DecoderStats`].
//!
//! [`PROTOCOLS`] is the one protocol registry: a line per protocol with its name (in
//! configurations, `session.toml`, scenes and on the command line), what its readings are,
//! a detector for `auto`, its frames as JSON (`imulab decode`), its [`reading`] decoder (what
//! `imulogd` logs) and its reading encoder (what `imulab sim --serve` sends). The daemon, the
//! simulator and `imulab decode` all dispatch through it, so adding a protocol is one codec
//! module and one table line (`docs/protocols.md`, "Adding a protocol").

pub mod can;
pub mod candump;
pub mod csv_line;
pub mod cycle;
pub mod dbc;
pub mod gnss;
pub mod imu_line;
pub mod mip;
pub mod nmea;
pub mod reading;
pub mod slcan;
pub mod ubx;
pub mod vectornav;
pub mod witmotion;
pub mod xbus;

use crate::types::DecoderStats;
use reading::{
    byte_readings, gnss_encoder, imu_encoder, Kind, Link, ReadingDecoderFactory, ReadingEncoder,
};

/// A sans-IO decoder: feed bytes with [`push`](Decoder::push), then call
/// [`poll`](Decoder::poll) until it returns `None` before pushing again.
pub trait Decoder {
    /// What one decoded unit is (a sentence, a message, a sample).
    type Frame;
    /// Appends bytes read from the device. Never fails: bad bytes are skipped and counted
    /// when polled.
    fn push(&mut self, bytes: &[u8]);
    /// Returns the next complete frame, or `None` when the buffered bytes hold no complete
    /// frame any more.
    fn poll(&mut self) -> Option<Self::Frame>;
    /// Counters since construction.
    fn stats(&self) -> DecoderStats;

    /// Called once the input has ended: returns frames the decoder held back (e.g. a merged
    /// epoch waiting for its cycle to close). Call until `None`. Partial frames are dropped.
    fn finish(&mut self) -> Option<Self::Frame> {
        None
    }

    /// Pushes `bytes` and hands every frame they complete to `sink`.
    fn decode(&mut self, bytes: &[u8], mut sink: impl FnMut(Self::Frame))
    where
        Self: Sized,
    {
        self.push(bytes);
        while let Some(frame) = self.poll() {
            sink(frame);
        }
    }
}

/// Fewest valid frames that make a protocol a candidate for auto-detection.
pub const MIN_DETECT_FRAMES: u64 = 3;

/// Auto-detection score of a protocol: the frames its decoder accepts in `sample`, or 0
/// unless they make a confident match: at least [`MIN_DETECT_FRAMES`] checksummed frames,
/// more frames accepted than rejected, and at least half of the sample's bytes inside
/// accepted frames. Random bytes pass a one-byte checksum now and then (64 KiB of them held
/// 2 "Xbus frames" beside 260 rejected ones), never all three tests.
pub(crate) fn accepted_frames(mut decoder: impl Decoder, sample: &[u8]) -> u32 {
    decoder.decode(sample, |_| {});
    let s = decoder.stats();
    let rejected = s.checksum_errors + s.frames_malformed + s.frames_too_long;
    let confident = s.frames_ok >= MIN_DETECT_FRAMES
        && s.frames_ok > rejected
        && s.bytes_skipped.saturating_mul(2) <= sample.len() as u64;
    if confident {
        u32::try_from(s.frames_ok).unwrap_or(u32::MAX)
    } else {
        0
    }
}

/// Why a frame could not be encoded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EncodeError {
    /// A value does not fit the field's wire range or is not finite.
    #[error("field `{field}` = {value} cannot be encoded (out of range or not finite)")]
    OutOfRange { field: &'static str, value: f64 },
    /// The encoded frame would exceed the protocol's length limit.
    #[error("frame of {len} bytes exceeds the protocol limit of {max}")]
    TooLong { len: usize, max: usize },
    /// A field holds something the protocol cannot carry (e.g. a `*` in an NMEA field).
    #[error("field `{field}` is invalid: {reason}")]
    Invalid {
        field: &'static str,
        reason: &'static str,
    },
}

/// A sans-IO encoder: appends the wire bytes of one frame to `out`.
pub trait Encoder {
    type Frame;
    /// Appends the encoded frame to `out`. On error `out` is left as it was.
    fn encode(&self, frame: &Self::Frame, out: &mut Vec<u8>) -> Result<(), EncodeError>;
}

/// A decoder seen through JSON: what `imulab decode` and tools that do not care about the
/// concrete frame type use. Implemented for every [`Decoder`] whose frame is `Serialize`.
pub trait JsonDecoder: Send {
    fn push(&mut self, bytes: &[u8]);
    /// Writes the next frame as one JSON object (no newline) into `out`; `false` when none.
    fn next_json(&mut self, out: &mut Vec<u8>) -> bool;
    /// Like [`next_json`](JsonDecoder::next_json) for frames held back until the input ended.
    fn finish_json(&mut self, out: &mut Vec<u8>) -> bool;
    fn stats(&self) -> DecoderStats;
}

impl<D> JsonDecoder for D
where
    D: Decoder + Send,
    D::Frame: serde::Serialize,
{
    fn push(&mut self, bytes: &[u8]) {
        Decoder::push(self, bytes);
    }

    fn next_json(&mut self, out: &mut Vec<u8>) -> bool {
        let frame = Decoder::poll(self);
        write_json(frame, out)
    }

    fn finish_json(&mut self, out: &mut Vec<u8>) -> bool {
        let frame = Decoder::finish(self);
        write_json(frame, out)
    }

    fn stats(&self) -> DecoderStats {
        Decoder::stats(self)
    }
}

fn write_json<F: serde::Serialize>(frame: Option<F>, out: &mut Vec<u8>) -> bool {
    match frame {
        Some(frame) => {
            // Serialising our own frame types into a Vec cannot fail (no maps with non-string
            // keys, no I/O); keep going rather than panic if it ever did.
            if serde_json::to_writer(&mut *out, &frame).is_err() {
                out.extend_from_slice(b"{\"error\":\"frame not serialisable\"}");
            }
            true
        }
        None => false,
    }
}

/// Options a protocol may need to build its decoders and encoder. Codecs do no I/O: the
/// caller reads the files and passes their text.
#[derive(Debug, Clone, Default)]
pub struct DecoderOptions {
    /// DBC file for IMU-over-CAN protocols.
    pub dbc: Option<NamedText>,
    /// Protocol-specific configuration file (e.g. a CSV column map or a DBC signal map).
    pub config: Option<NamedText>,
    /// Rates or their integrals, for a device that sends both (VectorNav, MIP).
    pub rows_from: RowsFrom,
    /// What the encoder of a device that can send rates, their integrals or both
    /// (VectorNav, MIP) sends.
    pub imu_output: ImuOutput,
    /// For `gnss` and `ubx`: also yield the IMU samples of UBX ESF-RAW / ESF-MEAS (a
    /// dead-reckoning receiver's IMU on its GNSS port) beside the fixes.
    pub esf_imu: bool,
}

/// Where an IMU's gyro and accelerometer rows come from when the device sends both its rates
/// and their integrals (VectorNav, MIP): the rates, or delta theta / delta velocity over
/// their interval (which also hold the motion between two samples). Either way a device that
/// sends only one of them gives rows from it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RowsFrom {
    #[default]
    Rates,
    Deltas,
}

/// What a device that can send its rates and their integrals over the sample interval
/// (VectorNav, MIP) is set to output: the rates, delta theta / delta velocity, or both.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ImuOutput {
    #[default]
    Rates,
    Deltas,
    Both,
}

/// The text of a file the caller read, with the name its error messages use.
#[derive(Debug, Clone)]
pub struct NamedText {
    /// Where the text came from (a path), for messages.
    pub name: String,
    pub text: String,
}

/// Why a decoder could not be built from the options.
#[derive(Debug, thiserror::Error)]
#[error("protocol `{protocol}`: {reason}")]
pub struct OpenError {
    pub protocol: &'static str,
    pub reason: String,
}

/// The protocols the codecs understand, named as in [`PROTOCOLS`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Protocol {
    /// NMEA 0183 sentences only.
    Nmea,
    /// u-blox UBX binary messages only.
    Ubx,
    /// NMEA and UBX interleaved on one port, merged into navigation epochs.
    Gnss,
    /// The IMU of a u-blox dead-reckoning receiver: UBX ESF-RAW and ESF-MEAS.
    UbxEsf,
    /// WitMotion 0x55 packets, assembled into IMU samples.
    Wit,
    /// Xsens Xbus messages (MTData2 decoded).
    Xbus,
    /// ASCII/CSV lines with a configurable column map.
    Csv,
    /// slcan (Lawicel) ASCII CAN, optionally through a DBC to IMU samples.
    Slcan,
    /// candump log, optionally through a DBC to IMU samples.
    Candump,
    /// An IMU on a CAN bus: CAN frames through a DBC to IMU samples.
    CanDbc,
    /// VectorNav binary output packets and async ASCII sentences.
    Vectornav,
    /// MicroStrain MIP packets (IMU data set decoded).
    Mip,
    /// `$IMU` ASCII lines (NMEA-style checksum) from a microcontroller IMU.
    ImuLine,
}

/// Builds a decoder of JSON objects (`imulab decode`).
pub type OpenJson = fn(&DecoderOptions) -> Result<Box<dyn JsonDecoder>, OpenError>;
/// Builds the factory of a protocol's reading decoders (what `imulogd` logs).
pub type OpenReadings = fn(&DecoderOptions) -> Result<ReadingDecoderFactory, OpenError>;
/// Builds a protocol's reading encoder (what `imulab sim --serve` sends).
pub type OpenEncoder = fn(&DecoderOptions) -> Result<Box<dyn ReadingEncoder>, OpenError>;

/// One row of the protocol table: everything the daemon, the simulator and `imulab decode`
/// know of a protocol.
pub struct ProtocolEntry {
    pub protocol: Protocol,
    /// Name in configuration files, `session.toml`, scenes and on the command line.
    pub name: &'static str,
    pub summary: &'static str,
    /// What its readings are: IMU samples or GNSS fixes.
    pub kind: Kind,
    /// What its reading decoder takes: bytes or CAN frames.
    pub link: Link,
    /// Whether its readings need a DBC file and its signal mapping (`DecoderOptions::dbc`
    /// and `config`).
    pub dbc: bool,
    /// Score for auto-detection: number of valid frames found in a sample of the stream
    /// (0 = not this protocol).
    pub detect: fn(&[u8]) -> u32,
    /// Its frames as JSON objects; `None` when it is not a byte stream.
    pub json: Option<OpenJson>,
    /// Its readings.
    pub readings: OpenReadings,
    /// Its encoder of readings; `None` when the simulator does not serve it.
    pub encoder: Option<OpenEncoder>,
}

fn never(_: &[u8]) -> u32 {
    0
}

/// The protocol table, one line per protocol. Auto-detection prefers the highest score, and
/// the earlier line on a tie: a protocol whose frames another row's decoder also accepts
/// (`$IMU` lines are NMEA sentences to `gnss` and `nmea`) goes above that row.
#[rustfmt::skip]
pub const PROTOCOLS: &[ProtocolEntry] = &[
    ProtocolEntry { protocol: Protocol::ImuLine, name: "imu-line", summary: "$IMU,t,gx,gy,gz,ax,ay,az[,temp]*CS ASCII lines", kind: Kind::Imu, link: Link::Bytes, dbc: false, detect: imu_line::detect_score, json: Some(|_| Ok(Box::new(imu_line::ImuLineDecoder::new()))), readings: |_| Ok(byte_readings(imu_line::ImuLineDecoder::new)), encoder: Some(|_| Ok(imu_encoder(imu_line::encode_sample))) },
    ProtocolEntry { protocol: Protocol::Gnss, name: "gnss", summary: "NMEA 0183 + u-blox UBX mixed, with merged fixes", kind: Kind::Gnss, link: Link::Bytes, dbc: false, detect: gnss::detect_score, json: Some(|_| Ok(Box::new(gnss::GnssDecoder::new()))), readings: gnss::readings, encoder: Some(|_| Ok(gnss_encoder(gnss::encode_fix))) },
    ProtocolEntry { protocol: Protocol::UbxEsf, name: "ubx-esf", summary: "u-blox dead-reckoning receiver's IMU (UBX ESF-RAW, ESF-MEAS) as IMU samples", kind: Kind::Imu, link: Link::Bytes, dbc: false, detect: never, json: Some(|_| Ok(Box::new(gnss::EsfImuDecoder::new()))), readings: |_| Ok(byte_readings(gnss::EsfImuDecoder::new)), encoder: None },
    ProtocolEntry { protocol: Protocol::Vectornav, name: "vectornav", summary: "VectorNav VN-100/200/300 binary output and $VN ASCII sentences", kind: Kind::Imu, link: Link::Bytes, dbc: false, detect: vectornav::detect_score, json: Some(|_| Ok(Box::new(vectornav::VnDecoder::new()))), readings: |o| { let from = o.rows_from; Ok(byte_readings(move || vectornav::VnSamples::new(from))) }, encoder: Some(|o| { let output = o.imu_output; Ok(imu_encoder(move |s, c, out| vectornav::encode_output(s, c, output, out))) }) },
    ProtocolEntry { protocol: Protocol::Nmea, name: "nmea", summary: "NMEA 0183 sentences", kind: Kind::Gnss, link: Link::Bytes, dbc: false, detect: nmea::detect_score, json: Some(|_| Ok(Box::new(nmea::NmeaDecoder::new()))), readings: |_| Ok(byte_readings(gnss::GnssDecoder::new)), encoder: Some(|_| Ok(gnss_encoder(nmea::encode_fix))) },
    ProtocolEntry { protocol: Protocol::Ubx, name: "ubx", summary: "u-blox UBX binary messages", kind: Kind::Gnss, link: Link::Bytes, dbc: false, detect: ubx::detect_score, json: Some(|_| Ok(Box::new(ubx::UbxDecoder::new()))), readings: gnss::readings, encoder: Some(|_| Ok(gnss_encoder(ubx::encode_fix))) },
    ProtocolEntry { protocol: Protocol::Wit, name: "wit", summary: "WitMotion serial IMU (0x55 packets) as IMU samples", kind: Kind::Imu, link: Link::Bytes, dbc: false, detect: witmotion::detect_score, json: Some(|_| Ok(Box::new(witmotion::WitImuDecoder::new()))), readings: |_| Ok(byte_readings(witmotion::WitImuDecoder::new)), encoder: Some(|_| Ok(imu_encoder(witmotion::encode_sample))) },
    ProtocolEntry { protocol: Protocol::Xbus, name: "xbus", summary: "Xsens MTi Xbus messages, MTData2 decoded", kind: Kind::Imu, link: Link::Bytes, dbc: false, detect: xbus::detect_score, json: Some(|_| Ok(Box::new(xbus::XbusDecoder::new()))), readings: |_| Ok(byte_readings(xbus::XbusDecoder::new)), encoder: Some(|_| Ok(imu_encoder(xbus::encode_sample))) },
    ProtocolEntry { protocol: Protocol::Mip, name: "mip", summary: "MicroStrain MIP packets (3DM-GX5, CV7), IMU data set decoded", kind: Kind::Imu, link: Link::Bytes, dbc: false, detect: mip::detect_score, json: Some(|_| Ok(Box::new(mip::MipDecoder::new()))), readings: |o| { let from = o.rows_from; Ok(byte_readings(move || mip::MipSamples::new(from))) }, encoder: Some(|o| { let output = o.imu_output; Ok(imu_encoder(move |s, c, out| mip::encode_output(s, c, output, out))) }) },
    ProtocolEntry { protocol: Protocol::Csv, name: "csv", summary: "ASCII/CSV IMU lines (column map from --config)", kind: Kind::Imu, link: Link::Bytes, dbc: false, detect: never, json: Some(csv_line::open_json), readings: csv_line::readings, encoder: Some(csv_line::encoder) },
    ProtocolEntry { protocol: Protocol::Slcan, name: "slcan", summary: "slcan ASCII CAN (with --dbc and --config: IMU samples)", kind: Kind::Imu, link: Link::Bytes, dbc: true, detect: slcan::detect_score, json: Some(dbc::open_slcan_json), readings: dbc::slcan_readings, encoder: Some(dbc::slcan_encoder) },
    ProtocolEntry { protocol: Protocol::Candump, name: "candump", summary: "candump log (with --dbc and --config: IMU samples)", kind: Kind::Imu, link: Link::Bytes, dbc: true, detect: candump::detect_score, json: Some(dbc::open_candump_json), readings: dbc::candump_readings, encoder: None },
    ProtocolEntry { protocol: Protocol::CanDbc, name: "can-dbc", summary: "an IMU on a CAN bus (SocketCAN or an slcan adapter) through a DBC file", kind: Kind::Imu, link: Link::Can, dbc: true, detect: never, json: None, readings: dbc::can_readings, encoder: None },
];

/// A protocol name that is not in [`PROTOCOLS`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown protocol `{name}` (known: {known})")]
pub struct UnknownProtocol {
    pub name: String,
    pub known: String,
}

impl Protocol {
    /// Looks a protocol up by its table name (case-insensitive).
    pub fn from_name(name: &str) -> Result<Protocol, UnknownProtocol> {
        PROTOCOLS
            .iter()
            .find(|entry| entry.name.eq_ignore_ascii_case(name.trim()))
            .map(|entry| entry.protocol)
            .ok_or_else(|| UnknownProtocol {
                name: name.to_string(),
                known: PROTOCOLS
                    .iter()
                    .map(|entry| entry.name)
                    .collect::<Vec<_>>()
                    .join(", "),
            })
    }

    /// This protocol's row in [`PROTOCOLS`].
    pub fn entry(self) -> &'static ProtocolEntry {
        // A missing row is a programming error, caught by the test below, never input-driven.
        PROTOCOLS
            .iter()
            .find(|entry| entry.protocol == self)
            .expect("every Protocol variant has a row in PROTOCOLS")
    }

    pub fn name(self) -> &'static str {
        self.entry().name
    }

    pub fn kind(self) -> Kind {
        self.entry().kind
    }

    pub fn link(self) -> Link {
        self.entry().link
    }

    /// True for receivers (their readings are GNSS fixes); false for IMUs.
    pub fn is_gnss(self) -> bool {
        self.kind() == Kind::Gnss
    }

    /// True for protocols that arrive as CAN frames (SocketCAN or slcan) rather than bytes.
    pub fn is_can(self) -> bool {
        self.link() == Link::Can
    }

    /// Builds this protocol's decoder of JSON objects.
    pub fn open(self, options: &DecoderOptions) -> Result<Box<dyn JsonDecoder>, OpenError> {
        let entry = self.entry();
        let open = entry.json.ok_or_else(|| OpenError {
            protocol: entry.name,
            reason: "carries CAN frames, not bytes: decode its slcan or candump log with \
                     `slcan` or `candump` and --dbc"
                .into(),
        })?;
        open(options)
    }

    /// Builds the factory of this protocol's reading decoders, reading nothing: the files it
    /// needs are in `options`.
    pub fn readings(self, options: &DecoderOptions) -> Result<ReadingDecoderFactory, OpenError> {
        (self.entry().readings)(options)
    }

    /// Builds this protocol's encoder of readings.
    pub fn encoder(self, options: &DecoderOptions) -> Result<Box<dyn ReadingEncoder>, OpenError> {
        let entry = self.entry();
        let open = entry.encoder.ok_or_else(|| OpenError {
            protocol: entry.name,
            reason: "has no encoder of readings (the simulator does not serve it)".into(),
        })?;
        open(options)
    }
}

/// Guesses the protocol of a stream from a sample of its first bytes (a few kB is plenty).
/// Returns `None` when no protocol makes a confident match (see `accepted_frames`).
pub fn detect(sample: &[u8]) -> Option<Protocol> {
    let mut best: Option<(u32, Protocol)> = None;
    for entry in PROTOCOLS {
        let score = (entry.detect)(sample);
        if score > 0 && best.is_none_or(|(best_score, _)| score > best_score) {
            best = Some((score, entry.protocol));
        }
    }
    best.map(|(_, protocol)| protocol)
}

/// What scanning the bytes at a frame start found.
#[derive(Debug)]
pub(crate) enum Scan<F> {
    /// Not enough bytes yet.
    Incomplete,
    /// A frame of `len` bytes.
    Frame { len: usize, frame: F },
    /// Drop `len` bytes (≥ 1) and count `reject`.
    Reject { len: usize, reject: Reject },
}

/// Why bytes were rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Reject {
    Checksum,
    TooLong,
    /// Framing broken (missing checksum, noise inside a frame, a line that does not parse).
    Malformed,
    /// Framing and checksum were right but the content is unusable (e.g. an NMEA field that
    /// does not parse): counted as malformed, but the decoder stays in sync.
    BadContent,
    /// Not a frame start after all (e.g. 0xB5 not followed by 0x62): plain garbage.
    NoSync,
}

/// Which bytes a stream may carry between frames without them counting as garbage.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Filler {
    /// Binary protocols: every byte outside a frame is garbage.
    #[default]
    None,
    /// Text protocols (NMEA, CSV lines, slcan, candump): CR and LF are line framing.
    LineEnds,
}

/// The byte buffer behind every streaming decoder, with its counters and the one resync rule
/// all decoders share (documented in `docs/protocols.md`, "Resynchronisation"):
///
/// - Every input byte ends up in exactly one place: an accepted frame (`frames_ok`), filler
///   the format allows between frames (CR/LF in text protocols, blank and comment lines where
///   the format has them), `bytes_skipped`, or the buffer (an unfinished frame). So the bytes
///   of a rejected frame are skipped bytes too, and the reason (`checksum_errors`,
///   `frames_too_long`, `frames_malformed`) is counted once per rejected frame.
/// - A decoder starts out of sync. Garbage before the first frame is skipped but is no
///   resync (a port opened mid-frame is normal). `resyncs` counts the times a decoder that
///   had accepted a frame dropped bytes it could not frame (garbage or a rejected frame); the
///   next accepted frame puts it back in sync. A frame whose checksum matched but whose
///   content is unusable is dropped without losing sync.
/// - Appended at the back, consumed at the front, compacted so it never holds more than the
///   unconsumed bytes.
#[derive(Debug, Default, Clone)]
pub struct StreamBuffer {
    bytes: Vec<u8>,
    start: usize,
    stats: DecoderStats,
    synced: bool,
    filler: Filler,
}

impl StreamBuffer {
    /// A buffer for a binary protocol.
    pub fn new() -> Self {
        Self::default()
    }

    /// A buffer for a text protocol: CR and LF outside frames are framing, not garbage.
    pub fn text() -> Self {
        StreamBuffer {
            filler: Filler::LineEnds,
            ..Self::default()
        }
    }

    /// Appends bytes, first dropping the consumed front when that frees enough room.
    pub fn push(&mut self, bytes: &[u8]) {
        if self.start == self.bytes.len() {
            self.bytes.clear();
            self.start = 0;
        } else if self.start > 0 && self.start >= self.bytes.len() / 2 {
            self.bytes.drain(..self.start);
            self.start = 0;
        }
        self.bytes.extend_from_slice(bytes);
    }

    /// The unconsumed bytes.
    pub fn data(&self) -> &[u8] {
        &self.bytes[self.start..]
    }

    pub fn len(&self) -> usize {
        self.bytes.len() - self.start
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Counters since construction.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Consumes `n` bytes (clamped to what is there) and returns them.
    fn consume(&mut self, n: usize) -> &[u8] {
        let from = self.start;
        self.start = (self.start + n).min(self.bytes.len());
        &self.bytes[from..self.start]
    }

    /// The first `len` bytes were a frame, handed out: counted, and the decoder is in sync.
    pub(crate) fn accept(&mut self, len: usize) {
        self.consume(len);
        self.stats.frames_ok += 1;
        self.synced = true;
    }

    /// Drops the bytes before the first one that may start a frame (one of `starts`), all of
    /// them when there is none; returns whether a frame may start at the front now. The
    /// search every decoder with start bytes makes before it tries a frame. In sync the next
    /// frame starts right at the front, so that is looked at before searching. Inlined so
    /// that the match on `starts` folds away in each decoder's poll loop.
    #[inline]
    pub(crate) fn skip_to_start(&mut self, starts: &[u8]) -> bool {
        let data = self.data();
        let found = match (starts, data.first()) {
            (_, Some(first)) if starts.contains(first) => Some(0),
            (&[a], _) => memchr::memchr(a, data),
            (&[a, b], _) => memchr::memchr2(a, b, data),
            (&[a, b, c], _) => memchr::memchr3(a, b, c, data),
            _ => data.iter().position(|b| starts.contains(b)),
        };
        let skipped = found.unwrap_or(data.len());
        self.skip(skipped);
        found.is_some()
    }

    /// The next frame of a protocol whose frames begin with one of `starts` and that `scan`
    /// frames: garbage before a start is skipped, a rejected frame counted and dropped.
    pub(crate) fn next_scanned<F>(
        &mut self,
        starts: &[u8],
        scan: impl Fn(&[u8]) -> Scan<F>,
    ) -> Option<F> {
        loop {
            if !self.skip_to_start(starts) {
                return None;
            }
            match scan(self.data()) {
                Scan::Incomplete => return None,
                Scan::Frame { len, frame } => {
                    self.accept(len);
                    return Some(frame);
                }
                Scan::Reject { len, reject } => self.reject(len, reject),
            }
        }
    }

    /// The length of the next complete `\n`-terminated line of at most `max_len` bytes (without
    /// the `\n`), for the line protocols; `None` until one is there. A longer line is rejected
    /// as too long: counted once, as soon as it is known, and its bytes skipped as they
    /// arrive, with `discarding` (the decoder's, kept between calls) set until its end.
    #[inline]
    pub(crate) fn next_line(&mut self, max_len: usize, discarding: &mut bool) -> Option<usize> {
        loop {
            let data = self.data();
            let newline = memchr::memchr(b'\n', data);
            if *discarding {
                let n = newline.map_or(data.len(), |pos| pos + 1);
                self.skip(n);
                newline?;
                *discarding = false;
                continue;
            }
            let Some(pos) = newline else {
                if data.len() > max_len {
                    self.reject(0, Reject::TooLong);
                    *discarding = true;
                    continue;
                }
                return None;
            };
            if pos > max_len {
                self.reject(pos + 1, Reject::TooLong);
                continue;
            }
            return Some(pos);
        }
    }

    /// Drops `len` bytes that belong to no frame. Filler is not counted and does not
    /// break sync; anything else is `bytes_skipped` and loses sync.
    pub(crate) fn skip(&mut self, len: usize) {
        if self.count_skipped(len) > 0 {
            self.lose_sync();
        }
    }

    /// Drops `len` bytes, adds those that are not filler to `bytes_skipped` and returns
    /// how many that was.
    fn count_skipped(&mut self, len: usize) -> usize {
        let filler = self.filler;
        let dropped = self.consume(len);
        let garbage = match filler {
            Filler::None => dropped.len(),
            Filler::LineEnds => dropped
                .iter()
                .filter(|&&b| b != b'\r' && b != b'\n')
                .count(),
        };
        self.stats.bytes_skipped += garbage as u64;
        garbage
    }

    /// Drops the first `len` bytes (may be 0 when a too-long frame's bytes are skipped as
    /// they arrive) of a frame rejected for `reason`: counts the reason, skips the bytes and,
    /// unless only the content was bad, loses sync.
    pub(crate) fn reject(&mut self, len: usize, reason: Reject) {
        match reason {
            Reject::Checksum => self.stats.checksum_errors += 1,
            Reject::TooLong => self.stats.frames_too_long += 1,
            Reject::Malformed | Reject::BadContent => self.stats.frames_malformed += 1,
            Reject::NoSync => {}
        }
        self.count_skipped(len);
        if reason != Reject::BadContent {
            self.lose_sync();
        }
    }

    /// Drops `len` bytes the format allows between frames (blank or comment lines): neither
    /// a frame nor garbage.
    pub(crate) fn pass(&mut self, len: usize) {
        self.consume(len);
    }

    fn lose_sync(&mut self) {
        if self.synced {
            self.stats.resyncs += 1;
            self.synced = false;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bytes of a xorshift64 generator (deterministic noise, as a wrong baud rate gives).
    fn noise(len: usize, mut seed: u64) -> Vec<u8> {
        (0..len)
            .map(|_| {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                (seed >> 24) as u8
            })
            .collect()
    }

    #[test]
    fn random_bytes_are_never_detected() {
        for seed in 1..=200u64 {
            for len in [256, 4096, 16 * 1024, 64 * 1024] {
                let sample = noise(len, seed.wrapping_mul(0x9e37_79b9_7f4a_7c15));
                assert_eq!(detect(&sample), None, "seed {seed}, {len} bytes");
            }
        }
    }

    #[test]
    fn every_protocol_has_a_table_row_and_name_round_trips() {
        for entry in PROTOCOLS {
            assert_eq!(Protocol::from_name(entry.name), Ok(entry.protocol));
            assert_eq!(entry.protocol.name(), entry.name);
        }
        assert!(Protocol::from_name("NMEA").is_ok());
        let err = Protocol::from_name("foo").unwrap_err();
        assert!(err.to_string().contains("nmea"), "{err}");
    }

    #[test]
    fn stream_buffer_consumes_and_compacts() {
        let mut buf = StreamBuffer::new();
        buf.push(b"abcdef");
        buf.accept(4);
        assert_eq!(buf.data(), b"ef");
        buf.push(b"gh");
        assert_eq!(buf.data(), b"efgh");
        buf.pass(100);
        assert!(buf.is_empty());
    }

    #[test]
    fn resync_rule_counts() {
        let mut buf = StreamBuffer::text();
        buf.push(b"xx\r\nFRAME\r\nyyBADZFRAME\n");
        // Garbage before the first frame: skipped, no resync; line ends are filler.
        buf.skip(4);
        buf.accept(5);
        buf.skip(2);
        assert_eq!((buf.stats().bytes_skipped, buf.stats().resyncs), (2, 0));
        // Garbage after a frame: one resync for the whole run, rejected frame included.
        buf.skip(2);
        buf.reject(3, Reject::Checksum);
        let s = buf.stats();
        assert_eq!((s.bytes_skipped, s.resyncs, s.checksum_errors), (7, 1, 1));
        // A frame with bad content after a good one: counted and skipped, sync kept.
        buf.pass(1);
        buf.accept(5);
        buf.push(b"BAD");
        buf.pass(1);
        buf.reject(3, Reject::BadContent);
        let s = buf.stats();
        assert_eq!((s.bytes_skipped, s.resyncs, s.frames_malformed), (10, 1, 1));
        assert_eq!(s.frames_ok, 2);
    }
}

#[cfg(test)]
mod resync_tests;
