//! `imulab thermal` end to end: a simulated chamber run with known coefficients is
//! characterised and the figures checked against the scene; bad temperature input gets
//! its message; the exported model compensates `imulab allan`.

use std::path::Path;
use std::process::{Command, Output};

const IMULAB: &str = env!("CARGO_BIN_EXE_imulab");

/// A 2 h 20 min run at 20 Hz: soak, ramp 25 → 45 °C, soak, ramp down to 5 °C, soak, back up.
const SCENE: &str = r#"
duration_s = 8400
rate_hz = 20
seed = 5
[location]
lat_deg = 48.0
lon_deg = 11.0
height_m = 500.0
[motion]
kind = "static"
[temperature]
kind = "program"
start_c = 25.0
segments = [
  { kind = "soak", duration_s = 1200 },
  { kind = "ramp", to_c = 45.0, c_per_min = 1.0 },
  { kind = "soak", duration_s = 1200 },
  { kind = "ramp", to_c = 5.0, c_per_min = 1.0 },
  { kind = "soak", duration_s = 1200 },
  { kind = "ramp", to_c = 25.0, c_per_min = 1.0 },
]
[[imu]]
name = "dut"
channels = ["accel"]
[imu.accel]
noise_density_ug_rthz = [100.0, 100.0, 100.0]
bias_tempco_mg_per_c = [0.8, -0.5, 0.0]
bias_tempco2_mg_per_c2 = [0.004, 0.0, 0.0]
bias_hysteresis_mg = [0.0, 0.6, 0.0]
warmup_bias_mg = [3.0, 0.0, 0.0]
[imu.thermal]
time_constant_s = 60.0
hysteresis_width_c = 2.0
warmup_time_constant_s = 150.0
[outputs]
truth_nav = false
truth_imu = false
"#;

fn imulab(args: &[&str]) -> Output {
    Command::new(IMULAB)
        .args(args)
        .output()
        .expect("run imulab")
}

