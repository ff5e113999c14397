//! The calibration file: a versioned JSON document (format in docs/calibration.md) with the
//! sensor and session it came from, units, each triad's bias and scale/misalignment matrix
//! with standard errors, and the fit's quality figures; also written as a Kalibr-style YAML
//! and a MATLAB script. [`Corrector`] is the one place it is applied (`--calibration` in
//! `allan`, `report`, `thermal`, `export` and `replay`).

use anyhow::{bail, Context, Result};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::Path;

/// `format` of the document.
pub const FORMAT: &str = "imulab-calibration";
/// Version of the layout. Readers take this one and version 1 (whose one-axis `rate_table`
/// summary, an older layout, is left out on reading); they refuse others.
pub const VERSION: u32 = 2;
/// The model, as written in every file.
pub const MODEL: &str = "raw = M * true + b; corrected = inverse(M) * (raw - b)";

/// One triad: raw = M·x + b.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TriadModel {
    /// b, in the triad's unit (rad/s or m/s^2).
    pub bias: [f64; 3],
    /// 1σ standard error of b.
    pub bias_sigma: [f64; 3],
    /// M, row by row (dimensionless): the diagonal is 1 + scale factor, M[i][j] the
    /// sensitivity of axis i to input about axis j.
    pub matrix: [[f64; 3]; 3],
    /// 1σ standard error of each entry of M (0 where the frame convention fixes it).
    pub matrix_sigma: [[f64; 3]; 3],
}

impl TriadModel {
    pub fn m(&self) -> Matrix3<f64> {
        Matrix3::from_fn(|i, j| self.matrix[i][j])
    }

    /// M⁻¹(raw − b), or the raw value when M is singular (never for a checked model).
    pub fn correct(&self, raw: &[f64; 3]) -> [f64; 3] {
        let r = Vector3::from(*raw) - Vector3::from(self.bias);
        match self.m().try_inverse() {
            Some(inv) => (inv * r).into(),
            None => *raw,
        }
    }

    /// Scale-factor errors M_ii − 1, ppm.
    pub fn scale_factor_ppm(&self) -> [f64; 3] {
        [0, 1, 2].map(|i| (self.matrix[i][i] - 1.0) * 1e6)
    }

    /// Off-diagonal entries xy, xz, yx, yz, zx, zy, mrad (the simulator's order).
    pub fn misalignment_mrad(&self) -> [f64; 6] {
        let m = &self.matrix;
        [m[0][1], m[0][2], m[1][0], m[1][2], m[2][0], m[2][1]].map(|v| v * 1e3)
    }

    fn check(&self, what: &str) -> Result<()> {
        let all = self
            .bias
            .iter()
            .chain(self.matrix.iter().flatten())
            .chain(&self.bias_sigma)
            .chain(self.matrix_sigma.iter().flatten());
        if all.clone().any(|v| v.is_infinite()) || self.bias.iter().any(|v| !v.is_finite()) {
            bail!("{what}: bias and matrix must be finite numbers");
        }
        if self.matrix.iter().flatten().any(|v| !v.is_finite()) {
            bail!("{what}: matrix must hold finite numbers");
        }
        let det = self.m().determinant();
        if det.is_nan() || det.abs() <= 1e-6 {
            bail!("{what}: matrix is singular (determinant {det:.3e})");
        }
        Ok(())
    }
}

/// One gyro axis's scale factor and non-linearity from a rate-table mounting.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RateTableAxis {
    /// The gyro axis along the spindle's positive direction (`x`, `-x`, … `-z`).
    pub axis: String,
    /// Table rates of the mounting, °/s, in order.
    pub rates_dps: Vec<f64>,
    /// Scale-factor error of that axis, ppm, and its 1σ.
    pub scale_factor_ppm: f64,
    pub scale_factor_sigma_ppm: f64,
    /// Quadratic term of the output against rate, ppm of reading per °/s, and its 1σ.
    pub quadratic_ppm_per_dps: f64,
    pub quadratic_sigma_ppm_per_dps: f64,
    /// Largest deviation from the straight-line fit, ppm of the largest rate used.
    pub nonlinearity_ppm_of_full_scale: f64,
}

/// How well the data supported the fit.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Quality {
    /// Still poses found and used (after dropping outliers).
    pub poses: usize,
    /// Start times (s) of poses dropped for moving.
    pub rejected_pose_times_s: Vec<f64>,
    /// Rotations between poses used by the gyro fit.
    pub rotations: usize,
    /// RMS of |specific force| − g over the poses, m/s^2, raw and corrected.
    pub gravity_residual_before: Option<f64>,
    pub gravity_residual_after: Option<f64>,
    /// The same with a constant accel bias (differs from `gravity_residual_after` when the
    /// fit kept a bias drift).
    pub gravity_residual_constant_bias: Option<f64>,
    /// Accel bias drift over the fitted run, m/s^2 per s, and its 1σ (present when the data
    /// supported it; `accel.bias` is then the bias at the middle of the poses).
    pub accel_bias_drift: Option<[f64; 3]>,
    pub accel_bias_drift_sigma: Option<[f64; 3]>,
    /// RMS angle between predicted and measured gravity after each rotation, rad, raw
    /// rates and corrected.
    pub rotation_residual_before: Option<f64>,
    pub rotation_residual_after: Option<f64>,
}

