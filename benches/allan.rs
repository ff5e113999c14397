//! Allan analyser benchmark: run time per deviation type on 6 h × 150 Hz (3.24 M samples),
//! one and six axes; a full six-axis OADEV report with fit (in memory and end to end from
//! the .npy file); and run time against error (dense vs octave grid for the fitted terms,
//! f32 vs f64 input and accumulation). Writes the simulated data to
//! `target/allan-bench/data.npy` for `benches/allan_vs_allantools.sh`.
//!
//! Run: `cargo bench --bench allan` (speed), or
//! `cargo bench --bench allan -- memory [DAYS] [session|npy]` (peak memory: writes DAYS
//! (default 7) of 150 Hz data into /tmp as a session or a six-column .npy, runs
//! `imulab allan` on three gyro axes and on one as child processes, reports their peak RSS
//! against the one-axis size, and deletes the data), or
//! `cargo bench --bench allan -- session [FLUSH_S]` (the session read path alone: 6 h of the
//! six simulated axes written as a session with FLUSH_S-second chunks (default 1) and the
//! default 10-minute file rotation, kept in `target/allan-bench/session-FLUSH_Ss` for the next
//! run; times reading six axes + time through `read_axes`, and the six-axis OADEV report with
//! fit end to end), or
//! `cargo bench --bench allan -- --only KIND[:GRID] [--runs N]` (the per-type table for the
//! matching rows alone, best of N runs, e.g. `--only oadev:octave --runs 30` under `perf`).

#[path = "support/results.rs"]
mod results;

use clap::Parser;
use imulab::allan::analysis::{analyse_axis, AnalysisOptions, AxisResult};
use imulab::allan::fit::{fit_noise_terms, Term};
use imulab::allan::input::AxisSeries;
use imulab::allan::pipeline::{analyse_inputs, AsRecorded, Options};
use imulab::allan::units::RateUnit;
use imulab::allan::{compute_curve, DeviationKind, Phase, TauGrid};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use serde_json::json;
use std::time::Instant;

// The synthetic data, shared with `examples/allan_probe.rs`.
use imulab_test_support::gyro_noise::{
    simulate, simulate_batches, K_TRUE, N_TRUE, RATE_HZ, SAMPLES,
};

fn best_of<T>(runs: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let (time, out) = best_of_prepared(runs, || (), |()| f());
    (time.wall, out)
}

/// Process CPU time (user + system, all threads), seconds.
fn cpu_now() -> f64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID)
        .map(|t| t.tv_sec() as f64 + t.tv_nsec() as f64 * 1e-9)
        .unwrap_or(f64::NAN)
}

/// Wall time and the process CPU time spent in the same run.
#[derive(Clone, Copy)]
struct Timed {
    wall: f64,
    cpu: f64,
}

/// Best wall time of `run(prepare())` over `runs` runs, with that run's CPU time;
/// `prepare` (e.g. copying the input that the analysis consumes) is not timed.
fn best_of_prepared<I, T>(
    runs: usize,
    mut prepare: impl FnMut() -> I,
    mut run: impl FnMut(I) -> T,
) -> (Timed, T) {
    let mut best = Timed {
        wall: f64::INFINITY,
        cpu: f64::NAN,
    };
    let mut out = None;
    for _ in 0..runs {
        let input = prepare();
        let (t, c) = (Instant::now(), cpu_now());
        let r = run(input);
        let wall = t.elapsed().as_secs_f64();
        if wall < best.wall {
            best = Timed {
                wall,
                cpu: cpu_now() - c,
            };
        }
        out = Some(r);
    }
    (best, out.expect("runs > 0"))
}

/// One axis as the analysis receives it after reading.
fn series(name: &str, rate: Vec<f64>) -> AxisSeries {
    AxisSeries::one_segment(name, 1.0 / RATE_HZ, rate)
}

/// The analysis of every axis in parallel (axes × τ), as `imulab allan` runs it.
fn analyse_all(
    axes: Vec<Vec<f64>>,
    kind: DeviationKind,
    grid: &TauGrid,
    fit: bool,
) -> Vec<AxisResult> {
    let options = AnalysisOptions {
        kind,
        grid: grid.clone(),
        fit,
        unit: RateUnit::RadPerSecond,
        sensor: RateUnit::RadPerSecond.sensor(),
    };
    axes.into_par_iter()
        .enumerate()
        .map(|(i, a)| analyse_axis("bench", series(&format!("{i}"), a), &options))
        .collect()
}

