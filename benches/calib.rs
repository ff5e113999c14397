//! Calibration benchmark: recovery of known accelerometer and gyro bias, scale factors and
//! misalignment from simulated 15-minute, 200 Hz tumbles (30 s still, 60 random poses held
//! 10 s, 3 s rotations) of each preset over seeds, each seed drawing its own deterministic
//! errors at the grade's size; the gravity residual before and after; and the time one
//! calibration takes; and, from the simulator's true bias, how far the accelerometer bias
//! drifts along gravity between poses during the run (the part of the residual a constant-bias
//! model cannot remove), the residual with a constant bias and with the fitted drift, and how
//! often the F-test kept the drift; then the three-mounting rate-table program
//! (`fixtures/scenes/rate_table_3axis.toml` with the gyro's scale factors, misalignments and
//! quadratic terms drawn per seed): errors of the whole gyro M and of each axis's quadratic
//! term, and how often the truth lies inside the stated 95 % interval. Method and tables:
//! docs/bench/calib.md. Run: `cargo bench --bench
//! calib` (`-- --seeds N` for another number of seeds; `-- --steady-accel` sets the
//! accelerometers' bias instability and random walk to zero; `-- --rate-table` runs the
//! rate-table program alone; `-- cli` times `imulab calibrate` on the tumble fixture and
//! replays `drive_calib.toml` with and without its calibration, release binary).
//! Figures and BENCHMARKS.md rows go to `benches/results/calib-<mode>.json`.

#[path = "support/results.rs"]
mod results;

#[path = "support/cli.rs"]
mod cli;
use cli::{imulab, profile_flag, replay_drifts};

use imulab::calib::recording::Recording;
use imulab::calib::run::{calibrate, Gravity, Mode, Options};
use imulab::calib::statics::DetectorOptions;
use imulab::calib::truth::Truth;
use imulab::calib::TriadModel;
use imulab::earth;
use imulab::sim::imu_model::ImuSpec;
use imulab::sim::outputs::MemorySink;
use imulab::sim::rng::Stream;
use imulab::sim::runner::run;
use imulab::sim::scene::Scene;
use serde_json::json;
use std::path::Path;
use std::time::Instant;

/// A grade's deterministic errors: 1σ of scale factor (ppm), misalignment (mrad) and
/// constant accel bias (mg), and the scale-factor target (ppm).
struct Grade {
    preset: &'static str,
    scale_ppm: f64,
    misalignment_mrad: f64,
    bias_mg: f64,
    scale_target_ppm: f64,
}

const GRADES: [Grade; 3] = [
    // MPU-6000: sensitivity tolerance ±3 %, cross-axis ±2 % (as 3σ).
    Grade {
        preset: "consumer",
        scale_ppm: 10_000.0,
        misalignment_mrad: 7.0,
        bias_mg: 0.0,
        scale_target_ppm: 500.0,
    },
    Grade {
        preset: "industrial",
        scale_ppm: 1_000.0,
        misalignment_mrad: 1.0,
        bias_mg: 5.0,
        scale_target_ppm: 100.0,
    },
    // STIM300: scale-factor accuracy ±500 ppm, misalignment ±1 mrad (as 3σ-ish).
    Grade {
        preset: "tactical",
        scale_ppm: 300.0,
        misalignment_mrad: 0.3,
        bias_mg: 0.0,
        scale_target_ppm: 100.0,
    },
];

fn draws(stream: &mut Stream, n: usize, sigma: f64) -> String {
    let v: Vec<String> = (0..n)
        .map(|_| format!("{:.6}", sigma * stream.normal()))
        .collect();
    format!("[{}]", v.join(", "))
}

