//! Strapdown mechanisation in the local-level NED frame on the WGS-84 earth: integrates
//! angular-rate / specific-force samples or angle / velocity increments into attitude
//! (quaternion), velocity and geodetic position, with earth rate, transport rate, Coriolis
//! and normal gravity.
//!
//! Algorithm (after Savage, *Strapdown Analytics*, and Shin's thesis, UCalgary 2005):
//! velocity first (rotation compensation ½Δθ×Δv, optional sculling, n-frame rotation
//! correction), then position (trapezoidal in velocity), then attitude
//! q⁺ = exp(−ζ) ⊗ q ⊗ exp(φ) with φ = Δθ plus optional coning and ζ the n-frame rotation.
//! Second order evaluates gravity, Coriolis and ζ at mid-interval (extrapolated); first order
//! at the start of the interval and integrates position with the old velocity (Euler).

use imulab_earth as earth;
use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Navigation state of the strapdown solution (IMU centre).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavState {
    pub t_s: f64,
    pub lat_rad: f64,
    pub lon_rad: f64,
    pub height_m: f64,
    /// Velocity north/east/down, m/s.
    pub vel_ned: Vector3<f64>,
    /// Attitude body (FRD) → NED.
    pub quat_nb: UnitQuaternion<f64>,
}

impl NavState {
    /// Roll, pitch, yaw in radians (ZYX Euler angles of body → NED).
    pub fn euler_rad(&self) -> (f64, f64, f64) {
        self.quat_nb.euler_angles()
    }

    /// Meridian and prime-vertical radii plus height, m.
    pub fn radii(&self) -> (f64, f64) {
        (
            earth::meridian_radius(self.lat_rad) + self.height_m,
            earth::prime_vertical_radius(self.lat_rad) + self.height_m,
        )
    }

    /// NED offset (m) of `self` relative to `other` (small-distance approximation, good to
    /// parts per million over kilometres).
    pub fn ned_offset_from(&self, lat: f64, lon: f64, height: f64) -> Vector3<f64> {
        let (rn, re) = self.radii();
        Vector3::new(
            (self.lat_rad - lat) * rn,
            wrap_pi(self.lon_rad - lon) * re * self.lat_rad.cos(),
            -(self.height_m - height),
        )
    }

    /// Moves the position by a small NED offset `d` (m).
    pub fn shift_position(&mut self, d: &Vector3<f64>) {
        let (rn, re) = self.radii();
        self.lat_rad += d.x / rn;
        self.lon_rad = wrap_pi(self.lon_rad + d.y / (re * self.lat_rad.cos()));
        self.height_m -= d.z;
    }
}

/// Wraps an angle into (−π, π].
pub fn wrap_pi(a: f64) -> f64 {
    if a > -std::f64::consts::PI && a <= std::f64::consts::PI {
        return a;
    }
    let w = a.rem_euclid(std::f64::consts::TAU);
    if w > std::f64::consts::PI {
        w - std::f64::consts::TAU
    } else {
        w
    }
}

/// Rotation angle, rad, below which [`rotation`] uses its power series (truncation error of
/// the half-angle sine and cosine below 10⁻²⁴).
pub const ROTATION_SERIES_MAX_RAD: f64 = 1e-2;

/// The unit quaternion of rotation vector `v` (axis × angle), as
/// `UnitQuaternion::from_scaled_axis`; the small rotations of one IMU step take the power
/// series of cos(θ/2) and sin(θ/2)/θ instead of a norm, a sine and a cosine.
pub fn rotation(v: &Vector3<f64>) -> UnitQuaternion<f64> {
    let t2 = v.norm_squared();
    if t2.is_nan() || t2 >= ROTATION_SERIES_MAX_RAD * ROTATION_SERIES_MAX_RAD {
        return UnitQuaternion::from_scaled_axis(*v);
    }
    // x = θ/2: cos x and sin x / (2x) to the x⁸ and x⁶ terms.
    let x2 = 0.25 * t2;
    let w = 1.0 - x2 / 2.0 * (1.0 - x2 / 12.0 * (1.0 - x2 / 30.0 * (1.0 - x2 / 56.0)));
    let s = 0.5 * (1.0 - x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0)));
    UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(w, s * v.x, s * v.y, s * v.z))
}

/// Order of the numerical integration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IntegrationOrder {
    First,
    #[default]
    Second,
}

/// Mechanisation options.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MechanisationOptions {
    pub order: IntegrationOrder,
    /// Coning (attitude) and sculling (velocity) corrections.
    pub coning_sculling: bool,
}

