//! `imulab demo` end to end on a short run (3 simulated minutes served at 30×): the chamber
//! goes through the `imulogd` binary over ptys, the session holds every row the simulator
//! sent (its `served.json` report against the session's row counts), and the white-noise
//! terms of the demo's `report.json` (ARW °/√h and VRW mg/√Hz per axis) agree with the
//! bench presets of issue 5 within the report's own confidence intervals.

use std::path::Path;
use std::process::Command;

/// Issue 5's presets per axis x/y/z: device, sensor, term, unit of the report compared,
/// values as in the seed paper (ARW °/√h; VRW "mg/√h", i.e. 60 × mg/√Hz) and the factor from
/// the report's unit per √Hz to that of the paper's values.
type Preset = (
    &'static str,
    &'static str,
    &'static str,
    &'static str,
    [f64; 3],
    f64,
);
const PRESETS: [Preset; 4] = [
    (
        "cheap",
        "gyro",
        "ARW",
        "deg/sqrt(h)",
        [0.36, 0.31, 0.30],
        1.0,
    ),
    (
        "dear",
        "gyro",
        "ARW",
        "deg/sqrt(h)",
        [0.30, 0.26, 0.30],
        1.0,
    ),
    (
        "cheap",
        "accel",
        "VRW",
        "mg/sqrt(Hz)",
        [6.6, 7.9, 8.5],
        60.0,
    ),
    ("dear", "accel", "VRW", "mg/sqrt(Hz)", [2.8, 3.0, 2.8], 60.0),
];

/// The white noise a 16-bit WitMotion frame adds (the demo serves `cheap` as WitMotion, `dear`
/// as Xbus float32, whose rounding is negligible): one LSB of rounding is uniform, variance
/// LSB²/12 per sample, i.e. a white noise density of LSB/√12 · √τ0: in °/√h (× 60) for the
/// gyro, mg/√Hz for the accelerometer.
fn wire_white_noise(device: &str, sensor: &str) -> f64 {
    if device != "cheap" {
        return 0.0;
    }
    let (lsb, per_sqrt_hz) = match sensor {
        "gyro" => (2000.0 / 32768.0, 60.0), // °/s (±2000 °/s full scale), to °/√h
        _ => (16.0 / 32768.0 * 1000.0, 1.0), // mg (±16 g full scale), mg/√Hz
    };
    lsb / 12f64.sqrt() * (1.0f64 / 150.0).sqrt() * per_sqrt_hz
}

fn session_rows(session: &Path, group: &str) -> u64 {
    imulab::store::Session::open(session)
        .unwrap_or_else(|e| panic!("{e}"))
        .stream_summary(group)
        .rows
}

