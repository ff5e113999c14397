//! Units: what the input rate is measured in, and the engineering units each fitted
//! noise term is quoted in (gyro ARW °/√h and °/s/√Hz, bias instability °/h, RRW °/h/√h;
//! accel VRW m/s/√h, mg/√Hz and µg/√Hz, bias instability mg and µg, acceleration random walk).

use super::fit::{NoiseFit, Term};
use serde::{Deserialize, Serialize};
use std::str::FromStr;

/// Standard gravity, m/s².
pub const STANDARD_GRAVITY: f64 = 9.806_65;
const DEG_PER_RAD: f64 = 180.0 / std::f64::consts::PI;

/// Physical quantity and unit of the input rate samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RateUnit {
    RadPerSecond,
    DegPerSecond,
    DegPerHour,
    MetrePerSecondSquared,
    StandardGravity,
    MilliG,
    /// No physical unit known: results stay in the input's own units.
    Unspecified,
}

/// Which sensor family the rate belongs to (decides the engineering units).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum SensorKind {
    Gyro,
    Accel,
}

impl FromStr for RateUnit {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Ok(match s.trim() {
            "rad/s" => RateUnit::RadPerSecond,
            "deg/s" | "°/s" | "dps" => RateUnit::DegPerSecond,
            "deg/h" | "°/h" | "dph" => RateUnit::DegPerHour,
            "m/s2" | "m/s^2" | "m/s²" => RateUnit::MetrePerSecondSquared,
            "g" => RateUnit::StandardGravity,
            "mg" => RateUnit::MilliG,
            "none" | "raw" => RateUnit::Unspecified,
            other => {
                return Err(format!(
                    "unknown unit `{other}`: use rad/s, deg/s, deg/h, m/s2, g, mg or none"
                ))
            }
        })
    }
}

impl RateUnit {
    /// The sensor the unit implies, if any.
    pub fn sensor(self) -> Option<SensorKind> {
        match self {
            RateUnit::RadPerSecond | RateUnit::DegPerSecond | RateUnit::DegPerHour => {
                Some(SensorKind::Gyro)
            }
            RateUnit::MetrePerSecondSquared | RateUnit::StandardGravity | RateUnit::MilliG => {
                Some(SensorKind::Accel)
            }
            RateUnit::Unspecified => None,
        }
    }

    /// Factor from this unit to the SI base (rad/s or m/s²).
    pub fn to_si(self) -> f64 {
        match self {
            RateUnit::RadPerSecond | RateUnit::MetrePerSecondSquared | RateUnit::Unspecified => 1.0,
            RateUnit::DegPerSecond => 1.0 / DEG_PER_RAD,
            RateUnit::DegPerHour => 1.0 / DEG_PER_RAD / 3600.0,
            RateUnit::StandardGravity => STANDARD_GRAVITY,
            RateUnit::MilliG => STANDARD_GRAVITY / 1000.0,
        }
    }

    pub fn symbol(self) -> &'static str {
        match self {
            RateUnit::RadPerSecond => "rad/s",
            RateUnit::DegPerSecond => "deg/s",
            RateUnit::DegPerHour => "deg/h",
            RateUnit::MetrePerSecondSquared => "m/s^2",
            RateUnit::StandardGravity => "g",
            RateUnit::MilliG => "mg",
            RateUnit::Unspecified => "u",
        }
    }
}

/// A number with its unit, as quoted in reports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Quantity {
    pub value: f64,
    pub unit: String,
}

/// A fitted term expressed in engineering units: value (None = not identified) and the
/// 95 % interval in each unit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TermInUnits {
    pub term: Term,
    /// Engineering name, e.g. "ARW", "VRW", "bias instability".
    pub name: String,
    pub identified: bool,
    /// One entry per unit: (unit, value, low, high); `value` is null when not identified.
    pub values: Vec<UnitValue>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UnitValue {
    pub unit: String,
    pub value: Option<f64>,
    pub low: f64,
    pub high: f64,
}

