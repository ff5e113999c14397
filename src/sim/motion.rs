//! Truth trajectory generator: turns a list of smooth manoeuvre segments (accelerate, cruise,
//! turn, climb, stop) into a stream of true navigation states and the error-free IMU output
//! (angular rate ω_ib^b and specific force f_ib^b) that produces them on the WGS-84 earth.
//!
//! Every manoeuvre uses the same C²-smooth "cycloidal" blend s(τ) = τ − sin(2πτ)/(2π), whose
//! rate s'(τ) = 1 − cos(2πτ) and acceleration vanish at both ends, so angular rate and
//! acceleration are continuous and the IMU output has no jumps. Velocity, heading and pitch
//! are closed-form functions of time; position is integrated from them with a classical
//! Runge-Kutta step between samples, so a noise-free strapdown mechanisation of `gyro_b` and
//! `accel_b` reproduces the trajectory (see `tests/fusion/mechanisation.rs`).
//!
//! By default the vehicle has zero roll and no side-slip: the body x axis points along the
//! velocity (pitch = flight-path angle while climbing), y to the right, z down (FRD), so the
//! non-holonomic constraint (no lateral or vertical body velocity) holds exactly. A real car
//! breaks it a little, and [`VehicleDynamics`] adds the two ways it does: tyre side-slip in
//! turns (the body yaws further into the turn than its velocity, by an angle proportional to
//! the lateral acceleration) and heave from the road (a vertical velocity that grows with
//! speed, as a sum of incommensurate sinusoids in the suspension's 1-4 Hz band). Both are
//! closed-form in time, so the IMU output still integrates exactly to the trajectory.

use imulab_earth as earth;
use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::f64::consts::{PI, TAU};

/// One manoeuvre of a drive. Durations in seconds, angles in degrees (positive = clockwise
/// seen from above, i.e. to the right), heights in metres (positive = up).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Segment {
    /// Change the forward speed by `dv_mps` (negative = brake), smoothly over `duration_s`.
    Accelerate { dv_mps: f64, duration_s: f64 },
    /// Keep speed and heading.
    Cruise { duration_s: f64 },
    /// Change heading by `angle_deg` at constant speed (a turn on the spot when stopped).
    Turn { angle_deg: f64, duration_s: f64 },
    /// Change height by `dh_m` at constant horizontal speed (needs forward speed ≥ 0.1 m/s).
    Climb { dh_m: f64, duration_s: f64 },
    /// Brake smoothly to a standstill over `duration_s` (stand still when already stopped).
    Stop { duration_s: f64 },
}

/// Start state and manoeuvres of a drive.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionSpec {
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Height above the WGS-84 ellipsoid, m.
    pub height_m: f64,
    /// Initial heading, degrees clockwise from north.
    pub heading_deg: f64,
    /// Initial forward speed, m/s.
    pub speed_mps: f64,
    pub segments: Vec<Segment>,
    /// How the vehicle breaks the non-holonomic constraint (none by default).
    #[serde(default)]
    pub vehicle: VehicleDynamics,
}

/// The motion of a real car's body that the segments' ideal path leaves out: what makes its
/// lateral and vertical body velocity non-zero.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VehicleDynamics {
    /// Side-slip gradient: the body yaws this many degrees further into the turn than the
    /// velocity per m/s² of lateral acceleration (a passenger car at road speed: 0.1-0.4;
    /// 0 = no slip).
    pub slip_deg_per_mps2: f64,
    /// RMS vertical body velocity from the road at speeds well above 5 m/s, m/s (half of it
    /// at 5 m/s, none at a standstill; a car on a good road: 0.01-0.05; 0 = a flat ride).
    pub heave_mps: f64,
}

/// Heave frequencies (Hz), phases (rad): incommensurate, within a car body's and wheel's
/// vertical modes, so the sum does not repeat within a drive.
const HEAVE_MODES: [(f64, f64); 4] = [(1.13, 0.4), (1.71, 2.1), (2.37, 4.0), (3.61, 5.3)];
/// Speed (m/s) at which the heave reaches half its RMS.
const HEAVE_HALF_SPEED_MPS: f64 = 5.0;