impl Default for MechanisationOptions {
    fn default() -> Self {
        Self {
            order: IntegrationOrder::Second,
            coning_sculling: true,
        }
    }
}

/// One IMU input, already corrected for the estimated biases and scale factors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ImuInput {
    /// Instantaneous angular rate (rad/s) and specific force (m/s²) at `t_s`.
    Rates {
        t_s: f64,
        gyro: Vector3<f64>,
        accel: Vector3<f64>,
    },
    /// Angle (rad) and velocity (m/s) increments over (`t_s` − `dt_s`, `t_s`].
    Increments {
        t_s: f64,
        dt_s: f64,
        dtheta: Vector3<f64>,
        dvel: Vector3<f64>,
    },
}

impl ImuInput {
    pub fn t_s(&self) -> f64 {
        match *self {
            ImuInput::Rates { t_s, .. } | ImuInput::Increments { t_s, .. } => t_s,
        }
    }
}

/// What one mechanisation step did, for the error-state model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepInfo {
    pub dt_s: f64,
    /// Mean angular rate and specific force over the step, body frame.
    pub gyro_b: Vector3<f64>,
    pub accel_b: Vector3<f64>,
}

/// Compensated increments of one interval: rotation vector and velocity change in the body
/// frame at the start of the interval.
struct Compensated {
    dt: f64,
    dtheta: Vector3<f64>,
    dvel: Vector3<f64>,
    rotation: Vector3<f64>,
    dvel_rot: Vector3<f64>,
}

/// The strapdown integrator with the memory its corrections need (previous sample/increment,
/// previous velocity for mid-interval extrapolation).
#[derive(Debug, Clone)]
pub struct Mechaniser {
    options: MechanisationOptions,
    prev_rates: Option<(f64, Vector3<f64>, Vector3<f64>)>,
    prev_increment: Option<(Vector3<f64>, Vector3<f64>)>,
    prev_vel: Option<Vector3<f64>>,
}

impl Mechaniser {
    pub fn new(options: MechanisationOptions) -> Self {
        Self {
            options,
            prev_rates: None,
            prev_increment: None,
            prev_vel: None,
        }
    }

    pub fn options(&self) -> MechanisationOptions {
        self.options
    }

    /// Forgets the sample history (after a data gap).
    pub fn reset_history(&mut self) {
        self.prev_rates = None;
        self.prev_increment = None;
        self.prev_vel = None;
    }

    /// Turns the input into compensated increments; `None` when there is nothing to integrate
    /// yet (first rate sample) or the interval is not positive.
    fn compensate(&mut self, input: &ImuInput) -> Option<Compensated> {
        let cs = self.options.coning_sculling;
        match *input {
            ImuInput::Rates { t_s, gyro, accel } => {
                let prev = self.prev_rates.replace((t_s, gyro, accel));
                let (t0, w0, f0) = prev?;
                let dt = t_s - t0;
                if dt.is_nan() || dt <= 0.0 {
                    return None;
                }
                let dtheta = 0.5 * (w0 + gyro) * dt;
                let dvel = 0.5 * (f0 + accel) * dt;
                let mut rotation = dtheta;
                let mut dvel_rot = dvel + 0.5 * dtheta.cross(&dvel);
                if cs {
                    // Exact to third order for rates linear in time over the interval.
                    let k = dt * dt / 12.0;
                    rotation += k * w0.cross(&gyro);
                    dvel_rot += k * (w0.cross(&accel) + f0.cross(&gyro));
                }
                Some(Compensated {
                    dt,
                    dtheta,
                    dvel,
                    rotation,
                    dvel_rot,
                })
            }
            ImuInput::Increments {
                dt_s, dtheta, dvel, ..
            } => {
                if dt_s.is_nan() || dt_s <= 0.0 {
                    return None;
                }
                let prev = self.prev_increment.replace((dtheta, dvel));
                let mut rotation = dtheta;
                let mut dvel_rot = dvel + 0.5 * dtheta.cross(&dvel);
                if let (true, Some((dth0, dv0))) = (cs, prev) {
                    // Two-sample coning and sculling corrections.
                    rotation += dth0.cross(&dtheta) / 12.0;
                    dvel_rot += (dth0.cross(&dvel) + dv0.cross(&dtheta)) / 12.0;
                }
                Some(Compensated {
                    dt: dt_s,
                    dtheta,
                    dvel,
                    rotation,
                    dvel_rot,
                })
            }
        }
    }

