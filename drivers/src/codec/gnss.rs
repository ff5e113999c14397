//! Mixed GNSS stream decoder: NMEA 0183 and u-blox UBX interleaved on one port (as u-blox
//! receivers emit by default). Yields every message, plus one merged [`EpochFix`] per
//! reporting cycle, the way gpsd merges a cycle into one TPV report.
//!
//! Epochs: NMEA sentences are grouped by their UTC time of day (GGA, RMC, GNS, GLL, GST, ZDA
//! carry one; GSA, VTG and HDT join the epoch in progress); within an epoch the latest
//! sentence's value wins, as in gpsd; UBX messages by iTOW, closed early by
//! UBX-NAV-EOE. NMEA and UBX epochs are kept apart (`source`), since a receiver sending both
//! reports the same solution twice. An epoch is emitted when the next one starts, on NAV-EOE,
//! or by [`Decoder::finish`] at the end of the input.

use std::collections::VecDeque;

use serde::Serialize;

use super::nmea::{self, Date, NmeaSentence, TimeOfDay};
use super::ubx::{self, UbxMessage};
use super::{Decoder, Scan, StreamBuffer};
use crate::types::{DecoderStats, FixType, GnssFix};

/// Which protocol an epoch was merged from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FixSource {
    Nmea,
    Ubx,
}

/// One merged navigation epoch.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct EpochFix {
    pub source: FixSource,
    /// UTC milliseconds since midnight (NMEA epochs; UBX epochs when UTC is valid).
    pub time_of_day_ms: Option<i64>,
    /// GPS time of week, ms (UBX epochs).
    pub itow_ms: Option<u32>,
    /// UTC date, when a sentence or message of this or an earlier epoch gave it.
    pub date: Option<Date>,
    #[serde(flatten)]
    pub fix: GnssFix,
}

/// One item of a mixed stream.
// Fixed-size messages (NAV-PVT, inline ESF-MEAS words) make this enum a few hundred bytes;
// moving that is cheaper than boxing, which would allocate per message.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum GnssFrame {
    Nmea(NmeaSentence),
    Ubx(UbxMessage),
    Fix(EpochFix),
}