/// The true state and error-free IMU output at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthSample {
    pub t_s: f64,
    pub lat_rad: f64,
    pub lon_rad: f64,
    pub height_m: f64,
    /// Velocity north/east/down, m/s.
    pub vel_ned: Vector3<f64>,
    /// Attitude body (FRD) → NED.
    pub quat_nb: UnitQuaternion<f64>,
    /// True ω_ib^b including earth rate and transport rate, rad/s.
    pub gyro_b: Vector3<f64>,
    /// True specific force f_ib^b, m/s².
    pub accel_b: Vector3<f64>,
}

/// Why a motion specification cannot be generated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MotionError {
    #[error("motion spec: {field} must be a finite number, got {value}")]
    NotFinite { field: String, value: f64 },
    #[error("motion spec: sample rate must be positive and finite, got {0} Hz")]
    BadRate(f64),
    #[error(
        "motion spec: latitude {0}° is outside ±89.9° (the NED frame is singular at the poles)"
    )]
    Latitude(f64),
    #[error("motion spec: initial speed {0} m/s is negative")]
    NegativeSpeed(f64),
    #[error("motion spec: segment {index} ({kind}): duration {duration_s} s must be positive")]
    Duration {
        index: usize,
        kind: &'static str,
        duration_s: f64,
    },
    #[error(
        "motion spec: segment {index} (accelerate) would make the speed negative ({speed_mps} m/s)"
    )]
    SpeedBelowZero { index: usize, speed_mps: f64 },
    #[error(
        "motion spec: segment {index} (climb) needs forward speed ≥ 0.1 m/s, have {speed_mps} m/s"
    )]
    ClimbTooSlow { index: usize, speed_mps: f64 },
    #[error("motion spec: vehicle.slip_deg_per_mps2 = {} must be within ±5 and vehicle.heave_mps = {} within [0, 1]", .0.slip_deg_per_mps2, .0.heave_mps)]
    Vehicle(VehicleDynamics),
    #[error("motion spec: {samples} samples is too many (duration × rate)")]
    TooLong { samples: f64 },
}

/// What one planned phase changes, in SI units.
#[derive(Debug, Clone, Copy)]
enum Profile {
    Speed { dv: f64 },
    Heading { dpsi: f64 },
    Vertical { dh: f64 },
    Hold,
}

/// A segment resolved against its start time, speed and heading.
#[derive(Debug, Clone, Copy)]
struct Phase {
    t0: f64,
    duration: f64,
    speed0: f64,
    heading0: f64,
    profile: Profile,
}

/// Kinematics at one instant: horizontal speed, heading and vertical velocity, with rates.
#[derive(Debug, Clone, Copy)]
struct Kinematics {
    speed: f64,
    speed_rate: f64,
    heading: f64,
    heading_rate: f64,
    heading_accel: f64,
    /// Vertical velocity of the path (a climb), m/s down.
    vel_down: f64,
    vel_down_rate: f64,
    /// Vertical velocity of the body over the path (road heave), m/s down.
    heave: f64,
    heave_rate: f64,
}

impl Kinematics {
    fn vel_ned(&self) -> Vector3<f64> {
        let (s, c) = self.heading.sin_cos();
        Vector3::new(self.speed * c, self.speed * s, self.vel_down + self.heave)
    }
}

/// Blend s(τ), its rate s'(τ) and acceleration s''(τ) (τ in [0, 1]).
fn blend(tau: f64) -> (f64, f64, f64) {
    let tau = tau.clamp(0.0, 1.0);
    let (sn, cs) = (TAU * tau).sin_cos();
    (tau - sn / TAU, 1.0 - cs, TAU * sn)
}

/// Streaming generator of [`TruthSample`]s at a fixed rate, O(1) memory beyond the segment list.
#[derive(Debug, Clone)]
pub struct MotionGenerator {
    phases: Vec<Phase>,
    final_speed: f64,
    final_heading: f64,
    duration: f64,
    rate_hz: f64,
    samples: u64,
    next_index: u64,
    cursor: usize,
    /// Position at the next sample's time: lat (rad), lon (rad, unwrapped), height (m).
    position: Vector3<f64>,
    vehicle: VehicleDynamics,
}

