//! The write-ahead journal (10 s chunks, 1 s flushes): a writer killed 7.3 s into a chunk
//! loses at most one flush interval once `recover` has replayed its journal; a torn journal
//! tail, recovering twice (or after an interrupted recover) and a partial file without a
//! journal (sessions from before it) all recover. The child writer is this test binary.

use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::common::*;
use imulab::store::recover::repair_partial;
use imulab::store::{
    recover, EventKind, EventRecord, GnssRecord, ImuRecord, Session, SessionWriter, TimeRange,
    WriterOptions,
};

const CHILD_ENV: &str = "IMULAB_STORE_TEST_JOURNAL_CHILD_DIR";
const SECOND: i64 = 1_000_000_000;

fn event(k: usize) -> EventRecord {
    EventRecord {
        t_mono_ns: imu_row(0, k * 100).t_mono_ns,
        t_wall_ns: 7 + k as i64,
        device: "imu_b".into(),
        kind: EventKind::Resync,
        detail: format!("resync {k}, ünïcode"),
    }
}

/// The writer child ([`run_writer_child`]): 10 s chunks, 1 s flushes, one file; besides
/// the two IMUs, the 5 Hz GNSS and an event every second.
#[test]
fn journal_child_writer() {
    let opts = WriterOptions {
        flush_interval: Duration::from_secs(1),
        chunk_interval: Duration::from_secs(10),
        fsync_on_flush: false, // SIGKILL keeps the page cache; fsync is for power loss
        ..WriterOptions::default()
    };
    run_writer_child(CHILD_ENV, opts, |w, i| {
        if i % 20 == 0 {
            w.append_gnss("gps", &[gnss_row(i / 20)]).unwrap();
        }
        if i % 100 == 0 {
            w.append_event(&event(i / 100)).unwrap();
        }
    });
}

/// Runs the child until it has appended `until_ns` of data time, SIGKILLs it, and returns
/// the last data time it reported.
fn write_and_kill(dir: &Path, until_ns: i64) -> i64 {
    let mut child = WriterChild::spawn("journal::journal_child_writer", CHILD_ENV, dir);
    child.wait_for(until_ns);
    child.kill()
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
    }
}

/// Everything a recovered session holds, in order.
#[derive(Debug, PartialEq)]
struct Contents {
    imu: [Vec<ImuRecord>; 2],
    gnss: Vec<GnssRecord>,
    events: Vec<EventRecord>,
}

fn contents(dir: &Path) -> Contents {
    let s = Session::open(dir).unwrap();
    assert!(s.problems().is_empty(), "{:?}", s.problems());
    assert!(s.files().iter().all(|f| !f.partial));
    let imu = ["imu_a", "imu_b"].map(|name| {
        let mut rows = Vec::new();
        for b in s.imu_blocks(name, TimeRange::all(), 700).unwrap() {
            let b = b.unwrap();
            rows.extend((0..b.len()).map(|k| b.record(k)));
        }
        rows
    });
    let mut gnss = Vec::new();
    for b in s.gnss_blocks("gps", TimeRange::all(), 700).unwrap() {
        let b = b.unwrap();
        gnss.extend((0..b.len()).map(|k| b.record(k)));
    }
    let (events, problems) = s.events();
    assert!(problems.is_empty(), "{problems:?}");
    Contents { imu, gnss, events }
}

