//! The follower on a session growing under it: looks between appends, flushes and
//! rotations take every row exactly once, and the result equals reading the finished
//! session at once and a full recomputation of the same samples.

use super::common::{mono_now, LiveSession, IMUS, RATE_HZ};
use imulab::allan::curve::compute_curve_from_rate;
use imulab::allan::{DeviationKind, TauGrid};
use imulab::store::EventKind;
use imulab::watch::follow::Follower;

#[test]
fn looks_during_the_run_take_every_row_once() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("run");
    let mut live = LiveSession::create(&session, mono_now());
    let mut follower = Follower::open(&session).unwrap();
    follower.look().unwrap();
    assert_eq!(follower.devices[0].rows, 0);
    for step in 0..12 {
        live.append(7.3);
        if step == 4 {
            live.event(IMUS[0], EventKind::Resync, "count=3");
            live.event(IMUS[1], EventKind::ChecksumError, "bad crc");
        }
        if step % 5 == 4 {
            live.rotate();
        }
        follower.look().unwrap();
        // Twice in a row: nothing new the second time.
        follower.look().unwrap();
        for d in follower
            .devices
            .iter()
            .filter(|d| d.info.name.starts_with("imu"))
        {
            assert_eq!(d.rows, live.rows, "{} after step {step}", d.info.name);
        }
    }
    live.close();
    follower.look().unwrap();
    assert!(follower.problems.is_empty(), "{:?}", follower.problems);
    let a = &follower.devices[0];
    assert_eq!(a.rows, live.rows);
    assert_eq!(a.gaps, 0);
    assert_eq!(a.events.get("resync"), Some(&3));
    assert_eq!(follower.devices[1].events.get("checksum_error"), Some(&1));
    assert!(follower.session_events.contains_key("session_start"));
    let rx = &follower.devices[2];
    assert_eq!(rx.rows, live.rows.div_ceil(30));
    let rate = a.mean_rate_hz().unwrap();
    assert!((rate / RATE_HZ - 1.0).abs() < 1e-6, "{rate}");
    // The curve of gyro_x equals the full computation on every sample written.
    let tau0 = a.tau0();
    let inc = a.axes[0].allan.curve(tau0);
    let full = compute_curve_from_rate(&live.gyro_x_a, tau0, DeviationKind::Adev, &TauGrid::Octave)
        .unwrap()
        .0;
    assert_eq!(inc.points.len(), full.points.len());
    for (p, q) in inc.points.iter().zip(&full.points) {
        assert!(
            (p.deviation - q.deviation).abs() <= 1e-12 * q.deviation,
            "m = {}",
            q.m
        );
    }
    // A follower that reads the finished session at once sees the same.
    let mut once = Follower::open(&session).unwrap();
    once.look().unwrap();
    for (x, y) in once.devices.iter().zip(&follower.devices) {
        assert_eq!((x.rows, x.gaps), (y.rows, y.gaps), "{}", x.info.name);
        assert_eq!(x.events, y.events);
    }
    assert_eq!(once.file_count(), follower.file_count());
    assert_eq!(once.file_count(), 3);
    // Temperature: bounded series with the written range.
    let (lo, hi) = a.temperature.range().unwrap();
    assert!((lo - 25.0).abs() < 1e-9 && hi > 25.0, "{lo} {hi}");
}

#[test]
fn a_gap_in_the_time_stamps_is_counted() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("run");
    let mut live = LiveSession::create(&session, mono_now());
    live.append(10.0);
    live.skip(2.0);
    live.append(10.0);
    live.close();
    let mut follower = Follower::open(&session).unwrap();
    follower.look().unwrap();
    let a = &follower.devices[0];
    assert_eq!(a.gaps, 1);
    assert_eq!(a.missing_samples, 300);
}

#[test]
fn not_a_session_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let e = Follower::open(&dir.path().join("missing"))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("missing"), "{e}");
}
