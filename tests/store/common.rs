//! Helpers shared by the `store_*` tests (included with `#[path]`): a small two-IMU + GNSS
//! session written with known values so readers can compare exactly.
#![allow(dead_code)]

use std::path::Path;
use std::time::Duration;

use imulab::store::{
    DeviceInfo, DeviceKind, EventKind, EventRecord, GnssRecord, ImuRecord, Manifest, SessionWriter,
    WriterOptions,
};
use imulab_drivers::types::FixType;

pub const IMU_HZ: f64 = 100.0;
pub const GNSS_HZ: f64 = 5.0;

pub fn device(name: &str, kind: DeviceKind, rate_hz: f64) -> DeviceInfo {
    DeviceInfo {
        name: name.into(),
        kind,
        model: format!("{name}-model"),
        serial: "SN42".into(),
        port: "sim".into(),
        protocol: "sim".into(),
        rate_hz,
        axis_frame: "FRD".into(),
        extra: Default::default(),
    }
}

pub fn manifest() -> Manifest {
    let mut config = toml::Table::new();
    config.insert("note".into(), toml::Value::String("test".into()));
    Manifest::new(
        vec![
            device("imu_a", DeviceKind::Imu, IMU_HZ),
            device("imu_b", DeviceKind::Imu, IMU_HZ),
            device("gps", DeviceKind::Gnss, GNSS_HZ),
        ],
        config,
    )
}

/// Deterministic IMU row `i` of device number `d` (values depend on both, exactly representable).
pub fn imu_row(d: usize, i: usize) -> ImuRecord {
    let t = (i as f64) * 0.01;
    ImuRecord {
        t_mono_ns: 1_000_000_000 + (i as i64) * 10_000_000,
        t_wall_ns: 1_700_000_000_000_000_000 + (i as i64) * 10_000_000,
        t_sensor: i as f64 * 4.0,
        gyro: [0.001 * d as f64 + t, -t, 0.5 * t],
        accel: [0.1, -0.2 + d as f64, -9.81 + t * 1e-3],
        temp: 25.0 + t * 1e-2,
        status: (i % 7) as u32,
    }
}

pub fn gnss_row(i: usize) -> GnssRecord {
    GnssRecord {
        t_mono_ns: 1_000_000_000 + (i as i64) * 200_000_000,
        t_wall_ns: 1_700_000_000_000_000_000 + (i as i64) * 200_000_000,
        week: 2300,
        tow_s: 345_600.0 + i as f64 * 0.2,
        utc_ns: 1_700_000_000_000_000_000 + (i as i64) * 200_000_000,
        lat_deg: 52.0 + i as f64 * 1e-7,
        lon_deg: 4.0,
        height_m: 10.0,
        vel_ned: [0.1, 0.2, -0.3],
        h_acc_m: 1.5,
        v_acc_m: 2.5,
        s_acc_mps: 0.2,
        fix_type: FixType::Fix3D,
        num_sats: 12,
        pdop: 1.2,
        hdop: 0.8,
        vdop: 1.0,
    }
}

/// Writes `seconds` of data (IMU in batches of `batch` rows) and closes the session.
pub fn write_session(dir: &Path, seconds: usize, batch: usize, opts: WriterOptions) -> Manifest {
    let manifest = manifest();
    let mut w = SessionWriter::create(dir, manifest.clone(), opts).expect("create");
    let n_imu = seconds * IMU_HZ as usize;
    let mut next_gnss = 0;
    let mut i = 0;
    while i < n_imu {
        let end = (i + batch).min(n_imu);
        for d in 0..2 {
            let rows: Vec<ImuRecord> = (i..end).map(|k| imu_row(d, k)).collect();
            w.append_imu(if d == 0 { "imu_a" } else { "imu_b" }, &rows)
                .expect("append imu");
        }
        let t_end = imu_row(0, end - 1).t_mono_ns;
        let mut fixes = Vec::new();
        while gnss_row(next_gnss).t_mono_ns <= t_end {
            fixes.push(gnss_row(next_gnss));
            next_gnss += 1;
        }
        w.append_gnss("gps", &fixes).expect("append gnss");
        if i == 0 {
            w.append_event(&EventRecord {
                t_mono_ns: imu_row(0, 0).t_mono_ns,
                t_wall_ns: 0,
                device: "imu_a".into(),
                kind: EventKind::ChecksumError,
                detail: "3 frames dropped, ünïcode ok".into(),
            })
            .expect("event");
        }
        i = end;
    }
    w.close().expect("close");
    manifest
}

pub fn fast_opts() -> WriterOptions {
    WriterOptions {
        fsync_on_flush: false,
        rotate_after: Duration::from_secs(10),
        ..WriterOptions::default()
    }
}

/// Held by every test that spawns a child writer, for its whole run. A child inherits the
/// parent's open file descriptors, and with them the HDF5 file locks (flock) of whatever
/// file another test thread has open at that moment, until it is killed: two such tests
/// in parallel made each other's files unopenable ("unable to lock file").
pub static CHILD_PROCESS_TESTS: std::sync::Mutex<()> = std::sync::Mutex::new(());

pub fn child_process_guard() -> std::sync::MutexGuard<'static, ()> {
    CHILD_PROCESS_TESTS
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}
