//! The IMU of a u-blox dead-reckoning receiver over a pty: hand-built UBX ESF-RAW messages
//! (checksums computed here), with a NAV-POSLLH, an NMEA sentence and a corrupted frame mixed
//! in, are logged as an IMU device with protocol `ubx-esf`: one row per sensor time tag, in
//! SI units, the corrupted frame counted and nothing else a row.

use std::time::Duration;

use crate::common::pty::Pty;
use crate::serial::{config, start};
use imulab::store::EventKind;

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
