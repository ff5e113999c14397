//! Mixed GNSS stream decoder: NMEA 0183 and u-blox UBX interleaved on one port (as u-blox
//! receivers emit by default). Yields every message, plus one merged [`EpochFix`] per
//! navigation epoch, the way gpsd merges a cycle into one TPV report.
//!
//! **Epochs.** Every message of one epoch is merged into one fix, whichever protocol carried
//! it. An epoch is keyed by its UTC time of day (NMEA GGA, RMC, GNS, GLL, GST, ZDA carry
//! one) and by its GPS time of week (UBX NAV messages carry iTOW). Once a NAV-PVT or
//! NAV-TIMEUTC with valid UTC has shown the receiver's GPS−UTC offset, an iTOW maps to a
//! time of day, so a UBX message and an NMEA sentence are of the same epoch when the two
//! times agree within 10 ms (NMEA prints hundredths of a second); before that, messages
//! with a key of the other protocol join the epoch in progress (receivers send all messages
//! of an epoch before the next epoch's first). Sentences without a time (GSA, VTG, GSV,
//! HDT) join the epoch in progress.
//!
//! **Closing an epoch** (never later than the next epoch's first message, no timers):
//! - a message whose key differs from the epoch's (a new time of day, a new iTOW, or an
//!   iTOW that maps to another time of day) closes it before the message is merged;
//! - UBX-NAV-EOE (end of epoch) closes it at once. A receiver may send NMEA after NAV-EOE:
//!   a message with the key of the epoch just closed by NAV-EOE is then yielded as a frame
//!   but not merged (the fix is out already), and from then on NAV-EOE no longer closes
//!   epochs (the decoder has learned that it does not end this receiver's epoch);
//! - [`Decoder::finish`] closes the epoch in progress at the end of the input.
//!
//! **Which source wins per field.** Within one protocol the latest message wins (as in
//! gpsd), except that NAV-PVT is never overwritten by NAV-POSLLH or NAV-VELNED (coarser,
//! cm/s velocity; gpsd's speed is NAV-PVT's too); across protocols UBX wins (NAV-PVT, else NAV-POSLLH/NAV-VELNED/NAV-STATUS/
//! NAV-SAT/NAV-TIMEUTC), and NMEA fills only what no UBX message of the epoch gave:
//! - position, heights, velocity, speed, track, accuracies (NAV-PVT hAcc/vAcc/sAcc over the
//!   σ of GST), satellites used, PDOP, UTC time and date: UBX first, then GGA/GNS/RMC/GLL,
//!   VTG, GST, GSA, ZDA;
//! - HDOP and VDOP: GGA/GNS and GSA (UBX NAV-PVT carries only PDOP);
//! - fix type: NAV-PVT (else NAV-STATUS) when the epoch has one, else the NMEA judgement
//!   ([`NmeaEpoch::fix_type`]: GGA/GNS quality and altitude, then the GSA mode; a GGA of
//!   no fix or fewer than 3 satellites yields to a GSA fix from 3 or more);
//! - GPS week and time of week: UBX only.
//!
//! `source` says whether any UBX message contributed ([`FixSource::Ubx`]) or only NMEA.

use std::collections::VecDeque;

use serde::Serialize;

use super::nmea::{self, Date, NmeaSentence, TimeOfDay};
use super::reading::{Reading, ToReading};
use super::ubx::{self, UbxMessage};
use super::{Decoder, EncodeError, Scan, StreamBuffer};
use crate::types::{DecoderStats, FixType, GnssFix, ImuSample};

/// Which protocol an epoch was merged from: `Ubx` when any UBX navigation message
/// contributed (its fields win), `Nmea` when only NMEA sentences did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FixSource {
    Nmea,
    Ubx,
}

/// Which protocols feed the merged fixes; every message is yielded as a frame either way.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum MergeSources {
    /// NMEA and UBX merged per epoch (the default).
    #[default]
    Both,
    /// Fixes from NMEA sentences alone (UBX messages are yielded, not merged).
    Nmea,
    /// Fixes from UBX messages alone (NMEA sentences are yielded, not merged).
    Ubx,
}

/// One merged navigation epoch.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct EpochFix {
    pub source: FixSource,
    /// UTC milliseconds since midnight: the NMEA sentences' time when the epoch has one,
    /// else NAV-PVT/NAV-TIMEUTC's when UTC is valid.
    pub time_of_day_ms: Option<i64>,
    /// GPS time of week, ms (when a UBX message contributed).
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
    /// Satellites the cycle's GSA sentences list as used (summed over constellations).
    gsa_used: u32,
    gga_quality: Option<u8>,
    gga_sats: Option<u8>,
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
                self.gga_sats = s.num_sats;
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
                self.gsa_used += s.sat_ids.iter().filter(|id| id.is_some()).count() as u32;
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
            NmeaSentence::Hdt(s) => {
                f.heading_deg = s.heading_deg.map(|h| h.to_f64()).or(f.heading_deg);
            }
            NmeaSentence::Gsv(_) | NmeaSentence::Proprietary(_) | NmeaSentence::Other(_) => {}
        }
    }

    /// Fix type of a cycle, judged from its own sentences: GGA (or GNS) quality and
    /// altitude first (quality 0 is no fix, otherwise 3D with an altitude and 2D without),
    /// then the GSA mode. A GGA that says no fix or fewer than 3 satellites yields to a GSA
    /// of the cycle that says a 2D or 3D fix from 3 or more satellites (gpsd does the same:
    /// such a GGA is a receiver reporting before its count is updated). A cycle with only a
    /// valid RMC or GLL keeps the previous cycle's dimension (2D at least), as gpsd does.
    /// DGNSS/RTK qualities refine a 3D fix.
    fn fix_type(&self, previous: FixType) -> FixType {
        let has_alt = self.fix.height_msl_m.is_some();
        let weak_valid = matches!(self.rmc_status, Some('A' | 'D'))
            || matches!(self.gll_status, Some('A' | 'D'));
        let weak_gga = self.gga_quality == Some(0) || self.gga_sats.is_some_and(|n| n < 3);
        if weak_gga && self.gsa_used >= 3 {
            match self.gsa_mode {
                Some(3) => return FixType::Fix3D,
                Some(2) => return FixType::Fix2D,
                _ => {}
            }
        }
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

/// How good a UBX message's position or velocity is, lowest first: within an epoch a message
/// never overwrites the value of a better one, whichever order they come in, and the latest
/// of equal rank wins (as in gpsd).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Rank {
    /// NAV-POSECEF / NAV-VELECEF.
    Ecef,
    /// NAV-SOL (ECEF position and velocity, with fix type, satellites and PDOP).
    Sol,
    /// NAV-POSLLH / NAV-VELNED (cm/s velocity).
    Llh,
    /// NAV-PVT (mm/s velocity).
    Pvt,
    /// NAV-HPPOSLLH (0.1 mm position).
    HighPrecision,
}

