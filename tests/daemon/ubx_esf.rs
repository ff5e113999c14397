//! The IMU of a u-blox dead-reckoning receiver over a pty: hand-built UBX ESF-RAW messages
//! (checksums computed here), with a NAV-POSLLH, an NMEA sentence and a corrupted frame mixed
//! in, are logged as an IMU device with protocol `ubx-esf`: one row per sensor time tag, in
//! SI units, the corrupted frame counted and nothing else a row. And the receiver's whole
//! port (NAV-PVT fixes and ESF-RAW on one pty) logged by one `ubx` device with
//! `[device.imu]`: its fixes and its IMU's rows in two devices of a real session.

use std::time::Duration;

use crate::common::daemon::parts_for;
use crate::common::imu_rows;
use crate::common::pty::Pty;
use crate::serial::{config, start};
use imulab::daemon::run;
use imulab::daemon::session::open_session_sink;
use imulab::store::{DeviceKind, EventKind, Session, TimeRange};
use imulab_drivers::types::{FixType, GnssFix};

const MESSAGES: u32 = 100;
const DEG: f64 = std::f64::consts::PI / 180.0;

/// A UBX frame with its Fletcher-8 checksum over class, id, length and payload.
fn ubx(class: u8, id: u8, payload: &[u8]) -> Vec<u8> {
    let mut frame = vec![0xB5, 0x62, class, id];
    frame.extend_from_slice(&(payload.len() as u16).to_le_bytes());
    frame.extend_from_slice(payload);
    let (mut a, mut b) = (0u8, 0u8);
    for &x in &frame[2..] {
        a = a.wrapping_add(x);
        b = b.wrapping_add(a);
    }
    frame.extend_from_slice(&[a, b]);
    frame
}

