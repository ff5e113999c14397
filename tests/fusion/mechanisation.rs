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
