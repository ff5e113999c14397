//! The GNSS receiver model: position-velocity-time fixes at 1-20 Hz derived from the truth
//! trajectory, with white plus first-order Gauss-Markov errors per NED axis, output latency,
//! fix type, satellite count and outages (listed intervals and/or periodic).
//!
//! Satellite count and DOPs vary with the sky: the count wanders around `num_sats` as a
//! Gauss-Markov process (σ = max(1, 0.15·`num_sats`), τ = [`GEOMETRY_TAU_S`]) rounded and
//! kept within 4..=40; HDOP = `hdop` · √(`num_sats`/N) · e^(0.1·u) and VDOP = `vdop` ·
//! √(`num_sats`/N) · e^(0.1·v), u and v unit Gauss-Markov processes with the same time
//! constant (DOP scales about as 1/√N for satellites spread over the sky; the log-normal
//! factor stands for geometry changes at equal counts); PDOP = √(HDOP² + VDOP²). The DOPs
//! are reported; the position noise is configured in metres and does not scale with them.
//!
//! During an outage the receiver still reports, as real receivers do: a `NoFix` epoch with
//! NaN position, velocity, accuracies and DOPs, tracking a quarter of the satellites it
//! would see (at most 3). The correlated errors keep evolving through outages.

use imulab_drivers::types::FixType;
use serde::{Deserialize, Serialize};

use super::motion::TruthSample;
use super::rng::Stream;
use imulab_earth as earth;
use imulab_store::GnssRecord;

/// GPS time starts 1980-01-06T00:00:00Z, 315 964 800 s after the Unix epoch.
const GPS_EPOCH_UNIX_S: i64 = 315_964_800;
/// GPS − UTC since 2017-01-01 (valid for simulated dates until the next leap second).
const GPS_UTC_LEAP_S: i64 = 18;
const WEEK_S: i64 = 604_800;
/// Time constant of the satellite count and DOP processes: the sky changes over minutes.
pub const GEOMETRY_TAU_S: f64 = 600.0;

/// One outage: no fix from `start_s` for `duration_s` (scene time).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Outage {
    pub start_s: f64,
    pub duration_s: f64,
}

/// Outages of `duration_s` every `every_s`, the first starting at `first_s`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PeriodicOutage {
    pub every_s: f64,
    pub duration_s: f64,
    #[serde(default)]
    pub first_s: f64,
}

/// A receiver's behaviour. Noise values are 1σ per axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GnssSpec {
    /// Fix rate, 1-20 Hz.
    pub rate_hz: f64,
    /// White position noise, north and east (each) and down, m.
    pub horizontal_white_m: f64,
    pub vertical_white_m: f64,
    /// Gauss-Markov position error, north and east (each) and down, m, and its time constant.
    pub horizontal_gm_m: f64,
    pub vertical_gm_m: f64,
    pub position_gm_tau_s: f64,
    /// White velocity noise per axis, m/s.
    pub velocity_white_mps: f64,
    /// Gauss-Markov velocity error per axis, m/s, and its time constant.
    pub velocity_gm_mps: f64,
    pub velocity_gm_tau_s: f64,
    /// Time from the epoch a fix describes to its arrival at the host, s.
    pub latency_s: f64,
    /// Fix type reported outside outages.
    pub fix_type: FixType,
    /// Mean number of satellites used outside outages.
    pub num_sats: u8,
    /// Typical horizontal and vertical DOP at `num_sats` satellites.
    #[serde(default = "default_hdop")]
    pub hdop: f64,
    #[serde(default = "default_vdop")]
    pub vdop: f64,
    /// Listed outages.
    #[serde(default)]
    pub outages: Vec<Outage>,
    /// A repeating outage pattern.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub periodic_outage: Option<PeriodicOutage>,
}

fn default_hdop() -> f64 {
    0.8
}

fn default_vdop() -> f64 {
    1.2
}

/// Every GNSS preset: name, source of its numbers.
pub const GNSS_PRESETS: &[(&str, &str)] = &[
    (
        "standalone",
        "u-blox NEO-M8 class single-frequency receiver: 2.5 m CEP horizontal, 0.05 m/s velocity",
    ),
    (
        "sbas",
        "SBAS/DGNSS-corrected receiver: about 0.6 m per horizontal axis, 1 m vertical",
    ),
    (
        "rtk",
        "u-blox ZED-F9P class RTK fixed: 0.01 m + 1 ppm horizontal, 0.05 m/s velocity",
    ),
];

