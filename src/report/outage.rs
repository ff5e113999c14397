//! What the fitted noise terms mean for bridging a GNSS outage: the standard free-inertial
//! horizontal position error growth of one horizontal channel, straight and level, from the
//! moment GNSS is lost (no aiding, no filter):
//!
//! | source | position error after t seconds |
//! |---|---|
//! | accelerometer bias b_a (m/s²) | ½·b_a·t² |
//! | gyro bias b_g (rad/s), through the tilt it builds up | g·b_g·t³/6 |
//! | velocity random walk σ_v (m/s/√s) | σ_v·t^{3/2}/√3 |
//! | angle random walk N (rad/√s), through tilt | g·N·t^{5/2}/√20 |
//!
//! These are the short-term straight-line error propagation results of P. D. Groves,
//! *Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems*, 2nd ed.,
//! Artech House 2013, §5.7 (INS error propagation; valid for outages much shorter than the
//! 84-minute Schuler period), also in O. J. Woodman, *An introduction to inertial navigation*,
//! Cambridge UCAM-CL-TR-696 (2007), §4–6. The random walks are the standard deviations of the
//! twice/three-times integrated white noise (variances σ_v²t³/3 and g²N²t⁵/20); the unit
//! tests check all four against a numerical integration of the error chain.
//!
//! The biases are the Allan bias instability B: the part of the bias a GNSS/INS filter cannot
//! have estimated before the outage. The four contributions are independent and add as a
//! root sum of squares (the biases as 1σ random constants). Initial attitude and velocity
//! errors, scale factors and the filter's own estimates are not modelled: `imulab study`
//! gives the filter-based answer.

use crate::allan::analysis::{AllanReport, AxisResult};
use crate::allan::fit::Term;
use crate::allan::units::{SensorKind, STANDARD_GRAVITY};
use serde::Serialize;

/// Lane-level accuracy, m.
pub const LANE_LEVEL_M: f64 = 0.1;
/// One metre, m.
pub const ONE_METRE_M: f64 = 1.0;

/// The four error sources of one horizontal channel, SI units.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct OutageTerms {
    /// Accelerometer bias (instability) b_a, m/s².
    pub accel_bias: f64,
    /// Gyro bias (instability) b_g, rad/s.
    pub gyro_bias: f64,
    /// Velocity random walk σ_v, m/s/√s (= m/s²/√Hz).
    pub vrw: f64,
    /// Angle random walk N, rad/√s (= rad/s/√Hz).
    pub arw: f64,
}

/// The sources in the order of [`OutageTerms::contributions`].
pub const SOURCES: [&str; 4] = ["accel bias", "gyro bias", "VRW", "ARW"];

impl OutageTerms {
    /// Position error after `t` s from each source: accel bias, gyro bias, VRW, ARW (m, 1σ).
    pub fn contributions(&self, t: f64) -> [f64; 4] {
        let g = STANDARD_GRAVITY;
        [
            0.5 * self.accel_bias * t * t,
            g * self.gyro_bias * t.powi(3) / 6.0,
            self.vrw * t.powf(1.5) / 3f64.sqrt(),
            g * self.arw * t.powf(2.5) / 20f64.sqrt(),
        ]
    }

    /// Root sum of squares of the contributions after `t` s, m.
    pub fn position_error(&self, t: f64) -> f64 {
        self.contributions(t)
            .iter()
            .map(|c| c * c)
            .sum::<f64>()
            .sqrt()
    }

    /// The longest outage (s) whose error stays within `limit` m; `None` when no source is
    /// known (all zero) or the inputs are not finite. Capped at 10⁶ s.
    pub fn horizon(&self, limit: f64) -> Option<f64> {
        let terms = [self.accel_bias, self.gyro_bias, self.vrw, self.arw];
        if limit.is_nan() || limit <= 0.0 || terms.iter().any(|v| !v.is_finite() || *v < 0.0) {
            return None;
        }
        if terms.iter().all(|v| *v == 0.0) {
            return None;
        }
        // The error grows monotonically in t: bisect on log t.
        let (mut lo, mut hi) = (1e-6f64, 1e6f64);
        if self.position_error(hi) <= limit {
            return Some(hi);
        }
        for _ in 0..200 {
            let mid = (lo * hi).sqrt();
            if self.position_error(mid) <= limit {
                lo = mid;
            } else {
                hi = mid;
            }
            if hi / lo < 1.0 + 1e-12 {
                break;
            }
        }
        Some(lo)
    }