/// The six columns of `path` when it is a SAMPLES × 6 float64 array.
fn read_npy_axes(path: &std::path::Path) -> Option<Vec<Vec<f64>>> {
    let file = std::io::BufReader::new(std::fs::File::open(path).ok()?);
    let npy = npyz::NpyFile::new(file).ok()?;
    if npy.shape() != [SAMPLES as u64, 6] || npy.order() != npyz::Order::C {
        return None;
    }
    let mut axes: Vec<Vec<f64>> = (0..6).map(|_| Vec::with_capacity(SAMPLES)).collect();
    for (i, v) in npy.data::<f64>().ok()?.enumerate() {
        axes[i % 6].push(v.ok()?);
    }
    (axes[5].len() == SAMPLES).then_some(axes)
}

fn write_npy(path: &std::path::Path, axes: &[Vec<f64>]) {
    use npyz::WriterBuilder;
    let file = std::io::BufWriter::new(std::fs::File::create(path).expect("create npy"));
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(&[SAMPLES as u64, axes.len() as u64])
        .writer(file)
        .begin_nd()
        .expect("npy header");
    for i in 0..SAMPLES {
        for a in axes {
            w.push(&a[i]).expect("npy write");
        }
    }
    w.finish().expect("npy finish");
}

/// `--only KIND[:GRID]` (e.g. `oadev`, `oadev:dense:10`): section 1 for the matching
/// cases alone, then exit; `--runs N` sets its best-of count (default 3), so a profiler
/// can record one deviation type many times. `None` when no filter was given.
fn only_filter(args: &[String]) -> Option<(String, Option<String>, usize)> {
    let value = |flag: &str| {
        args.iter()
            .position(|a| a == flag)
            .and_then(|i| args.get(i + 1).cloned())
            .or_else(|| {
                let prefix = format!("{flag}=");
                args.iter()
                    .find_map(|a| a.strip_prefix(&prefix).map(str::to_string))
            })
    };
    let only = value("--only")?;
    let runs = value("--runs").and_then(|r| r.parse().ok()).unwrap_or(3);
    let (kind, grid) = match only.split_once(':') {
        Some((k, g)) => (k.to_string(), Some(g.to_string())),
        None => (only, None),
    };
    Some((kind, grid, runs))
}