impl GnssSpec {
    /// The spec of preset `name` (see [`GNSS_PRESETS`]), at 10 Hz with 50 ms latency.
    pub fn preset(name: &str) -> Option<GnssSpec> {
        let base = |h_w, h_gm, v_w, v_gm, tau, vel, fix, sats: u8| GnssSpec {
            rate_hz: 10.0,
            horizontal_white_m: h_w,
            vertical_white_m: v_w,
            horizontal_gm_m: h_gm,
            vertical_gm_m: v_gm,
            position_gm_tau_s: tau,
            velocity_white_mps: vel,
            velocity_gm_mps: 0.0,
            velocity_gm_tau_s: 1.0,
            latency_s: 0.05,
            fix_type: fix,
            num_sats: sats,
            // Open sky: more satellites, better geometry.
            hdop: 0.8 * (12.0 / f64::from(sats)).sqrt(),
            vdop: 1.2 * (12.0 / f64::from(sats)).sqrt(),
            outages: Vec::new(),
            periodic_outage: None,
        };
        match name {
            // 2.5 m CEP = 2.12 m per horizontal axis (CEP = 1.1774 σ), split into a slow
            // part (ionosphere, multipath) and white receiver noise.
            "standalone" => Some(base(0.7, 2.0, 1.2, 3.5, 600.0, 0.05, FixType::Fix3D, 12)),
            "sbas" => Some(base(0.3, 0.5, 0.5, 0.9, 300.0, 0.05, FixType::Dgnss, 14)),
            "rtk" => Some(base(
                0.008,
                0.005,
                0.012,
                0.008,
                60.0,
                0.05,
                FixType::RtkFixed,
                20,
            )),
            _ => None,
        }
    }

    /// Checks the spec; the error names the field.
    pub fn validate(&self) -> Result<(), String> {
        if !(1.0..=20.0).contains(&self.rate_hz) {
            return Err(format!(
                "rate_hz must be within 1-20 Hz, got {}",
                self.rate_hz
            ));
        }
        for (name, v) in [
            ("horizontal_white_m", self.horizontal_white_m),
            ("vertical_white_m", self.vertical_white_m),
            ("horizontal_gm_m", self.horizontal_gm_m),
            ("vertical_gm_m", self.vertical_gm_m),
            ("velocity_white_mps", self.velocity_white_mps),
            ("velocity_gm_mps", self.velocity_gm_mps),
            ("latency_s", self.latency_s),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{name} must be finite and >= 0, got {v}"));
            }
        }
        if !(4..=40).contains(&self.num_sats) {
            return Err(format!(
                "num_sats must be within 4-40, got {}",
                self.num_sats
            ));
        }
        for (name, v) in [("hdop", self.hdop), ("vdop", self.vdop)] {
            if !(v.is_finite() && (0.3..=50.0).contains(&v)) {
                return Err(format!("{name} must be within 0.3-50, got {v}"));
            }
        }
        for (name, v) in [
            ("position_gm_tau_s", self.position_gm_tau_s),
            ("velocity_gm_tau_s", self.velocity_gm_tau_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} must be > 0, got {v}"));
            }
        }
        for (i, o) in self.outages.iter().enumerate() {
            if !(o.start_s.is_finite() && o.duration_s.is_finite() && o.duration_s > 0.0) {
                return Err(format!(
                    "outages[{i}]: start_s must be finite and duration_s > 0, got {} and {}",
                    o.start_s, o.duration_s
                ));
            }
        }
        if let Some(p) = &self.periodic_outage {
            if !(p.every_s.is_finite()
                && p.duration_s > 0.0
                && p.duration_s < p.every_s
                && p.first_s.is_finite())
            {
                return Err(format!(
                    "periodic_outage: need 0 < duration_s < every_s and finite first_s, got every_s {} duration_s {} first_s {}",
                    p.every_s, p.duration_s, p.first_s
                ));
            }
        }
        Ok(())
    }

    /// Whether scene time `t_s` falls in an outage.
    pub fn in_outage(&self, t_s: f64) -> bool {
        let listed = self
            .outages
            .iter()
            .any(|o| t_s >= o.start_s && t_s < o.start_s + o.duration_s);
        let periodic = self.periodic_outage.is_some_and(|p| {
            t_s >= p.first_s && (t_s - p.first_s).rem_euclid(p.every_s) < p.duration_s
        });
        listed || periodic
    }
}

