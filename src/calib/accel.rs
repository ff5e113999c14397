//! Accelerometer calibration from gravity magnitude: at rest in any pose the calibrated
//! specific force has the length of local gravity. With the model raw = M·f + b, M lower
//! triangular (its frame: x along the accelerometer's x axis, y in its x-y plane; the
//! rotation a full M would add cannot be seen from magnitudes), the nine parameters come from
//! a nonlinear least-squares fit over the poses, with standard errors from the covariance.
//! One robust pass drops poses whose residual is far outside the rest (motion during a
//! "still" interval) and refits. A bias drifting linearly in time (three more parameters,
//! b(t) = b + d·(t − t̄)) is then fitted too and kept only when an F-test says the data
//! supports it (the drop in Σr² against the three parameters, at the 0.1 % level); poses
//! pooled from several recordings, on separate clocks, keep the constant bias.

use super::lsq::{conditioning, minimise, Fit};
use super::statics::{pose_spread, StaticInterval};
use super::TriadModel;
use anyhow::{bail, Result};
use statrs::distribution::{ContinuousCDF, FisherSnedecor};

/// Fewest poses the nine-parameter fit accepts.
pub const MIN_POSES: usize = 9;

/// The accelerometer fit and how well the data supported it.
#[derive(Debug, Clone)]
pub struct AccelFit {
    pub model: TriadModel,
    /// RMS of |raw| − g over the poses used, m/s² (before) and of |corrected| − g (after).
    pub residual_before: f64,
    pub residual_after: f64,
    /// Poses used and the indices (into the intervals given) dropped as outliers.
    pub poses_used: usize,
    pub rejected: Vec<usize>,
    pub converged: bool,
    /// RMS of |corrected| − g with a constant bias (the same as `residual_after` unless the
    /// drift was kept).
    pub residual_constant_bias: f64,
    /// The bias drift, when the F-test kept it.
    pub drift: Option<BiasDrift>,
}

/// A linear accelerometer bias drift over the run: the bias is `model.bias` at `t_mid_s`
/// and changes by `per_s` per second.
#[derive(Debug, Clone, PartialEq)]
pub struct BiasDrift {
    pub per_s: [f64; 3],
    /// 1σ of `per_s`.
    pub sigma_per_s: [f64; 3],
    pub t_mid_s: f64,
    /// The F-test's p-value for the drift's three parameters.
    pub p_value: f64,
}

/// Significance level at which the bias drift is kept.
pub const DRIFT_LEVEL: f64 = 0.001;

/// Corrected specific force M⁻¹(raw − b) for lower-triangular M given as the fit's
/// parameters [b (3), m00, m10, m11, m20, m21, m22].
fn corrected(p: &[f64], raw: &[f64; 3]) -> [f64; 3] {
    let r = [raw[0] - p[0], raw[1] - p[1], raw[2] - p[2]];
    let x = r[0] / p[3];
    let y = (r[1] - p[4] * x) / p[5];
    let z = (r[2] - p[6] * x - p[7] * y) / p[8];
    [x, y, z]
}

