//! Temperature profiles that drive the sensors' bias and scale-factor temperature
//! coefficients: a constant chamber, a linear ramp, or piecewise-linear set points.

use serde::{Deserialize, Serialize};

/// A temperature over time, °C. Held constant before the first and after the last point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum TemperatureProfile {
    /// A chamber held at one temperature.
    Constant { celsius: f64 },
    /// From `start_c` at `start_s` linearly to `end_c` at `end_s`.
    Ramp {
        start_c: f64,
        end_c: f64,
        start_s: f64,
        end_s: f64,
    },
    /// Piecewise-linear through `[time_s, celsius]` points, times strictly increasing.
    Points { points: Vec<[f64; 2]> },
}

impl Default for TemperatureProfile {
    fn default() -> Self {
        TemperatureProfile::Constant { celsius: 25.0 }
    }
}

impl TemperatureProfile {
    /// Checks the profile; the error says what is wrong.
    pub fn validate(&self) -> Result<(), String> {
        let finite = |x: f64, what: &str| {
            if x.is_finite() {
                Ok(())
            } else {
                Err(format!("{what} must be a finite number, got {x}"))
            }
        };
        match self {
            TemperatureProfile::Constant { celsius } => finite(*celsius, "celsius"),
            TemperatureProfile::Ramp {
                start_c,
                end_c,
                start_s,
                end_s,
            } => {
                finite(*start_c, "start_c")?;
                finite(*end_c, "end_c")?;
                finite(*start_s, "start_s")?;
                finite(*end_s, "end_s")?;
                if end_s <= start_s {
                    return Err(format!("end_s ({end_s}) must be after start_s ({start_s})"));
                }
                Ok(())
            }
            TemperatureProfile::Points { points } => {
                if points.is_empty() {
                    return Err("points must hold at least one [time_s, celsius] pair".into());
                }
                for (i, p) in points.iter().enumerate() {
                    finite(p[0], &format!("points[{i}] time"))?;
                    finite(p[1], &format!("points[{i}] celsius"))?;
                    if i > 0 && p[0] <= points[i - 1][0] {
                        return Err(format!(
                            "points[{i}] time {} is not after points[{}] time {}",
                            p[0],
                            i - 1,
                            points[i - 1][0]
                        ));
                    }
                }
                Ok(())
            }
        }
    }

    /// Whether the temperature never changes (the simulator then evaluates it once).
    pub fn is_constant(&self) -> bool {
        match self {
            TemperatureProfile::Constant { .. } => true,
            TemperatureProfile::Ramp { start_c, end_c, .. } => start_c == end_c,
            TemperatureProfile::Points { points } => points.iter().all(|p| p[1] == points[0][1]),
        }
    }

    /// Temperature at time `t_s`, °C.
    pub fn at(&self, t_s: f64) -> f64 {
        match self {
            TemperatureProfile::Constant { celsius } => *celsius,
            TemperatureProfile::Ramp {
                start_c,
                end_c,
                start_s,
                end_s,
            } => {
                let f = ((t_s - start_s) / (end_s - start_s)).clamp(0.0, 1.0);
                start_c + f * (end_c - start_c)
            }
            TemperatureProfile::Points { points } => {
                let Some(first) = points.first() else {
                    return f64::NAN;
                };
                if t_s <= first[0] {
                    return first[1];
                }
                // Points are few; a binary search keeps long profiles cheap too.
                let i = points.partition_point(|p| p[0] <= t_s);
                match points.get(i) {
                    None => points[points.len() - 1][1],
                    Some(hi) => {
                        let lo = points[i - 1];
                        lo[1] + (t_s - lo[0]) / (hi[0] - lo[0]) * (hi[1] - lo[1])
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_and_points_interpolate() {
        let r = TemperatureProfile::Ramp {
            start_c: 10.0,
            end_c: 30.0,
            start_s: 100.0,
            end_s: 200.0,
        };
        assert_eq!(r.at(0.0), 10.0);
        assert_eq!(r.at(150.0), 20.0);
        assert_eq!(r.at(1e9), 30.0);
        let p = TemperatureProfile::Points {
            points: vec![[0.0, 25.0], [10.0, 35.0], [20.0, 15.0]],
        };
        p.validate().unwrap();
        assert_eq!(p.at(-1.0), 25.0);
        assert_eq!(p.at(5.0), 30.0);
        assert_eq!(p.at(15.0), 25.0);
        assert_eq!(p.at(99.0), 15.0);
        assert!(!p.is_constant());
    }

    #[test]
    fn bad_profiles_are_rejected() {
        let p = TemperatureProfile::Points {
            points: vec![[0.0, 25.0], [0.0, 30.0]],
        };
        assert!(p.validate().unwrap_err().contains("points[1]"));
        assert!(TemperatureProfile::Points { points: vec![] }
            .validate()
            .is_err());
        let r = TemperatureProfile::Constant { celsius: f64::NAN };
        assert!(r.validate().is_err());
    }
}
