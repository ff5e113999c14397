//! The real `imulogd` binary logging a WitMotion IMU on a pty into an HDF5 session:
//! SIGTERM closes every file cleanly and exits 0 within 2 s; SIGKILL mid-run, then
//! `imulab recover`, loses at most one flush interval of samples.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::common::daemon::connected_report;
use crate::common::encode::wit_sample;
use crate::common::pty::Pty;
use imulab::store::{Session, TimeRange};
use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;

const FLUSH_MS: u64 = 200;
const RATE_HZ: u64 = 200;

struct Logging {
    child: Child,
    session_dir: PathBuf,
    sent: Arc<AtomicU64>,
    keep_sending: Arc<AtomicBool>,
    sender: std::thread::JoinHandle<Pty>,
}

/// Starts `imulogd` on a config for one WitMotion IMU on a fresh pty, waits until it logs,
/// and streams samples at [`RATE_HZ`] until told to stop.
fn start_logging(dir: &Path) -> Logging {
    let mut pty = Pty::open();
    let config = dir.join("imulogd.toml");
    std::fs::write(
        &config,
        format!(
            "[session]\noutput_dir = \"{}\"\nname = \"run\"\nflush_interval_ms = {FLUSH_MS}\ndisk_reserve_mb = 1\n\
             [[device]]\nname = \"imu\"\nprotocol = \"wit\"\nrate_hz = {RATE_HZ}\nserial = {{ port = \"{}\" }}\n",
            dir.display(),
            pty.slave_path.display()
        ),
    )
    .unwrap();
    let child = Command::new(env!("CARGO_BIN_EXE_imulogd"))
        .arg("--config")
        .arg(&config)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("imulogd starts");
    let status_path = dir.join("imulogd-status.json");
    let t = Instant::now();
    let session_dir = loop {
        if let Some(dir) = connected_report(&status_path, 1).and_then(|r| r.session_dir) {
            break dir;
        }
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "imulogd did not open the pty"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let sent = Arc::new(AtomicU64::new(0));
    let keep_sending = Arc::new(AtomicBool::new(true));
    let sender = {
        let (sent, keep_sending) = (sent.clone(), keep_sending.clone());
        std::thread::spawn(move || {
            let start = Instant::now();
            let mut seq = 0u64;
            while keep_sending.load(Ordering::SeqCst) {
                pty.write(&wit_sample(seq));
                seq += 1;
                sent.store(seq, Ordering::SeqCst);
                // On schedule, not sleep-accumulated.
                let next = start + Duration::from_micros(seq * 1_000_000 / RATE_HZ);
                std::thread::sleep(next.saturating_duration_since(Instant::now()));
            }
            pty
        })
    };
    Logging {
        child,
        session_dir,
        sent,
        keep_sending,
        sender,
    }
}

/// The sensor-time sequence numbers in the session (time of day = seq × 10 ms).
fn logged_seqs(session_dir: &Path) -> Vec<u64> {
    let session = Session::open(session_dir).expect("the session opens");
    assert!(session.problems().is_empty(), "{:?}", session.problems());
    let mut seqs = Vec::new();
    for block in session.imu_blocks("imu", TimeRange::all(), 256).unwrap() {
        let block = block.unwrap();
        seqs.extend(block.t_sensor.iter().map(|t| (t * 100.0).round() as u64));
    }
    seqs
}

#[test]
fn sigterm_closes_every_file_and_exits_0_within_2_s() {
    let dir = tempfile::tempdir().unwrap();
    let mut logging = start_logging(dir.path());
    std::thread::sleep(Duration::from_millis(700));
    logging.keep_sending.store(false, Ordering::SeqCst);
    let pty = logging.sender.join().unwrap();
    let sent = logging.sent.load(Ordering::SeqCst);
    std::thread::sleep(Duration::from_millis(100));

    let t = Instant::now();
    kill(Pid::from_raw(logging.child.id() as i32), Signal::SIGTERM).unwrap();
    let status = loop {
        if let Some(status) = logging.child.try_wait().unwrap() {
            break status;
        }
        if t.elapsed() > Duration::from_secs(3) {
            let _ = logging.child.kill();
            panic!("imulogd did not exit within 3 s of SIGTERM");
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let took = t.elapsed();
    drop(pty);
    assert_eq!(status.code(), Some(0), "{status:?}");
    assert!(took < Duration::from_secs(2), "exit took {took:?}");

    let session = Session::open(&logging.session_dir).unwrap();
    assert!(
        session.files().iter().all(|f| !f.partial),
        "every chunk file closed and renamed: {:?}",
        session.files()
    );
    assert_eq!(
        logged_seqs(&logging.session_dir),
        (0..sent).collect::<Vec<_>>(),
        "every sample sent is in the session"
    );
}

#[test]
fn sigkill_then_recover_loses_at_most_one_flush_interval() {
    let dir = tempfile::tempdir().unwrap();
    let mut logging = start_logging(dir.path());
    std::thread::sleep(Duration::from_millis(1100));
    // Mid-stream: the sender keeps going while the daemon dies.
    let sent_at_kill = logging.sent.load(Ordering::SeqCst);
    logging.child.kill().unwrap(); // SIGKILL
    logging.child.wait().unwrap();
    logging.keep_sending.store(false, Ordering::SeqCst);
    drop(logging.sender.join().unwrap());

    let recover = Command::new(env!("CARGO_BIN_EXE_imulab"))
        .arg("recover")
        .arg(&logging.session_dir)
        .output()
        .expect("imulab recover runs");
    assert!(
        recover.status.success(),
        "{}",
        String::from_utf8_lossy(&recover.stderr)
    );
    let seqs = logged_seqs(&logging.session_dir);
    let count = seqs.len() as u64;
    assert_eq!(
        seqs,
        (0..count).collect::<Vec<_>>(),
        "what survived is the start of the stream, without holes"
    );
    // One flush interval of samples, and up to 45 ms of samples written to the pty that the
    // daemon had not read yet (or written after `sent` was read, before the signal landed):
    // never received, not lost. (The decoder holds no whole sample: each one is emitted on
    // its closing packet.)
    let allowed = FLUSH_MS * RATE_HZ / 1000 + 45 * RATE_HZ / 1000;
    let lost = sent_at_kill.saturating_sub(count);
    println!(
        "sent {sent_at_kill} before SIGKILL, {count} recovered, {lost} lost (allowed {allowed})"
    );
    assert!(
        lost <= allowed,
        "lost {lost} samples, more than one flush interval ({allowed})"
    );
    assert!(count > 0);
}