fn main() {
    let raw: Vec<String> = std::env::args().skip(1).collect();
    let only = only_filter(&raw);
    let mut skip_value = false;
    let args: Vec<String> = raw
        .iter()
        .filter(|a| {
            let value = std::mem::take(&mut skip_value);
            skip_value = *a == "--only" || *a == "--runs";
            !value && !a.starts_with("--")
        })
        .cloned()
        .collect();
    if args.first().map(String::as_str) == Some("memory") {
        let days: f64 = args.get(1).and_then(|d| d.parse().ok()).unwrap_or(7.0);
        let format = args.get(2).map_or("session", String::as_str);
        memory_benchmark(days, format);
        return;
    }
    if args.first().map(String::as_str) == Some("session") {
        let flush_s: u64 = args.get(1).and_then(|d| d.parse().ok()).unwrap_or(1);
        session_read_benchmark(flush_s.max(1));
        return;
    }
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/allan-bench");
    std::fs::create_dir_all(&dir).expect("bench dir");
    // Both tools must see the same samples: an existing data.npy of the right shape is used
    // as it is (e.g. one allantools was already timed on), otherwise it is simulated here.
    let axes = match read_npy_axes(&dir.join("data.npy")) {
        Some(axes) => {
            println!("(using the existing {})", dir.join("data.npy").display());
            axes
        }
        None => {
            let axes: Vec<Vec<f64>> = (0..6).map(|a| simulate(100 + a)).collect();
            write_npy(&dir.join("data.npy"), &axes);
            axes
        }
    };
    let threads = rayon::current_num_threads();
    println!(
        "# Allan benchmark: {SAMPLES} samples per axis at {RATE_HZ} Hz, {threads} rayon threads\n"
    );

    // 1. Per deviation type, one axis and six axes (phase building included): wall and
    //    process CPU time with the default rayon pool, and the one axis on one thread.
    println!("| deviation | grid | taus | 1 axis [s] | 1 axis CPU [s] | 1 axis, 1 thread [s] | 1 axis, 1 thread CPU [s] | 6 axes [s] | 6 axes CPU [s] |");
    println!("|---|---|---|---|---|---|---|---|---|");
    let single = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("one-thread pool");
    let cases: [(DeviationKind, TauGrid, &str); 8] = [
        (DeviationKind::Oadev, TauGrid::Octave, "octave"),
        (DeviationKind::Oadev, TauGrid::Dense(10), "dense:10"),
        (DeviationKind::Adev, TauGrid::Octave, "octave"),
        (DeviationKind::Mdev, TauGrid::Octave, "octave"),
        (DeviationKind::Tdev, TauGrid::Octave, "octave"),
        (DeviationKind::Hdev, TauGrid::Octave, "octave"),
        (DeviationKind::Ohdev, TauGrid::Octave, "octave"),
        (DeviationKind::Totdev, TauGrid::Octave, "octave"),
    ];
    let runs = only.as_ref().map_or(3, |o| o.2.max(1));
    let mut kinds_json = Vec::new();
    // Phase building, deviations, noise identification, EDF and intervals are all timed; the
    // copy of the input (which the analysis consumes) is not.
    for (kind, grid, label) in &cases {
        if let Some((k, g, _)) = &only {
            if kind.name() != k || g.as_ref().is_some_and(|g| g != label) {
                continue;
            }
        }
        let (one, result) = best_of_prepared(
            runs,
            || vec![axes[0].clone()],
            |a| analyse_all(a, *kind, grid, false),
        );
        let (serial, _) = single.install(|| {
            best_of_prepared(
                runs,
                || vec![axes[0].clone()],
                |a| analyse_all(a, *kind, grid, false),
            )
        });
        let (six, _) = best_of_prepared(2, || axes.clone(), |a| analyse_all(a, *kind, grid, false));
        println!(
            "| {} | {label} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} |",
            kind.name(),
            result[0].curve.points.len(),
            one.wall,
            one.cpu,
            serial.wall,
            serial.cpu,
            six.wall,
            six.cpu
        );
        let points = &result[0].curve.points;
        kinds_json.push(json!({
            "kind": kind.name(), "grid": label, "taus": points.len(),
            "one_axis_s": one.wall, "one_axis_cpu_s": one.cpu,
            "one_thread_s": serial.wall, "one_thread_cpu_s": serial.cpu,
            "six_axes_s": six.wall, "six_axes_cpu_s": six.cpu,
            "axis0_tau_s": points.iter().map(|p| p.tau).collect::<Vec<_>>(),
            "axis0_deviation": points.iter().map(|p| p.deviation).collect::<Vec<_>>(),
        }));
    }

    if only.is_some() {
        return;
    }

    // 2. Full six-axis OADEV report with fit (phase, curve with EDF/CI/noise id, IRLS fit,
    //    units): in memory, and end to end from the .npy file (reading included).
    let (report, fits) = best_of_prepared(
        3,
        || axes.clone(),
        |a| analyse_all(a, DeviationKind::Oadev, &TauGrid::Octave, true),
    );
    let (report_serial, _) = single.install(|| {
        best_of_prepared(
            3,
            || axes.clone(),
            |a| analyse_all(a, DeviationKind::Oadev, &TauGrid::Octave, true),
        )
    });
    println!(
        "\nSix-axis OADEV octave report with fit, in memory: {:.3} s, CPU {:.3} s ({} fits); on one thread {:.3} s, CPU {:.3} s",
        report.wall,
        report.cpu,
        fits.iter().filter(|r| r.fit.is_some()).count(),
        report_serial.wall,
        report_serial.cpu
    );
    let npy = dir.join("data.npy");
    let cli = AnalysisCli::parse_from([
        "bench", "--rate", "150", "--units", "rad/s", "--fit", "--kind", "oadev",
    ]);
    let (end_to_end, report_doc) = best_of_prepared(
        3,
        || (),
        |()| {
            analyse_inputs(
                std::slice::from_ref(&npy),
                &cli.analysis,
                &AsRecorded,
                &mut (),
            )
            .expect("analyse the npy file")
        },
    );
    println!(
        "Six-axis OADEV octave report with fit, from data.npy (reading included): {:.3} s, CPU {:.3} s ({} axes)\n",
        end_to_end.wall,
        end_to_end.cpu,
        report_doc.axes.len()
    );

    // 2b. The same six axes as a session (one IMU: gyro = columns 0–2, accel = 3–5),
    //     end to end through the session reader (decompression included).
    let session = dir.join("session");
    let _ = std::fs::remove_dir_all(&session);
    write_axes_session(&session, &axes);
    let cli = AnalysisCli::parse_from(["bench", "--fit", "--kind", "oadev"]);
    let (from_session, session_doc) = best_of_prepared(
        3,
        || (),
        |()| {
            analyse_inputs(
                std::slice::from_ref(&session),
                &cli.analysis,
                &AsRecorded,
                &mut (),
            )
            .expect("analyse the session")
        },
    );
    println!(
        "Six-axis OADEV octave report with fit, from a session (reading included): {:.3} s, CPU {:.3} s ({} axes)\n",
        from_session.wall,
        from_session.cpu,
        session_doc.axes.len()
    );
    std::fs::remove_dir_all(&session).expect("delete the benchmark session");

    // 3. Run time against error: grid density and the fitted terms (mean |error| over 6 axes).
    println!(
        "| grid | taus | time 6 axes [s] | mean abs error N | mean abs error K | K identified |"
    );
    println!("|---|---|---|---|---|---|");
    let mut grids_json = Vec::new();
    for (grid, label) in [
        (TauGrid::Octave, "octave"),
        (TauGrid::Decade, "decade"),
        (TauGrid::Dense(5), "dense:5"),
        (TauGrid::Dense(10), "dense:10"),
        (TauGrid::Dense(20), "dense:20"),
    ] {
        let (t, results) = best_of(2, || {
            axes.iter()
                .map(|a| {
                    let c = compute_curve(
                        &Phase::from_rate(a.clone()),
                        1.0 / RATE_HZ,
                        DeviationKind::Oadev,
                        &grid,
                    );
                    (c.points.len(), fit_noise_terms(&c).ok())
                })
                .collect::<Vec<_>>()
        });
        let taus = results[0].0;
        let (mut en, mut ek, mut kid) = (0.0, 0.0, 0);
        for (_, f) in &results {
            if let Some(f) = f {
                if let Some(n) = f.get(Term::RandomWalk).and_then(|t| t.value) {
                    en += (n / N_TRUE - 1.0).abs();
                }
                if let Some(k) = f.get(Term::RateRandomWalk).and_then(|t| t.value) {
                    ek += (k / K_TRUE - 1.0).abs();
                    kid += 1;
                }
            }
        }
        println!(
            "| {label} | {taus} | {t:.3} | {:.2e} | {} | {kid}/6 |",
            en / 6.0,
            if kid > 0 {
                format!("{:.2e}", ek / kid as f64)
            } else {
                "-".into()
            }
        );
        grids_json.push(json!({
            "grid": label, "taus": taus, "six_axes_s": t,
            "mean_abs_rel_err_n": en / 6.0,
            "mean_abs_rel_err_k": (kid > 0).then(|| ek / kid as f64),
            "k_identified_of_6": kid,
        }));
    }

    // 4. f32 vs f64: input precision and naive f32 accumulation against the f64 compensated path,
    //    on the accelerometer-like case (1 g offset on the axis).
    println!("\n| variant | time 1 axis [s] | max relative error of OADEV (octave) |");
    println!("|---|---|---|");
    let with_g: Vec<f64> = axes[0].iter().map(|v| v + 9.80665).collect();
    let tau0 = 1.0 / RATE_HZ;
    let (t_ref, reference) = best_of(3, || {
        compute_curve(
            &Phase::from_rate(with_g.clone()),
            tau0,
            DeviationKind::Oadev,
            &TauGrid::Octave,
        )
    });
    println!("| f64 input, compensated f64 phase (default) | {t_ref:.3} | reference |");
    let f32_input: Vec<f64> = with_g.iter().map(|&v| f64::from(v as f32)).collect();
    let (t32, c32) = best_of(3, || {
        compute_curve(
            &Phase::from_rate(f32_input.clone()),
            tau0,
            DeviationKind::Oadev,
            &TauGrid::Octave,
        )
    });
    println!(
        "| f32 input promoted to f64 | {t32:.3} | {:.2e} |",
        max_rel(&reference, &c32)
    );
    // Plain f64: running phase without mean removal or compensation, plain sums.
    let (tp, plain) = best_of(3, || naive_f64_oadev(&with_g, &reference));
    println!("| plain f64 phase (no mean removal, plain sums) | {tp:.3} | {plain:.2e} |");
    // Naive f32 accumulation: phase as a plain f32 running sum without mean removal.
    let (tn, naive) = best_of(3, || naive_f32_oadev(&with_g, &reference));
    println!(
        "| naive f32 phase (no mean removal, plain sum) | {tn:.3} | {:.2e} |",
        naive
    );
    let precision_json = json!([
        {"variant": "f64 input, compensated f64 phase (default)", "time_s": t_ref, "max_rel_err": null},
        {"variant": "f32 input", "time_s": t32, "max_rel_err": max_rel(&reference, &c32)},
        {"variant": "plain f64 phase", "time_s": tp, "max_rel_err": plain},
        {"variant": "naive f32 phase", "time_s": tn, "max_rel_err": naive},
    ]);

    // 5. Coverage of the fit's 95 % term intervals on independent simulated runs
    //    (100 s crossover regime of tests/allan/fit.rs: 600 000 samples at 100 Hz).
    let mut covered = [0usize; 2];
    let mut identified = [0usize; 2];
    let runs = 100;
    let (n_true, k_true) = (2e-3, 5e-4);
    let t_cov = Instant::now();
    for seed in 0..runs {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(10_000 + seed);
        let mut walk = 0.0;
        let y: Vec<f64> = (0..600_000)
            .map(|_| {
                let w: f64 = StandardNormal.sample(&mut rng);
                let s: f64 = StandardNormal.sample(&mut rng);
                walk += k_true * 0.1 * s;
                n_true * 10.0 * w + walk
            })
            .collect();
        let c = compute_curve(
            &Phase::from_rate(y),
            0.01,
            DeviationKind::Oadev,
            &TauGrid::Octave,
        );
        if let Ok(f) = fit_noise_terms(&c) {
            for (i, (term, truth)) in [(Term::RandomWalk, n_true), (Term::RateRandomWalk, k_true)]
                .iter()
                .enumerate()
            {
                if let Some(t) = f.get(*term) {
                    if t.value.is_some() {
                        identified[i] += 1;
                        if t.low <= *truth && *truth <= t.high {
                            covered[i] += 1;
                        }
                    }
                }
            }
        }
    }
    println!(
        "\nFit interval coverage over {runs} runs ({:.1} s): N identified {}/{runs}, truth inside 95 % interval {}/{}; K identified {}/{runs}, inside {}/{}",
        t_cov.elapsed().as_secs_f64(),
        identified[0],
        covered[0],
        identified[0],
        identified[1],
        covered[1],
        identified[1]
    );

    // 6. Our OADEV of axis 0 for the cross-check against allantools' printout.
    let c = compute_curve(
        &Phase::from_rate(axes[0].clone()),
        tau0,
        DeviationKind::Oadev,
        &TauGrid::Octave,
    );
    println!("\nimulab OADEV axis 0 (tau, dev):");
    for p in &c.points {
        println!("{:.6e} {:.10e}", p.tau, p.deviation);
    }

    // The figures for `benches/allan_vs_allantools.sh` (which owns the rows against
    // allantools) and the run-time-against-error plot of BENCHMARKS.md.
    results::write(
        "allan",
        "speed",
        json!({ "samples": SAMPLES, "rate_hz": RATE_HZ, "axes": 6, "rayon_threads": threads }),
        json!({
            "kinds": kinds_json,
            "report_with_fit": {
                "in_memory_s": report.wall, "in_memory_cpu_s": report.cpu,
                "one_thread_s": report_serial.wall, "from_npy_s": end_to_end.wall,
                "from_session_s": from_session.wall,
            },
            "grids": grids_json,
            "precision": precision_json,
            "fit_coverage": {
                "runs": runs, "n_identified": identified[0], "n_covered": covered[0],
                "k_identified": identified[1], "k_covered": covered[1],
            },
        }),
        &[],
    );
}