    /// The source with the largest contribution after `t` s.
    pub fn dominant(&self, t: f64) -> &'static str {
        let c = self.contributions(t);
        let i = (0..4).max_by(|&a, &b| c[a].total_cmp(&c[b])).unwrap_or(0);
        SOURCES[i]
    }
}

/// One device's outage figures.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DeviceOutage {
    pub device: String,
    pub terms: OutageTerms,
    /// Sources that the fit could not identify and that enter with their upper bound (the
    /// horizons are then lower bounds).
    pub bounded: Vec<&'static str>,
    /// Longest outage within [`LANE_LEVEL_M`], s.
    pub lane_level_s: Option<f64>,
    /// Longest outage within [`ONE_METRE_M`], s.
    pub one_metre_s: Option<f64>,
}

/// Why a device has no outage figures.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NoOutage {
    pub device: String,
    pub reason: String,
}

/// The horizontal axes of `sensor` of `device`: those named `…_x`/`…_y` (session channels),
/// else every axis of that sensor (plain files with other channel names).
fn horizontal_axes<'a>(
    report: &'a AllanReport,
    device: &str,
    sensor: SensorKind,
) -> Vec<&'a AxisResult> {
    let all: Vec<&AxisResult> = report
        .axes
        .iter()
        // Per-plateau curves (named "axis @ T °C") repeat their axis: skip them.
        .filter(|a| a.device == device && a.sensor == Some(sensor) && !a.axis.contains(" @ "))
        .collect();
    let horizontal: Vec<&AxisResult> = all
        .iter()
        .copied()
        .filter(|a| a.axis.ends_with("_x") || a.axis.ends_with("_y"))
        .collect();
    if horizontal.is_empty() {
        all
    } else {
        horizontal
    }
}

/// Mean over `axes` of `term` in SI units; the flag says an axis only had an upper bound.
fn mean_si(axes: &[&AxisResult], term: Term) -> Result<(f64, bool), String> {
    let mut sum = 0.0;
    let mut bounded = false;
    for a in axes {
        let fit = a
            .fit
            .as_ref()
            .ok_or_else(|| format!("{} has no noise fit", a.axis))?;
        let t = fit
            .get(term)
            .ok_or_else(|| format!("{} has no {} term", a.axis, term.symbol()))?;
        let value = match t.value {
            Some(v) => v,
            None => {
                bounded = true;
                t.high
            }
        };
        sum += value * a.unit.to_si();
    }
    Ok((sum / axes.len() as f64, bounded))
}

