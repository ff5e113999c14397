//! Mechanisation alone against the truth generator: a stationary noise-free IMU stays put,
//! a drive with turns and a climb returns to the truth, and increments agree with rates.

use imulab::fusion::mechanisation::{
    ImuInput, IntegrationOrder, MechanisationOptions, Mechaniser, NavState,
};
use imulab::sim::motion::{static_truth, MotionGenerator, MotionSpec, Segment, TruthSample};
use nalgebra::{UnitQuaternion, Vector3};

fn errors(nav: &NavState, t: &TruthSample) -> (f64, f64, f64) {
    let dp = nav.ned_offset_from(t.lat_rad, t.lon_rad, t.height_m).norm();
    let dv = (nav.vel_ned - t.vel_ned).norm();
    let da = (nav.quat_nb.inverse() * t.quat_nb).angle();
    (dp, dv, da)
}

#[test]
fn stationary_noise_free_imu_stays_put_for_ten_minutes() {
    for &(lat_deg, order) in &[
        (45.0, IntegrationOrder::Second),
        (-33.0, IntegrationOrder::First),
    ] {
        let q = UnitQuaternion::from_euler_angles(0.02, -0.03, 1.1);
        let truth = static_truth(f64::to_radians(lat_deg), 0.3, 120.0, q);
        let mut nav = imulab::study::nav_state(&truth);
        let mut mech = Mechaniser::new(MechanisationOptions {
            order,
            coning_sculling: true,
        });
        let rate = 100.0;
        for k in 0..=(600.0 * rate) as usize {
            let input = ImuInput::Rates {
                t_s: k as f64 / rate,
                gyro: truth.gyro_b,
                accel: truth.accel_b,
            };
            mech.step(&mut nav, &input);
        }
        let (dp, dv, da) = errors(&nav, &truth);
        assert!(dp < 1e-3, "lat {lat_deg}: drift {dp} m");
        assert!(dv < 1e-5 && da < 1e-9, "dv {dv} da {da}");
    }
}

fn drive() -> MotionSpec {
    MotionSpec {
        vehicle: Default::default(),
        lat_deg: 52.0,
        lon_deg: 4.0,
        height_m: 30.0,
        heading_deg: 10.0,
        speed_mps: 0.0,
        segments: vec![
            Segment::Accelerate {
                dv_mps: 15.0,
                duration_s: 8.0,
            },
            Segment::Turn {
                angle_deg: 360.0,
                duration_s: 40.0,
            },
            Segment::Climb {
                dh_m: 6.0,
                duration_s: 10.0,
            },
            Segment::Turn {
                angle_deg: -90.0,
                duration_s: 6.0,
            },
            Segment::Cruise { duration_s: 5.0 },
            Segment::Stop { duration_s: 6.0 },
        ],
    }
}

#[test]
fn constant_rate_turns_return_to_truth_with_rates_and_increments() {
    let rate = 200.0;
    // Truth at twice the IMU rate: even samples give rates, pairs of halves give Simpson
    // increments of the same signal.
    let truth: Vec<TruthSample> = MotionGenerator::new(&drive(), 2.0 * rate)
        .expect("plan")
        .collect();
    let mut by_rates = imulab::study::nav_state(&truth[0]);
    let mut by_incs = by_rates;
    let mut mech_r = Mechaniser::new(MechanisationOptions::default());
    let mut mech_i = Mechaniser::new(MechanisationOptions::default());
    mech_r.step(
        &mut by_rates,
        &ImuInput::Rates {
            t_s: 0.0,
            gyro: truth[0].gyro_b,
            accel: truth[0].accel_b,
        },
    );
    let mut worst = (0.0f64, 0.0f64, 0.0f64);
    for k in (2..truth.len()).step_by(2) {
        let (a, m, b) = (&truth[k - 2], &truth[k - 1], &truth[k]);
        let dt = b.t_s - a.t_s;
        let simpson =
            |x: Vector3<f64>, y: Vector3<f64>, z: Vector3<f64>| (x + 4.0 * y + z) * dt / 6.0;
        mech_r.step(
            &mut by_rates,
            &ImuInput::Rates {
                t_s: b.t_s,
                gyro: b.gyro_b,
                accel: b.accel_b,
            },
        );
        mech_i.step(
            &mut by_incs,
            &ImuInput::Increments {
                t_s: b.t_s,
                dt_s: dt,
                dtheta: simpson(a.gyro_b, m.gyro_b, b.gyro_b),
                dvel: simpson(a.accel_b, m.accel_b, b.accel_b),
            },
        );
        let e = errors(&by_rates, b);
        worst = (worst.0.max(e.0), worst.1.max(e.1), worst.2.max(e.2));
        let d = by_rates
            .ned_offset_from(by_incs.lat_rad, by_incs.lon_rad, by_incs.height_m)
            .norm();
        assert!(d < 0.01, "t {}: rates vs increments differ by {d} m", b.t_s);
    }
    let last = truth.last().expect("truth");
    let (dp, dv, da) = errors(&by_incs, last);
    println!(
        "worst rates: pos {} m vel {} m/s att {} rad; increments end: {dp} {dv} {da}",
        worst.0, worst.1, worst.2
    );
    assert!(
        worst.0 < 0.01 && worst.1 < 1e-3 && worst.2 < 1e-6,
        "{worst:?}"
    );
    assert!(dp < 0.01 && dv < 1e-3 && da < 1e-6);
}

