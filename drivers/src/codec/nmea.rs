//! NMEA 0183 (up to 4.11) sentence codec: GGA, RMC, GSA, GSV, VTG, ZDA, GST, GNS, HDT and GLL from
//! any talker; proprietary `$P…` and every other sentence kept raw.
//!
//! Numbers are kept as exact decimals ([`Decimal`]) so the text a receiver sent is recoverable
//! and encode → decode is the identity. In JSON every value is SI: lat/lon in signed degrees,
//! time of day in seconds, lengths in m, speeds in m/s (`speed_mps`, converted from the
//! sentence's knots or km/h), angles in degrees; and every sentence carries its own text in
//! `raw` (re-encoded, so field for field what the receiver sent), from which the original
//! units are recoverable.
//!
//! Framing rule (documented in `docs/protocols.md`): a sentence starts at `$` or `!` and ends
//! at `*hh` (hex checksum, either case); the line end after it may be CRLF, LF or absent.
//! - No `*hh` before CR/LF: rejected as malformed (missing checksum), skipped through the line end.
//! - A byte outside printable ASCII, or a new `$`/`!`, before the checksum: rejected as
//!   malformed; decoding resumes *at* that byte (it may start a UBX frame or a new sentence).
//! - Longer than [`MAX_SENTENCE_LEN`] (talker sentences) or [`MAX_PROPRIETARY_LEN`] (`$P…`)
//!   bytes from `$` to the checksum: rejected as too long; decoding resumes after the `$`.
//! - Bad checksum: counted, skipped through the checksum.
//! - Checksum fine but a known sentence's field is unparsable: counted as malformed, dropped
//!   without losing sync (exception: an invalid RMC date becomes `None`, keeping the fix).
//!
//! Counting (skipped bytes, resyncs) follows the one rule of [`StreamBuffer`]; CR and LF
//! between sentences are framing, not garbage.

use std::fmt;
use std::io::Write as _;

use serde::{Serialize, Serializer};

use super::{accepted_frames, Decoder, EncodeError, Encoder, Reject, Scan, StreamBuffer};
use crate::types::{DecoderStats, FixType, GnssFix};

/// Longest talker sentence accepted, from `$` to the last checksum digit. The standard says
/// 82 with CRLF; real receivers exceed it (114-byte GSV lines occur in the gpsd captures),
/// so we allow 128 and reject beyond.
pub const MAX_SENTENCE_LEN: usize = 128;
/// Longest proprietary (`$P…`) sentence accepted (MediaTek and SiRF emit ~200-byte ones).
pub const MAX_PROPRIETARY_LEN: usize = 256;

const POW10: [f64; 19] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18,
];
pub(crate) const KNOT_MPS: f64 = 1852.0 / 3600.0;

/// An exact decimal as written in a sentence: `mantissa / 10^scale`. Serialises as a number.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Decimal {
    pub mantissa: i64,
    /// Digits after the decimal point (0..=18).
    pub scale: u8,
}

impl Decimal {
    pub fn new(mantissa: i64, scale: u8) -> Self {
        Decimal {
            mantissa,
            scale: scale.min(18),
        }
    }

    /// The value as f64 (correctly rounded: both operands are exact in f64 up to 2^53).
    pub fn to_f64(self) -> f64 {
        self.mantissa as f64 / POW10[usize::from(self.scale.min(18))]
    }

    /// Parses `[-+]digits[.digits]` (at most 18 significant digits, i.e. after leading
    /// zeros, and at most 18 after the point). `None` for anything else. Leading zeros do
    /// not count, so `.123…` and the `0.123…` it is written back as parse alike.
    pub fn parse(text: &[u8]) -> Option<Decimal> {
        let (negative, digits) = match text.first()? {
            b'-' => (true, &text[1..]),
            b'+' => (false, &text[1..]),
            _ => (false, text),
        };
        let mut mantissa: i64 = 0;
        let mut scale: u8 = 0;
        let mut seen_point = false;
        let mut n_digits = 0u32;
        let mut significant = 0u32;
        for &b in digits {
            match b {
                b'0'..=b'9' => {
                    n_digits += 1;
                    if mantissa != 0 || b != b'0' {
                        significant += 1;
                    }
                    if significant > 18 {
                        return None;
                    }
                    mantissa = mantissa * 10 + i64::from(b - b'0');
                    if seen_point {
                        scale += 1;
                        if scale > 18 {
                            return None;
                        }
                    }
                }
                b'.' if !seen_point => seen_point = true,
                _ => return None,
            }
        }
        if n_digits == 0 {
            return None;
        }
        Some(Decimal {
            mantissa: if negative { -mantissa } else { mantissa },
            scale,
        })
    }

    /// Writes the decimal with at least `min_int_digits` integer digits (zero padded).
    fn write_padded(self, min_int_digits: usize, out: &mut Vec<u8>) {
        // A scale above 18 cannot come from parsing; clamp rather than overflow.
        let scale = u32::from(self.scale.min(18));
        let abs = self.mantissa.unsigned_abs();
        let divisor = 10u64.pow(scale);
        if self.mantissa < 0 {
            out.push(b'-');
        }
        let _ = write!(out, "{:0width$}", abs / divisor, width = min_int_digits);
        if scale > 0 {
            let _ = write!(out, ".{:0width$}", abs % divisor, width = scale as usize);
        }
    }
}

impl Serialize for Decimal {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_f64(self.to_f64())
    }
}

impl fmt::Display for Decimal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut buf = Vec::new();
        self.write_padded(1, &mut buf);
        f.write_str(&String::from_utf8_lossy(&buf))
    }
}

/// A latitude or longitude as sent: `(d)ddmm.mmmm` plus hemisphere letter.
/// Serialises as signed degrees (north and east positive).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Coordinate {
    /// Degrees × 100 + minutes, exactly as written.
    pub ddmm: Decimal,
    /// `N`, `S`, `E` or `W`.
    pub hemisphere: char,
}

impl Coordinate {
    /// Signed degrees (S and W negative).
    pub fn degrees(self) -> f64 {
        let scale = u32::from(self.ddmm.scale.min(18));
        // i128: 100 × 10^18 does not fit i64.
        let unit = 100 * 10i128.pow(scale);
        let abs = i128::from(self.ddmm.mantissa.unsigned_abs());
        let whole_degrees = (abs / unit) as f64;
        let minutes = (abs % unit) as f64 / POW10[scale as usize];
        let magnitude = whole_degrees + minutes / 60.0;
        let sign = if self.ddmm.mantissa < 0 { -1.0 } else { 1.0 };
        match self.hemisphere {
            'S' | 'W' => -sign * magnitude,
            _ => sign * magnitude,
        }
    }
}

impl Serialize for Coordinate {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_f64(self.degrees())
    }
}

/// UTC time of day `hhmmss[.ss]`. Serialises as seconds since midnight.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimeOfDay {
    pub hour: u8,
    pub minute: u8,
    /// Seconds including the fraction, exactly as written (0 ≤ s < 61).
    pub second: Decimal,
}

