//! Calibration: recovery of the simulator's true bias, scale factors and misalignment from
//! simulated tumbles, six-position and rate-table runs; the checks that refuse data which
//! cannot support a fit; and `imulab calibrate` end to end with `--calibration` applied by
//! `export` and `allan`.

use imulab::calib::recording::Recording;
use imulab::calib::run::{calibrate, calibrate_inputs, Gravity, Mode, Options, Outcome};
use imulab::calib::statics::DetectorOptions;
use imulab::calib::truth::Truth;
use imulab::calib::TriadModel;
use imulab::earth;
use imulab::sim::outputs::MemorySink;
use imulab::sim::runner::run;
use imulab::sim::scene::Scene;
use std::path::Path;
use std::process::Command;

/// A tumble scene text: `poses` random poses held `hold` s, one IMU `preset` with the given
/// accel/gyro scale (ppm) and misalignment (mrad) overrides.
fn tumble_scene(preset: &str, poses: usize, hold: f64, rate: f64, seed: u64) -> String {
    let duration = 30.0 + poses as f64 * (hold + 3.0) + 5.0;
    format!(
        r#"
duration_s = {duration}
rate_hz = {rate}
seed = {seed}
[location]
lat_deg = 45.0
lon_deg = 7.0
height_m = 250.0
[motion]
kind = "tumble"
first_hold_s = 30
hold_s = {hold}
rotate_s = 3
poses = {poses}
[[imu]]
name = "imu"
preset = "{preset}"
[imu.gyro]
scale_factor_ppm = [3000, -2000, 4000]
misalignment_mrad = [2.0, -3.0, 1.5, 2.5, -1.0, 3.0]
[imu.accel]
bias_mg = [20, -15, 25]
scale_factor_ppm = [2500, -3000, 1800]
misalignment_mrad = [2.0, -1.5, 3.0, -2.0, 1.0, 2.5]
[outputs]
truth_nav = false
truth_imu = true
truth_every = 100
"#
    )
}

/// Simulates `text` in memory; returns the recording, the truth and local gravity.
fn simulate(text: &str) -> (Recording, Truth, f64) {
    let scene = Scene::parse(text, Path::new(".")).expect("scene");
    let mut sink = MemorySink::default();
    run(&scene, &mut sink).expect("run");
    let rec = Recording::from_records("imu", &sink.imu["imu"]);
    let truth_rows = &sink.truth_imu["imu"];
    let n = truth_rows.len() as f64;
    let mut g = [0.0; 3];
    let mut a = [0.0; 3];
    for r in truth_rows {
        for k in 0..3 {
            g[k] += r.gyro_bias[k] / n;
            a[k] += r.accel_bias[k] / n;
        }
    }
    let truth = Truth::of_spec(&scene.imus[0].spec, g, a);
    let loc = scene.location;
    let gravity = earth::normal_gravity(loc.lat_deg.to_radians(), loc.height_m);
    (rec, truth, gravity)
}

fn options(mode: Mode, g: f64) -> Options {
    Options {
        mode,
        detector: DetectorOptions::default(),
        gravity: Gravity::Value(g),
    }
}

/// Largest |fitted − true| of the scale factors (ppm), the off-diagonals (mrad) and the
/// biases, each also as a multiple of the stated 1σ.
fn errors(fit: &TriadModel, truth: &TriadModel) -> (f64, f64, f64) {
    let mut scale = 0.0f64;
    let mut mis = 0.0f64;
    let mut bias = 0.0f64;
    for i in 0..3 {
        for j in 0..3 {
            let e = (fit.matrix[i][j] - truth.matrix[i][j]).abs();
            if i == j {
                scale = scale.max(e * 1e6);
            } else {
                mis = mis.max(e * 1e3);
            }
        }
        bias = bias.max((fit.bias[i] - truth.bias[i]).abs());
    }
    (scale, mis, bias)
}

fn outcome(text: &str, mode: Mode) -> (Outcome, Truth, f64) {
    let (rec, truth, g) = simulate(text);
    let o = calibrate(&rec, &options(mode, g)).expect("calibrate");
    (o, truth, g)
}