#[test]
fn a_car_with_side_slip_and_heave_integrates_to_its_truth_and_breaks_nhc_by_its_own_amounts() {
    use imulab::sim::motion::VehicleDynamics;
    let rate = 200.0;
    let vehicle = VehicleDynamics {
        slip_deg_per_mps2: 0.25,
        heave_mps: 0.03,
    };
    let truth: Vec<TruthSample> = MotionGenerator::new(&MotionSpec { vehicle, ..drive() }, rate)
        .expect("plan")
        .collect();
    let mut nav = imulab::study::nav_state(&truth[0]);
    let mut mech = Mechaniser::new(MechanisationOptions::default());
    let (mut worst, mut lateral_max, mut slip_max) = ((0.0f64, 0.0f64, 0.0f64), 0.0f64, 0.0f64);
    let (mut vertical_sq, mut moving) = (0.0, 0usize);
    for s in &truth {
        mech.step(
            &mut nav,
            &ImuInput::Rates {
                t_s: s.t_s,
                gyro: s.gyro_b,
                accel: s.accel_b,
            },
        );
        let e = errors(&nav, s);
        worst = (worst.0.max(e.0), worst.1.max(e.1), worst.2.max(e.2));
        let v_body = s.quat_nb.inverse() * s.vel_ned;
        let speed = s.vel_ned.xy().norm();
        lateral_max = lateral_max.max(v_body.y.abs());
        if speed > 14.9 {
            vertical_sq += v_body.z * v_body.z;
            moving += 1;
        }
        slip_max = slip_max.max((v_body.y / v_body.x.max(1e-9)).abs().atan());
    }
    let vertical_rms = (vertical_sq / moving as f64).sqrt();
    println!(
        "worst: pos {} m vel {} m/s att {} rad; lateral body velocity max {lateral_max:.3} m/s, slip max {:.3}°, vertical RMS at 15 m/s {vertical_rms:.4} m/s",
        worst.0, worst.1, worst.2, slip_max.to_degrees()
    );
    assert!(
        worst.0 < 0.01 && worst.1 < 1e-3 && worst.2 < 1e-6,
        "{worst:?}"
    );
    // The sharpest turn, 90° in 6 s at 15 m/s, peaks at a heading rate of 2·(π/2)/6 rad/s: a
    // lateral acceleration of 7.85 m/s², so 0.25°/(m/s²) slips 1.96° and moves 0.51 m/s
    // sideways.
    let a_lat = 15.0 * std::f64::consts::PI / 6.0;
    let slip = (0.25 * a_lat).to_radians();
    assert!(
        (slip_max - slip).abs() < 0.02 * slip,
        "{slip_max} vs {slip}"
    );
    assert!((lateral_max - 15.0 * slip.sin()).abs() < 0.02 * 15.0 * slip.sin());
    // Heave at 15 m/s: 0.03 m/s × 15 / (15 + 5).
    let expected = 0.03 * 15.0 / 20.0;
    assert!(
        (vertical_rms - expected).abs() < 0.25 * expected,
        "{vertical_rms} vs {expected}"
    );
}