fn scene(grade: &Grade, seed: u64, steady_accel: bool) -> String {
    let mut s = Stream::new(seed, &format!("bench/calib/{}", grade.preset));
    format!(
        r#"
duration_s = 900
rate_hz = 200
seed = {seed}
[location]
lat_deg = 48.15
lon_deg = 11.57
height_m = 520.0
[motion]
kind = "tumble"
first_hold_s = 30
hold_s = 10
rotate_s = 3
poses = 60
[[imu]]
name = "imu"
preset = "{preset}"
[imu.gyro]
scale_factor_ppm = {gs}
misalignment_mrad = {gm}
[imu.accel]
bias_mg = {ab}
scale_factor_ppm = {as_}
misalignment_mrad = {am}
{steady}
[outputs]
truth_nav = false
truth_imu = true
truth_every = 200
"#,
        preset = grade.preset,
        gs = draws(&mut s, 3, grade.scale_ppm),
        gm = draws(&mut s, 6, grade.misalignment_mrad),
        ab = draws(&mut s, 3, grade.bias_mg),
        as_ = draws(&mut s, 3, grade.scale_ppm),
        am = draws(&mut s, 6, grade.misalignment_mrad),
        steady = if steady_accel {
            "bias_instability_mg = [0.0, 0.0, 0.0]\nrrw_mg_rth = [0.0, 0.0, 0.0]"
        } else {
            ""
        },
    )
}

/// Per seed: worst scale error (ppm), worst misalignment error (deg), whether every
/// misalignment is within 0.02° or its 95 % interval, worst bias error.
struct Recovery {
    scale_ppm: f64,
    mis_deg: f64,
    mis_ok: bool,
    bias: f64,
}

