//! Initial alignment: static levelling (roll and pitch from the mean specific force while the
//! IMU stands still), the gyro bias from the mean angular rate over the same still period
//! ([`static_gyro_bias`]), and heading from the GNSS track once the vehicle moves, or given.
//!
//! Low-cost gyros cannot see earth rate through their bias, so there is no gyrocompassing:
//! the earth rate's horizontal part, whose direction depends on the unknown heading, is an
//! uncertainty of the static gyro bias instead.

/// Motion thresholds of the levelling period: deviation of the angular rate (rad/s) and of
/// the specific force (m/s²) from their running means; far above MEMS noise at 1 kHz. The
/// rate is compared with its own mean, not with zero, so a gyro whose turn-on bias exceeds the
/// threshold (a consumer MEMS part: σ 6.7 °/s) still levels and measures that bias.
pub const LEVEL_GYRO_THRESHOLD: f64 = 0.05;
pub const LEVEL_ACCEL_THRESHOLD: f64 = 0.3;
/// How far the first sample's specific force may be from gravity's magnitude beyond the
/// accel threshold, m/s² (0.1 g: consumer MEMS datasheets give zero-g offsets up to ±80 mg).
pub const LEVEL_GRAVITY_TOLERANCE: f64 = 1.0;
/// GNSS horizontal speed above which the vehicle is no longer standing still, m/s (well above
/// a standalone receiver's velocity noise of a few cm/s).
pub const STILL_SPEED_MPS: f64 = 0.5;

use crate::config::Axes;
use imulab_earth::OMEGA_IE;
use nalgebra::{UnitQuaternion, Vector3};

/// Roll and pitch (rad) of a body whose accelerometers read the mean specific force `f_b`
/// (m/s², FRD) at rest. At rest f_b = −C_nb g, so a level body reads (0, 0, −g).
pub fn level(f_b: &Vector3<f64>) -> (f64, f64) {
    let roll = (-f_b.y).atan2(-f_b.z);
    let pitch = f_b.x.atan2((f_b.y * f_b.y + f_b.z * f_b.z).sqrt());
    (roll, pitch)
}

/// Heading (rad from north) of a vehicle moving forward with NED velocity `v`.
pub fn heading_from_velocity(v: &Vector3<f64>) -> f64 {
    v.y.atan2(v.x)
}

/// Attitude body → NED from roll, pitch, heading.
pub fn attitude(roll: f64, pitch: f64, heading: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(roll, pitch, heading)
}

/// Accumulates IMU data while the vehicle stands still, for levelling.
#[derive(Debug, Clone, Default)]
pub struct StaticLeveller {
    sum_f: Vector3<f64>,
    sum_w: Vector3<f64>,
    duration_s: f64,
    moved: bool,
    /// Integral of the rate since the still period ended (rad, body) and its duration (s),
    /// from which [`StaticLeveller::turned_rad`] is taken.
    sum_w_moving: Vector3<f64>,
    duration_moving_s: f64,
}

/// The tilt error that levelling leaves, as a function of the accelerometer bias error: the
/// levelled attitude makes the mean specific force `f_b` read as pure gravity, so its
/// horizontal part in the n-frame is zero and the north/east attitude error φ_h satisfies
/// [fⁿ×]_h φ_h = (C_nb δb_a)_h (the filter's velocity-error equation at rest). Returns the 2×3
/// matrix J with φ_h = J δb_a, or `None` when fⁿ has no vertical part.
pub fn levelling_tilt_jacobian(
    f_b: &Vector3<f64>,
    quat_nb: &UnitQuaternion<f64>,
) -> Option<nalgebra::Matrix2x3<f64>> {
    let c_nb = quat_nb.to_rotation_matrix().into_inner();
    let f_z = (c_nb * f_b).z;
    // [f×] restricted to north/east rows and columns: [[0, −f_z], [f_z, 0]].
    let a = nalgebra::Matrix2::new(0.0, -f_z, f_z, 0.0);
    let a_inv = a.try_inverse()?;
    Some(a_inv * c_nb.fixed_rows::<2>(0))
}

/// The gyro bias measured while standing still, as a prior for the filter's bias state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StaticGyroBias {
    /// Estimated bias per axis, rad/s.
    pub bias: Vector3<f64>,
    /// 1σ of that estimate per axis, rad/s.
    pub sigma: Vector3<f64>,
}