fn finite(field: &str, value: f64) -> Result<f64, MotionError> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(MotionError::NotFinite {
            field: field.to_string(),
            value,
        })
    }
}

impl MotionGenerator {
    /// Plans the drive; fails on non-finite numbers, non-positive durations, negative speeds,
    /// latitudes beyond ±89.9° and climbs without forward speed.
    pub fn new(spec: &MotionSpec, rate_hz: f64) -> Result<Self, MotionError> {
        if !(rate_hz.is_finite() && rate_hz > 0.0) {
            return Err(MotionError::BadRate(rate_hz));
        }
        let lat = finite("lat_deg", spec.lat_deg)?;
        if lat.abs() > 89.9 {
            return Err(MotionError::Latitude(lat));
        }
        let lon = finite("lon_deg", spec.lon_deg)?;
        let slip = finite("vehicle.slip_deg_per_mps2", spec.vehicle.slip_deg_per_mps2)?;
        let heave = finite("vehicle.heave_mps", spec.vehicle.heave_mps)?;
        if slip.abs() > 5.0 || !(0.0..=1.0).contains(&heave) {
            return Err(MotionError::Vehicle(spec.vehicle));
        }
        let height = finite("height_m", spec.height_m)?;
        let mut heading = finite("heading_deg", spec.heading_deg)?.to_radians();
        let mut speed = finite("speed_mps", spec.speed_mps)?;
        if speed < 0.0 {
            return Err(MotionError::NegativeSpeed(speed));
        }
        let mut phases = Vec::with_capacity(spec.segments.len());
        let mut t = 0.0;
        for (index, segment) in spec.segments.iter().enumerate() {
            let (kind, duration, profile) = match *segment {
                Segment::Accelerate { dv_mps, duration_s } => {
                    let dv = finite(&format!("segments[{index}].dv_mps"), dv_mps)?;
                    if speed + dv < -1e-9 {
                        return Err(MotionError::SpeedBelowZero {
                            index,
                            speed_mps: speed + dv,
                        });
                    }
                    (
                        "accelerate",
                        duration_s,
                        Profile::Speed { dv: dv.max(-speed) },
                    )
                }
                Segment::Cruise { duration_s } => ("cruise", duration_s, Profile::Hold),
                Segment::Turn {
                    angle_deg,
                    duration_s,
                } => {
                    let dpsi = finite(&format!("segments[{index}].angle_deg"), angle_deg)?;
                    (
                        "turn",
                        duration_s,
                        Profile::Heading {
                            dpsi: dpsi.to_radians(),
                        },
                    )
                }
                Segment::Climb { dh_m, duration_s } => {
                    let dh = finite(&format!("segments[{index}].dh_m"), dh_m)?;
                    if speed < 0.1 {
                        return Err(MotionError::ClimbTooSlow {
                            index,
                            speed_mps: speed,
                        });
                    }
                    ("climb", duration_s, Profile::Vertical { dh })
                }
                Segment::Stop { duration_s } => ("stop", duration_s, Profile::Speed { dv: -speed }),
            };
            if !(duration.is_finite() && duration > 0.0) {
                return Err(MotionError::Duration {
                    index,
                    kind,
                    duration_s: duration,
                });
            }
            phases.push(Phase {
                t0: t,
                duration,
                speed0: speed,
                heading0: heading,
                profile,
            });
            match profile {
                Profile::Speed { dv } => speed = (speed + dv).max(0.0),
                Profile::Heading { dpsi } => heading += dpsi,
                Profile::Vertical { .. } | Profile::Hold => {}
            }
            t += duration;
        }
        let samples = (t * rate_hz + 1e-9).floor() + 1.0;
        if samples > 1e12 {
            return Err(MotionError::TooLong { samples });
        }
        Ok(Self {
            phases,
            final_speed: speed,
            final_heading: heading,
            duration: t,
            rate_hz,
            samples: samples as u64,
            next_index: 0,
            cursor: 0,
            position: Vector3::new(lat.to_radians(), lon.to_radians(), height),
            vehicle: spec.vehicle,
        })
    }