/// Accumulates UBX messages of one epoch (same iTOW).
#[derive(Debug, Default, Clone)]
struct UbxEpoch {
    itow_ms: Option<u32>,
    fix: GnssFix,
    has_data: bool,
    date: Option<Date>,
    time_of_day_ms: Option<i64>,
    /// GPS week from NAV-SOL or NAV-TIMEGPS of this epoch.
    week: Option<u16>,
    /// NAV-PVT, NAV-SOL or NAV-STATUS gave the fix type.
    fix_known: bool,
    /// Rank of the message the position / the velocity came from.
    position_rank: Option<Rank>,
    velocity_rank: Option<Rank>,
    /// ECEF velocity (NAV-SOL, NAV-VELECEF), turned into NED once the position is known.
    ecef_velocity: Option<[f64; 3]>,
    /// The fix type, satellites and PDOP came from NAV-PVT (NAV-SOL does not overwrite them).
    has_pvt: bool,
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

    /// Whether a position of `rank` may replace the epoch's (and takes its place if so).
    fn take_position(&mut self, rank: Rank) -> bool {
        let better = self.position_rank.is_none_or(|r| rank >= r);
        if better {
            self.position_rank = Some(rank);
        }
        better
    }

    fn take_velocity(&mut self, rank: Rank) -> bool {
        let better = self.velocity_rank.is_none_or(|r| rank >= r);
        if better {
            self.velocity_rank = Some(rank);
        }
        better
    }

    fn set_ecef_position(&mut self, rank: Rank, ecef_m: [f64; 3]) {
        if self.take_position(rank) {
            if let Some((lat, lon, height)) = ecef_to_geodetic(ecef_m) {
                let f = &mut self.fix;
                f.lat_deg = Some(lat);
                f.lon_deg = Some(lon);
                f.height_m = Some(height);
                f.height_msl_m = None;
                f.h_acc_m = None;
                f.v_acc_m = None;
            }
        }
    }

    fn set_ecef_velocity(&mut self, rank: Rank, ecef_vel_mps: [f64; 3], s_acc_mps: f64) {
        if self.take_velocity(rank) {
            self.ecef_velocity = Some(ecef_vel_mps);
            self.fix.vel_ned = None;
            self.fix.s_acc_mps = Some(s_acc_mps);
        }
    }

