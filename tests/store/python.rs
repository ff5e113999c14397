//! Runs `docs/read_session.py` (h5py + numpy, in a venv cached under `target/`) on a session
//! Rust wrote, with a live `.partial` file, raw journal, truth and events, and compares every
//! value. Skips with a message when Python or the packages cannot be had.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use crate::common::*;
use imulab::store::{
    EventKind, EventRecord, SessionWriter, TruthImuRecord, TruthNavRecord, WriterOptions,
};

/// A venv with h5py and numpy, made once and reused; `None` (with the reason printed) when
/// it cannot be made.
fn python_with_h5py() -> Option<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("target");
    let venv = root.join("store-pyvenv");
    let python = venv.join("bin/python");
    if python.exists() {
        return Some(python);
    }
    // Build beside and rename, so a half-made venv is never mistaken for a good one.
    let tmp = root.join(format!("store-pyvenv.tmp-{}", std::process::id()));
    let _serial = crate::common::child_process_guard();
    let ok = Command::new("python3")
        .args(["-m", "venv"])
        .arg(&tmp)
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    if !ok {
        eprintln!("SKIP: python3 -m venv failed (install python3 and python3-venv)");
        return None;
    }
    // (still holding the child-process guard taken above)
    let ok = Command::new(tmp.join("bin/python"))
        .args(["-m", "pip", "install", "--quiet", "h5py", "numpy"])
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    if !ok {
        eprintln!("SKIP: pip install h5py numpy failed (no access to PyPI?)");
        let _ = std::fs::remove_dir_all(&tmp);
        return None;
    }
    if std::fs::rename(&tmp, &venv).is_err() {
        let _ = std::fs::remove_dir_all(&tmp); // another test run won the race
    }
    Some(python)
}

fn truth_nav(i: usize) -> TruthNavRecord {
    TruthNavRecord {
        t_mono_ns: 1_000_000_000 + i as i64 * 100_000_000,
        lat_deg: 52.0 + i as f64 * 1e-6,
        lon_deg: 4.5,
        height_m: 3.0,
        vel_ned: [1.0, 0.5, i as f64 * 0.25],
        quat_nb: [1.0, 0.0, 0.0, i as f64 * 0.125],
    }
}

fn truth_imu(i: usize) -> TruthImuRecord {
    let x = i as f64;
    TruthImuRecord {
        t_mono_ns: imu_row(0, i).t_mono_ns,
        gyro_bias: [1e-5, 2e-5, x * 1e-9],
        accel_bias: [1e-3, -1e-3, 0.0],
        gyro_true: [0.0, 0.0, x * 0.001],
        accel_true: [0.0, 0.0, -9.81],
    }
}

fn raw_bytes(i: usize) -> Vec<u8> {
    (0..(i % 13 + 1)).map(|k| (i * 7 + k) as u8).collect()
}

/// Floats are dumped as Python `repr()` strings, which parse back exactly.
fn as_f64(v: &serde_json::Value) -> f64 {
    v.as_str().unwrap().parse().unwrap()
}