impl TimeOfDay {
    pub fn seconds_of_day(self) -> f64 {
        f64::from(self.hour) * 3600.0 + f64::from(self.minute) * 60.0 + self.second.to_f64()
    }

    /// Milliseconds since midnight, rounded (the key `GnssDecoder` merges epochs by).
    pub fn millis_of_day(self) -> i64 {
        let scale = self.second.scale.min(18);
        let second_ms = if scale <= 3 {
            self.second.mantissa * 10i64.pow(3 - u32::from(scale))
        } else {
            let div = 10i64.pow(u32::from(scale) - 3);
            (self.second.mantissa + div / 2) / div
        };
        (i64::from(self.hour) * 3600 + i64::from(self.minute) * 60) * 1000 + second_ms
    }

    fn parse(text: &[u8]) -> Option<TimeOfDay> {
        if text.len() < 6 || !text[..4].iter().all(u8::is_ascii_digit) {
            return None;
        }
        let hour = (text[0] - b'0') * 10 + (text[1] - b'0');
        let minute = (text[2] - b'0') * 10 + (text[3] - b'0');
        let second = Decimal::parse(&text[4..])?;
        let valid = hour < 24
            && minute < 60
            && second.mantissa >= 0
            && second.to_f64() < 61.0
            && text[4].is_ascii_digit()
            && text[5].is_ascii_digit();
        valid.then_some(TimeOfDay {
            hour,
            minute,
            second,
        })
    }

    fn write(self, out: &mut Vec<u8>) {
        let _ = write!(out, "{:02}{:02}", self.hour, self.minute);
        self.second.write_padded(2, out);
    }
}

impl Serialize for TimeOfDay {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_f64(self.seconds_of_day())
    }
}

/// A calendar date (RMC's two-digit year is read as 1980–2079).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Date {
    pub year: u16,
    pub month: u8,
    pub day: u8,
}

/// Talker identifier (`GP`, `GN`, `GL`, `GA`, `GB`, `GQ`, `BD`, …). Serialises as a string.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Talker(pub [u8; 2]);

impl Talker {
    pub fn as_str(&self) -> &str {
        std::str::from_utf8(&self.0).unwrap_or("??")
    }
}

impl Serialize for Talker {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

/// GGA: time, position, fix quality.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Gga {
    pub talker: Talker,
    pub time: Option<TimeOfDay>,
    pub lat: Option<Coordinate>,
    pub lon: Option<Coordinate>,
    /// 0 invalid, 1 GPS, 2 DGPS, 3 PPS, 4 RTK fixed, 5 RTK float, 6 dead reckoning, 7 manual, 8 simulator.
    pub quality: Option<u8>,
    pub num_sats: Option<u8>,
    pub hdop: Option<Decimal>,
    /// Altitude above mean sea level, m.
    pub alt_msl_m: Option<Decimal>,
    /// Geoid separation (ellipsoid − MSL), m.
    pub geoid_sep_m: Option<Decimal>,
    pub dgps_age_s: Option<Decimal>,
    pub dgps_station: Option<u16>,
}

/// RMC: recommended minimum (time, date, position, speed, track). JSON has the speed in
/// m/s (`speed_mps`), see [`RmcJson`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(into = "RmcJson")]
pub struct Rmc {
    pub talker: Talker,
    pub time: Option<TimeOfDay>,
    /// `A` valid, `V` warning.
    pub status: Option<char>,
    pub lat: Option<Coordinate>,
    pub lon: Option<Coordinate>,
    pub speed_knots: Option<Decimal>,
    pub track_deg: Option<Decimal>,
    pub date: Option<Date>,
    /// Magnetic variation, degrees, with `E`/`W`.
    pub mag_var_deg: Option<Decimal>,
    pub mag_var_dir: Option<char>,
    /// NMEA 2.3 mode indicator (`A`, `D`, `E`, `N`, …).
    pub mode: Option<char>,
    /// NMEA 4.1 navigational status.
    pub nav_status: Option<char>,
}

/// GSA: fix mode, satellites used, DOPs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Gsa {
    pub talker: Talker,
    /// `M` manual, `A` automatic.
    pub selection: Option<char>,
    /// 1 no fix, 2 2D, 3 3D.
    pub fix_mode: Option<u8>,
    pub sat_ids: [Option<u16>; 12],
    pub pdop: Option<Decimal>,
    pub hdop: Option<Decimal>,
    pub vdop: Option<Decimal>,
    /// NMEA 4.1 GNSS system id (some receivers write a decimal here).
    pub system_id: Option<Decimal>,
}

/// One satellite in a GSV sentence.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SatInView {
    pub prn: u16,
    pub elevation_deg: Option<Decimal>,
    pub azimuth_deg: Option<Decimal>,
    pub snr_dbhz: Option<Decimal>,
}

/// GSV: satellites in view (up to four per sentence).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Gsv {
    pub talker: Talker,
    pub total_msgs: u8,
    pub msg_num: u8,
    pub sats_in_view: Option<u16>,
    pub sats: [Option<SatInView>; 4],
    /// NMEA 4.1 signal id (one hex digit).
    pub signal_id: Option<char>,
}

/// VTG: track and ground speed. JSON has the speed in m/s (`speed_mps`), see [`VtgJson`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(into = "VtgJson")]
pub struct Vtg {
    pub talker: Talker,
    pub track_true_deg: Option<Decimal>,
    pub track_mag_deg: Option<Decimal>,
    pub speed_knots: Option<Decimal>,
    pub speed_kmh: Option<Decimal>,
    pub mode: Option<char>,
}

/// ZDA: UTC date and time, local zone.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Zda {
    pub talker: Talker,
    pub time: Option<TimeOfDay>,
    pub day: Option<u8>,
    pub month: Option<u8>,
    pub year: Option<u16>,
    pub zone_hours: Option<i8>,
    pub zone_minutes: Option<u8>,
}

/// GST: pseudorange noise statistics (1σ position errors, m).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Gst {
    pub talker: Talker,
    pub time: Option<TimeOfDay>,
    pub rms: Option<Decimal>,
    pub major_m: Option<Decimal>,
    pub minor_m: Option<Decimal>,
    pub orientation_deg: Option<Decimal>,
    pub lat_sigma_m: Option<Decimal>,
    pub lon_sigma_m: Option<Decimal>,
    pub alt_sigma_m: Option<Decimal>,
}

/// Mode letters of a GNS sentence, one per constellation (at most 8 kept).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ModeLetters {
    pub letters: [u8; 8],
    pub len: u8,
}

impl ModeLetters {
    pub fn as_str(&self) -> &str {
        std::str::from_utf8(&self.letters[..usize::from(self.len.min(8))]).unwrap_or("")
    }
}

impl Serialize for ModeLetters {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

/// GNS: multi-constellation fix data.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Gns {
    pub talker: Talker,
    pub time: Option<TimeOfDay>,
    pub lat: Option<Coordinate>,
    pub lon: Option<Coordinate>,
    pub mode: ModeLetters,
    pub num_sats: Option<u8>,
    pub hdop: Option<Decimal>,
    pub alt_msl_m: Option<Decimal>,
    pub geoid_sep_m: Option<Decimal>,
    pub dgps_age_s: Option<Decimal>,
    pub dgps_station: Option<u16>,
    pub nav_status: Option<char>,
}