fn simulate(dir: &Path) -> std::path::PathBuf {
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let session = dir.join("session");
    let out = imulab(&[
        "sim",
        scene.to_str().unwrap(),
        "-o",
        session.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    session
}

fn within(value: f64, truth: f64, fraction: f64) -> bool {
    (value - truth).abs() <= fraction * truth.abs()
}

#[test]
fn recovers_the_scene_and_the_model_compensates_allan() {
    let dir = tempfile::tempdir().unwrap();
    let session = simulate(dir.path());
    let json = dir.path().join("thermal.json");
    let model = dir.path().join("model.json");
    let html = dir.path().join("thermal.html");
    let out = imulab(&[
        "thermal",
        session.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
        "--model",
        model.to_str().unwrap(),
        "--html",
        html.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("thermal lag chamber → sensor"), "{stdout}");
    let doc: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let device = &doc["devices"][0];
    let lag = device["lag"]["time_constant_s"].as_f64().unwrap();
    assert!(within(lag, 60.0, 0.05), "lag {lag}");
    let axis = |name: &str| {
        device["axes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|a| a["axis"] == name)
            .unwrap()
            .clone()
    };
    let x = axis("accel_x");
    let c1 = x["coefficients"][1]["value"].as_f64().unwrap();
    let c2 = x["coefficients"][2]["value"].as_f64().unwrap();
    assert!(within(c1, 0.8, 0.05), "c1 {c1}");
    assert!(within(c2, 0.004, 0.05), "c2 {c2}");
    let tau = x["warmup"]["time_constant_s"].as_f64().unwrap();
    let amplitude = x["warmup"]["amplitude"].as_f64().unwrap();
    assert!(within(tau, 150.0, 0.1), "warm-up τ {tau}");
    assert!(within(amplitude, 3.0, 0.1), "warm-up amplitude {amplitude}");
    let y = axis("accel_y");
    let gap = y["hysteresis"]["largest_gap"].as_f64().unwrap();
    assert!(within(gap, 0.6, 0.1), "hysteresis gap {gap}");
    assert!(!y["plateaus"].as_array().unwrap().is_empty());
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(page.contains("<svg") && page.contains("Thermal characterisation"));

    // The model removes the temperature dependence: the long-τ Allan deviation drops.
    let long_tau = |extra: &[&str]| -> f64 {
        let json = dir.path().join("allan.json");
        let mut args = vec![
            "allan",
            session.to_str().unwrap(),
            "--axes",
            "accel_x",
            "--json",
            json.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let out = imulab(&args);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let doc: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
        let points = doc["axes"][0]["curve"]["points"]
            .as_array()
            .unwrap()
            .clone();
        points
            .iter()
            .rev()
            .find_map(|p| p["deviation"].as_f64())
            .unwrap()
    };
    let before = long_tau(&[]);
    let after = long_tau(&["--compensate", model.to_str().unwrap()]);
    assert!(after < before / 10.0, "before {before}, after {after}");
}

fn write_csv(dir: &Path, name: &str, temps: impl Fn(usize) -> String) -> std::path::PathBuf {
    let path = dir.join(name);
    let mut text = String::from("accel_x,temp\n");
    for i in 0..20_000 {
        text.push_str(&format!("{},{}\n", 1e-3 * (i % 7) as f64, temps(i)));
    }
    std::fs::write(&path, text).unwrap();
    path
}

fn fails_with(args: &[&str], wanted: &str) {
    let out = imulab(args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} succeeded");
    assert!(stderr.contains(wanted), "{args:?}: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn bad_temperature_input_is_explained() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let p = |p: &Path| p.to_str().unwrap().to_string();
    let no_temp = d.join("no_temp.csv");
    std::fs::write(&no_temp, "accel_x\n0.1\n0.2\n").unwrap();
    fails_with(
        &["thermal", &p(&no_temp), "--rate", "10"],
        "no temperature column `temp`",
    );
    let constant = write_csv(d, "constant.csv", |_| "25.0".into());
    fails_with(
        &["thermal", &p(&constant), "--rate", "10"],
        "in every sample",
    );
    let all_nan = write_csv(d, "nan.csv", |_| "NaN".into());
    fails_with(
        &["thermal", &p(&all_nan), "--rate", "10"],
        "no valid temperature reading",
    );
    let hot = write_csv(d, "hot.csv", |i| {
        if i % 3 == 0 {
            "20.0".into()
        } else {
            "900".into()
        }
    });
    fails_with(
        &["thermal", &p(&hot), "--rate", "10"],
        "outside -60 to 150 °C",
    );
    // Two temperatures only (a step): too few for any fit with a check, and for --order 2.
    let two = write_csv(d, "two.csv", |i| {
        if i < 10_000 {
            "20.0".into()
        } else {
            "40.0".into()
        }
    });
    fails_with(&["thermal", &p(&two), "--rate", "10"], "at least 3");
    let three = write_csv(d, "three.csv", |i| format!("{}", 20 + 10 * (i / 7000)));
    fails_with(
        &["thermal", &p(&three), "--rate", "10", "--order", "2"],
        "--order 2 needs at least 4 distinct temperatures",
    );
    // Stuck at 30 °C while the logged chamber ramps from 20 to 60 °C.
    let stuck = d.join("stuck.csv");
    let mut text = String::from("accel_x,temp,chamber\n");
    for i in 0..20_000 {
        let chamber = 20.0 + 40.0 * i as f64 / 20_000.0;
        let temp = if i < 5000 { chamber } else { 30.0 };
        text.push_str(&format!("0.001,{temp},{chamber}\n"));
    }
    std::fs::write(&stuck, text).unwrap();
    fails_with(
        &[
            "thermal",
            &p(&stuck),
            "--rate",
            "10",
            "--chamber-column",
            "chamber",
        ],
        "stuck at 30 °C",
    );
}