#[test]
fn tumble_recovers_accel_and_gyro_of_an_industrial_imu() {
    let (o, truth, g) = outcome(
        &tumble_scene("industrial", 24, 8.0, 100.0, 4),
        Mode::MultiPosition,
    );
    let c = &o.calibration;
    let accel = c.accel.as_ref().unwrap();
    let gyro = c.gyro.as_ref().unwrap();
    let (s, m, b) = errors(accel, &truth.accel);
    // Industrial accel noise 120 µg/√Hz over 8 s poses: scale and misalignment to ~0.1 ‰.
    assert!(s < 200.0, "accel scale error {s} ppm\n{c:#?}");
    assert!(m < 0.2, "accel misalignment error {m} mrad");
    assert!(
        b < 0.1e-3 * 9.80665,
        "accel bias error {} mg",
        b / 9.80665e-3
    );
    // Each accel parameter within 4σ of its stated uncertainty.
    for i in 0..3 {
        let e = (accel.matrix[i][i] - truth.accel.matrix[i][i]).abs();
        assert!(
            e < 4.0 * accel.matrix_sigma[i][i],
            "axis {i}: {e} vs σ {}",
            accel.matrix_sigma[i][i]
        );
    }
    let (s, m, _) = errors(gyro, &truth.gyro);
    assert!(
        s < 1000.0,
        "gyro scale error {s} ppm\n{gyro:#?}\n{:#?}",
        truth.gyro
    );
    assert!(m < 1.0, "gyro misalignment error {m} mrad");
    let q = &c.quality;
    // Calibration takes the gravity residual from the uncalibrated level to the noise.
    let (before, after) = (
        q.gravity_residual_before.unwrap(),
        q.gravity_residual_after.unwrap(),
    );
    assert!(before > 10.0 * after, "{before} {after}");
    assert!(after < 0.05e-3 * g, "{after}");
    assert!(q.rotation_residual_after.unwrap() < q.rotation_residual_before.unwrap() / 5.0);
    assert_eq!(q.poses, 25);
    assert_eq!(q.rotations, 24);
}

/// The bias-drift model selection: a steady accelerometer bias keeps the constant-bias fit; a
/// bias ramping 4 mg/h is kept as a drift, recovered within its interval, and takes the gravity
/// residual down to the white-noise level.
#[test]
fn accel_bias_drift_is_fitted_only_when_the_bias_moves() {
    let steady = tumble_scene("industrial", 30, 8.0, 100.0, 5).replace(
        "bias_mg = [20, -15, 25]",
        "bias_mg = [20, -15, 25]\nbias_instability_mg = [0, 0, 0]\nrrw_mg_rth = [0, 0, 0]",
    );
    let (o, _, _) = outcome(&steady, Mode::MultiPosition);
    let q = &o.calibration.quality;
    assert_eq!(q.accel_bias_drift, None, "{q:?}");
    assert_eq!(q.gravity_residual_after, q.gravity_residual_constant_bias);
    let ramp_mg_h = [4.0, -3.0, 5.0];
    let ramping = steady.replace(
        "rrw_mg_rth = [0, 0, 0]",
        "rrw_mg_rth = [0, 0, 0]\nrate_ramp_mg_per_h = [4.0, -3.0, 5.0]",
    );
    let (o, truth, g) = outcome(&ramping, Mode::MultiPosition);
    let q = &o.calibration.quality;
    let (drift, sigma) = (
        q.accel_bias_drift.expect("drift kept"),
        q.accel_bias_drift_sigma.unwrap(),
    );
    for k in 0..3 {
        let want = ramp_mg_h[k] * 9.80665e-3 / 3600.0;
        assert!(
            (drift[k] - want).abs() < 3.0 * sigma[k],
            "axis {k}: {} vs {want} (σ {})",
            drift[k],
            sigma[k]
        );
    }
    let (constant, after) = (
        q.gravity_residual_constant_bias.unwrap(),
        q.gravity_residual_after.unwrap(),
    );
    assert!(after < 0.7 * constant, "{after} vs {constant}");
    assert!(after < 0.06e-3 * g, "{after}");
    assert!(
        o.notes.iter().any(|n| n.contains("drifted")),
        "{:?}",
        o.notes
    );
    // The bias written is the run's mean bias (the truth's), at the middle of the poses.
    let a = o.calibration.accel.unwrap();
    for k in 0..3 {
        assert!(
            (a.bias[k] - truth.accel.bias[k]).abs() < 0.05e-3 * g,
            "{a:?}"
        );
    }
}

#[test]
fn six_position_finds_each_face_and_the_full_matrix() {
    let text = tumble_scene("industrial", 5, 10.0, 100.0, 2).replace(
        "poses = 5",
        "orientations = [[180, 0, 0], [90, 0, 0], [-90, 0, 0], [0, 90, 0], [0, -90, 0]]",
    );
    let (o, truth, _) = outcome(&text, Mode::SixPosition);
    let mut faces = o.faces.clone();
    faces.sort();
    assert_eq!(
        faces,
        ["+x up", "+y up", "+z up", "-x up", "-y up", "-z up"]
    );
    // The fixture's frame is the body frame: compare with the simulator's own M.
    let a = o.calibration.accel.unwrap();
    assert!((a.matrix[0][0] - 1.0025).abs() < 3e-4, "{a:?}");
    assert!((a.matrix[0][1] - 0.002).abs() < 3e-4, "{a:?}");
    assert!(
        (a.bias[0] - truth.accel.bias[0]).abs() < 0.2e-3 * 9.8,
        "{a:?}"
    );
}

