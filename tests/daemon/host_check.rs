//! Configuration traps that only the host shows (a port used twice, an unusable
//! `output_dir`, a `status_file` over a foreign file, a disk already below the reserve),
//! through the real `imulogd` binary: `--check-config` refuses them, and so does a start,
//! before any session directory is created.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

const FIXTURES: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures");

fn serial_device(name: &str, port: &Path) -> String {
    format!(
        "[[device]]\nname = \"{name}\"\nprotocol = \"wit\"\nrate_hz = 100\nserial = {{ port = \"{}\" }}\n",
        port.display()
    )
}

fn can_device(name: &str) -> String {
    format!(
        "[[device]]\nname = \"{name}\"\nprotocol = \"can-dbc\"\nrate_hz = 100\ncan = {{ interface = \"vcan0\" }}\n\
         dbc = {{ file = \"{FIXTURES}/imu_can.dbc\", mapping = \"{FIXTURES}/imu_can_mapping.toml\" }}\n"
    )
}

/// Writes `imulogd.toml` in `dir` with the given `[session]` lines and devices.
fn write_config(dir: &Path, session: &str, devices: &str) -> PathBuf {
    let path = dir.join("imulogd.toml");
    std::fs::write(&path, format!("[session]\n{session}\n{devices}")).unwrap();
    path
}

fn imulogd(flag: &str, config: &Path) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_imulogd"))
        .arg(flag)
        .arg(config)
        .env("RUST_LOG", "error")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("imulogd starts");
    let t = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t.elapsed() > Duration::from_secs(10) {
            let _ = child.kill();
            panic!("imulogd {flag} did not exit within 10 s: it started instead of refusing");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// Both `--check-config` and a start refuse the config with exit 2 and every `needle` in
/// the message; the start creates nothing in `output_dir`.
fn assert_refused(config: &Path, output_dir: &Path, needles: &[&str]) {
    let before = list(output_dir);
    for flag in ["--check-config", "--config"] {
        let out = imulogd(flag, config);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "imulogd {flag}: {stderr}");
        for needle in needles {
            assert!(
                stderr.contains(needle),
                "imulogd {flag}: no `{needle}` in:\n{stderr}"
            );
        }
    }
    assert_eq!(list(output_dir), before, "a refused start created files");
}

fn list(dir: &Path) -> Vec<PathBuf> {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|r| r.map(|e| e.unwrap().path()).collect())
        .unwrap_or_default();
    entries.sort();
    entries
}

#[test]
fn two_devices_on_one_port_through_a_symlink_are_refused_naming_both() {
    let dir = tempfile::tempdir().unwrap();
    let port = dir.path().join("ttyUSB0");
    std::fs::write(&port, b"").unwrap();
    let link = dir.path().join("imu-A1B2");
    std::os::unix::fs::symlink(&port, &link).unwrap();
    let devices = serial_device("imu-a", &port) + &serial_device("imu-b", &link);
    let config = write_config(
        dir.path(),
        &format!("output_dir = \"{}\"", dir.path().display()),
        &devices,
    );
    assert_refused(
        &config,
        dir.path(),
        &[
            "device[1]",
            "`imu-a` (device[0]) and `imu-b` (device[1]) both use the port",
            "ttyUSB0",
        ],
    );
}

#[test]
fn two_can_devices_decoding_the_same_frames_are_refused_naming_both() {
    let dir = tempfile::tempdir().unwrap();
    let devices = can_device("can-a") + &can_device("can-b");
    let config = write_config(
        dir.path(),
        &format!("output_dir = \"{}\"", dir.path().display()),
        &devices,
    );
    assert_refused(
        &config,
        dir.path(),
        &["`can-a` (device[0]) and `can-b` (device[1]) both use the CAN interface vcan0"],
    );
}

