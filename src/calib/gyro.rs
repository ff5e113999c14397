//! Gyroscope calibration from the rotations between poses: with the model raw = M·ω + b
//! (M a full 3×3 matrix in the accelerometer's frame), the corrected rates M⁻¹(raw − b)
//! integrated from the end of one still pose to the start of the next must turn the gravity
//! direction the calibrated accelerometer gives in the first pose into the one it gives in
//! the second. The bias during a rotation is taken as the still rate interpolated between
//! the two poses (which also removes the earth rate and g-sensitivity each pose sees); the
//! nine entries of M come from a nonlinear least-squares fit over the rotations, with the
//! Jacobian of each rotation formed analytically in the same pass that integrates it (the
//! perturbation of every step carried to the end of the rotation), so an iteration
//! integrates each rotation once rather than once per parameter and direction.

use super::lsq::{conditioning_of, minimise_with};
use super::recording::Recording;
use super::statics::{unit, StaticInterval};
use super::TriadModel;
use anyhow::{bail, Result};
use nalgebra::{DMatrix, Matrix3, SMatrix, Vector3};
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

/// The skew-symmetric matrix [v]× with [v]× w = v × w.
fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// The rotation matrix Exp(φ) and the right Jacobian J_r(φ) of SO(3), with Exp(φ + δ) ≈
/// Exp(φ)·Exp(J_r(φ)·δ).
fn exp_and_right_jacobian(phi: &Vector3<f64>) -> (Matrix3<f64>, Matrix3<f64>) {
    let t2 = phi.norm_squared();
    let (s, c, d) = if t2 < 1e-8 {
        // Taylor series of sin θ/θ, (1 − cos θ)/θ², (θ − sin θ)/θ³.
        (1.0 - t2 / 6.0, 0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0)
    } else {
        let t = t2.sqrt();
        (t.sin() / t, (1.0 - t.cos()) / t2, (t - t.sin()) / (t2 * t))
    };
    let k = skew(phi);
    let k2 = k * k;
    let i = Matrix3::identity();
    (i + k * s + k2 * c, i - k * c + k2 * d)
}

/// The rotation matrix Exp(φ) alone.
fn exp(phi: &Vector3<f64>) -> Matrix3<f64> {
    let t2 = phi.norm_squared();
    let (s, c) = if t2 < 1e-8 {
        (1.0 - t2 / 6.0, 0.5 - t2 / 24.0)
    } else {
        let t = t2.sqrt();
        (t.sin() / t, (1.0 - t.cos()) / t2)
    };
    let k = skew(phi);
    Matrix3::identity() + k * s + k * k * c
}

impl Rotation {
    /// Gravity direction after the rotation predicted with correction matrix `a` = M⁻¹.
    fn predict(&self, a: &Matrix3<f64>) -> Vector3<f64> {
        self.predict_with_jacobian(a, false).0
    }

    /// The predicted direction p = Rᵀ·before, R = Exp(a·d₁)…Exp(a·d_N), and (when `with_jacobian`)
    /// ∂p/∂a with a's entries row by row. A change δa turns R into R·Exp(ε) with
    /// ε = Σₖ Sₖᵀ J_r(a·dₖ) δa dₖ (Sₖ the steps after k), so p changes by [p]× ε.
    fn predict_with_jacobian(
        &self,
        a: &Matrix3<f64>,
        with_jacobian: bool,
    ) -> (Vector3<f64>, SMatrix<f64, 3, 9>) {
        let mut suffix = Matrix3::identity();
        let mut g = SMatrix::<f64, 3, 9>::zeros();
        for d in self.increments.iter().rev() {
            let phi = a * d;
            if with_jacobian {
                let (e, jr) = exp_and_right_jacobian(&phi);
                let b: Matrix3<f64> = suffix.transpose() * jr;
                for i in 0..3 {
                    for j in 0..3 {
                        let mut col = g.column_mut(3 * i + j);
                        col += b.column(i) * d[j];
                    }
                }
                suffix = e * suffix;
            } else {
                suffix = exp(&phi) * suffix;
            }
        }
        let p = suffix.transpose() * self.before;
        (p, skew(&p) * g)
    }
}

fn matrix(p: &[f64]) -> Matrix3<f64> {
    Matrix3::from_row_slice(&p[..9])
}

