//! The true calibration of a simulated IMU, in the convention a fit reports: the
//! simulator's accelerometer matrix M (any 3×3) split as L·Q, L lower triangular (what the
//! gravity-magnitude fit can see) and Q the rotation from the body frame to the
//! accelerometer frame; the gyro's M in that frame is M_g·Qᵀ. Biases are the simulator's
//! mean true bias over the run (its turn-on draw included).

use super::file::{lq, TriadModel};
use anyhow::{anyhow, Context, Result};
use imulab_sim::imu_model::ImuSpec;
use imulab_sim::scene::Scene;
use imulab_store::{Session, TimeRange};
use nalgebra::Matrix3;
use std::path::Path;

/// True accel and gyro models of one IMU.
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    pub accel: TriadModel,
    /// The gyro in the accelerometer's frame (a tumble's convention).
    pub gyro: TriadModel,
    /// The gyro in the body frame (a rate table's).
    pub gyro_body: TriadModel,
}

/// The simulator's M = I + diag(scale factor) + misalignment of one triad.
fn sim_matrix(scale: [f64; 3], mis: [f64; 6]) -> Matrix3<f64> {
    let (s, m) = (scale.map(|v| v * 1e-6), mis.map(|v| v * 1e-3));
    Matrix3::new(
        1.0 + s[0],
        m[0],
        m[1],
        m[2],
        1.0 + s[1],
        m[3],
        m[4],
        m[5],
        1.0 + s[2],
    )
}

fn model(m: &Matrix3<f64>, bias: [f64; 3]) -> TriadModel {
    TriadModel {
        bias,
        bias_sigma: [0.0; 3],
        matrix: [0, 1, 2].map(|i| [m[(i, 0)], m[(i, 1)], m[(i, 2)]]),
        matrix_sigma: [[0.0; 3]; 3],
    }
}

impl Truth {
    /// The truth of `spec` with mean true biases `gyro_bias` (rad/s) and `accel_bias` (m/s²).
    pub fn of_spec(spec: &ImuSpec, gyro_bias: [f64; 3], accel_bias: [f64; 3]) -> Truth {
        let ma = sim_matrix(spec.accel.scale_factor_ppm, spec.accel.misalignment_mrad);
        let mg = sim_matrix(spec.gyro.scale_factor_ppm, spec.gyro.misalignment_mrad);
        let (l, q) = lq(&ma);
        Truth {
            accel: model(&l, accel_bias),
            gyro: model(&(mg * q.transpose()), gyro_bias),
            gyro_body: model(&mg, gyro_bias),
        }
    }

    /// The truth of IMU `device` of a simulated session: the scene in its manifest and the
    /// mean of its `/truth/imu/<device>` biases. `None` when the session is not simulated.
    pub fn of_session(dir: &Path, device: &str) -> Result<Option<Truth>> {
        let session = Session::open(dir)?;
        let manifest = session.manifest();
        let is_sim = manifest.device(device).is_some_and(|d| d.protocol == "sim");
        if !is_sim || manifest.truth_nav_rate_hz.is_none() {
            return Ok(None);
        }
        let text = toml::to_string(&manifest.config).context("scene of the session")?;
        let scene = Scene::parse(&text, dir).context("scene of the session")?;
        let spec = scene
            .imus
            .iter()
            .find(|i| i.name == device)
            .ok_or_else(|| anyhow!("the session's scene has no IMU `{device}`"))?
            .spec
            .clone();
        let (mut g, mut a, mut n) = ([0.0; 3], [0.0; 3], 0usize);
        for block in session.truth_imu_blocks(device, TimeRange::all(), 65_536)? {
            let block = block?;
            for (gb, ab) in block.gyro_bias.iter().zip(&block.accel_bias) {
                for k in 0..3 {
                    g[k] += gb[k];
                    a[k] += ab[k];
                }
                n += 1;
            }
        }
        if n == 0 {
            return Ok(None);
        }
        let n = n as f64;
        Ok(Some(Truth::of_spec(
            &spec,
            g.map(|v| v / n),
            a.map(|v| v / n),
        )))
    }
}