/// The outage figures of every device of `report`, in input order, or why there are none.
pub fn device_outages(report: &AllanReport) -> Vec<Result<DeviceOutage, NoOutage>> {
    let mut devices: Vec<&str> = Vec::new();
    for a in &report.axes {
        if !devices.contains(&a.device.as_str()) {
            devices.push(&a.device);
        }
    }
    devices
        .into_iter()
        .map(|device| {
            let fail = |reason: String| NoOutage {
                device: device.to_string(),
                reason,
            };
            let gyro = horizontal_axes(report, device, SensorKind::Gyro);
            let accel = horizontal_axes(report, device, SensorKind::Accel);
            if gyro.is_empty() || accel.is_empty() {
                return Err(fail(
                    "needs gyro and accelerometer axes with known units".to_string(),
                ));
            }
            let mut bounded = Vec::new();
            let mut get = |axes: &[&AxisResult], term, name| -> Result<f64, NoOutage> {
                let (v, b) = mean_si(axes, term).map_err(fail)?;
                if b {
                    bounded.push(name);
                }
                Ok(v)
            };
            let terms = OutageTerms {
                accel_bias: get(&accel, Term::BiasInstability, SOURCES[0])?,
                gyro_bias: get(&gyro, Term::BiasInstability, SOURCES[1])?,
                vrw: get(&accel, Term::RandomWalk, SOURCES[2])?,
                arw: get(&gyro, Term::RandomWalk, SOURCES[3])?,
            };
            Ok(DeviceOutage {
                device: device.to_string(),
                terms,
                bounded,
                lane_level_s: terms.horizon(LANE_LEVEL_M),
                one_metre_s: terms.horizon(ONE_METRE_M),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Integrates the error chain numerically: tilt θ' = gyro error, velocity v' = g·θ +
    /// accel error, position r' = v (explicit midpoint steps of `dt`).
    fn integrate(
        accel: impl Fn(usize) -> f64,
        gyro: impl Fn(usize) -> f64,
        n: usize,
        dt: f64,
    ) -> f64 {
        let (mut theta, mut v, mut r) = (0.0, 0.0, 0.0);
        for i in 0..n {
            let theta_new = theta + gyro(i) * dt;
            let v_new = v + (STANDARD_GRAVITY * 0.5 * (theta + theta_new) + accel(i)) * dt;
            r += 0.5 * (v + v_new) * dt;
            theta = theta_new;
            v = v_new;
        }
        r
    }

    #[test]
    fn bias_terms_match_integrating_the_error_chain() {
        let (t, n) = (30.0, 30_000);
        let dt = t / n as f64;
        let accel = OutageTerms {
            accel_bias: 2e-3,
            ..OutageTerms::default()
        };
        let r = integrate(|_| 2e-3, |_| 0.0, n, dt);
        assert!((accel.position_error(t) - r).abs() < 1e-6 * r, "{r}");
        let gyro = OutageTerms {
            gyro_bias: 1e-4,
            ..OutageTerms::default()
        };
        let r = integrate(|_| 0.0, |_| 1e-4, n, dt);
        assert!((gyro.position_error(t) - r).abs() < 1e-4 * r, "{r}");
    }

    #[test]
    fn random_walk_terms_match_monte_carlo() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
        let (t, n, runs) = (10.0, 200, 4000);
        let dt = t / n as f64;
        // White noise of density D sampled at dt has standard deviation D/√dt.
        let (vrw, arw) = (3e-3, 2e-4);
        let mut var = [0.0, 0.0];
        for _ in 0..runs {
            let a: Vec<f64> = (0..n)
                .map(|_| {
                    let z: f64 = StandardNormal.sample(&mut rng);
                    vrw / dt.sqrt() * z
                })
                .collect();
            let g: Vec<f64> = (0..n)
                .map(|_| {
                    let z: f64 = StandardNormal.sample(&mut rng);
                    arw / dt.sqrt() * z
                })
                .collect();
            var[0] += integrate(|i| a[i], |_| 0.0, n, dt).powi(2) / runs as f64;
            var[1] += integrate(|_| 0.0, |i| g[i], n, dt).powi(2) / runs as f64;
        }
        let c = OutageTerms {
            vrw,
            arw,
            ..OutageTerms::default()
        }
        .contributions(t);
        // 4000 runs: the sample standard deviation is within ~2.5 % (2σ of 1/√(2·4000)·…).
        for (sim, model) in [(var[0].sqrt(), c[2]), (var[1].sqrt(), c[3])] {
            assert!((sim / model - 1.0).abs() < 0.04, "sim {sim} model {model}");
        }
    }

    #[test]
    fn horizon_inverts_the_error_growth() {
        let terms = OutageTerms {
            accel_bias: 1e-3,
            gyro_bias: 5e-5,
            vrw: 1e-3,
            arw: 1e-4,
        };
        for limit in [LANE_LEVEL_M, ONE_METRE_M] {
            let t = terms.horizon(limit).unwrap();
            assert!((terms.position_error(t) / limit - 1.0).abs() < 1e-9, "{t}");
        }
        assert!(terms.horizon(0.1).unwrap() < terms.horizon(1.0).unwrap());
        assert_eq!(OutageTerms::default().horizon(1.0), None);
        let bad = OutageTerms {
            vrw: f64::NAN,
            ..terms
        };
        assert_eq!(bad.horizon(1.0), None);
    }
}