#[test]
fn distinct_ports_are_accepted() {
    let dir = tempfile::tempdir().unwrap();
    let devices = serial_device("imu-a", &dir.path().join("ttyUSB0"))
        + &serial_device("imu-b", &dir.path().join("ttyUSB1"));
    let config = write_config(
        dir.path(),
        &format!("output_dir = \"{}\"", dir.path().display()),
        &devices,
    );
    let out = imulogd("--check-config", &config);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn output_dir_that_is_a_file_or_under_a_file_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("not-a-dir");
    std::fs::write(&file, b"data").unwrap();
    let device = serial_device("imu-a", &dir.path().join("ttyUSB0"));
    let config = write_config(
        dir.path(),
        &format!("output_dir = \"{}\"", file.display()),
        &device,
    );
    assert_refused(
        &config,
        dir.path(),
        &["session.output_dir", "is not a directory"],
    );
    // Under a regular file nothing can be created, not even by root.
    let under = file.join("sessions/bench");
    let config = write_config(
        dir.path(),
        &format!("output_dir = \"{}\"", under.display()),
        &device,
    );
    assert_refused(
        &config,
        dir.path(),
        &[
            "session.output_dir",
            "cannot be created",
            "not-a-dir is not a directory",
        ],
    );
    assert_eq!(std::fs::read(&file).unwrap(), b"data");
}

#[test]
fn missing_output_dir_with_a_usable_parent_is_created_and_logged_into() {
    let dir = tempfile::tempdir().unwrap();
    let output_dir = dir.path().join("new/sessions");
    let device = serial_device("imu-a", &dir.path().join("ttyUSB0"));
    let config = write_config(
        dir.path(),
        &format!(
            "output_dir = \"{}\"\nname = \"run\"\ndisk_reserve_mb = 1",
            output_dir.display()
        ),
        &device,
    );
    let out = imulogd("--check-config", &config);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("does not exist and will be created"),
        "{stdout}"
    );
    assert!(!output_dir.exists(), "--check-config created the directory");

    // A real start creates it and writes the session and the status file there.
    let mut child = Command::new(env!("CARGO_BIN_EXE_imulogd"))
        .arg("--config")
        .arg(&config)
        .env("RUST_LOG", "error")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let status = output_dir.join("imulogd-status.json");
    let t = Instant::now();
    while !status.exists() && t.elapsed() < Duration::from_secs(10) {
        std::thread::sleep(Duration::from_millis(50));
    }
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(child.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .unwrap();
    let exit = child.wait().unwrap();
    assert!(status.exists(), "no status file in the created output_dir");
    assert_eq!(exit.code(), Some(0));
    assert!(
        output_dir.join("run").is_dir(),
        "no session in {}",
        output_dir.display()
    );
}

#[test]
fn status_file_over_a_foreign_file_is_refused_and_the_file_kept() {
    let dir = tempfile::tempdir().unwrap();
    let foreign = dir.path().join("notes.json");
    std::fs::write(&foreign, b"{\"keep\": \"me\"}\n").unwrap();
    let device = serial_device("imu-a", &dir.path().join("ttyUSB0"));
    let config = write_config(
        dir.path(),
        &format!(
            "output_dir = \"{}\"\nstatus_file = \"{}\"",
            dir.path().join("sessions").display(),
            foreign.display()
        ),
        &device,
    );
    assert_refused(
        &config,
        dir.path(),
        &[
            "session.status_file",
            "refusing to replace",
            "notes.json",
            "not an imulogd status file",
        ],
    );
    assert_eq!(std::fs::read(&foreign).unwrap(), b"{\"keep\": \"me\"}\n");
}

#[test]
fn status_file_under_a_regular_file_is_refused_and_a_missing_directory_created() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("not-a-dir");
    std::fs::write(&file, b"data").unwrap();
    let device = serial_device("imu-a", &dir.path().join("ttyUSB0"));
    let session = |status: &Path| {
        format!(
            "output_dir = \"{}\"\nstatus_file = \"{}\"",
            dir.path().display(),
            status.display()
        )
    };
    let config = write_config(dir.path(), &session(&file.join("status.json")), &device);
    assert_refused(
        &config,
        dir.path(),
        &["session.status_file", "not-a-dir is not a directory"],
    );
    let config = write_config(
        dir.path(),
        &session(&dir.path().join("run/imulogd/status.json")),
        &device,
    );
    let out = imulogd("--check-config", &config);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("its directory does not exist and will be created"),
        "{stdout}"
    );
}

#[test]
fn a_disk_below_the_reserve_at_start_creates_no_session() {
    let dir = tempfile::tempdir().unwrap();
    let output_dir = dir.path().join("sessions");
    std::fs::create_dir(&output_dir).unwrap();
    let device = serial_device("imu-a", &dir.path().join("ttyUSB0"));
    // 1 EiB: more than any test machine has free.
    let config = write_config(
        dir.path(),
        &format!(
            "output_dir = \"{}\"\nname = \"run\"\ndisk_reserve_mb = 1099511627776",
            output_dir.display()
        ),
        &device,
    );
    let out = imulogd("--config", &config);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{stderr}");
    assert!(stderr.contains("below the disk reserve"), "{stderr}");
    assert!(stderr.contains("no session was created"), "{stderr}");
    assert_eq!(
        list(&output_dir),
        Vec::<PathBuf>::new(),
        "a session was created"
    );
}