    /// Total duration of the drive, s (the last sample is at this time).
    pub fn duration_s(&self) -> f64 {
        self.duration
    }

    /// Kinematics at time `t`; moves the phase cursor forward (times must not go backwards
    /// by more than one phase, which the RK4 sub-steps of one sample interval never do).
    fn kinematics(&mut self, t: f64) -> Kinematics {
        let mut k = self.path_kinematics(t);
        let rms = self.vehicle.heave_mps;
        if rms > 0.0 {
            // w = rms·g(v)·S(t): S of unit RMS, g = v/(v + v½) rising from 0 at a standstill.
            let amplitude = rms * (2.0 / HEAVE_MODES.len() as f64).sqrt();
            let (mut sum, mut sum_rate) = (0.0, 0.0);
            for (f, phase) in HEAVE_MODES {
                let (sn, cs) = (TAU * f * t + phase).sin_cos();
                sum += amplitude * sn;
                sum_rate += amplitude * TAU * f * cs;
            }
            let g = k.speed / (k.speed + HEAVE_HALF_SPEED_MPS);
            let g_rate =
                HEAVE_HALF_SPEED_MPS / (k.speed + HEAVE_HALF_SPEED_MPS).powi(2) * k.speed_rate;
            k.heave = g * sum;
            k.heave_rate = g_rate * sum + g * sum_rate;
        }
        k
    }

    /// Kinematics of the segments' ideal path at time `t`, see [`Self::kinematics`].
    fn path_kinematics(&mut self, t: f64) -> Kinematics {
        while self.cursor + 1 < self.phases.len() && t >= self.phases[self.cursor + 1].t0 {
            self.cursor += 1;
        }
        while self.cursor > 0 && t < self.phases[self.cursor].t0 {
            self.cursor -= 1;
        }
        let hold = |speed, heading| Kinematics {
            speed,
            speed_rate: 0.0,
            heading,
            heading_rate: 0.0,
            heading_accel: 0.0,
            vel_down: 0.0,
            vel_down_rate: 0.0,
            heave: 0.0,
            heave_rate: 0.0,
        };
        let Some(phase) = self.phases.get(self.cursor).copied() else {
            return hold(self.final_speed, self.final_heading);
        };
        if t >= phase.t0 + phase.duration {
            return hold(self.final_speed, self.final_heading);
        }
        let mut k = hold(phase.speed0, phase.heading0);
        let (s, ds, dds) = blend((t - phase.t0) / phase.duration);
        let d = phase.duration;
        match phase.profile {
            Profile::Speed { dv } => {
                k.speed = (phase.speed0 + dv * s).max(0.0);
                k.speed_rate = dv / d * ds;
            }
            Profile::Heading { dpsi } => {
                k.heading = phase.heading0 + dpsi * s;
                k.heading_rate = dpsi / d * ds;
                k.heading_accel = dpsi / (d * d) * dds;
            }
            Profile::Vertical { dh } => {
                k.vel_down = -dh / d * ds;
                k.vel_down_rate = -dh / (d * d) * dds;
            }
            Profile::Hold => {}
        }
        k
    }

    /// Rate of change of (lat, lon, height) at `position` for velocity `v`.
    fn position_rate(position: &Vector3<f64>, v: &Vector3<f64>) -> Vector3<f64> {
        let (lat, h) = (position.x, position.z);
        let rn = earth::meridian_radius(lat) + h;
        let re = earth::prime_vertical_radius(lat) + h;
        Vector3::new(v.x / rn, v.y / (re * lat.cos()), -v.z)
    }