#[derive(clap::Parser)]
struct AnalysisCli {
    #[command(flatten)]
    analysis: Options,
}

fn max_rel(a: &imulab::allan::Curve, b: &imulab::allan::Curve) -> f64 {
    a.points
        .iter()
        .zip(&b.points)
        .map(|(p, q)| (p.deviation - q.deviation).abs() / p.deviation)
        .fold(0.0, f64::max)
}

/// A straightforward f64 implementation: running f64 phase of the raw samples (offset
/// included), plain f64 sums of the squared second differences. Maximum relative error
/// against `reference`.
fn naive_f64_oadev(y: &[f64], reference: &imulab::allan::Curve) -> f64 {
    let mut x = Vec::with_capacity(y.len() + 1);
    let mut acc = 0.0f64;
    x.push(0.0);
    for &v in y {
        acc += v;
        x.push(acc);
    }
    let mut worst = 0.0f64;
    for p in &reference.points {
        let m = p.m;
        let count = x.len() - 2 * m;
        let s: f64 = (0..count)
            .map(|i| {
                let d = x[i + 2 * m] - 2.0 * x[i + m] + x[i];
                d * d
            })
            .sum();
        let dev = (s / (2.0 * (m * m) as f64 * count as f64)).sqrt();
        worst = worst.max((dev - p.deviation).abs() / p.deviation);
    }
    worst
}