#[test]
fn a_reserve_below_what_one_check_interval_can_write_is_refused_with_the_floor() {
    let dir = tempfile::tempdir().unwrap();
    let device = format!(
        "[[device]]\nname = \"imu-a\"\nprotocol = \"wit\"\nrate_hz = 100\nserial = {{ port = \"{}\", baud = 921600 }}\n",
        dir.path().join("ttyUSB0").display()
    );
    // 60 s between flushes of raw bytes at 921600 baud (92160 B/s) and 100 rows/s, each
    // row in the HDF5 file and in the journal.
    let row = std::mem::size_of::<imulab::store::ImuRecord>() as f64;
    let floor = (((92_160.0 + 2.0 * 100.0 * row) * 60.0) / f64::from(1u32 << 20)).ceil() as u64;
    assert!(floor >= 6, "{floor}");
    let session = |reserve: u64| {
        format!(
            "output_dir = \"{}\"\nflush_interval_ms = 60000\nraw_journal = true\ndisk_reserve_mb = {reserve}",
            dir.path().display()
        )
    };
    for reserve in [0, floor - 1] {
        let config = write_config(dir.path(), &session(reserve), &device);
        assert_refused(
            &config,
            dir.path(),
            &[
                "session.disk_reserve_mb",
                &format!("{reserve} MB is less than the {floor} MB"),
                &format!("use at least {floor}"),
            ],
        );
    }
    let config = write_config(dir.path(), &session(floor), &device);
    let out = imulogd("--check-config", &config);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A replay's speed-up is part of the floor: a capture played at 50× its recorded pace can
/// write 50 times what its rate says, and `pace = "fast"` (no rate at all) needs the reserve
/// the writer's check by volume takes.
#[test]
fn a_replay_faster_than_recorded_raises_the_reserve_floor() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("wit.bin");
    std::fs::write(&capture, [0x55u8; 64]).unwrap();
    let device = |pace: &str| {
        format!(
            "[[device]]\nname = \"imu-a\"\nprotocol = \"wit\"\nrate_hz = 1000\n\
             file = {{ path = \"{}\", baud = 921600, pace = {pace} }}\n",
            capture.display()
        )
    };
    let session = |reserve: u64| {
        format!(
            "output_dir = \"{}\"\nraw_journal = true\ndisk_reserve_mb = {reserve}",
            dir.path().display()
        )
    };
    // 1000 rows/s (HDF5 and journal) and 92160 raw bytes/s over the 1 s check interval.
    let row = std::mem::size_of::<imulab::store::ImuRecord>() as f64;
    let per_s = 92_160.0 + 2.0 * 1000.0 * row;
    let mib = f64::from(1u32 << 20);
    let at_recorded = (per_s / mib).ceil() as u64;
    let at_50 = (50.0 * per_s / mib).ceil() as u64;
    assert!(at_50 > 2 * at_recorded, "{at_recorded} {at_50}");
    for (pace, floor) in [("\"recorded\"", at_recorded), ("50", at_50)] {
        let config = write_config(dir.path(), &session(floor - 1), &device(pace));
        assert_refused(
            &config,
            dir.path(),
            &[
                "session.disk_reserve_mb",
                &format!("{} MB is less than the {floor} MB", floor - 1),
                "times each replay's pace factor",
            ],
        );
        let config = write_config(dir.path(), &session(floor), &device(pace));
        let out = imulogd("--check-config", &config);
        assert!(
            out.status.success(),
            "pace {pace}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    // As fast as the writer goes: no rate bounds it, the volume check does.
    let config = write_config(dir.path(), &session(1), &device("\"fast\""));
    let out = imulogd("--check-config", &config);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("1 MB is less than the") && stderr.contains("pace = \"fast\" replay"),
        "{stderr}"
    );
    let floor: u64 = stderr
        .split("use at least ")
        .nth(1)
        .and_then(|r| r.split(':').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no floor in {stderr}"));
    assert!(floor > 1, "{stderr}");
    let config = write_config(dir.path(), &session(floor), &device("\"fast\""));
    let out = imulogd("--check-config", &config);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