    fn sample_at(&self, t: f64, k: &Kinematics) -> TruthSample {
        let (lat, lon, h) = (self.position.x, self.position.y, self.position.z);
        let vel = k.vel_ned();
        let (pitch, pitch_rate) = if k.speed > 0.0 && k.vel_down != 0.0 {
            let ratio = -k.vel_down / k.speed;
            (
                ratio.atan(),
                (-k.vel_down_rate / k.speed) / (1.0 + ratio * ratio),
            )
        } else {
            (0.0, 0.0)
        };
        // Side-slip: the body yaws K·a_lat further into the turn than the path's heading.
        let slip_gain = self.vehicle.slip_deg_per_mps2.to_radians();
        let yaw = k.heading + slip_gain * k.speed * k.heading_rate;
        let yaw_rate = k.heading_rate
            + slip_gain * (k.speed_rate * k.heading_rate + k.speed * k.heading_accel);
        let quat_nb = UnitQuaternion::from_euler_angles(0.0, pitch, yaw);
        let (sp, cp) = pitch.sin_cos();
        let omega_nb_b = Vector3::new(-yaw_rate * sp, pitch_rate, yaw_rate * cp);
        let (sh, ch) = k.heading.sin_cos();
        let accel_ned = Vector3::new(
            k.speed_rate * ch - k.speed * k.heading_rate * sh,
            k.speed_rate * sh + k.speed * k.heading_rate * ch,
            k.vel_down_rate + k.heave_rate,
        );
        let w_ie = earth::earth_rate_ned(lat);
        let w_en = earth::transport_rate_ned(lat, h, &vel);
        let f_ned = accel_ned + (2.0 * w_ie + w_en).cross(&vel) - earth::gravity_ned(lat, h);
        let c_bn = quat_nb.inverse();
        TruthSample {
            t_s: t,
            lat_rad: lat,
            lon_rad: wrap_pi(lon),
            height_m: h,
            vel_ned: vel,
            quat_nb,
            gyro_b: omega_nb_b + c_bn * (w_ie + w_en),
            accel_b: c_bn * f_ned,
        }
    }
}

/// Wraps an angle into (−π, π].
fn wrap_pi(a: f64) -> f64 {
    let w = a.rem_euclid(TAU);
    if w > PI {
        w - TAU
    } else {
        w
    }
}

impl Iterator for MotionGenerator {
    type Item = TruthSample;

    fn next(&mut self) -> Option<TruthSample> {
        if self.next_index >= self.samples {
            return None;
        }
        let dt = 1.0 / self.rate_hz;
        let t = self.next_index as f64 * dt;
        let k0 = self.kinematics(t);
        let sample = self.sample_at(t, &k0);
        // Classical RK4 of the position ODE over [t, t + dt]; velocity is closed-form in time.
        let v0 = k0.vel_ned();
        let vm = self.kinematics(t + 0.5 * dt).vel_ned();
        let v1 = self.kinematics(t + dt).vel_ned();
        let p = self.position;
        let k1 = Self::position_rate(&p, &v0);
        let k2 = Self::position_rate(&(p + 0.5 * dt * k1), &vm);
        let k3 = Self::position_rate(&(p + 0.5 * dt * k2), &vm);
        let k4 = Self::position_rate(&(p + dt * k3), &v1);
        self.position = p + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
        self.next_index += 1;
        Some(sample)
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let left = usize::try_from(self.samples - self.next_index).unwrap_or(usize::MAX);
        (left, Some(left))
    }
}