/// The bench's IMU device description.
fn bench_device() -> imulab::store::DeviceInfo {
    imulab::store::DeviceInfo {
        name: "imu0".into(),
        kind: imulab::store::DeviceKind::Imu,
        model: "sim".into(),
        serial: String::new(),
        port: "sim".into(),
        protocol: "sim".into(),
        rate_hz: RATE_HZ,
        axis_frame: "FRD".into(),
        extra: Default::default(),
    }
}

/// A session writer for the benchmark data (no fsync, no rotation within a week).
fn bench_writer(path: &std::path::Path) -> imulab::store::SessionWriter {
    use imulab::store::WriterOptions;
    bench_writer_with(
        path,
        WriterOptions {
            fsync_on_flush: false,
            rotate_after: std::time::Duration::from_secs(86_400),
            rotate_bytes: 8 << 30,
            flush_interval: std::time::Duration::from_secs(60),
            ..WriterOptions::default()
        },
    )
}

fn bench_writer_with(
    path: &std::path::Path,
    options: imulab::store::WriterOptions,
) -> imulab::store::SessionWriter {
    use imulab::store::{Manifest, SessionWriter};
    SessionWriter::create(
        path,
        Manifest::new(vec![bench_device()], toml::Table::new()),
        options,
    )
    .expect("create the session")
}