/// GLL: geographic position, time and status.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Gll {
    pub talker: Talker,
    pub lat: Option<Coordinate>,
    pub lon: Option<Coordinate>,
    pub time: Option<TimeOfDay>,
    /// `A` valid, `V` invalid.
    pub status: Option<char>,
    /// NMEA 2.3 mode indicator.
    pub mode: Option<char>,
}

/// HDT: true heading.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Hdt {
    pub talker: Talker,
    pub heading_deg: Option<Decimal>,
}

/// A sentence kept as text: proprietary `$P…` or one this codec does not interpret.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct RawSentence {
    /// `$` or `!`.
    pub start: char,
    /// Everything between the start character and `*` (address and fields).
    pub body: String,
}

/// One decoded sentence. Serialises as its fields with a `sentence` tag plus `raw`, the
/// sentence's text (see the module docs).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(into = "SentenceJson")]
pub enum NmeaSentence {
    Gga(Gga),
    Rmc(Rmc),
    Gsa(Gsa),
    Gsv(Gsv),
    Vtg(Vtg),
    Zda(Zda),
    Gst(Gst),
    Gns(Gns),
    Hdt(Hdt),
    Gll(Gll),
    Proprietary(RawSentence),
    Other(RawSentence),
}

/// The JSON form of [`Rmc`]: the same fields with the speed in m/s instead of knots.
#[derive(Serialize)]
pub struct RmcJson {
    pub talker: Talker,
    pub time: Option<TimeOfDay>,
    pub status: Option<char>,
    pub lat: Option<Coordinate>,
    pub lon: Option<Coordinate>,
    pub speed_mps: Option<f64>,
    pub track_deg: Option<Decimal>,
    pub date: Option<Date>,
    pub mag_var_deg: Option<Decimal>,
    pub mag_var_dir: Option<char>,
    pub mode: Option<char>,
    pub nav_status: Option<char>,
}

impl From<Rmc> for RmcJson {
    fn from(s: Rmc) -> Self {
        RmcJson {
            talker: s.talker,
            time: s.time,
            status: s.status,
            lat: s.lat,
            lon: s.lon,
            speed_mps: s.speed_mps(),
            track_deg: s.track_deg,
            date: s.date,
            mag_var_deg: s.mag_var_deg,
            mag_var_dir: s.mag_var_dir,
            mode: s.mode,
            nav_status: s.nav_status,
        }
    }
}

/// The JSON form of [`Vtg`]: one speed in m/s (from knots, else km/h) instead of both.
#[derive(Serialize)]
pub struct VtgJson {
    pub talker: Talker,
    pub track_true_deg: Option<Decimal>,
    pub track_mag_deg: Option<Decimal>,
    pub speed_mps: Option<f64>,
    pub mode: Option<char>,
}

impl From<Vtg> for VtgJson {
    fn from(s: Vtg) -> Self {
        VtgJson {
            talker: s.talker,
            track_true_deg: s.track_true_deg,
            track_mag_deg: s.track_mag_deg,
            speed_mps: s.speed_mps(),
            mode: s.mode,
        }
    }
}

/// The JSON form of [`NmeaSentence`]: its fields (tagged with `sentence`) plus `raw`.
#[derive(Serialize)]
struct SentenceJson {
    #[serde(flatten)]
    fields: SentenceFields,
    /// The sentence as text, `$…*hh` without the line end.
    raw: String,
}

/// [`NmeaSentence`]'s fields under their `sentence` tag (the enum itself serialises through
/// `into`, so its variants are listed again here with their JSON names).
#[derive(Serialize)]
#[serde(tag = "sentence")]
enum SentenceFields {
    #[serde(rename = "GGA")]
    Gga(Gga),
    #[serde(rename = "RMC")]
    Rmc(Rmc),
    #[serde(rename = "GSA")]
    Gsa(Gsa),
    #[serde(rename = "GSV")]
    Gsv(Gsv),
    #[serde(rename = "VTG")]
    Vtg(Vtg),
    #[serde(rename = "ZDA")]
    Zda(Zda),
    #[serde(rename = "GST")]
    Gst(Gst),
    #[serde(rename = "GNS")]
    Gns(Gns),
    #[serde(rename = "HDT")]
    Hdt(Hdt),
    #[serde(rename = "GLL")]
    Gll(Gll),
    #[serde(rename = "proprietary")]
    Proprietary(RawSentence),
    #[serde(rename = "other")]
    Other(RawSentence),
}

impl From<NmeaSentence> for SentenceJson {
    fn from(sentence: NmeaSentence) -> Self {
        let mut text = Vec::new();
        // A decoded sentence always re-encodes (encode → decode is the identity); should it
        // ever fail, `raw` is left empty rather than failing the whole JSON line.
        let _ = NmeaEncoder.encode(&sentence, &mut text);
        while text.last().is_some_and(|b| *b == b'\r' || *b == b'\n') {
            text.pop();
        }
        let fields = match sentence {
            NmeaSentence::Gga(s) => SentenceFields::Gga(s),
            NmeaSentence::Rmc(s) => SentenceFields::Rmc(s),
            NmeaSentence::Gsa(s) => SentenceFields::Gsa(s),
            NmeaSentence::Gsv(s) => SentenceFields::Gsv(s),
            NmeaSentence::Vtg(s) => SentenceFields::Vtg(s),
            NmeaSentence::Zda(s) => SentenceFields::Zda(s),
            NmeaSentence::Gst(s) => SentenceFields::Gst(s),
            NmeaSentence::Gns(s) => SentenceFields::Gns(s),
            NmeaSentence::Hdt(s) => SentenceFields::Hdt(s),
            NmeaSentence::Gll(s) => SentenceFields::Gll(s),
            NmeaSentence::Proprietary(s) => SentenceFields::Proprietary(s),
            NmeaSentence::Other(s) => SentenceFields::Other(s),
        };
        SentenceJson {
            fields,
            raw: String::from_utf8_lossy(&text).into_owned(),
        }
    }
}

impl Rmc {
    pub fn speed_mps(&self) -> Option<f64> {
        self.speed_knots.map(|k| k.to_f64() * KNOT_MPS)
    }
}

impl Vtg {
    pub fn speed_mps(&self) -> Option<f64> {
        self.speed_knots
            .map(|k| k.to_f64() * KNOT_MPS)
            .or(self.speed_kmh.map(|k| k.to_f64() / 3.6))
    }
}

fn hex_value(b: u8) -> Option<u8> {
    match b {
        b'0'..=b'9' => Some(b - b'0'),
        b'a'..=b'f' => Some(b - b'a' + 10),
        b'A'..=b'F' => Some(b - b'A' + 10),
        _ => None,
    }
}

