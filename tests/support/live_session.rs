//! A simulated live session: two IMUs at 150 Hz written with the store's writer in steps,
//! as imulogd writes them (white rate noise plus a slow random walk of the bias, a
//! temperature ramp), and a GNSS receiver at 5 Hz; and `imulab watch` serving it (the watch
//! tests and `benches/watch.rs`).

use imulab::store::{
    DeviceInfo, DeviceKind, EventKind, EventRecord, GnssRecord, ImuRecord, Manifest, SessionWriter,
    WriterOptions,
};
use imulab_drivers::types::FixType;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::path::Path;
use std::time::Duration;

pub const RATE_HZ: f64 = 150.0;
pub const IMUS: [&str; 2] = ["imu_a", "imu_b"];

/// White noise density of the gyro (rad/s/√Hz) and of the accel (m/s²/√Hz), per IMU.
pub const GYRO_ARW: [f64; 2] = [1e-3, 3e-3];
pub const ACCEL_VRW: [f64; 2] = [2e-3, 5e-3];

pub fn device(name: &str, kind: DeviceKind, rate_hz: f64) -> DeviceInfo {
    DeviceInfo {
        name: name.into(),
        kind,
        model: "sim".into(),
        serial: String::new(),
        port: "sim".into(),
        protocol: "sim".into(),
        rate_hz,
        axis_frame: "FRD".into(),
        extra: Default::default(),
    }
}

/// The writer side of a live session. Rows carry host time stamps starting at `t0_ns`.
pub struct LiveSession {
    pub writer: Option<SessionWriter>,
    rng: Xoshiro256PlusPlus,
    /// Rows per IMU so far, written or skipped.
    pub rows: u64,
    /// Rows left out by [`LiveSession::skip`].
    pub skipped: u64,
    t0_ns: i64,
    bias: [[f64; 6]; 2],
    /// Every gyro_x sample of the first IMU, for the full recomputation.
    pub gyro_x_a: Vec<f64>,
}

impl LiveSession {
    pub fn create(dir: &Path, t0_ns: i64) -> Self {
        let devices = vec![
            device(IMUS[0], DeviceKind::Imu, RATE_HZ),
            device(IMUS[1], DeviceKind::Imu, RATE_HZ),
            device("rx", DeviceKind::Gnss, 5.0),
        ];
        let options = WriterOptions {
            fsync_on_flush: false,
            // Rows reach the live file at every flush (no journal wait).
            chunk_interval: Duration::from_secs(1),
            flush_interval: Duration::from_secs(1),
            ..WriterOptions::default()
        };
        let writer =
            SessionWriter::create(dir, Manifest::new(devices, toml::Table::new()), options)
                .unwrap();
        let mut live = LiveSession {
            writer: Some(writer),
            rng: Xoshiro256PlusPlus::seed_from_u64(24),
            rows: 0,
            skipped: 0,
            t0_ns,
            bias: [[0.0; 6]; 2],
            gyro_x_a: Vec::new(),
        };
        // As imulogd does: a session-wide event (no device) opens the session.
        live.event("", EventKind::SessionStart, "");
        live
    }

    fn t_ns(&self, row: u64) -> i64 {
        self.t0_ns + (row as f64 * 1e9 / RATE_HZ).round() as i64
    }

    /// Writes `seconds` more of data (both IMUs, the receiver) and flushes.
    pub fn append(&mut self, seconds: f64) {
        let n = (seconds * RATE_HZ).round() as u64;
        let sqrt_rate = RATE_HZ.sqrt();
        let mut per_imu: [Vec<ImuRecord>; 2] = [Vec::new(), Vec::new()];
        let mut gnss = Vec::new();
        for row in self.rows..self.rows + n {
            let t = self.t_ns(row);
            for (k, rows) in per_imu.iter_mut().enumerate() {
                let mut v = [0.0; 6];
                for (axis, value) in v.iter_mut().enumerate() {
                    let white = if axis < 3 { GYRO_ARW[k] } else { ACCEL_VRW[k] };
                    let g: f64 = StandardNormal.sample(&mut self.rng);
                    let w: f64 = StandardNormal.sample(&mut self.rng);
                    self.bias[k][axis] += 1e-6 * w;
                    *value = white * sqrt_rate * g + self.bias[k][axis];
                }
                rows.push(ImuRecord {
                    t_mono_ns: t,
                    t_wall_ns: 1_700_000_000_000_000_000 + t,
                    t_sensor: f64::NAN,
                    gyro: [v[0], v[1], v[2]],
                    accel: [v[3], v[4], -9.80665 + v[5]],
                    temp: 25.0 + 1e-4 * row as f64 + 0.01 * k as f64,
                    status: 0,
                });
            }
            self.gyro_x_a.push(per_imu[0].last().unwrap().gyro[0]);
            if row % 30 == 0 {
                gnss.push(GnssRecord {
                    t_mono_ns: t,
                    t_wall_ns: 1_700_000_000_000_000_000 + t,
                    week: 2400,
                    tow_s: 1e-9 * t as f64,
                    utc_ns: i64::MIN,
                    lat_deg: 45.0,
                    lon_deg: 7.0,
                    height_m: 250.0,
                    vel_ned: [0.0; 3],
                    h_acc_m: 0.02,
                    v_acc_m: 0.03,
                    s_acc_mps: 0.05,
                    heading_deg: f64::NAN,
                    fix_type: FixType::RtkFixed,
                    num_sats: 20,
                    pdop: 1.2,
                    hdop: 0.7,
                    vdop: 1.0,
                });
            }
        }
        let w = self.writer.as_mut().unwrap();
        for (k, rows) in per_imu.iter().enumerate() {
            for piece in rows.chunks(500) {
                w.append_imu(IMUS[k], piece).unwrap();
            }
        }
        w.append_gnss("rx", &gnss).unwrap();
        self.rows += n;
        w.flush().unwrap();
    }

