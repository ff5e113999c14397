//! Attitude programs at a fixed place: a **tumble** (static poses joined by rotations, as a
//! person turns an IMU by hand or on a cube) and a **rate table** (constant-rate segments
//! about one body axis). Each gives the true attitude and the error-free IMU output at any
//! instant in closed form, so the truth needs no integration.
//!
//! A rotation from pose q₀ to pose q₁ turns about the fixed body axis of q₀⁻¹q₁ by its angle θ
//! with the cycloidal blend of [`super::motion`]: q(t) = q₀ ⊗ exp(u θ s(τ)/2), body rate
//! u θ s'(τ)/d. A rate-table change of rate from r₀ to r₁ uses the same blend on the rate. The
//! position stays put: the gyro sees the body rate plus the earth rate, the accelerometer the
//! reaction to gravity.

use nalgebra::{Unit, UnitQuaternion, Vector3};
use serde::Deserialize;
use std::f64::consts::TAU;

use super::motion::{static_truth, TruthSample};
use super::rng::Stream;

/// The `[motion] kind = "tumble"` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TumbleSpec {
    /// Attitude of the first pose (z-y-x Euler, degrees).
    #[serde(default)]
    pub roll_deg: f64,
    #[serde(default)]
    pub pitch_deg: f64,
    #[serde(default)]
    pub heading_deg: f64,
    /// The still period at the start (a static detector takes its threshold from it), s.
    #[serde(default = "default_first_hold")]
    pub first_hold_s: f64,
    /// How long each later pose is held still, s: one time for every pose, or a list with
    /// one time per pose (a chamber run holding ±1 g poses only at the end of each soak).
    pub hold_s: Holds,
    /// How long each rotation to the next pose takes, s.
    pub rotate_s: f64,
    /// Number of random poses after the first (drawn from the scene seed); alternative to
    /// `orientations`.
    pub poses: Option<usize>,
    /// The poses after the first, each `[roll, pitch, heading]` in degrees.
    pub orientations: Option<Vec<[f64; 3]>>,
}

fn default_first_hold() -> f64 {
    30.0
}

/// The hold time of a tumble's poses: the same for all, or one per pose.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(untagged)]
pub enum Holds {
    Every(f64),
    Each(Vec<f64>),
}

impl Holds {
    /// The hold time of each of `poses` poses, checked.
    fn per_pose(&self, poses: usize) -> Result<Vec<f64>, String> {
        match self {
            Holds::Every(hold) => Ok(vec![positive("hold_s", *hold)?; poses]),
            Holds::Each(list) if list.len() != poses => Err(format!(
                "hold_s lists {} times for {poses} poses: give one per pose, or one number for all",
                list.len()
            )),
            Holds::Each(list) => list
                .iter()
                .enumerate()
                .map(|(i, &h)| positive(&format!("hold_s[{i}]"), h))
                .collect(),
        }
    }
}

/// One constant-rate step of a rate table.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RateStep {
    /// Table rate, °/s (positive: right-handed about the spindle axis).
    pub rate_dps: f64,
    /// Time at that rate after the ramp to it, s.
    pub duration_s: f64,
}

/// One mounting of the IMU on a rate table: the body axis on the spindle and the attitude
/// at table angle 0.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Mounting {
    /// Body axis on the spindle: "x", "y", "z", or "-x" … "-z".
    pub axis: String,
    /// Attitude at table angle 0 (z-y-x Euler, degrees).
    #[serde(default)]
    pub roll_deg: f64,
    #[serde(default)]
    pub pitch_deg: f64,
    #[serde(default)]
    pub heading_deg: f64,
}

/// The `[motion] kind = "rate_table"` table: one mounting (`axis` and the attitude), or
/// `mountings` run one after the other, each with the same steps.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RateTableSpec {
    /// Mounting attitude at table angle 0 (z-y-x Euler, degrees), with `axis`.
    #[serde(default)]
    pub roll_deg: f64,
    #[serde(default)]
    pub pitch_deg: f64,
    #[serde(default)]
    pub heading_deg: f64,
    /// Body axis on the spindle: "x", "y", "z", or "-x" … "-z".
    pub axis: Option<String>,
    /// Mountings in order (instead of `axis` and the attitude), e.g. x, then y, then z on
    /// the spindle.
    pub mountings: Option<Vec<Mounting>>,
    /// Still period before the first step of each mounting, s.
    #[serde(default = "default_first_hold")]
    pub first_hold_s: f64,
    /// Duration of the rotation from one mounting to the next (the IMU taken off and put
    /// back), s.
    #[serde(default = "default_remount")]
    pub remount_s: f64,
    /// Duration of each change of rate, s.
    pub ramp_s: f64,
    pub steps: Vec<RateStep>,
}