    fn apply(&mut self, msg: &UbxMessage) {
        match msg {
            UbxMessage::NavPvt(m) => {
                if self.take_position(Rank::Pvt) {
                    let f = &mut self.fix;
                    f.lat_deg = Some(m.lat_deg);
                    f.lon_deg = Some(m.lon_deg);
                    f.height_m = Some(m.height_m);
                    f.height_msl_m = Some(m.height_msl_m);
                    f.h_acc_m = Some(m.h_acc_m);
                    f.v_acc_m = Some(m.v_acc_m);
                }
                if self.take_velocity(Rank::Pvt) {
                    let f = &mut self.fix;
                    f.vel_ned = Some([m.vel_n_mps, m.vel_e_mps, m.vel_d_mps]);
                    f.speed_mps = Some(m.ground_speed_mps);
                    f.track_deg = Some(m.head_mot_deg);
                    f.s_acc_mps = Some(m.s_acc_mps);
                    self.ecef_velocity = None;
                }
                let f = &mut self.fix;
                f.num_sats = Some(m.num_sv);
                f.pdop = Some(m.pdop);
                f.fix = pvt_fix_type(m.fix_type, m.flags);
                // flags bit 5: headVehValid (heading of the vehicle, dead-reckoning receivers).
                if m.flags & 0x20 != 0 {
                    f.heading_deg = m.head_veh_deg.or(f.heading_deg);
                }
                self.fix_known = true;
                self.has_pvt = true;
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
            UbxMessage::NavHpposllh(m) => {
                // flags bit 0: invalidLlh.
                if m.flags & 0x01 == 0 && self.take_position(Rank::HighPrecision) {
                    let f = &mut self.fix;
                    f.lat_deg = Some(m.lat_deg);
                    f.lon_deg = Some(m.lon_deg);
                    f.height_m = Some(m.height_m);
                    f.height_msl_m = Some(m.height_msl_m);
                    f.h_acc_m = Some(m.h_acc_m);
                    f.v_acc_m = Some(m.v_acc_m);
                }
            }
            UbxMessage::NavPosllh(m) => {
                if self.take_position(Rank::Llh) {
                    let f = &mut self.fix;
                    f.lat_deg = Some(m.lat_deg);
                    f.lon_deg = Some(m.lon_deg);
                    f.height_m = Some(m.height_m);
                    f.height_msl_m = Some(m.height_msl_m);
                    f.h_acc_m = Some(m.h_acc_m);
                    f.v_acc_m = Some(m.v_acc_m);
                }
            }
            UbxMessage::NavVelned(m) => {
                if self.take_velocity(Rank::Llh) {
                    let f = &mut self.fix;
                    f.vel_ned = Some([m.vel_n_mps, m.vel_e_mps, m.vel_d_mps]);
                    f.speed_mps = Some(m.ground_speed_mps);
                    f.track_deg = Some(m.heading_deg);
                    f.s_acc_mps = Some(m.s_acc_mps);
                    self.ecef_velocity = None;
                }
            }
            UbxMessage::NavSol(m) => {
                self.set_ecef_position(Rank::Sol, m.ecef_m);
                self.set_ecef_velocity(Rank::Sol, m.ecef_vel_mps, m.s_acc_mps);
                if !self.has_pvt {
                    let f = &mut self.fix;
                    f.fix = pvt_fix_type(m.gps_fix, m.flags & 0x02);
                    f.num_sats = Some(m.num_sv);
                    f.pdop = Some(m.pdop);
                    self.fix_known = true;
                }
                // flags bit 2: week number valid.
                if m.flags & 0x04 != 0 {
                    self.week = u16::try_from(m.week).ok();
                }
            }
            UbxMessage::NavPosecef(m) => self.set_ecef_position(Rank::Ecef, m.ecef_m),
            UbxMessage::NavVelecef(m) => {
                self.set_ecef_velocity(Rank::Ecef, m.ecef_vel_mps, m.s_acc_mps)
            }
            UbxMessage::NavTimegps(m) => {
                // valid bits: 0 time of week, 1 week, 2 leap seconds.
                if m.valid & 0x02 != 0 {
                    self.week = u16::try_from(m.week).ok();
                }
                if m.valid & 0x07 == 0x07 && self.time_of_day_ms.is_none() {
                    if let Some((date, ms, sub_ms_ns)) = gps_to_utc(m) {
                        self.date = Some(date);
                        self.time_of_day_ms = Some(ms.rem_euclid(DAY_MS));
                        self.fix.utc_ns = ms
                            .checked_mul(1_000_000)
                            .and_then(|ns| ns.checked_add(sub_ms_ns));
                    }
                }
            }
            UbxMessage::NavRelposned(m) => {
                if let Some(heading) = m.valid_heading_deg() {
                    self.fix.heading_deg = Some(heading);
                }
            }
            UbxMessage::NavStatus(m) => {
                if self.fix.fix == FixType::NoFix {
                    self.fix.fix = pvt_fix_type(m.gps_fix, m.flags & 0x02);
                }
                self.fix_known = true;
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
                self.fix.num_sats = Some(u8::try_from(used).unwrap_or(u8::MAX));
            }
            UbxMessage::NavDop(m) => {
                let f = &mut self.fix;
                f.pdop = f.pdop.or(Some(m.pdop));
                f.hdop = Some(m.hdop);
                f.vdop = Some(m.vdop);
            }
            _ => return,
        }
        self.has_data = true;
    }

    /// The epoch's fix, and whether a message of it gave the fix type.
    fn take(&mut self, week: Option<u16>) -> Option<(EpochFix, bool)> {
        let epoch = std::mem::take(self);
        let fix_known = epoch.fix_known;
        epoch.has_data.then(|| (epoch.into_fix(week), fix_known))
    }

    fn into_fix(self, week: Option<u16>) -> EpochFix {
        let mut fix = self.fix;
        if let (Some(v), Some(lat), Some(lon)) = (self.ecef_velocity, fix.lat_deg, fix.lon_deg) {
            let [n, e, d] = ecef_to_ned(v, lat, lon);
            fix.vel_ned = Some([n, e, d]);
            fix.speed_mps = Some(n.hypot(e));
            fix.track_deg = Some(e.atan2(n).to_degrees().rem_euclid(360.0));
        }
        fix.week = self.week.or(week);
        fix.tow_s = self.itow_ms.map(|ms| f64::from(ms) / 1000.0);
        EpochFix {
            source: FixSource::Ubx,
            time_of_day_ms: self.time_of_day_ms,
            itow_ms: self.itow_ms,
            date: self.date,
            fix,
        }
    }
}

/// The fix of one HNR-PVT: the high-rate solution is complete in itself and stands apart
/// from the NAV epochs (its own times, up to 30 Hz), so it is a fix of its own.
fn hnr_fix(m: &ubx::HnrPvt, week: Option<u16>) -> EpochFix {
    let mut epoch = UbxEpoch {
        itow_ms: Some(m.itow_ms),
        ..UbxEpoch::default()
    };
    if m.valid & 0x03 == 0x03 {
        let date = Date {
            year: m.year,
            month: m.month,
            day: m.day,
        };
        epoch.set_utc(date, m.hour, m.min, m.sec, m.nano_ns);
    }
    let f = &mut epoch.fix;
    f.fix = pvt_fix_type(m.gps_fix, m.flags & 0x02);
    f.lat_deg = Some(m.lat_deg);
    f.lon_deg = Some(m.lon_deg);
    f.height_m = Some(m.height_m);
    f.height_msl_m = Some(m.height_msl_m);
    f.h_acc_m = Some(m.h_acc_m);
    f.v_acc_m = Some(m.v_acc_m);
    f.speed_mps = Some(m.ground_speed_mps);
    f.track_deg = Some(m.head_mot_deg);
    f.s_acc_mps = Some(m.s_acc_mps);
    // flags bit 4: headVehValid.
    f.heading_deg = (m.flags & 0x10 != 0).then_some(m.head_veh_deg);
    epoch.into_fix(week)
}

/// WGS-84 semi-major axis, m, and first eccentricity squared.
const WGS84_A: f64 = 6_378_137.0;
const WGS84_E2: f64 = 6.694_379_990_141_33e-3;

/// Geodetic latitude, longitude (degrees) and ellipsoidal height (m) of an ECEF position
/// (`None` near the centre of the Earth, where the receiver has no solution). Bowring's
/// start and three fixed-point steps: below 1 µm near the surface; written here because the
/// drivers crate has no geodesy dependency for this one conversion.
fn ecef_to_geodetic([x, y, z]: [f64; 3]) -> Option<(f64, f64, f64)> {
    let p = x.hypot(y);
    if p.hypot(z) < 1.0e5 {
        return None;
    }
    let b = WGS84_A * (1.0 - WGS84_E2).sqrt();
    let ep2 = WGS84_E2 / (1.0 - WGS84_E2);
    let theta = (z * WGS84_A).atan2(p * b);
    let mut lat =
        (z + ep2 * b * theta.sin().powi(3)).atan2(p - WGS84_E2 * WGS84_A * theta.cos().powi(3));
    let mut height = 0.0;
    for _ in 0..3 {
        let n = WGS84_A / (1.0 - WGS84_E2 * lat.sin().powi(2)).sqrt();
        height = if lat.cos().abs() > 1e-9 {
            p / lat.cos() - n
        } else {
            z.abs() - n * (1.0 - WGS84_E2)
        };
        lat = z.atan2(p * (1.0 - WGS84_E2 * n / (n + height)));
    }
    Some((lat.to_degrees(), y.atan2(x).to_degrees(), height))
}

/// An ECEF vector in the local north, east, down frame at `lat_deg`, `lon_deg`.
fn ecef_to_ned([x, y, z]: [f64; 3], lat_deg: f64, lon_deg: f64) -> [f64; 3] {
    let (sl, cl) = lat_deg.to_radians().sin_cos();
    let (so, co) = lon_deg.to_radians().sin_cos();
    [
        -sl * co * x - sl * so * y + cl * z,
        -so * x + co * y,
        -cl * co * x - cl * so * y - sl * z,
    ]
}

/// Unix time of the GPS epoch (1980-01-06T00:00:00Z), ms.
const GPS_EPOCH_UNIX_MS: i64 = 315_964_800_000;

/// Proleptic Gregorian date of a day count since 1970-01-01 (inverse of `days_from_civil`).
fn civil_from_days(days: i64) -> Option<Date> {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = (doy - (153 * mp + 2) / 5 + 1) as u8;
    let month = if mp < 10 { mp + 3 } else { mp - 9 } as u8;
    let year = yoe + era * 400 + i64::from(month <= 2);
    Some(Date {
        year: u16::try_from(year).ok()?,
        month,
        day,
    })
}

/// UTC of a NAV-TIMEGPS (week, iTOW, fTOW, leap seconds): the date, Unix ms (floor) and the
/// nanoseconds below that millisecond.
fn gps_to_utc(m: &ubx::NavTimegps) -> Option<(Date, i64, i64)> {
    let week = i64::from(m.week);
    if week < 0 {
        return None;
    }
    // Week 32767 is past 2^63 ns since 1970: checked, so a corrupt week gives no time.
    let utc_ns = (week * 604_800_000 + i64::from(m.itow_ms) + GPS_EPOCH_UNIX_MS
        - i64::from(m.leap_s) * 1000)
        .checked_mul(1_000_000)?
        .checked_add(i64::from(m.ftow_ns))?;
    let ms = utc_ns.div_euclid(1_000_000);
    let date = civil_from_days(ms.div_euclid(DAY_MS))?;
    Some((date, ms, utc_ns.rem_euclid(1_000_000)))
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
        UbxMessage::NavSol(m) => Some(m.itow_ms),
        UbxMessage::NavPosecef(m) => Some(m.itow_ms),
        UbxMessage::NavVelecef(m) => Some(m.itow_ms),
        UbxMessage::NavTimegps(m) => Some(m.itow_ms),
        UbxMessage::NavHpposllh(m) => Some(m.itow_ms),
        UbxMessage::NavRelposned(m) => Some(m.itow_ms),
        UbxMessage::NavDop(m) => Some(m.itow_ms),
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

/// One epoch's fix from its UBX part and its NMEA part: UBX wins per field, NMEA fills the
/// rest (the rule in the module doc).
fn merge(ubx: Option<(EpochFix, bool)>, nmea: Option<EpochFix>) -> Option<EpochFix> {
    let (u, n) = match (ubx, nmea) {
        (None, None) => return None,
        (Some((u, _)), None) => return Some(u),
        (None, Some(n)) => return Some(n),
        (Some(u), Some(n)) => (u, n),
    };
    let ((u, fix_known), n) = (u, n);
    let (a, b) = (u.fix, n.fix);
    // Position and heights go as a pair from one source, so lat/lon never mix.
    let (lat_deg, lon_deg) = if a.lat_deg.is_some() && a.lon_deg.is_some() {
        (a.lat_deg, a.lon_deg)
    } else {
        (b.lat_deg, b.lon_deg)
    };
    let (height_m, height_msl_m) = if a.height_m.is_some() || a.height_msl_m.is_some() {
        (a.height_m, a.height_msl_m)
    } else {
        (b.height_m, b.height_msl_m)
    };
    let fix = GnssFix {
        week: a.week,
        tow_s: a.tow_s,
        utc_ns: a.utc_ns.or(b.utc_ns),
        lat_deg,
        lon_deg,
        height_m,
        height_msl_m,
        vel_ned: a.vel_ned.or(b.vel_ned),
        speed_mps: a.speed_mps.or(b.speed_mps),
        track_deg: a.track_deg.or(b.track_deg),
        heading_deg: a.heading_deg.or(b.heading_deg),
        h_acc_m: a.h_acc_m.or(b.h_acc_m),
        v_acc_m: a.v_acc_m.or(b.v_acc_m),
        s_acc_mps: a.s_acc_mps.or(b.s_acc_mps),
        fix: if fix_known { a.fix } else { b.fix },
        num_sats: a.num_sats.or(b.num_sats),
        pdop: a.pdop.or(b.pdop),
        hdop: a.hdop.or(b.hdop),
        vdop: a.vdop.or(b.vdop),
    };
    Some(EpochFix {
        source: FixSource::Ubx,
        time_of_day_ms: n.time_of_day_ms.or(u.time_of_day_ms),
        itow_ms: u.itow_ms,
        date: u.date.or(n.date),
        fix,
    })
}

/// Milliseconds in a day.
const DAY_MS: i64 = 86_400_000;

/// Whether two times of day (ms) are the same epoch: within 10 ms, across midnight too.
fn same_time_of_day(a: i64, b: i64) -> bool {
    let d = (a - b).rem_euclid(DAY_MS);
    !(10..=DAY_MS - 10).contains(&d)
}

/// The keys of an epoch closed by NAV-EOE, to recognise messages sent after it.
#[derive(Debug, Clone, Copy)]
struct ClosedKeys {
    time_of_day_ms: Option<i64>,
    itow_ms: Option<u32>,
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
    /// GPS time of week minus UTC time of day, ms modulo a day (whole seconds), learned
    /// from NAV-PVT/NAV-TIMEUTC with valid UTC: maps an iTOW to a time of day.
    itow_minus_utc_ms: Option<i64>,
    /// NAV-EOE closes epochs until a message of an epoch it closed arrives after it.
    eoe_closes: bool,
    /// The keys of the last epoch NAV-EOE closed, while no message of a new epoch came.
    eoe_closed: Option<ClosedKeys>,
    sources: MergeSources,
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
            itow_minus_utc_ms: None,
            eoe_closes: true,
            eoe_closed: None,
            sources: MergeSources::Both,
            finished: false,
        }
    }

