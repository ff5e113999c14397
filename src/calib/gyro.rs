//! Gyroscope calibration from the rotations between poses: with the model raw = M·ω + b
//! (M a full 3×3 matrix in the accelerometer's frame), the corrected rates M⁻¹(raw − b)
//! integrated from the end of one still pose to the start of the next must turn the gravity
//! direction the calibrated accelerometer gives in the first pose into the one it gives in
//! the second. The bias during a rotation is taken as the still rate interpolated between
//! the two poses (which also removes the earth rate and g-sensitivity each pose sees); the
//! nine entries of M come from a nonlinear least-squares fit over the rotations.

use super::lsq::{conditioning, minimise};
use super::recording::Recording;
use super::statics::{unit, StaticInterval};
use super::TriadModel;
use anyhow::{bail, Result};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use rayon::prelude::*;

/// Fewest rotations the nine-parameter fit accepts.
pub const MIN_ROTATIONS: usize = 6;

/// The gyro fit and how well the data supported it.
#[derive(Debug, Clone)]
pub struct GyroFit {
    pub model: TriadModel,
    /// RMS angle between the gravity direction the rotations predict and the one the
    /// accelerometer gives, rad, with M = I (before) and the fitted M (after).
    pub residual_before: f64,
    pub residual_after: f64,
    pub rotations: usize,
    pub converged: bool,
}

/// One rotation between consecutive poses: the rate increments (raw − bias)·dt and the
/// gravity directions before and after.
struct Rotation {
    increments: Vec<Vector3<f64>>,
    before: Vector3<f64>,
    after: Vector3<f64>,
}

impl Rotation {
    /// Gravity direction after the rotation predicted with correction matrix `a` = M⁻¹.
    fn predict(&self, a: &Matrix3<f64>) -> Vector3<f64> {
        let mut q = UnitQuaternion::identity();
        for d in &self.increments {
            q *= UnitQuaternion::from_scaled_axis(a * d);
        }
        q.inverse_transform_vector(&self.before)
    }
}

fn matrix(p: &[f64]) -> Matrix3<f64> {
    Matrix3::from_row_slice(&p[..9])
}

/// Fits the gyro over the rotations between consecutive `poses` of `rec`, with gravity
/// directions from the calibrated accelerometer `accel`.
pub fn fit_gyro(rec: &Recording, poses: &[StaticInterval], accel: &TriadModel) -> Result<GyroFit> {
    let rotations: Vec<Rotation> = poses
        .windows(2)
        .map(|w| {
            let (p, q) = (&w[0], &w[1]);
            let (t0, t1) = (rec.t[p.end - 1], rec.t[q.start]);
            let bias_at = |t: f64| {
                let s = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0);
                Vector3::from(p.gyro_mean) * (1.0 - s) + Vector3::from(q.gyro_mean) * s
            };
            let increments = (p.end - 1..q.start)
                .map(|i| {
                    let dt = rec.t[i + 1] - rec.t[i];
                    let mid = (Vector3::from(rec.gyro[i]) + Vector3::from(rec.gyro[i + 1])) / 2.0;
                    (mid - bias_at((rec.t[i] + rec.t[i + 1]) / 2.0)) * dt
                })
                .collect();
            let dir = |s: &StaticInterval| Vector3::from(unit(accel.correct(&s.accel_mean)).0);
            Rotation {
                increments,
                before: dir(p),
                after: dir(q),
            }
        })
        .collect();
    if rotations.len() < MIN_ROTATIONS {
        bail!(
            "found {} rotations between still poses; the gyro fit needs at least {MIN_ROTATIONS} (12 or more recommended): turn the IMU about each of its axes between the poses",
            rotations.len()
        );
    }
    let residuals = |p: &[f64]| -> Vec<f64> {
        let a = matrix(p)
            .try_inverse()
            .unwrap_or(Matrix3::from_element(f64::NAN));
        rotations
            .par_iter()
            .map(|r| r.after - r.predict(&a))
            .collect::<Vec<_>>()
            .into_iter()
            .flat_map(|v| [v.x, v.y, v.z])
            .collect()
    };
    let x0 = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let steps = [1e-7; 9];
    let c = conditioning(&residuals, &x0, &steps);
    if c < 1e-9 {
        bail!(
            "the rotations between the poses cannot separate the gyro's scale factors and misalignment (conditioning {c:.1e}): turn the IMU about each of its three axes, in both directions, between poses"
        );
    }
    let rms_angle = |r: &[f64]| {
        (r.chunks(3)
            .map(|v| {
                (2.0 * ((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() / 2.0).asin()).powi(2)
            })
            .sum::<f64>()
            / (r.len() / 3) as f64)
            .sqrt()
    };
    let before = rms_angle(&residuals(&x0));
    let fit = minimise(&residuals, &x0, &steps);
    let p = &fit.params;
    let s = &fit.sigma;
    let n = poses.len() as f64;
    let mut bias = [0.0; 3];
    for pose in poses {
        for (b, g) in bias.iter_mut().zip(&pose.gyro_mean) {
            *b += g / n;
        }
    }
    let mut spread = [0.0; 3];
    for pose in poses {
        for k in 0..3 {
            spread[k] += (pose.gyro_mean[k] - bias[k]).powi(2) / (n - 1.0).max(1.0);
        }
    }
    Ok(GyroFit {
        model: TriadModel {
            bias,
            bias_sigma: spread.map(|v| (v / n).sqrt()),
            matrix: [[p[0], p[1], p[2]], [p[3], p[4], p[5]], [p[6], p[7], p[8]]],
            matrix_sigma: [[s[0], s[1], s[2]], [s[3], s[4], s[5]], [s[6], s[7], s[8]]],
        },
        residual_before: before,
        residual_after: rms_angle(&fit.residuals),
        rotations: rotations.len(),
        converged: fit.converged,
    })
}