fn default_remount() -> f64 {
    10.0
}

fn spindle_axis(name: &str) -> Result<Unit<Vector3<f64>>, String> {
    let (sign, bare) = match name.strip_prefix('-') {
        Some(a) => (-1.0, a),
        None => (1.0, name),
    };
    let axis = match bare {
        "x" => Vector3::x(),
        "y" => Vector3::y(),
        "z" => Vector3::z(),
        _ => return Err(format!("axis must be x, y, z, -x, -y or -z, got {name:?}")),
    };
    Ok(Unit::new_normalize(axis * sign))
}

#[derive(Debug, Clone, Copy)]
enum Piece {
    Hold {
        q: UnitQuaternion<f64>,
    },
    Rotate {
        q0: UnitQuaternion<f64>,
        axis: Unit<Vector3<f64>>,
        angle: f64,
    },
    /// Rate from `r0` to `r1` (rad/s) with the blend when `ramp`, else constant `r0`;
    /// `q0` is the attitude at the piece's start.
    Spin {
        q0: UnitQuaternion<f64>,
        axis: Unit<Vector3<f64>>,
        r0: f64,
        r1: f64,
        ramp: bool,
    },
}

#[derive(Debug, Clone, Copy)]
struct Timed {
    t0: f64,
    duration: f64,
    piece: Piece,
}

/// A planned attitude program: pieces in time order, the last one held for ever.
#[derive(Debug, Clone)]
pub struct AttitudeProgram {
    pieces: Vec<Timed>,
    lat_rad: f64,
    lon_rad: f64,
    height_m: f64,
    cursor: usize,
}

fn euler(r: f64, p: f64, h: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(r.to_radians(), p.to_radians(), h.to_radians())
}

fn positive(what: &str, v: f64) -> Result<f64, String> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(format!("{what} must be > 0, got {v}"))
    }
}

/// A uniformly distributed random attitude (Shoemake's method from three uniforms).
fn random_attitude(stream: &mut Stream) -> UnitQuaternion<f64> {
    let (u1, u2, u3) = (stream.uniform(), stream.uniform(), stream.uniform());
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    let q = nalgebra::Quaternion::new(
        b * (TAU * u3).cos(),
        a * (TAU * u2).sin(),
        a * (TAU * u2).cos(),
        b * (TAU * u3).sin(),
    );
    UnitQuaternion::from_quaternion(q)
}

/// Integral of the blend s over [0, τ]: τ²/2 + (cos 2πτ − 1)/(2π)².
fn blend_integral(tau: f64) -> f64 {
    tau * tau / 2.0 + ((TAU * tau).cos() - 1.0) / (TAU * TAU)
}

fn blend(tau: f64) -> (f64, f64) {
    let tau = tau.clamp(0.0, 1.0);
    let (sn, cs) = (TAU * tau).sin_cos();
    (tau - sn / TAU, 1.0 - cs)
}

impl AttitudeProgram {
    /// Plans a tumble; random poses come from `seed`.
    pub fn tumble(
        spec: &TumbleSpec,
        seed: u64,
        lat_deg: f64,
        lon_deg: f64,
        height_m: f64,
    ) -> Result<Self, String> {
        let first = positive("first_hold_s", spec.first_hold_s)?;
        let rotate = positive("rotate_s", spec.rotate_s)?;
        let poses: Vec<UnitQuaternion<f64>> = match (spec.poses, &spec.orientations) {
            (Some(_), Some(_)) => return Err("give either poses or orientations, not both".into()),
            (None, None) => {
                return Err(
                    "give poses = N (random poses) or orientations = [[roll, pitch, heading], ...]"
                        .into(),
                )
            }
            (Some(n), None) => {
                let mut stream = Stream::new(seed, "motion/tumble");
                (0..n).map(|_| random_attitude(&mut stream)).collect()
            }
            (None, Some(list)) => {
                if let Some(bad) = list.iter().find(|o| o.iter().any(|x| !x.is_finite())) {
                    return Err(format!("orientations: {bad:?} must be finite"));
                }
                list.iter().map(|o| euler(o[0], o[1], o[2])).collect()
            }
        };
        let holds = spec.hold_s.per_pose(poses.len())?;
        let mut q = euler(spec.roll_deg, spec.pitch_deg, spec.heading_deg);
        let mut pieces = vec![Timed {
            t0: 0.0,
            duration: first,
            piece: Piece::Hold { q },
        }];
        let mut t = first;
        for (next, hold) in poses.into_iter().zip(holds) {
            let rel = q.inverse() * next;
            if let Some((axis, angle)) = rel.axis_angle() {
                pieces.push(Timed {
                    t0: t,
                    duration: rotate,
                    piece: Piece::Rotate { q0: q, axis, angle },
                });
                t += rotate;
            }
            pieces.push(Timed {
                t0: t,
                duration: hold,
                piece: Piece::Hold { q: next },
            });
            t += hold;
            q = next;
        }
        Ok(Self::at_place(pieces, lat_deg, lon_deg, height_m))
    }