    /// Advances `nav` to the input's time. Returns `None` (and leaves `nav` alone but for its
    /// time) when the input only primes the history.
    pub fn step(&mut self, nav: &mut NavState, input: &ImuInput) -> Option<StepInfo> {
        let Some(c) = self.compensate(input) else {
            nav.t_s = input.t_s();
            return None;
        };
        let dt = c.dt;
        let second = self.options.order == IntegrationOrder::Second;
        let (lat0, h0, v0) = (nav.lat_rad, nav.height_m, nav.vel_ned);
        // One sine and cosine per step: the other latitudes of the step are within a few
        // 10⁻⁸ rad of the start and are reached by `Latitude::shifted`.
        let start = earth::Latitude::new(lat0);
        let rm_start = start.meridian_radius();

        // Velocity: forces at mid-interval (extrapolated) for second order.
        let (mid, h_m, v_m) = if second {
            let v_prev = self.prev_vel.unwrap_or(v0);
            (
                start.shifted(0.5 * dt * v0.x / (rm_start + h0)),
                h0 - 0.5 * dt * v0.z,
                v0 + 0.5 * (v0 - v_prev),
            )
        } else {
            (start, h0, v0)
        };
        let w_ie = mid.earth_rate_ned();
        let w_en = mid.transport_rate_ned(h_m, &v_m);
        let zeta = (w_ie + w_en) * dt;
        let dv_n = nav.quat_nb * c.dvel_rot;
        let dv_n = dv_n - 0.5 * zeta.cross(&dv_n);
        let g = Vector3::new(0.0, 0.0, mid.normal_gravity(h_m));
        let v1 = v0 + dv_n + (g - (2.0 * w_ie + w_en).cross(&v_m)) * dt;

        // Position.
        let v_pos = if second { 0.5 * (v0 + v1) } else { v0 };
        let h1 = h0 - v_pos.z * dt;
        let h_avg = if second { 0.5 * (h0 + h1) } else { h0 };
        let half = start.shifted(0.5 * dt * v_pos.x / (rm_start + h_avg));
        let reference = if second { half } else { start };
        let lat1 = lat0 + dt * v_pos.x / (reference.meridian_radius() + h_avg);
        let lon1 = nav.lon_rad
            + dt * v_pos.y / ((reference.prime_vertical_radius() + h_avg) * reference.cos);

        // Attitude: n-frame rotation at mid-interval (now known) for second order.
        let zeta = if second {
            let v_avg = 0.5 * (v0 + v1);
            (half.earth_rate_ned() + half.transport_rate_ned(h_avg, &v_avg)) * dt
        } else {
            zeta
        };
        let q = rotation(&(-zeta)) * nav.quat_nb * rotation(&c.rotation);

        self.prev_vel = Some(v0);
        nav.t_s = input.t_s();
        nav.lat_rad = lat1;
        nav.lon_rad = wrap_pi(lon1);
        nav.height_m = h1;
        nav.vel_ned = v1;
        nav.quat_nb = UnitQuaternion::new_normalize(q.into_inner());
        Some(StepInfo {
            dt_s: dt,
            gyro_b: c.dtheta / dt,
            accel_b: c.dvel / dt,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The series rotation equals nalgebra's exact one over the range it covers, and beyond
    /// it is nalgebra's.
    #[test]
    fn rotation_series_matches_exact_quaternion() {
        for angle in [0.0, 1e-9, 1e-6, 1e-4, 3e-3, 9.9e-3, 0.02, 0.5] {
            let v = Vector3::new(0.3, -0.8, 0.52).normalize() * angle;
            let exact = UnitQuaternion::from_scaled_axis(v);
            let series = rotation(&v);
            assert!(
                (series.coords - exact.coords).amax() < 3e-16,
                "{angle}: {} vs {}",
                series.coords,
                exact.coords
            );
            assert!((series.coords.norm() - 1.0).abs() < 1e-15);
        }
        // A wrong series term would show at the top of the range.
        let v = Vector3::new(0.0, 0.0, 9e-3);
        let w = 1.0 - v.z * v.z / 8.0;
        assert!((rotation(&v).w - w).abs() > 1e-12);
    }

    #[test]
    fn wrap_pi_keeps_the_range_and_wraps_outside() {
        assert_eq!(wrap_pi(1.0), 1.0);
        assert_eq!(wrap_pi(std::f64::consts::PI), std::f64::consts::PI);
        assert!((wrap_pi(3.0 * std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
        assert!((wrap_pi(-4.0) - (2.0 * std::f64::consts::PI - 4.0)).abs() < 1e-12);
    }
}