fn recovery(fit: &TriadModel, truth: &TriadModel) -> Recovery {
    let mut r = Recovery {
        scale_ppm: 0.0,
        mis_deg: 0.0,
        mis_ok: true,
        bias: 0.0,
    };
    for i in 0..3 {
        for j in 0..3 {
            let e = (fit.matrix[i][j] - truth.matrix[i][j]).abs();
            if i == j {
                r.scale_ppm = r.scale_ppm.max(e * 1e6);
            } else if fit.matrix_sigma[i][j] > 0.0 {
                r.mis_deg = r.mis_deg.max(e.to_degrees());
                r.mis_ok &= e.to_degrees() < 0.02 || e < 1.96 * fit.matrix_sigma[i][j];
            }
        }
        r.bias = r.bias.max((fit.bias[i] - truth.bias[i]).abs());
    }
    r
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

/// The three-mounting rate-table program over `seeds`, tactical preset, with the gyro's
/// scale factors (300 ppm), misalignments (0.3 mrad) and quadratic terms (0.3 ppm per °/s)
/// drawn per seed (1σ).
fn rate_table_rows(seeds: u64) -> (serde_json::Value, results::Row) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/scenes");
    let fixture = std::fs::read_to_string(root.join("rate_table_3axis.toml")).expect("fixture");
    let table = root.join("rate_table_3axis.csv");
    let (mut scale, mut mis, mut quad) = (Vec::new(), 0.0f64, 0.0f64);
    let (mut m_in, mut m_all, mut q_in, mut q_all) = (0, 0, 0, 0);
    let mut times = Vec::new();
    for seed in 0..seeds {
        let mut s = Stream::new(seed, "bench/calib/rate_table");
        let text = fixture
            .replace("seed = 29", &format!("seed = {}", 1000 + seed))
            .replace("[300, -200, 450]", &draws(&mut s, 3, 300.0))
            .replace("[0.2, -0.3, 0.1, 0.25, -0.15, 0.3]", &draws(&mut s, 6, 0.3))
            .replace("[0.4, -0.25, 0.15]", &draws(&mut s, 3, 0.3));
        let sc = Scene::parse(&text, Path::new(".")).expect("scene");
        let mut sink = MemorySink::default();
        run(&sc, &mut sink).expect("run");
        let rec = Recording::from_records("stim", &sink.imu["stim"]);
        let spec: &ImuSpec = &sc.imus[0].spec;
        let truth = Truth::of_spec(spec, [0.0; 3], [0.0; 3]).gyro_body;
        let opts = Options {
            mode: Mode::RateTable(table.clone()),
            detector: DetectorOptions::default(),
            gravity: Gravity::Auto,
        };
        let start = Instant::now();
        let o = match calibrate(&rec, &opts) {
            Ok(o) => o,
            Err(e) => {
                println!("<!-- rate table seed {seed}: {e:#} -->");
                continue;
            }
        };
        times.push(start.elapsed().as_secs_f64());
        let g = o.calibration.gyro.as_ref().unwrap();
        let mut worst_scale = 0.0f64;
        for i in 0..3 {
            for j in 0..3 {
                let e = (g.matrix[i][j] - truth.matrix[i][j]).abs();
                if i == j {
                    worst_scale = worst_scale.max(e * 1e6);
                } else {
                    mis = mis.max(e.to_degrees());
                }
                m_in += usize::from(e < 1.96 * g.matrix_sigma[i][j]);
                m_all += 1;
            }
        }
        scale.push(worst_scale);
        for (k, a) in o.calibration.rate_table.iter().flatten().enumerate() {
            let e = (a.quadratic_ppm_per_dps - spec.gyro.scale_quadratic_ppm_per_dps[k]).abs();
            quad = quad.max(e);
            q_in += usize::from(e < 1.96 * a.quadratic_sigma_ppm_per_dps);
            q_all += 1;
        }
    }
    println!(
        "\n# rate table, three mountings (x, -y, z on the spindle, 8 rates of ±10-200 °/s held 20 s each), tactical gyro, {seeds} seeds\n"
    );
    println!("| gyro scale err p50 / max (ppm) | gyro mis. err max (°) | M entries in their 95 % interval | quadratic err max (ppm per °/s) | quadratic in 95 % | calibrate time p50 / max (s) |");
    println!("| --- | --- | --- | --- | --- | --- |");
    println!(
        "| {:.1} / {:.1} | {:.5} | {m_in}/{m_all} | {quad:.4} | {q_in}/{q_all} | {:.3} / {:.3} |",
        percentile(&mut scale, 0.5),
        percentile(&mut scale, 1.0),
        mis,
        percentile(&mut times, 0.5),
        percentile(&mut times, 1.0),
    );
    let share = 100.0 * m_in as f64 / m_all.max(1) as f64;
    let row = results::Row::new(
        "calib-rate-table",
        results::SIM_CALIB_THERMAL,
        7,
        "rate table, 3 mountings",
        "docs/bench/calib.md",
    )
    .data(format!("{seeds} seeds, tactical gyro"))
    .ours(format!(
        "scale ≤ {:.0} ppm, misalignment ≤ {mis:.4}°; {share:.1} % in 95 % CI",
        percentile(&mut scale, 1.0)
    ))
    .target("truth in CI")
    // Truth in its 95 % interval: at least 90 % of the matrix entries over the seeds.
    .met(share >= 90.0)
    .command(format!(
        "cargo bench --bench calib{} -- --seeds {seeds} --rate-table",
        profile_flag()
    ));
    let figures = json!({
        "seeds": seeds, "scale_err_ppm_p50": percentile(&mut scale, 0.5),
        "scale_err_ppm_max": percentile(&mut scale, 1.0), "mis_err_deg_max": mis,
        "m_in_ci": m_in, "m_entries": m_all, "quadratic_err_max": quad,
        "quadratic_in_ci": q_in, "quadratic_entries": q_all,
        "calibrate_s_p50": percentile(&mut times, 0.5), "calibrate_s_max": percentile(&mut times, 1.0),
    });
    (figures, row)
}

/// A gravity residual within this factor of the noise-plus-drift floor is at that floor.
const AT_FLOOR: f64 = 1.1;
/// A gravity residual within this factor of the white-noise floor alone is at that floor.
const AT_WHITE_FLOOR: f64 = 1.5;

