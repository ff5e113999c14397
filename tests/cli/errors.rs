//! Every error a user can cause says what happened and what to do, in one or two lines,
//! with a non-zero exit and no panic: wrong paths, wrong protocols, a serial port in use by
//! another process, a serial port without permission, and a session still being written.
//!
//! The port tests need a second, unprivileged user: root opens a pty even when another
//! process holds it exclusively (CAP_SYS_ADMIN) and ignores file modes, so when the tests
//! run as root the child runs as `nobody` through `setpriv`, and the tests are skipped with a
//! reason when that is not possible.

use std::io::{BufRead, BufReader};
use std::os::fd::AsRawFd;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use imulab::store::{DeviceInfo, DeviceKind, ImuRecord, Manifest, SessionWriter, WriterOptions};

const IMULAB: &str = env!("CARGO_BIN_EXE_imulab");
const IMULOGD: &str = env!("CARGO_BIN_EXE_imulogd");
const NOBODY: &str = "65534";

fn imulab(args: &[&str]) -> Output {
    Command::new(IMULAB)
        .args(args)
        .output()
        .expect("run imulab")
}

/// The error text of a failed run, checked for the rules every message keeps: non-zero
/// exit, one or two lines after the program name, no panic or backtrace.
fn failure(out: &Output) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(
        !out.status.success(),
        "expected a failure, stderr: {stderr}"
    );
    assert_ne!(out.status.code(), Some(101), "panicked: {stderr}");
    assert!(
        !stderr.contains("panicked") && !stderr.contains("RUST_BACKTRACE"),
        "{stderr}"
    );
    let start = stderr
        .find("imulab: ")
        .or_else(|| stderr.find("imulogd: "))
        .unwrap_or_else(|| panic!("no `imulab:`/`imulogd:` message in: {stderr}"));
    let message = stderr[start..].trim_end().to_string();
    let lines = message.lines().count();
    assert!((1..=2).contains(&lines), "{lines} lines: {message}");
    message
}

fn assert_has(message: &str, parts: &[&str]) {
    for p in parts {
        assert!(message.contains(p), "`{p}` missing from: {message}");
    }
}

#[test]
fn wrong_paths() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no-such-run");
    let file = dir.path().join("notes.txt");
    std::fs::write(&file, "not a session\n").unwrap();
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let (missing, file, empty) = (
        missing.to_str().unwrap(),
        file.to_str().unwrap(),
        empty.to_str().unwrap(),
    );

    for cmd in ["inspect", "recover"] {
        let m = failure(&imulab(&[cmd, missing]));
        assert_has(&m, &[missing, "no such directory", "check the path"]);
    }
    let m = failure(&imulab(&[
        "export", missing, "--device", "a", "--format", "csv",
    ]));
    assert_has(&m, &[missing, "no such directory", "check the path"]);
    // `compare` takes sessions or files: a missing one is a missing file.
    let m = failure(&imulab(&["compare", missing, file]));
    assert_has(&m, &[missing, "No such file", "hint: check the path"]);
    // A file where a session directory is expected.
    let m = failure(&imulab(&["inspect", file]));
    assert_has(&m, &[file, "it is a file", "give the session directory"]);
    let m = failure(&imulab(&["inspect", empty]));
    assert_has(
        &m,
        &[empty, "no session.toml", "give a session's own directory"],
    );
    // Input files of the analyses and of decode.
    let csv = format!("{missing}.csv");
    let m = failure(&imulab(&["allan", &csv]));
    assert_has(&m, &[&csv, "No such file", "hint: check the path"]);
    assert_eq!(m.matches("No such file").count(), 1, "said twice: {m}");
    let m = failure(&imulab(&["decode", &csv]));
    assert_has(&m, &[&csv, "No such file", "hint: check the path"]);
    let m = failure(&imulab(&["sim", &format!("{missing}.toml"), "-o", missing]));
    assert_has(&m, &["No such file", "hint: check the path"]);
    // The daemon's configuration: missing, and a directory.
    let out = Command::new(IMULOGD)
        .args(["--check-config", &format!("{missing}.toml")])
        .output()
        .unwrap();
    let m = failure(&out);
    assert_has(
        &m,
        &["cannot read the file", "give the path of an existing"],
    );
    let out = Command::new(IMULOGD)
        .args(["--config", empty])
        .output()
        .unwrap();
    let m = failure(&out);
    assert_has(&m, &[empty, "give the path of an existing"]);
}

