//! The daemon over ptys with the real codecs and transports, the way it runs on a bench:
//! the configuration's devices are opened through `connector_for` (the drivers' serial and
//! slcan transports) and decoded through `decoder_for` (the drivers' codecs), and the bytes
//! are made by the drivers' encoders. Checked: every sample sent is logged exactly once with
//! its values to the encoding's resolution (WitMotion, Xbus, CSV with its own column map,
//! mixed UBX + NMEA, a CAN IMU through a DBC over slcan), garbage costs only itself and
//! becomes resync events, and a device path that never exists is an error in the status.

use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::common::daemon::parts_for;
use crate::common::encode::{accel_of, gnss_cycle, gyro_of, temp_of, wit_sample, xbus_sample};
use crate::common::pty::Pty;
use imulab::daemon::config::{parse, CheckedConfig};
use imulab::daemon::sink::{MemorySink, MemoryStore};
use imulab::daemon::status::{read_status_file, DeviceState};
use imulab::daemon::{run, Outcome};
use imulab::store::{EventKind, ImuRecord};
use imulab_drivers::codec::dbc::{DbcImu, DbcImuMapping};
use imulab_drivers::codec::slcan::{SlcanEncoder, SlcanMessage};
use imulab_drivers::codec::Encoder;
use tokio::sync::watch;

/// Samples per device in these tests.
const SAMPLES: u64 = 60;

/// A running daemon built the way `imulogd` builds it, writing into memory.
pub struct Daemon {
    stop: watch::Sender<bool>,
    handle: tokio::task::JoinHandle<Outcome>,
    pub sink: MemorySink,
    pub status_path: PathBuf,
}

pub fn config(dir: &Path, devices: &str) -> CheckedConfig {
    let text = format!(
        "[session]\noutput_dir = \"{}\"\nflush_interval_ms = 50\n\n{devices}",
        dir.display()
    );
    parse(&text, "test").unwrap_or_else(|e| panic!("{e}"))
}

pub fn start(config: CheckedConfig) -> Daemon {
    let sink = MemorySink::new();
    let status_path = config.status_path();
    let session_dir = config.session.output_dir.join("session");
    let parts = parts_for(&config, Box::new(sink.clone()), session_dir);
    let (stop, stop_rx) = watch::channel(false);
    let handle = tokio::spawn(async move { run(&config, parts, stop_rx).await });
    Daemon {
        stop,
        handle,
        sink,
        status_path,
    }
}