/// Engineering name and (unit, factor from SI base) list for a term.
pub fn term_units(
    term: Term,
    sensor: Option<SensorKind>,
    input: RateUnit,
) -> (&'static str, Vec<(String, f64)>) {
    let u = input.symbol();
    match (sensor, term) {
        (Some(SensorKind::Gyro), Term::Quantization) => (
            "angle quantization",
            vec![("rad".into(), 1.0), ("arcsec".into(), DEG_PER_RAD * 3600.0)],
        ),
        (Some(SensorKind::Gyro), Term::RandomWalk) => (
            "ARW",
            vec![
                ("deg/sqrt(h)".into(), DEG_PER_RAD * 60.0),
                ("deg/s/sqrt(Hz)".into(), DEG_PER_RAD),
                ("rad/s/sqrt(Hz)".into(), 1.0),
            ],
        ),
        (Some(SensorKind::Gyro), Term::BiasInstability) => (
            "bias instability",
            vec![
                ("deg/h".into(), DEG_PER_RAD * 3600.0),
                ("rad/s".into(), 1.0),
            ],
        ),
        (Some(SensorKind::Gyro), Term::RateRandomWalk) => (
            "RRW",
            vec![
                ("deg/h/sqrt(h)".into(), DEG_PER_RAD * 3600.0 * 60.0),
                ("rad/s^2/sqrt(Hz)".into(), 1.0),
            ],
        ),
        (Some(SensorKind::Gyro), Term::RateRamp) => (
            "rate ramp",
            vec![
                ("deg/h^2".into(), DEG_PER_RAD * 3600.0 * 3600.0),
                ("rad/s^2".into(), 1.0),
            ],
        ),
        (Some(SensorKind::Accel), Term::Quantization) => {
            ("velocity quantization", vec![("m/s".into(), 1.0)])
        }
        (Some(SensorKind::Accel), Term::RandomWalk) => (
            "VRW",
            vec![
                ("m/s/sqrt(h)".into(), 60.0),
                ("mg/sqrt(Hz)".into(), 1000.0 / STANDARD_GRAVITY),
                ("ug/sqrt(Hz)".into(), 1e6 / STANDARD_GRAVITY),
                ("m/s^2/sqrt(Hz)".into(), 1.0),
            ],
        ),
        (Some(SensorKind::Accel), Term::BiasInstability) => (
            "bias instability",
            vec![
                ("mg".into(), 1000.0 / STANDARD_GRAVITY),
                ("ug".into(), 1e6 / STANDARD_GRAVITY),
                ("m/s^2".into(), 1.0),
            ],
        ),
        (Some(SensorKind::Accel), Term::RateRandomWalk) => (
            "AccRW",
            vec![
                ("m/s/h/sqrt(h)".into(), 3600f64.powf(1.5)),
                ("ug/sqrt(s)".into(), 1e6 / STANDARD_GRAVITY),
                ("m/s^3/sqrt(Hz)".into(), 1.0),
            ],
        ),
        (Some(SensorKind::Accel), Term::RateRamp) => {
            ("acceleration ramp", vec![("m/s^3".into(), 1.0)])
        }
        (None, Term::Quantization) => ("quantization", vec![(format!("{u}*s"), 1.0)]),
        (None, Term::RandomWalk) => ("white noise density", vec![(format!("{u}/sqrt(Hz)"), 1.0)]),
        (None, Term::BiasInstability) => ("bias instability", vec![(u.to_string(), 1.0)]),
        (None, Term::RateRandomWalk) => ("random walk", vec![(format!("{u}/sqrt(s)"), 1.0)]),
        (None, Term::RateRamp) => ("ramp", vec![(format!("{u}/s"), 1.0)]),
    }
}

/// A bias temperature coefficient (`per_degree`, input units per °C) in engineering units:
/// °/h/°C for a gyro, mg/°C for an accelerometer, the input unit per °C otherwise.
pub fn thermal_coefficient_in_units(
    per_degree: f64,
    sensor: Option<SensorKind>,
    input: RateUnit,
) -> Quantity {
    match sensor {
        Some(SensorKind::Gyro) => Quantity {
            value: per_degree * input.to_si() * DEG_PER_RAD * 3600.0,
            unit: "deg/h/°C".into(),
        },
        Some(SensorKind::Accel) => Quantity {
            value: per_degree * input.to_si() * 1000.0 / STANDARD_GRAVITY,
            unit: "mg/°C".into(),
        },
        None => Quantity {
            value: per_degree,
            unit: format!("{}/°C", input.symbol()),
        },
    }
}

/// Expresses a fit (computed on samples in `input` units) in engineering units.
pub fn fit_in_units(
    fit: &NoiseFit,
    sensor: Option<SensorKind>,
    input: RateUnit,
) -> Vec<TermInUnits> {
    // With no physical unit the base stays the input's own unit (factor 1).
    let to_si = if sensor.is_some() { input.to_si() } else { 1.0 };
    fit.terms
        .iter()
        .map(|t| {
            let (name, units) = term_units(t.term, sensor, input);
            TermInUnits {
                term: t.term,
                name: name.to_string(),
                identified: t.value.is_some(),
                values: units
                    .into_iter()
                    .map(|(unit, factor)| {
                        let f = factor * to_si;
                        UnitValue {
                            unit,
                            value: t.value.map(|v| v * f),
                            low: t.low * f,
                            high: t.high * f,
                        }
                    })
                    .collect(),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::TermEstimate;

    #[test]
    fn arw_conversion_matches_hand_calculation() {
        // 1 deg/s/sqrt(Hz) = 60 deg/sqrt(h).
        let fit = NoiseFit {
            terms: vec![TermEstimate {
                term: Term::RandomWalk,
                value: Some(1.0),
                low: 0.5,
                high: 2.0,
            }],
            reduced_chi_squared: 1.0,
            points: 3,
        };
        let t = fit_in_units(&fit, Some(SensorKind::Gyro), RateUnit::DegPerSecond);
        let arw = &t[0].values[0];
        assert_eq!(arw.unit, "deg/sqrt(h)");
        assert!((arw.value.unwrap() - 60.0).abs() < 1e-12);
        assert!((t[0].values[1].value.unwrap() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn accel_bias_in_mg() {
        let fit = NoiseFit {
            terms: vec![TermEstimate {
                term: Term::BiasInstability,
                value: Some(STANDARD_GRAVITY / 1000.0),
                low: 0.0,
                high: 1.0,
            }],
            reduced_chi_squared: 1.0,
            points: 3,
        };
        let t = fit_in_units(
            &fit,
            Some(SensorKind::Accel),
            RateUnit::MetrePerSecondSquared,
        );
        assert!((t[0].values[0].value.unwrap() - 1.0).abs() < 1e-12);
        assert!("furlongs".parse::<RateUnit>().is_err());
    }
}
