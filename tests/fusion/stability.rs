//! Long-run stability: a 24 h static replay keeps the covariance symmetric and positive
//! definite; hours without GNSS never produce a NaN; bad inputs are rejected and counted.

use crate::support::{simulate, ImuErrors};
use imulab::fusion::config::FusionConfig;
use imulab::fusion::mechanisation::ImuInput;
use imulab::fusion::navigator::{replay, GnssObservation, Navigator, ReplayOptions, ReplayResult};
use imulab::sim::motion::{MotionSpec, Segment};
use nalgebra::{Cholesky, Vector3};

fn static_spec(hours: f64) -> MotionSpec {
    MotionSpec {
        vehicle: Default::default(),
        lat_deg: -27.5,
        lon_deg: 153.0,
        height_m: 40.0,
        heading_deg: 200.0,
        speed_mps: 0.0,
        segments: vec![Segment::Cruise {
            duration_s: hours * 3600.0,
        }],
    }
}

fn errors() -> ImuErrors {
    let c = FusionConfig::default().imu;
    ImuErrors {
        arw: c.arw_rad_per_sqrt_s.max(),
        vrw: c.vrw_mps_per_sqrt_s.max(),
        gyro_bias: Vector3::new(2e-5, -4e-5, 3e-5),
        accel_bias: Vector3::new(0.02, -0.03, 0.04),
        gyro_scale: Vector3::zeros(),
        accel_scale: Vector3::zeros(),
    }
}

fn coarse_config() -> FusionConfig {
    FusionConfig {
        covariance_interval_s: 1.0,
        output_interval_s: 600.0,
        ..FusionConfig::default()
    }
}

fn assert_all_finite(r: &ReplayResult) {
    for s in &r.filtered {
        let n = &s.nav;
        assert!(n.lat_rad.is_finite() && n.lon_rad.is_finite() && n.height_m.is_finite());
        assert!(
            n.vel_ned
                .iter()
                .chain(s.cov_nav.iter())
                .all(|v| v.is_finite()),
            "t {}",
            n.t_s
        );
        assert!(n.quat_nb.coords.iter().all(|v| v.is_finite()));
    }
}

#[test]
fn day_long_static_replay_keeps_covariance_symmetric_positive_definite() {
    // 24 h at 5 Hz IMU, GNSS every 60 s, ZUPT on: coarse so the test stays quick.
    let d = simulate(
        &static_spec(24.0),
        5.0,
        300,
        &errors(),
        (1.0, 2.0, 0.05),
        Vector3::zeros(),
        7,
    );
    let mut c = coarse_config();
    c.zupt.enabled = true;
    c.zupt.window_s = 10.0;
    c.zupt.gyro_threshold_rad_s = 0.05;
    c.zupt.accel_threshold_mps2 = 0.5;
    let mut nav = Navigator::<15>::new(
        &c,
        ReplayOptions {
            initial: Some(imulab::study::nav_state(&d.truth[0])),
            ..Default::default()
        },
    );
    let mut fixes = d.gnss.iter().peekable();
    let mut checked = 0;
    for (k, imu) in d.imu.iter().enumerate() {
        while let Some(f) = fixes.next_if(|f| f.t_s < imu.t_s()) {
            nav.push_gnss(f);
        }
        nav.push_imu(imu);
        if k % 18_000 == 0 {
            let p = nav.ins().expect("running").p;
            assert!((p - p.transpose()).amax() == 0.0, "asymmetric at {k}");
            assert!(Cholesky::new(p).is_some(), "not PD at {k}");
            checked += 1;
        }
    }
    let p = nav.ins().expect("running").p;
    let r = nav.finish();
    assert!(checked >= 24);
    assert!(Cholesky::new(p).is_some() && (p - p.transpose()).amax() == 0.0);
    assert_eq!(r.stats.filter.pd_events, 0);
    assert_eq!(r.stats.filter.propagation_repairs, 0);
    assert!(r.stats.zupt_updates > 1000, "{:?}", r.stats);
    assert_all_finite(&r);
    let last = r.filtered.last().expect("output");
    let err = last
        .nav
        .ned_offset_from(d.truth[0].lat_rad, d.truth[0].lon_rad, d.truth[0].height_m);
    println!("24 h static: final error {err:?}, stats {:?}", r.stats);
    assert!(err.norm() < 3.0, "{err:?}");
}

