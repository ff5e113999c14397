//! `imulab sim -o`: a simulated scene written as a session reads back through the store's
//! reader with the same rows the in-memory sink saw, plus truth and the scene in the manifest.

use std::path::Path;

use crate::space::bytes_outside_chunks;
use imulab::sim::outputs::{MemorySink, SessionSink, Tee};
use imulab::sim::runner::run;
use imulab::sim::scene::{Scene, START_MONO_NS};
use imulab::store::{Session, TimeRange};

#[test]
fn session_reads_back_what_was_simulated() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/scenes/short_drive.toml");
    let scene = Scene::load(&path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("session");
    let mut memory = MemorySink::default();
    let mut session = SessionSink::create(&out, &scene).unwrap();
    run(&scene, &mut Tee(&mut session, &mut memory)).unwrap();
    session.close().unwrap();

    let s = Session::open(&out).unwrap();
    assert!(s.problems().is_empty(), "{:?}", s.problems());
    let m = s.manifest();
    assert_eq!(m.truth_nav_rate_hz, Some(100.0));
    assert_eq!(m.config.get("seed").and_then(|v| v.as_integer()), Some(3));
    assert_eq!(m.devices.len(), 2);

    let mut gyro = Vec::new();
    let mut t = Vec::new();
    for b in s.imu_blocks("imu", TimeRange::all(), 1000).unwrap() {
        let b = b.unwrap();
        gyro.extend(b.gyro);
        t.extend(b.t_mono_ns);
    }
    let want = &memory.imu["imu"];
    assert_eq!(gyro.len(), want.len());
    assert!(want.iter().zip(&gyro).all(|(r, g)| r.gyro == *g));
    assert!(want.iter().zip(&t).all(|(r, t)| r.t_mono_ns == *t));

    let fixes: usize = s
        .gnss_blocks("gnss", TimeRange::all(), 1000)
        .unwrap()
        .map(|b| b.unwrap().len())
        .sum();
    assert_eq!(fixes, memory.gnss["gnss"].len());
    let mut bias = Vec::new();
    for b in s.truth_imu_blocks("imu", TimeRange::all(), 1000).unwrap() {
        bias.extend(b.unwrap().gyro_bias);
    }
    assert_eq!(bias.len(), memory.truth_imu["imu"].len());
    assert!(memory.truth_imu["imu"]
        .iter()
        .zip(&bias)
        .all(|(r, b)| r.gyro_bias == *b));
    let nav: usize = s
        .truth_nav_blocks(TimeRange::all(), 1000)
        .unwrap()
        .map(|b| b.unwrap().len())
        .sum();
    assert_eq!(nav, 6000);
    let (events, problems) = s.events();
    assert!(problems.is_empty());
    assert_eq!(events.len(), 2);
}

#[test]
fn existing_session_directory_is_refused() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/scenes/short_static.toml");
    let scene = Scene::load(&path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("something"), b"x").unwrap();
    let e = SessionSink::create(dir.path(), &scene)
        .err()
        .expect("refused");
    assert!(format!("{e:#}").contains("not empty"), "{e:#}");
}

/// The simulator hands its rows over a block (4096 samples) at a time, one table after the
/// other, so every table lags the newest row by up to a block. The writer once took that for
/// a stalled device and wrote each table's incomplete chunk early, then stored it again once
/// complete: 9.5 % of each file of this session was dead copies (`h5stat -S`: 444 kB
/// unaccounted of 4.68 MB, beside 73 kB of metadata). Metadata alone is 1.6 % here
/// (`h5stat -S`: object headers and the chunk indexes of 40 datasets, ~23 bytes per chunk),
/// so 4 % allows for more than twice that and still catches a dead copy of one chunk in ten
/// of the IMU's.
#[test]
fn simulated_session_stores_every_chunk_once() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/scenes/drive_30min.toml");
    let scene = Scene::load(&path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("session");
    let mut session = SessionSink::create(&out, &scene).unwrap();
    run(&scene, &mut session).unwrap();
    session.close().unwrap();
    let s = Session::open(&out).unwrap();
    // 30 min of 100 Hz rotated every 10 min of data: three files of 10 min of samples each
    // (the simulator's blocks of 4096 samples, 40.96 s, are split at the rotation times;
    // they once made files of whole blocks), the stop event (timed at the end, where a
    // fourth file would start) in the last.
    assert_eq!(s.files().len(), 3, "{:?}", s.files());
    for (k, f) in s.files().iter().enumerate() {
        let h5 = hdf5::File::open(&f.path).unwrap();
        let t = h5
            .dataset("imu/imu/t_mono_ns")
            .unwrap()
            .read_raw::<i64>()
            .unwrap();
        let start = START_MONO_NS + k as i64 * 600_000_000_000;
        let span = start..start + 600_000_000_000;
        // 60 000 samples, give or take one whose arrival jitter crosses a rotation time.
        assert!(
            t.len().abs_diff(60_000) <= 1,
            "{}: {}",
            f.path.display(),
            t.len()
        );
        assert!(
            span.contains(&t[0]) && span.contains(&t[t.len() - 1]),
            "{}: rows from {} to {} ns, span {span:?}",
            f.path.display(),
            t[0],
            t[t.len() - 1]
        );
        let kinds = h5.dataset("events/kind").unwrap();
        let kinds = kinds.read_raw::<hdf5::types::FixedAscii<32>>().unwrap();
        let kinds: Vec<&str> = kinds.iter().map(|k| k.as_str()).collect();
        let want: &[&str] = match k {
            0 => &["session_start"],
            1 => &["rotation"],
            _ => &["rotation", "session_stop"],
        };
        assert_eq!(kinds, want, "{}", f.path.display());
    }
    for f in s.files() {
        let (size, outside) = bytes_outside_chunks(&f.path);
        let share = outside as f64 / size as f64;
        assert!(
            share <= 0.04,
            "{}: {outside} of {size} bytes ({:.1} %) hold no chunk (see h5stat -S)",
            f.path.display(),
            100.0 * share
        );
    }
}
