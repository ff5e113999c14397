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
//! rate-table program alone).

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
fn rate_table_rows(seeds: u64) {
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
    if args.iter().any(|a| a == "--rate-table") {
        rate_table_rows(seeds);
        return;
    }
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
    }
    rate_table_rows(seeds);
}
