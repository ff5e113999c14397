//! A really full disk: the test mounts a small tmpfs (when it may: root or CAP_SYS_ADMIN;
//! skipped with the reason otherwise), points the session at it and streams fast until free
//! space falls under the reserve. The daemon must close the session cleanly, say why and exit
//! non-zero, and every chunk file must read back without problems.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::common::daemon::parts_for;
use crate::common::encode::wit_sample;
use crate::common::{encode_imu, LineDecoder, QueueConnector};
use imulab::daemon::config::{parse, CheckedConfig};
use imulab::daemon::session::open_session_sink;
use imulab::daemon::source::{Connector, DecoderFactory, FrameDecoder};
use imulab::daemon::{disk, run, DaemonParts, Outcome};
use imulab::store::{EventKind, Session, TimeRange};
use nix::mount::{mount, umount, MsFlags};
use tokio::io::AsyncWriteExt;

/// A tmpfs mounted for the test, unmounted when dropped.
struct SmallFs {
    dir: tempfile::TempDir,
}

impl SmallFs {
    fn mount(size_mib: u32) -> Result<Self, String> {
        let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
        let options = format!("size={size_mib}m");
        mount(
            Some("tmpfs"),
            dir.path(),
            Some("tmpfs"),
            MsFlags::MS_NOSUID | MsFlags::MS_NODEV,
            Some(options.as_str()),
        )
        .map_err(|e| format!("cannot mount a tmpfs ({e}); needs root or CAP_SYS_ADMIN"))?;
        Ok(SmallFs { dir })
    }

    fn path(&self) -> &Path {
        self.dir.path()
    }
}