#[test]
fn rate_table_measures_scale_factor_on_the_spindle_axis() {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/scenes/rate_table.toml"),
    )
    .unwrap()
    .replace("name = \"stim\"", "name = \"imu\"");
    let dir = tempfile::tempdir().unwrap();
    let table = dir.path().join("rates.csv");
    std::fs::write(&table, "rate_dps\n10\n-10\n50\n-50\n100\n-100\n200\n-200\n").unwrap();
    let (o, _, _) = outcome(&text, Mode::RateTable(table));
    let axes = o.calibration.rate_table.unwrap();
    assert_eq!(axes.len(), 1);
    let t = &axes[0];
    assert_eq!(t.axis, "z");
    assert!(
        o.notes.iter().any(|n| n.contains("one mounting")),
        "{:?}",
        o.notes
    );
    // The scene's z scale factor is 450 ppm; tactical ARW over 20 s segments leaves ~10 ppm.
    assert!((t.scale_factor_ppm - 450.0).abs() < 30.0, "{t:?}");
    assert!(t.nonlinearity_ppm_of_full_scale < 50.0, "{t:?}");
    let g = o.calibration.gyro.unwrap();
    // Cross-axis: M_xz = 0.3 mrad... the x row's z entry is misalignment xz = -0.3 mrad.
    assert!((g.matrix[0][2] + 0.3e-3).abs() < 0.05e-3, "{g:?}");
}

fn fixture(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/scenes")
        .join(name)
}

fn rate_table_3axis() -> String {
    std::fs::read_to_string(fixture("rate_table_3axis.toml"))
        .unwrap()
        .replace("name = \"stim\"", "name = \"imu\"")
}

/// The three-mounting program (x up, -y along the spindle, z down; eight rates each): the
/// whole gyro M, each axis's scale factor and quadratic term, against the simulator's truth
/// and the stated 95 % intervals.
#[test]
fn rate_table_three_mountings_recover_the_whole_gyro_matrix() {
    let text = rate_table_3axis();
    let scene = Scene::parse(&text, Path::new(".")).unwrap();
    let quadratic = scene.imus[0].spec.gyro.scale_quadratic_ppm_per_dps;
    let (o, truth, _) = outcome(&text, Mode::RateTable(fixture("rate_table_3axis.csv")));
    let c = &o.calibration;
    assert!(c.frame.contains("mounting fixture"), "{}", c.frame);
    let axes = c.rate_table.as_ref().unwrap();
    let names: Vec<&str> = axes.iter().map(|a| a.axis.as_str()).collect();
    assert_eq!(names, ["x", "-y", "z"]);
    let g = c.gyro.as_ref().unwrap();
    let t = &truth.gyro_body;
    // Every entry of M measured, each within a small multiple of its stated 1σ, and most
    // inside the 95 % interval (1.96σ).
    let mut inside = 0;
    let mut report = String::new();
    for i in 0..3 {
        for j in 0..3 {
            let (e, s) = (g.matrix[i][j] - t.matrix[i][j], g.matrix_sigma[i][j]);
            report += &format!("M[{i}][{j}] error {:+.2e} σ {:.2e}\n", e, s);
            assert!(s > 0.0 && s < 2e-5, "{report}");
            assert!(e.abs() < 3.5 * s, "{report}");
            inside += usize::from(e.abs() < 1.96 * s);
        }
    }
    for (k, a) in axes.iter().enumerate() {
        let (e, s) = (
            a.quadratic_ppm_per_dps - quadratic[k],
            a.quadratic_sigma_ppm_per_dps,
        );
        report += &format!("axis {k} quadratic error {e:+.4} σ {s:.4}\n");
        assert!(s > 0.0 && s < 0.05, "{report}");
        assert!(e.abs() < 3.5 * s, "{report}");
        inside += usize::from(e.abs() < 1.96 * s);
    }
    println!("{report}");
    assert!(
        inside >= 10,
        "{inside} of 12 inside the 95 % interval\n{report}"
    );
    // The quadratic term shows as non-linearity of the order of k·full scale.
    assert!(axes[0].nonlinearity_ppm_of_full_scale > 10.0, "{axes:?}");
}

/// One mounting of the three-mounting program as a scene of its own (its own seed, so its
/// own noise and turn-on bias): what a user who records each mounting separately has.
fn rate_table_mounting(k: usize) -> String {
    let lines = [
        "  { axis = \"x\", pitch_deg = 90 },\n",
        "  { axis = \"-y\", roll_deg = 90 },\n",
        "  { axis = \"z\" },\n",
    ];
    let mut text = rate_table_3axis()
        .replace("duration_s = 650", "duration_s = 215")
        .replace("seed = 29", &format!("seed = {}", 41 + k));
    for (j, line) in lines.iter().enumerate() {
        if j != k {
            text = text.replace(line, "");
        }
    }
    text
}

