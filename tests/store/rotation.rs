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

/// The reader opens a chunk file when it reaches it: a file that vanishes after
/// `Session::open` is one error naming it, and the other files still read whole.
#[test]
fn a_chunk_file_that_vanishes_after_open_is_one_error_naming_it() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    write_session(&dir, 12, 100, opts(4));
    let files = chunk_files(&dir);
    assert!(files.len() >= 3, "{files:?}");
    let session = imulab::store::Session::open(&dir).unwrap();
    assert!(session.problems().is_empty(), "{:?}", session.problems());
    let gone = &files[1];
    let gone_rows = times(gone, "imu/imu_a").len();
    std::fs::remove_file(gone).unwrap();
    let (mut rows, mut errors) = (0, Vec::new());
    for block in session
        .imu_blocks("imu_a", imulab::store::TimeRange::all(), 250)
        .unwrap()
    {
        match block {
            Ok(b) => rows += b.t_mono_ns.len(),
            Err(e) => errors.push(e.to_string()),
        }
    }
    assert_eq!(errors.len(), 1, "{errors:?}");
    assert!(
        errors[0].contains(&*gone.to_string_lossy()),
        "{}",
        errors[0]
    );
    assert_eq!(rows + gone_rows, 12 * IMU_HZ as usize);
}
