//! Crash safety: a child process writing a session is killed with SIGKILL; `recover` must
//! make the partial file readable, completed chunks must be intact, and at most one flush
//! interval of data may be lost. The child is this same test binary, re-run with an env var.

use std::time::Duration;

use crate::common::*;
use imulab::store::{recover, Session, TimeRange, WriterOptions};

const CHILD_ENV: &str = "IMULAB_STORE_TEST_CHILD_DIR";

/// The writer child ([`run_writer_child`]): the two IMUs only, a new file every 10 s.
#[test]
fn child_writer() {
    let opts = WriterOptions {
        rotate_after: Duration::from_secs(10),
        fsync_on_flush: false, // SIGKILL keeps the page cache; fsync is for power loss
        ..WriterOptions::default()
    };
    run_writer_child(CHILD_ENV, opts, |_, _| {});
}

#[test]
fn kill_9_then_recover_loses_at_most_one_flush_interval() {
    if std::env::var(CHILD_ENV).is_ok() {
        return;
    }
    let _serial = child_process_guard();
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("killed");
    let mut child = WriterChild::spawn("recover::child_writer", CHILD_ENV, &dir);
    // Let it write 25.3 s of data: two completed 10 s chunks and a partial one.
    child.wait_for(imu_row(0, 2530).t_mono_ns);
    // While the writer lives, recover must refuse to touch its file.
    let e = recover(&dir).unwrap_err().to_string();
    assert!(e.contains("still running"), "{e}");
    let last_t = child.kill();

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