/// The truth of an IMU standing still at a place with attitude `quat_nb` (body → NED):
/// zero velocity, the gyro sees only earth rate, the accelerometer only the reaction to gravity.
pub fn static_truth(
    lat_rad: f64,
    lon_rad: f64,
    height_m: f64,
    quat_nb: UnitQuaternion<f64>,
) -> TruthSample {
    let c_bn = quat_nb.inverse();
    TruthSample {
        t_s: 0.0,
        lat_rad,
        lon_rad,
        height_m,
        vel_ned: Vector3::zeros(),
        quat_nb,
        gyro_b: c_bn * earth::earth_rate_ned(lat_rad),
        accel_b: c_bn * (-earth::gravity_ned(lat_rad, height_m)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(segments: Vec<Segment>) -> MotionSpec {
        MotionSpec {
            lat_deg: 45.0,
            lon_deg: 7.0,
            height_m: 250.0,
            heading_deg: 30.0,
            speed_mps: 0.0,
            segments,
            vehicle: VehicleDynamics::default(),
        }
    }

    #[test]
    fn parses_segments_from_toml_and_rejects_unknown_keys() {
        let text = r#"
            lat_deg = 45.0
            lon_deg = 7.0
            height_m = 250.0
            heading_deg = 0.0
            speed_mps = 0.0
            segments = [
              { kind = "accelerate", dv_mps = 10.0, duration_s = 5.0 },
              { kind = "turn", angle_deg = 90.0, duration_s = 10.0 },
              { kind = "climb", dh_m = 5.0, duration_s = 10.0 },
              { kind = "cruise", duration_s = 3.0 },
              { kind = "stop", duration_s = 4.0 },
            ]
        "#;
        let spec: MotionSpec = toml::from_str(text).expect("valid spec");
        assert_eq!(spec.segments.len(), 5);
        assert_eq!(
            spec.segments[1],
            Segment::Turn {
                angle_deg: 90.0,
                duration_s: 10.0
            }
        );
        let bad = text.replace("dh_m = 5.0", "dh_m = 5.0, bank_deg = 3.0");
        assert!(toml::from_str::<MotionSpec>(&bad).is_err());
        let gen = MotionGenerator::new(&spec, 10.0).expect("plan");
        assert!((gen.duration_s() - 32.0).abs() < 1e-12);
        assert_eq!(gen.count(), 321);
    }

    #[test]
    fn rejects_bad_specs_with_reasons() {
        let e = MotionGenerator::new(&spec(vec![Segment::Cruise { duration_s: 0.0 }]), 100.0);
        assert!(matches!(e, Err(MotionError::Duration { index: 0, .. })));
        let e = MotionGenerator::new(
            &spec(vec![Segment::Climb {
                dh_m: 3.0,
                duration_s: 5.0,
            }]),
            100.0,
        );
        assert!(matches!(e, Err(MotionError::ClimbTooSlow { .. })));
        let e = MotionGenerator::new(
            &spec(vec![Segment::Accelerate {
                dv_mps: -1.0,
                duration_s: 5.0,
            }]),
            100.0,
        );
        assert!(matches!(e, Err(MotionError::SpeedBelowZero { .. })));
        let mut s = spec(vec![]);
        s.lat_deg = f64::NAN;
        assert!(matches!(
            MotionGenerator::new(&s, 100.0),
            Err(MotionError::NotFinite { .. })
        ));
        assert!(MotionGenerator::new(&spec(vec![]), 0.0).is_err());
    }

    #[test]
    fn segments_reach_their_targets() {
        let s = MotionSpec {
            speed_mps: 0.0,
            heading_deg: 0.0,
            ..spec(vec![
                Segment::Accelerate {
                    dv_mps: 12.0,
                    duration_s: 6.0,
                },
                Segment::Turn {
                    angle_deg: -90.0,
                    duration_s: 9.0,
                },
                Segment::Climb {
                    dh_m: 4.0,
                    duration_s: 8.0,
                },
                Segment::Stop { duration_s: 5.0 },
            ])
        };
        let last = MotionGenerator::new(&s, 50.0)
            .expect("plan")
            .last()
            .expect("samples");
        assert!(last.vel_ned.norm() < 1e-9, "{:?}", last.vel_ned);
        let (_, _, yaw) = last.quat_nb.euler_angles();
        assert!((yaw + std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!((last.height_m - 254.0).abs() < 1e-6, "{}", last.height_m);
    }

    #[test]
    fn specific_force_at_rest_is_gravity_reaction() {
        let q = UnitQuaternion::from_euler_angles(0.1, -0.2, 2.0);
        let s = static_truth(0.8, 0.1, 100.0, q);
        assert!((s.accel_b.norm() - earth::normal_gravity(0.8, 100.0)).abs() < 1e-12);
        assert!((s.gyro_b.norm() - earth::OMEGA_IE).abs() < 1e-15);
        let first = MotionGenerator::new(&spec(vec![Segment::Cruise { duration_s: 1.0 }]), 10.0)
            .expect("plan")
            .next()
            .expect("sample");
        let q0 = UnitQuaternion::from_euler_angles(0.0, 0.0, 30f64.to_radians());
        let st = static_truth(first.lat_rad, first.lon_rad, first.height_m, q0);
        assert!((first.accel_b - st.accel_b).norm() < 1e-12);
        assert!((first.gyro_b - st.gyro_b).norm() < 1e-18);
    }
}
