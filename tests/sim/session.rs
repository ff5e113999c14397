//! `imulab sim -o`: a simulated scene written as a session reads back through the store's
//! reader with the same rows the in-memory sink saw, plus truth and the scene in the manifest.

use std::path::Path;

use imulab::sim::outputs::{MemorySink, SessionSink, Tee};
use imulab::sim::runner::run;
use imulab::sim::scene::Scene;
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