/// One IMU row at row index `row` of a 150 Hz stream.
fn bench_record(row: usize, gyro: [f64; 3], accel: [f64; 3]) -> imulab::store::ImuRecord {
    let t_ns = 1_000_000_000 + (row as f64 * 1e9 / RATE_HZ).round() as i64;
    imulab::store::ImuRecord {
        t_mono_ns: t_ns,
        t_wall_ns: 1_700_000_000_000_000_000 + t_ns,
        t_sensor: f64::NAN,
        gyro,
        accel,
        temp: 25.0,
        status: 0,
    }
}

/// Writes six axes (gyro x, y, z then accel x, y, z) as a session with one IMU `imu0`.
fn write_axes_session(path: &std::path::Path, axes: &[Vec<f64>]) {
    write_axes_session_with(axes, bench_writer(path));
}

fn write_axes_session_with(axes: &[Vec<f64>], mut writer: imulab::store::SessionWriter) {
    let mut records = Vec::with_capacity(9_000);
    let rows = axes[0].len();
    for start in (0..rows).step_by(9_000) {
        records.clear();
        records.extend((start..(start + 9_000).min(rows)).map(|r| {
            let v = |a: usize| axes[a][r];
            bench_record(r, [v(0), v(1), v(2)], [v(3), v(4), v(5)])
        }));
        writer.append_imu("imu0", &records).expect("append rows");
    }
    writer.close().expect("close the session");
}

/// Writes `rows` rows as a session with one IMU `imu0` (gyro simulated, accel constant).
fn write_memory_session(path: &std::path::Path, rows: usize) {
    let mut writer = bench_writer(path);
    let mut row = 0;
    let mut records = Vec::with_capacity(9_000);
    simulate_batches(rows, 9_000, |batch| {
        records.clear();
        for gyro in batch {
            records.push(bench_record(row, *gyro, [0.0, 0.0, -9.80665]));
            row += 1;
        }
        writer.append_imu("imu0", &records).expect("append rows");
    });
    writer.close().expect("close the session");
}

/// Writes `rows` × 6 float64 (gyro x, y, z simulated; accel constant) as a row-major .npy,
/// the layout of a six-axis IMU export.
fn write_memory_npy(path: &std::path::Path, rows: usize) {
    use npyz::WriterBuilder;
    let file = std::io::BufWriter::with_capacity(
        1 << 20,
        std::fs::File::create(path).expect("create npy"),
    );
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(&[rows as u64, 6])
        .writer(file)
        .begin_nd()
        .expect("npy header");
    simulate_batches(rows, 65_536, |batch| {
        for gyro in batch {
            for v in gyro.iter().chain(&[0.0, 0.0, -9.80665]) {
                w.push(v).expect("npy write");
            }
        }
    });
    w.finish().expect("npy finish");
}