/// Each entry of the fitted M against the truth: all within 3.5σ, and how many inside the
/// 95 % interval.
fn inside_95(g: &TriadModel, truth: &TriadModel, what: &str) -> usize {
    let mut inside = 0;
    let mut report = String::new();
    for i in 0..3 {
        for j in 0..3 {
            let (e, s) = (g.matrix[i][j] - truth.matrix[i][j], g.matrix_sigma[i][j]);
            report += &format!("{what} M[{i}][{j}] error {e:+.2e} σ {s:.2e}\n");
            assert!(s > 0.0 && s < 2e-5, "{report}");
            assert!(e.abs() < 3.5 * s, "{report}");
            inside += usize::from(e.abs() < 1.96 * s);
        }
    }
    println!("{report}");
    inside
}

/// The three mountings recorded as three inputs, each on its own clock: the segments are
/// found in each, the rows go to the inputs in order, and the whole M comes out as from the
/// single recording, each entry within its 95 % interval of the truth. The same rows with
/// times and an `input` column naming the inputs give the same M; times without an `input`
/// column are refused.
#[test]
fn rate_table_mountings_as_three_inputs_recover_the_same_matrix_as_one_recording() {
    let csv = fixture("rate_table_3axis.csv");
    let (single, truth, g) = outcome(&rate_table_3axis(), Mode::RateTable(csv.clone()));
    let recs: Vec<Recording> = (0..3)
        .map(|k| {
            let mut rec = simulate(&rate_table_mounting(k)).0;
            rec.name = format!("runs/mount-{k}");
            rec
        })
        .collect();
    let three = calibrate_inputs(&recs, &options(Mode::RateTable(csv), g)).unwrap();
    let per_input: Vec<usize> = three.inputs.iter().map(|i| i.segments).collect();
    assert_eq!(per_input, [8, 8, 8]);
    for s in &three.segments {
        // On its own input's clock: inside that input's 215 s.
        assert!(s.t_end < 215.0, "{s:?}");
        assert_eq!(s.spindle, s.input, "{s:?}");
    }
    let c = &three.calibration;
    let names: Vec<&str> = c
        .rate_table
        .as_ref()
        .unwrap()
        .iter()
        .map(|a| a.axis.as_str())
        .collect();
    assert_eq!(names, ["x", "-y", "z"]);
    assert!(c.frame.contains("mounting fixture"), "{}", c.frame);
    let (m1, m3) = (
        single.calibration.gyro.as_ref().unwrap(),
        c.gyro.as_ref().unwrap(),
    );
    let t = &truth.gyro_body;
    let (in1, in3) = (
        inside_95(m1, t, "one input"),
        inside_95(m3, t, "three inputs"),
    );
    assert!(
        in1 >= 8 && in3 >= 8,
        "inside the 95 % interval: {in1} and {in3} of 9"
    );
    for i in 0..3 {
        for j in 0..3 {
            let s = m1.matrix_sigma[i][j].hypot(m3.matrix_sigma[i][j]);
            let d = m3.matrix[i][j] - m1.matrix[i][j];
            assert!(d.abs() < 3.0 * s, "M[{i}][{j}]: {d:+.2e} apart, σ {s:.2e}");
        }
    }

    // The rows with the segments' times, each naming its input by path's last component.
    let dir = tempfile::tempdir().unwrap();
    let table = dir.path().join("rates.csv");
    let mut text = String::from("rate_dps,start_s,end_s,input\n");
    for s in &three.segments {
        text += &format!(
            "{},{},{},mount-{}\n",
            s.rate_dps, s.t_start, s.t_end, s.input
        );
    }
    std::fs::write(&table, &text).unwrap();
    let timed = calibrate_inputs(&recs, &options(Mode::RateTable(table.clone()), g)).unwrap();
    let mt = timed.calibration.gyro.as_ref().unwrap();
    for i in 0..3 {
        for j in 0..3 {
            let d = mt.matrix[i][j] - m3.matrix[i][j];
            assert!(
                d.abs() < 0.1 * m3.matrix_sigma[i][j],
                "M[{i}][{j}] {d:+.2e}"
            );
        }
    }
    // The same times without the `input` column: whose clock is unknown.
    let no_input: String = text
        .lines()
        .map(|l| l.rsplit_once(',').unwrap().0.to_string() + "\n")
        .collect();
    std::fs::write(&table, no_input).unwrap();
    let e = format!(
        "{:#}",
        calibrate_inputs(&recs, &options(Mode::RateTable(table), g)).unwrap_err()
    );
    assert!(e.contains("need an `input` column"), "{e}");
}

