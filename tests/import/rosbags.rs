//! Bags written by the `rosbags` Python package (the ROS bag library used without a ROS
//! install; `write_bags.py`) read as they were written: a ROS 2 bag directory in MCAP
//! storage and a ROS 1 bag with lz4 chunks. Uses `python3` when it has `rosbags`, else a venv
//! made under `target/` with `pip install rosbags`; skips with the reason when neither can be
//! had.

use super::{imulab, text};
use imulab::store::{Session, TimeRange};
use std::path::{Path, PathBuf};
use std::process::Command;

const T0: i64 = 1_700_000_000_000_000_000;

fn has_rosbags(python: &Path) -> bool {
    Command::new(python)
        .args(["-c", "import rosbags, numpy"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

/// A Python with `rosbags`, or `None` with the reason printed.
fn python_with_rosbags() -> Option<PathBuf> {
    let system = PathBuf::from("python3");
    if has_rosbags(&system) {
        return Some(system);
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("target");
    let venv = root.join("bag-pyvenv");
    let python = venv.join("bin/python");
    if has_rosbags(&python) {
        return Some(python);
    }
    // Built beside and renamed, so a half-made venv is never taken for a good one.
    let tmp = root.join(format!("bag-pyvenv.tmp-{}", std::process::id()));
    let made = Command::new("python3")
        .args(["-m", "venv"])
        .arg(&tmp)
        .status()
        .is_ok_and(|s| s.success())
        && Command::new(tmp.join("bin/python"))
            .args(["-m", "pip", "install", "--quiet", "rosbags"])
            .status()
            .is_ok_and(|s| s.success());
    if !made {
        let _ = std::fs::remove_dir_all(&tmp);
        eprintln!("SKIP: no python3 with the rosbags package, and `pip install rosbags` into a venv failed");
        return None;
    }
    let _ = std::fs::rename(&tmp, &venv);
    let _ = std::fs::remove_dir_all(&tmp);
    has_rosbags(&python).then_some(python)
}

#[test]
fn bags_written_by_rosbags_read_as_written() {
    let Some(python) = python_with_rosbags() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/import/write_bags.py");
    let out = Command::new(&python)
        .arg(&script)
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out));
    for bag in ["ros2_bag", "ros1.bag"] {
        let path = dir.path().join(bag);
        let session = dir.path().join(format!("{bag}.session"));
        let out = imulab(&[
            "import",
            path.to_str().unwrap(),
            "-o",
            session.to_str().unwrap(),
        ]);
        let said = text(&out);
        assert!(out.status.success(), "{bag}: {said}");
        assert!(
            said.contains("/imu/data") && said.contains("500 messages"),
            "{said}"
        );
        let s = Session::open(&session).unwrap();
        let rows: Vec<_> = s
            .imu_blocks("imu_data", TimeRange::all(), 1024)
            .unwrap()
            .flat_map(|b| {
                let b = b.unwrap();
                (0..b.len()).map(move |i| b.record(i)).collect::<Vec<_>>()
            })
            .collect();
        assert_eq!(rows.len(), 500, "{bag}");
        for (i, r) in rows.iter().enumerate() {
            let f = i as f64;
            let log = T0 + i as i64 * 10_000_000 + 5_000;
            assert_eq!(r.t_mono_ns, log, "{bag} row {i}");
            assert!(
                (r.t_sensor - (log - 1_000_000) as f64 * 1e-9).abs() < 1e-6,
                "{bag} row {i}"
            );
            assert_eq!(
                r.gyro,
                [f * 1e-3, -f * 2e-3, 0.5 + f * 1e-6],
                "{bag} row {i}"
            );
            assert_eq!(r.accel, [0.1 * f, -0.01 * f, 9.81], "{bag} row {i}");
        }
        let fixes: Vec<_> = s
            .gnss_blocks("gps_fix", TimeRange::all(), 64)
            .unwrap()
            .flat_map(|b| {
                let b = b.unwrap();
                (0..b.len()).map(move |i| b.record(i)).collect::<Vec<_>>()
            })
            .collect();
        assert_eq!(fixes.len(), 5, "{bag}");
        for (k, r) in fixes.iter().enumerate() {
            let f = k as f64;
            assert_eq!(
                (r.lat_deg, r.lon_deg, r.height_m),
                (48.0 + f * 1e-4, 11.0 - f * 1e-4, 500.0 + f),
                "{bag} fix {k}"
            );
            assert!((r.h_acc_m - 0.5).abs() < 1e-12 && (r.v_acc_m - 1.0).abs() < 1e-12);
        }
        let out = imulab(&[
            "allan",
            path.to_str().unwrap(),
            "--sensor",
            "gyro",
            "--axes",
            "z",
        ]);
        assert!(out.status.success(), "{bag}: {}", text(&out));
        assert!(text(&out).contains("500 samples"), "{}", text(&out));
    }
}
