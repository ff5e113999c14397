//! The six-position test: the IMU rests with each axis pointing up and then down (on the
//! faces of a cube or an aligned fixture). With raw = M·f + b, the axis-j-up reading is
//! g·M e_j + b and the axis-j-down one −g·M e_j + b, so each column of M is their half
//! difference over g and b the mean of all six; M is the full matrix in the fixture's
//! frame. The standard errors are those of the six means only: the fixture's own alignment
//! error adds to them.

use super::statics::StaticInterval;
use super::TriadModel;
use anyhow::{bail, Result};

const FACES: [&str; 6] = ["+x up", "-x up", "+y up", "-y up", "+z up", "-z up"];
/// Largest angle between a pose's gravity direction and its nearest axis.
const MAX_TILT_DEG: f64 = 10.0;

/// Fits the accelerometer from poses that include each axis up and down; several poses on
/// one face are averaged. Returns the model and, per pose, the face it was taken as.
pub fn six_position(poses: &[StaticInterval], g: f64) -> Result<(TriadModel, Vec<&'static str>)> {
    // Per face: weighted sum of means, of variances of the mean, and sample count.
    let mut sum = [[0.0; 3]; 6];
    let mut var = [[0.0; 3]; 6];
    let mut count = [0usize; 6];
    let mut labels = Vec::with_capacity(poses.len());
    for p in poses {
        let m = p.accel_mean;
        let norm = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
        let axis = (0..3)
            .max_by(|&a, &b| m[a].abs().total_cmp(&m[b].abs()))
            .unwrap_or(0);
        let tilt = (m[axis].abs() / norm).clamp(-1.0, 1.0).acos().to_degrees();
        if tilt > MAX_TILT_DEG {
            bail!(
                "six-position mode: the pose at {:.1}-{:.1} s is {tilt:.0}° away from any axis (the limit is {MAX_TILT_DEG}°); rest the IMU on the faces of a cube or an aligned fixture, or calibrate the poses as a tumble (without --six-position)",
                p.t_start,
                p.t_end
            );
        }
        let face = 2 * axis + usize::from(m[axis] < 0.0);
        let n = p.samples();
        for k in 0..3 {
            sum[face][k] += m[k] * n as f64;
            var[face][k] += (p.accel_std[k] * p.accel_std[k]) * n as f64;
        }
        count[face] += n;
        labels.push(FACES[face]);
    }
    let missing: Vec<&str> = (0..6)
        .filter(|&f| count[f] == 0)
        .map(|f| FACES[f])
        .collect();
    if !missing.is_empty() {
        bail!(
            "six-position mode needs each axis up and down; missing: {} (found {} poses: {})",
            missing.join(", "),
            poses.len(),
            labels.join(", ")
        );
    }
    let mut mean = [[0.0; 3]; 6];
    let mut sigma2 = [[0.0; 3]; 6];
    for f in 0..6 {
        let n = count[f] as f64;
        for k in 0..3 {
            mean[f][k] = sum[f][k] / n;
            // Variance of the mean: the samples' variance over their count.
            sigma2[f][k] = var[f][k] / n / n;
        }
    }
    let mut matrix = [[0.0; 3]; 3];
    let mut matrix_sigma = [[0.0; 3]; 3];
    let mut bias = [0.0; 3];
    let mut bias_sigma = [0.0; 3];
    for j in 0..3 {
        let (up, down) = (2 * j, 2 * j + 1);
        for i in 0..3 {
            matrix[i][j] = (mean[up][i] - mean[down][i]) / (2.0 * g);
            matrix_sigma[i][j] = (sigma2[up][i] + sigma2[down][i]).sqrt() / (2.0 * g);
        }
    }
    for i in 0..3 {
        bias[i] = (0..6).map(|f| mean[f][i]).sum::<f64>() / 6.0;
        bias_sigma[i] = (0..6).map(|f| sigma2[f][i]).sum::<f64>().sqrt() / 6.0;
    }
    Ok((
        TriadModel {
            bias,
            bias_sigma,
            matrix,
            matrix_sigma,
        },
        labels,
    ))
}