/// The gyro bias from a still period of `duration_s` whose mean angular rate was `mean_w`,
/// combined with the filter's prior (zero mean, 1σ `sigma0`) per axis.
///
/// The mean reads bias + C_bn ω_ie (earth rate). With roll and pitch from levelling and the
/// heading the body had while still, `heading` (1σ `heading_sigma`, rad), the whole earth
/// rate is subtracted; what is left of it is the heading error's share: the earth rate's
/// horizontal part (ω_ie cos φ at latitude φ) turned by `heading_sigma`. The white noise adds
/// `arw`²/T. The result is the Bayesian combination of that measurement with the prior, so a
/// gyro whose bias is already known better than that gains little. A heading known to no
/// better than a radian leaves the whole horizontal earth rate as the error bound.
#[allow(clippy::too_many_arguments)]
pub fn static_gyro_bias(
    mean_w: &Vector3<f64>,
    duration_s: f64,
    roll: f64,
    pitch: f64,
    heading: f64,
    heading_sigma: f64,
    lat_rad: f64,
    arw: &Axes,
    sigma0: &Axes,
) -> StaticGyroBias {
    let c_bn = attitude(roll, pitch, heading)
        .to_rotation_matrix()
        .matrix()
        .transpose();
    let (sin, cos) = lat_rad.sin_cos();
    let measured = mean_w - c_bn * Vector3::new(OMEGA_IE * cos, 0.0, -OMEGA_IE * sin);
    // The horizontal earth rate turned by a heading error δψ moves by 2·sin(δψ/2) of itself.
    // (`min` also takes a NaN σ as a radian.)
    let turned = 2.0 * (0.5 * heading_sigma.abs().min(1.0)).sin();
    let mut bias = Vector3::zeros();
    let mut sigma = Vector3::from(sigma0.0);
    for i in 0..3 {
        let horizontal = OMEGA_IE * cos * c_bn[(i, 0)].hypot(c_bn[(i, 1)]) * turned;
        let r = horizontal.powi(2) + arw[i].powi(2) / duration_s;
        let p0 = sigma0[i].powi(2);
        if !(r.is_finite() && p0.is_finite() && p0 + r > 0.0) {
            continue;
        }
        let gain = p0 / (p0 + r);
        bias[i] = gain * measured[i];
        sigma[i] = ((1.0 - gain) * p0).sqrt();
    }
    StaticGyroBias { bias, sigma }
}

impl StaticLeveller {
    /// Adds one interval of `dt_s` seconds with mean specific force `f_b` and rate `w_b`.
    /// Stops accumulating for good at the first sign of motion: a rate off the running mean
    /// by more than `gyro_threshold`, a specific force off the running mean by more than
    /// `accel_threshold` (or, for the first sample, off gravity by more than that plus
    /// [`LEVEL_GRAVITY_TOLERANCE`]).
    pub fn add(
        &mut self,
        f_b: &Vector3<f64>,
        w_b: &Vector3<f64>,
        dt_s: f64,
        gravity: f64,
        gyro_threshold: f64,
        accel_threshold: f64,
    ) {
        let finite = f_b.iter().chain(w_b.iter()).all(|v| v.is_finite());
        if !finite || dt_s.is_nan() || dt_s <= 0.0 {
            return;
        }
        if !self.moved {
            let (off, turning) = if self.duration_s > 0.0 {
                (
                    (f_b - self.sum_f / self.duration_s).norm(),
                    (w_b - self.sum_w / self.duration_s).norm(),
                )
            } else {
                // Gravity's magnitude against the reading's, within a MEMS part's zero-g
                // offset.
                (
                    ((f_b.norm() - gravity).abs() - LEVEL_GRAVITY_TOLERANCE).max(0.0),
                    0.0,
                )
            };
            self.moved = turning > gyro_threshold || off > accel_threshold;
        }
        if self.moved {
            // The first moving sample's turn counts too.
            self.sum_w_moving += w_b * dt_s;
            self.duration_moving_s += dt_s;
        } else {
            self.sum_f += f_b * dt_s;
            self.sum_w += w_b * dt_s;
            self.duration_s += dt_s;
        }
    }

    /// Ends the static period (the GNSS says the vehicle moves).
    pub fn stop(&mut self) {
        self.moved = true;
    }

    /// Seconds of static data collected.
    pub fn duration_s(&self) -> f64 {
        self.duration_s
    }

