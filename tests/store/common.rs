//! Helpers shared by the store tests: a small two-IMU + GNSS session written with known
//! values so readers can compare exactly.
#![allow(dead_code)]

use std::io::{BufRead, BufReader, Lines};
use std::path::Path;
use std::process::{Child, ChildStdout, Command, Stdio};
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
        heading_deg: (i as f64 * 0.5) % 360.0,
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

/// The body of a writer child (a test that does something only when this test binary is
/// re-run by [`WriterChild::spawn`] with `env` naming the session directory): writes 100 Hz
/// data for `imu_a` and `imu_b` in 10-row batches (0.1 s of data time), calls `extra` with
/// the batch's first row index for whatever else the test appends, and prints
/// `T=<last t_mono_ns appended>` after each batch, until it is killed.
pub fn run_writer_child(
    env: &str,
    opts: WriterOptions,
    mut extra: impl FnMut(&mut SessionWriter, usize),
) {
    let Ok(dir) = std::env::var(env) else {
        return; // only does something when run as the child
    };
    let mut w = SessionWriter::create(Path::new(&dir), manifest(), opts).unwrap();
    let mut i = 0;
    loop {
        for (d, name) in ["imu_a", "imu_b"].iter().enumerate() {
            let rows: Vec<_> = (i..i + 10).map(|k| imu_row(d, k)).collect();
            w.append_imu(name, &rows).unwrap();
        }
        extra(&mut w, i);
        i += 10;
        println!("T={}", imu_row(0, i - 1).t_mono_ns);
        std::thread::sleep(Duration::from_micros(300));
    }
}

/// A writer child: this test binary re-run with only the test `test` (one that calls
/// [`run_writer_child`]) and `env` naming the session directory. Hold
/// [`child_process_guard`] while it lives.
pub struct WriterChild {
    child: Child,
    lines: Lines<BufReader<ChildStdout>>,
    last_t: i64,
}

impl WriterChild {
    pub fn spawn(test: &str, env: &str, dir: &Path) -> Self {
        let mut child = Command::new(std::env::current_exe().unwrap())
            .args(["--exact", test, "--nocapture", "--test-threads=1"])
            .env(env, dir)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let lines = BufReader::new(child.stdout.take().unwrap()).lines();
        WriterChild {
            child,
            lines,
            last_t: i64::MIN,
        }
    }

    /// Waits until the child reports having appended data up to `t_mono_ns`.
    pub fn wait_for(&mut self, t_mono_ns: i64) {
        while self.last_t < t_mono_ns {
            let line = self.lines.next().expect("child ended early").unwrap();
            self.note(&line);
        }
    }

    /// SIGKILLs the child and returns the last data time it reported.
    pub fn kill(mut self) -> i64 {
        self.child.kill().unwrap(); // SIGKILL
        self.child.wait().unwrap();
        while let Some(line) = self.lines.next() {
            self.note(&line.unwrap());
        }
        self.last_t
    }

    fn note(&mut self, line: &str) {
        if let Some(t) = line.strip_prefix("T=") {
            self.last_t = t.parse().unwrap();
        }
    }
}