    /// Restricts the fixes to one protocol's messages (to compare a receiver's NMEA and UBX
    /// solutions, or to follow a consumer that merges differently).
    pub fn with_merge_sources(mut self, sources: MergeSources) -> Self {
        self.sources = sources;
        self
    }

    /// Sets the UTC date assumed for NMEA epochs until a sentence (RMC, ZDA) gives one.
    pub fn with_date(mut self, date: Date) -> Self {
        self.nmea_date = Some(date);
        self
    }

    /// The UTC time of day of an iTOW, once the GPS−UTC offset is known.
    fn itow_time_of_day(&self, itow_ms: u32) -> Option<i64> {
        self.itow_minus_utc_ms
            .map(|offset| (i64::from(itow_ms) - offset).rem_euclid(DAY_MS))
    }

    /// Whether the epoch in progress holds no message with a key.
    fn epoch_unkeyed(&self) -> bool {
        self.nmea_epoch.key_ms.is_none() && self.ubx_epoch.itow_ms.is_none()
    }

    /// Closes the epoch in progress: its merged fix, if it has data, is queued.
    fn close_epoch(&mut self) {
        let nmea = self
            .nmea_epoch
            .take(self.nmea_date, &mut self.nmea_last_fix);
        let ubx = self.ubx_epoch.take(self.ubx_week);
        if let Some(fix) = merge(ubx, nmea) {
            self.ready.push_back(GnssFrame::Fix(fix));
        }
    }

    /// Whether a message keyed `time_of_day_ms` / `itow_ms` belongs to the epoch NAV-EOE
    /// just closed (the receiver sends messages after NAV-EOE: stop closing on it).
    fn is_late(&mut self, time_of_day_ms: Option<i64>, itow_ms: Option<u32>) -> bool {
        let Some(closed) = self.eoe_closed else {
            return false;
        };
        let closed_tod = closed
            .time_of_day_ms
            .or_else(|| closed.itow_ms.and_then(|i| self.itow_time_of_day(i)));
        let tod = time_of_day_ms.or_else(|| itow_ms.and_then(|i| self.itow_time_of_day(i)));
        let late = match (itow_ms, closed.itow_ms, tod, closed_tod) {
            (Some(a), Some(b), _, _) => a == b,
            (_, _, Some(a), Some(b)) => same_time_of_day(a, b),
            _ => false,
        };
        if late {
            self.eoe_closes = false;
        } else {
            self.eoe_closed = None;
        }
        late
    }

    fn on_nmea(&mut self, sentence: NmeaSentence) {
        if self.sources == MergeSources::Ubx {
            self.ready.push_back(GnssFrame::Nmea(sentence));
            return;
        }
        let key = sentence_time(&sentence).map(|t| t.millis_of_day());
        if let Some(key) = key {
            if self.epoch_unkeyed() && self.is_late(Some(key), None) {
                self.ready.push_back(GnssFrame::Nmea(sentence));
                return;
            }
            let other_epoch = match self.nmea_epoch.key_ms {
                Some(current) => current != key,
                None => self
                    .ubx_epoch
                    .itow_ms
                    .and_then(|i| self.itow_time_of_day(i))
                    .is_some_and(|tod| !same_time_of_day(tod, key)),
            };
            if other_epoch {
                self.close_epoch();
            }
            self.nmea_epoch.key_ms = Some(key);
        }
        self.nmea_epoch.apply(&sentence, &mut self.nmea_date);
        self.ready.push_back(GnssFrame::Nmea(sentence));
    }

