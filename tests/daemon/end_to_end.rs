//! The acceptance test of the daemon (issue 7): the simulator serves a bench over ptys (two
//! IMUs at 150 Hz, WitMotion and Xsens Xbus, and a u-blox-like receiver sending UBX and NMEA
//! mixed at 10 Hz), accelerated; the daemon, built from its configuration exactly as
//! `imulogd` builds it (drivers' serial transport and codecs), logs them into an HDF5
//! session; the test reads the session back with the store reader. Every frame the
//! simulator sent is there exactly once, in order, with the values the drivers' decoders
//! make of the sent bytes (so equal to what was encoded, to the encoding's resolution),
//! arrival times are monotonic, and the rates are right.

use std::path::Path;
use std::time::{Duration, Instant};

use crate::common::daemon::{connected_report, parts_for};
use crate::common::{gnss_rows, imu_rows};
use imulab::daemon::config::parse;
use imulab::daemon::mapping::{gnss_record, ImuMapping};
use imulab::daemon::run;
use imulab::daemon::session::open_session_sink;
use imulab::sim::scene::Scene;
use imulab::sim::serve::{
    Fault, FaultKind, Sent, ServeOptions, ServeReport, Server, Speed, StartWhen,
};
use imulab::store::{EventKind, GnssRecord, ImuRecord, Session};

/// Scene seconds served; at [`SPEED`] this is a little over 2 s of wall time.
const SCENE_S: f64 = 16.0;
const SPEED: f64 = 8.0;
const IMU_HZ: f64 = 150.0;
const GNSS_HZ: f64 = 10.0;

fn bench_scene() -> Scene {
    let text = format!(
        "duration_s = {SCENE_S}\nrate_hz = {IMU_HZ}\nseed = 7\n\
         [location]\nlat_deg = 48.1\nlon_deg = 11.6\nheight_m = 520.0\n\
         [motion]\nkind = \"static\"\n\
         [[imu]]\nname = \"wit\"\npreset = \"bench-cheap\"\nprotocol = \"wit\"\n\
         [[imu]]\nname = \"mti\"\npreset = \"industrial\"\nprotocol = \"xbus\"\n\
         [[gnss]]\nname = \"rx\"\npreset = \"standalone\"\nrate_hz = {GNSS_HZ}\nprotocol = \"gnss\"\n"
    );
    Scene::parse(&text, Path::new(".")).unwrap_or_else(|e| panic!("{e:#}"))
}

/// Row equality with the arrival times left out; NaN equals NaN (the debug form compares
/// every value exactly, bit for bit up to the sign of zero).
pub(crate) fn same<T: std::fmt::Debug>(a: &T, b: &T) -> bool {
    format!("{a:?}") == format!("{b:?}")
}

pub(crate) fn without_times_imu(mut r: ImuRecord) -> ImuRecord {
    r.t_mono_ns = 0;
    r.t_wall_ns = 0;
    r
}

pub(crate) fn without_times_gnss(mut r: GnssRecord) -> GnssRecord {
    r.t_mono_ns = 0;
    r.t_wall_ns = 0;
    r
}

/// Rows per second of arrival time over the stream, without its last row: a sample or
/// epoch whose closing packet is not known (WitMotion before its cycle is learned) is
/// complete only when the next one starts, so the last one may be written when the input
/// ends (here: when the daemon stops).
fn arrival_rate(t_mono_ns: &[i64]) -> f64 {
    let n = t_mono_ns.len() - 1;
    let span = (t_mono_ns[n - 1] - t_mono_ns[0]) as f64 * 1e-9;
    (n - 1) as f64 / span
}

/// Serves the bench scene (with `faults`) to a daemon built from its configuration, logging
/// into an HDF5 session (with the raw journal when `raw_journal`); returns what the simulator
/// sent and where the session is.
pub(crate) async fn serve_and_log(
    faults: Vec<Fault>,
    raw_journal: bool,
) -> (tempfile::TempDir, ServeReport, std::path::PathBuf) {
    serve_scene_and_log(
        bench_scene(),
        SPEED,
        faults,
        "retry_initial_ms = 20\nretry_max_ms = 100\n",
        &format!("raw_journal = {raw_journal}\n"),
    )
    .await
}