/// Scans one sentence at `buf[0]` (which must be `$` or `!`).
pub(crate) fn scan_sentence(buf: &[u8]) -> Scan<NmeaSentence> {
    let proprietary = buf.get(1) == Some(&b'P');
    let limit = if proprietary {
        MAX_PROPRIETARY_LEN
    } else {
        MAX_SENTENCE_LEN
    };
    // The checksum star may sit at most at limit − 3 (star plus two hex digits).
    let region = buf.get(1..buf.len().min(limit - 2)).unwrap_or(&[]);
    let stop = memchr::memchr3(b'*', b'\r', b'\n', region);
    let body = &region[..stop.unwrap_or(region.len())];
    // Non-printable bytes or a new start character before the stop: binary noise. The
    // branch-free fold vectorises; the exact position is only looked up when needed.
    let is_noise = |b: u8| b.wrapping_sub(0x20) > 0x5e || b == b'$' || b == b'!';
    if body.iter().fold(false, |acc, &b| acc | is_noise(b)) {
        let at = body.iter().position(|&b| is_noise(b)).unwrap_or(0);
        return Scan::Reject {
            len: 1 + at,
            reject: Reject::Malformed,
        };
    }
    let Some(stop) = stop else {
        return if buf.len() < limit - 2 {
            Scan::Incomplete
        } else {
            Scan::Reject {
                len: 1,
                reject: Reject::TooLong,
            }
        };
    };
    let i = 1 + stop;
    if buf[i] != b'*' {
        // CR or LF before any checksum.
        return Scan::Reject {
            len: i + 1,
            reject: Reject::Malformed,
        };
    }
    if buf.len() < i + 3 {
        return Scan::Incomplete;
    }
    let len = i + 3;
    let given = match (hex_value(buf[i + 1]), hex_value(buf[i + 2])) {
        (Some(h), Some(l)) => (h << 4) | l,
        _ => {
            return Scan::Reject {
                len: i + 1,
                reject: Reject::Malformed,
            }
        }
    };
    let checksum = body.iter().fold(0u8, |acc, &b| acc ^ b);
    if given != checksum {
        return Scan::Reject {
            len,
            reject: Reject::Checksum,
        };
    }
    match parse_body(buf[0], body) {
        Some(frame) => Scan::Frame { len, frame },
        None => Scan::Reject {
            len,
            reject: Reject::BadContent,
        },
    }
}

/// Comma-separated fields; past the end every field is empty.
struct Fields<'a> {
    rest: Option<&'a [u8]>,
}

impl<'a> Fields<'a> {
    fn new(text: &'a [u8]) -> Self {
        Fields { rest: Some(text) }
    }

    fn next(&mut self) -> &'a [u8] {
        let Some(rest) = self.rest else {
            return &[];
        };
        // Fields are a few bytes long: a plain scan beats memchr's set-up cost here.
        match rest.iter().position(|&b| b == b',') {
            Some(pos) => {
                self.rest = Some(&rest[pos + 1..]);
                &rest[..pos]
            }
            None => {
                self.rest = None;
                rest
            }
        }
    }

    fn remaining_count(&self) -> usize {
        self.rest
            .map_or(0, |rest| memchr::memchr_iter(b',', rest).count() + 1)
    }

    /// Optional decimal; `Err` when present but not a number.
    fn decimal(&mut self) -> Result<Option<Decimal>, ()> {
        let f = self.next();
        if f.is_empty() {
            Ok(None)
        } else {
            Decimal::parse(f).map(Some).ok_or(())
        }
    }

    fn integer<T: TryFrom<i64>>(&mut self) -> Result<Option<T>, ()> {
        match self.decimal()? {
            None => Ok(None),
            Some(d) if d.scale == 0 => T::try_from(d.mantissa).map(Some).map_err(|_| ()),
            // Some receivers write integers as "08.0"; accept when the fraction is zero.
            Some(d) if d.mantissa % 10i64.pow(u32::from(d.scale)) == 0 => {
                T::try_from(d.mantissa / 10i64.pow(u32::from(d.scale)))
                    .map(Some)
                    .map_err(|_| ())
            }
            Some(_) => Err(()),
        }
    }

    fn character(&mut self) -> Result<Option<char>, ()> {
        match self.next() {
            [] => Ok(None),
            [c] => Ok(Some(char::from(*c))),
            _ => Err(()),
        }
    }

    fn time(&mut self) -> Result<Option<TimeOfDay>, ()> {
        let f = self.next();
        if f.is_empty() {
            Ok(None)
        } else {
            TimeOfDay::parse(f).map(Some).ok_or(())
        }
    }

    fn coordinate(&mut self, positive: u8, negative: u8) -> Result<Option<Coordinate>, ()> {
        let value = self.decimal()?;
        let hemisphere = self.next();
        match (value, hemisphere) {
            (None, []) => Ok(None),
            (Some(ddmm), [h]) if *h == positive || *h == negative => {
                if ddmm.mantissa < 0 {
                    return Err(());
                }
                Ok(Some(Coordinate {
                    ddmm,
                    hemisphere: char::from(*h),
                }))
            }
            _ => Err(()),
        }
    }

    /// A field that must be empty or equal to a fixed unit letter.
    fn unit(&mut self, _letter: u8) {
        self.next();
    }
}

fn parse_body(start: u8, body: &[u8]) -> Option<NmeaSentence> {
    let raw = || RawSentence {
        start: char::from(start),
        body: String::from_utf8_lossy(body).into_owned(),
    };
    if start == b'$' && body.first() == Some(&b'P') {
        return Some(NmeaSentence::Proprietary(raw()));
    }
    let address_end = memchr::memchr(b',', body).unwrap_or(body.len());
    let address = &body[..address_end];
    if start != b'$' || address.len() != 5 || !address.iter().all(u8::is_ascii_alphanumeric) {
        return Some(NmeaSentence::Other(raw()));
    }
    let talker = Talker([address[0], address[1]]);
    let fields = body.get(address_end + 1..).unwrap_or(&[]);
    let mut f = Fields::new(fields);
    let parsed = match &address[2..] {
        b"GGA" => parse_gga(talker, &mut f).map(NmeaSentence::Gga),
        b"RMC" => parse_rmc(talker, &mut f).map(NmeaSentence::Rmc),
        b"GSA" => parse_gsa(talker, &mut f).map(NmeaSentence::Gsa),
        b"GSV" => parse_gsv(talker, &mut f).map(NmeaSentence::Gsv),
        b"VTG" => parse_vtg(talker, &mut f).map(NmeaSentence::Vtg),
        b"ZDA" => parse_zda(talker, &mut f).map(NmeaSentence::Zda),
        b"GST" => parse_gst(talker, &mut f).map(NmeaSentence::Gst),
        b"GNS" => parse_gns(talker, &mut f).map(NmeaSentence::Gns),
        b"GLL" => parse_gll(talker, &mut f).map(NmeaSentence::Gll),
        b"HDT" => Ok(NmeaSentence::Hdt(Hdt {
            talker,
            heading_deg: f.decimal().ok()?,
        })),
        _ => Ok(NmeaSentence::Other(raw())),
    };
    parsed.ok()
}