#[test]
fn wrong_protocols() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("capture.log");
    let mut nmea = Vec::new();
    for i in 0..50 {
        let body = format!("GPHDT,{}.5,T", 100 + i);
        let sum = body.bytes().fold(0u8, |a, b| a ^ b);
        nmea.extend_from_slice(format!("${body}*{sum:02X}\r\n").as_bytes());
    }
    std::fs::write(&capture, &nmea).unwrap();
    let capture = capture.to_str().unwrap();

    // Sanity: the capture itself decodes, so the failures below are the protocol's fault.
    let out = imulab(&["decode", capture, "--quiet"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    let m = failure(&imulab(&["decode", capture, "--protocol", "nope"]));
    assert_has(&m, &["unknown protocol `nope`", "nmea", "ubx", "`auto`"]);
    // The right bytes decoded with the wrong protocol: nothing comes out.
    let m = failure(&imulab(&[
        "decode",
        capture,
        "--protocol",
        "ubx",
        "--quiet",
    ]));
    assert_has(&m, &["no frames decoded", "try --protocol auto"]);

    // A daemon configuration naming an unknown protocol.
    let config = dir.path().join("imulogd.toml");
    std::fs::write(
        &config,
        format!(
            "[session]\noutput_dir = \"{}\"\n\n[[device]]\nname = \"imu\"\nprotocol = \"nope\"\n\
             rate_hz = 100\nserial = {{ port = \"/dev/ttyUSB0\", baud = 115200 }}\n",
            dir.path().display()
        ),
    )
    .unwrap();
    for flag in ["--check-config", "--config"] {
        let out = Command::new(IMULOGD)
            .arg(flag)
            .arg(&config)
            .output()
            .unwrap();
        let m = failure(&out);
        assert_eq!(out.status.code(), Some(2), "{m}");
        assert_has(&m, &["device[0].protocol", "nope", "allowed:", "ubx"]);
    }
}

/// A pty pair; the slave's path is what a user would give as the port.
struct Pty {
    _master: std::os::fd::OwnedFd,
    slave: std::fs::File,
    path: PathBuf,
}

fn open_pty(mode: u32) -> Pty {
    let pty = nix::pty::openpty(None, None).expect("openpty");
    let path = std::fs::read_link(format!("/proc/self/fd/{}", pty.slave.as_raw_fd()))
        .expect("pty slave path");
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(mode)).expect("chmod pty");
    Pty {
        _master: pty.master,
        slave: std::fs::File::from(pty.slave),
        path,
    }
}

/// A command that runs `program` as an unprivileged user, or why that cannot be done here.
fn unprivileged(program: &str) -> Result<Command, String> {
    if !is_root() {
        return Ok(Command::new(program));
    }
    let args = [
        &format!("--reuid={NOBODY}"),
        &format!("--regid={NOBODY}"),
        "--clear-groups",
        "--",
    ];
    let probe = Command::new("setpriv")
        .args(args)
        .args(["test", "-x", program])
        .status();
    match probe {
        Ok(s) if s.success() => {
            let mut cmd = Command::new("setpriv");
            cmd.args(args).arg(program);
            Ok(cmd)
        }
        Ok(_) => Err(format!(
            "user {NOBODY} cannot run {program} (a directory on its path is private)"
        )),
        Err(e) => Err(format!(
            "setpriv is not available ({e}); install util-linux"
        )),
    }
}

fn is_root() -> bool {
    // SAFETY: geteuid has no preconditions and cannot fail.
    unsafe { libc::geteuid() == 0 }
}

fn skip(test: &str, why: &str) {
    eprintln!("skipped {test}: {why}");
}