/// ∂a/∂M for a = M⁻¹, entries of both row by row: ∂a_kl/∂M_ij = −a_ki·a_jl.
fn inverse_derivative(a: &Matrix3<f64>) -> SMatrix<f64, 9, 9> {
    let mut t = SMatrix::<f64, 9, 9>::zeros();
    for k in 0..3 {
        for l in 0..3 {
            for i in 0..3 {
                for j in 0..3 {
                    t[(3 * k + l, 3 * i + j)] = -a[(k, i)] * a[(j, l)];
                }
            }
        }
    }
    t
}

/// One rotation between consecutive poses `p` and `q` of `rec`.
fn rotation(
    rec: &Recording,
    p: &StaticInterval,
    q: &StaticInterval,
    accel: &TriadModel,
) -> Rotation {
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
}

/// Fits the gyro over the rotations between consecutive poses of each run (a recording and
/// its poses; never from one run into the next), with gravity directions from the
/// calibrated accelerometer `accel`.
pub fn fit_gyro(runs: &[(&Recording, &[StaticInterval])], accel: &TriadModel) -> Result<GyroFit> {
    let rotations: Vec<Rotation> = runs
        .iter()
        .flat_map(|&(rec, poses)| poses.windows(2).map(|w| rotation(rec, &w[0], &w[1], accel)))
        .collect();
    let poses: Vec<&StaticInterval> = runs.iter().flat_map(|(_, p)| p.iter()).collect();
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
    // The residual is after − p, so its Jacobian in M is −∂p/∂a · ∂a/∂M.
    let jacobian = |p: &[f64]| -> DMatrix<f64> {
        let Some(a) = matrix(p).try_inverse() else {
            return DMatrix::from_element(3 * rotations.len(), 9, f64::NAN);
        };
        let t = inverse_derivative(&a);
        let blocks: Vec<SMatrix<f64, 3, 9>> = rotations
            .par_iter()
            .map(|r| -(r.predict_with_jacobian(&a, true).1 * t))
            .collect();
        let mut j = DMatrix::zeros(3 * rotations.len(), 9);
        for (k, b) in blocks.iter().enumerate() {
            j.view_mut((3 * k, 0), (3, 9)).copy_from(b);
        }
        j
    };
    let x0 = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let steps = [1e-7; 9];
    let c = conditioning_of(&jacobian(&x0));
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
    let fit = minimise_with(&residuals, Some(&jacobian), &x0, &steps);
    let p = &fit.params;
    let s = &fit.sigma;
    let n = poses.len() as f64;
    let mut bias = [0.0; 3];
    for pose in &poses {
        for (b, g) in bias.iter_mut().zip(&pose.gyro_mean) {
            *b += g / n;
        }
    }
    let mut spread = [0.0; 3];
    for pose in &poses {
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

#[cfg(test)]
mod tests {
    use super::*;

    fn rotation() -> Rotation {
        // A turn of about 100° about a wandering axis in 400 steps.
        let increments = (0..400)
            .map(|i| {
                let t = i as f64 / 400.0;
                Vector3::new(
                    0.004 + 0.002 * t,
                    -0.003 * (6.0 * t).sin(),
                    0.002 * (3.0 * t).cos(),
                )
            })
            .collect();
        Rotation {
            increments,
            before: Vector3::new(0.1, -0.2, 0.97).normalize(),
            after: Vector3::zeros(),
        }
    }

    #[test]
    fn analytic_jacobian_matches_central_differences() {
        let r = rotation();
        let m = Matrix3::new(
            1.01, 0.004, -0.006, -0.003, 0.99, 0.005, 0.007, -0.002, 1.015,
        );
        let a = m.try_inverse().unwrap();
        let (p, dp_da) = r.predict_with_jacobian(&a, true);
        assert!((p - r.predict(&a)).norm() < 1e-14);
        let analytic = -(dp_da * inverse_derivative(&a));
        let h = 1e-7;
        for k in 0..9 {
            let mut up = m;
            up[(k / 3, k % 3)] += h;
            let mut down = m;
            down[(k / 3, k % 3)] -= h;
            let numeric = -(r.predict(&up.try_inverse().unwrap())
                - r.predict(&down.try_inverse().unwrap()))
                / (2.0 * h);
            let err = (numeric - analytic.column(k)).norm();
            assert!(
                err < 1e-6 * numeric.norm().max(1e-3),
                "column {k}: numeric {numeric:?} analytic {:?}",
                analytic.column(k)
            );
        }
    }
}