/// A first-order Gauss-Markov process sampled at a fixed interval (exact AR(1)).
#[derive(Debug, Clone)]
struct Gm {
    phi: f64,
    step_sigma: f64,
    value: f64,
}

impl Gm {
    fn new(sigma: f64, tau_s: f64, dt_s: f64, stream: &mut Stream) -> Self {
        let phi = (-dt_s / tau_s).exp();
        Gm {
            phi,
            step_sigma: sigma * (1.0 - phi * phi).sqrt(),
            value: sigma * stream.normal(),
        }
    }

    fn step(&mut self, stream: &mut Stream) -> f64 {
        let v = self.value;
        self.value = self.phi * v + self.step_sigma * stream.normal();
        v
    }
}

/// Simulates one receiver epoch by epoch.
#[derive(Debug, Clone)]
pub struct GnssSimulator {
    spec: GnssSpec,
    position_gm: [Gm; 3],
    velocity_gm: [Gm; 3],
    gm_stream: Stream,
    white_stream: Stream,
    sigma_position: [f64; 3],
    sigma_velocity: f64,
    /// Satellite count, HDOP and VDOP processes (unit σ), on their own stream so the
    /// position and velocity errors do not depend on them.
    geometry: [Gm; 3],
    geometry_stream: Stream,
}

impl GnssSimulator {
    /// A simulator for `spec`, its streams keyed by `seed` and `name`.
    pub fn new(spec: &GnssSpec, name: &str, seed: u64) -> Result<Self, String> {
        spec.validate()?;
        let dt = 1.0 / spec.rate_hz;
        let mut gm_stream = Stream::new(seed, &format!("gnss/{name}/gm"));
        let position_gm = [
            spec.horizontal_gm_m,
            spec.horizontal_gm_m,
            spec.vertical_gm_m,
        ]
        .map(|s| Gm::new(s, spec.position_gm_tau_s, dt, &mut gm_stream));
        let velocity_gm = [0, 1, 2].map(|_| {
            Gm::new(
                spec.velocity_gm_mps,
                spec.velocity_gm_tau_s,
                dt,
                &mut gm_stream,
            )
        });
        let h = spec.horizontal_white_m.hypot(spec.horizontal_gm_m);
        let v = spec.vertical_white_m.hypot(spec.vertical_gm_m);
        let mut geometry_stream = Stream::new(seed, &format!("gnss/{name}/geometry"));
        let geometry = [0, 1, 2].map(|_| Gm::new(1.0, GEOMETRY_TAU_S, dt, &mut geometry_stream));
        Ok(GnssSimulator {
            geometry,
            geometry_stream,
            position_gm,
            velocity_gm,
            gm_stream,
            white_stream: Stream::new(seed, &format!("gnss/{name}/white")),
            sigma_position: [h, h, v],
            sigma_velocity: spec.velocity_white_mps.hypot(spec.velocity_gm_mps),
            spec: spec.clone(),
        })
    }

    /// The spec this simulator runs.
    pub fn spec(&self) -> &GnssSpec {
        &self.spec
    }