/// ESF-RAW with two sample sets (gyro x/y/z, gyro temperature, accel x/y/z) for tags
/// `tag` and `tag + 10`; the values grow with the tag so every row is distinct.
fn esf_raw(tag: u32) -> Vec<u8> {
    let mut payload = vec![0u8; 4];
    for t in [tag, tag + 10] {
        let v = t as i32;
        for (data_type, value) in [
            (14u32, v),
            (13, -v),
            (5, 2 * v),
            (12, 2000 + v % 100),
            (16, v),
            (17, -3 * v),
            (18, 10_000),
        ] {
            let word = (data_type << 24) | (value as u32 & 0x00FF_FFFF);
            payload.extend_from_slice(&word.to_le_bytes());
            payload.extend_from_slice(&t.to_le_bytes());
        }
    }
    ubx(0x10, 0x03, &payload)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn esf_raw_over_a_pty_is_an_imu_device_one_row_per_time_tag() {
    let dir = tempfile::tempdir().unwrap();
    let mut pty = Pty::open();
    let devices = format!(
        "[[device]]\nname = \"f9r-imu\"\nprotocol = \"ubx-esf\"\nrate_hz = 100\n\
         serial = {{ port = \"{}\", baud = 115200 }}\n",
        pty.slave_path.display()
    );
    let daemon = start(config(dir.path(), &devices));
    tokio::time::sleep(Duration::from_millis(200)).await;
    let pty = tokio::task::spawn_blocking(move || {
        for k in 0..MESSAGES {
            let mut bytes = esf_raw(1000 + 20 * k);
            if k == 40 {
                // A fix and an NMEA sentence on the same port, and a frame with a bad checksum.
                bytes.extend(ubx(0x01, 0x02, &[0u8; 28]));
                bytes.extend_from_slice(b"$GPHDT,271.25,T*06\r\n");
                let mut bad = esf_raw(1);
                let last = bad.len() - 1;
                bad[last] ^= 0x55;
                bytes.extend(bad);
            }
            pty.write(&bytes);
            std::thread::sleep(Duration::from_millis(3));
        }
        std::thread::sleep(Duration::from_millis(150));
        pty
    })
    .await
    .unwrap();
    let store = daemon.stop().await;
    drop(pty);

    let rows = &store.imu["f9r-imu"];
    assert_eq!(
        rows.len(),
        2 * MESSAGES as usize,
        "events: {:?}",
        store.events
    );
    for (i, r) in rows.iter().enumerate() {
        let tag = 1000 + 10 * i as u32;
        let v = f64::from(tag);
        assert_eq!(r.t_sensor, v, "row {i}");
        let want_gyro = [v, -v, 2.0 * v].map(|x| x / 4096.0 * DEG);
        for (got, want) in r.gyro.iter().zip(want_gyro) {
            assert!((got - want).abs() < 1e-15, "row {i}: {:?}", r.gyro);
        }
        assert_eq!(r.accel, [v / 1024.0, -3.0 * v / 1024.0, 10_000.0 / 1024.0]);
        assert_eq!(r.temp, f64::from(2000 + tag % 100) / 100.0);
    }
    assert!(
        store
            .events
            .iter()
            .any(|e| e.device == "f9r-imu" && e.kind == EventKind::ChecksumError),
        "the corrupted frame is reported: {:?}",
        store.events
    );
}

/// NAV-PVT and NAV-EOE of a 3D fix at `k` × 100 ms after 2026-11-23 12:30:00 UTC.
fn nav_pvt(k: u32) -> (Vec<u8>, f64, f64) {
    let lat = 48.1 + f64::from(k) * 1e-5;
    let lon = 11.5 - f64::from(k) * 2e-5;
    let fix = GnssFix {
        week: Some(2394),
        tow_s: Some(131_418.0 + f64::from(k) * 0.1),
        utc_ns: Some(1_795_437_000_000_000_000 + i64::from(k) * 100_000_000),
        lat_deg: Some(lat),
        lon_deg: Some(lon),
        height_m: Some(547.0),
        height_msl_m: Some(500.0),
        vel_ned: Some([0.1, -0.2, 0.0]),
        h_acc_m: Some(1.5),
        v_acc_m: Some(2.5),
        fix: FixType::Fix3D,
        num_sats: Some(12),
        ..GnssFix::default()
    };
    let mut out = Vec::new();
    imulab_drivers::codec::ubx::encode_fix(&fix, &mut out).expect("a fix NAV-PVT carries");
    (out, lat, lon)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_receiver_port_logs_its_fixes_and_its_esf_imu_as_two_devices() {
    const FIXES: u32 = 20;
    const ESF_PER_FIX: u32 = 5;
    let dir = tempfile::tempdir().unwrap();
    let mut pty = Pty::open();
    let devices = format!(
        "[[device]]\nname = \"f9r\"\nprotocol = \"ubx\"\nrate_hz = 10\n\
         serial = {{ port = \"{}\", baud = 460800 }}\n\
         gap_factor = 5\nimu = {{ name = \"f9r_imu\", rate_hz = 100 }}\n",
        pty.slave_path.display()
    );
    let config = config(dir.path(), &devices);
    let session_dir = dir.path().join("session");
    let sink = open_session_sink(&config, &session_dir).expect("session created");
    let parts = parts_for(&config, Box::new(sink), session_dir.clone());
    let (stop, stop_rx) = tokio::sync::watch::channel(false);
    let daemon = tokio::spawn(async move { run(&config, parts, stop_rx).await });
    tokio::time::sleep(Duration::from_millis(200)).await;
    let (pty, sent) = tokio::task::spawn_blocking(move || {
        let mut sent = Vec::new();
        for k in 0..FIXES {
            let (mut bytes, lat, lon) = nav_pvt(k);
            sent.push((lat, lon));
            for m in 0..ESF_PER_FIX {
                bytes.extend(esf_raw(1000 + 20 * (ESF_PER_FIX * k + m)));
            }
            if k == 7 {
                let mut bad = esf_raw(1);
                let last = bad.len() - 1;
                bad[last] ^= 0x55;
                bytes.extend(bad);
            }
            pty.write(&bytes);
            std::thread::sleep(Duration::from_millis(5));
        }
        std::thread::sleep(Duration::from_millis(200));
        (pty, sent)
    })
    .await
    .unwrap();
    let _ = stop.send(true);
    let outcome = daemon.await.unwrap();
    assert_eq!(outcome.exit_code(), 0, "{outcome:?}");
    drop(pty);

    let session = Session::open(&session_dir).expect("the session opens");
    assert!(session.problems().is_empty(), "{:?}", session.problems());
    let devices = &session.manifest().devices;
    let summary: Vec<(&str, DeviceKind, &str, f64)> = devices
        .iter()
        .map(|d| (d.name.as_str(), d.kind, d.protocol.as_str(), d.rate_hz))
        .collect();
    assert_eq!(
        summary,
        [
            ("f9r", DeviceKind::Gnss, "ubx", 10.0),
            ("f9r_imu", DeviceKind::Imu, "ubx-esf", 100.0)
        ]
    );
    assert_eq!(devices[1].port, devices[0].port);
    assert_eq!(
        devices[1].extra.get("receiver").and_then(|v| v.as_str()),
        Some("f9r")
    );

    let mut fixes = Vec::new();
    for block in session.gnss_blocks("f9r", TimeRange::all(), 64).unwrap() {
        let block = block.unwrap();
        fixes.extend(
            block
                .lat_deg
                .iter()
                .copied()
                .zip(block.lon_deg.iter().copied()),
        );
    }
    assert_eq!(fixes.len(), FIXES as usize);
    for ((lat, lon), (want_lat, want_lon)) in fixes.iter().zip(&sent) {
        assert!((lat - want_lat).abs() < 1e-7 && (lon - want_lon).abs() < 1e-7);
    }

    let rows = imu_rows(&session, "f9r_imu");
    assert_eq!(rows.len(), (2 * FIXES * ESF_PER_FIX) as usize);
    for (i, r) in rows.iter().enumerate() {
        // The receiver's sensor time tag is the IMU's sensor clock.
        let v = f64::from(1000 + 10 * i as u32);
        assert_eq!(r.t_sensor, v, "row {i}");
        assert_eq!(r.accel, [v / 1024.0, -3.0 * v / 1024.0, 10_000.0 / 1024.0]);
    }

    // `imulab inspect` sees the IMU with its rows and its receiver's gap factor.
    let report = imulab::cli::inspect::inspect(&session, 0);
    let imu = report
        .devices
        .iter()
        .find(|d| d.name == "f9r_imu")
        .expect("inspect lists the IMU");
    assert_eq!(
        (imu.kind.as_str(), imu.rows, imu.gap_factor),
        ("imu", u64::from(2 * FIXES * ESF_PER_FIX), 5.0)
    );

    // The port's faults are the receiver's, counted once.
    let (events, problems) = session.events();
    assert!(problems.is_empty(), "{problems:?}");
    let checksum: Vec<_> = events
        .iter()
        .filter(|e| e.kind == EventKind::ChecksumError)
        .collect();
    assert_eq!(checksum.len(), 1, "{events:?}");
    assert_eq!(checksum[0].device, "f9r");
    assert!(checksum[0].detail.contains("(1 in total)"), "{checksum:?}");
    assert!(
        !events.iter().any(|e| e.kind == EventKind::Gap),
        "{events:?}"
    );
}