/// Every row is the expected one for its position (so none is missing, repeated or
/// changed), and the rows reach back to `last_t - max_lost_ns`.
fn check(c: &Contents, last_t: i64, max_lost_ns: i64) {
    for (d, rows) in c.imu.iter().enumerate() {
        for (n, r) in rows.iter().enumerate() {
            assert_eq!(*r, imu_row(d, n), "imu {d} row {n}");
        }
        let kept = rows.last().map_or(i64::MIN, |r| r.t_mono_ns);
        assert!(
            last_t - kept <= max_lost_ns,
            "imu {d}: kept {} rows up to {kept}, last appended {last_t}: lost {:.3} s",
            rows.len(),
            (last_t - kept) as f64 * 1e-9
        );
    }
    for (n, r) in c.gnss.iter().enumerate() {
        assert_eq!(*r, gnss_row(n), "gnss row {n}");
    }
    let fixes_due = (0..).take_while(|&n| gnss_row(n).t_mono_ns <= last_t - max_lost_ns);
    assert!(c.gnss.len() >= fixes_due.count(), "{} fixes", c.gnss.len());
    for (k, e) in c.events.iter().enumerate() {
        assert_eq!(*e, event(k), "event {k}");
    }
    let events_due = (0..).take_while(|&k| event(k).t_mono_ns <= last_t - max_lost_ns);
    assert!(
        c.events.len() >= events_due.count(),
        "{} events",
        c.events.len()
    );
}

fn rows_from_journal(report: &imulab::store::RecoverReport, group: &str) -> u64 {
    report.files[0]
        .tables
        .iter()
        .find(|t| t.group == group)
        .map_or(0, |t| t.rows_from_journal)
}

#[test]
fn kill_mid_chunk_recovers_everything_but_the_last_flush_interval() {
    if std::env::var(CHILD_ENV).is_ok() {
        return;
    }
    let _serial = child_process_guard();
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("killed");
    // One complete 10 s chunk (from t = 1 s) and 7.3 s into the second.
    let last_t = write_and_kill(&dir, imu_row(0, 1730).t_mono_ns);
    let partial = dir.join("chunk-000000.h5.partial");
    let journals =
        |d: &Path| ["chunk-000000.h5.journal0", "chunk-000000.h5.journal1"].map(|n| d.join(n));
    assert!(partial.exists() && journals(&dir).iter().any(|j| j.exists()));

    let copies: Vec<PathBuf> = ["torn", "twice", "no-journal"]
        .iter()
        .map(|n| tmp.path().join(n))
        .collect();
    for c in &copies {
        copy_dir(&dir, c);
    }

    // The plain case: everything older than one flush interval, exactly once.
    let report = recover(&dir).unwrap();
    assert_eq!(report.files.len(), 1);
    assert_eq!(report.files[0].journal_bytes_dropped, 0);
    assert!(
        journals(&dir).iter().all(|j| !j.exists()),
        "recover removes the journal"
    );
    let full = contents(&dir);
    check(&full, last_t, SECOND);
    // The HDF5 file held whole 10 s chunks only: the last 7.3 s came from the journal.
    assert!(rows_from_journal(&report, "imu/imu_a") >= 600, "{report:?}");
    assert!(rows_from_journal(&report, "gnss/gps") >= 12, "{report:?}");
    assert!(recover(&dir).unwrap().files.is_empty());
    assert_eq!(contents(&dir), full, "recovering again changes nothing");

    // A torn journal tail: the cut record is dropped, every row before it kept. (Both
    // files are cut: the one not being appended holds only rows the other, or the HDF5
    // file, holds too.)
    for j in journals(&copies[0]) {
        let len = std::fs::metadata(&j).map_or(0, |m| m.len());
        if len > 0 {
            let f = std::fs::OpenOptions::new().write(true).open(&j).unwrap();
            f.set_len(len - 5).unwrap();
        }
    }
    let report = recover(&copies[0]).unwrap();
    assert!(report.files[0].journal_bytes_dropped > 0);
    let torn = contents(&copies[0]);
    // The last record holds at most one flush interval of rows (and a batch).
    check(&torn, last_t, 2 * SECOND + SECOND / 10);
    assert!(torn.imu[0].len() >= 1000 + 500, "{}", torn.imu[0].len());

    // An interrupted recover (the file repaired and replayed, not yet renamed), then a
    // full one: the same session as recovering once.
    let p = copies[1].join("chunk-000000.h5.partial");
    let j = journals(&copies[1]);
    let (_, first, _) = repair_partial(&p, &j).unwrap();
    let (_, second, _) = repair_partial(&p, &j).unwrap();
    assert!(first.iter().any(|t| t.rows_from_journal > 0));
    assert!(
        second.iter().all(|t| t.rows_from_journal == 0),
        "{second:?}"
    );
    recover(&copies[1]).unwrap();
    assert_eq!(contents(&copies[1]), full);

    // A partial file without a journal (a session from before it) still recovers: the
    // complete chunks are intact; the rest of the chunk being filled (up to a chunk
    // interval and a flush interval) is lost.
    for j in journals(&copies[2]) {
        let _ = std::fs::remove_file(j);
    }
    let report = recover(&copies[2]).unwrap();
    assert!(report.files[0]
        .tables
        .iter()
        .all(|t| t.rows_from_journal == 0));
    let old = contents(&copies[2]);
    check(&old, last_t, 11 * SECOND);
    assert!(old.imu[0].len() >= 1000, "{}", old.imu[0].len());
}