    /// Heading turned since the still period ended, rad: the heading now less the heading
    /// while still (0 before motion).
    pub fn turned_rad(&self) -> f64 {
        // The heading's rate is the rate less the still mean (bias and earth rate), turned
        // level with the roll and pitch of the still period; both are fixed once it ended,
        // so the integral of the rate gives the turn.
        match (self.mean_gyro(), self.roll_pitch()) {
            (Some(mean), Some((roll, pitch))) => {
                let turn_b = self.sum_w_moving - mean * self.duration_moving_s;
                (attitude(roll, pitch, 0.0) * turn_b).z
            }
            _ => 0.0,
        }
    }

    /// Whether motion ended the static period.
    pub fn moved(&self) -> bool {
        self.moved
    }

    /// Roll and pitch from the static data, or `None` with none collected.
    pub fn roll_pitch(&self) -> Option<(f64, f64)> {
        self.mean_specific_force().map(|f| level(&f))
    }

    /// Mean specific force over the static data, or `None` with none collected.
    pub fn mean_specific_force(&self) -> Option<Vector3<f64>> {
        (self.duration_s > 0.0).then(|| self.sum_f / self.duration_s)
    }

    /// Mean angular rate over the static data, or `None` with none collected.
    pub fn mean_gyro(&self) -> Option<Vector3<f64>> {
        (self.duration_s > 0.0).then(|| self.sum_w / self.duration_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use imulab_earth as earth;
    use imulab_sim::motion::static_truth;

    #[test]
    fn levelling_recovers_roll_and_pitch() {
        for &(roll, pitch, yaw) in &[(0.0, 0.0, 0.0), (0.1, -0.2, 2.5), (-0.3, 0.25, -1.0)] {
            let t = static_truth(0.8, 0.0, 50.0, attitude(roll, pitch, yaw));
            let mut lev = StaticLeveller::default();
            let g = earth::normal_gravity(0.8, 50.0);
            for _ in 0..10 {
                lev.add(&t.accel_b, &t.gyro_b, 0.01, g, 0.01, 0.1);
            }
            let (r, p) = lev.roll_pitch().expect("static data");
            assert!(
                (r - roll).abs() < 1e-12 && (p - pitch).abs() < 1e-12,
                "{r} {p}"
            );
        }
        assert!(
            (heading_from_velocity(&Vector3::new(0.0, -3.0, 0.0)) + std::f64::consts::FRAC_PI_2)
                .abs()
                < 1e-12
        );
    }

    #[test]
    fn leveller_measures_a_gyro_bias_above_the_motion_threshold() {
        let mut lev = StaticLeveller::default();
        let f = Vector3::new(0.0, 0.0, -9.8);
        // A consumer part: 0.1 rad/s of turn-on bias, twice the motion threshold.
        let bias = Vector3::new(0.1, -0.04, 0.07);
        for _ in 0..100 {
            lev.add(&f, &bias, 0.01, 9.8, 0.05, 0.3);
        }
        assert!(!lev.moved());
        assert!((lev.mean_gyro().expect("static data") - bias).norm() < 1e-12);
        lev.add(
            &f,
            &(bias + Vector3::new(0.0, 0.0, 0.06)),
            0.01,
            9.8,
            0.05,
            0.3,
        );
        assert!(lev.moved(), "a turn of 0.06 rad/s ends the still period");
    }

    #[test]
    fn static_gyro_bias_removes_earth_rate_and_weighs_the_prior() {
        let lat = 0.8f64;
        let (roll, pitch, heading) = (0.02, -0.03, 1.2);
        let c_bn = attitude(roll, pitch, heading)
            .to_rotation_matrix()
            .into_inner()
            .transpose();
        let bias = Vector3::new(0.1, -0.05, 0.08);
        let earth = c_bn * Vector3::new(OMEGA_IE * lat.cos(), 0.0, -OMEGA_IE * lat.sin());
        let mean = bias + earth;
        let arw = Axes::all(1e-6);
        let wide = Axes::all(0.1);
        let horizontal = OMEGA_IE * lat.cos();
        // The heading known: the whole earth rate goes, and only the white noise is left.
        let known = static_gyro_bias(&mean, 60.0, roll, pitch, heading, 0.0, lat, &arw, &wide);
        assert!((known.bias - bias).norm() < 1e-9, "{:?}", known.bias);
        assert!(
            known.sigma.max() < 1e-6 / 60f64.sqrt() * 1.01,
            "{}",
            known.sigma
        );
        // Known to 5°: a horizontal axis keeps the earth rate turned by 5° as its error bound.
        let five = 5f64.to_radians();
        let b = static_gyro_bias(&mean, 60.0, roll, pitch, heading, five, lat, &arw, &wide);
        assert!((b.bias - bias).norm() < 1e-6, "{:?}", b.bias);
        assert!(
            b.sigma.x > 0.98 * five * horizontal && b.sigma.x < 1.01 * five * horizontal,
            "{} vs {}",
            b.sigma.x,
            five * horizontal
        );
        // Heading unknown: the earth rate's whole horizontal part bounds the error, and the
        // vertical axis is free of it (tilt aside).
        let lost = static_gyro_bias(&mean, 60.0, roll, pitch, 0.0, 10.0, lat, &arw, &wide);
        assert!(lost.sigma.x > 0.95 * horizontal && lost.sigma.x < 1.01 * horizontal);
        assert!(lost.sigma.z < 0.1 * horizontal, "{}", lost.sigma.z);
        // A prior tighter than the earth rate's horizontal part barely moves.
        let tight = Axes::all(1e-6);
        let t = static_gyro_bias(&mean, 60.0, roll, pitch, 0.0, 10.0, lat, &arw, &tight);
        assert!(t.bias.x.abs() < 0.01 * bias.x, "{}", t.bias.x);
        assert!(t.sigma.x > 0.99e-6 && t.sigma.x <= 1e-6);
    }

    #[test]
    fn leveller_follows_the_heading_turned_after_the_still_period() {
        let g = 9.80665;
        let bias = Vector3::new(0.01, -0.02, 0.03);
        let f = Vector3::new(0.0, 0.0, -g);
        let run = |lev: &mut StaticLeveller, rate: &Vector3<f64>, samples: usize| {
            for _ in 0..samples {
                lev.add(
                    &f,
                    rate,
                    0.01,
                    g,
                    LEVEL_GYRO_THRESHOLD,
                    LEVEL_ACCEL_THRESHOLD,
                );
            }
        };
        let mut lev = StaticLeveller::default();
        run(&mut lev, &bias, 1000);
        assert_eq!(lev.turned_rad(), 0.0);
        // A quarter turn to the left at 0.5 rad/s, then a straight run: the bias is not a turn.
        let left = bias + Vector3::new(0.0, 0.0, -0.5);
        let quarter = (std::f64::consts::FRAC_PI_2 / 0.5 / 0.01).round() as usize;
        run(&mut lev, &left, quarter);
        run(&mut lev, &bias, 500);
        assert!(lev.moved());
        assert!(
            (lev.turned_rad() + std::f64::consts::FRAC_PI_2).abs() < 1e-3,
            "{}",
            lev.turned_rad()
        );
        assert!((lev.mean_gyro().expect("still data") - bias).norm() < 1e-12);
    }

    #[test]
    fn levelling_tilt_jacobian_cancels_the_bias_in_the_specific_force() {
        // Levelled on f_b + b, the attitude error φ_h = J δb makes [f×]φ − C δb vanish in
        // the horizontal rows (the filter's velocity-error equation at rest).
        let q = attitude(0.05, -0.02, 1.1);
        let f_true = q.inverse() * Vector3::new(0.0, 0.0, -9.8);
        let j = levelling_tilt_jacobian(&f_true, &q).expect("vertical gravity");
        let db = Vector3::new(0.02, -0.03, 0.05);
        let phi_h = j * db;
        let phi = Vector3::new(phi_h.x, phi_h.y, 0.0);
        let f_n = q * f_true;
        let residual = f_n.cross(&phi) - q * db;
        assert!(
            residual.x.abs() < 1e-3 * db.norm() && residual.y.abs() < 1e-3 * db.norm(),
            "{residual:?}"
        );
    }

    #[test]
    fn leveller_stops_at_motion() {
        let mut lev = StaticLeveller::default();
        let f = Vector3::new(0.0, 0.0, -9.8);
        lev.add(&f, &Vector3::zeros(), 1.0, 9.8, 0.01, 0.1);
        lev.add(
            &Vector3::new(2.0, 0.0, -9.8),
            &Vector3::zeros(),
            1.0,
            9.8,
            0.01,
            0.1,
        );
        lev.add(&f, &Vector3::zeros(), 1.0, 9.8, 0.01, 0.1);
        assert_eq!(lev.duration_s(), 1.0);
    }
}