#[test]
fn demo_logs_through_imulogd_and_recovers_the_bench_presets() {
    let out = tempfile::tempdir().unwrap();
    let run = Command::new(env!("CARGO_BIN_EXE_imulab"))
        .args([
            "demo",
            "--minutes",
            "3",
            "--speed",
            "30",
            "--runs",
            "2",
            "--out",
        ])
        .arg(out.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stdout}\n{stderr}");
    for stage in 1..=5 {
        assert!(stderr.contains(&format!("[{stage}/5] ")), "{stderr}");
    }
    for line in ["\n1. ", "\n2. ", "\n3. ", "imulogd exited 0"] {
        assert!(stdout.contains(line), "{line:?} missing:\n{stdout}");
    }
    for file in [
        "report.html",
        "imulogd.toml",
        "study.json",
        "drive/replay-cheap/errors.json",
    ] {
        assert!(out.path().join(file).is_file(), "{file} missing");
    }

    // Every row the simulator sent is in the session imulogd wrote.
    let served: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.path().join("served.json")).unwrap()).unwrap();
    assert_eq!(served["undelivered_bytes"], 0);
    let session = out.path().join("session");
    let streams = served["streams"].as_array().unwrap();
    assert_eq!(streams.len(), 3);
    for s in streams {
        let (name, frames) = (s["sensor"].as_str().unwrap(), s["frames"].as_u64().unwrap());
        let (group, per_frame) = match s["protocol"].as_str().unwrap() {
            // Each mixed epoch is stored once: its UBX and NMEA messages merge.
            "gnss" => (format!("/gnss/{name}"), 1),
            _ => (format!("/imu/{name}"), 1),
        };
        assert!(frames > 0, "{name}: nothing served");
        assert_eq!(session_rows(&session, &group), frames * per_frame, "{name}");
    }
    assert_eq!(session_rows(&session, "/imu/cheap"), 3 * 60 * 150);

    // Each fitted term in report.json carries its 95 % interval (`low`, `high`); the preset,
    // combined with the wire's rounding noise (quadrature sum), must lie inside it. The demo's
    // seed is fixed, so this is deterministic: with 12 terms at 95 % a changed seed or model may
    // put one outside by chance; look at the printed values before widening anything.
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.path().join("report.json")).unwrap()).unwrap();
    let axes = report["axes"].as_array().unwrap();
    for (device, sensor, term, unit, values, paper_factor) in PRESETS {
        for (i, axis) in ["x", "y", "z"].iter().enumerate() {
            let name = format!("{sensor}_{axis}");
            let a = axes
                .iter()
                .find(|a| a["device"] == device && a["axis"] == name.as_str())
                .unwrap_or_else(|| panic!("{device} {name} missing"));
            let t = a["terms"]
                .as_array()
                .unwrap()
                .iter()
                .find(|t| t["name"] == term)
                .unwrap_or_else(|| panic!("{device} {name}: no {term}"));
            assert_eq!(t["identified"], true, "{device} {name} {term}");
            let v = t["values"]
                .as_array()
                .unwrap()
                .iter()
                .find(|v| v["unit"] == unit)
                .unwrap();
            let value = v["value"].as_f64().unwrap();
            let (low, high) = (v["low"].as_f64().unwrap(), v["high"].as_f64().unwrap());
            let expected = (values[i] / paper_factor).hypot(wire_white_noise(device, sensor));
            println!("{device} {name} {term}: {value:.4} [{low:.4}, {high:.4}] vs {expected:.4}");
            assert!(
                low <= expected && expected <= high,
                "{device} {name} {term}: {value} [95 % {low}, {high}] vs preset {} (with the wire's rounding {expected})",
                values[i]
            );
        }
    }
}

#[test]
fn demo_without_imulogd_says_how_to_build_it() {
    let dir = tempfile::tempdir().unwrap();
    let lone = dir.path().join("imulab");
    std::fs::copy(env!("CARGO_BIN_EXE_imulab"), &lone).unwrap();
    let run = Command::new(&lone)
        .args(["demo", "--out"])
        .arg(dir.path().join("out"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success());
    assert!(
        stderr.contains("imulogd not found") && stderr.contains("cargo build --release --bins"),
        "{stderr}"
    );
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
}

#[test]
fn demo_without_out_writes_to_a_new_directory_it_names() {
    let dir = tempfile::tempdir().unwrap();
    let lone = dir.path().join("imulab");
    std::fs::copy(env!("CARGO_BIN_EXE_imulab"), &lone).unwrap();
    let tmp = dir.path().join("tmp");
    std::fs::create_dir(&tmp).unwrap();
    // Run from a directory of its own: nothing may appear there.
    let cwd = dir.path().join("cwd");
    std::fs::create_dir(&cwd).unwrap();
    let run = Command::new(&lone)
        .arg("demo")
        .current_dir(&cwd)
        .env("TMPDIR", &tmp)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    let made: Vec<_> = std::fs::read_dir(&tmp)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(made.len(), 1, "{made:?}");
    let name = made[0].file_name().unwrap().to_string_lossy().into_owned();
    assert!(name.starts_with("imulab-demo-"), "{name}");
    assert!(
        stderr.contains(&format!(
            "writing to {}",
            made[0].canonicalize().unwrap().display()
        )),
        "{stderr}"
    );
    assert_eq!(std::fs::read_dir(&cwd).unwrap().count(), 0);
}