impl Daemon {
    /// Waits (at most 10 s) until `device` has `count` events of `kind` in the sink, so a test
    /// acts on what the daemon did rather than on how long it usually takes.
    pub async fn wait_for_event(&self, device: &str, kind: EventKind, count: usize) {
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        loop {
            let seen = self
                .sink
                .snapshot()
                .events
                .iter()
                .filter(|e| e.device == device && e.kind == kind)
                .count();
            if seen >= count {
                return;
            }
            assert!(
                std::time::Instant::now() < deadline,
                "{device}: {count} {kind:?} event(s) not seen within 10 s (seen {seen})"
            );
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }

    pub async fn stop(self) -> MemoryStore {
        let _ = self.stop.send(true);
        let outcome = self.handle.await.unwrap();
        assert_eq!(outcome.exit_code(), 0, "{outcome:?}");
        self.sink.snapshot()
    }
}

/// The CSV layout of the CSV device below: `µs;gx;gy;gz (deg/s);ax;ay;az (mg)`.
const CSV_TABLE: &str = "csv = { separator = \";\", time = { index = 0, scale = 1e-6 }, \
    gyro = [{ index = 1, scale = 0.017453292519943295 }, { index = 2, scale = 0.017453292519943295 }, { index = 3, scale = 0.017453292519943295 }], \
    accel = [{ index = 4, scale = 0.00980665 }, { index = 5, scale = 0.00980665 }, { index = 6, scale = 0.00980665 }] }";

pub fn csv_sample(seq: u64) -> Vec<u8> {
    let g = gyro_of(2, seq).map(|v| v.to_degrees());
    let a = accel_of(2, seq).map(|v| v / 0.00980665);
    format!(
        "{};{:.4};{:.4};{:.4};{:.3};{:.3};{:.3}\r\n",
        seq * 10_000,
        g[0],
        g[1],
        g[2],
        a[0],
        a[1],
        a[2]
    )
    .into_bytes()
}

/// Checks one device's rows: sample `k` of `expected` (sensor time, gyro, accel) within
/// `tol_gyro`/`tol_accel`, every sample exactly once and in order, arrival times monotonic.
pub fn check_rows(
    name: &str,
    rows: &[ImuRecord],
    device: u64,
    seqs: impl Iterator<Item = u64>,
    time_of: impl Fn(u64) -> f64,
    tol_gyro: f64,
    tol_accel: f64,
) {
    let seqs: Vec<u64> = seqs.collect();
    let times: Vec<f64> = rows.iter().map(|r| r.t_sensor).collect();
    let want: Vec<f64> = seqs.iter().map(|&s| time_of(s)).collect();
    assert_eq!(rows.len(), seqs.len(), "{name}: sensor times {times:?}");
    for ((row, &seq), want_t) in rows.iter().zip(&seqs).zip(&want) {
        assert!(
            (row.t_sensor - want_t).abs() < 1e-6,
            "{name} sample {seq}: time {} != {want_t}",
            row.t_sensor
        );
        for axis in 0..3 {
            let (g, a) = (gyro_of(device, seq)[axis], accel_of(device, seq)[axis]);
            assert!(
                (row.gyro[axis] - g).abs() <= tol_gyro,
                "{name} sample {seq} gyro[{axis}] {} vs {g}",
                row.gyro[axis]
            );
            assert!(
                (row.accel[axis] - a).abs() <= tol_accel,
                "{name} sample {seq} accel[{axis}] {} vs {a}",
                row.accel[axis]
            );
        }
    }
    assert!(
        rows.windows(2).all(|w| w[0].t_mono_ns <= w[1].t_mono_ns),
        "{name}: arrival times monotonic"
    );
}

fn events_of(store: &MemoryStore, device: &str, kind: EventKind) -> Vec<String> {
    store
        .events
        .iter()
        .filter(|e| e.device == device && e.kind == kind)
        .map(|e| e.detail.clone())
        .collect()
}

/// Garbage that is no frame start of any of the protocols here (no 0x55, 0xFA, `$`, digits
/// or line ends), so it costs exactly the frame it is written into and nothing else.
const GARBAGE: &[u8] = b"\x01\x02garbage!!\xfe\xff\x00\x13";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn wit_xbus_and_csv_over_ptys_log_every_sample_once_and_garbage_costs_only_itself() {
    let dir = tempfile::tempdir().unwrap();
    let mut ptys = [Pty::open(), Pty::open(), Pty::open()];
    let devices = format!(
        "[[device]]\nname = \"wit\"\nprotocol = \"wit\"\nrate_hz = 100\nserial = {{ port = \"{}\", baud = 115200 }}\n\
         [[device]]\nname = \"xsens\"\nprotocol = \"xbus\"\nrate_hz = 100\nserial = {{ port = \"{}\", baud = 921600 }}\n\
         [[device]]\nname = \"home\"\nprotocol = \"csv\"\nrate_hz = 100\nserial = {{ port = \"{}\" }}\n{CSV_TABLE}\n",
        ptys[0].slave_path.display(),
        ptys[1].slave_path.display(),
        ptys[2].slave_path.display()
    );
    let daemon = start(config(dir.path(), &devices));
    tokio::time::sleep(Duration::from_millis(200)).await;
    // Garbage between samples (wit, xbus) and inside a line (csv: that line is lost).
    let cut_line = 25u64;
    let ptys = tokio::task::spawn_blocking(move || {
        for seq in 0..SAMPLES {
            if seq == 20 {
                ptys[0].write(GARBAGE);
                ptys[1].write(GARBAGE);
            }
            ptys[0].write(&wit_sample(seq));
            ptys[1].write(&xbus_sample(seq));
            let mut line = csv_sample(seq);
            if seq == cut_line {
                line.splice(3..3, GARBAGE.iter().copied());
            }
            ptys[2].write(&line);
            std::thread::sleep(Duration::from_millis(3));
        }
        std::thread::sleep(Duration::from_millis(200));
        ptys
    })
    .await
    .unwrap();
    let store = daemon.stop().await;
    drop(ptys);

    // WitMotion: ±2000 °/s and ±16 g in 16 bits, rounded: half a count.
    let wit_gyro = 2000f64.to_radians() / 32768.0 / 2.0 + 1e-12;
    let wit_accel = 16.0 * 9.80665 / 32768.0 / 2.0 + 1e-12;
    check_rows(
        "wit",
        &store.imu["wit"],
        0,
        0..SAMPLES,
        |s| s as f64 * 0.01,
        wit_gyro,
        wit_accel,
    );
    check_rows(
        "xsens",
        &store.imu["xsens"],
        1,
        0..SAMPLES,
        |s| s as f64 * 0.01,
        1e-6,
        1e-5,
    );
    check_rows(
        "home",
        &store.imu["home"],
        2,
        (0..SAMPLES).filter(|&s| s != cut_line),
        |s| s as f64 * 0.01,
        0.5e-4 * PI / 180.0 + 1e-12,
        0.5e-3 * 0.00980665 + 1e-12,
    );
    for name in ["wit", "xsens", "home"] {
        let resyncs = events_of(&store, name, EventKind::Resync);
        assert!(
            !resyncs.is_empty(),
            "{name}: the garbage is a resync event: {:?}",
            store.events
        );
    }
    let wit_temps: Vec<f64> = store.imu["wit"].iter().map(|r| r.temp).collect();
    assert!(
        (wit_temps[7] - temp_of(7)).abs() <= 0.005 + 1e-9,
        "{wit_temps:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mixed_ubx_and_nmea_receiver_logs_each_epoch_once() {
    let dir = tempfile::tempdir().unwrap();
    let mut pty = Pty::open();
    let devices = format!(
        "[[device]]\nname = \"gnss\"\nprotocol = \"gnss\"\nrate_hz = 10\nserial = {{ port = \"{}\", baud = 38400 }}\n",
        pty.slave_path.display()
    );
    let daemon = start(config(dir.path(), &devices));
    tokio::time::sleep(Duration::from_millis(200)).await;
    let cycles = 20u64;
    let (pty, sent) = tokio::task::spawn_blocking(move || {
        let mut sent = Vec::new();
        for k in 0..cycles {
            let (bytes, lat, lon) = gnss_cycle(k);
            pty.write(&bytes);
            sent.push((lat, lon));
            std::thread::sleep(Duration::from_millis(5));
        }
        std::thread::sleep(Duration::from_millis(200));
        (pty, sent)
    })
    .await
    .unwrap();
    let store = daemon.stop().await;
    drop(pty);
    let rows = &store.gnss["gnss"];
    // The receiver reports each solution twice (NMEA and UBX); the codec merges them into one
    // fix per epoch (UBX wins per field, NMEA fills what NAV-PVT lacks: HDOP from the GGA).
    assert_eq!(rows.len() as u64, cycles, "one row per epoch: {rows:?}");
    for (k, ((lat, lon), r)) in sent.iter().zip(rows).enumerate() {
        // NAV-PVT's position (1e-7 deg), not the NMEA one (1e-5 minutes).
        assert!(
            (r.lat_deg - lat).abs() < 1e-7 && (r.lon_deg - lon).abs() < 1e-7,
            "epoch {k}: {r:?}"
        );
        assert!(
            (r.tow_s - (216_000.0 + k as f64 * 0.1)).abs() < 1e-9,
            "{r:?}"
        );
        assert_eq!(r.hdop, 0.8, "epoch {k}: HDOP from the GGA: {r:?}");
        assert_eq!(r.pdop, 1.2, "epoch {k}: PDOP from NAV-PVT: {r:?}");
    }
    assert!(
        rows.windows(2)
            .all(|w| w[1].utc_ns - w[0].utc_ns == 100_000_000),
        "one epoch every 100 ms: {rows:?}"
    );
    assert!(rows.windows(2).all(|w| w[0].t_mono_ns <= w[1].t_mono_ns));
    assert!(
        events_of(&store, "gnss", EventKind::Resync).is_empty(),
        "{:?}",
        store.events
    );
}

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn can_imu_over_slcan_on_a_pty_decodes_through_the_dbc() {
    let dir = tempfile::tempdir().unwrap();
    let mut pty = Pty::open();
    let devices = format!(
        "[[device]]\nname = \"canimu\"\nprotocol = \"can-dbc\"\nrate_hz = 100\n\
         slcan = {{ port = \"{}\", baud = 115200, bitrate = 500000 }}\n\
         dbc = {{ file = \"{}\", mapping = \"{}\" }}\n",
        pty.slave_path.display(),
        fixtures().join("imu_can.dbc").display(),
        fixtures().join("imu_can_mapping.toml").display()
    );
    let dbc_text = std::fs::read_to_string(fixtures().join("imu_can.dbc")).unwrap();
    let mapping = DbcImuMapping::from_toml_str(
        &std::fs::read_to_string(fixtures().join("imu_can_mapping.toml")).unwrap(),
    )
    .unwrap();
    let imu = DbcImu::new(&dbc_text, &mapping).unwrap();
    let daemon = start(config(dir.path(), &devices));
    let (pty, handshake) = tokio::task::spawn_blocking(move || {
        // Close, bitrate, open: as a real adapter, answer each with OK.
        let handshake = pty.answer_slcan_commands(3);
        for seq in 0..SAMPLES {
            let sample = imulab_drivers::ImuSample {
                sensor_time: Some(seq as f64 * 0.01),
                gyro: Some(gyro_of(3, seq)),
                accel: Some(accel_of(3, seq)),
                temp_c: Some(temp_of(seq)),
                status: (seq % 4) as u32,
            };
            let mut bytes = Vec::new();
            for frame in imu.encode(&sample).unwrap() {
                let message = SlcanMessage::Frame {
                    frame,
                    timestamp_ms: None,
                };
                SlcanEncoder.encode(&message, &mut bytes).unwrap();
            }
            if seq == 30 {
                bytes.extend_from_slice(b"t18\r"); // a truncated frame line
            }
            pty.write(&bytes);
            std::thread::sleep(Duration::from_millis(3));
        }
        std::thread::sleep(Duration::from_millis(200));
        (pty, handshake)
    })
    .await
    .unwrap();
    let store = daemon.stop().await;
    drop(pty);
    assert_eq!(
        handshake, "C\rS6\rO\r",
        "the adapter is opened at 500 kbit/s"
    );
    // 0.01 °/s and 0.0005 g per count.
    let gyro_tol = 0.005f64.to_radians() + 1e-12;
    let accel_tol = 0.00025 * 9.80665 + 1e-12;
    let rows = &store.imu["canimu"];
    check_rows(
        "canimu",
        rows,
        3,
        0..SAMPLES,
        |s| s as f64 * 0.01,
        gyro_tol,
        accel_tol,
    );
    for (seq, row) in rows.iter().enumerate() {
        assert_eq!(row.status, (seq % 4) as u32);
        assert!((row.temp - temp_of(seq as u64)).abs() <= 0.005 + 1e-9);
    }
    let bad = events_of(&store, "canimu", EventKind::Resync);
    assert_eq!(
        bad.len(),
        1,
        "the truncated line is reported: {:?}",
        store.events
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_serial_device_that_never_exists_is_an_error_in_the_status() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("imu-never-plugged");
    let devices = format!(
        "[[device]]\nname = \"ghost\"\nprotocol = \"wit\"\nrate_hz = 100\nretry_initial_ms = 20\nretry_max_ms = 100\n\
         serial = {{ port = \"{}\" }}\n",
        missing.display()
    );
    let daemon = start(config(dir.path(), &devices));
    tokio::time::sleep(Duration::from_millis(1300)).await;
    let status = read_status_file(&daemon.status_path).expect("status file written");
    let ghost = &status.devices[0];
    assert_eq!(ghost.state, DeviceState::Absent, "{ghost:?}");
    let error = ghost.last_error.clone().unwrap_or_default();
    assert!(error.contains("imu-never-plugged"), "{error}");
    let store = daemon.stop().await;
    assert!(store.imu.get("ghost").is_none_or(|r| r.is_empty()));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tcp_device_is_read_through_the_drivers_tcp_transport() {
    let dir = tempfile::tempdir().unwrap();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let address = listener.local_addr().unwrap();
    let devices = format!(
        "[[device]]\nname = \"ser2net\"\nprotocol = \"wit\"\nrate_hz = 100\ntcp = {{ address = \"{address}\" }}\n"
    );
    let daemon = start(config(dir.path(), &devices));
    let (mut socket, _) = tokio::time::timeout(Duration::from_secs(5), listener.accept())
        .await
        .expect("the daemon connects")
        .unwrap();
    use tokio::io::AsyncWriteExt;
    for seq in 0..SAMPLES {
        socket.write_all(&wit_sample(seq)).await.unwrap();
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    let store = daemon.stop().await;
    drop(socket);
    let wit_gyro = 2000f64.to_radians() / 32768.0 / 2.0 + 1e-12;
    let wit_accel = 16.0 * 9.80665 / 32768.0 / 2.0 + 1e-12;
    check_rows(
        "ser2net",
        &store.imu["ser2net"],
        0,
        0..SAMPLES,
        |s| s as f64 * 0.01,
        wit_gyro,
        wit_accel,
    );
}