fn parse_gll(talker: Talker, f: &mut Fields) -> Result<Gll, ()> {
    Ok(Gll {
        talker,
        lat: f.coordinate(b'N', b'S')?,
        lon: f.coordinate(b'E', b'W')?,
        time: f.time()?,
        status: f.character()?,
        mode: f.character()?,
    })
}

fn parse_gga(talker: Talker, f: &mut Fields) -> Result<Gga, ()> {
    let time = f.time()?;
    let lat = f.coordinate(b'N', b'S')?;
    let lon = f.coordinate(b'E', b'W')?;
    let quality = f.integer()?;
    let num_sats = f.integer()?;
    let hdop = f.decimal()?;
    let alt_msl_m = f.decimal()?;
    f.unit(b'M');
    let geoid_sep_m = f.decimal()?;
    f.unit(b'M');
    let dgps_age_s = f.decimal()?;
    let dgps_station = f.integer()?;
    Ok(Gga {
        talker,
        time,
        lat,
        lon,
        quality,
        num_sats,
        hdop,
        alt_msl_m,
        geoid_sep_m,
        dgps_age_s,
        dgps_station,
    })
}

fn parse_rmc(talker: Talker, f: &mut Fields) -> Result<Rmc, ()> {
    let time = f.time()?;
    let status = f.character()?;
    let lat = f.coordinate(b'N', b'S')?;
    let lon = f.coordinate(b'E', b'W')?;
    let speed_knots = f.decimal()?;
    let track_deg = f.decimal()?;
    // A date field that is not a valid ddmmyy is dropped (None) rather than rejecting the
    // sentence: receivers with a week-rollover bug send e.g. "2208-1" next to a good fix.
    let date = match f.next() {
        d if d.len() == 6 && d.iter().all(u8::is_ascii_digit) => {
            let two = |i: usize| (d[i] - b'0') * 10 + (d[i + 1] - b'0');
            let yy = u16::from(two(4));
            let date = Date {
                day: two(0),
                month: two(2),
                year: if yy < 80 { 2000 + yy } else { 1900 + yy },
            };
            ((1..=31).contains(&date.day) && (1..=12).contains(&date.month)).then_some(date)
        }
        _ => None,
    };
    let mag_var_deg = f.decimal()?;
    let mag_var_dir = f.character()?;
    let mode = f.character()?;
    let nav_status = f.character()?;
    Ok(Rmc {
        talker,
        time,
        status,
        lat,
        lon,
        speed_knots,
        track_deg,
        date,
        mag_var_deg,
        mag_var_dir,
        mode,
        nav_status,
    })
}

fn parse_gsa(talker: Talker, f: &mut Fields) -> Result<Gsa, ()> {
    let selection = f.character()?;
    let fix_mode = f.integer()?;
    let mut sat_ids = [None; 12];
    for id in &mut sat_ids {
        *id = f.integer()?;
    }
    Ok(Gsa {
        talker,
        selection,
        fix_mode,
        sat_ids,
        pdop: f.decimal()?,
        hdop: f.decimal()?,
        vdop: f.decimal()?,
        system_id: f.decimal()?,
    })
}

fn parse_gsv(talker: Talker, f: &mut Fields) -> Result<Gsv, ()> {
    let total_msgs = f.integer()?.ok_or(())?;
    let msg_num = f.integer()?.ok_or(())?;
    let sats_in_view = f.integer()?;
    let remaining = f.remaining_count();
    let groups = (remaining / 4).min(4);
    let mut sats = [None; 4];
    for slot in sats.iter_mut().take(groups) {
        let prn: Option<u16> = f.integer()?;
        let elevation_deg = f.decimal()?;
        let azimuth_deg = f.decimal()?;
        let snr_dbhz = f.decimal()?;
        // A group without a PRN cannot be attributed to a satellite (some Quectel firmware
        // sends ",,56,279,"); it is dropped rather than rejecting the sentence.
        *slot = prn.map(|prn| SatInView {
            prn,
            elevation_deg,
            azimuth_deg,
            snr_dbhz,
        });
    }
    let signal_id = if remaining % 4 == 1 && remaining / 4 <= 4 {
        f.character()?
    } else {
        None
    };
    Ok(Gsv {
        talker,
        total_msgs,
        msg_num,
        sats_in_view,
        sats,
        signal_id,
    })
}

fn parse_vtg(talker: Talker, f: &mut Fields) -> Result<Vtg, ()> {
    let track_true_deg = f.decimal()?;
    f.unit(b'T');
    let track_mag_deg = f.decimal()?;
    f.unit(b'M');
    let speed_knots = f.decimal()?;
    f.unit(b'N');
    let speed_kmh = f.decimal()?;
    f.unit(b'K');
    Ok(Vtg {
        talker,
        track_true_deg,
        track_mag_deg,
        speed_knots,
        speed_kmh,
        mode: f.character()?,
    })
}

fn parse_zda(talker: Talker, f: &mut Fields) -> Result<Zda, ()> {
    Ok(Zda {
        talker,
        time: f.time()?,
        day: f.integer()?,
        month: f.integer()?,
        year: f.integer()?,
        zone_hours: f.integer()?,
        zone_minutes: f.integer()?,
    })
}

fn parse_gst(talker: Talker, f: &mut Fields) -> Result<Gst, ()> {
    Ok(Gst {
        talker,
        time: f.time()?,
        rms: f.decimal()?,
        major_m: f.decimal()?,
        minor_m: f.decimal()?,
        orientation_deg: f.decimal()?,
        lat_sigma_m: f.decimal()?,
        lon_sigma_m: f.decimal()?,
        alt_sigma_m: f.decimal()?,
    })
}

fn parse_gns(talker: Talker, f: &mut Fields) -> Result<Gns, ()> {
    let time = f.time()?;
    let lat = f.coordinate(b'N', b'S')?;
    let lon = f.coordinate(b'E', b'W')?;
    let mode_text = f.next();
    if mode_text.len() > 8 || !mode_text.iter().all(u8::is_ascii_uppercase) {
        return Err(());
    }
    let mut mode = ModeLetters::default();
    mode.letters[..mode_text.len()].copy_from_slice(mode_text);
    mode.len = mode_text.len() as u8;
    Ok(Gns {
        talker,
        time,
        lat,
        lon,
        mode,
        num_sats: f.integer()?,
        hdop: f.decimal()?,
        alt_msl_m: f.decimal()?,
        geoid_sep_m: f.decimal()?,
        dgps_age_s: f.decimal()?,
        dgps_station: f.integer()?,
        nav_status: f.character()?,
    })
}

/// Streaming NMEA decoder (see the module docs for the framing rule and
/// [`StreamBuffer`] for the counting rule).
#[derive(Debug)]
pub struct NmeaDecoder {
    buffer: StreamBuffer,
}

impl Default for NmeaDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl NmeaDecoder {
    /// Bytes held waiting for the rest of a frame (bounded by the longest frame).
    pub fn buffered_len(&self) -> usize {
        self.buffer.len()
    }