/// A completed file with a journal left beside it (a crash between the writer's rename and
/// its removal of the journal): `recover` removes the journal and leaves the file alone.
#[test]
fn orphan_journal_beside_a_completed_file_is_removed() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    write_session(&dir, 3, 10, fast_opts());
    let before = contents(&dir);
    std::fs::write(dir.join("chunk-000000.h5.journal1"), b"IMLJ torn").unwrap();
    let report = recover(&dir).unwrap();
    assert!(report.files.is_empty());
    assert!(!dir.join("chunk-000000.h5.journal1").exists());
    assert_eq!(contents(&dir), before);
}

const STALL_TIMER_ENV: &str = "IMULAB_STORE_TEST_STALL_TIMER_DIR";
const STALL_APPENDS_ENV: &str = "IMULAB_STORE_TEST_STALL_APPENDS_DIR";
const SLOW_TIMER_ENV: &str = "IMULAB_STORE_TEST_SLOW_TIMER_DIR";
/// GNSS fixes the stalling receiver sends (3 s at 5 Hz) before it falls silent: fewer than
/// its 50-row chunk, which therefore never fills.
const STALLED_FIXES: usize = 15;

/// Fix `k` of a receiver sending at half its nominal 5 Hz (one every 0.4 s from t = 1 s).
fn slow_fix(k: usize) -> GnssRecord {
    GnssRecord {
        t_mono_ns: imu_row(0, 40 * k).t_mono_ns,
        ..gnss_row(k)
    }
}

/// The IMUs stream on; the GNSS sends [`STALLED_FIXES`] and stalls, or (`slow`) sends
/// [`slow_fix`]es throughout. With `timer` the child calls `maybe_flush_and_rotate` every
/// second of data time, as imulogd does.
fn run_gnss_child(env: &str, timer: bool, slow: bool) {
    let opts = WriterOptions {
        fsync_on_flush: false,
        ..WriterOptions::default()
    };
    run_writer_child(env, opts, |w, i| {
        if slow && i % 40 == 0 {
            w.append_gnss("gps", &[slow_fix(i / 40)]).unwrap();
        } else if !slow && i % 20 == 0 && i / 20 < STALLED_FIXES {
            w.append_gnss("gps", &[gnss_row(i / 20)]).unwrap();
        }
        if timer && (i + 10) % 100 == 0 {
            w.maybe_flush_and_rotate(imu_row(0, i + 9).t_mono_ns)
                .unwrap();
        }
    });
}

#[test]
fn stall_child_writer_with_timer() {
    run_gnss_child(STALL_TIMER_ENV, true, false);
}

#[test]
fn stall_child_writer_appends_only() {
    run_gnss_child(STALL_APPENDS_ENV, false, false);
}

#[test]
fn slow_child_writer_with_timer() {
    run_gnss_child(SLOW_TIMER_ENV, true, true);
}