/// A tumble recorded as two inputs (the industrial preset, no turn-on bias: one power-up's
/// bias): neither has the 9 poses the accelerometer needs, both together do; the gyro uses
/// the 7 rotations within each input and none from the end of the first to the start of
/// the second.
#[test]
fn tumble_split_into_two_inputs_pools_the_poses_and_keeps_rotations_within_each() {
    let recs: Vec<Recording> = [11, 12]
        .into_iter()
        .map(|seed| simulate(&tumble_scene("industrial", 7, 8.0, 100.0, seed)).0)
        .collect();
    let (_, truth, g) = simulate(&tumble_scene("industrial", 7, 8.0, 100.0, 11));
    let e = format!(
        "{:#}",
        calibrate(&recs[0], &options(Mode::MultiPosition, g)).unwrap_err()
    );
    assert!(e.contains("found 8 still poses"), "{e}");
    let mut recs = recs;
    // A file's stem is no device name: it does not stand against the other input's.
    recs[1].device = "tumble-b".into();
    recs[1].device_named = false;
    let o = calibrate_inputs(&recs, &options(Mode::MultiPosition, g)).unwrap();
    let c = &o.calibration;
    assert_eq!(c.device, "imu");
    let q = &c.quality;
    assert_eq!(q.poses, 16);
    assert_eq!(q.rotations, 14);
    let per: Vec<(usize, usize)> = o.inputs.iter().map(|i| (i.poses, i.rotations)).collect();
    assert_eq!(per, [(8, 7), (8, 7)]);
    // Separate clocks: no bias drift is fitted across them.
    assert_eq!(q.accel_bias_drift, None);
    let (accel, gyro) = (c.accel.as_ref().unwrap(), c.gyro.as_ref().unwrap());
    let (s, m, b) = errors(accel, &truth.accel);
    assert!(s < 300.0 && m < 0.3, "accel: {s} ppm, {m} mrad\n{accel:#?}");
    assert!(
        b < 0.2e-3 * 9.80665,
        "accel bias error {} mg",
        b / 9.80665e-3
    );
    for i in 0..3 {
        let e = (accel.matrix[i][i] - truth.accel.matrix[i][i]).abs();
        assert!(e < 4.0 * accel.matrix_sigma[i][i], "axis {i}: {e}");
    }
    let (s, m, _) = errors(gyro, &truth.gyro);
    assert!(s < 1500.0 && m < 1.5, "gyro: {s} ppm, {m} mrad\n{gyro:#?}");
    let (before, after) = (
        q.rotation_residual_before.unwrap(),
        q.rotation_residual_after.unwrap(),
    );
    assert!(after < before / 5.0, "{before} {after}");
}

/// Inputs of different sample rates, or of two devices, are refused with one line naming
/// the input.
#[test]
fn inputs_of_different_rates_or_devices_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut paths = Vec::new();
    for (rate, name) in [(100.0, "a.csv"), (200.0, "b.csv")] {
        let (rec, _, _) = simulate(&tumble_scene("industrial", 2, 4.0, rate, 3));
        let mut text = String::from("t,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n");
        for ((t, w), a) in rec.t.iter().zip(&rec.gyro).zip(&rec.accel) {
            text += &format!(
                "{t},{},{},{},{},{},{}\n",
                w[0], w[1], w[2], a[0], a[1], a[2]
            );
        }
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        paths.push(path.to_str().unwrap().to_string());
    }
    let (ok, text) = imulab(&["calibrate", &paths[0], &paths[1]]);
    assert!(!ok, "{text}");
    let line = text
        .lines()
        .find(|l| l.starts_with("imulab:"))
        .unwrap_or_else(|| panic!("{text}"));
    assert!(
        line.contains(&format!("input 2 ({})", paths[1]))
            && line.contains("200.00 Hz")
            && line.contains("100.00 Hz"),
        "{text}"
    );
    // The same rate twice passes the check (and goes on to the fit).
    let (_, text) = imulab(&["calibrate", &paths[0], &paths[0]]);
    assert!(!text.contains("sampled at"), "{text}");
    // Two sessions' devices.
    let (mut a, _, g) = simulate(&tumble_scene("industrial", 2, 4.0, 100.0, 3));
    let mut b = a.clone();
    a.source = "runs/a [imu]".into();
    b.source = "runs/b [mems]".into();
    b.device = "mems".into();
    let e = format!(
        "{:#}",
        calibrate_inputs(&[a, b], &options(Mode::MultiPosition, g)).unwrap_err()
    );
    assert!(
        e.contains("input 2 (runs/b [mems]) is device `mems`") && !e.contains('\n'),
        "{e}"
    );
}

/// The CSV's `axis` column states the mountings instead of gravity; one that contradicts the
/// gyro is refused.
#[test]
fn rate_table_axis_column_states_the_mountings() {
    let dir = tempfile::tempdir().unwrap();
    let table = dir.path().join("rates.csv");
    let rates = [10, -10, 50, -50, 100, -100, 200, -200];
    let csv = |axes: [&str; 3]| {
        let mut text = String::from("rate_dps,axis\n");
        for a in axes {
            for r in rates {
                text += &format!("{r},{a}\n");
            }
        }
        text
    };
    let (rec, _, g) = simulate(&rate_table_3axis());
    std::fs::write(&table, csv(["x", "y", "z"])).unwrap();
    let stated = calibrate(&rec, &options(Mode::RateTable(table.clone()), g)).unwrap();
    let by_gravity = calibrate(
        &rec,
        &options(Mode::RateTable(fixture("rate_table_3axis.csv")), g),
    )
    .unwrap();
    assert_eq!(stated.calibration.gyro, by_gravity.calibration.gyro);
    std::fs::write(&table, csv(["y", "x", "z"])).unwrap();
    let e = format!(
        "{:#}",
        calibrate(&rec, &options(Mode::RateTable(table), g)).unwrap_err()
    );
    assert!(e.contains("follows the table rate"), "{e}");
}

