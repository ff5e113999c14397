//! Never panic on input: arbitrary KF-GINS configuration text, and arbitrary IMU samples and
//! GNSS fixes (NaN, infinities, absurd magnitudes, time going backwards) through the replay.

use imulab::fusion::config::FusionConfig;
use imulab::fusion::kfgins::KfGinsConfig;
use imulab::fusion::mechanisation::{ImuInput, NavState};
use imulab::fusion::navigator::{replay, GnssObservation, ReplayOptions};
use nalgebra::{UnitQuaternion, Vector3};
use proptest::prelude::*;
use std::path::Path;

fn wild() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => -20.0..20.0f64,
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(-1e300),
        1 => Just(1e12),
        1 => Just(0.0),
    ]
}

fn v3() -> impl Strategy<Value = Vector3<f64>> {
    (wild(), wild(), wild()).prop_map(|(a, b, c)| Vector3::new(a, b, c))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn kf_gins_config_text_never_panics(text in "(([a-z.]{0,8}|imunoise|initpos|antlever)(:| :)?( \\[?[0-9a-z ,.\\-]{0,12}\\]?)?(#.*)?\n( {2})?){0,12}") {
        let _ = KfGinsConfig::from_str(&text, "fuzz.yaml", Path::new("."));
    }

    #[test]
    fn replay_never_panics_and_never_outputs_nan(
        imu in prop::collection::vec((0.0..0.05f64, any::<bool>(), v3(), v3()), 1..150),
        fixes in prop::collection::vec((-0.5..2.0f64, wild(), wild(), wild(), v3()), 0..12),
        states in prop_oneof![Just(15usize), Just(21usize)],
        given in any::<bool>(),
    ) {
        let mut t = 0.0;
        let inputs: Vec<ImuInput> = imu.iter().map(|&(dt, inc, a, b)| {
            t += dt;
            if inc {
                ImuInput::Increments { t_s: t, dt_s: dt, dtheta: a * 1e-3, dvel: b * 1e-2 }
            } else {
                ImuInput::Rates { t_s: t, gyro: a, accel: b }
            }
        }).collect();
        let gnss: Vec<GnssObservation> = fixes.iter().map(|&(t, lat, lon, h, v)| GnssObservation {
            t_s: t,
            lat_rad: 0.8 + lat * 1e-6,
            lon_rad: 0.1 + lon * 1e-6,
            height_m: h,
            sigma_ned_m: Vector3::new(lat.abs(), 1.0, h),
            vel_ned: Some(v),
            sigma_vel_mps: v,
        }).collect();
        let mut config = FusionConfig { states, ..FusionConfig::default() };
        config.nhc.enabled = true;
        config.zupt.enabled = true;
        config.alignment.min_speed_mps = 0.5;
        let initial = given.then_some(NavState {
            t_s: 0.0, lat_rad: 0.8, lon_rad: 0.1, height_m: 100.0,
            vel_ned: Vector3::new(1.0, 0.0, 0.0), quat_nb: UnitQuaternion::identity(),
        });
        let r = replay(&config, inputs, gnss, ReplayOptions { initial, smooth: true, ..Default::default() });
        for s in r.filtered.iter().chain(&r.smoothed) {
            prop_assert!(s.nav.lat_rad.is_finite() && s.nav.lon_rad.is_finite() && s.nav.height_m.is_finite());
            prop_assert!(s.nav.vel_ned.iter().all(|v| v.is_finite()));
            prop_assert!(s.cov_nav.iter().all(|v| v.is_finite()));
        }
    }
}
