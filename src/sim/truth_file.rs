//! Truth trajectories read from a CSV file, for motion that neither `static` nor the segment
//! generator describes (a recorded drive, another simulator's output).
//!
//! Header and columns (SI units, angles of position in degrees):
//! `t_s,lat_deg,lon_deg,height_m,vn,ve,vd,qw,qx,qy,qz,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z`
//! with the attitude body → NED as a unit quaternion (scalar first), the true angular rate
//! ω_ib^b in rad/s and specific force f_ib^b in m/s². Rows must be at the scene rate:
//! row k has t_s = k / rate_hz (within 1 µs).

use std::fs::File;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use serde::Deserialize;

use super::motion::TruthSample;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Row {
    t_s: f64,
    lat_deg: f64,
    lon_deg: f64,
    height_m: f64,
    vn: f64,
    ve: f64,
    vd: f64,
    qw: f64,
    qx: f64,
    qy: f64,
    qz: f64,
    gyro_x: f64,
    gyro_y: f64,
    gyro_z: f64,
    accel_x: f64,
    accel_y: f64,
    accel_z: f64,
}

/// Streams truth samples from a CSV file, checking each row.
pub struct TruthFileReader {
    rows: csv::DeserializeRecordsIntoIter<File, Row>,
    path: PathBuf,
    rate_hz: f64,
    index: u64,
}

impl TruthFileReader {
    /// Opens `path` for a scene at `rate_hz`.
    pub fn open(path: &Path, rate_hz: f64) -> Result<Self> {
        let file = File::open(path)
            .with_context(|| format!("cannot open truth file {}", path.display()))?;
        let reader = csv::ReaderBuilder::new()
            .trim(csv::Trim::All)
            .from_reader(file);
        Ok(TruthFileReader {
            rows: reader.into_deserialize(),
            path: path.to_path_buf(),
            rate_hz,
            index: 0,
        })
    }

    /// The next sample; None at the end of the file.
    pub fn next_sample(&mut self) -> Option<Result<TruthSample>> {
        let row = self.rows.next()?;
        let line = self.index + 2; // header is line 1
        let k = self.index;
        self.index += 1;
        Some(
            row.map_err(|e| anyhow!("{e}"))
                .and_then(|r| self.check(r, k))
                .with_context(|| format!("truth file {} line {line}", self.path.display())),
        )
    }

    fn check(&self, r: Row, k: u64) -> Result<TruthSample> {
        let values = [
            r.t_s, r.lat_deg, r.lon_deg, r.height_m, r.vn, r.ve, r.vd, r.qw, r.qx, r.qy, r.qz,
            r.gyro_x, r.gyro_y, r.gyro_z, r.accel_x, r.accel_y, r.accel_z,
        ];
        if values.iter().any(|v| !v.is_finite()) {
            bail!("every value must be a finite number");
        }
        let expected = k as f64 / self.rate_hz;
        if (r.t_s - expected).abs() > 1e-6 {
            bail!(
                "t_s {} should be {expected} (rows must be at the scene rate {} Hz)",
                r.t_s,
                self.rate_hz
            );
        }
        if r.lat_deg.abs() > 89.9 {
            bail!("lat_deg {} is outside ±89.9", r.lat_deg);
        }
        let q = Quaternion::new(r.qw, r.qx, r.qy, r.qz);
        if (q.norm() - 1.0).abs() > 1e-6 {
            bail!("quaternion norm {} is not 1", q.norm());
        }
        Ok(TruthSample {
            t_s: r.t_s,
            lat_rad: r.lat_deg.to_radians(),
            lon_rad: r.lon_deg.to_radians(),
            height_m: r.height_m,
            vel_ned: Vector3::new(r.vn, r.ve, r.vd),
            quat_nb: UnitQuaternion::from_quaternion(q),
            gyro_b: Vector3::new(r.gyro_x, r.gyro_y, r.gyro_z),
            accel_b: Vector3::new(r.accel_x, r.accel_y, r.accel_z),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    const HEADER: &str =
        "t_s,lat_deg,lon_deg,height_m,vn,ve,vd,qw,qx,qy,qz,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n";

    fn write(body: &str) -> tempfile::NamedTempFile {
        let mut f = tempfile::NamedTempFile::new().unwrap();
        f.write_all(HEADER.as_bytes()).unwrap();
        f.write_all(body.as_bytes()).unwrap();
        f
    }

    #[test]
    fn reads_rows_and_reports_bad_ones_with_line() {
        let f = write(
            "0,48,11,500,1,0,0,1,0,0,0,0,0,0,0,0,-9.8\n\
             0.1,48,11,500,1,0,0,1,0,0,0,0,0,0,0,0,-9.8\n\
             0.3,48,11,500,1,0,0,1,0,0,0,0,0,0,0,0,-9.8\n\
             0.3,48,11,500,1,0,0,2,0,0,0,0,0,0,0,0,-9.8\n",
        );
        let mut r = TruthFileReader::open(f.path(), 10.0).unwrap();
        let s = r.next_sample().unwrap().unwrap();
        assert_eq!(s.vel_ned.x, 1.0);
        assert!(r.next_sample().unwrap().is_ok());
        let e = format!("{:#}", r.next_sample().unwrap().unwrap_err());
        assert!(e.contains("line 4") && e.contains("0.2"), "{e}");
        let e = format!("{:#}", r.next_sample().unwrap().unwrap_err());
        assert!(e.contains("line 5") && e.contains("norm"), "{e}");
        assert!(r.next_sample().is_none());
    }

    #[test]
    fn garbage_is_an_error_not_a_panic() {
        let f = write("0,48,x,500\n\u{0}\u{1}\n");
        let mut r = TruthFileReader::open(f.path(), 10.0).unwrap();
        assert!(r.next_sample().unwrap().is_err());
    }
}