/// Peak memory of `imulab allan` on `days` of 150 Hz data, as a session or a six-column .npy
/// in /tmp (deleted afterwards): three gyro axes, OADEV octave with fit, run as a child under
/// GNU time, whose maximum resident set size is compared with the size of one axis.
fn memory_benchmark(days: f64, format: &str) {
    let rows = (days * 86_400.0 * RATE_HZ) as usize;
    let dir = std::env::temp_dir().join(format!("imulab-allan-memory-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("create the benchmark directory");
    let t_write = Instant::now();
    let (input, common): (std::path::PathBuf, Vec<&str>) = if format == "npy" {
        let path = dir.join("week.npy");
        write_memory_npy(&path, rows);
        (path, vec!["--rate", "150", "--units", "rad/s"])
    } else {
        let path = dir.join("session");
        write_memory_session(&path, rows);
        (path, vec!["--sensor", "gyro"])
    };
    let disk = if input.is_dir() {
        std::fs::read_dir(&input)
            .map(|d| {
                d.flatten()
                    .filter_map(|e| e.metadata().ok())
                    .map(|m| m.len())
                    .sum()
            })
            .unwrap_or(0)
    } else {
        std::fs::metadata(&input).map(|m| m.len()).unwrap_or(0)
    };
    println!(
        "# Allan memory benchmark: {days} days at {RATE_HZ} Hz = {rows} rows, {format} {} ({:.0} MB, written in {:.1} s)\n",
        input.display(),
        disk as f64 / 1e6,
        t_write.elapsed().as_secs_f64()
    );
    let axis_mb = rows as f64 * 8.0 / 1e6;
    println!("| run | peak RSS [MB] | one axis [MB] | all 6 axes [MB] | peak / one axis | wall [s] | CPU [s] |");
    println!("|---|---|---|---|---|---|---|");
    let mut runs = Vec::new();
    let gyro_axes = if format == "npy" { "0,1,2" } else { "x,y,z" };
    let one_axis = if format == "npy" { "0" } else { "x" };
    for (label, axes) in [
        ("three gyro axes, default --memory-mib 1024", gyro_axes),
        ("one gyro axis", one_axis),
    ] {
        // GNU time reports the child's own peak RSS (KiB) and CPU times on its last line.
        let t = Instant::now();
        let output = std::process::Command::new("/usr/bin/time")
            .args(["-f", "peak-rss-kib %M cpu %U %S"])
            .arg(env!("CARGO_BIN_EXE_imulab"))
            .arg("allan")
            .arg(&input)
            .args(&common)
            .args(["--axes", axes, "--kind", "oadev", "--fit"])
            .output()
            .expect("run imulab allan under /usr/bin/time");
        let wall = t.elapsed().as_secs_f64();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(output.status.success(), "imulab allan failed: {stderr}");
        let fields: Vec<f64> = stderr
            .lines()
            .rev()
            .find_map(|l| l.strip_prefix("peak-rss-kib "))
            .map(|l| {
                l.split_whitespace()
                    .filter_map(|v| v.parse().ok())
                    .collect()
            })
            .unwrap_or_default();
        let [peak_kib, user, system] = fields[..] else {
            panic!("no usage line from /usr/bin/time: {stderr}");
        };
        let peak_mb = peak_kib * 1024.0 / 1e6;
        println!(
            "| {label} | {peak_mb:.0} | {axis_mb:.0} | {:.0} | {:.2} | {wall:.1} | {:.1} |",
            6.0 * axis_mb,
            peak_mb / axis_mb,
            user + system
        );
        runs.push(json!({
            "run": label, "peak_rss_mb": peak_mb, "wall_s": wall, "cpu_s": user + system,
        }));
        let text = String::from_utf8_lossy(&output.stdout);
        for line in text
            .lines()
            .filter(|l| l.starts_with("Gyro ARW") || l.starts_with("Gyro RRW"))
        {
            println!("    {line}");
        }
    }
    std::fs::remove_dir_all(&dir).expect("delete the benchmark data");
    println!("\ninput deleted");
    // Memory in proportion to one axis: reading three axes peaks no higher than one (10 %).
    let peak = |i: usize| runs[i]["peak_rss_mb"].as_f64().unwrap_or(f64::NAN);
    let (three, one) = (peak(0), peak(1));
    let rows = [results::Row::new(
        "allan-memory",
        results::ALLAN,
        6,
        "memory",
        "docs/bench/allan.md",
    )
    .data(format!("{days} days × 150 Hz, 3 axes"))
    .ours(format!("{three:.0} MB ({:.2}× one axis)", three / axis_mb))
    .target("∝ one axis")
    .met(three <= 1.1 * one)
    .timed()
    .command(format!(
        "cargo bench --bench allan -- memory {days} session"
    ))];
    results::write(
        "allan",
        &format!("memory-{format}"),
        json!({ "days": days, "format": format, "rows": rows_total(days) }),
        json!({ "disk_mb": disk as f64 / 1e6, "one_axis_mb": axis_mb, "runs": runs }),
        if format == "session" { &rows } else { &[] },
    );
}

fn rows_total(days: f64) -> usize {
    (days * 86_400.0 * RATE_HZ) as usize
}

/// The session read path: six axes + time of 6 h read through `read_axes` (what `imulab
/// allan` does before analysing), then the six-axis OADEV report with fit end to end, on a
/// session with `flush_s`-second chunks and the writer's default rotation (10 min files).
fn session_read_benchmark(flush_s: u64) {
    use imulab::allan::input::{read_axes, DataKind, GapPolicy, SampleSource, Timing};
    use imulab::allan::session_source::SessionSource;
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/allan-bench");
    std::fs::create_dir_all(&dir).expect("bench dir");
    let axes = read_npy_axes(&dir.join("data.npy"))
        .unwrap_or_else(|| (0..6).map(|a| simulate(100 + a)).collect());
    let session = dir.join(format!("session-{flush_s}s"));
    let complete = imulab::store::Session::open(&session).is_ok_and(|s| {
        s.problems().is_empty() && s.stream_summary("imu/imu0").rows == SAMPLES as u64
    });
    if !complete {
        let _ = std::fs::remove_dir_all(&session);
        let t = Instant::now();
        let options = imulab::store::WriterOptions {
            fsync_on_flush: false,
            flush_interval: std::time::Duration::from_secs(flush_s),
            ..imulab::store::WriterOptions::default()
        };
        let writer = bench_writer_with(&session, options);
        write_axes_session_with(&axes, writer);
        println!(
            "(wrote {} in {:.1} s)",
            session.display(),
            t.elapsed().as_secs_f64()
        );
    }
    let files = std::fs::read_dir(&session).map_or(0, |d| d.count());
    println!(
        "# Session read benchmark: {SAMPLES} rows × 6 axes at {RATE_HZ} Hz, {flush_s} s chunks, {files} files in {}\n",
        session.display()
    );
    let (read, series) = best_of_prepared(
        3,
        || (),
        |()| {
            let source = SessionSource::open(&session, None, None, None).expect("open session");
            let wanted: Vec<usize> = [
                "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z",
            ]
            .iter()
            .map(|c| source.channel_index(c).expect("channel"))
            .collect();
            let t = source.channel_index("t").expect("time channel");
            read_axes(
                &source,
                &wanted,
                &Timing::ArrivalTimes {
                    channel: t,
                    scale: 1.0,
                },
                GapPolicy::Error,
                DataKind::Rate,
                None,
            )
            .expect("read six axes")
        },
    );
    for (got, want) in series.iter().zip(&axes) {
        assert_eq!(got.segments.len(), 1, "{}: one segment", got.name);
        assert!(got.segments[0] == *want, "{}: values differ", got.name);
    }
    println!(
        "Read six axes + time (read_axes, gap check included): {:.3} s, CPU {:.3} s, {:.1} M rows/s of CPU",
        read.wall,
        read.cpu,
        SAMPLES as f64 / read.cpu / 1e6
    );
    drop(series);
    let cli = AnalysisCli::parse_from(["bench", "--fit", "--kind", "oadev"]);
    let (report, doc) = best_of_prepared(
        3,
        || (),
        |()| {
            analyse_inputs(
                std::slice::from_ref(&session),
                &cli.analysis,
                &AsRecorded,
                &mut (),
            )
            .expect("analyse the session")
        },
    );
    println!(
        "Six-axis OADEV octave report with fit, from the session (reading included): {:.3} s, CPU {:.3} s ({} axes)",
        report.wall,
        report.cpu,
        doc.axes.len()
    );
    let row = results::Row::new(
        "allan-session-report",
        results::ALLAN,
        4,
        "six-axis report with fit",
        "docs/bench/allan.md",
    )
    .data(format!("6 h session, {files} files"))
    .ours(format!("{:.2} s", report.wall))
    .target("< 0.5 s")
    .met(report.wall < 0.5)
    .timed()
    .command(format!("cargo bench --bench allan -- session {flush_s}"));
    results::write(
        "allan",
        "session",
        json!({ "flush_s": flush_s, "rows": SAMPLES, "axes": 6 }),
        json!({
            "files": files,
            "read_six_axes_s": read.wall, "read_six_axes_cpu_s": read.cpu,
            "report_with_fit_s": report.wall, "report_with_fit_cpu_s": report.cpu,
        }),
        &[row],
    );
}

/// What a straightforward f32 implementation does: cumulative f32 sum of the raw samples,
/// second differences in f32. Returns the maximum relative error against `reference`.
fn naive_f32_oadev(y: &[f64], reference: &imulab::allan::Curve) -> f64 {
    let mut x = Vec::with_capacity(y.len() + 1);
    let mut acc = 0.0f32;
    x.push(0.0f32);
    for &v in y {
        acc += v as f32;
        x.push(acc);
    }
    let mut worst = 0.0f64;
    for p in &reference.points {
        let m = p.m;
        let count = x.len() - 2 * m;
        let mut s = 0.0f32;
        for i in 0..count {
            let d = x[i + 2 * m] - 2.0 * x[i + m] + x[i];
            s += d * d;
        }
        let dev = (f64::from(s) / (2.0 * (m * m) as f64 * count as f64)).sqrt();
        worst = worst.max((dev - p.deviation).abs() / p.deviation);
    }
    worst
}