    /// Leaves `seconds` without rows (a gap in the time stamps).
    pub fn skip(&mut self, seconds: f64) {
        let n = (seconds * RATE_HZ).round() as u64;
        self.rows += n;
        self.skipped += n;
    }

    /// A daemon event for `device`.
    pub fn event(&mut self, device: &str, kind: EventKind, detail: &str) {
        let t = self.t_ns(self.rows);
        let w = self.writer.as_mut().unwrap();
        w.append_event(&EventRecord {
            t_mono_ns: t,
            t_wall_ns: 1_700_000_000_000_000_000 + t,
            device: device.into(),
            kind,
            detail: detail.into(),
        })
        .unwrap();
    }

    pub fn rotate(&mut self) {
        self.writer.as_mut().unwrap().rotate().unwrap();
    }

    pub fn close(&mut self) {
        if let Some(w) = self.writer.take() {
            w.close().unwrap();
        }
    }
}

/// CLOCK_MONOTONIC now, ns.
pub fn mono_now() -> i64 {
    imulab::daemon::clock::mono_ns()
}

/// `imulab watch` running on a free loopback port; killed when dropped.
pub struct Served {
    pub child: std::process::Child,
    pub addr: std::net::SocketAddr,
}

impl Served {
    /// Starts `IMULAB watch SESSION --listen 127.0.0.1:0 ARGS…` (`imulab` the binary, the
    /// caller's `env!("CARGO_BIN_EXE_imulab")`) and waits for its address.
    pub fn start(imulab: &str, session: &Path, args: &[&str]) -> Self {
        use std::io::BufRead;
        let mut child = std::process::Command::new(imulab)
            .arg("watch")
            .arg(session)
            .args(["--listen", "127.0.0.1:0"])
            .args(args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::inherit())
            .spawn()
            .unwrap();
        let stdout = child.stdout.take().unwrap();
        let mut line = String::new();
        std::io::BufReader::new(stdout)
            .read_line(&mut line)
            .unwrap();
        let addr = line
            .split("http://")
            .nth(1)
            .and_then(|rest| rest.split('/').next())
            .and_then(|a| a.parse().ok())
            .unwrap_or_else(|| panic!("no address in `{line}`"));
        Served { child, addr }
    }

    /// Sends `head` (request line and headers, without the blank line) and returns the
    /// status code and the whole response.
    pub fn raw(&self, head: &str) -> (u16, String) {
        use std::io::{Read, Write};
        let mut s = std::net::TcpStream::connect(self.addr).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
        s.write_all(format!("{head}\r\nConnection: close\r\n\r\n").as_bytes())
            .unwrap();
        let mut out = Vec::new();
        let _ = s.read_to_end(&mut out);
        let text = String::from_utf8_lossy(&out).to_string();
        let code = text
            .split_whitespace()
            .nth(1)
            .and_then(|c| c.parse().ok())
            .unwrap_or(0);
        (code, text)
    }

    /// GET `path` with a local Host header.
    pub fn get(&self, path: &str) -> (u16, String) {
        self.raw(&format!("GET {path} HTTP/1.1\r\nHost: {}", self.addr))
    }
}

impl Drop for Served {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A finished session of `seconds` of data, in `dir/run`.
pub fn finished_session(dir: &Path, seconds: f64) -> std::path::PathBuf {
    let session = dir.join("run");
    let mut live = LiveSession::create(&session, mono_now());
    live.append(seconds);
    live.event(IMUS[0], EventKind::Resync, "count=2");
    live.close();
    session
}
