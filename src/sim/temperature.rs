//! Chamber temperature profiles that drive the sensors' thermal models: a constant chamber,
//! a linear ramp, piecewise-linear set points, or a chamber program (soaks, steps, ramps at
//! a rate in °C/min, repeated as cycles). The sensor's own temperature follows the chamber
//! through its thermal time constant (see [`super::imu_model::ThermalSpec`]).

use serde::{Deserialize, Serialize};
use std::sync::OnceLock;

/// How long a chamber program's step takes to reach its new set point, s.
pub const STEP_S: f64 = 1.0;

/// One segment of a chamber program.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ProgramSegment {
    /// Hold the current set point for `duration_s`.
    Soak { duration_s: f64 },
    /// Jump to `to_c` (within [`STEP_S`]).
    Step { to_c: f64 },
    /// Ramp to `to_c` at `c_per_min` °C per minute (the sign follows the direction).
    Ramp { to_c: f64, c_per_min: f64 },
}

fn one_cycle() -> u32 {
    1
}

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
    /// A chamber program starting at `start_c` at time 0: the segments in order, all of them
    /// repeated `cycles` times, then the last set point held.
    Program {
        start_c: f64,
        segments: Vec<ProgramSegment>,
        #[serde(default = "one_cycle")]
        cycles: u32,
        /// The program as set points, built on first use.
        #[serde(skip)]
        points: OnceLock<Vec<[f64; 2]>>,
    },
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
            TemperatureProfile::Program {
                start_c,
                segments,
                cycles,
                ..
            } => {
                finite(*start_c, "start_c")?;
                if segments.is_empty() {
                    return Err("segments must hold at least one soak, step or ramp".into());
                }
                if *cycles == 0 {
                    return Err("cycles must be >= 1".into());
                }
                for (i, seg) in segments.iter().enumerate() {
                    let at = |what: &str| format!("segments[{i}] {what}");
                    match seg {
                        ProgramSegment::Soak { duration_s } => {
                            if !(duration_s.is_finite() && *duration_s > 0.0) {
                                return Err(format!(
                                    "{} must be > 0 s, got {duration_s}",
                                    at("duration_s")
                                ));
                            }
                        }
                        ProgramSegment::Step { to_c } => finite(*to_c, &at("to_c"))?,
                        ProgramSegment::Ramp { to_c, c_per_min } => {
                            finite(*to_c, &at("to_c"))?;
                            if !(c_per_min.is_finite() && c_per_min.abs() > 0.0) {
                                return Err(format!(
                                    "{} must be a non-zero rate in °C/min, got {c_per_min}",
                                    at("c_per_min")
                                ));
                            }
                        }
                    }
                }
                Ok(())
            }
        }
    }

    /// A chamber program with `segments` repeated `cycles` times.
    pub fn program(start_c: f64, segments: Vec<ProgramSegment>, cycles: u32) -> Self {
        TemperatureProfile::Program {
            start_c,
            segments,
            cycles,
            points: OnceLock::new(),
        }
    }

    /// Whether the temperature never changes (the simulator then evaluates it once).
    pub fn is_constant(&self) -> bool {
        match self {
            TemperatureProfile::Constant { .. } => true,
            TemperatureProfile::Ramp { start_c, end_c, .. } => start_c == end_c,
            TemperatureProfile::Points { points } => points.iter().all(|p| p[1] == points[0][1]),
            TemperatureProfile::Program {
                start_c, segments, ..
            } => segments.iter().all(|s| match s {
                ProgramSegment::Soak { .. } => true,
                ProgramSegment::Step { to_c } | ProgramSegment::Ramp { to_c, .. } => {
                    to_c == start_c
                }
            }),
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
            TemperatureProfile::Points { points } => piecewise(points, t_s),
            TemperatureProfile::Program {
                start_c,
                segments,
                cycles,
                points,
            } => piecewise(
                points.get_or_init(|| program_points(*start_c, segments, *cycles)),
                t_s,
            ),
        }
    }

    /// Time of the last change of the set point, s (0 for a constant chamber).
    pub fn end_s(&self) -> f64 {
        match self {
            TemperatureProfile::Constant { .. } => 0.0,
            TemperatureProfile::Ramp { end_s, .. } => *end_s,
            TemperatureProfile::Points { points } => points.last().map_or(0.0, |p| p[0]),
            TemperatureProfile::Program {
                start_c,
                segments,
                cycles,
                points,
            } => points
                .get_or_init(|| program_points(*start_c, segments, *cycles))
                .last()
                .map_or(0.0, |p| p[0]),
        }
    }
}

/// The set points of a chamber program, `[time_s, celsius]`.
fn program_points(start_c: f64, segments: &[ProgramSegment], cycles: u32) -> Vec<[f64; 2]> {
    let mut points = vec![[0.0, start_c]];
    let (mut t, mut c) = (0.0, start_c);
    for _ in 0..cycles {
        for seg in segments {
            match *seg {
                ProgramSegment::Soak { duration_s } => t += duration_s,
                ProgramSegment::Step { to_c } => {
                    if to_c == c {
                        continue;
                    }
                    points.push([t, c]);
                    t += STEP_S;
                    c = to_c;
                }
                ProgramSegment::Ramp { to_c, c_per_min } => {
                    if to_c == c {
                        continue;
                    }
                    points.push([t, c]);
                    t += (to_c - c).abs() / c_per_min.abs() * 60.0;
                    c = to_c;
                }
            }
            if points.last().is_some_and(|p| p[0] < t) {
                points.push([t, c]);
            }
        }
    }
    points.dedup_by(|b, a| a[0] == b[0]);
    points
}

/// Piecewise-linear interpolation through `points`, held constant outside them.
fn piecewise(points: &[[f64; 2]], t_s: f64) -> f64 {
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
        let bad = TemperatureProfile::program(
            25.0,
            vec![ProgramSegment::Ramp {
                to_c: 60.0,
                c_per_min: 0.0,
            }],
            1,
        );
        assert!(bad
            .validate()
            .unwrap_err()
            .contains("segments[0] c_per_min"));
    }

    #[test]
    fn program_soaks_ramps_steps_and_cycles() {
        let p = TemperatureProfile::program(
            25.0,
            vec![
                ProgramSegment::Soak { duration_s: 600.0 },
                ProgramSegment::Ramp {
                    to_c: 45.0,
                    c_per_min: 2.0,
                },
                ProgramSegment::Soak { duration_s: 300.0 },
                ProgramSegment::Step { to_c: 25.0 },
            ],
            2,
        );
        p.validate().unwrap();
        assert_eq!(p.at(300.0), 25.0);
        // 20 °C at 2 °C/min: 600 s of ramp.
        assert!((p.at(900.0) - 35.0).abs() < 1e-12);
        assert_eq!(p.at(1300.0), 45.0);
        assert_eq!(p.at(1500.0 + STEP_S), 25.0);
        // The second cycle starts after the step.
        let second = 1500.0 + STEP_S;
        assert_eq!(p.at(second + 600.0 + 300.0), 35.0);
        assert!((p.end_s() - 2.0 * second).abs() < 1e-9);
        assert!(!p.is_constant());
        let text = "kind = \"program\"\nstart_c = 20.0\ncycles = 3\nsegments = [{ kind = \"soak\", duration_s = 60.0 }, { kind = \"ramp\", to_c = 30.0, c_per_min = -1.0 }]\n";
        let parsed: TemperatureProfile = toml::from_str(text).unwrap();
        parsed.validate().unwrap();
        assert_eq!(parsed.at(60.0 + 300.0), 25.0);
    }
}