    fn on_ubx(&mut self, msg: UbxMessage) {
        if self.sources == MergeSources::Nmea {
            self.ready.push_back(GnssFrame::Ubx(msg));
            return;
        }
        match &msg {
            UbxMessage::RxmRawx(raw) => self.ubx_week = Some(raw.week),
            UbxMessage::NavSol(m) if m.flags & 0x04 != 0 => {
                self.ubx_week = u16::try_from(m.week).ok();
            }
            UbxMessage::NavTimegps(m) if m.valid & 0x02 != 0 => {
                self.ubx_week = u16::try_from(m.week).ok();
            }
            UbxMessage::HnrPvt(m) => {
                let fix = hnr_fix(m, self.ubx_week);
                self.ready.push_back(GnssFrame::Ubx(msg));
                self.ready.push_back(GnssFrame::Fix(fix));
                return;
            }
            _ => {}
        }
        let end_of_epoch =
            matches!(&msg, UbxMessage::Other(raw) if raw.class == 0x01 && raw.id == 0x61);
        if let Some(itow) = ubx_itow(&msg) {
            if self.epoch_unkeyed() && self.is_late(None, Some(itow)) {
                self.ready.push_back(GnssFrame::Ubx(msg));
                return;
            }
            let other_epoch = match self.ubx_epoch.itow_ms {
                Some(current) => current != itow,
                None => match (self.nmea_epoch.key_ms, self.itow_time_of_day(itow)) {
                    (Some(key), Some(tod)) => !same_time_of_day(tod, key),
                    _ => false,
                },
            };
            if other_epoch {
                self.close_epoch();
            }
            self.ubx_epoch.itow_ms = Some(itow);
        }
        self.ubx_epoch.apply(&msg);
        if let (Some(itow), Some(tod)) = (self.ubx_epoch.itow_ms, self.ubx_epoch.time_of_day_ms) {
            // Whole seconds: NAV-PVT's UTC may be a rounding step off the epoch's iTOW.
            let offset = (i64::from(itow) - tod).rem_euclid(DAY_MS);
            self.itow_minus_utc_ms = Some((offset + 500) / 1000 * 1000 % DAY_MS);
        }
        self.ready.push_back(GnssFrame::Ubx(msg));
        if end_of_epoch && self.eoe_closes {
            self.eoe_closed = Some(ClosedKeys {
                time_of_day_ms: self.nmea_epoch.key_ms,
                itow_ms: self.ubx_epoch.itow_ms,
            });
            self.close_epoch();
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
            if !self.buffer.skip_to_start(&[b'$', b'!', 0xB5]) {
                return None;
            }
            let data = self.buffer.data();
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
        self.close_epoch();
        self.ready.pop_front()
    }

    fn stats(&self) -> DecoderStats {
        self.buffer.stats()
    }
}

/// Merged navigation epochs are readings; the raw sentences and messages are not.
impl ToReading for GnssFrame {
    fn to_reading(self) -> Option<Reading> {
        match self {
            GnssFrame::Fix(epoch) => Some(Reading::Gnss(epoch.fix)),
            GnssFrame::Nmea(_) | GnssFrame::Ubx(_) => None,
        }
    }
}

/// The epoch of a u-blox receiver with its default output: NMEA GGA and RMC, then UBX
/// NAV-PVT and NAV-EOE, all for the same fix.
pub fn encode_fix(fix: &GnssFix, out: &mut Vec<u8>) -> Result<(), EncodeError> {
    nmea::encode_fix(fix, out)?;
    ubx::encode_fix(fix, out)
}

/// The IMU of a u-blox dead-reckoning receiver (NEO-M8L, ZED-F9R) on a port of its own:
/// ESF-RAW (several samples per message) and ESF-MEAS (one) become [`ImuSample`]s; fixes,
/// other UBX messages and NMEA on the same port are decoded and dropped (the IMU readings of
/// [`GnssEsfDecoder`]).
#[derive(Debug, Clone, Default)]
pub struct EsfImuDecoder {
    port: GnssEsfDecoder,
}

impl EsfImuDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    /// The next IMU sample among `next`'s readings.
    fn imu(mut next: impl FnMut() -> Option<Reading>) -> Option<ImuSample> {
        loop {
            if let Reading::Imu(sample) = next()? {
                return Some(sample);
            }
        }
    }
}

impl Decoder for EsfImuDecoder {
    type Frame = ImuSample;

    fn push(&mut self, bytes: &[u8]) {
        self.port.push(bytes);
    }

    fn poll(&mut self) -> Option<ImuSample> {
        Self::imu(|| self.port.poll())
    }

    fn stats(&self) -> DecoderStats {
        self.port.stats()
    }

    fn finish(&mut self) -> Option<ImuSample> {
        Self::imu(|| self.port.finish())
    }
}

/// A u-blox dead-reckoning receiver's one port as both of its devices: the merged fixes
/// of [`GnssDecoder`] and the IMU samples of its ESF-RAW and ESF-MEAS messages (as
/// [`EsfImuDecoder`] gives them), in the order they complete. One decoder, so the port's
/// counters (checksum errors, resyncs) are counted once.
#[derive(Debug, Clone, Default)]
pub struct GnssEsfDecoder {
    gnss: GnssDecoder,
    ready: VecDeque<Reading>,
}

impl GnssEsfDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    fn take(&mut self, frame: GnssFrame) {
        match frame {
            GnssFrame::Fix(epoch) => self.ready.push_back(Reading::Gnss(epoch.fix)),
            GnssFrame::Ubx(UbxMessage::EsfRaw(raw)) => self
                .ready
                .extend(raw.to_imu_samples().into_iter().map(Reading::Imu)),
            GnssFrame::Ubx(UbxMessage::EsfMeas(meas)) => {
                self.ready.extend(meas.to_imu_sample().map(Reading::Imu))
            }
            GnssFrame::Ubx(_) | GnssFrame::Nmea(_) => {}
        }
    }
}

impl Decoder for GnssEsfDecoder {
    type Frame = Reading;

    fn push(&mut self, bytes: &[u8]) {
        self.gnss.push(bytes);
    }

    fn poll(&mut self) -> Option<Reading> {
        while self.ready.is_empty() {
            let frame = self.gnss.poll()?;
            self.take(frame);
        }
        self.ready.pop_front()
    }

    fn stats(&self) -> DecoderStats {
        self.gnss.stats()
    }

    fn finish(&mut self) -> Option<Reading> {
        while self.ready.is_empty() {
            let frame = self.gnss.finish()?;
            self.take(frame);
        }
        self.ready.pop_front()
    }
}