#[test]
fn rate_table_with_a_mounting_missing_or_too_few_rates_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let two = rate_table_3axis().replace("  { axis = \"z\" },\n", "");
    let table = dir.path().join("rates.csv");
    let rates = "10\n-10\n50\n-50\n100\n-100\n200\n-200\n";
    std::fs::write(&table, format!("rate_dps\n{rates}{rates}")).unwrap();
    let (rec, _, g) = simulate(&two);
    let e = format!(
        "{:#}",
        calibrate(&rec, &options(Mode::RateTable(table.clone()), g)).unwrap_err()
    );
    assert!(e.contains("x and y") && e.contains("z missing"), "{e}");
    // Three rates in the z mounting.
    let few = rate_table_3axis()
        .replace(
            "  { axis = \"x\", pitch_deg = 90 },\n  { axis = \"-y\", roll_deg = 90 },\n",
            "",
        )
        .replace("  { rate_dps = -50, duration_s = 20 },\n", "")
        .replace("  { rate_dps = 100, duration_s = 20 },\n", "")
        .replace("  { rate_dps = -100, duration_s = 20 },\n", "")
        .replace("  { rate_dps = 200, duration_s = 20 },\n", "")
        .replace("  { rate_dps = -200, duration_s = 20 },\n", "");
    std::fs::write(&table, "rate_dps\n10\n-10\n50\n").unwrap();
    let (rec, _, g) = simulate(&few);
    let e = format!(
        "{:#}",
        calibrate(&rec, &options(Mode::RateTable(table), g)).unwrap_err()
    );
    assert!(
        e.contains("z on the spindle has 3 different rates") && e.contains("at least 4"),
        "{e}"
    );
}

#[test]
fn too_few_poses_is_refused_with_advice() {
    let (rec, _, g) = simulate(&tumble_scene("industrial", 5, 8.0, 100.0, 1));
    let e = format!(
        "{:#}",
        calibrate(&rec, &options(Mode::MultiPosition, g)).unwrap_err()
    );
    assert!(
        e.contains("found 6 still poses") && e.contains("at least 9"),
        "{e}"
    );
}

#[test]
fn poses_too_similar_are_refused() {
    let text = tumble_scene("industrial", 12, 6.0, 100.0, 1).replace(
        "poses = 12",
        "orientations = [[3, 0, 0], [0, 3, 10], [-3, 0, 20], [0, -3, 30], [2, 2, 40], [-2, 2, 50], [2, -2, 60], [-2, -2, 70], [4, 0, 80], [0, 4, 90], [-4, 0, 100], [0, -4, 110]]",
    );
    let (rec, _, g) = simulate(&text);
    let e = format!(
        "{:#}",
        calibrate(&rec, &options(Mode::MultiPosition, g)).unwrap_err()
    );
    assert!(
        e.contains("too similar") && e.contains("up and down"),
        "{e}"
    );
}

#[test]
fn a_recording_that_does_not_start_still_is_refused() {
    let text = tumble_scene("industrial", 12, 6.0, 100.0, 1)
        .replace("first_hold_s = 30", "first_hold_s = 1");
    let (rec, _, g) = simulate(&text);
    let e = format!(
        "{:#}",
        calibrate(&rec, &options(Mode::MultiPosition, g)).unwrap_err()
    );
    assert!(e.contains("still"), "{e}");
}

#[test]
fn six_position_names_the_missing_faces() {
    let (rec, _, g) = simulate(&tumble_scene("industrial", 5, 8.0, 100.0, 1).replace(
        "poses = 5",
        "orientations = [[180, 0, 0], [90, 0, 0], [-90, 0, 0], [0, 90, 0], [0, 90, 0]]",
    ));
    let e = format!(
        "{:#}",
        calibrate(&rec, &options(Mode::SixPosition, g)).unwrap_err()
    );
    assert!(e.contains("missing: -x up"), "{e}");
}

fn imulab(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_imulab"))
        .args(args)
        .output()
        .expect("run imulab");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr),
    )
}