/// The whole document.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Calibration {
    pub format: String,
    pub version: u32,
    pub generator: String,
    /// The IMU (session device name, or the file's stem).
    pub device: String,
    /// What it was fitted on (path and device).
    pub source: String,
    /// `multi-position`, `six-position` or `rate-table`.
    pub method: String,
    pub model: String,
    /// The frame the corrected values are in.
    pub frame: String,
    /// Units of the biases (gyro, accel); M is dimensionless.
    pub gyro_unit: String,
    pub accel_unit: String,
    /// Local gravity the accelerometer fit used, m/s^2.
    pub gravity: Option<f64>,
    pub accel: Option<TriadModel>,
    pub gyro: Option<TriadModel>,
    /// Rate-table method: one entry per mounting.
    pub rate_table: Option<Vec<RateTableAxis>>,
    pub quality: Quality,
}

impl Calibration {
    /// An empty document for `device` from `source` by `method`.
    pub fn new(device: &str, source: &str, method: &str, frame: &str) -> Calibration {
        Calibration {
            format: FORMAT.into(),
            version: VERSION,
            generator: format!("imulab {}", env!("CARGO_PKG_VERSION")),
            device: device.into(),
            source: source.into(),
            method: method.into(),
            model: MODEL.into(),
            frame: frame.into(),
            gyro_unit: "rad/s".into(),
            accel_unit: "m/s^2".into(),
            gravity: None,
            accel: None,
            gyro: None,
            rate_table: None,
            quality: Quality::default(),
        }
    }

    /// Reads and checks a calibration file.
    pub fn load(path: &Path) -> Result<Calibration> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read calibration {}", path.display()))?;
        let mut doc: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| anyhow::anyhow!("{}: not a calibration file ({e})", path.display()))?;
        if doc["version"] == 1 {
            if let Some(fields) = doc.as_object_mut() {
                fields.insert("rate_table".into(), serde_json::Value::Null);
                fields.insert("version".into(), VERSION.into());
            }
        }
        let c: Calibration = serde_path_to_error::deserialize(doc).map_err(|e| {
            anyhow::anyhow!(
                "{}: not a calibration file (at {}: {})",
                path.display(),
                e.path(),
                e.inner()
            )
        })?;
        c.check()
            .with_context(|| format!("calibration {}", path.display()))?;
        Ok(c)
    }

    fn check(&self) -> Result<()> {
        if self.format != FORMAT {
            bail!("format is {:?}, expected {FORMAT:?}", self.format);
        }
        if self.version != VERSION {
            bail!(
                "version {} is not supported (this imulab reads versions 1 and {VERSION})",
                self.version
            );
        }
        if self.gyro_unit != "rad/s" || self.accel_unit != "m/s^2" {
            bail!(
                "units must be gyro_unit \"rad/s\" and accel_unit \"m/s^2\", got {:?} and {:?}",
                self.gyro_unit,
                self.accel_unit
            );
        }
        if let Some(a) = &self.accel {
            a.check("accel")?;
        }
        if let Some(g) = &self.gyro {
            g.check("gyro")?;
        }
        if self.accel.is_none() && self.gyro.is_none() {
            bail!("has neither an accel nor a gyro model");
        }
        Ok(())
    }

    /// Writes the JSON document.
    pub fn save(&self, path: &Path) -> Result<()> {
        let text = serde_json::to_string_pretty(self)?;
        std::fs::write(path, text + "\n").with_context(|| format!("writing {}", path.display()))
    }

    /// The Kalibr-style YAML: `imu0` with the scale-misalignment model's matrices.
    pub fn kalibr_yaml(&self, update_rate_hz: f64) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "# imulab calibration of {} from {} ({}).\n# Model: {MODEL}; M is the accelerometer's M, and for the gyroscopes M * C_gyro_i\n# is the gyro's M (M lower triangular, C_gyro_i a rotation). A (g-sensitivity) is not fitted.\n# Biases in rad/s and m/s^2.",
            self.device, self.source, self.method
        );
        let _ = writeln!(s, "imu0:\n  model: scale-misalignment");
        let _ = writeln!(s, "  update_rate: {update_rate_hz}");
        let mat = |m: &Matrix3<f64>| {
            let rows: Vec<String> = (0..3)
                .map(|i| format!("[{:.9}, {:.9}, {:.9}]", m[(i, 0)], m[(i, 1)], m[(i, 2)]))
                .collect();
            format!("[{}]", rows.join(", "))
        };
        let vec = |v: &[f64; 3]| {
            let [x, y, z] = v.map(yaml_float);
            format!("[{x}, {y}, {z}]")
        };
        if let Some(a) = &self.accel {
            let (l, _) = lq(&a.m());
            let _ = writeln!(
                s,
                "  accelerometers:\n    M: {}\n    bias: {}",
                mat(&l),
                vec(&a.bias)
            );
        }
        if let Some(g) = &self.gyro {
            let (l, q) = lq(&g.m());
            let _ = writeln!(
                s,
                "  gyroscopes:\n    A: {}\n    C_gyro_i: {}\n    M: {}\n    bias: {}",
                mat(&Matrix3::zeros()),
                mat(&q),
                mat(&l),
                vec(&g.bias)
            );
        }
        s
    }

    /// A MATLAB/Octave script that defines `cal` with the biases and matrices.
    pub fn matlab_script(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "% imulab calibration of {} from {} ({}).\n% Model: raw = M * true + b. Correct a 3xN block of raw samples with\n%   corrected = cal.accel.M \\ (raw - cal.accel.bias);\n% Biases in rad/s (gyro) and m/s^2 (accel).",
            self.device, self.source, self.method
        );
        let _ = writeln!(
            s,
            "cal = struct();\ncal.device = '{}';",
            self.device.replace('\'', "''")
        );
        for (name, t) in [("accel", &self.accel), ("gyro", &self.gyro)] {
            let Some(t) = t else { continue };
            let m = &t.matrix;
            let _ = writeln!(
                s,
                "cal.{name}.bias = [{:.12e}; {:.12e}; {:.12e}];",
                t.bias[0], t.bias[1], t.bias[2]
            );
            let _ = writeln!(
                s,
                "cal.{name}.M = [{:.12} {:.12} {:.12}; {:.12} {:.12} {:.12}; {:.12} {:.12} {:.12}];",
                m[0][0], m[0][1], m[0][2], m[1][0], m[1][1], m[1][2], m[2][0], m[2][1], m[2][2]
            );
        }
        s
    }
}