    /// The fix for the epoch at scene time `truth.t_s`, arriving `latency_s` later on the
    /// host clocks that started at `start_mono_ns` / `start_wall_ns`.
    pub fn epoch(
        &mut self,
        truth: &TruthSample,
        start_mono_ns: i64,
        start_wall_ns: i64,
    ) -> GnssRecord {
        let t_s = truth.t_s;
        // Advance every process every epoch so outages do not shift the noise sequence.
        let pos_err: [f64; 3] = [0, 1, 2].map(|i| {
            let w = [
                self.spec.horizontal_white_m,
                self.spec.horizontal_white_m,
                self.spec.vertical_white_m,
            ][i];
            self.position_gm[i].step(&mut self.gm_stream) + w * self.white_stream.normal()
        });
        let vel_err: [f64; 3] = [0, 1, 2].map(|i| {
            self.velocity_gm[i].step(&mut self.gm_stream)
                + self.spec.velocity_white_mps * self.white_stream.normal()
        });
        let epoch_ns = (t_s * 1e9).round() as i64;
        let arrival_ns = epoch_ns + (self.spec.latency_s * 1e9).round() as i64;
        let utc_ns = start_wall_ns + epoch_ns;
        let (week, tow_s) = gps_week_tow(utc_ns);
        let mut rec = GnssRecord {
            t_mono_ns: start_mono_ns + arrival_ns,
            t_wall_ns: start_wall_ns + arrival_ns,
            week,
            tow_s,
            utc_ns,
            lat_deg: f64::NAN,
            lon_deg: f64::NAN,
            height_m: f64::NAN,
            vel_ned: [f64::NAN; 3],
            h_acc_m: f64::NAN,
            v_acc_m: f64::NAN,
            s_acc_mps: f64::NAN,
            fix_type: FixType::NoFix,
            num_sats: 0,
            pdop: f64::NAN,
            hdop: f64::NAN,
            vdop: f64::NAN,
            heading_deg: f64::NAN,
        };
        let [n, u, v] = [0, 1, 2].map(|i| self.geometry[i].step(&mut self.geometry_stream));
        let n0 = f64::from(self.spec.num_sats);
        let sats = (n0 + (0.15 * n0).max(1.0) * n).round().clamp(4.0, 40.0);
        if self.spec.in_outage(t_s) {
            rec.num_sats = ((sats / 4.0).floor() as u8).min(3);
            return rec;
        }
        let lat = truth.lat_rad;
        let h = truth.height_m;
        let rn = earth::meridian_radius(lat) + h;
        let re = earth::prime_vertical_radius(lat) + h;
        rec.lat_deg = (lat + pos_err[0] / rn).to_degrees();
        rec.lon_deg = (truth.lon_rad + pos_err[1] / (re * lat.cos())).to_degrees();
        rec.height_m = h - pos_err[2];
        rec.vel_ned = [0, 1, 2].map(|i| truth.vel_ned[i] + vel_err[i]);
        rec.h_acc_m = self.sigma_position[0] * std::f64::consts::SQRT_2;
        rec.v_acc_m = self.sigma_position[2];
        rec.s_acc_mps = self.sigma_velocity;
        rec.fix_type = self.spec.fix_type;
        rec.num_sats = sats as u8;
        let fewer = (n0 / sats).sqrt();
        rec.hdop = self.spec.hdop * fewer * (0.1 * u).exp();
        rec.vdop = self.spec.vdop * fewer * (0.1 * v).exp();
        rec.pdop = rec.hdop.hypot(rec.vdop);
        rec
    }
}