    pub fn new() -> Self {
        NmeaDecoder {
            buffer: StreamBuffer::text(),
        }
    }
}

impl Decoder for NmeaDecoder {
    type Frame = NmeaSentence;

    fn push(&mut self, bytes: &[u8]) {
        self.buffer.push(bytes);
    }

    fn poll(&mut self) -> Option<NmeaSentence> {
        self.buffer.next_scanned(b"$!", scan_sentence)
    }

    fn stats(&self) -> DecoderStats {
        self.buffer.stats()
    }
}

/// The sentences a receiver sends for one epoch: GGA then RMC (talker `GN`), time and date
/// from the fix's UTC time. Without a position the fields are empty, with quality 0 and
/// status `V`, as receivers send them. Height above MSL is `height_msl_m`, the geoid
/// separation `height_m - height_msl_m`.
pub fn encode_fix(fix: &GnssFix, out: &mut Vec<u8>) -> Result<(), EncodeError> {
    use chrono::{Datelike, Timelike};
    let utc_ns = fix.utc_ns.ok_or(EncodeError::Invalid {
        field: "utc_ns",
        reason: "an NMEA epoch needs its UTC time",
    })?;
    let utc = chrono::DateTime::from_timestamp_nanos(utc_ns);
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
    let valid = fix.has_position();
    let (lat, lon) = match (valid, fix.lat_deg, fix.lon_deg) {
        (true, Some(lat), Some(lon)) => (
            Some(coordinate_of(lat, 'N', 'S')),
            Some(coordinate_of(lon, 'E', 'W')),
        ),
        _ => (None, None),
    };
    let quality = match fix.fix {
        _ if !valid => 0,
        FixType::Dgnss => 2,
        FixType::RtkFixed => 4,
        FixType::RtkFloat => 5,
        FixType::DeadReckoning | FixType::GnssDeadReckoning => 6,
        _ => 1,
    };
    let opt = |v: Option<f64>, scale| -> Result<Option<Decimal>, EncodeError> {
        match v {
            Some(v) if valid => Ok(Some(decimal_of(v, scale)?)),
            _ => Ok(None),
        }
    };
    let msl = fix.height_msl_m.or(fix.height_m);
    let separation = match (fix.height_m, msl) {
        (Some(h), Some(msl)) => Some(h - msl),
        _ => None,
    };
    let gga = Gga {
        talker,
        time,
        lat,
        lon,
        quality: Some(quality),
        num_sats: fix.num_sats,
        hdop: opt(fix.hdop, 2)?,
        alt_msl_m: opt(msl, 3)?,
        geoid_sep_m: opt(separation, 1)?,
        dgps_age_s: None,
        dgps_station: None,
    };
    let (speed, track) = match fix.vel_ned {
        Some([n, e, _]) => (
            Some(n.hypot(e)),
            Some(e.atan2(n).to_degrees().rem_euclid(360.0)),
        ),
        None => (None, None),
    };
    let mode = match fix.fix {
        _ if !valid => 'N',
        FixType::Dgnss => 'D',
        FixType::RtkFixed => 'R',
        FixType::RtkFloat => 'F',
        FixType::DeadReckoning | FixType::GnssDeadReckoning => 'E',
        _ => 'A',
    };
    let rmc = Rmc {
        talker,
        time,
        status: Some(if valid { 'A' } else { 'V' }),
        lat,
        lon,
        speed_knots: opt(speed.map(|s| s / KNOT_MPS), 3)?,
        track_deg: opt(track, 2)?,
        date,
        mag_var_deg: None,
        mag_var_dir: None,
        mode: Some(mode),
        nav_status: None,
    };
    NmeaEncoder.encode(&NmeaSentence::Gga(gga), out)?;
    NmeaEncoder.encode(&NmeaSentence::Rmc(rmc), out)
}