/// Days since 1970-01-01 of a proleptic Gregorian date (H. Hinnant's `days_from_civil`;
/// no crate in the drivers' dependency set does calendar arithmetic).
fn days_from_civil(year: i64, month: u8, day: u8) -> i64 {
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let m = i64::from(month);
    let mp = if m > 2 { m - 3 } else { m + 9 };
    let doy = (153 * mp + 2) / 5 + i64::from(day) - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

fn utc_ns(date: Date, ms_of_day: i64) -> Option<i64> {
    if !(1..=12).contains(&date.month) || !(1..=31).contains(&date.day) {
        return None;
    }
    let days = days_from_civil(i64::from(date.year), date.month, date.day);
    days.checked_mul(86_400_000)?
        .checked_add(ms_of_day)?
        .checked_mul(1_000_000)
}

/// Accumulates NMEA sentences of one epoch.
#[derive(Debug, Default, Clone)]
struct NmeaEpoch {
    key_ms: Option<i64>,
    fix: GnssFix,
    has_data: bool,
    gsa_mode: Option<u8>,
    gga_quality: Option<u8>,
    rmc_status: Option<char>,
    gll_status: Option<char>,
    gns_no_fix: Option<bool>,
}

impl NmeaEpoch {
    fn set_position(&mut self, lat: Option<nmea::Coordinate>, lon: Option<nmea::Coordinate>) {
        if let (Some(lat), Some(lon)) = (lat, lon) {
            self.fix.lat_deg = Some(lat.degrees());
            self.fix.lon_deg = Some(lon.degrees());
        }
    }

    fn apply(&mut self, sentence: &NmeaSentence, date: &mut Option<Date>) {
        // Satellite lists, heading and raw sentences alone do not make a fix epoch.
        self.has_data |= !matches!(
            sentence,
            NmeaSentence::Gsv(_)
                | NmeaSentence::Hdt(_)
                | NmeaSentence::Proprietary(_)
                | NmeaSentence::Other(_)
        );
        let f = &mut self.fix;
        match sentence {
            NmeaSentence::Gga(s) => {
                self.gga_quality = s.quality;
                f.num_sats = s.num_sats.or(f.num_sats);
                f.hdop = s.hdop.map(|d| d.to_f64()).or(f.hdop);
                if let Some(alt) = s.alt_msl_m {
                    f.height_msl_m = Some(alt.to_f64());
                    f.height_m = s.geoid_sep_m.map(|sep| alt.to_f64() + sep.to_f64());
                }
                self.set_position(s.lat, s.lon);
            }
            NmeaSentence::Gns(s) => {
                f.num_sats = s.num_sats.or(f.num_sats);
                f.hdop = s.hdop.map(|d| d.to_f64()).or(f.hdop);
                if let Some(alt) = s.alt_msl_m {
                    f.height_msl_m = Some(alt.to_f64());
                    f.height_m = s.geoid_sep_m.map(|sep| alt.to_f64() + sep.to_f64());
                }
                let letters = s.mode.as_str();
                if !letters.is_empty() {
                    self.gns_no_fix = Some(letters.bytes().all(|b| b == b'N'));
                }
                self.set_position(s.lat, s.lon);
            }
            NmeaSentence::Rmc(s) => {
                self.rmc_status = s.status;
                if let Some(d) = s.date {
                    *date = Some(d);
                }
                f.speed_mps = s.speed_mps().or(f.speed_mps);
                f.track_deg = s.track_deg.map(|t| t.to_f64()).or(f.track_deg);
                self.set_position(s.lat, s.lon);
            }
            NmeaSentence::Gll(s) => {
                self.gll_status = s.status;
                if s.status != Some('V') {
                    self.set_position(s.lat, s.lon);
                }
            }
            NmeaSentence::Gsa(s) => {
                if s.fix_mode.is_some() {
                    self.gsa_mode = s.fix_mode;
                }
                f.pdop = s.pdop.map(|d| d.to_f64()).or(f.pdop);
                f.hdop = s.hdop.map(|d| d.to_f64()).or(f.hdop);
                f.vdop = s.vdop.map(|d| d.to_f64()).or(f.vdop);
            }
            NmeaSentence::Vtg(s) => {
                f.speed_mps = s.speed_mps().or(f.speed_mps);
                f.track_deg = s.track_true_deg.map(|t| t.to_f64()).or(f.track_deg);
            }
            NmeaSentence::Gst(s) => {
                if let (Some(lat), Some(lon)) = (s.lat_sigma_m, s.lon_sigma_m) {
                    f.h_acc_m = Some(lat.to_f64().hypot(lon.to_f64()));
                }
                f.v_acc_m = s.alt_sigma_m.map(|d| d.to_f64()).or(f.v_acc_m);
            }
            NmeaSentence::Zda(s) => {
                if let (Some(day), Some(month), Some(year)) = (s.day, s.month, s.year) {
                    *date = Some(Date { year, month, day });
                }
            }
            NmeaSentence::Gsv(_)
            | NmeaSentence::Hdt(_)
            | NmeaSentence::Proprietary(_)
            | NmeaSentence::Other(_) => {}
        }
    }

    /// Fix type as gpsd judges a cycle: GGA (or GNS) quality and altitude first (quality 0
    /// is no fix, otherwise 3D with an altitude and 2D without), then the GSA mode. A cycle
    /// with only a valid RMC or GLL keeps the previous cycle's dimension (2D at least).
    /// DGNSS/RTK qualities refine a 3D fix.
    fn fix_type(&self, previous: FixType) -> FixType {
        let has_alt = self.fix.height_msl_m.is_some();
        let weak_valid = matches!(self.rmc_status, Some('A' | 'D'))
            || matches!(self.gll_status, Some('A' | 'D'));
        let base = match (self.gga_quality, self.gns_no_fix, self.gsa_mode) {
            (Some(0), _, _) | (None, Some(true), _) => FixType::NoFix,
            (Some(6), _, _) => FixType::DeadReckoning,
            (Some(_), _, _) | (None, Some(false), _) if has_alt => FixType::Fix3D,
            (Some(_), _, _) | (None, Some(false), _) => FixType::Fix2D,
            (None, None, Some(3)) => FixType::Fix3D,
            (None, None, Some(2)) => FixType::Fix2D,
            (None, None, Some(_)) => FixType::NoFix,
            (None, None, None) if weak_valid => previous.max(FixType::Fix2D),
            (None, None, None) => FixType::NoFix,
        };
        if base >= FixType::Fix3D {
            match self.gga_quality {
                Some(2) => return FixType::Dgnss,
                Some(4) => return FixType::RtkFixed,
                Some(5) => return FixType::RtkFloat,
                _ => {}
            }
        }
        base
    }

    fn take(&mut self, date: Option<Date>, previous: &mut FixType) -> Option<EpochFix> {
        if !self.has_data || (self.key_ms.is_none() && self.fix.lat_deg.is_none()) {
            *self = NmeaEpoch::default();
            return None;
        }
        let mut fix = self.fix;
        fix.fix = self.fix_type(*previous);
        *previous = fix.fix;
        fix.utc_ns = match (date, self.key_ms) {
            (Some(d), Some(ms)) => utc_ns(d, ms),
            _ => None,
        };
        let epoch = EpochFix {
            source: FixSource::Nmea,
            time_of_day_ms: self.key_ms,
            itow_ms: None,
            date,
            fix,
        };
        *self = NmeaEpoch::default();
        Some(epoch)
    }
}

fn sentence_time(sentence: &NmeaSentence) -> Option<TimeOfDay> {
    match sentence {
        NmeaSentence::Gga(s) => s.time,
        NmeaSentence::Rmc(s) => s.time,
        NmeaSentence::Gns(s) => s.time,
        NmeaSentence::Gst(s) => s.time,
        NmeaSentence::Zda(s) => s.time,
        NmeaSentence::Gll(s) => s.time,
        _ => None,
    }
}

/// Accumulates UBX messages of one epoch (same iTOW).
#[derive(Debug, Default, Clone)]
struct UbxEpoch {
    itow_ms: Option<u32>,
    fix: GnssFix,
    has_data: bool,
    date: Option<Date>,
    time_of_day_ms: Option<i64>,
}

impl UbxEpoch {
    fn set_utc(&mut self, date: Date, hour: u8, min: u8, sec: u8, nano_ns: i32) {
        let ms = (i64::from(hour) * 3600 + i64::from(min) * 60 + i64::from(sec)) * 1000
            + i64::from(nano_ns).div_euclid(1_000_000);
        self.date = Some(date);
        self.time_of_day_ms = Some(ms);
        self.fix.utc_ns = utc_ns(date, ms)
            .and_then(|ns| ns.checked_add(i64::from(nano_ns).rem_euclid(1_000_000)));
    }

    fn apply(&mut self, msg: &UbxMessage) {
        let f = &mut self.fix;
        match msg {
            UbxMessage::NavPvt(m) => {
                f.lat_deg = Some(m.lat_deg);
                f.lon_deg = Some(m.lon_deg);
                f.height_m = Some(m.height_m);
                f.height_msl_m = Some(m.height_msl_m);
                f.h_acc_m = Some(m.h_acc_m);
                f.v_acc_m = Some(m.v_acc_m);
                f.vel_ned = Some([m.vel_n_mps, m.vel_e_mps, m.vel_d_mps]);
                f.speed_mps = Some(m.ground_speed_mps);
                f.track_deg = Some(m.head_mot_deg);
                f.s_acc_mps = Some(m.s_acc_mps);
                f.num_sats = Some(m.num_sv);
                f.pdop = Some(m.pdop);
                f.fix = pvt_fix_type(m.fix_type, m.flags);
                // valid bits 0 and 1: UTC date and time of day are valid.
                if m.valid & 0x03 == 0x03 {
                    let date = Date {
                        year: m.year,
                        month: m.month,
                        day: m.day,
                    };
                    self.set_utc(date, m.hour, m.min, m.sec, m.nano_ns);
                }
            }
            UbxMessage::NavPosllh(m) => {
                f.lat_deg = Some(m.lat_deg);
                f.lon_deg = Some(m.lon_deg);
                f.height_m = Some(m.height_m);
                f.height_msl_m = Some(m.height_msl_m);
                f.h_acc_m = Some(m.h_acc_m);
                f.v_acc_m = Some(m.v_acc_m);
            }
            UbxMessage::NavVelned(m) => {
                f.vel_ned = Some([m.vel_n_mps, m.vel_e_mps, m.vel_d_mps]);
                f.speed_mps = Some(m.ground_speed_mps);
                f.track_deg = Some(m.heading_deg);
                f.s_acc_mps = Some(m.s_acc_mps);
            }
            UbxMessage::NavStatus(m) => {
                if f.fix == FixType::NoFix {
                    f.fix = pvt_fix_type(m.gps_fix, m.flags & 0x02);
                }
            }
            UbxMessage::NavTimeutc(m) => {
                // valid bits: 0 validTOW, 1 validWKN, 2 validUTC.
                if m.valid & 0x04 != 0 {
                    let date = Date {
                        year: m.year,
                        month: m.month,
                        day: m.day,
                    };
                    self.set_utc(date, m.hour, m.min, m.sec, m.nano_ns);
                }
            }
            UbxMessage::NavSat(m) => {
                let used = m.svs.iter().filter(|sv| sv.flags & 0x08 != 0).count();
                f.num_sats = Some(u8::try_from(used).unwrap_or(u8::MAX));
            }
            _ => return,
        }
        self.has_data = true;
    }

    fn take(&mut self, week: Option<u16>) -> Option<EpochFix> {
        if !self.has_data {
            *self = UbxEpoch::default();
            return None;
        }
        let mut fix = self.fix;
        fix.week = week;
        fix.tow_s = self.itow_ms.map(|ms| f64::from(ms) / 1000.0);
        let epoch = EpochFix {
            source: FixSource::Ubx,
            time_of_day_ms: self.time_of_day_ms,
            itow_ms: self.itow_ms,
            date: self.date,
            fix,
        };
        *self = UbxEpoch::default();
        Some(epoch)
    }
}

/// Fix type from NAV-PVT/NAV-STATUS `fixType` and flags (bit 1 diffSoln, bits 6–7 carrier
/// solution). Like gpsd, the fix type is reported even when gnssFixOK (bit 0) is clear.
fn pvt_fix_type(fix_type: u8, flags: u8) -> FixType {
    let base = match fix_type {
        1 => FixType::DeadReckoning,
        2 => FixType::Fix2D,
        3 => FixType::Fix3D,
        4 => FixType::GnssDeadReckoning,
        5 => FixType::TimeOnly,
        _ => FixType::NoFix,
    };
    if matches!(base, FixType::Fix3D | FixType::GnssDeadReckoning) {
        match flags >> 6 {
            1 => return FixType::RtkFloat,
            2 => return FixType::RtkFixed,
            _ if flags & 0x02 != 0 => return FixType::Dgnss,
            _ => {}
        }
    }
    base
}

fn ubx_itow(msg: &UbxMessage) -> Option<u32> {
    match msg {
        UbxMessage::NavPvt(m) => Some(m.itow_ms),
        UbxMessage::NavPosllh(m) => Some(m.itow_ms),
        UbxMessage::NavVelned(m) => Some(m.itow_ms),
        UbxMessage::NavStatus(m) => Some(m.itow_ms),
        UbxMessage::NavTimeutc(m) => Some(m.itow_ms),
        UbxMessage::NavSat(m) => Some(m.itow_ms),
        UbxMessage::NavCov(m) => Some(m.itow_ms),
        UbxMessage::Other(raw) if raw.class == 0x01 && raw.payload.len() >= 4 => {
            Some(u32::from_le_bytes([
                raw.payload[0],
                raw.payload[1],
                raw.payload[2],
                raw.payload[3],
            ]))
        }
        _ => None,
    }
}

/// Streaming decoder for NMEA + UBX on one port.
#[derive(Debug, Clone)]
pub struct GnssDecoder {
    buffer: StreamBuffer,
    ready: VecDeque<GnssFrame>,
    nmea_epoch: NmeaEpoch,
    nmea_date: Option<Date>,
    /// Fix type of the last NMEA epoch (a cycle with only RMC/GLL keeps it, as gpsd does).
    nmea_last_fix: FixType,
    ubx_epoch: UbxEpoch,
    ubx_week: Option<u16>,
    finished: bool,
}

impl GnssDecoder {
    /// Bytes held waiting for the rest of a frame (bounded by the longest frame).
    pub fn buffered_len(&self) -> usize {
        self.buffer.len()
    }

    pub fn new() -> Self {
        GnssDecoder {
            buffer: StreamBuffer::text(),
            ready: VecDeque::with_capacity(4),
            nmea_epoch: NmeaEpoch::default(),
            nmea_date: None,
            nmea_last_fix: FixType::NoFix,
            ubx_epoch: UbxEpoch::default(),
            ubx_week: None,
            finished: false,
        }
    }

    /// Sets the UTC date assumed for NMEA epochs until a sentence (RMC, ZDA) gives one.
    pub fn with_date(mut self, date: Date) -> Self {
        self.nmea_date = Some(date);
        self
    }

    fn on_nmea(&mut self, sentence: NmeaSentence) {
        if let Some(time) = sentence_time(&sentence) {
            let key = time.millis_of_day();
            match self.nmea_epoch.key_ms {
                Some(current) if current != key => {
                    if let Some(fix) = self
                        .nmea_epoch
                        .take(self.nmea_date, &mut self.nmea_last_fix)
                    {
                        self.ready.push_back(GnssFrame::Fix(fix));
                    }
                    self.nmea_epoch.key_ms = Some(key);
                }
                Some(_) => {}
                None => self.nmea_epoch.key_ms = Some(key),
            }
        }
        self.nmea_epoch.apply(&sentence, &mut self.nmea_date);
        self.ready.push_back(GnssFrame::Nmea(sentence));
    }

    fn on_ubx(&mut self, msg: UbxMessage) {
        if let UbxMessage::RxmRawx(raw) = &msg {
            self.ubx_week = Some(raw.week);
        }
        let end_of_epoch =
            matches!(&msg, UbxMessage::Other(raw) if raw.class == 0x01 && raw.id == 0x61);
        if let Some(itow) = ubx_itow(&msg) {
            if self
                .ubx_epoch
                .itow_ms
                .is_some_and(|current| current != itow)
            {
                if let Some(fix) = self.ubx_epoch.take(self.ubx_week) {
                    self.ready.push_back(GnssFrame::Fix(fix));
                }
            }
            self.ubx_epoch.itow_ms = Some(itow);
        }
        self.ubx_epoch.apply(&msg);
        self.ready.push_back(GnssFrame::Ubx(msg));
        if end_of_epoch {
            if let Some(fix) = self.ubx_epoch.take(self.ubx_week) {
                self.ready.push_back(GnssFrame::Fix(fix));
            }
        }
    }
}

impl Default for GnssDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder for GnssDecoder {
    type Frame = GnssFrame;

    fn push(&mut self, bytes: &[u8]) {
        self.finished = false;
        self.buffer.push(bytes);
    }

    fn poll(&mut self) -> Option<GnssFrame> {
        loop {
            if let Some(frame) = self.ready.pop_front() {
                return Some(frame);
            }
            let data = self.buffer.data();
            let Some(start) = memchr::memchr3(b'$', b'!', 0xB5, data) else {
                let n = data.len();
                self.buffer.skip(n);
                return None;
            };
            if start > 0 {
                self.buffer.skip(start);
                continue;
            }
            let (len, outcome) = if data[0] == 0xB5 {
                match ubx::scan_frame(data) {
                    Scan::Incomplete => return None,
                    Scan::Frame { len, frame } => (len, Ok(GnssFrame::Ubx(frame))),
                    Scan::Reject { len, reject } => (len, Err(reject)),
                }
            } else {
                match nmea::scan_sentence(data) {
                    Scan::Incomplete => return None,
                    Scan::Frame { len, frame } => (len, Ok(GnssFrame::Nmea(frame))),
                    Scan::Reject { len, reject } => (len, Err(reject)),
                }
            };
            match outcome {
                Ok(frame) => {
                    self.buffer.accept(len);
                    match frame {
                        GnssFrame::Nmea(s) => self.on_nmea(s),
                        GnssFrame::Ubx(m) => self.on_ubx(m),
                        GnssFrame::Fix(_) => {}
                    }
                }
                Err(reject) => self.buffer.reject(len, reject),
            }
        }
    }

    fn finish(&mut self) -> Option<GnssFrame> {
        if let Some(frame) = self.ready.pop_front() {
            return Some(frame);
        }
        if self.finished {
            return None;
        }
        self.finished = true;
        if let Some(fix) = self
            .nmea_epoch
            .take(self.nmea_date, &mut self.nmea_last_fix)
        {
            self.ready.push_back(GnssFrame::Fix(fix));
        }
        if let Some(fix) = self.ubx_epoch.take(self.ubx_week) {
            self.ready.push_back(GnssFrame::Fix(fix));
        }
        self.ready.pop_front()
    }

    fn stats(&self) -> DecoderStats {
        self.buffer.stats()
    }
}

/// Auto-detection score: NMEA sentences plus UBX frames found. This row comes first in the
/// table, so `auto` picks the mixed decoder (which also yields merged fixes) for pure NMEA
/// and pure UBX streams too.
pub fn detect_score(sample: &[u8]) -> u32 {
    nmea::detect_score(sample) + ubx::detect_score(sample)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::nmea::KNOT_MPS;

    #[test]
    fn civil_days_known_values() {
        assert_eq!(days_from_civil(1970, 1, 1), 0);
        assert_eq!(days_from_civil(2000, 3, 1), 11_017);
        assert_eq!(days_from_civil(2019, 4, 6), 17_992);
    }

    #[test]
    fn nmea_cycle_merges_into_one_fix() {
        let stream = b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A\r\n\
$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n\
$GPGSA,A,3,04,05,,09,12,,,24,,,,,2.5,1.3,2.1*39\r\n\
$GPGGA,123520,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*4D\r\n";
        let mut d = GnssDecoder::new();
        let mut fixes = Vec::new();
        d.decode(stream, |f| {
            if let GnssFrame::Fix(fix) = f {
                fixes.push(fix)
            }
        });
        while let Some(f) = d.finish() {
            if let GnssFrame::Fix(fix) = f {
                fixes.push(fix)
            }
        }
        assert_eq!(d.stats().frames_ok, 4, "{:?}", d.stats());
        assert_eq!(fixes.len(), 2);
        let first = fixes[0];
        assert_eq!(first.time_of_day_ms, Some(45_319_000));
        assert_eq!(first.fix.fix, FixType::Fix3D);
        assert_eq!(first.fix.pdop, Some(2.5));
        assert!((first.fix.speed_mps.unwrap_or(0.0) - 22.4 * KNOT_MPS).abs() < 1e-12);
        assert_eq!(first.fix.track_deg, Some(84.4));
        assert_eq!(
            first.date,
            Some(Date {
                year: 1994,
                month: 3,
                day: 23
            })
        );
        // 1994-03-23T12:35:19Z
        assert_eq!(first.fix.utc_ns, Some(764_426_119_000_000_000));
        assert_eq!(fixes[1].time_of_day_ms, Some(45_320_000));
        let json = serde_json::to_string(&GnssFrame::Fix(first)).unwrap_or_default();
        assert!(json.contains("\"kind\":\"fix\""), "{json}");
        assert!(json.contains("\"lat_deg\":48.1173"), "{json}");
    }
}