/// Serves `scene` over ptys at `speed` × real time (with `faults`) to a daemon built from its
/// configuration as `imulogd` builds it, one device per endpoint (`device_keys` added to each,
/// `session_keys` to `[session]`), into an HDF5 session; returns what the simulator sent and
/// where the session is.
pub(crate) async fn serve_scene_and_log(
    scene: Scene,
    speed: f64,
    faults: Vec<Fault>,
    device_keys: &str,
    session_keys: &str,
) -> (tempfile::TempDir, ServeReport, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    // Accelerated, the devices really do send `speed` times faster; the configured rate
    // sizes the store's chunks (one flush interval each) and the gap detector.
    let rate_of = |sensor: &str| {
        speed
            * scene
                .gnss
                .iter()
                .find(|g| g.name == sensor)
                .map_or(scene.rate_hz, |g| g.spec.rate_hz)
    };
    let mut devices = String::new();
    let mut server = Server::start(
        scene.clone(),
        ServeOptions {
            speed: Speed::Factor(speed),
            link_dir: Some(dir.path().join("dev")),
            start: StartWhen::OnDemand,
            record_sent: true,
            faults,
        },
    )
    .unwrap_or_else(|e| panic!("{e:#}"));
    for e in server.endpoints() {
        devices.push_str(&format!(
            "[[device]]\nname = \"{}\"\nprotocol = \"{}\"\nrate_hz = {}\n{device_keys}serial = {{ port = \"{}\", baud = 921600 }}\n",
            e.sensor,
            e.protocol.name(),
            rate_of(&e.sensor),
            e.path().display()
        ));
    }
    let text = format!(
        "[session]\noutput_dir = \"{}\"\nname = \"logged\"\nflush_interval_ms = 100\n{session_keys}\n{devices}",
        dir.path().display()
    );
    let config = parse(&text, "end-to-end").unwrap_or_else(|e| panic!("{e}"));
    let session_dir = dir.path().join("logged");
    let status_path = config.status_path();
    let sink = Box::new(open_session_sink(&config, &session_dir).unwrap());
    let parts = parts_for(&config, sink, session_dir.clone());
    let (stop, stop_rx) = tokio::sync::watch::channel(false);
    let daemon = tokio::spawn(async move { run(&config, parts, stop_rx).await });

    // Start the scene once the daemon has every device open (the status file says so).
    let endpoints = server.endpoints().len();
    let t = Instant::now();
    while connected_report(&status_path, endpoints).is_none() {
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "the daemon did not open the ptys"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    server.begin();
    let served_at = Instant::now();
    while !server.is_finished() {
        assert!(
            served_at.elapsed() < Duration::from_secs(60),
            "serve did not finish"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let report = server.finish().unwrap_or_else(|e| panic!("{e:#}"));
    let wall_s = served_at.elapsed().as_secs_f64();
    // Let the daemon read the last bytes, then stop it before the ptys close.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let _ = stop.send(true);
    let outcome = daemon.await.unwrap();
    drop(server);
    assert_eq!(outcome.exit_code(), 0, "{outcome:?}");
    println!(
        "served {} s of scene in {wall_s:.2} s (×{speed}); undelivered bytes {}",
        scene.duration_s, report.undelivered_bytes
    );
    assert_eq!(report.undelivered_bytes, 0);
    (dir, report, session_dir)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn simulated_bench_is_logged_completely_exactly_once_with_its_values() {
    let (_dir, report, session_dir) = serve_and_log(Vec::new(), false).await;
    let session = Session::open(&session_dir).expect("the session opens");
    assert!(session.problems().is_empty(), "{:?}", session.problems());
    assert!(
        session.files().iter().all(|f| !f.partial),
        "{:?}",
        session.files()
    );
    let (events, problems) = session.events();
    assert!(problems.is_empty(), "{problems:?}");
    for name in ["wit", "mti", "rx"] {
        let bad: Vec<_> = events
            .iter()
            .filter(|e| e.device == name)
            .filter(|e| {
                matches!(
                    e.kind,
                    EventKind::Resync
                        | EventKind::ChecksumError
                        | EventKind::Disconnect
                        | EventKind::QueueOverflow
                )
            })
            .collect();
        assert!(bad.is_empty(), "{name}: {bad:?}");
    }

    let identity = ImuMapping {
        body_from_sensor: nalgebra::Matrix3::identity(),
        gyro_scale: 1.0,
        accel_scale: 1.0,
    };
    let no_time = imulab::daemon::clock::Arrival {
        mono_ns: 0,
        wall_ns: 0,
    };
    for stream in &report.streams {
        assert_eq!(
            stream.encode_errors, 0,
            "{}: {:?}",
            stream.sensor, stream.first_encode_error
        );
        assert_eq!(stream.frames_overflowed, 0, "{}", stream.sensor);
        match &stream.sent {
            Sent::Imu(sent) => {
                let rows = imu_rows(&session, &stream.sensor);
                assert_eq!(
                    rows.len(),
                    sent.len(),
                    "{}: {} rows for {} frames sent",
                    stream.sensor,
                    rows.len(),
                    sent.len()
                );
                assert_eq!(sent.len() as f64, SCENE_S * IMU_HZ, "{}", stream.sensor);
                for (k, (row, frame)) in rows.iter().zip(sent).enumerate() {
                    let sample = frame.sample.as_ref().unwrap_or_else(|| {
                        panic!("{} frame {k}: the drivers do not decode it", stream.sensor)
                    });
                    let want = without_times_imu(identity.imu_record(sample, no_time));
                    assert!(
                        same(&without_times_imu(*row), &want),
                        "{} frame {k}: logged {row:?}, sent {want:?}",
                        stream.sensor
                    );
                    // And what was encoded is the simulated record, to the wire's resolution
                    // (a loose bound here: the simulator's tests check it per protocol).
                    for axis in 0..3 {
                        assert!(
                            (row.gyro[axis] - frame.record.gyro[axis]).abs() < 2e-3,
                            "{} frame {k} gyro: {row:?} vs {:?}",
                            stream.sensor,
                            frame.record
                        );
                        assert!(
                            (row.accel[axis] - frame.record.accel[axis]).abs() < 3e-3,
                            "{} frame {k} accel: {row:?} vs {:?}",
                            stream.sensor,
                            frame.record
                        );
                    }
                }
                let t: Vec<i64> = rows.iter().map(|r| r.t_mono_ns).collect();
                assert!(
                    t.windows(2).all(|w| w[0] <= w[1]),
                    "{}: arrival times",
                    stream.sensor
                );
                let rate = arrival_rate(&t);
                // The sensor's own clock runs at scene time: the nominal rate.
                let sensor_span = rows[rows.len() - 1].t_sensor - rows[0].t_sensor;
                let sensor_rate = (rows.len() - 1) as f64 / sensor_span;
                println!(
                    "{}: {} rows, arrival rate {rate:.0} /s (nominal {}), sensor-time rate {sensor_rate:.2} Hz",
                    stream.sensor,
                    rows.len(),
                    IMU_HZ * SPEED
                );
                assert!(
                    (sensor_rate / IMU_HZ - 1.0).abs() < 0.01,
                    "{}: sensor time says {sensor_rate} Hz",
                    stream.sensor
                );
                assert!(
                    (rate / (IMU_HZ * SPEED) - 1.0).abs() < 0.25,
                    "{}: rows arrived at {rate:.0}/s, expected {} (×{SPEED})",
                    stream.sensor,
                    IMU_HZ * SPEED
                );
            }
            Sent::Gnss(sent) => {
                let rows = gnss_rows(&session, &stream.sensor);
                // The mixed receiver's epochs (UBX and NMEA merged), in the order they were sent.
                let fixes: Vec<GnssRecord> = sent
                    .iter()
                    .flat_map(|s| s.fixes.iter())
                    .map(|f| without_times_gnss(gnss_record(&f.fix, no_time)))
                    .collect();
                assert_eq!(sent.len() as f64, SCENE_S * GNSS_HZ, "{}", stream.sensor);
                assert_eq!(
                    fixes.len(),
                    sent.len(),
                    "one merged fix per epoch (UBX and NMEA)"
                );
                assert_eq!(
                    rows.len(),
                    fixes.len(),
                    "{}: rows vs epochs sent",
                    stream.sensor
                );
                for (k, (row, want)) in rows.iter().zip(&fixes).enumerate() {
                    assert!(
                        same(&without_times_gnss(*row), want),
                        "{} epoch {k}: logged {row:?}, sent {want:?}",
                        stream.sensor
                    );
                }
                let t: Vec<i64> = rows.iter().map(|r| r.t_mono_ns).collect();
                assert!(
                    t.windows(2).all(|w| w[0] <= w[1]),
                    "{}: arrival times",
                    stream.sensor
                );
                assert!(
                    rows.iter().all(|r| r.tow_s.is_finite()),
                    "{}: every merged row carries the UBX time of week",
                    stream.sensor
                );
                let rate = arrival_rate(&t);
                println!(
                    "{}: {} rows, epoch rate {rate:.1} /s (nominal {})",
                    stream.sensor,
                    rows.len(),
                    GNSS_HZ * SPEED
                );
                assert!(
                    (rate / (GNSS_HZ * SPEED) - 1.0).abs() < 0.25,
                    "{}: epochs arrived at {rate:.1}/s, expected {}",
                    stream.sensor,
                    GNSS_HZ * SPEED
                );
            }
        }
    }
}

/// Faults from the simulator: garbage in the WitMotion stream costs no frame (a resync
/// event), and the Xbus pty closed for 0.4 s of scene time and reopened under the same link
/// gives disconnect, gap and reconnect events, with every frame sent to the new pty logged.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn simulator_faults_garbage_and_reopen_cost_only_themselves() {
    let faults = vec![
        Fault {
            sensor: "wit".into(),
            at_s: 5.0,
            kind: FaultKind::Garbage,
            bytes: 300,
            down_s: 0.0,
        },
        Fault {
            sensor: "mti".into(),
            at_s: 8.0,
            kind: FaultKind::Reopen,
            bytes: 0,
            down_s: 4.0,
        },
    ];
    let (_dir, report, session_dir) = serve_and_log(faults, false).await;
    let session = Session::open(&session_dir).expect("the session opens");
    let (events, _) = session.events();
    let kinds = |device: &str| -> Vec<EventKind> {
        events
            .iter()
            .filter(|e| e.device == device)
            .map(|e| e.kind)
            .collect()
    };
    let decoded = |frame: &imulab::sim::serve::SentImu| {
        without_times_imu(
            ImuMapping {
                body_from_sensor: nalgebra::Matrix3::identity(),
                gyro_scale: 1.0,
                accel_scale: 1.0,
            }
            .imu_record(
                frame.sample.as_ref().expect("decodable"),
                imulab::daemon::clock::Arrival {
                    mono_ns: 0,
                    wall_ns: 0,
                },
            ),
        )
    };
    for stream in &report.streams {
        let Sent::Imu(sent) = &stream.sent else {
            continue;
        };
        let rows = imu_rows(&session, &stream.sensor);
        match stream.sensor.as_str() {
            "wit" => {
                assert_eq!(stream.garbage_bytes, 300);
                assert_eq!(rows.len(), sent.len(), "wit: no frame lost to the garbage");
                for (k, (row, frame)) in rows.iter().zip(sent).enumerate() {
                    assert!(
                        same(&without_times_imu(*row), &decoded(frame)),
                        "wit frame {k}"
                    );
                }
                assert!(
                    kinds("wit").contains(&EventKind::Resync),
                    "{:?}",
                    kinds("wit")
                );
            }
            "mti" => {
                assert!(
                    stream.frames_unplugged > 0,
                    "frames due while unplugged are not sent"
                );
                // Frames sent to the first pty and not yet read when it closed are lost with
                // it (the kernel discards them); every frame sent to the new pty is logged.
                let after: Vec<_> = sent.iter().filter(|f| f.generation == 1).collect();
                assert!(!after.is_empty());
                let tail = &rows[rows.len() - after.len()..];
                for (k, (row, frame)) in tail.iter().zip(&after).enumerate() {
                    assert!(
                        same(&without_times_imu(*row), &decoded(frame)),
                        "mti frame {k} after the reopen"
                    );
                }
                let before = sent.len() - after.len();
                let kept = rows.len() - after.len();
                let lost = before - kept;
                println!(
                    "mti: {before} frames before the reopen, {lost} lost at the close, {} after",
                    after.len()
                );
                // What was lost is the tail the daemon had not read yet when the pty closed
                // (a hang-up discards unread bytes, as unplugging a USB adapter does): the
                // frames before it are all there, and it is at most the last 30 ms of data
                // (the daemon reads as bytes arrive; the slack is for a loaded machine).
                for (k, (row, frame)) in rows[..kept].iter().zip(sent).enumerate() {
                    assert!(
                        same(&without_times_imu(*row), &decoded(frame)),
                        "mti frame {k} before the reopen"
                    );
                }
                assert!(
                    lost as f64 <= 0.030 * IMU_HZ * SPEED,
                    "{lost} frames lost at the close"
                );
                let k = kinds("mti");
                for kind in [EventKind::Disconnect, EventKind::Gap, EventKind::Reconnect] {
                    assert!(k.contains(&kind), "{kind:?} missing: {k:?}");
                }
            }
            _ => {}
        }
    }
}