/// A stalled device's incomplete chunk reaches the HDF5 file (not only the journal) once
/// its oldest row is a chunk interval old and no row came for a flush interval, on the live
/// writer's timer. Appends alone write whole chunks only (a table fed in blocks, table
/// after table, is not stalled), and a device still sending, at half its rate, fills its
/// chunk by itself (it would be written early only at two chunk intervals): a chunk
/// written half and later whole would be stored twice. Whichever way, `recover` brings back
/// every fix exactly once. The children are killed 14.5 s after the first fix.
#[test]
fn stalled_device_reaches_the_file_on_the_timer_only() {
    if [STALL_TIMER_ENV, STALL_APPENDS_ENV, SLOW_TIMER_ENV]
        .iter()
        .any(|e| std::env::var(e).is_ok())
    {
        return;
    }
    let _serial = child_process_guard();
    let tmp = tempfile::tempdir().unwrap();
    for (test, env, in_file) in [
        (
            "journal::stall_child_writer_with_timer",
            STALL_TIMER_ENV,
            true,
        ),
        (
            "journal::stall_child_writer_appends_only",
            STALL_APPENDS_ENV,
            false,
        ),
        (
            "journal::slow_child_writer_with_timer",
            SLOW_TIMER_ENV,
            false,
        ),
    ] {
        let dir = tmp.path().join(env);
        let mut child = WriterChild::spawn(test, env, &dir);
        child.wait_for(imu_row(0, 1450).t_mono_ns);
        let last_t = child.kill();
        let report = recover(&dir).unwrap();
        let gnss = contents(&dir).gnss;
        if env == SLOW_TIMER_ENV {
            assert_eq!(gnss, (0..gnss.len()).map(slow_fix).collect::<Vec<_>>());
            let due = (0..).take_while(|&k| slow_fix(k).t_mono_ns <= last_t - SECOND);
            assert!(gnss.len() >= due.count(), "{test}: {} fixes", gnss.len());
        } else {
            assert_eq!(gnss, (0..STALLED_FIXES).map(gnss_row).collect::<Vec<_>>());
        }
        let from_journal = if in_file { 0 } else { gnss.len() as u64 };
        assert_eq!(
            rows_from_journal(&report, "gnss/gps"),
            from_journal,
            "{test}: {report:?}"
        );
    }
}

/// Rows stamped far faster than their data time (a replay as fast as the writer goes: here
/// 40 000 rows within 40 ms) reach the disk as they are appended, not all at the close:
/// complete chunks wait in memory for at most about 1 MiB, whatever their timestamps say.
#[test]
fn rows_stamped_faster_than_a_flush_interval_reach_the_disk_as_they_come() {
    if std::env::var(CHILD_ENV).is_ok() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("fast");
    // Uncompressed, so the file's size says how many rows it holds.
    let opts = WriterOptions {
        deflate_level: 0,
        ..fast_opts()
    };
    let mut w = SessionWriter::create(&dir, manifest(), opts).unwrap();
    let rows: Vec<ImuRecord> = (0..40_000)
        .map(|i| ImuRecord {
            t_mono_ns: SECOND + i as i64 * 1000,
            ..imu_row(0, i)
        })
        .collect();
    for block in rows.chunks(1000) {
        w.append_imu("imu_a", block).unwrap();
    }
    let appended = (rows.len() * std::mem::size_of::<ImuRecord>()) as u64;
    let on_disk: u64 = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().metadata().unwrap().len())
        .sum();
    assert!(
        on_disk + (2 << 20) > appended,
        "{on_disk} bytes on disk before the close for {appended} bytes of rows appended"
    );
    w.close().unwrap();
    let session = Session::open(&dir).unwrap();
    let mut read = Vec::new();
    for block in session.imu_blocks("imu_a", TimeRange::all(), 4096).unwrap() {
        read.extend(block.unwrap().t_mono_ns.iter().copied());
    }
    let want: Vec<i64> = rows.iter().map(|r| r.t_mono_ns).collect();
    assert_eq!(read, want);
}
