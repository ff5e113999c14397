//! VectorNav and MicroStrain MIP end to end: the simulator serves a VN-100-like IMU
//! (VectorNav binary output) and a 3DM-GX5-like IMU (MIP IMU data set) over ptys at 200 Hz,
//! accelerated, with garbage written into both streams mid-way; the daemon, built from its
//! configuration as `imulogd` builds it, logs them into an HDF5 session. Every frame sent is
//! a row, once, in order, equal to what the drivers' decoders make of the sent bytes; the
//! garbage costs no frame and is a resync event.

use std::path::Path;

use crate::common::imu_rows;
use crate::end_to_end::serve_scene_and_log;
use imulab::daemon::clock::Arrival;
use imulab::daemon::mapping::ImuMapping;
use imulab::sim::scene::Scene;
use imulab::sim::serve::{Fault, FaultKind, Sent};
use imulab::store::{EventKind, ImuRecord, Session};

const SCENE_S: f64 = 8.0;
const SPEED: f64 = 8.0;
const IMU_HZ: f64 = 200.0;

fn scene() -> Scene {
    let text = format!(
        "duration_s = {SCENE_S}\nrate_hz = {IMU_HZ}\nseed = 11\n\
         [location]\nlat_deg = 48.1\nlon_deg = 11.6\nheight_m = 520.0\n\
         [motion]\nkind = \"static\"\n\
         [[imu]]\nname = \"vn\"\npreset = \"industrial\"\nprotocol = \"vectornav\"\n\
         [[imu]]\nname = \"gx5\"\npreset = \"industrial\"\nprotocol = \"mip\"\n"
    );
    Scene::parse(&text, Path::new(".")).unwrap_or_else(|e| panic!("{e:#}"))
}

fn without_times(mut r: ImuRecord) -> ImuRecord {
    r.t_mono_ns = 0;
    r.t_wall_ns = 0;
    r
}