#[test]
fn calibrate_end_to_end_then_export_and_allan_apply_it() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("tumble.toml");
    std::fs::write(&scene, tumble_scene("industrial", 14, 6.0, 100.0, 8)).unwrap();
    let session = dir.path().join("session");
    let (ok, text) = imulab(&[
        "sim",
        scene.to_str().unwrap(),
        "-o",
        session.to_str().unwrap(),
    ]);
    assert!(ok, "{text}");
    let cal = dir.path().join("cal.json");
    let yaml = dir.path().join("cal.yaml");
    let m = dir.path().join("cal.m");
    let (ok, text) = imulab(&[
        "calibrate",
        session.to_str().unwrap(),
        "-o",
        cal.to_str().unwrap(),
        "--kalibr",
        yaml.to_str().unwrap(),
        "--matlab",
        m.to_str().unwrap(),
    ]);
    assert!(ok, "{text}");
    assert!(text.contains("still intervals: 15 found"), "{text}");
    assert!(
        text.contains("truth"),
        "the simulated session's truth is shown: {text}"
    );
    assert!(
        text.contains("normal gravity at the session's place"),
        "{text}"
    );
    let c = imulab::calib::Calibration::load(&cal).unwrap();
    assert_eq!(c.device, "imu");
    assert!(std::fs::read_to_string(&yaml).unwrap().contains("C_gyro_i"));
    assert!(std::fs::read_to_string(&m)
        .unwrap()
        .contains("cal.accel.M = ["));

    // Export with the calibration: the first (still) rows' specific force has gravity's length.
    let csv_path = dir.path().join("imu.csv");
    let (ok, text) = imulab(&[
        "export",
        session.to_str().unwrap(),
        "--device",
        "imu",
        "--end",
        "20",
        "--calibration",
        cal.to_str().unwrap(),
        "-o",
        csv_path.to_str().unwrap(),
    ]);
    assert!(ok, "{text}");
    let body = std::fs::read_to_string(&csv_path).unwrap();
    assert!(
        body.starts_with("# gyro and accel calibrated with"),
        "{}",
        &body[..200]
    );
    let mut reader = csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .from_reader(body.as_bytes());
    let (mut sum, mut n) = (0.0, 0.0);
    for row in reader.records() {
        let row = row.unwrap();
        let a: Vec<f64> = (6..9).map(|i| row[i].parse().unwrap()).collect();
        sum += (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        n += 1.0;
    }
    let g = earth::normal_gravity(45f64.to_radians(), 250.0);
    assert!((sum / n - g).abs() < 0.1e-3 * g, "{} vs {g}", sum / n);

    // allan applies it too; a calibration of another device is refused.
    let (ok, text) = imulab(&[
        "allan",
        session.to_str().unwrap(),
        "--to",
        "25",
        "--calibration",
        cal.to_str().unwrap(),
    ]);
    assert!(ok, "{text}");
    let (ok, text) = imulab(&[
        "allan",
        session.to_str().unwrap(),
        "--device",
        "nope",
        "--calibration",
        cal.to_str().unwrap(),
    ]);
    assert!(!ok && !text.contains("panicked"), "{text}");
    std::fs::write(&cal, "{\"format\": \"imulab-calibration\", \"version\": 7}").unwrap();
    let (ok, text) = imulab(&[
        "export",
        session.to_str().unwrap(),
        "--device",
        "imu",
        "--calibration",
        cal.to_str().unwrap(),
    ]);
    assert!(!ok && text.contains("not a calibration file"), "{text}");
}

/// The per-outage `max horizontal drift X m` figures of a replay's output.
fn outage_drifts(stdout: &str) -> Vec<f64> {
    stdout
        .lines()
        .filter_map(|l| l.split("max horizontal drift ").nth(1))
        .map(|d| {
            d.trim_end_matches(" m")
                .parse()
                .unwrap_or_else(|_| panic!("drift `{d}` is not a number of metres"))
        })
        .collect()
}