/// The reading decoders of the `gnss` and `ubx` rows: merged fixes, and with
/// [`DecoderOptions::esf_imu`](super::DecoderOptions::esf_imu) the receiver's ESF IMU
/// samples too.
pub fn readings(
    options: &super::DecoderOptions,
) -> Result<super::reading::ReadingDecoderFactory, super::OpenError> {
    Ok(if options.esf_imu {
        super::reading::byte_readings(GnssEsfDecoder::new)
    } else {
        super::reading::byte_readings(GnssDecoder::new)
    })
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

    use crate::codec::ubx::{NavPvt, RawMessage, UbxEncoder};
    use crate::codec::Encoder;

    /// The fix type of one NMEA cycle (GGA then GSA, with an altitude) and the next one's
    /// GGA that closes it.
    fn gga_gsa_fix(quality: u8, gga_sats: u8, gsa_mode: u8, gsa_used: &[u8]) -> FixType {
        let ids: Vec<String> = (0..12)
            .map(|i| {
                gsa_used
                    .get(i)
                    .map_or(String::new(), |id| format!("{id:02}"))
            })
            .collect();
        let stream = [
            format!("GPGGA,120326,4221.3871,N,01322.0800,E,{quality},{gga_sats:02},3.1,746.1,M,44.2,M,,"),
            format!("GPGSA,A,{gsa_mode},{},3.1,3.1,", ids.join(",")),
            "GPGGA,120327,4221.3872,N,01322.0800,E,1,03,3.1,746.1,M,44.2,M,,".to_string(),
        ]
        .iter()
        .map(|b| with_checksum(b))
        .collect::<String>();
        let fixes = fixes_of(stream.as_bytes());
        assert_eq!(fixes.len(), 2, "{fixes:#?}");
        fixes[0].1.fix.fix
    }

    #[test]
    fn a_gga_with_fewer_than_3_satellites_yields_to_the_cycles_gsa_mode() {
        // The Garmin GPS 25LP of gpsd's captures: quality 1, altitude, 0 satellites; its GSA
        // says 2D from 3 satellites.
        assert_eq!(gga_gsa_fix(1, 0, 2, &[1, 3, 14]), FixType::Fix2D);
        assert_eq!(gga_gsa_fix(0, 0, 3, &[1, 3, 14, 19]), FixType::Fix3D);
        // A GSA with fewer than 3 satellites, or saying no fix, does not overrule the GGA.
        assert_eq!(gga_gsa_fix(1, 0, 2, &[1, 3]), FixType::Fix3D);
        assert_eq!(gga_gsa_fix(1, 2, 1, &[1, 3, 14]), FixType::Fix3D);
        assert_eq!(gga_gsa_fix(0, 0, 2, &[1, 3]), FixType::NoFix);
        // With 3 or more satellites the GGA's quality and altitude decide.
        assert_eq!(gga_gsa_fix(1, 3, 2, &[1, 3, 14]), FixType::Fix3D);
    }

    /// A NAV-PVT of 2026-12-01 at `sec` seconds past 12:00:00 UTC (iTOW with 18 leap
    /// seconds: Tuesday), 3D fix at 48.1°N 11.5°E, 2 m/s north.
    fn pvt(sec: u8) -> Vec<u8> {
        let itow = (2 * 86_400 + 12 * 3600 + u32::from(sec) + 18) * 1000;
        let m = NavPvt {
            itow_ms: itow,
            year: 2026,
            month: 12,
            day: 1,
            hour: 12,
            min: 0,
            sec,
            valid: 0x07,
            t_acc_ns: 20,
            nano_ns: 0,
            fix_type: 3,
            flags: 0x01,
            flags2: 0,
            num_sv: 11,
            lon_deg: 11.5,
            lat_deg: 48.1,
            height_m: 600.0,
            height_msl_m: 553.0,
            h_acc_m: 1.5,
            v_acc_m: 2.5,
            vel_n_mps: 2.0,
            vel_e_mps: 0.0,
            vel_d_mps: 0.0,
            ground_speed_mps: 2.0,
            head_mot_deg: 0.0,
            s_acc_mps: 0.1,
            head_acc_deg: 3.0,
            pdop: 1.8,
            flags3: 0,
            head_veh_deg: None,
            mag_dec_deg: None,
            mag_acc_deg: None,
        };
        let mut out = Vec::new();
        let eoe = UbxMessage::Other(RawMessage {
            class: 0x01,
            id: 0x61,
            payload: itow.to_le_bytes().to_vec(),
        });
        let _ = UbxEncoder.encode(&UbxMessage::NavPvt(m), &mut out);
        out.extend_from_slice(&eoe_bytes(&eoe));
        out
    }

    fn eoe_bytes(eoe: &UbxMessage) -> Vec<u8> {
        let mut out = Vec::new();
        let _ = UbxEncoder.encode(eoe, &mut out);
        out
    }

    /// A NAV-PVT without its NAV-EOE.
    fn pvt_only(sec: u8) -> Vec<u8> {
        let mut bytes = pvt(sec);
        bytes.truncate(bytes.len() - 12);
        bytes
    }

    fn with_checksum(body: &str) -> String {
        let sum = body.bytes().fold(0u8, |a, b| a ^ b);
        format!("${body}*{sum:02X}\r\n")
    }

    /// GGA (other position than the PVT's, HDOP 0.9), RMC and GSA (VDOP 2.1) at 12:00:`sec`.
    fn nmea(sec: u8) -> String {
        [
            format!("GPGGA,1200{sec:02}.00,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"),
            format!("GPRMC,1200{sec:02}.00,A,4807.038,N,01131.000,E,022.4,084.4,011226,,"),
            "GPGSA,A,3,04,05,,09,12,,,24,,,,,2.5,0.9,2.1".to_string(),
        ]
        .iter()
        .map(|b| with_checksum(b))
        .collect()
    }

    /// The fixes of `stream`, each with how many messages had been yielded before it.
    fn fixes_of(stream: &[u8]) -> Vec<(usize, EpochFix)> {
        let mut d = GnssDecoder::new();
        let mut messages = 0;
        let mut fixes = Vec::new();
        let mut take = |f: GnssFrame| match f {
            GnssFrame::Fix(fix) => fixes.push((messages, fix)),
            _ => messages += 1,
        };
        d.decode(stream, &mut take);
        while let Some(f) = d.finish() {
            take(f);
        }
        assert_eq!(d.stats().frames_ok as usize, messages, "{:?}", d.stats());
        fixes
    }

    fn assert_merged(fix: &EpochFix, sec: u8) {
        assert_eq!(fix.source, FixSource::Ubx);
        assert_eq!(fix.time_of_day_ms, Some(43_200_000 + i64::from(sec) * 1000));
        // UBX wins: NAV-PVT's position, speed, satellites, PDOP, accuracies.
        assert_eq!(fix.fix.lat_deg, Some(48.1));
        assert_eq!(fix.fix.lon_deg, Some(11.5));
        assert_eq!(fix.fix.speed_mps, Some(2.0));
        assert_eq!(fix.fix.num_sats, Some(11));
        assert_eq!(fix.fix.pdop, Some(1.8));
        assert_eq!(fix.fix.h_acc_m, Some(1.5));
        assert_eq!(fix.fix.fix, FixType::Fix3D);
        // NMEA fills what NAV-PVT lacks.
        assert_eq!(fix.fix.hdop, Some(0.9));
        assert_eq!(fix.fix.vdop, Some(2.1));
    }

    #[test]
    fn mixed_epoch_closed_by_eoe_gives_one_fix_without_delay() {
        // The simulator's order: NMEA, then NAV-PVT and NAV-EOE.
        let mut stream = Vec::new();
        for sec in 0..3 {
            stream.extend_from_slice(nmea(sec).as_bytes());
            stream.extend_from_slice(&pvt(sec));
        }
        let fixes = fixes_of(&stream);
        assert_eq!(fixes.len(), 3, "{fixes:#?}");
        for (k, (yielded, fix)) in fixes.iter().enumerate() {
            // Out right after the epoch's NAV-EOE, not when the next epoch starts.
            assert_eq!(*yielded, 5 * (k + 1));
            assert_merged(fix, k as u8);
        }
    }

    #[test]
    fn mixed_epoch_without_eoe_closes_on_the_next_epoch() {
        // u-blox order without NAV-EOE: NAV-PVT, then the NMEA of the same epoch.
        let mut stream = Vec::new();
        for sec in 0..3 {
            stream.extend_from_slice(&pvt_only(sec));
            stream.extend_from_slice(nmea(sec).as_bytes());
        }
        let fixes = fixes_of(&stream);
        assert_eq!(fixes.len(), 3, "{fixes:#?}");
        for (k, (yielded, fix)) in fixes.iter().enumerate() {
            assert_eq!(*yielded, 4 * (k + 1));
            assert_merged(fix, k as u8);
        }
    }

    #[test]
    fn nmea_after_eoe_is_learned_and_later_epochs_merge() {
        let mut stream = Vec::new();
        for sec in 0..4 {
            stream.extend_from_slice(&pvt(sec));
            stream.extend_from_slice(nmea(sec).as_bytes());
        }
        let fixes = fixes_of(&stream);
        // Epoch 0 closed by NAV-EOE before its NMEA (not merged, no second fix); then
        // NAV-EOE no longer closes, so epochs 1.. merge and close on the next NAV-PVT.
        assert_eq!(fixes.len(), 4, "{fixes:#?}");
        assert_eq!(fixes[0].1.fix.hdop, None);
        assert_eq!(fixes[0].1.time_of_day_ms, Some(43_200_000));
        for (k, (_, fix)) in fixes.iter().enumerate().skip(1) {
            assert_merged(fix, k as u8);
        }
    }

    #[test]
    fn ubx_of_another_epoch_closes_an_nmea_epoch() {
        // Epoch 0 only NMEA, epoch 1 starts with a NAV-PVT: once the GPS−UTC offset is
        // known, the PVT's iTOW tells the epochs apart.
        let mut stream = Vec::new();
        stream.extend_from_slice(&pvt_only(0));
        stream.extend_from_slice(nmea(1).as_bytes());
        stream.extend_from_slice(&pvt_only(2));
        stream.extend_from_slice(nmea(2).as_bytes());
        let fixes = fixes_of(&stream);
        let times: Vec<Option<i64>> = fixes.iter().map(|(_, f)| f.time_of_day_ms).collect();
        assert_eq!(
            times,
            vec![Some(43_200_000), Some(43_201_000), Some(43_202_000)],
            "{fixes:#?}"
        );
        assert_eq!(fixes[1].1.source, FixSource::Nmea);
        assert_merged(&fixes[2].1, 2);
    }

    #[test]
    fn nav_pvt_is_not_overwritten_by_a_later_velned() {
        let mut stream = pvt_only(0);
        let velned = UbxMessage::NavVelned(crate::codec::ubx::NavVelned {
            itow_ms: (2 * 86_400 + 12 * 3600 + 18) * 1000,
            vel_n_mps: 0.0,
            vel_e_mps: 0.0,
            vel_d_mps: 0.0,
            speed_mps: 0.0,
            ground_speed_mps: 0.0,
            heading_deg: 0.0,
            s_acc_mps: 0.5,
            c_acc_deg: 180.0,
        });
        let _ = UbxEncoder.encode(&velned, &mut stream);
        let fixes = fixes_of(&stream);
        assert_eq!(fixes.len(), 1, "{fixes:#?}");
        assert_eq!(fixes[0].1.fix.speed_mps, Some(2.0));
        assert_eq!(fixes[0].1.fix.vel_ned, Some([2.0, 0.0, 0.0]));
        assert_eq!(fixes[0].1.fix.s_acc_mps, Some(0.1));
    }

    use crate::codec::ubx::{HnrPvt, NavPosllh, NavSol, NavTimegps, NavVelned};

    fn encoded(messages: &[UbxMessage]) -> Vec<u8> {
        let mut out = Vec::new();
        for m in messages {
            UbxEncoder.encode(m, &mut out).expect("encodes");
        }
        out
    }

    #[test]
    fn ecef_round_trip_of_a_known_point() {
        // 44.0688°N 121.3143°W, 1110.69 m: ECEF from the closed-form forward formula.
        let (lat, lon, h) = (44.068_809_737_f64, -121.314_308_893_f64, 1110.6877);
        let (sl, cl) = lat.to_radians().sin_cos();
        let (so, co) = lon.to_radians().sin_cos();
        let n = WGS84_A / (1.0 - WGS84_E2 * sl * sl).sqrt();
        let ecef = [
            (n + h) * cl * co,
            (n + h) * cl * so,
            (n * (1.0 - WGS84_E2) + h) * sl,
        ];
        let (lat2, lon2, h2) = ecef_to_geodetic(ecef).expect("on the Earth");
        assert!((lat2 - lat).abs() < 1e-11, "{lat2}");
        assert!((lon2 - lon).abs() < 1e-11, "{lon2}");
        assert!((h2 - h).abs() < 1e-6, "{h2}");
        assert_eq!(ecef_to_geodetic([0.0, 0.0, 10.0]), None);
        // Eastward velocity at the point stays east.
        let up = [cl * co, cl * so, sl];
        let east = [-so, co, 0.0];
        let v = [east[0] * 3.0 - up[0], east[1] * 3.0 - up[1], -up[2]];
        let [vn, ve, vd] = ecef_to_ned(v, lat, lon);
        assert!(vn.abs() < 1e-12 && (ve - 3.0).abs() < 1e-12 && (vd - 1.0).abs() < 1e-12);
    }

    #[test]
    fn old_receiver_messages_of_one_itow_merge_into_one_fix() {
        // NAV-SOL (ECEF), NAV-POSLLH, NAV-VELNED, NAV-TIMEGPS of iTOW 230 400 000 (week 2000),
        // then the next epoch's NAV-SOL: the LLH position and NED velocity win over the
        // ECEF ones, NAV-SOL gives the fix type, satellites and PDOP, NAV-TIMEGPS the UTC.
        let itow = 230_400_000;
        let sol = |itow_ms| {
            UbxMessage::NavSol(NavSol {
                itow_ms,
                ftow_ns: 0,
                week: 2000,
                gps_fix: 3,
                flags: 0x0D,
                ecef_m: [4_158_803.99, 681_905.07, 4_771_844.83],
                p_acc_m: 5.0,
                ecef_vel_mps: [0.0, 0.0, 0.0],
                s_acc_mps: 0.3,
                pdop: 1.7,
                num_sv: 9,
            })
        };
        let stream = encoded(&[
            sol(itow),
            UbxMessage::NavPosllh(NavPosllh {
                itow_ms: itow,
                lon_deg: 9.3117355,
                lat_deg: 48.740963,
                height_m: 311.793,
                height_msl_m: 264.182,
                h_acc_m: 9.0,
                v_acc_m: 11.5,
            }),
            UbxMessage::NavVelned(NavVelned {
                itow_ms: itow,
                vel_n_mps: -0.13,
                vel_e_mps: -0.38,
                vel_d_mps: 0.1,
                speed_mps: 0.41,
                ground_speed_mps: 0.4,
                heading_deg: 249.19,
                s_acc_mps: 0.31,
                c_acc_deg: 46.0,
            }),
            UbxMessage::NavTimegps(NavTimegps {
                itow_ms: itow,
                ftow_ns: 0,
                week: 2000,
                leap_s: 18,
                valid: 0x07,
                t_acc_ns: 20,
            }),
            sol(itow + 1000),
        ]);
        let fixes: Vec<EpochFix> = fixes_of(&stream).into_iter().map(|(_, f)| f).collect();
        assert_eq!(fixes.len(), 2, "{fixes:#?}");
        let f = &fixes[0];
        assert_eq!(f.itow_ms, Some(itow));
        assert_eq!(f.fix.lat_deg, Some(48.740963));
        assert_eq!(f.fix.height_msl_m, Some(264.182));
        assert_eq!(f.fix.vel_ned, Some([-0.13, -0.38, 0.1]));
        assert_eq!(f.fix.track_deg, Some(249.19));
        assert_eq!(
            (f.fix.fix, f.fix.num_sats, f.fix.pdop),
            (FixType::Fix3D, Some(9), Some(1.7))
        );
        assert_eq!(f.fix.week, Some(2000));
        // GPS week 2000, Tuesday 16:00:00 GPS = 2018-05-08T15:59:42Z.
        assert_eq!(f.time_of_day_ms, Some((15 * 3600 + 59 * 60 + 42) * 1000));
        assert_eq!(f.fix.utc_ns, Some(1_525_795_182_000_000_000));
        // The NAV-SOL-only epoch: position from ECEF (that point is 0.2 m off the POSLLH
        // one), zero velocity, no MSL height.
        let g = &fixes[1];
        let (lat, lon) = (g.fix.lat_deg.unwrap_or(0.0), g.fix.lon_deg.unwrap_or(0.0));
        assert!(
            (lat - 48.740_963).abs() < 1e-5 && (lon - 9.311_735_5).abs() < 1e-5,
            "{g:?}"
        );
        assert_eq!(g.fix.height_msl_m, None);
        assert_eq!(g.fix.speed_mps, Some(0.0));
        assert_eq!(g.fix.fix, FixType::Fix3D);
    }

    #[test]
    fn hnr_pvt_is_a_fix_of_its_own_and_leaves_the_nav_epoch_open() {
        let hnr = UbxMessage::HnrPvt(HnrPvt {
            itow_ms: (2 * 86_400 + 12 * 3600 + 18) * 1000 + 500,
            year: 2026,
            month: 12,
            day: 1,
            hour: 12,
            min: 0,
            sec: 0,
            valid: 0x07,
            nano_ns: 500_000_000,
            gps_fix: 4,
            flags: 0x13,
            lon_deg: 11.5000001,
            lat_deg: 48.1000001,
            height_m: 600.0,
            height_msl_m: 553.0,
            ground_speed_mps: 2.0,
            speed_mps: 2.0,
            head_mot_deg: 1.5,
            head_veh_deg: 2.5,
            h_acc_m: 1.5,
            v_acc_m: 2.5,
            s_acc_mps: 0.1,
            head_acc_deg: 3.0,
        });
        // NAV-PVT of 12:00:00, the HNR-PVT of 12:00:00.5, then the epoch's NMEA.
        let mut stream = pvt_only(0);
        stream.extend_from_slice(&encoded(&[hnr]));
        stream.extend_from_slice(nmea(0).as_bytes());
        let fixes = fixes_of(&stream);
        assert_eq!(fixes.len(), 2, "{fixes:#?}");
        let (_, high_rate) = &fixes[0];
        assert_eq!(high_rate.time_of_day_ms, Some(43_200_500));
        assert_eq!(high_rate.fix.lat_deg, Some(48.1000001));
        assert_eq!(high_rate.fix.heading_deg, Some(2.5));
        assert_eq!(high_rate.fix.fix, FixType::Dgnss);
        // The NAV epoch still merges its NMEA.
        assert_merged(&fixes[1].1, 0);
    }

    #[test]
    fn hdt_heading_joins_the_epoch() {
        let mut stream = nmea(0);
        stream.push_str(&with_checksum("GPHDT,271.25,T"));
        stream.push_str(&nmea(1));
        let fixes = fixes_of(stream.as_bytes());
        assert_eq!(fixes.len(), 2, "{fixes:#?}");
        assert_eq!(fixes[0].1.fix.heading_deg, Some(271.25));
        assert_eq!(fixes[1].1.fix.heading_deg, None);
    }

    /// ESF-RAW with one sample set (gyro z, accel x) under sensor time tag `tag`.
    fn esf_raw(tag: u32) -> Vec<u8> {
        let mut payload = vec![0u8; 4];
        for (data_type, value) in [(5u32, 4096u32), (16, 1024)] {
            payload.extend_from_slice(&((data_type << 24) | value).to_le_bytes());
            payload.extend_from_slice(&tag.to_le_bytes());
        }
        let mut out = Vec::new();
        let msg = UbxMessage::Other(RawMessage {
            class: 0x10,
            id: 0x03,
            payload,
        });
        let _ = UbxEncoder.encode(&msg, &mut out);
        out
    }

    #[test]
    fn ubx_with_esf_gives_fixes_and_imu_samples_and_counts_faults_once() {
        let mut stream = Vec::new();
        for sec in 0..3u8 {
            stream.extend(pvt(sec));
            for k in 0..4 {
                stream.extend(esf_raw(100 * u32::from(sec) + k));
            }
        }
        let mut bad = esf_raw(999);
        let last = bad.len() - 1;
        bad[last] ^= 0x55;
        stream.extend(bad);
        let readings = |esf_imu: bool| {
            let options = crate::codec::DecoderOptions {
                esf_imu,
                ..Default::default()
            };
            let factory = readings(&options).expect("opens");
            let mut decoder = factory();
            decoder.push(crate::codec::reading::Input::Bytes(&stream));
            let mut out = Vec::new();
            while let Some(r) = decoder.poll() {
                out.push(r);
            }
            while let Some(r) = decoder.finish() {
                out.push(r);
            }
            (out, decoder.stats())
        };
        let (both, stats) = readings(true);
        let fixes = both
            .iter()
            .filter(|r| matches!(r, Reading::Gnss(_)))
            .count();
        let imu: Vec<&ImuSample> = both
            .iter()
            .filter_map(|r| match r {
                Reading::Imu(s) => Some(s),
                Reading::Gnss(_) => None,
            })
            .collect();
        assert_eq!((fixes, imu.len()), (3, 12), "{both:?}");
        assert_eq!(imu[5].sensor_time, Some(101.0));
        let deg = std::f64::consts::PI / 180.0;
        assert_eq!(imu[0].gyro.map(|g| g[2]), Some(deg));
        assert_eq!(imu[0].accel.map(|a| a[0]), Some(1.0));
        assert_eq!(stats.checksum_errors, 1);
        // Without the option the same port gives the fixes alone.
        let (fixes_only, plain) = readings(false);
        assert_eq!(fixes_only.len(), 3);
        assert!(fixes_only.iter().all(|r| matches!(r, Reading::Gnss(_))));
        assert_eq!(plain, stats);
    }
}