#[test]
fn hours_without_gnss_never_give_nan() {
    // 4 h at 5 Hz IMU; GNSS for the first 2 minutes only.
    let d = simulate(
        &static_spec(4.0),
        5.0,
        5,
        &errors(),
        (1.0, 2.0, 0.05),
        Vector3::zeros(),
        8,
    );
    let gnss: Vec<_> = d.gnss.iter().filter(|f| f.t_s < 120.0).copied().collect();
    let c = coarse_config();
    let r = replay(
        &c,
        d.imu.iter().copied(),
        gnss,
        ReplayOptions {
            initial: Some(imulab::study::nav_state(&d.truth[0])),
            ..Default::default()
        },
    );
    println!("{:?}", r.stats);
    assert_all_finite(&r);
    assert!(r.filtered.len() >= 24);
    // The unaided vertical channel diverges; the filter must say so with its covariance.
    let last = r.filtered.last().expect("output");
    assert!(last.cov_nav[(2, 2)].sqrt() > 100.0);
    // Against the truth, the hours without GNSS are reported as unbounded, not averaged.
    let e = imulab::fusion::metrics::errors(&r.filtered, |t| d.truth_at(t));
    let s = imulab::fusion::metrics::summarise(&e, &[(120.0, 4.0 * 3600.0)]);
    println!("{s:?}");
    let from = s.unbounded_from_s.expect("position becomes unbounded");
    assert!(from > 120.0 && from < 4.0 * 3600.0, "{from}");
    assert!(s.unbounded_epochs > 0 && s.outages[0].unbounded);
    assert!(s.horizontal.max.is_finite());
}

#[test]
fn bad_inputs_are_rejected_and_counted() {
    let d = simulate(
        &static_spec(0.05),
        50.0,
        10,
        &errors(),
        (1.0, 2.0, 0.05),
        Vector3::zeros(),
        9,
    );
    let mut imu = d.imu.clone();
    imu.insert(
        100,
        ImuInput::Rates {
            t_s: f64::NAN,
            gyro: Vector3::zeros(),
            accel: Vector3::zeros(),
        },
    );
    if let ImuInput::Increments {
        t_s, dt_s, dvel, ..
    } = imu[200]
    {
        imu[200] = ImuInput::Increments {
            t_s,
            dt_s,
            dtheta: Vector3::new(f64::NAN, 0.0, 0.0),
            dvel,
        };
    }
    let back = imu[300];
    imu.insert(301, back); // time going backwards: same time again
    let mut gnss: Vec<GnssObservation> = Vec::new();
    for (i, f) in d.gnss.iter().enumerate() {
        gnss.push(*f);
        if i == 5 {
            gnss.push(*f); // duplicate
        }
        if i == 8 {
            gnss.push(GnssObservation {
                t_s: f.t_s - 0.5,
                ..*f
            }); // out of order
        }
        if i == 11 {
            gnss.push(GnssObservation {
                t_s: f.t_s + 0.01,
                lat_rad: f64::NAN,
                ..*f
            });
        }
    }
    let r = replay(
        &coarse_config(),
        imu,
        gnss,
        ReplayOptions {
            initial: Some(imulab::study::nav_state(&d.truth[0])),
            ..Default::default()
        },
    );
    let s = r.stats;
    assert_eq!(s.imu_rejected_non_finite, 2);
    assert_eq!(s.imu_rejected_time, 1);
    assert_eq!(s.gnss_rejected_duplicate, 1);
    assert_eq!(s.gnss_rejected_out_of_order, 1);
    assert_eq!(s.gnss_rejected_invalid, 1);
    assert_eq!(s.gnss_used as usize, d.gnss.len());
    assert_all_finite(&r);
}