fn norm(v: &[f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

const STEPS: [f64; 12] = [
    1e-6, 1e-6, 1e-6, 1e-7, 1e-7, 1e-7, 1e-7, 1e-7, 1e-7, 1e-6, 1e-6, 1e-6,
];

/// The pose's mean less the drift part of the bias, `p[9..12]` being the bias change over
/// the poses' time span at normalised time `tau` (−½ … ½).
fn undrifted(p: &[f64], raw: &[f64; 3], tau: f64) -> [f64; 3] {
    [0, 1, 2].map(|k| raw[k] - p[9 + k] * tau)
}

/// Fits the accelerometer to the poses' mean specific forces with local gravity `g`; the
/// bias drift is tried only when `drift` (the poses' times on one clock).
pub fn fit_accel(poses: &[StaticInterval], g: f64, drift: bool) -> Result<AccelFit> {
    if poses.len() < MIN_POSES {
        bail!(
            "found {} still poses; the accelerometer fit needs at least {MIN_POSES} (12 or more recommended): hold the IMU still in at least 12 different orientations, each for longer than --min-static, with every axis pointing up and down at least once",
            poses.len()
        );
    }
    let (widest, spread) = pose_spread(poses);
    if spread < 0.02 {
        bail!(
            "the {} poses are too similar to separate bias from scale and misalignment: their gravity directions span {:.0}° and barely leave a plane or an axis (direction spread {spread:.3}, needs > 0.02); turn the IMU so that each axis points up and down at least once",
            poses.len(),
            widest.to_degrees()
        );
    }
    let mut used: Vec<usize> = (0..poses.len()).collect();
    let mut rejected = Vec::new();
    let x0 = [0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 1.0];
    let mut fit;
    loop {
        let means: Vec<[f64; 3]> = used.iter().map(|&i| poses[i].accel_mean).collect();
        let f =
            |p: &[f64]| -> Vec<f64> { means.iter().map(|m| norm(&corrected(p, m)) - g).collect() };
        let c = conditioning(&f, &x0, &STEPS[..9]);
        if c < 1e-12 {
            bail!(
                "the poses cannot separate the accelerometer's bias, scale and misalignment (conditioning {c:.1e}); add poses with each axis up and each axis down"
            );
        }
        fit = minimise(&f, &x0, &STEPS[..9]);
        // One robust pass: residuals beyond 6 scaled MADs (and above the noise a pose
        // mean can have) are poses that moved.
        let mut abs: Vec<f64> = fit.residuals.iter().map(|r| r.abs()).collect();
        let mid = abs.len() / 2;
        let mad = *abs.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1 * 1.4826;
        let limit = (6.0 * mad).max(1e-4 * g);
        let bad: Vec<usize> = fit
            .residuals
            .iter()
            .enumerate()
            .filter(|(_, r)| r.abs() > limit)
            .map(|(k, _)| used[k])
            .collect();
        if bad.is_empty() || !rejected.is_empty() || used.len() - bad.len() < MIN_POSES {
            break;
        }
        rejected = bad;
        used.retain(|i| !rejected.contains(i));
    }
    let constant = fit.clone();
    // The drifting bias on the same poses, from the constant fit.
    let times: Vec<f64> = used
        .iter()
        .map(|&i| 0.5 * (poses[i].t_start + poses[i].t_end))
        .collect();
    let t_mid = times.iter().sum::<f64>() / times.len() as f64;
    let (t_lo, t_hi) = times
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &t| {
            (a.min(t), b.max(t))
        });
    let span = (t_hi - t_lo).max(1e-9);
    let drift_fit = {
        let means: Vec<([f64; 3], f64)> = used
            .iter()
            .zip(&times)
            .map(|(&i, &t)| (poses[i].accel_mean, (t - t_mid) / span))
            .collect();
        let f = |p: &[f64]| -> Vec<f64> {
            means
                .iter()
                .map(|(m, tau)| norm(&corrected(p, &undrifted(p, m, *tau))) - g)
                .collect()
        };
        let mut x0 = constant.params.clone();
        x0.extend([0.0; 3]);
        minimise(&f, &x0, &STEPS)
    };
    let n = used.len() as f64;
    let ssr = |f: &Fit| f.residuals.iter().map(|r| r * r).sum::<f64>();
    let (ssr0, ssr1) = (ssr(&constant), ssr(&drift_fit));
    let dof = n - 12.0;
    let p_value = if dof >= 1.0 && ssr1 > 0.0 && ssr1 < ssr0 {
        let stat = (ssr0 - ssr1) / 3.0 / (ssr1 / dof);
        FisherSnedecor::new(3.0, dof).map_or(1.0, |d| 1.0 - d.cdf(stat))
    } else {
        1.0
    };
    let keep = drift && p_value < DRIFT_LEVEL && drift_fit.sigma.iter().all(|v| v.is_finite());
    let chosen = if keep { &drift_fit } else { &constant };
    let p = &chosen.params;
    let s = &chosen.sigma;
    let matrix = [[p[3], 0.0, 0.0], [p[4], p[5], 0.0], [p[6], p[7], p[8]]];
    let matrix_sigma = [[s[3], 0.0, 0.0], [s[4], s[5], 0.0], [s[6], s[7], s[8]]];
    let before = used
        .iter()
        .map(|&i| (norm(&poses[i].accel_mean) - g).powi(2))
        .sum::<f64>()
        / used.len() as f64;
    Ok(AccelFit {
        model: TriadModel {
            bias: [p[0], p[1], p[2]],
            bias_sigma: [s[0], s[1], s[2]],
            matrix,
            matrix_sigma,
        },
        residual_before: before.sqrt(),
        residual_after: chosen.rms,
        poses_used: used.len(),
        rejected,
        converged: chosen.converged,
        residual_constant_bias: constant.rms,
        drift: keep.then(|| BiasDrift {
            per_s: [9, 10, 11].map(|k| p[k] / span),
            sigma_per_s: [9, 10, 11].map(|k| s[k] / span),
            t_mid_s: t_mid,
            p_value,
        }),
    })
}