/// The two rows of the tumble table (accel recovery, gravity residual) from its per-grade
/// figures.
fn tumble_rows(seeds: u64, grades: &[serde_json::Value]) -> Vec<results::Row> {
    let f = |g: &serde_json::Value, k: &str| g[k].as_f64().unwrap_or(f64::NAN);
    let each = |k: &str, digits: usize| {
        grades
            .iter()
            .map(|g| format!("{:.digits$}", f(g, k)))
            .collect::<Vec<_>>()
            .join(" / ")
    };
    let worst = |k: &str| grades.iter().map(|g| f(g, k)).fold(0.0f64, f64::max);
    let targets: Vec<f64> = grades.iter().map(|g| f(g, "scale_target_ppm")).collect();
    let mut target_ppm: Vec<String> = targets.iter().map(|t| format!("{t:.0}")).collect();
    target_ppm.dedup();
    let scale_ok = grades
        .iter()
        .all(|g| f(g, "accel_scale_err_ppm_max") <= f(g, "scale_target_ppm"));
    let mis_ok = grades.iter().all(|g| g["accel_mis_ok"] == g["done"]);
    let bias_ok = worst("accel_bias_err_mg_max") <= 0.1;
    let data = format!("{seeds} seeds × {} grades, 15 min tumbles", grades.len());
    let command = format!(
        "cargo bench --bench calib{} -- --seeds {seeds}",
        profile_flag()
    );
    let accel = results::Row::new(
        "calib-accel",
        results::SIM_CALIB_THERMAL,
        5,
        "accel calibration",
        "docs/bench/calib.md",
    )
    .data(data)
    .ours(format!(
        "scale ≤ {} ppm, misalignment ≤ {:.3}°, bias ≤ {:.3} mg",
        each("accel_scale_err_ppm_max", 0),
        worst("accel_mis_err_deg_max"),
        worst("accel_bias_err_mg_max")
    ))
    .target(format!("{} ppm, 0.02°, 0.1 mg", target_ppm.join(" / ")))
    .met(scale_ok && mis_ok && bias_ok)
    .command(command);
    // Against the white-noise floor alone and with the bias drift along g added.
    let white: Vec<f64> = grades
        .iter()
        .map(|g| f(g, "g_residual_after_mg") / f(g, "pose_noise_mg"))
        .collect();
    let with_drift: Vec<f64> = grades
        .iter()
        .map(|g| f(g, "g_residual_after_mg") / f(g, "noise_and_drift_mg"))
        .collect();
    let over: Vec<usize> = (0..grades.len())
        .filter(|&i| white[i] > AT_WHITE_FLOOR)
        .collect();
    let drift_ok = with_drift.iter().all(|r| *r <= AT_FLOOR);
    let name = |i: usize| grades[i]["preset"].as_str().unwrap_or("").to_string();
    let met = match (over.is_empty(), drift_ok) {
        (true, _) => "yes".to_string(),
        (false, true) => format!(
            "yes with drift; {} white alone",
            over.iter()
                .map(|&i| format!("{} {:.1}×", name(i), white[i]))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        (false, false) => "no".into(),
    };
    let mut residual = results::Row::new(
        "calib-gravity-residual",
        results::SIM_CALIB_THERMAL,
        6,
        "gravity residual",
        "docs/bench/calib.md",
    )
    .data("same")
    .ours(format!(
        "{} mg (raw {})",
        each("g_residual_after_mg", 3),
        grades
            .iter()
            .map(|g| {
                let v = f(g, "g_residual_before_mg");
                if v >= 10.0 {
                    format!("{v:.1}")
                } else {
                    format!("{v:.2}")
                }
            })
            .collect::<Vec<_>>()
            .join(" / ")
    ))
    .ratio(format!(
        "{}× noise + drift",
        with_drift
            .iter()
            .map(|r| format!("{r:.2}"))
            .collect::<Vec<_>>()
            .join(" / ")
    ))
    .target("noise floor")
    .met_text(met)
    .command("same");
    if let Some(&i) = over.first() {
        let mut n = name(i);
        n[..1].make_ascii_uppercase();
        residual = residual.not_met(
            format!("{n} gravity residual at the white-noise floor ({:.1}×)", white[i]),
            format!(
                "its bias instability wanders {:.3} mg along g during the tumble; {:.2}× the noise-plus-drift floor",
                f(&grades[i], "bias_drift_along_g_mg"),
                with_drift[i]
            ),
        );
    }
    vec![accel, residual]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let seeds: u64 = args
        .iter()
        .position(|a| a == "--seeds")
        .and_then(|i| args.get(i + 1))
        .and_then(|s| s.parse().ok())
        .unwrap_or(20);
    let steady_accel = args.iter().any(|a| a == "--steady-accel");
    if args.iter().any(|a| a == "cli") {
        cli_rows();
        return;
    }
    if args.iter().any(|a| a == "--rate-table") {
        let (figures, row) = rate_table_rows(seeds);
        results::write(
            "calib",
            "rate-table",
            json!({ "seeds": seeds }),
            figures,
            &[row],
        );
        return;
    }
    let mut grade_figures = Vec::new();
    println!(
        "# calibration recovery, {seeds} seeds per preset, 15 min 200 Hz tumbles (60 poses){}\n",
        if steady_accel {
            ", accelerometer bias instability and random walk off"
        } else {
            ""
        }
    );
    println!("| preset | accel scale err p50 / max (ppm) | target | accel mis. err max (°) | mis. ok (0.02° or 95 %) | accel bias err max (mg) | gyro scale err p50 / max (ppm) | gyro mis. err max (°) | gyro mis. ok | g residual before → constant bias → after (mg) | drift kept | pose-mean noise (mg) | bias drift along g (mg) | √(noise² + drift²) (mg) | calibrate time p50 / max (s) |");
    println!(
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    for grade in &GRADES {
        let mut a_scale = Vec::new();
        let mut g_scale = Vec::new();
        let (mut a_mis, mut g_mis, mut a_bias) = (0.0f64, 0.0f64, 0.0f64);
        let (mut a_ok, mut g_ok) = (0, 0);
        let (mut before, mut after, mut floor) = (Vec::new(), Vec::new(), Vec::new());
        let (mut constant, mut drift_kept) = (Vec::new(), 0);
        let mut drift = Vec::new();
        let mut times = Vec::new();
        for seed in 0..seeds {
            let sc =
                Scene::parse(&scene(grade, seed, steady_accel), Path::new(".")).expect("scene");
            let mut sink = MemorySink::default();
            run(&sc, &mut sink).expect("run");
            let rec = Recording::from_records("imu", &sink.imu["imu"]);
            let rows = &sink.truth_imu["imu"];
            let n = rows.len() as f64;
            let (mut gb, mut ab) = ([0.0; 3], [0.0; 3]);
            for r in rows {
                for k in 0..3 {
                    gb[k] += r.gyro_bias[k] / n;
                    ab[k] += r.accel_bias[k] / n;
                }
            }
            let truth = Truth::of_spec(&sc.imus[0].spec, gb, ab);
            let g = earth::normal_gravity(sc.location.lat_deg.to_radians(), sc.location.height_m);
            let opts = Options {
                mode: Mode::MultiPosition,
                detector: DetectorOptions::default(),
                gravity: Gravity::Value(g),
            };
            let start = Instant::now();
            let o = match calibrate(&rec, &opts) {
                Ok(o) => o,
                Err(e) => {
                    println!("<!-- {} seed {seed}: {e:#} -->", grade.preset);
                    continue;
                }
            };
            times.push(start.elapsed().as_secs_f64());
            let c = &o.calibration;
            let ra = recovery(c.accel.as_ref().unwrap(), &truth.accel);
            let rg = recovery(c.gyro.as_ref().unwrap(), &truth.gyro);
            a_scale.push(ra.scale_ppm);
            g_scale.push(rg.scale_ppm);
            a_mis = a_mis.max(ra.mis_deg);
            g_mis = g_mis.max(rg.mis_deg);
            a_bias = a_bias.max(ra.bias);
            a_ok += usize::from(ra.mis_ok);
            g_ok += usize::from(rg.mis_ok);
            let mg = 1e3 / 9.80665;
            before.push(c.quality.gravity_residual_before.unwrap() * mg);
            after.push(c.quality.gravity_residual_after.unwrap() * mg);
            constant.push(c.quality.gravity_residual_constant_bias.unwrap() * mg);
            drift_kept += usize::from(c.quality.accel_bias_drift.is_some());
            if let Some(d) = o.inputs[0].detection.as_ref() {
                let f: f64 = d
                    .intervals
                    .iter()
                    .map(|p| {
                        (p.accel_std.iter().map(|s| s * s).sum::<f64>() / 3.0 / p.samples() as f64)
                            .sqrt()
                    })
                    .sum::<f64>()
                    / d.intervals.len() as f64;
                floor.push(f * mg);
                // The true bias averaged over each pose, less its run mean, along that pose's
                // gravity direction: what a constant bias leaves in the magnitude residual.
                let t0 = sink.imu["imu"][0].t_mono_ns;
                let along: Vec<f64> = d
                    .intervals
                    .iter()
                    .filter_map(|p| {
                        let inside: Vec<_> = rows
                            .iter()
                            .filter(|r| {
                                let t = (r.t_mono_ns - t0) as f64 * 1e-9;
                                t >= p.t_start && t <= p.t_end
                            })
                            .collect();
                        if inside.is_empty() {
                            return None;
                        }
                        let k = inside.len() as f64;
                        let a = p.accel_mean;
                        let norm = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
                        Some(
                            (0..3)
                                .map(|j| {
                                    let b = inside.iter().map(|r| r.accel_bias[j]).sum::<f64>() / k;
                                    (b - ab[j]) * a[j] / norm
                                })
                                .sum::<f64>(),
                        )
                    })
                    .collect();
                let m = along.iter().sum::<f64>() / along.len().max(1) as f64;
                let rms = (along.iter().map(|v| (v - m).powi(2)).sum::<f64>()
                    / along.len().max(1) as f64)
                    .sqrt();
                drift.push(rms * mg);
            }
        }
        let done = times.len();
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        println!(
            "| {} | {:.0} / {:.0} | {:.0} | {:.4} | {a_ok}/{done} | {:.3} | {:.0} / {:.0} | {:.4} | {g_ok}/{done} | {:.2} → {:.4} → {:.4} | {drift_kept}/{done} | {:.4} | {:.4} | {:.4} | {:.3} / {:.3} |",
            grade.preset,
            percentile(&mut a_scale, 0.5),
            percentile(&mut a_scale, 1.0),
            grade.scale_target_ppm,
            a_mis,
            a_bias * 1e3 / 9.80665,
            percentile(&mut g_scale, 0.5),
            percentile(&mut g_scale, 1.0),
            g_mis,
            mean(&before),
            mean(&constant),
            mean(&after),
            mean(&floor),
            mean(&drift),
            (mean(&floor).powi(2) + mean(&drift).powi(2)).sqrt(),
            percentile(&mut times, 0.5),
            percentile(&mut times, 1.0),
        );
        grade_figures.push(json!({
            "preset": grade.preset, "done": done, "scale_target_ppm": grade.scale_target_ppm,
            "accel_scale_err_ppm_p50": percentile(&mut a_scale, 0.5),
            "accel_scale_err_ppm_max": percentile(&mut a_scale, 1.0),
            "accel_mis_err_deg_max": a_mis, "accel_mis_ok": a_ok,
            "accel_bias_err_mg_max": a_bias * 1e3 / 9.80665,
            "gyro_scale_err_ppm_p50": percentile(&mut g_scale, 0.5),
            "gyro_scale_err_ppm_max": percentile(&mut g_scale, 1.0),
            "gyro_mis_err_deg_max": g_mis, "gyro_mis_ok": g_ok,
            "g_residual_before_mg": mean(&before), "g_residual_constant_bias_mg": mean(&constant),
            "g_residual_after_mg": mean(&after), "drift_kept": drift_kept,
            "pose_noise_mg": mean(&floor), "bias_drift_along_g_mg": mean(&drift),
            "noise_and_drift_mg": (mean(&floor).powi(2) + mean(&drift).powi(2)).sqrt(),
            "calibrate_s_p50": percentile(&mut times, 0.5), "calibrate_s_max": percentile(&mut times, 1.0),
        }));
    }
    let (rate_table, rate_row) = rate_table_rows(seeds);
    let mut rows = tumble_rows(seeds, &grade_figures);
    // The full run writes the rate-table figures too; its row belongs to `--rate-table`.
    drop(rate_row);
    if steady_accel {
        rows.clear();
    }
    results::write(
        "calib",
        if steady_accel {
            "tumble-steady-accel"
        } else {
            "tumble"
        },
        json!({ "seeds": seeds, "steady_accel": steady_accel }),
        json!({ "grades": grade_figures, "rate_table": rate_table }),
        &rows,
    );
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// The fixture chain through the release CLI: `imulab calibrate` on the 15 min tumble (timed,
/// 3 runs), then the replay of `drive_calib.toml` with and without that calibration.
fn cli_rows() {
    let tmp = std::env::temp_dir().join(format!("imulab-calib-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).expect("temporary directory");
    let p = |name: &str| tmp.join(name).display().to_string();
    imulab(&["sim", "fixtures/scenes/tumble_15min.toml", "-o", &p("T")]);
    let times: Vec<f64> = (0..3)
        .map(|_| imulab(&["calibrate", &p("T"), "-o", &p("cal.json")]).0)
        .collect();
    imulab(&["sim", "fixtures/scenes/drive_calib.toml", "-o", &p("D")]);
    let raw = replay_drifts(&p("D"), "every:180:60", &tmp.join("R0"), &[]);
    let calibration = p("cal.json");
    let cal = replay_drifts(
        &p("D"),
        "every:180:60",
        &tmp.join("R1"),
        &["--calibration", &calibration],
    );
    let _ = std::fs::remove_dir_all(&tmp);
    let (lo, hi) = results::min_max(&times);
    println!(
        "imulab calibrate: {lo:.3}-{hi:.3} s wall; replay drift RMS {:.2} → {:.2} m",
        rms(&raw),
        rms(&cal)
    );
    let command = "cargo bench --bench calib -- cli";
    let time = results::Row::new(
        "calib-time",
        results::SIM_CALIB_THERMAL,
        8,
        "calibration time",
        "docs/bench/calib.md",
    )
    .data("15 min × 200 Hz tumble")
    .ours(format!("{} s wall", results::range(lo, hi, 2)))
    .target("< 1 s")
    .met(hi < 1.0)
    .timed()
    .command(command);
    let replay = results::Row::new(
        "calib-replay",
        results::SIM_CALIB_THERMAL,
        8,
        "replay drift, `--calibration`",
        "docs/bench/calib.md",
    )
    .data(format!("`drive_calib.toml`, {} × 60 s outages", raw.len()))
    .ours(format!("RMS {:.1} → {:.1} m", rms(&raw), rms(&cal)))
    .ratio(format!("{:.1}× smaller", rms(&raw) / rms(&cal)))
    .target("smaller")
    .met(rms(&cal) < rms(&raw))
    .command("same");
    results::write(
        "calib",
        "cli",
        json!({ "tumble": "fixtures/scenes/tumble_15min.toml", "drive": "fixtures/scenes/drive_calib.toml", "outages": "every:180:60" }),
        json!({ "calibrate_wall_s": times, "drift_raw_m": raw, "drift_calibrated_m": cal }),
        &[time, replay],
    );
}