    /// Plans a rate table run: for each mounting, a still period, the steps (each reached
    /// by a ramp), a ramp back to rest; between mountings a rotation to the next one.
    pub fn rate_table(
        spec: &RateTableSpec,
        lat_deg: f64,
        lon_deg: f64,
        height_m: f64,
    ) -> Result<Self, String> {
        let first = positive("first_hold_s", spec.first_hold_s)?;
        let ramp = positive("ramp_s", spec.ramp_s)?;
        let remount = positive("remount_s", spec.remount_s)?;
        let mountings: Vec<(Unit<Vector3<f64>>, UnitQuaternion<f64>)> =
            match (&spec.axis, &spec.mountings) {
                (Some(_), Some(_)) => {
                    return Err("give either axis (one mounting) or mountings, not both".into())
                }
                (None, None) => {
                    return Err(
                        "give axis = \"z\" (one mounting) or mountings = [{ axis = \"x\", pitch_deg = 90 }, ...]"
                            .into(),
                    )
                }
                (Some(axis), None) => vec![(
                    spindle_axis(axis)?,
                    euler(spec.roll_deg, spec.pitch_deg, spec.heading_deg),
                )],
                (None, Some(list)) => {
                    if list.is_empty() {
                        return Err("mountings: give at least one { axis }".into());
                    }
                    let mut out = Vec::new();
                    for (i, m) in list.iter().enumerate() {
                        let axis = spindle_axis(&m.axis).map_err(|e| format!("mountings[{i}]: {e}"))?;
                        if ![m.roll_deg, m.pitch_deg, m.heading_deg].iter().all(|v| v.is_finite()) {
                            return Err(format!("mountings[{i}]: the attitude must be finite"));
                        }
                        out.push((axis, euler(m.roll_deg, m.pitch_deg, m.heading_deg)));
                    }
                    out
                }
            };
        if spec.steps.is_empty() {
            return Err("steps: give at least one { rate_dps, duration_s }".into());
        }
        for (i, step) in spec.steps.iter().enumerate() {
            if !step.rate_dps.is_finite() {
                return Err(format!("steps[{i}].rate_dps must be finite"));
            }
            positive(&format!("steps[{i}].duration_s"), step.duration_s)?;
        }
        let mut pieces = Vec::new();
        let mut t = 0.0;
        let mut q = mountings[0].1;
        for (k, &(axis, q_mount)) in mountings.iter().enumerate() {
            if k > 0 {
                if let Some((turn, angle)) = (q.inverse() * q_mount).axis_angle() {
                    pieces.push(Timed {
                        t0: t,
                        duration: remount,
                        piece: Piece::Rotate {
                            q0: q,
                            axis: turn,
                            angle,
                        },
                    });
                    t += remount;
                }
            }
            q = q_mount;
            pieces.push(Timed {
                t0: t,
                duration: first,
                piece: Piece::Hold { q },
            });
            t += first;
            let mut rate = 0.0;
            let steps = spec.steps.iter().copied().chain(std::iter::once(RateStep {
                rate_dps: 0.0,
                duration_s: 1.0,
            }));
            for step in steps {
                let r1 = step.rate_dps.to_radians();
                pieces.push(Timed {
                    t0: t,
                    duration: ramp,
                    piece: Piece::Spin {
                        q0: q,
                        axis,
                        r0: rate,
                        r1,
                        ramp: true,
                    },
                });
                let ramp_angle = rate * ramp + (r1 - rate) * ramp * blend_integral(1.0);
                q *= UnitQuaternion::from_axis_angle(&axis, ramp_angle);
                t += ramp;
                pieces.push(Timed {
                    t0: t,
                    duration: step.duration_s,
                    piece: Piece::Spin {
                        q0: q,
                        axis,
                        r0: r1,
                        r1,
                        ramp: false,
                    },
                });
                q *= UnitQuaternion::from_axis_angle(&axis, r1 * step.duration_s);
                t += step.duration_s;
                rate = r1;
            }
        }
        Ok(Self::at_place(pieces, lat_deg, lon_deg, height_m))
    }