impl Drop for SmallFs {
    fn drop(&mut self) {
        let _ = umount(self.dir.path());
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_filling_disk_stops_the_session_cleanly_with_exit_status_3() {
    let fs = match SmallFs::mount(10) {
        Ok(fs) => fs,
        Err(reason) => {
            println!("SKIPPED a_filling_disk_stops_the_session_cleanly: {reason}");
            return;
        }
    };
    let text = format!(
        "[session]\noutput_dir = \"{}\"\nflush_interval_ms = 100\nraw_journal = true\ndeflate_level = 0\n\
         disk_reserve_mb = 6\n\
         [[device]]\nname = \"imu\"\nprotocol = \"csv\"\nrate_hz = 10000\nserial = {{ port = \"/dev/imu\" }}\n",
        fs.path().display()
    );
    let config = parse(&text, "test").unwrap_or_else(|e| panic!("{e}"));
    let session_dir: PathBuf = fs.path().join("session");
    let sink = open_session_sink(&config, &session_dir).expect("session created");
    let imu = QueueConnector::default();
    let mut port = imu.plug();
    let decoders: DecoderFactory =
        Box::new(|| Box::new(LineDecoder::default()) as Box<dyn FrameDecoder>);
    let space_dir = session_dir.clone();
    let parts = DaemonParts {
        sink: Box::new(sink),
        session_dir: session_dir.clone(),
        connectors: vec![Box::new(imu) as Box<dyn Connector>],
        decoders: vec![decoders],
        free_space: Box::new(move || disk::free_bytes(&space_dir)),
        status_path: fs.path().join("status.json"),
    };
    let (_stop, stop_rx) = tokio::sync::watch::channel(false);
    let daemon = tokio::spawn(async move { run(&config, parts, stop_rx).await });
    // About 4 MB/s of rows and raw bytes: the 4 MiB above the reserve last ~1-2 s.
    let sender = tokio::spawn(async move {
        let mut seq = 0u64;
        loop {
            let mut burst = Vec::new();
            for _ in 0..250 {
                burst.extend_from_slice(&encode_imu(
                    seq,
                    [1e-3 * seq as f64, 0.0, 0.0],
                    [0.0, 0.0, 9.81],
                ));
                seq += 1;
            }
            if port.write_all(&burst).await.is_err() {
                break;
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    });
    let t = Instant::now();
    let outcome = tokio::time::timeout(Duration::from_secs(30), daemon)
        .await
        .expect("the daemon stops by itself")
        .unwrap();
    sender.abort();
    println!("stopped after {:?}: {outcome:?}", t.elapsed());
    let session = stopped_by_the_reserve(&outcome, &session_dir, "daemon");
    let mut rows = 0usize;
    let mut next = 0u64;
    for block in session.imu_blocks("imu", TimeRange::all(), 4096).unwrap() {
        let block = block.unwrap();
        for s in &block.t_sensor {
            assert_eq!(*s as u64, next, "rows are contiguous from 0");
            next += 1;
        }
        rows += block.len();
    }
    assert!(rows > 10_000, "{rows} rows");
    let (events, _) = session.events();
    let low: Vec<_> = events
        .iter()
        .filter(|e| e.kind == EventKind::DiskLow)
        .collect();
    assert_eq!(low.len(), 1, "{events:?}");
    assert!(
        low[0].detail.contains("below the reserve"),
        "{}",
        low[0].detail
    );
    let stop = events
        .iter()
        .find(|e| e.kind == EventKind::SessionStop)
        .unwrap();
    assert!(
        stop.detail.contains("disk reserve reached"),
        "{}",
        stop.detail
    );
}

/// The reserve check is fooled (free space reads as plenty) and the file system really fills
/// up: the daemon stops with exit status 3, says "disk full" once and points at `imulab
/// recover`; once space is freed, recover gives back the rows written, contiguous from the
/// first.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_disk_says_disk_full_once_and_the_session_recovers() {
    let fs = match SmallFs::mount(8) {
        Ok(fs) => fs,
        Err(reason) => {
            println!("SKIPPED a_full_disk_says_disk_full_once: {reason}");
            return;
        }
    };
    // All but ~1.5 MiB taken by a ballast file, freed after the run.
    let ballast = fs.path().join("ballast");
    std::fs::write(&ballast, vec![0u8; 6 << 20 | 512 << 10]).unwrap();
    let text = format!(
        "[session]\noutput_dir = \"{}\"\nflush_interval_ms = 100\nraw_journal = true\ndeflate_level = 0\n\
         disk_reserve_mb = 4\n\
         [[device]]\nname = \"imu\"\nprotocol = \"csv\"\nrate_hz = 10000\nserial = {{ port = \"/dev/imu\" }}\n",
        fs.path().display()
    );
    let config = parse(&text, "test").unwrap_or_else(|e| panic!("{e}"));
    let session_dir: PathBuf = fs.path().join("session");
    let sink = open_session_sink(&config, &session_dir).expect("session created");
    let imu = QueueConnector::default();
    let mut port = imu.plug();
    let decoders: DecoderFactory =
        Box::new(|| Box::new(LineDecoder::default()) as Box<dyn FrameDecoder>);
    let parts = DaemonParts {
        sink: Box::new(sink),
        session_dir: session_dir.clone(),
        connectors: vec![Box::new(imu) as Box<dyn Connector>],
        decoders: vec![decoders],
        // Lies: the reserve check never stops the session, ENOSPC does.
        free_space: Box::new(|| Ok(u64::MAX / 2)),
        status_path: fs.path().join("status.json"),
    };
    let (_stop, stop_rx) = tokio::sync::watch::channel(false);
    let daemon = tokio::spawn(async move { run(&config, parts, stop_rx).await });
    let sender = tokio::spawn(async move {
        let mut seq = 0u64;
        loop {
            let mut burst = Vec::new();
            for _ in 0..250 {
                burst.extend_from_slice(&encode_imu(
                    seq,
                    [1e-3 * seq as f64, 0.0, 0.0],
                    [0.0, 0.0, 9.81],
                ));
                seq += 1;
            }
            if port.write_all(&burst).await.is_err() {
                break;
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    });
    let outcome = tokio::time::timeout(Duration::from_secs(30), daemon)
        .await
        .expect("the daemon stops by itself")
        .unwrap();
    sender.abort();
    let message = outcome.message();
    println!("{message}");
    assert!(matches!(outcome, Outcome::DiskFull { .. }), "{outcome:?}");
    assert_eq!(outcome.exit_code(), 3);
    assert_eq!(message.matches("disk full").count(), 1, "{message}");
    assert!(!message.contains("No space left"), "said once: {message}");
    assert!(
        message.contains(&format!("imulab recover {}", session_dir.display())),
        "{message}"
    );

    std::fs::remove_file(&ballast).unwrap();
    let report = imulab::store::recover(&session_dir).unwrap_or_else(|e| panic!("{e}"));
    println!("{report:?}");
    let session = Session::open(&session_dir).expect("session opens");
    assert!(session.problems().is_empty(), "{:?}", session.problems());
    let mut next = 0u64;
    for block in session.imu_blocks("imu", TimeRange::all(), 4096).unwrap() {
        for s in &block.unwrap().t_sensor {
            assert_eq!(*s as u64, next, "rows are contiguous from 0");
            next += 1;
        }
    }
    println!("{next} rows recovered");
    assert!(next > 1000, "{next} rows");
}

/// A capture replayed as fast as the writer goes (`pace = "fast"`) onto a small file system:
/// the store's own allocation (HDF5 chunks and metadata, the journal's growth) must not carry
/// the session past the reserve into a full disk. It stops at the reserve with exit status 3,
/// closes cleanly and keeps every row written before the stop, in order.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fast_replay_stops_at_the_reserve_not_at_a_full_disk() {
    fast_replay_stops_at_the_reserve(true).await;
}

/// The same without the raw journal: the rows alone (HDF5 and the write-ahead journal) are
/// what fills the disk, and the reserve still stops the replay first.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fast_replay_without_the_raw_journal_stops_at_the_reserve() {
    fast_replay_stops_at_the_reserve(false).await;
}

/// A fast replay of WitMotion samples onto a 12 MiB tmpfs with a 4 MiB reserve: 200 000
/// with the raw journal, 600 000 without (200 000 rows alone fit above the reserve).
async fn fast_replay_stops_at_the_reserve(raw_journal: bool) {
    let fs = match SmallFs::mount(12) {
        Ok(fs) => fs,
        Err(reason) => {
            println!("SKIPPED a fast replay (raw_journal = {raw_journal}) stopped by the reserve: {reason}");
            return;
        }
    };
    // The capture lives off the small file system.
    let source_dir = tempfile::tempdir().unwrap();
    let samples = if raw_journal { 200_000u64 } else { 600_000 };
    let capture = write_wit_capture(source_dir.path(), samples);
    let config = replay_config(fs.path(), &capture, raw_journal, 100);
    let session_dir: PathBuf = fs.path().join("session");
    let t = Instant::now();
    let outcome = replay_onto(&config, &session_dir, fs.path()).await;
    println!("stopped after {:?}: {outcome:?}", t.elapsed());
    let session = stopped_by_the_reserve(&outcome, &session_dir, "replay");
    let rows = rows_in_capture_order(&session);
    println!("{rows} of {samples} rows kept (raw_journal = {raw_journal})");
    assert!(rows > 10_000 && rows < samples, "{rows} rows");
    let (events, _) = session.events();
    let low: Vec<_> = events
        .iter()
        .filter(|e| e.kind == EventKind::DiskLow)
        .collect();
    assert_eq!(low.len(), 1, "{events:?}");
    let stop = events
        .iter()
        .find(|e| e.kind == EventKind::SessionStop)
        .unwrap();
    assert!(
        stop.detail.contains("disk reserve reached"),
        "{}",
        stop.detail
    );
}

/// A short capture that fits above the reserve while it plays, but whose rows, written at
/// the end (the store holds a fast replay's chunks until then), leave less free space than
/// the reserve: the run has ended by itself, yet the session records the reserve stop, a
/// `disk_low` event, with every row of the capture, and the daemon exits with status 3 as
/// for any stop by the reserve (it would refuse to start another session there).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_capture_that_ends_below_the_reserve_is_recorded_as_a_reserve_stop() {
    let fs = match SmallFs::mount(16) {
        Ok(fs) => fs,
        Err(reason) => {
            println!("SKIPPED a_capture_that_ends_below_the_reserve: {reason}");
            return;
        }
    };
    let source_dir = tempfile::tempdir().unwrap();
    let samples = 4_000u64;
    let capture = write_wit_capture(source_dir.path(), samples);
    // A 1 s flush interval: the replay is over before the store writes anything.
    let config = replay_config(fs.path(), &capture, false, 1000);
    let reserve = config.session.disk_reserve_mb << 20;
    // What the whole session takes, from a first run on plenty of room.
    let trial = fs.path().join("trial");
    let free_before = disk::free_bytes(fs.path()).unwrap();
    let outcome = replay_onto(&config, &trial, fs.path()).await;
    assert_eq!(outcome.exit_code(), 0, "{outcome:?}");
    let session_bytes = free_before - disk::free_bytes(fs.path()).unwrap();
    std::fs::remove_dir_all(&trial).unwrap();
    // Leave the reserve and half of that.
    let free = disk::free_bytes(fs.path()).unwrap();
    let ballast = free - reserve - session_bytes / 2;
    std::fs::write(fs.path().join("ballast"), vec![0u8; ballast as usize]).unwrap();
    println!(
        "session of {session_bytes} bytes; {} bytes free above the reserve",
        disk::free_bytes(fs.path()).unwrap() - reserve
    );

    let session_dir = fs.path().join("session");
    let outcome = replay_onto(&config, &session_dir, fs.path()).await;
    println!("{outcome:?}: {}", outcome.message());
    let session = stopped_by_the_reserve(&outcome, &session_dir, "replay");
    assert_eq!(
        rows_in_capture_order(&session),
        samples,
        "every row is kept"
    );
    let (events, _) = session.events();
    let low: Vec<_> = events
        .iter()
        .filter(|e| e.kind == EventKind::DiskLow)
        .collect();
    assert_eq!(low.len(), 1, "{events:?}");
    assert!(
        low[0].detail.contains("below the reserve") && low[0].detail.contains("last batches"),
        "{}",
        low[0].detail
    );
    let stop = events.last().unwrap();
    assert_eq!(stop.kind, EventKind::SessionStop);
    assert!(
        stop.detail.contains("disk reserve reached"),
        "{}",
        stop.detail
    );
}

/// Writes `samples` WitMotion samples (10 ms apart) to `dir/wit.bin`.
fn write_wit_capture(dir: &Path, samples: u64) -> PathBuf {
    let capture = dir.join("wit.bin");
    let bytes: Vec<u8> = (0..samples).flat_map(wit_sample).collect();
    std::fs::write(&capture, &bytes).unwrap();
    capture
}

/// A session in `output_dir` with a 4 MiB reserve replaying `capture` as fast as it goes.
fn replay_config(
    output_dir: &Path,
    capture: &Path,
    raw_journal: bool,
    flush_interval_ms: u64,
) -> CheckedConfig {
    let text = format!(
        "[session]\noutput_dir = \"{}\"\nflush_interval_ms = {flush_interval_ms}\nraw_journal = {raw_journal}\n\
         disk_reserve_mb = 4\n\
         [[device]]\nname = \"imu\"\nprotocol = \"wit\"\nrate_hz = 100\n\
         file = {{ path = \"{}\", pace = \"fast\" }}\n",
        output_dir.display(),
        capture.display()
    );
    parse(&text, "test").unwrap_or_else(|e| panic!("{e}"))
}

/// Runs the daemon on `config` into `session_dir`, free space read from the file system,
/// until it stops by itself.
async fn replay_onto(config: &CheckedConfig, session_dir: &Path, status_dir: &Path) -> Outcome {
    let sink = Box::new(open_session_sink(config, session_dir).expect("session created"));
    let mut parts = parts_for(config, sink, session_dir.to_path_buf());
    let space_dir = session_dir.to_path_buf();
    parts.free_space = Box::new(move || disk::free_bytes(&space_dir));
    parts.status_path = status_dir.join("status.json");
    let (_stop, stop_rx) = tokio::sync::watch::channel(false);
    tokio::time::timeout(Duration::from_secs(60), run(config, parts, stop_rx))
        .await
        .expect("the daemon stops by itself")
}

/// Checks that the rows are the capture's from its first, one every 10 ms of sensor time
/// without a hole; returns how many.
fn rows_in_capture_order(session: &Session) -> u64 {
    let mut rows = 0u64;
    let mut first = None;
    for block in session.imu_blocks("imu", TimeRange::all(), 4096).unwrap() {
        let block = block.unwrap();
        for s in &block.t_sensor {
            let first = *first.get_or_insert(*s);
            let want = first + 0.01 * rows as f64;
            assert!(
                (s - want).abs() < 1e-3,
                "row {rows}: t_sensor {s}, expected {want}"
            );
            rows += 1;
        }
    }
    rows
}

/// Checks that the disk reserve stopped `what` (exit 3) and that the session it left opens
/// whole, every chunk file closed; returns that session.
fn stopped_by_the_reserve(outcome: &Outcome, session_dir: &Path, what: &str) -> Session {
    match outcome {
        Outcome::DiskReserve {
            free_bytes,
            reserve_bytes,
        } => assert!(free_bytes < reserve_bytes),
        other => panic!("expected the disk reserve to stop the {what}, got {other:?}"),
    }
    assert_eq!(outcome.exit_code(), 3);
    let session = Session::open(session_dir).expect("session opens");
    assert!(session.problems().is_empty(), "{:?}", session.problems());
    assert!(
        session.files().iter().all(|f| !f.partial),
        "{:?}",
        session.files()
    );
    session
}