/// `v` in exponent form with a signed exponent (`9.806650000e+0`): YAML 1.1 readers such as
/// PyYAML, which Kalibr uses, take `9.8e0` for a string.
fn yaml_float(v: f64) -> String {
    let s = format!("{v:.9e}");
    match s.split_once('e') {
        Some((mantissa, exp)) if !exp.starts_with('-') => format!("{mantissa}e+{exp}"),
        _ => s,
    }
}

/// M = L·Q with L lower triangular (positive diagonal) and Q a rotation.
pub fn lq(m: &Matrix3<f64>) -> (Matrix3<f64>, Matrix3<f64>) {
    let qr = m.transpose().qr();
    let (mut q, mut r) = (qr.q(), qr.r());
    for i in 0..3 {
        if r[(i, i)] < 0.0 {
            for j in 0..3 {
                r[(i, j)] = -r[(i, j)];
                q[(j, i)] = -q[(j, i)];
            }
        }
    }
    (r.transpose(), q.transpose())
}

/// A calibration ready to apply to rows of SI samples.
#[derive(Debug, Clone)]
pub struct Corrector {
    gyro: Option<(Matrix3<f64>, Vector3<f64>)>,
    accel: Option<(Matrix3<f64>, Vector3<f64>)>,
}

impl Corrector {
    /// The corrector of `cal`, checked against the device it is applied to: a calibration
    /// fitted on another device is refused.
    pub fn new(cal: &Calibration, device: &str) -> Result<Corrector> {
        if cal.device != device {
            bail!(
                "the calibration is for device `{}` (from {}), not `{device}`; fit one on this device with `imulab calibrate`",
                cal.device,
                cal.source
            );
        }
        let prepare = |t: &Option<TriadModel>| {
            t.as_ref()
                .and_then(|t| Some((t.m().try_inverse()?, Vector3::from(t.bias))))
        };
        Ok(Corrector {
            gyro: prepare(&cal.gyro),
            accel: prepare(&cal.accel),
        })
    }