/// `ddmm.mmmmmmm` with hemisphere (7 decimals of a minute: 0.2 mm).
fn coordinate_of(deg: f64, positive: char, negative: char) -> Coordinate {
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

/// `value` with `scale` decimals.
fn decimal_of(value: f64, scale: u8) -> Result<Decimal, EncodeError> {
    let m = (value * 10f64.powi(i32::from(scale))).round();
    if !m.is_finite() || m.abs() > 1e17 {
        return Err(EncodeError::OutOfRange {
            field: "nmea number",
            value,
        });
    }
    Ok(Decimal::new(m as i64, scale))
}

/// Auto-detection score: number of valid sentences in the sample.
pub fn detect_score(sample: &[u8]) -> u32 {
    accepted_frames(NmeaDecoder::new(), sample)
}

/// NMEA encoder: writes `$…*hh\r\n` with the checksum computed.
#[derive(Debug, Default, Clone, Copy)]
pub struct NmeaEncoder;

fn put_opt_decimal(out: &mut Vec<u8>, value: Option<Decimal>) {
    out.push(b',');
    if let Some(d) = value {
        d.write_padded(1, out);
    }
}

fn put_opt_int<T: fmt::Display>(out: &mut Vec<u8>, value: Option<T>, width: usize) {
    out.push(b',');
    if let Some(v) = value {
        let _ = write!(out, "{v:0width$}");
    }
}

fn put_opt_char(
    out: &mut Vec<u8>,
    value: Option<char>,
    field: &'static str,
) -> Result<(), EncodeError> {
    out.push(b',');
    if let Some(c) = value {
        if !c.is_ascii_graphic() || matches!(c, ',' | '*' | '$' | '!') {
            return Err(EncodeError::Invalid {
                field,
                reason: "must be one printable ASCII character other than , * $ !",
            });
        }
        out.push(c as u8);
    }
    Ok(())
}

fn put_opt_time(out: &mut Vec<u8>, value: Option<TimeOfDay>) {
    out.push(b',');
    if let Some(t) = value {
        t.write(out);
    }
}

fn put_coordinate(
    out: &mut Vec<u8>,
    value: Option<Coordinate>,
    int_digits: usize,
    field: &'static str,
) -> Result<(), EncodeError> {
    out.push(b',');
    match value {
        Some(c) => {
            if c.ddmm.mantissa < 0 || !matches!(c.hemisphere, 'N' | 'S' | 'E' | 'W') {
                return Err(EncodeError::Invalid {
                    field,
                    reason: "coordinate must be non-negative with hemisphere N/S/E/W",
                });
            }
            c.ddmm.write_padded(int_digits, out);
            out.push(b',');
            out.push(c.hemisphere as u8);
        }
        None => out.push(b','),
    }
    Ok(())
}

fn put_talker(out: &mut Vec<u8>, talker: Talker, formatter: &[u8]) -> Result<(), EncodeError> {
    if !talker.0.iter().all(u8::is_ascii_alphanumeric) {
        return Err(EncodeError::Invalid {
            field: "talker",
            reason: "must be two ASCII letters or digits",
        });
    }
    out.push(b'$');
    out.extend_from_slice(&talker.0);
    out.extend_from_slice(formatter);
    Ok(())
}

impl NmeaEncoder {
    fn encode_body(&self, sentence: &NmeaSentence, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        match sentence {
            NmeaSentence::Gga(s) => {
                put_talker(out, s.talker, b"GGA")?;
                put_opt_time(out, s.time);
                put_coordinate(out, s.lat, 4, "lat")?;
                put_coordinate(out, s.lon, 5, "lon")?;
                put_opt_int(out, s.quality, 1);
                put_opt_int(out, s.num_sats, 2);
                put_opt_decimal(out, s.hdop);
                put_opt_decimal(out, s.alt_msl_m);
                out.extend_from_slice(b",M");
                put_opt_decimal(out, s.geoid_sep_m);
                out.extend_from_slice(b",M");
                put_opt_decimal(out, s.dgps_age_s);
                put_opt_int(out, s.dgps_station, 4);
            }
            NmeaSentence::Rmc(s) => {
                put_talker(out, s.talker, b"RMC")?;
                put_opt_time(out, s.time);
                put_opt_char(out, s.status, "status")?;
                put_coordinate(out, s.lat, 4, "lat")?;
                put_coordinate(out, s.lon, 5, "lon")?;
                put_opt_decimal(out, s.speed_knots);
                put_opt_decimal(out, s.track_deg);
                out.push(b',');
                if let Some(d) = s.date {
                    if !(1980..=2079).contains(&d.year) || d.day > 99 || d.month > 99 {
                        return Err(EncodeError::OutOfRange {
                            field: "date",
                            value: f64::from(d.year),
                        });
                    }
                    let _ = write!(out, "{:02}{:02}{:02}", d.day, d.month, d.year % 100);
                }
                put_opt_decimal(out, s.mag_var_deg);
                put_opt_char(out, s.mag_var_dir, "mag_var_dir")?;
                put_opt_char(out, s.mode, "mode")?;
                if s.nav_status.is_some() {
                    put_opt_char(out, s.nav_status, "nav_status")?;
                }
            }
            NmeaSentence::Gsa(s) => {
                put_talker(out, s.talker, b"GSA")?;
                put_opt_char(out, s.selection, "selection")?;
                put_opt_int(out, s.fix_mode, 1);
                for id in s.sat_ids {
                    put_opt_int(out, id, 2);
                }
                put_opt_decimal(out, s.pdop);
                put_opt_decimal(out, s.hdop);
                put_opt_decimal(out, s.vdop);
                if s.system_id.is_some() {
                    put_opt_decimal(out, s.system_id);
                }
            }
            NmeaSentence::Gsv(s) => {
                put_talker(out, s.talker, b"GSV")?;
                put_opt_int(out, Some(s.total_msgs), 1);
                put_opt_int(out, Some(s.msg_num), 1);
                put_opt_int(out, s.sats_in_view, 2);
                let used = s
                    .sats
                    .iter()
                    .rposition(Option::is_some)
                    .map_or(0, |i| i + 1);
                for sat in &s.sats[..used] {
                    match sat {
                        Some(sat) => {
                            put_opt_int(out, Some(sat.prn), 2);
                            put_opt_decimal(out, sat.elevation_deg);
                            put_opt_decimal(out, sat.azimuth_deg);
                            put_opt_decimal(out, sat.snr_dbhz);
                        }
                        None => out.extend_from_slice(b",,,,"),
                    }
                }
                if s.signal_id.is_some() {
                    put_opt_char(out, s.signal_id, "signal_id")?;
                }
            }
            NmeaSentence::Vtg(s) => {
                put_talker(out, s.talker, b"VTG")?;
                put_opt_decimal(out, s.track_true_deg);
                out.extend_from_slice(b",T");
                put_opt_decimal(out, s.track_mag_deg);
                out.extend_from_slice(b",M");
                put_opt_decimal(out, s.speed_knots);
                out.extend_from_slice(b",N");
                put_opt_decimal(out, s.speed_kmh);
                out.extend_from_slice(b",K");
                put_opt_char(out, s.mode, "mode")?;
            }
            NmeaSentence::Zda(s) => {
                put_talker(out, s.talker, b"ZDA")?;
                put_opt_time(out, s.time);
                put_opt_int(out, s.day, 2);
                put_opt_int(out, s.month, 2);
                put_opt_int(out, s.year, 4);
                put_opt_int(out, s.zone_hours, 2);
                put_opt_int(out, s.zone_minutes, 2);
            }
            NmeaSentence::Gst(s) => {
                put_talker(out, s.talker, b"GST")?;
                put_opt_time(out, s.time);
                for v in [
                    s.rms,
                    s.major_m,
                    s.minor_m,
                    s.orientation_deg,
                    s.lat_sigma_m,
                    s.lon_sigma_m,
                    s.alt_sigma_m,
                ] {
                    put_opt_decimal(out, v);
                }
            }
            NmeaSentence::Gns(s) => {
                put_talker(out, s.talker, b"GNS")?;
                put_opt_time(out, s.time);
                put_coordinate(out, s.lat, 4, "lat")?;
                put_coordinate(out, s.lon, 5, "lon")?;
                out.push(b',');
                let mode = s.mode.as_str();
                if !mode.bytes().all(|b| b.is_ascii_uppercase()) {
                    return Err(EncodeError::Invalid {
                        field: "mode",
                        reason: "mode letters must be uppercase ASCII",
                    });
                }
                out.extend_from_slice(mode.as_bytes());
                put_opt_int(out, s.num_sats, 2);
                put_opt_decimal(out, s.hdop);
                put_opt_decimal(out, s.alt_msl_m);
                put_opt_decimal(out, s.geoid_sep_m);
                put_opt_decimal(out, s.dgps_age_s);
                put_opt_int(out, s.dgps_station, 4);
                if s.nav_status.is_some() {
                    put_opt_char(out, s.nav_status, "nav_status")?;
                }
            }
            NmeaSentence::Gll(s) => {
                put_talker(out, s.talker, b"GLL")?;
                put_coordinate(out, s.lat, 4, "lat")?;
                put_coordinate(out, s.lon, 5, "lon")?;
                put_opt_time(out, s.time);
                put_opt_char(out, s.status, "status")?;
                put_opt_char(out, s.mode, "mode")?;
            }
            NmeaSentence::Hdt(s) => {
                put_talker(out, s.talker, b"HDT")?;
                put_opt_decimal(out, s.heading_deg);
                out.extend_from_slice(b",T");
            }
            NmeaSentence::Proprietary(raw) | NmeaSentence::Other(raw) => {
                if !matches!(raw.start, '$' | '!')
                    || !raw
                        .body
                        .bytes()
                        .all(|b| (0x20..=0x7e).contains(&b) && !matches!(b, b'*' | b'$' | b'!'))
                {
                    return Err(EncodeError::Invalid {
                        field: "body",
                        reason: "raw sentence must be printable ASCII without * $ !",
                    });
                }
                out.push(raw.start as u8);
                out.extend_from_slice(raw.body.as_bytes());
            }
        }
        Ok(())
    }
}

impl Encoder for NmeaEncoder {
    type Frame = NmeaSentence;

    fn encode(&self, sentence: &NmeaSentence, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        let begin = out.len();
        if let Err(e) = self.encode_body(sentence, out) {
            out.truncate(begin);
            return Err(e);
        }
        let checksum = out[begin + 1..].iter().fold(0u8, |acc, &b| acc ^ b);
        let len = out.len() - begin + 3;
        let limit = if matches!(sentence, NmeaSentence::Proprietary(_)) {
            MAX_PROPRIETARY_LEN
        } else {
            MAX_SENTENCE_LEN
        };
        if len > limit {
            out.truncate(begin);
            return Err(EncodeError::TooLong { len, max: limit });
        }
        let _ = write!(out, "*{checksum:02X}\r\n");
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eighteen_decimals_without_integer_digit_round_trip() {
        // Fuzz find (nmea target): ".100111111111111111" parsed (18 digits) but was written
        // back as "0.100111111111111111", which had 19 digits and was refused.
        let line = b"$GNRMC,012245.00,A,3454.4922,S,13835.7617,E,.100111111111111111,0.0,120821,,,D*7E\r\n";
        let body = &line[1..line.len() - 5];
        let sum = body.iter().fold(0u8, |a, &b| a ^ b);
        let line = [&line[..line.len() - 4], format!("{sum:02X}\r\n").as_bytes()].concat();
        let mut d = NmeaDecoder::new();
        let mut frames = Vec::new();
        d.decode(&line, |f| frames.push(f));
        assert_eq!(frames.len(), 1, "{:?}", d.stats());
        let mut bytes = Vec::new();
        NmeaEncoder.encode(&frames[0], &mut bytes).expect("encodes");
        let mut again = Vec::new();
        NmeaDecoder::new().decode(&bytes, |f| again.push(f));
        assert_eq!(again, frames, "{}", String::from_utf8_lossy(&bytes));
        assert_eq!(
            Decimal::parse(b"0.0000000000000000001"),
            None,
            "scale above 18"
        );
        assert!(Decimal::parse(b"000000000000000000001.5").is_some());
    }

    fn decode_all(bytes: &[u8]) -> (Vec<NmeaSentence>, DecoderStats) {
        let mut d = NmeaDecoder::new();
        let mut frames = Vec::new();
        d.decode(bytes, |f| frames.push(f));
        (frames, d.stats())
    }

    #[test]
    fn decodes_textbook_gga() {
        let (frames, stats) =
            decode_all(b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n");
        assert_eq!(stats.frames_ok, 1, "{stats:?}");
        let NmeaSentence::Gga(gga) = &frames[0] else {
            panic!("not GGA: {frames:?}")
        };
        assert_eq!(gga.talker.as_str(), "GP");
        assert_eq!(gga.time.map(|t| t.seconds_of_day()), Some(45319.0));
        let lat = gga.lat.map(Coordinate::degrees).unwrap_or(f64::NAN);
        assert!((lat - (48.0 + 7.038 / 60.0)).abs() < 1e-12);
        let lon = gga.lon.map(Coordinate::degrees).unwrap_or(f64::NAN);
        assert!((lon - (11.0 + 31.0 / 60.0)).abs() < 1e-12);
        assert_eq!(gga.quality, Some(1));
        assert_eq!(gga.num_sats, Some(8));
        assert_eq!(gga.alt_msl_m, Some(Decimal::new(5454, 1)));
        assert_eq!(gga.dgps_age_s, None);
    }

    #[test]
    fn lower_case_checksum_and_lf_only_accepted() {
        let (frames, stats) = decode_all(b"$GPHDT,274.07,T*03\n$GPHDT,274.07,T*03");
        assert_eq!(frames.len(), 2, "{stats:?}");
        let (frames, _) = decode_all(b"$GNRMC,,V,,,,,,,,,,N*4d\r\n");
        assert_eq!(frames.len(), 1);
    }

    #[test]
    fn bad_checksum_missing_checksum_noise_and_overlong_are_counted() {
        let mut input = Vec::new();
        input.extend_from_slice(b"$GPHDT,274.07,T*04\r\n"); // wrong checksum
        input.extend_from_slice(b"$GPHDT,274.07,T\r\n"); // missing checksum
        input.extend_from_slice(b"$GPHDT,27\x004.07,T*03\r\n"); // binary noise
        input.extend_from_slice(b"$GPTXT,");
        input.extend_from_slice(&[b'A'; 200]);
        input.extend_from_slice(b"*00\r\n");
        input.extend_from_slice(b"$GPHDT,274.07,T*03\r\n");
        let (frames, stats) = decode_all(&input);
        assert_eq!(frames.len(), 1, "{stats:?}");
        assert_eq!(stats.checksum_errors, 1);
        assert_eq!(stats.frames_malformed, 2);
        assert_eq!(stats.frames_too_long, 1);
        assert!(stats.bytes_skipped > 200);
    }

    #[test]
    fn proprietary_and_unknown_kept_raw() {
        let mut out = Vec::new();
        let raw = NmeaSentence::Proprietary(RawSentence {
            start: '$',
            body: "PUBX,00,foo".into(),
        });
        NmeaEncoder.encode(&raw, &mut out).unwrap();
        let (frames, _) = decode_all(&out);
        assert_eq!(frames, vec![raw]);
        let (frames, _) = decode_all(b"$GPTXT,01,01,02,ANTSTATUS=OK*3B\r\n");
        assert!(
            matches!(&frames[0], NmeaSentence::Other(r) if r.body.starts_with("GPTXT")),
            "{frames:?}"
        );
    }

    #[test]
    fn gsv_group_without_prn_is_dropped() {
        let (frames, stats) =
            decode_all(b"$GLGSV,2,2,08,81,11,130,17,68,38,195,16,70,10,331,,,56,279,,1*7A\r\n");
        assert_eq!(stats.frames_ok, 1, "{stats:?}");
        let NmeaSentence::Gsv(gsv) = &frames[0] else {
            panic!()
        };
        assert_eq!(gsv.sats[3], None);
        assert_eq!(gsv.signal_id, Some('1'));
    }

    #[test]
    fn gsv_with_signal_id_and_gsa_dops() {
        let line = b"$GPGSV,3,1,11,03,03,111,00,04,15,270,00,06,01,010,00,13,06,292,00,1*6B\r\n";
        let mut body_ck = 0u8;
        for &b in &line[1..line.len() - 5] {
            body_ck ^= b;
        }
        let fixed = format!(
            "{}*{:02X}\r\n",
            std::str::from_utf8(&line[..line.len() - 5]).unwrap(),
            body_ck
        );
        let (frames, stats) = decode_all(fixed.as_bytes());
        assert_eq!(stats.frames_ok, 1);
        let NmeaSentence::Gsv(gsv) = &frames[0] else {
            panic!()
        };
        assert_eq!(gsv.sats_in_view, Some(11));
        assert_eq!(gsv.sats[3].map(|s| s.prn), Some(13));
        assert_eq!(gsv.signal_id, Some('1'));
    }
}
