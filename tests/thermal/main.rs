//! `imulab thermal` end to end: a simulated chamber run with known coefficients is
//! characterised and the figures checked against the scene; bad temperature input gets
//! its message; the exported model compensates `imulab allan` and `imulab export`, and a
//! model of the drive scene's tempcos shrinks `imulab replay`'s outage drift.

use imulab_test_support::browser::{chromium, chromium_missing, run};
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

/// `imulab ARGS…`, which must succeed (its stderr is the failure message).
fn imulab_ok(args: &[&str]) -> Output {
    let out = imulab(args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn simulate(dir: &Path) -> std::path::PathBuf {
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let session = dir.join("session");
    imulab_ok(&[
        "sim",
        scene.to_str().unwrap(),
        "-o",
        session.to_str().unwrap(),
    ]);
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

    // The compensated export's accel_x no longer trends with temperature.
    let slope = |extra: &[&str]| -> (f64, String) {
        let csv = dir.path().join("export.csv");
        let mut args = vec![
            "export",
            session.to_str().unwrap(),
            "--device",
            "dut",
            "-o",
            csv.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let out = imulab(&args);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let text = std::fs::read_to_string(&csv).unwrap();
        let first = text.lines().next().unwrap().to_string();
        let header: Vec<&str> = text
            .lines()
            .find(|l| !l.starts_with('#'))
            .unwrap()
            .split(',')
            .collect();
        let col = |n: &str| header.iter().position(|h| *h == n).unwrap();
        let (ax, temp) = (col("accel_x"), col("temp"));
        // After the first soak (warm-up settled): least-squares slope of accel_x on temp.
        let points: Vec<(f64, f64)> = text
            .lines()
            .filter(|l| !l.starts_with('#'))
            .skip(1 + 1200 * 20)
            .map(|l| {
                let f: Vec<&str> = l.split(',').collect();
                (f[temp].parse().unwrap(), f[ax].parse().unwrap())
            })
            .collect();
        let n = points.len() as f64;
        let (mt, ma) = points
            .iter()
            .fold((0.0, 0.0), |(a, b), (t, v)| (a + t / n, b + v / n));
        let (sta, stt) = points.iter().fold((0.0, 0.0), |(a, b), (t, v)| {
            (a + (t - mt) * (v - ma), b + (t - mt) * (t - mt))
        });
        (sta / stt / 9.806_65e-3, first)
    };
    let (raw, raw_first) = slope(&[]);
    let (flat, first) = slope(&["--compensate", model.to_str().unwrap()]);
    assert!(raw_first.starts_with("t_mono_ns"), "{raw_first}");
    assert!(
        first.starts_with("# accel_x") && first.contains("compensated with thermal model"),
        "{first}"
    );
    // The scene: 0.8 mg/°C plus 0.004 mg/°C² about 25 °C, symmetric over 5..45 °C.
    assert!(within(raw, 0.8, 0.1), "uncompensated slope {raw} mg/°C");
    assert!(flat.abs() < 0.02, "compensated slope {flat} mg/°C");

    // A model of another device or with an axis a session IMU does not have: one line.
    let doc = std::fs::read_to_string(&model).unwrap();
    for (edited, wanted) in [
        (doc.replace("\"dut\"", "\"other\""), "no device `dut`"),
        (doc.replace("\"accel_x\"", "\"mag_x\""), "axis `mag_x`"),
    ] {
        let bad = dir.path().join("bad-model.json");
        std::fs::write(&bad, edited).unwrap();
        let out = imulab(&[
            "export",
            session.to_str().unwrap(),
            "--device",
            "dut",
            "--compensate",
            bad.to_str().unwrap(),
        ]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && stderr.contains(wanted), "{stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
}

/// Mean of the `max horizontal drift X m` lines of a replay's output.
fn mean_outage_drift(stdout: &str) -> f64 {
    let drifts: Vec<f64> = stdout
        .lines()
        .filter_map(|l| l.split("max horizontal drift ").nth(1))
        .map(|d| d.trim_end_matches(" m").parse().unwrap())
        .collect();
    assert_eq!(drifts.len(), 4, "{stdout}");
    drifts.iter().sum::<f64>() / drifts.len() as f64
}

#[test]
fn compensation_shrinks_the_outage_drift_of_a_thermal_drive() {
    let dir = tempfile::tempdir().unwrap();
    let scene = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/fixtures/scenes/thermal_drive.toml"
    );
    let session = dir.path().join("session");
    imulab_ok(&["sim", scene, "-o", session.to_str().unwrap()]);
    // The scene's own tempcos (°/h/°C, mg/°C about 25 °C) as a model.
    let (dph, mg) = (std::f64::consts::PI / 180.0 / 3600.0, 9.806_65e-3);
    let axes: Vec<serde_json::Value> = [
        ("gyro_x", "rad/s", 15.0 * dph),
        ("gyro_y", "rad/s", -12.0 * dph),
        ("gyro_z", "rad/s", 20.0 * dph),
        ("accel_x", "m/s^2", 0.5 * mg),
        ("accel_y", "m/s^2", -0.4 * mg),
        ("accel_z", "m/s^2", 0.3 * mg),
    ]
    .iter()
    .map(|(axis, unit, c1)| {
        serde_json::json!({"axis": axis, "unit": unit, "reference_c": 25.0,
            "valid_range_c": [10.0, 50.0], "coefficients": [0.0, c1], "ci95": [0.0, 0.0]})
    })
    .collect();
    let model = dir.path().join("model.json");
    let doc = serde_json::json!({"format": "imulab-thermal-model", "version": 1,
        "generator": "test", "source": "thermal_drive.toml", "temperature": "sensor",
        "devices": [{"device": "imu", "axes": axes}]});
    std::fs::write(&model, doc.to_string()).unwrap();
    let replay = |extra: &[&str]| -> String {
        let out_dir = dir.path().join("replay");
        let mut args = vec![
            "replay",
            session.to_str().unwrap(),
            "--outages",
            "every:120:30",
            "--out",
            out_dir.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let out = imulab(&args);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let before = mean_outage_drift(&replay(&[]));
    let compensated = replay(&["--compensate", model.to_str().unwrap()]);
    assert!(
        compensated.contains("thermally compensated"),
        "{compensated}"
    );
    let after = mean_outage_drift(&compensated);
    assert!(
        after < before / 3.0,
        "mean outage drift {before:.2} m without, {after:.2} m with compensation"
    );

    let bad = dir.path().join("other.json");
    std::fs::write(&bad, doc.to_string().replace("\"imu\"", "\"imu9\"")).unwrap();
    let out = imulab(&[
        "replay",
        session.to_str().unwrap(),
        "--compensate",
        bad.to_str().unwrap(),
        "--out",
        dir.path().join("bad").to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("no device `imu`"),
        "{stderr}"
    );
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

/// `imulab report` of a chamber session carries the thermal section with both plots; a real
/// headless Chromium renders it (skipped, saying why, without `/usr/bin/chromium`). With
/// `IMULAB_THERMAL_SCREENSHOT=FILE` the screenshot is copied there (docs/img/report-thermal.png).
#[test]
fn report_shows_the_thermal_section() {
    let dir = tempfile::tempdir().unwrap();
    let session = simulate(dir.path());
    let html = dir.path().join("report.html");
    imulab_ok(&[
        "report",
        session.to_str().unwrap(),
        "--html",
        html.to_str().unwrap(),
        "--axes",
        "accel_x,accel_y,accel_z",
        "--study-runs",
        "0",
        "--quiet",
    ]);
    let page = std::fs::read_to_string(&html).unwrap();
    let section = page
        .split("<section id=\"thermal\">")
        .nth(1)
        .expect("no thermal section in the report");
    assert!(section.contains("Thermal characterisation"));
    assert!(section.contains("bias against sensor temperature"));
    assert!(section.contains("temperature and bias against time"));
    assert!(section.contains("rising") && section.contains("falling"));
    assert!(
        page.find("<section id=\"thermal\">") < page.find("Data health"),
        "the thermal section comes before the data health"
    );

    if chromium_missing("the browser check") {
        return;
    }
    let profile = tempfile::tempdir().unwrap();
    let shot = dir.path().join("report.png");
    let render = |extra: &[String]| -> Output {
        let mut c = chromium(profile.path());
        c.args(extra).arg(format!("file://{}", html.display()));
        run(c)
    };
    let dom = render(&["--dump-dom".to_string()]);
    let dom = String::from_utf8_lossy(&dom.stdout);
    assert!(
        dom.contains("id=\"thermal\"") && dom.contains("bias against sensor temperature"),
        "chromium's DOM lacks the thermal section"
    );
    let out = render(&[
        format!("--screenshot={}", shot.display()),
        "--window-size=1200,1600".to_string(),
    ]);
    let png = std::fs::read(&shot).unwrap_or_else(|e| {
        panic!(
            "no screenshot ({e}): {}",
            String::from_utf8_lossy(&out.stderr)
        )
    });
    assert!(
        png.starts_with(b"\x89PNG") && png.len() > 10_000,
        "{} bytes",
        png.len()
    );
    if let Ok(copy) = std::env::var("IMULAB_THERMAL_SCREENSHOT") {
        std::fs::copy(&shot, copy).unwrap();
    }
}

/// The chamber run with ±1 g poses at the end of each soak (fixtures/scenes/chamber_poses.toml):
/// the accelerometer scale tempco comes from the poses, and the turns stay out of every axis's
/// bias fit, so the pitch axis's gyro and the z accelerometer (1 g → 0 in the poses) keep the
/// tempcos a static run gives.
#[test]
fn a_chamber_run_with_poses_gives_the_scale_tempco_and_clean_bias_fits() {
    let dir = tempfile::tempdir().unwrap();
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/scenes/chamber_poses.toml");
    let session = dir.path().join("session");
    imulab_ok(&[
        "sim",
        scene.to_str().unwrap(),
        "-o",
        session.to_str().unwrap(),
    ]);
    let json = dir.path().join("thermal.json");
    imulab_ok(&[
        "thermal",
        session.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
    ]);
    let doc: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let axes = doc["devices"][0]["axes"].as_array().unwrap().clone();
    let names: Vec<&str> = axes.iter().map(|a| a["axis"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        ["gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"],
        "axes in the session's order"
    );
    let axis = |name: &str| axes.iter().find(|a| a["axis"] == name).unwrap();
    let c1 = |name: &str| axis(name)["coefficients"][1]["value"].as_f64().unwrap();
    let residual = |name: &str| axis(name)["fit"]["residual_rms"].as_f64().unwrap();
    // The preset (icm20948-thermal): accel scale tempco 260 ppm/°C; gyro y bias tempco
    // −20 °/h/°C; accel z 0.80 mg/°C, less the 0.26 mg/°C its scale tempco adds under −1 g.
    let scale = axis("accel_x")["scale_factor"]["coefficients"][1]["value"]
        .as_f64()
        .unwrap();
    assert!(within(scale, 260.0, 0.05), "scale tempco {scale} ppm/°C");
    assert!(
        within(c1("gyro_y"), -20.0, 0.05),
        "gyro_y c1 {}",
        c1("gyro_y")
    );
    assert!(
        within(c1("accel_z"), 0.54, 0.05),
        "accel_z c1 {}",
        c1("accel_z")
    );
    // Residuals at the noise of 1 s blocks: the ICM's 54 °/h/√Hz gyro and ~0.3 mg accel.
    let dph = std::f64::consts::PI / 180.0 / 3600.0;
    for gyro in ["gyro_x", "gyro_y", "gyro_z"] {
        assert!(
            residual(gyro) < 100.0 * dph,
            "{gyro} residual {} rad/s",
            residual(gyro)
        );
    }
    for accel in ["accel_x", "accel_y", "accel_z"] {
        assert!(
            residual(accel) < 1e-3 * 9.80665,
            "{accel} residual {} m/s²",
            residual(accel)
        );
    }
}