#[test]
fn h5py_snippet_reads_what_rust_wrote() {
    let Some(python) = python_with_h5py() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("py");
    let mut manifest = manifest();
    manifest.truth_nav_rate_hz = Some(10.0);
    let opts = WriterOptions {
        rotate_after: Duration::from_secs(5),
        raw_journal: true,
        fsync_on_flush: false,
        ..WriterOptions::default()
    };
    let mut w = SessionWriter::create(&dir, manifest, opts).unwrap();
    let n = 1200; // 12 s: two completed files and a live partial one
    for start in (0..n).step_by(50) {
        let a: Vec<_> = (start..start + 50).map(|i| imu_row(0, i)).collect();
        let b: Vec<_> = (start..start + 50).map(|i| imu_row(1, i)).collect();
        w.append_imu("imu_a", &a).unwrap();
        w.append_imu("imu_b", &b).unwrap();
        let tru: Vec<_> = (start..start + 50).map(truth_imu).collect();
        w.append_truth_imu("imu_a", &tru).unwrap();
        let nav: Vec<_> = (start / 10..(start + 50) / 10).map(truth_nav).collect();
        w.append_truth_nav(&nav).unwrap();
        // One fix per 20 IMU rows (0.2 s); every other one without a heading.
        let fixes: Vec<_> = (start / 20..(start + 50) / 20)
            .map(|k| {
                let mut r = gnss_row(k);
                if k % 2 == 1 {
                    r.heading_deg = f64::NAN;
                }
                r
            })
            .collect();
        if !fixes.is_empty() {
            w.append_gnss("gps", &fixes).unwrap();
        }
        for i in start..start + 50 {
            w.append_raw("imu_a", imu_row(0, i).t_mono_ns, &raw_bytes(i))
                .unwrap();
        }
        if start == 600 {
            w.append_event(&EventRecord {
                t_mono_ns: imu_row(0, start).t_mono_ns,
                t_wall_ns: 5,
                device: "imu_b".into(),
                kind: EventKind::Resync,
                detail: "lost sync, 12 bytes skipped — ok".into(),
            })
            .unwrap();
        }
    }
    w.flush().unwrap();
    // The writer stays open: the last file is a live `.partial` that h5py reads with swmr=True.
    let dump = tmp.path().join("dump.json");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/read_session.py");
    let _serial = crate::common::child_process_guard();
    let out = Command::new(&python)
        .arg(&script)
        .arg(&dir)
        .arg("--dump-json")
        .arg(&dump)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "read_session.py failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(dir.join("chunk-000002.h5.partial").exists());
    w.close().unwrap();

    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&dump).unwrap()).unwrap();
    for (d, name) in ["imu_a", "imu_b"].iter().enumerate() {
        let t = &v[format!("imu/{name}")];
        assert_eq!(t["t_mono_ns"].as_array().unwrap().len(), n, "{name}");
        for i in [0, 1, 499, 500, 777, n - 1] {
            let r = imu_row(d, i);
            assert_eq!(t["t_mono_ns"][i].as_i64().unwrap(), r.t_mono_ns);
            assert_eq!(t["t_wall_ns"][i].as_i64().unwrap(), r.t_wall_ns);
            assert_eq!(as_f64(&t["t_sensor"][i]), r.t_sensor);
            for k in 0..3 {
                assert_eq!(as_f64(&t["gyro"][i][k]), r.gyro[k]);
                assert_eq!(as_f64(&t["accel"][i][k]), r.accel[k]);
            }
            assert_eq!(as_f64(&t["temp"][i]), r.temp);
            assert_eq!(t["status"][i].as_u64().unwrap(), u64::from(r.status));
        }
    }
    // The heading column of the GNSS table, NaN where a fix had none.
    let gps = &v["gnss/gps"];
    let headings = gps["heading_deg"].as_array().unwrap();
    assert_eq!(headings.len(), n / 20);
    for k in [0, 1, 2, 25, n / 20 - 1] {
        let h = as_f64(&headings[k]);
        if k % 2 == 1 {
            assert!(h.is_nan(), "fix {k}: {h}");
        } else {
            assert_eq!(h, gnss_row(k).heading_deg, "fix {k}");
        }
    }
    let nav = &v["truth/nav"];
    assert_eq!(nav["t_mono_ns"].as_array().unwrap().len(), n / 10);
    assert_eq!(as_f64(&nav["quat_nb"][33][3]), truth_nav(33).quat_nb[3]);
    let ti = &v["truth/imu/imu_a"];
    assert_eq!(
        as_f64(&ti["gyro_bias"][901][2]),
        truth_imu(901).gyro_bias[2]
    );
    let ev = &v["events"];
    let resync = ev["kind"]
        .as_array()
        .unwrap()
        .iter()
        .position(|k| k == "resync")
        .unwrap();
    assert_eq!(ev["device"][resync], "imu_b");
    assert_eq!(ev["detail"][resync], "lost sync, 12 bytes skipped — ok");
    assert!(ev["kind"]
        .as_array()
        .unwrap()
        .iter()
        .any(|k| k == "rotation"));
    // Raw: every read comes back at its offset in the concatenated bytes.
    let raw = &v["raw/imu_a"];
    let bytes: Vec<u8> = (0..raw["bytes"].as_str().unwrap().len() / 2)
        .map(|k| u8::from_str_radix(&raw["bytes"].as_str().unwrap()[2 * k..2 * k + 2], 16).unwrap())
        .collect();
    assert_eq!(raw["len"].as_array().unwrap().len(), n);
    for i in [0, 7, 500, n - 1] {
        let off = raw["offset"][i].as_u64().unwrap() as usize;
        let len = raw["len"][i].as_u64().unwrap() as usize;
        assert_eq!(
            &bytes[off..off + len],
            raw_bytes(i).as_slice(),
            "raw read {i}"
        );
    }
    let expect_total: usize = (0..n).map(|i| raw_bytes(i).len()).sum();
    assert_eq!(bytes.len(), expect_total);
}