#[test]
fn the_tumble_calibration_shrinks_the_outage_drift_of_a_drive() {
    let dir = tempfile::tempdir().unwrap();
    let scenes = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/scenes");
    let tumble = dir.path().join("tumble");
    let drive = dir.path().join("drive");
    for (scene, out) in [("tumble_15min.toml", &tumble), ("drive_calib.toml", &drive)] {
        let (ok, text) = imulab(&[
            "sim",
            &format!("{scenes}/{scene}"),
            "-o",
            out.to_str().unwrap(),
        ]);
        assert!(ok, "{text}");
    }
    let cal = dir.path().join("cal.json");
    let (ok, text) = imulab(&[
        "calibrate",
        tumble.to_str().unwrap(),
        "-o",
        cal.to_str().unwrap(),
    ]);
    assert!(ok, "{text}");
    let out_dir = dir.path().join("replay");
    let replay = |extra: &[&str]| -> Vec<f64> {
        let mut args = vec![
            "replay",
            drive.to_str().unwrap(),
            "--outages",
            "every:180:60",
            "--out",
            out_dir.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let (ok, text) = imulab(&args);
        assert!(ok, "{text}");
        let drifts = outage_drifts(&text);
        assert_eq!(drifts.len(), 6, "{text}");
        drifts
    };
    let rms = |v: &[f64]| (v.iter().map(|d| d * d).sum::<f64>() / v.len() as f64).sqrt();
    let raw = replay(&[]);
    let calibrated = replay(&["--calibration", cal.to_str().unwrap()]);
    println!(
        "per-outage max horizontal drift, raw {raw:.2?} (RMS {:.2} m), calibrated {calibrated:.2?} (RMS {:.2} m)",
        rms(&raw),
        rms(&calibrated)
    );
    assert!(
        rms(&calibrated) < 0.7 * rms(&raw),
        "RMS outage drift {:.2} m raw, {:.2} m calibrated",
        rms(&raw),
        rms(&calibrated)
    );
    let worse = raw.iter().zip(&calibrated).filter(|(r, c)| c > r).count();
    assert!(
        worse <= 1,
        "calibration made {worse} of 6 outages drift more: raw {raw:?}, calibrated {calibrated:?}"
    );
}

/// Kalibr reads its IMU YAML with PyYAML (`yaml.safe_load`); the file read that way gives back
/// the calibration under Kalibr's measurement model, accel: raw = M·a + b, gyro:
/// raw = M·C_gyro_i·ω + A·a + b (M lower triangular, C_gyro_i a rotation).
#[test]
fn kalibr_yaml_read_as_kalibr_reads_it_gives_back_the_model() {
    let mut cal = imulab::calib::Calibration::new("imu", "test", "multi-position", "accel");
    let accel = TriadModel {
        bias: [1.2, -0.15, 0.3],
        bias_sigma: [0.0; 3],
        matrix: [
            [1.009, 0.0, 0.0],
            [0.005, 0.988, 0.0],
            [-0.003, 0.004, 1.006],
        ],
        matrix_sigma: [[0.0; 3]; 3],
    };
    // A full gyro M: misalignment above and below the diagonal.
    let gyro = TriadModel {
        bias: [1e-3, -2e-3, 5e-4],
        bias_sigma: [0.0; 3],
        matrix: [
            [1.012, 0.004, -0.006],
            [0.003, 0.992, 0.005],
            [-0.002, 0.007, 1.015],
        ],
        matrix_sigma: [[0.0; 3]; 3],
    };
    cal.accel = Some(accel.clone());
    cal.gyro = Some(gyro.clone());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("imu.yaml");
    std::fs::write(&path, cal.kalibr_yaml(200.0)).unwrap();
    let out = Command::new("python3")
        .args([
            "-c",
            "import json, sys, yaml; print(json.dumps(yaml.safe_load(open(sys.argv[1]))))",
            path.to_str().unwrap(),
        ])
        .output()
        .expect("python3 with PyYAML (python3-yaml), the YAML reader Kalibr uses");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let imu = &doc["imu0"];
    assert_eq!(imu["model"], "scale-misalignment");
    assert_eq!(imu["update_rate"], 200.0);
    let mat = |v: &serde_json::Value| {
        nalgebra::Matrix3::from_fn(|i, j| v[i][j].as_f64().expect("a number"))
    };
    let vec3 =
        |v: &serde_json::Value| nalgebra::Vector3::from_fn(|i, _| v[i].as_f64().expect("a number"));
    let (m_a, b_a) = (
        mat(&imu["accelerometers"]["M"]),
        vec3(&imu["accelerometers"]["bias"]),
    );
    let g = &imu["gyroscopes"];
    let (m_g, c_g, a_g, b_g) = (
        mat(&g["M"]),
        mat(&g["C_gyro_i"]),
        mat(&g["A"]),
        vec3(&g["bias"]),
    );
    for m in [&m_a, &m_g] {
        assert!(
            m[(0, 1)] == 0.0 && m[(0, 2)] == 0.0 && m[(1, 2)] == 0.0,
            "{m}"
        );
    }
    assert!((c_g.transpose() * c_g - nalgebra::Matrix3::identity()).norm() < 1e-8);
    assert!((c_g.determinant() - 1.0).abs() < 1e-8);
    assert!((m_a - accel.m()).norm() < 1e-8, "{m_a} vs {}", accel.m());
    assert!(
        (m_g * c_g - gyro.m()).norm() < 1e-8,
        "{} vs {}",
        m_g * c_g,
        gyro.m()
    );
    assert_eq!(a_g, nalgebra::Matrix3::zeros());
    // Kalibr's forward model on a true rate and specific force, then imulab's correction.
    let (w, f) = (
        nalgebra::Vector3::new(0.3, -0.7, 1.1),
        nalgebra::Vector3::new(1.5, -2.0, 9.4),
    );
    let raw_w = m_g * c_g * w + a_g * f + b_g;
    let raw_f = m_a * f + b_a;
    let back_w = nalgebra::Vector3::from(gyro.correct(&raw_w.into()));
    let back_f = nalgebra::Vector3::from(accel.correct(&raw_f.into()));
    assert!((back_w - w).norm() < 1e-7, "{back_w} vs {w}");
    assert!((back_f - f).norm() < 1e-6, "{back_f} vs {f}");
}
