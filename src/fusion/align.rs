//! Initial alignment: static levelling (roll and pitch from the mean specific force while the
//! IMU stands still) and heading from the GNSS track once the vehicle moves, or given.
//!
//! Low-cost gyros cannot see earth rate through their bias, so there is no gyrocompassing.

/// Motion thresholds of the levelling period: angular rate (rad/s) and deviation of the
/// specific force from its running mean (m/s²); far above MEMS noise at 1 kHz.
pub const LEVEL_GYRO_THRESHOLD: f64 = 0.05;
pub const LEVEL_ACCEL_THRESHOLD: f64 = 0.3;

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
    duration_s: f64,
    moved: bool,
}

impl StaticLeveller {
    /// Adds one interval of `dt_s` seconds with mean specific force `f_b` and rate `w_b`.
    /// Stops accumulating for good at the first sign of motion: a rate above
    /// `gyro_threshold`, a specific force off the running mean by more than
    /// `accel_threshold` (or, for the first sample, off gravity by more than that).
    pub fn add(
        &mut self,
        f_b: &Vector3<f64>,
        w_b: &Vector3<f64>,
        dt_s: f64,
        gravity: f64,
        gyro_threshold: f64,
        accel_threshold: f64,
    ) {
        if self.moved || dt_s.is_nan() || dt_s <= 0.0 {
            return;
        }
        let finite = f_b.iter().chain(w_b.iter()).all(|v| v.is_finite());
        if !finite {
            return;
        }
        let off = if self.duration_s > 0.0 {
            (f_b - self.sum_f / self.duration_s).norm()
        } else {
            (f_b.norm() - gravity).abs()
        };
        if w_b.norm() > gyro_threshold || off > accel_threshold {
            self.moved = true;
            return;
        }
        self.sum_f += f_b * dt_s;
        self.duration_s += dt_s;
    }

    /// Seconds of static data collected.
    pub fn duration_s(&self) -> f64 {
        self.duration_s
    }

    /// Whether motion ended the static period.
    pub fn moved(&self) -> bool {
        self.moved
    }

    /// Roll and pitch from the static data, or `None` with none collected.
    pub fn roll_pitch(&self) -> Option<(f64, f64)> {
        (self.duration_s > 0.0).then(|| level(&(self.sum_f / self.duration_s)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::earth;
    use crate::sim::motion::static_truth;

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