    /// Which triads it corrects, for messages.
    pub fn describe(&self) -> &'static str {
        match (self.gyro.is_some(), self.accel.is_some()) {
            (true, true) => "gyro and accel",
            (true, false) => "gyro",
            _ => "accel",
        }
    }

    pub fn corrects_gyro(&self) -> bool {
        self.gyro.is_some()
    }

    pub fn corrects_accel(&self) -> bool {
        self.accel.is_some()
    }

    /// Corrects rows in place (rad/s and m/s²).
    pub fn apply(&self, gyro: &mut [[f64; 3]], accel: &mut [[f64; 3]]) {
        for (triad, rows) in [(&self.gyro, gyro), (&self.accel, accel)] {
            if let Some((inv, b)) = triad {
                for r in rows.iter_mut() {
                    *r = (inv * (Vector3::from(*r) - b)).into();
                }
            }
        }
    }

    /// Corrects columns in place: `gyro` and `accel` are the x, y, z columns, when present.
    pub fn apply_columns(&self, gyro: Option<[&mut [f64]; 3]>, accel: Option<[&mut [f64]; 3]>) {
        for (triad, cols) in [(&self.gyro, gyro), (&self.accel, accel)] {
            let (Some((inv, b)), Some([x, y, z])) = (triad, cols) else {
                continue;
            };
            for i in 0..x.len().min(y.len()).min(z.len()) {
                let v = inv * (Vector3::new(x[i], y[i], z[i]) - b);
                (x[i], y[i], z[i]) = (v.x, v.y, v.z);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cal() -> Calibration {
        let mut c = Calibration::new("imu", "test", "multi-position", "accelerometer");
        c.accel = Some(TriadModel {
            bias: [0.1, -0.2, 0.3],
            bias_sigma: [1e-4; 3],
            matrix: [[1.01, 0.0, 0.0], [0.002, 0.99, 0.0], [-0.001, 0.003, 1.005]],
            matrix_sigma: [[1e-5; 3]; 3],
        });
        c
    }

    #[test]
    fn round_trips_and_corrects() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cal.json");
        let c = cal();
        c.save(&path).unwrap();
        let back = Calibration::load(&path).unwrap();
        assert_eq!(back, c);
        let a = c.accel.as_ref().unwrap();
        let truth = [0.3, -9.7, 1.2];
        let raw: [f64; 3] = (a.m() * Vector3::from(truth) + Vector3::from(a.bias)).into();
        let fixed = a.correct(&raw);
        for k in 0..3 {
            assert!((fixed[k] - truth[k]).abs() < 1e-12);
        }
        let corrector = Corrector::new(&c, "imu").unwrap();
        let mut rows = [raw];
        corrector.apply(&mut [], &mut rows);
        assert!((rows[0][1] - truth[1]).abs() < 1e-12);
        let e = Corrector::new(&c, "other").unwrap_err().to_string();
        assert!(e.contains("for device `imu`"), "{e}");
    }

    #[test]
    fn bad_files_say_what_is_wrong() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cal.json");
        let mut c = cal();
        c.version = 9;
        c.save(&path).unwrap();
        let e = format!("{:#}", Calibration::load(&path).unwrap_err());
        assert!(e.contains("version 9"), "{e}");
        std::fs::write(&path, "{\"format\": 1}").unwrap();
        let e = format!("{:#}", Calibration::load(&path).unwrap_err());
        assert!(
            e.contains("not a calibration file") && e.contains("format"),
            "{e}"
        );
        let mut c = cal();
        c.accel.as_mut().unwrap().matrix = [[0.0; 3]; 3];
        c.save(&path).unwrap();
        let e = format!("{:#}", Calibration::load(&path).unwrap_err());
        assert!(e.contains("singular"), "{e}");
    }

    #[test]
    fn version_1_files_are_read_without_their_rate_table_summary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cal.json");
        let c = cal();
        c.save(&path).unwrap();
        let mut doc: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        doc["version"] = 1.into();
        doc["rate_table"] = serde_json::json!({
            "axis": "z", "rates_dps": [10.0, -10.0, 50.0], "scale_factor_ppm": 450.0,
            "scale_factor_sigma_ppm": 5.0, "quadratic_ppm_per_dps": 0.01,
            "nonlinearity_ppm_of_full_scale": 3.0
        });
        std::fs::write(&path, doc.to_string()).unwrap();
        let back = Calibration::load(&path).unwrap();
        assert_eq!(back.rate_table, None);
        assert_eq!(back.gyro, c.gyro);
        assert_eq!(back.accel, c.accel);
    }

    #[test]
    fn lq_splits_into_triangle_and_rotation() {
        let m = Matrix3::new(1.01, 0.004, -0.006, 0.003, 0.99, 0.005, -0.002, 0.007, 1.02);
        let (l, q) = lq(&m);
        assert!((l * q - m).norm() < 1e-12);
        assert!((q * q.transpose() - Matrix3::identity()).norm() < 1e-12);
        assert!(q.determinant() > 0.0);
        assert!(l[(0, 1)] == 0.0 && l[(0, 2)].abs() < 1e-15 && l[(1, 2)].abs() < 1e-15);
    }
}