/// Runs imulogd with one serial device on `port` until its stderr holds `needle` (or 20 s
/// pass), stops it with SIGTERM, and returns what it printed.
fn imulogd_until(mut cmd: Command, dir: &Path, port: &Path, needle: &str) -> String {
    std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o777)).unwrap();
    let config = dir.join("imulogd.toml");
    std::fs::write(
        &config,
        format!(
            "[session]\noutput_dir = \"{d}/sessions\"\nstatus_file = \"{d}/status.json\"\n\n\
             [[device]]\nname = \"imu\"\nprotocol = \"wit\"\nrate_hz = 100\n\
             serial = {{ port = \"{p}\", baud = 115200 }}\n",
            d = dir.display(),
            p = port.display()
        ),
    )
    .unwrap();
    std::fs::set_permissions(&config, std::fs::Permissions::from_mode(0o644)).unwrap();
    let mut child = cmd
        .arg("--config")
        .arg(&config)
        .env("NO_COLOR", "1")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start imulogd");
    let pid = nix::unistd::Pid::from_raw(child.id() as i32);
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let mut seen = String::new();
    let deadline = Instant::now() + Duration::from_secs(20);
    while Instant::now() < deadline && !seen.contains(needle) {
        if let Ok(line) = rx.recv_timeout(Duration::from_millis(200)) {
            seen.push_str(&line);
            seen.push('\n');
        }
    }
    // setpriv execs imulogd, so the child's pid is the daemon's.
    let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
    let status = child.wait().unwrap();
    while let Ok(line) = rx.recv_timeout(Duration::from_millis(200)) {
        seen.push_str(&line);
        seen.push('\n');
    }
    assert!(!seen.contains("panicked"), "{seen}");
    assert_ne!(status.code(), Some(101), "{seen}");
    seen
}

/// `imulab decode` and then `imulogd` open `pty` as an unprivileged user: `imulab` must fail
/// and imulogd log (until `needle` shows) with every one of `decode_parts` / `daemon_parts`
/// in the message. Skipped, with the reason, when no unprivileged user can run them.
fn both_binaries_explain(
    test: &str,
    pty: &Pty,
    needle: &str,
    decode_parts: &[&str],
    daemon_parts: &[&str],
) {
    let port = pty.path.to_str().unwrap();
    let mut cmd = match unprivileged(IMULAB) {
        Ok(c) => c,
        Err(why) => return skip(test, &why),
    };
    let out = cmd
        .args(["decode", port, "--duration", "1"])
        .output()
        .unwrap();
    assert_has(&failure(&out), decode_parts);

    let dir = tempfile::tempdir().unwrap();
    let cmd = unprivileged(IMULOGD).unwrap();
    let log = imulogd_until(cmd, dir.path(), &pty.path, needle);
    assert_has(&log, daemon_parts);
}

#[test]
fn port_in_use_by_another_process() {
    let pty = open_pty(0o666);
    // SAFETY: TIOCEXCL takes no argument; the fd is open for the whole test.
    let rc = unsafe { libc::ioctl(pty.slave.as_raw_fd(), libc::TIOCEXCL) };
    assert_eq!(rc, 0, "TIOCEXCL: {}", std::io::Error::last_os_error());
    let port = pty.path.to_str().unwrap();
    let parts = [port, "in use by another process", &format!("fuser {port}")];
    both_binaries_explain(
        "port_in_use_by_another_process",
        &pty,
        "in use by another process",
        &parts,
        &parts,
    );
}

#[test]
fn serial_port_without_permission() {
    if !is_root() {
        // Without root the test cannot hand the port to another user; a port this user may
        // not open is all it needs.
        return skip(
            "serial_port_without_permission",
            "needs root to make a pty another user cannot open",
        );
    }
    let pty = open_pty(0o600);
    let port = pty.path.to_str().unwrap();
    both_binaries_explain(
        "serial_port_without_permission",
        &pty,
        "dialout",
        &[
            port,
            "permission denied",
            "sudo usermod -aG dialout $USER",
            "log in again",
        ],
        &[port, "permission denied", "sudo usermod -aG dialout $USER"],
    );
}

fn write_rows(writer: &mut SessionWriter, from: usize, to: usize) {
    let rows: Vec<ImuRecord> = (from..to)
        .map(|i| ImuRecord {
            t_mono_ns: 1_000_000_000 + i as i64 * 10_000_000,
            t_wall_ns: 1_700_000_000_000_000_000 + i as i64 * 10_000_000,
            t_sensor: i as f64,
            gyro: [1e-3, 0.0, 0.0],
            accel: [0.0, 0.0, -9.81],
            temp: 25.0,
            status: 0,
        })
        .collect();
    writer.append_imu("imu0", &rows).unwrap();
}

