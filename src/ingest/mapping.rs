//! Frames to session rows: unit overrides, the axis rotation into the body frame, and NaN
//! (or the documented sentinel) for whatever the device did not send.

use imulab_drivers::types::{GnssFix, ImuSample};
use nalgebra::{Matrix3, Vector3};

use imulab_store::{GnssRecord, ImuRecord};

use super::clock::Arrival;

/// Per-device conversion from sensor frame and units to body frame and SI.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuMapping {
    pub body_from_sensor: Matrix3<f64>,
    pub gyro_scale: f64,
    pub accel_scale: f64,
}

impl ImuMapping {
    fn apply(&self, v: Option<[f64; 3]>, scale: f64) -> [f64; 3] {
        match v {
            Some(v) => {
                let body = self.body_from_sensor * Vector3::from(v) * scale;
                [body.x, body.y, body.z]
            }
            None => [f64::NAN; 3],
        }
    }

    /// The row for one sample that arrived at `at`.
    pub fn imu_record(&self, sample: &ImuSample, at: Arrival) -> ImuRecord {
        ImuRecord {
            t_mono_ns: at.mono_ns,
            t_wall_ns: at.wall_ns,
            t_sensor: sample.sensor_time.unwrap_or(f64::NAN),
            gyro: self.apply(sample.gyro, self.gyro_scale),
            accel: self.apply(sample.accel, self.accel_scale),
            temp: sample.temp_c.unwrap_or(f64::NAN),
            status: sample.status,
        }
    }
}

/// The row for one GNSS epoch that arrived at `at`.
pub fn gnss_record(fix: &GnssFix, at: Arrival) -> GnssRecord {
    let nan = f64::NAN;
    GnssRecord {
        t_mono_ns: at.mono_ns,
        t_wall_ns: at.wall_ns,
        week: fix.week.unwrap_or(0),
        tow_s: fix.tow_s.unwrap_or(nan),
        utc_ns: fix.utc_ns.unwrap_or(i64::MIN),
        lat_deg: fix.lat_deg.unwrap_or(nan),
        lon_deg: fix.lon_deg.unwrap_or(nan),
        height_m: fix.height_m.unwrap_or(nan),
        vel_ned: fix.vel_ned.unwrap_or([nan; 3]),
        h_acc_m: fix.h_acc_m.unwrap_or(nan),
        v_acc_m: fix.v_acc_m.unwrap_or(nan),
        s_acc_mps: fix.s_acc_mps.unwrap_or(nan),
        fix_type: fix.fix,
        num_sats: fix.num_sats.unwrap_or(0),
        pdop: fix.pdop.unwrap_or(nan),
        hdop: fix.hdop.unwrap_or(nan),
        vdop: fix.vdop.unwrap_or(nan),
        heading_deg: fix.heading_deg.unwrap_or(nan),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_and_units_apply_to_gyro_and_accel() {
        // body x = -sensor y, body y = sensor x, body z = sensor z; gyro in deg/s, accel in g.
        let m = ImuMapping {
            body_from_sensor: Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0),
            gyro_scale: std::f64::consts::PI / 180.0,
            accel_scale: 9.80665,
        };
        let sample = ImuSample {
            sensor_time: Some(12.5),
            gyro: Some([180.0, 90.0, 0.0]),
            accel: Some([0.0, 0.0, 1.0]),
            temp_c: None,
            status: 7,
        };
        let at = Arrival {
            mono_ns: 5,
            wall_ns: 6,
        };
        let r = m.imu_record(&sample, at);
        let pi = std::f64::consts::PI;
        assert!((r.gyro[0] + pi / 2.0).abs() < 1e-12);
        assert!((r.gyro[1] - pi).abs() < 1e-12);
        assert_eq!(r.gyro[2], 0.0);
        assert_eq!(r.accel, [0.0, 0.0, 9.80665]);
        assert!(r.temp.is_nan());
        assert_eq!(
            (r.t_mono_ns, r.t_wall_ns, r.t_sensor, r.status),
            (5, 6, 12.5, 7)
        );
    }

    #[test]
    fn missing_fields_become_nan_and_sentinels() {
        let r = gnss_record(
            &GnssFix::default(),
            Arrival {
                mono_ns: 1,
                wall_ns: 2,
            },
        );
        assert_eq!(r.week, 0);
        assert_eq!(r.utc_ns, i64::MIN);
        assert!(r.lat_deg.is_nan() && r.vel_ned[2].is_nan() && r.tow_s.is_nan());
        let m = ImuMapping {
            body_from_sensor: Matrix3::identity(),
            gyro_scale: 1.0,
            accel_scale: 1.0,
        };
        let r = m.imu_record(
            &ImuSample::default(),
            Arrival {
                mono_ns: 1,
                wall_ns: 2,
            },
        );
        assert!(r.gyro.iter().chain(&r.accel).all(|v| v.is_nan()));
    }
}
