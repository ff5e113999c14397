//! Crash safety: a child process writing a session is killed with SIGKILL; `recover` must
//! make the partial file readable, completed chunks must be intact, and at most one flush
//! interval of data may be lost. The child is this same test binary, re-run with an env var.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

use crate::common::*;
use imulab::store::{recover, Session, SessionWriter, TimeRange, WriterOptions};

const CHILD_ENV: &str = "IMULAB_STORE_TEST_CHILD_DIR";

/// The writer child: writes 100 Hz data for two IMUs in 10-row batches (0.1 s of data time)
/// forever, printing `T=<last t_mono_ns appended>` after each batch.
#[test]
fn child_writer() {
    let Ok(dir) = std::env::var(CHILD_ENV) else {
        return; // only does something when run as the child
    };
    let opts = WriterOptions {
        rotate_after: Duration::from_secs(10),
        fsync_on_flush: false, // SIGKILL keeps the page cache; fsync is for power loss
        ..WriterOptions::default()
    };
    let mut w = SessionWriter::create(std::path::Path::new(&dir), manifest(), opts).unwrap();
    let mut i = 0;
    loop {
        for (d, name) in ["imu_a", "imu_b"].iter().enumerate() {
            let rows: Vec<_> = (i..i + 10).map(|k| imu_row(d, k)).collect();
            w.append_imu(name, &rows).unwrap();
        }
        i += 10;
        println!("T={}", imu_row(0, i - 1).t_mono_ns);
        std::thread::sleep(Duration::from_micros(300));
    }
}

#[test]
fn kill_9_then_recover_loses_at_most_one_flush_interval() {
    if std::env::var(CHILD_ENV).is_ok() {
        return;
    }
    let _serial = child_process_guard();
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("killed");
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "recover::child_writer",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD_ENV, &dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let mut last_t = i64::MIN;
    // Let it write 25.3 s of data: two completed 10 s chunks and a partial one.
    while last_t < imu_row(0, 2530).t_mono_ns {
        let line = lines.next().expect("child ended early").unwrap();
        if let Some(t) = line.strip_prefix("T=") {
            last_t = t.parse().unwrap();
        }
    }
    // While the writer lives, recover must refuse to touch its file.
    let e = recover(&dir).unwrap_err().to_string();
    assert!(e.contains("still running"), "{e}");
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    for line in lines {
        if let Some(t) = line.unwrap().strip_prefix("T=") {
            last_t = t.parse().unwrap();
        }
    }

    assert!(dir.join("chunk-000000.h5").exists());
    assert!(dir.join("chunk-000001.h5").exists());
    assert!(dir.join("chunk-000002.h5.partial").exists());
    // A killed SWMR file still has its superblock flag set, so HDF5 refuses to open it for
    // writing; `recover` clears it itself.
    assert!(hdf5::File::open_rw(dir.join("chunk-000002.h5.partial")).is_err());
    let report = recover(&dir).unwrap();
    assert_eq!(report.files.len(), 1);
    assert!(report.files[0].superblock_flags_cleared);
    assert!(!dir.join("chunk-000002.h5.partial").exists());
    // The writer grows its tables ahead of the rows written; those unwritten rows are cut,
    // not reported as data lost (a row is dropped only if its time had reached the disk).
    for t in &report.files[0].tables {
        assert!(
            t.rows_dropped <= 200,
            "{}: {} rows dropped, {} kept",
            t.group,
            t.rows_dropped,
            t.rows_kept
        );
    }

    let s = Session::open(&dir).unwrap();
    assert!(s.problems().is_empty(), "{:?}", s.problems());
    assert!(s.files().iter().all(|f| !f.partial));
    for (d, name) in ["imu_a", "imu_b"].iter().enumerate() {
        let mut n = 0;
        for block in s.imu_blocks(name, TimeRange::all(), 1000).unwrap() {
            let block = block.unwrap();
            for k in 0..block.len() {
                assert_eq!(block.record(k), imu_row(d, n), "{name} row {n}");
                n += 1;
            }
        }
        let kept_t = imu_row(d, n - 1).t_mono_ns;
        let lost_ns = last_t - kept_t;
        eprintln!(
            "{name}: kept {n} rows, lost {:.3} s of data",
            lost_ns as f64 * 1e-9
        );
        assert!(
            lost_ns <= 1_000_000_000,
            "{name}: lost {lost_ns} ns of data (kept {n} rows, last appended t {last_t})"
        );
        assert!(
            n >= 2000,
            "{name}: completed chunks must be intact, got {n} rows"
        );
    }
    // Recovering again finds nothing to do.
    assert!(recover(&dir).unwrap().files.is_empty());
}