fn session_writer(dir: &Path) -> SessionWriter {
    let device = DeviceInfo {
        name: "imu0".into(),
        kind: DeviceKind::Imu,
        model: "test".into(),
        serial: String::new(),
        port: "sim".into(),
        protocol: "sim".into(),
        rate_hz: 100.0,
        axis_frame: "FRD".into(),
        extra: Default::default(),
    };
    let options = WriterOptions {
        fsync_on_flush: false,
        ..WriterOptions::default()
    };
    SessionWriter::create(
        dir,
        Manifest::new(vec![device], toml::Table::new()),
        options,
    )
    .unwrap()
}

#[test]
fn session_still_being_written() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("live");
    let mut writer = session_writer(&dir);
    write_rows(&mut writer, 0, 500);
    writer.flush().unwrap();
    let d = dir.to_str().unwrap();

    // Reading a live session works and says it is live.
    let out = imulab(&["export", d, "--device", "imu0", "--format", "csv"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert_has(
        &stderr,
        &["still being written", "what it has flushed so far"],
    );
    assert_eq!(String::from_utf8_lossy(&out.stdout).lines().count(), 501);
    // Recovering it is refused with what to do instead.
    let m = failure(&imulab(&["recover", d]));
    assert_has(
        &m,
        &[
            "still being written",
            "closed chunk files are readable now",
            "Stop the writer",
            "crashed",
        ],
    );
    writer.close().unwrap();
    let out = imulab(&["inspect", d]);
    assert!(out.status.success());
    assert!(!String::from_utf8_lossy(&out.stderr).contains("still being written"));
}

#[test]
fn partial_file_of_a_live_writer() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("run");
    let mut writer = session_writer(&dir);
    write_rows(&mut writer, 0, 300);
    writer.close().unwrap();
    // The next chunk as a writer has just created it: not readable yet.
    std::fs::write(dir.join("chunk-000001.h5.partial"), b"\x89HDF\r\n").unwrap();
    let lock = std::fs::File::create(dir.join("writer.lock")).unwrap();
    let lock = nix::fcntl::Flock::lock(lock, nix::fcntl::FlockArg::LockExclusiveNonblock)
        .map_err(|(_, e)| e)
        .unwrap();
    let d = dir.to_str().unwrap();
    let m = failure(&imulab(&[
        "export", d, "--device", "imu0", "--format", "csv",
    ]));
    assert_has(
        &m,
        &[
            "chunk-000001.h5.partial",
            "still being written",
            "closed chunk files are readable now",
            "wait for the writer to close this one",
            &format!("imulab recover {d}"),
        ],
    );
    // Once the writer is gone (crash), the same file is the one `recover` is for.
    drop(lock);
    let m = failure(&imulab(&[
        "export", d, "--device", "imu0", "--format", "csv",
    ]));
    assert_has(
        &m,
        &[
            "chunk-000001.h5.partial",
            "stopped without closing it",
            &format!("imulab recover {d}"),
        ],
    );
    assert!(!m.contains("still being written"), "{m}");
}

/// The rendering itself: a source repeated in its wrapper's text is printed once.
#[test]
fn repeated_source_text_is_printed_once() {
    #[derive(Debug, thiserror::Error)]
    #[error("data.csv: {0}")]
    struct Wrap(#[source] std::io::Error);
    let os = std::io::Error::from_raw_os_error(libc::ENOENT);
    let err = anyhow::Error::new(Wrap(os)).context("reading data.csv");
    let text = imulab::cli::errors::render(&err);
    assert_eq!(
        text.matches("No such file or directory").count(),
        1,
        "{text}"
    );
    assert!(
        text.starts_with("reading data.csv: data.csv: No such file"),
        "{text}"
    );
    assert!(text.contains("\nhint: check the path"), "{text}");
    assert_eq!(text.lines().count(), 2, "{text}");
}

#[test]
fn custom_texts_get_no_generic_hint() {
    let err = anyhow::Error::new(std::io::Error::new(
        std::io::ErrorKind::PermissionDenied,
        "permission denied; add yourself to the dialout group",
    ))
    .context("cannot open serial port `/dev/ttyUSB0`");
    assert_eq!(
        imulab::cli::errors::render(&err),
        "cannot open serial port `/dev/ttyUSB0`: permission denied; add yourself to the dialout group"
    );
}