    fn at_place(pieces: Vec<Timed>, lat_deg: f64, lon_deg: f64, height_m: f64) -> Self {
        AttitudeProgram {
            pieces,
            lat_rad: lat_deg.to_radians(),
            lon_rad: lon_deg.to_radians(),
            height_m,
            cursor: 0,
        }
    }

    /// Time at which the last piece ends, s (later times hold its final state).
    pub fn duration_s(&self) -> f64 {
        self.pieces.last().map_or(0.0, |p| p.t0 + p.duration)
    }

    /// The truth at time `t` (s); times should mostly increase (a cursor follows them).
    pub fn at(&mut self, t: f64) -> TruthSample {
        while self.cursor + 1 < self.pieces.len() && t >= self.pieces[self.cursor + 1].t0 {
            self.cursor += 1;
        }
        while self.cursor > 0 && t < self.pieces[self.cursor].t0 {
            self.cursor -= 1;
        }
        let p = self.pieces[self.cursor];
        let tau = ((t - p.t0) / p.duration).clamp(0.0, 1.0);
        let (q, rate_b) = match p.piece {
            Piece::Hold { q } => (q, Vector3::zeros()),
            Piece::Rotate { q0, axis, angle } => {
                let (s, ds) = blend(tau);
                (
                    q0 * UnitQuaternion::from_axis_angle(&axis, angle * s),
                    axis.into_inner() * (angle * ds / p.duration),
                )
            }
            Piece::Spin {
                q0,
                axis,
                r0,
                r1,
                ramp,
            } => {
                let elapsed = (t - p.t0).min(p.duration).max(0.0);
                let (phi, rate) = if ramp {
                    let (s, _) = blend(tau);
                    (
                        r0 * elapsed + (r1 - r0) * p.duration * blend_integral(tau),
                        r0 + (r1 - r0) * s,
                    )
                } else {
                    // The last piece (table at rest or still) holds its rate for ever.
                    let e = if self.cursor + 1 == self.pieces.len() {
                        (t - p.t0).max(0.0)
                    } else {
                        elapsed
                    };
                    (r0 * e, r0)
                };
                (
                    q0 * UnitQuaternion::from_axis_angle(&axis, phi),
                    axis.into_inner() * rate,
                )
            }
        };
        let mut s = static_truth(self.lat_rad, self.lon_rad, self.height_m, q);
        s.t_s = t;
        s.gyro_b += rate_b;
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tumble(n: usize) -> AttitudeProgram {
        let spec = TumbleSpec {
            roll_deg: 0.0,
            pitch_deg: 0.0,
            heading_deg: 0.0,
            first_hold_s: 10.0,
            hold_s: Holds::Every(4.0),
            rotate_s: 2.0,
            poses: Some(n),
            orientations: None,
        };
        AttitudeProgram::tumble(&spec, 3, 45.0, 7.0, 200.0).unwrap()
    }

    /// Integrates the body rate (minus the earth rate) with small steps and checks the
    /// attitude it reaches is the program's own: the rates and attitudes agree.
    #[test]
    fn body_rates_integrate_to_the_poses() {
        let mut p = tumble(6);
        let rate = 1000.0;
        let end = p.duration_s();
        let mut q = p.at(0.0).quat_nb;
        let mut k = 0u64;
        while (k as f64) / rate < end {
            let t = k as f64 / rate;
            // Midpoint rule on ω_nb^b.
            let mid = p.at(t + 0.5 / rate);
            let w_ie = imulab_earth::earth_rate_ned(p.lat_rad);
            let w_nb = mid.gyro_b - mid.quat_nb.inverse() * w_ie;
            q *= UnitQuaternion::from_scaled_axis(w_nb / rate);
            k += 1;
        }
        let last = p.at(end);
        assert!(
            q.angle_to(&last.quat_nb) < 1e-6,
            "{}",
            q.angle_to(&last.quat_nb)
        );
        assert!(
            (last.accel_b.norm() - imulab_earth::normal_gravity(p.lat_rad, 200.0)).abs() < 1e-9
        );
    }

    #[test]
    fn each_pose_is_held_for_its_own_time() {
        let mut spec = TumbleSpec {
            roll_deg: 0.0,
            pitch_deg: 0.0,
            heading_deg: 0.0,
            first_hold_s: 10.0,
            hold_s: Holds::Each(vec![5.0, 7.0]),
            rotate_s: 2.0,
            poses: None,
            orientations: Some(vec![[0.0, 90.0, 0.0], [0.0, -90.0, 0.0]]),
        };
        let mut p = AttitudeProgram::tumble(&spec, 1, 45.0, 7.0, 200.0).unwrap();
        assert!((p.duration_s() - 26.0).abs() < 1e-12, "{}", p.duration_s());
        let up = euler(0.0, 90.0, 0.0);
        let down = euler(0.0, -90.0, 0.0);
        for (t, q) in [(12.1, up), (16.9, up), (19.1, down), (25.9, down)] {
            assert!(p.at(t).quat_nb.angle_to(&q) < 1e-12, "t = {t}");
        }
        assert!(
            p.at(17.5).quat_nb.angle_to(&up) > 1e-3,
            "rotating at 17.5 s"
        );
        spec.hold_s = Holds::Each(vec![5.0]);
        let e = AttitudeProgram::tumble(&spec, 1, 45.0, 7.0, 200.0).unwrap_err();
        assert!(e.contains("hold_s lists 1 times for 2 poses"), "{e}");
        spec.hold_s = Holds::Each(vec![5.0, -1.0]);
        let e = AttitudeProgram::tumble(&spec, 1, 45.0, 7.0, 200.0).unwrap_err();
        assert!(e.contains("hold_s[1] must be > 0"), "{e}");
    }

    #[test]
    fn rate_table_reaches_its_rates() {
        let spec = RateTableSpec {
            roll_deg: 0.0,
            pitch_deg: 0.0,
            heading_deg: 0.0,
            axis: Some("-z".into()),
            mountings: None,
            first_hold_s: 5.0,
            remount_s: 10.0,
            ramp_s: 2.0,
            steps: vec![
                RateStep {
                    rate_dps: 30.0,
                    duration_s: 10.0,
                },
                RateStep {
                    rate_dps: -90.0,
                    duration_s: 10.0,
                },
            ],
        };
        let mut p = AttitudeProgram::rate_table(&spec, 45.0, 7.0, 0.0).unwrap();
        let w = p.at(12.0).gyro_b;
        let earth = p.at(0.0).gyro_b;
        assert!((w.z - earth.z + 30f64.to_radians()).abs() < 1e-4, "{w}");
        let w = p.at(25.0).gyro_b;
        assert!((w.z - 90f64.to_radians()).abs() < 1e-3, "{w}");
        // Spinning about the vertical: gravity stays on z.
        assert!(p.at(20.0).accel_b.xy().norm() < 1e-9);
        let bad = RateTableSpec {
            axis: Some("w".into()),
            ..spec
        };
        assert!(AttitudeProgram::rate_table(&bad, 45.0, 7.0, 0.0)
            .unwrap_err()
            .contains("axis"));
    }

    #[test]
    fn rate_table_mountings_put_each_axis_on_the_spindle_in_turn() {
        let spec = RateTableSpec {
            roll_deg: 0.0,
            pitch_deg: 0.0,
            heading_deg: 0.0,
            axis: None,
            mountings: Some(
                [("x", 0.0, 90.0), ("y", -90.0, 0.0), ("z", 0.0, 0.0)]
                    .map(|(axis, roll_deg, pitch_deg)| Mounting {
                        axis: axis.into(),
                        roll_deg,
                        pitch_deg,
                        heading_deg: 0.0,
                    })
                    .to_vec(),
            ),
            first_hold_s: 5.0,
            remount_s: 4.0,
            ramp_s: 1.0,
            steps: vec![RateStep {
                rate_dps: 60.0,
                duration_s: 10.0,
            }],
        };
        // Each mounting: 5 s rest, 1 s ramp, 10 s at rate, 1 s ramp, 1 s at rest; 4 s between.
        let mut p = AttitudeProgram::rate_table(&spec, 45.0, 7.0, 0.0).unwrap();
        assert!((p.duration_s() - (3.0 * 18.0 + 2.0 * 4.0)).abs() < 1e-9);
        for (k, t0) in [0.0, 22.0, 44.0].into_iter().enumerate() {
            let rest = p.at(t0 + 2.0);
            let spin = p.at(t0 + 11.0);
            let g = rest.accel_b.normalize();
            assert!(g[k].abs() > 0.999, "mounting {k}: gravity {g}");
            let w = spin.gyro_b - rest.gyro_b;
            assert!(
                (w[k] - 60f64.to_radians()).abs() < 1e-3,
                "mounting {k}: {w}"
            );
            // The table turns about the vertical: gravity stays on the spindle axis.
            assert!((spin.accel_b.normalize()[k].abs() - 1.0).abs() < 1e-6);
        }
        let both = RateTableSpec {
            axis: Some("z".into()),
            ..spec
        };
        assert!(AttitudeProgram::rate_table(&both, 45.0, 7.0, 0.0)
            .unwrap_err()
            .contains("not both"));
    }
}