/// GPS week and time of week for a UTC instant in ns since the Unix epoch.
pub fn gps_week_tow(utc_ns: i64) -> (u16, f64) {
    let gps_ns = utc_ns - (GPS_EPOCH_UNIX_S - GPS_UTC_LEAP_S) * 1_000_000_000;
    if gps_ns < 0 {
        return (0, f64::NAN);
    }
    let week_ns = WEEK_S * 1_000_000_000;
    let week = gps_ns / week_ns;
    let tow_ns = gps_ns % week_ns;
    (
        u16::try_from(week).unwrap_or(u16::MAX),
        tow_ns as f64 * 1e-9,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::static_truth;
    use nalgebra::UnitQuaternion;

    #[test]
    fn week_and_tow() {
        // 2024-01-01T00:00:00Z is GPS week 2295, TOW 86418 s (Monday + 18 leap seconds).
        let (w, tow) = gps_week_tow(1_704_067_200 * 1_000_000_000);
        assert_eq!(w, 2295);
        assert!((tow - 86_418.0).abs() < 1e-9, "{tow}");
    }

    #[test]
    fn outages_listed_and_periodic() {
        let mut s = GnssSpec::preset("standalone").unwrap();
        s.outages.push(Outage {
            start_s: 10.0,
            duration_s: 5.0,
        });
        s.periodic_outage = Some(PeriodicOutage {
            every_s: 180.0,
            duration_s: 60.0,
            first_s: 100.0,
        });
        s.validate().unwrap();
        assert!(!s.in_outage(9.99) && s.in_outage(10.0) && s.in_outage(14.9) && !s.in_outage(15.0));
        assert!(!s.in_outage(99.0) && s.in_outage(100.0) && s.in_outage(159.0));
        assert!(!s.in_outage(160.0) && s.in_outage(280.0) && !s.in_outage(340.0));
    }

    #[test]
    fn bad_specs_name_the_field() {
        let mut s = GnssSpec::preset("rtk").unwrap();
        s.rate_hz = 50.0;
        assert!(s.validate().unwrap_err().contains("rate_hz"));
        let mut s = GnssSpec::preset("rtk").unwrap();
        s.periodic_outage = Some(PeriodicOutage {
            every_s: 10.0,
            duration_s: 20.0,
            first_s: 0.0,
        });
        assert!(s.validate().unwrap_err().contains("periodic_outage"));
    }

    #[test]
    fn errors_have_the_configured_spread_and_latency() {
        let mut spec = GnssSpec::preset("sbas").unwrap();
        spec.position_gm_tau_s = 0.5; // short so the test sees many independent values
        let lat = 0.8;
        let truth = static_truth(lat, 0.2, 300.0, UnitQuaternion::identity());
        let mut sim = GnssSimulator::new(&spec, "g", 3).unwrap();
        let n = 4000;
        let rn = earth::meridian_radius(lat) + 300.0;
        let mut sum2 = [0.0; 3];
        for k in 0..n {
            let t = TruthSample {
                t_s: k as f64 * 0.1,
                ..truth
            };
            let r = sim.epoch(&t, 1_000, 0);
            assert_eq!(r.t_mono_ns, 1_000 + (k as i64) * 100_000_000 + 50_000_000);
            let dn = (r.lat_deg.to_radians() - lat) * rn;
            sum2[0] += dn * dn;
            sum2[1] += (r.height_m - 300.0).powi(2);
            sum2[2] += r.vel_ned[0].powi(2);
        }
        let sd = sum2.map(|s| (s / n as f64).sqrt());
        let expect = [0.3f64.hypot(0.5), 0.5f64.hypot(0.9), 0.05];
        for i in 0..3 {
            // GM correlation over 5 epochs leaves ~800 independent values: 2.5 % std error.
            assert!(
                (sd[i] / expect[i] - 1.0).abs() < 0.1,
                "{i}: {} vs {}",
                sd[i],
                expect[i]
            );
        }
    }

    #[test]
    fn satellites_and_dops_vary_plausibly_and_drop_in_outages() {
        let mut spec = GnssSpec::preset("standalone").unwrap();
        spec.rate_hz = 1.0;
        spec.outages.push(Outage {
            start_s: 5000.0,
            duration_s: 100.0,
        });
        let truth = static_truth(0.8, 0.2, 300.0, UnitQuaternion::identity());
        let mut sim = GnssSimulator::new(&spec, "g", 5).unwrap();
        let (mut sats, mut hdop) = (Vec::new(), Vec::new());
        for k in 0..20_000 {
            let t = TruthSample {
                t_s: f64::from(k),
                ..truth
            };
            let r = sim.epoch(&t, 0, 0);
            if spec.in_outage(t.t_s) {
                assert_eq!(r.fix_type, FixType::NoFix);
                assert!(r.num_sats <= 3 && r.hdop.is_nan() && r.pdop.is_nan());
                continue;
            }
            assert!((4..=40).contains(&r.num_sats));
            assert!((r.pdop - r.hdop.hypot(r.vdop)).abs() < 1e-12);
            sats.push(f64::from(r.num_sats));
            hdop.push(r.hdop);
        }
        let n = sats.len() as f64;
        let mean = |v: &[f64]| v.iter().sum::<f64>() / n;
        let (ms, mh) = (mean(&sats), mean(&hdop));
        let sd = (sats.iter().map(|x| (x - ms).powi(2)).sum::<f64>() / n).sqrt();
        // 12 ± 1.8 satellites; 33 correlation times: loose bounds.
        assert!((ms - 12.0).abs() < 1.5, "mean sats {ms}");
        assert!((0.9..3.0).contains(&sd), "sats spread {sd}");
        assert!((mh - 0.8).abs() < 0.15, "mean hdop {mh}");
        // More satellites, smaller HDOP.
        let cov = sats
            .iter()
            .zip(&hdop)
            .map(|(s, h)| (s - ms) * (h - mh))
            .sum::<f64>();
        assert!(cov < 0.0, "{cov}");
        // The sky changes: not one value.
        assert!(sats.iter().any(|&s| s != sats[0]));
    }
}