/// The session `serve_scene_and_log` wrote, checked free of problems.
fn opened(session_dir: &Path) -> Session {
    let session = Session::open(session_dir).expect("the session opens");
    assert!(session.problems().is_empty(), "{:?}", session.problems());
    session
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn vectornav_and_mip_over_ptys_are_logged_completely_and_garbage_costs_only_itself() {
    let faults = ["vn", "gx5"]
        .map(|sensor| Fault {
            sensor: sensor.into(),
            at_s: 4.0,
            kind: FaultKind::Garbage,
            bytes: 300,
            down_s: 0.0,
        })
        .to_vec();
    let (_dir, report, session_dir) = serve_scene_and_log(scene(), SPEED, faults, "", "").await;
    let session = opened(&session_dir);
    let (events, _) = session.events();
    let identity = ImuMapping {
        body_from_sensor: nalgebra::Matrix3::identity(),
        gyro_scale: 1.0,
        accel_scale: 1.0,
    };
    let no_time = Arrival {
        mono_ns: 0,
        wall_ns: 0,
    };
    for stream in &report.streams {
        let Sent::Imu(sent) = &stream.sent else {
            panic!("only IMUs here")
        };
        assert_eq!(stream.encode_errors, 0, "{:?}", stream.first_encode_error);
        assert_eq!(stream.garbage_bytes, 300);
        assert_eq!(sent.len() as f64, SCENE_S * IMU_HZ, "{}", stream.sensor);
        let rows = imu_rows(&session, &stream.sensor);
        assert_eq!(
            rows.len(),
            sent.len(),
            "{}: one row per frame",
            stream.sensor
        );
        for (k, (row, frame)) in rows.iter().zip(sent).enumerate() {
            let sample = frame.sample.as_ref().expect("decodable");
            let want = without_times(identity.imu_record(sample, no_time));
            assert_eq!(
                format!("{:?}", without_times(*row)),
                format!("{want:?}"),
                "{} frame {k}",
                stream.sensor
            );
            // Device time is k / rate (TimeStartup, MIP reference timestamp).
            assert!(
                (row.t_sensor - k as f64 / IMU_HZ).abs() < 1e-9,
                "{} frame {k}: t_sensor {}",
                stream.sensor,
                row.t_sensor
            );
            for axis in 0..3 {
                assert!((row.gyro[axis] - frame.record.gyro[axis]).abs() < 1e-6);
                assert!((row.accel[axis] - frame.record.accel[axis]).abs() < 1e-5);
            }
        }
        let resyncs = events
            .iter()
            .filter(|e| e.device == stream.sensor && e.kind == EventKind::Resync)
            .count();
        assert!(resyncs >= 1, "{}: {events:?}", stream.sensor);
        println!(
            "{}: {} rows of {} frames, {} resync event(s)",
            stream.sensor,
            rows.len(),
            sent.len(),
            resyncs
        );
    }
}

/// The simulator serving delta theta / delta velocity: a VN-100-like IMU sending
/// DeltaThetaVel only and a 3DM-GX5-like IMU sending scaled rates and deltas, logged by
/// the daemon with `rows_from = "deltas"`. Every frame is a row (the MIP's first from its
/// rates: no interval before it), equal to the simulated rates within the f32 wire.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn vectornav_and_mip_deltas_from_the_simulator_give_the_simulated_rates() {
    const SECONDS: f64 = 3.0;
    let text = format!(
        "duration_s = {SECONDS}\nrate_hz = {IMU_HZ}\nseed = 12\n\
         [location]\nlat_deg = 48.1\nlon_deg = 11.6\nheight_m = 520.0\n\
         [motion]\nkind = \"static\"\n\
         [[imu]]\nname = \"vn\"\npreset = \"industrial\"\nprotocol = \"vectornav\"\noutput = \"deltas\"\n\
         [[imu]]\nname = \"gx5\"\npreset = \"industrial\"\nprotocol = \"mip\"\noutput = \"both\"\n"
    );
    let scene = Scene::parse(&text, Path::new(".")).unwrap_or_else(|e| panic!("{e:#}"));
    let (_dir, report, session_dir) =
        serve_scene_and_log(scene, SPEED, Vec::new(), "rows_from = \"deltas\"\n", "").await;
    let session = opened(&session_dir);
    // f32 deltas (and VectorNav's f32 interval) divided back: a few units of 2^-24 relative.
    let within = |got: f64, want: f64| (got - want).abs() <= 4e-7 * want.abs() + 1e-12;
    for stream in &report.streams {
        let Sent::Imu(sent) = &stream.sent else {
            panic!("only IMUs here")
        };
        assert_eq!(stream.encode_errors, 0, "{:?}", stream.first_encode_error);
        assert_eq!(sent.len() as f64, SECONDS * IMU_HZ, "{}", stream.sensor);
        let rows = imu_rows(&session, &stream.sensor);
        assert_eq!(
            rows.len(),
            sent.len(),
            "{}: one row per frame",
            stream.sensor
        );
        let mut as_sent_rates = 0;
        for (k, (row, frame)) in rows.iter().zip(sent).enumerate() {
            assert!(
                (row.t_sensor - k as f64 / IMU_HZ).abs() < 1e-9,
                "{} frame {k}: t_sensor {}",
                stream.sensor,
                row.t_sensor
            );
            for axis in 0..3 {
                let (gyro, accel) = (frame.record.gyro[axis], frame.record.accel[axis]);
                assert!(
                    within(row.gyro[axis], gyro) && within(row.accel[axis], accel),
                    "{} frame {k} axis {axis}: {:?} {:?} vs {:?} {:?}",
                    stream.sensor,
                    row.gyro,
                    row.accel,
                    frame.record.gyro,
                    frame.record.accel
                );
            }
            let f32_rates = |v: [f64; 3]| v.map(|x| f64::from(x as f32));
            if row.gyro == f32_rates(frame.record.gyro)
                && row.accel == f32_rates(frame.record.accel)
            {
                as_sent_rates += 1;
            }
        }
        // The rows are the deltas', not the rates' (which the MIP sends too).
        assert!(
            as_sent_rates <= 1,
            "{}: {as_sent_rates} rows equal the f32 rates",
            stream.sensor
        );
    }
}
