//! Rotation by data time: which file each row and event lands in when a session is rotated
//! every `rotate_after` of data time (docs/session-format.md).

use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::common::*;
use imulab::store::{EventKind, EventRecord, SessionWriter, WriterOptions};

/// The finished chunk files of a session, in order.
fn chunk_files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            name.starts_with("chunk-") && name.ends_with(".h5")
        })
        .collect();
    files.sort();
    files
}

/// `t_mono_ns` of the table `group` in one chunk file.
fn times(file: &Path, group: &str) -> Vec<i64> {
    let f = hdf5::File::open(file).unwrap();
    f.dataset(&format!("{group}/t_mono_ns"))
        .unwrap()
        .read_raw::<i64>()
        .unwrap()
}

/// Kinds of the events in one chunk file, in order.
fn event_kinds(file: &Path) -> Vec<String> {
    let f = hdf5::File::open(file).unwrap();
    f.dataset("events/kind")
        .unwrap()
        .read_raw::<hdf5::types::FixedAscii<32>>()
        .unwrap()
        .iter()
        .map(|k| k.as_str().to_string())
        .collect()
}

fn opts(rotate_s: u64) -> WriterOptions {
    WriterOptions {
        fsync_on_flush: false,
        rotate_after: Duration::from_secs(rotate_s),
        ..WriterOptions::default()
    }
}

/// Appends `n` IMU rows of both IMUs from row `i`, and the GNSS fixes up to the last of them.
fn append_block(w: &mut SessionWriter, i: usize, n: usize, next_gnss: &mut usize) {
    for (d, name) in ["imu_a", "imu_b"].iter().enumerate() {
        let rows: Vec<_> = (i..i + n).map(|k| imu_row(d, k)).collect();
        w.append_imu(name, &rows).unwrap();
    }
    let t_end = imu_row(0, i + n - 1).t_mono_ns;
    let mut fixes = Vec::new();
    while gnss_row(*next_gnss).t_mono_ns <= t_end {
        fixes.push(gnss_row(*next_gnss));
        *next_gnss += 1;
    }
    w.append_gnss("gps", &fixes).unwrap();
}

fn stop_event(t_mono_ns: i64) -> EventRecord {
    EventRecord {
        t_mono_ns,
        t_wall_ns: 0,
        device: String::new(),
        kind: EventKind::SessionStop,
        detail: "end of run".into(),
    }
}

/// A run whose length is a whole number of `rotate_after` ends with its `session_stop`
/// timed at the end, i.e. exactly where a next file would start. That event must go into
/// the last file with data, not start a file of its own (it once did: a third file holding
/// only a rotation and the stop event).
#[test]
fn a_stop_event_at_the_rotation_time_goes_into_the_last_file() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    let mut w = SessionWriter::create(&dir, manifest(), opts(10)).unwrap();
    let mut next_gnss = 0;
    // 20 s of 100 Hz data in blocks of 10 s: rotation at 10 s falls between two blocks.
    for block in 0..2 {
        append_block(&mut w, block * 1000, 1000, &mut next_gnss);
    }
    w.append_event(&stop_event(imu_row(0, 2000).t_mono_ns))
        .unwrap();
    w.close().unwrap();

    let files = chunk_files(&dir);
    assert_eq!(files.len(), 2, "{files:?}");
    for f in &files {
        assert!(
            !times(f, "imu/imu_a").is_empty(),
            "{}: no data",
            f.display()
        );
    }
    assert_eq!(
        event_kinds(&files[1]),
        ["rotation", "session_stop"],
        "{}",
        files[1].display()
    );
}

/// Rows are split at rotation times whatever the size of the appends: each file holds
/// exactly `rotate_after` of data time, for every table, even when the rows come in blocks
/// longer than that, one table after the other (as the simulator hands them over: 4096
/// samples of one table, then of the next). The writer once decided only at the first row
/// of an append, so every file held whole blocks (here 40.96 s instead of 10 s).
#[test]
fn files_hold_exactly_rotate_after_of_data_whatever_the_block_size() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    let mut w = SessionWriter::create(&dir, manifest(), opts(10)).unwrap();
    let mut next_gnss = 0;
    // 100 s of 100 Hz data in blocks of 4096 rows, then the stop event at the end.
    let mut i = 0;
    while i < 10_000 {
        let n = 4096.min(10_000 - i);
        append_block(&mut w, i, n, &mut next_gnss);
        i += n;
    }
    w.append_event(&stop_event(imu_row(0, 10_000).t_mono_ns))
        .unwrap();
    w.close().unwrap();

    let files = chunk_files(&dir);
    assert_eq!(files.len(), 10, "{files:?}");
    for (k, f) in files.iter().enumerate() {
        for (d, name) in ["imu_a", "imu_b"].iter().enumerate() {
            let want: Vec<i64> = (1000 * k..1000 * (k + 1))
                .map(|i| imu_row(d, i).t_mono_ns)
                .collect();
            let got = times(f, &format!("imu/{name}"));
            assert!(
                got == want,
                "{}: {name} has {} rows from {:?} to {:?}",
                f.display(),
                got.len(),
                got.first(),
                got.last()
            );
        }
        let want: Vec<i64> = (50 * k..50 * (k + 1))
            .map(|i| gnss_row(i).t_mono_ns)
            .collect();
        let got = times(f, "gnss/gps");
        assert!(
            got == want,
            "{}: gps has {} rows from {:?} to {:?}",
            f.display(),
            got.len(),
            got.first(),
            got.last()
        );
        let kinds = event_kinds(f);
        match k {
            0 => assert!(kinds.is_empty(), "{kinds:?}"),
            9 => assert_eq!(kinds, ["rotation", "session_stop"]),
            _ => assert_eq!(kinds, ["rotation"]),
        }
        if k > 0 {
            // The rotation event is timed where the file's span starts.
            assert_eq!(times(f, "events")[0], imu_row(0, 1000 * k).t_mono_ns);
        }
    }
}

/// A live writer's timer says every table's rows are in up to its time: a file kept open
/// for a table that has not passed the rotation time yet (a device gone quiet) is finished
/// there, and the quiet table's later rows go into the next file.
#[test]
fn the_timer_finishes_a_file_a_quiet_table_kept_open() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    let mut w = SessionWriter::create(&dir, manifest(), opts(10)).unwrap();
    let rows =
        |d: usize, r: std::ops::Range<usize>| -> Vec<_> { r.map(|i| imu_row(d, i)).collect() };
    w.append_imu("imu_b", &rows(1, 0..500)).unwrap();
    w.append_imu("imu_a", &rows(0, 0..1200)).unwrap();
    // imu_b has rows in file 0 and has not passed 10 s: file 0 stays open.
    assert!(dir.join("chunk-000000.h5.partial").exists());
    assert!(dir.join("chunk-000001.h5.partial").exists());
    w.maybe_flush_and_rotate(imu_row(0, 1200).t_mono_ns)
        .unwrap();
    assert!(dir.join("chunk-000000.h5").exists());
    w.append_imu("imu_b", &rows(1, 500..1200)).unwrap();
    w.close().unwrap();
    let files = chunk_files(&dir);
    assert_eq!(files.len(), 2, "{files:?}");
    assert_eq!(times(&files[0], "imu/imu_a").len(), 1000);
    assert_eq!(times(&files[0], "imu/imu_b").len(), 500);
    assert_eq!(times(&files[1], "imu/imu_a").len(), 200);
    assert_eq!(times(&files[1], "imu/imu_b").len(), 700);
}
