//! Times one Allan curve on axis 0 of the Allan benchmark's data (6 h × 150 Hz of white
//! rate noise N = 2e-3 plus rate random walk K = 5e-5, simulated with the bench's seed
//! 100) in a rayon pool of THREADS threads, and prints the minimum and median process CPU
//! time and wall time over RUNS runs. Only the analysis is timed, not the copy of the
//! input it consumes.
//!
//! `cargo run --release --example allan_probe -- KIND [RUNS] [THREADS] [GRID] [phase] [parts] [print]`
//!
//! - KIND: any deviation kind (adev, oadev, mdev, hdev, ohdev, tdev, totdev); RUNS
//!   (default 10), THREADS (default 1), GRID (octave, decade, dense:N, all; default octave).
//! - Default: `analyse_axis` without fit (what the bench's per-type rows time).
//! - `phase`: the phase path instead (`Phase::from_rate` + `compute_curve`), which ADEV and
//!   HDEV on an octave grid skip since `compute_curve_from_rate`.
//! - `parts`: also the pieces alone: the phase, and the deviation sums of every grid
//!   factor (`variances_with`, e.g. the MDEV/TDEV window-sum kernel).
//! - `print`: the mean and every point of the curve (m, deviation, count, EDF, α).
use imulab::allan::analysis::{analyse_axis, AnalysisOptions};
use imulab::allan::deviation::variances_with;
use imulab::allan::input::AxisSeries;
use imulab::allan::numerics::Simd;
use imulab::allan::units::RateUnit;
use imulab::allan::{compute_curve, Curve, DeviationKind, Phase, TauGrid};
use std::time::Instant;

// The bench's synthetic data (one generator for both).
use imulab_test_support::gyro_noise::{simulate, RATE_HZ, SAMPLES};

fn cpu_ms() -> f64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID)
        .map(|t| t.tv_sec() as f64 * 1e3 + t.tv_nsec() as f64 * 1e-6)
        .unwrap_or(f64::NAN)
}

/// Runs `f(prepare())` `runs` times (only `f` timed), prints the min and median CPU and
/// wall milliseconds under `label`, and returns the last result.
fn time<P, T>(label: &str, runs: usize, prepare: impl Fn() -> P, f: impl Fn(P) -> T) -> T {
    let (mut cpus, mut walls, mut last) = (Vec::new(), Vec::new(), None);
    for _ in 0..runs {
        let input = prepare();
        let (t, c) = (Instant::now(), cpu_ms());
        last = Some(f(input));
        walls.push(t.elapsed().as_secs_f64() * 1e3);
        cpus.push(cpu_ms() - c);
    }
    cpus.sort_by(f64::total_cmp);
    walls.sort_by(f64::total_cmp);
    println!(
        "  {label:<13} cpu ms min {:.3} med {:.3}; wall ms min {:.3} med {:.3}",
        cpus[0],
        cpus[runs / 2],
        walls[0],
        walls[runs / 2]
    );
    last.expect("at least one run")
}

fn usage(problem: &str) -> ! {
    eprintln!(
        "allan_probe: {problem}\nusage: allan_probe KIND [RUNS] [THREADS] [GRID] [phase] [parts] [print]"
    );
    std::process::exit(2)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let kind_name = args.first().map_or("hdev", String::as_str);
    let kind = DeviationKind::ALL
        .into_iter()
        .find(|k| k.name() == kind_name)
        .unwrap_or_else(|| usage(&format!("unknown deviation kind `{kind_name}`")));
    let number = |i: usize, default: usize| match args.get(i) {
        None => default,
        Some(s) => s
            .parse::<usize>()
            .ok()
            .filter(|&v| v > 0)
            .unwrap_or_else(|| usage(&format!("argument {} `{s}` is not a positive count", i + 1))),
    };
    let runs = number(1, 10);
    let threads = number(2, 1);
    let (mut grid, mut phase_path, mut parts, mut print) = (TauGrid::Octave, false, false, false);
    for option in args.iter().skip(3) {
        match option.as_str() {
            "phase" => phase_path = true,
            "parts" => parts = true,
            "print" => print = true,
            other => grid = other.parse().unwrap_or_else(|e: String| usage(&e)),
        }
    }
    let y = simulate(100);
    let tau0 = 1.0 / RATE_HZ;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap_or_else(|e| usage(&format!("thread pool of {threads}: {e}")));
    let factors = grid.factors(kind, SAMPLES + 1, tau0);
    println!(
        "{} {} τ, threads={threads}, runs={runs}",
        kind.name(),
        factors.len()
    );
    if parts {
        let phase = time(
            "phase:",
            runs,
            || y.clone(),
            |r| pool.install(|| Phase::from_rate(r)),
        );
        time(
            "sums:",
            runs,
            || (),
            |()| pool.install(|| variances_with(kind, &phase, &factors, Simd::detected())),
        );
    }
    let (curve, mean): (Curve, f64) = if phase_path {
        time(
            "phase path:",
            runs,
            || y.clone(),
            |r| {
                pool.install(|| {
                    let phase = Phase::from_rate(r);
                    (compute_curve(&phase, tau0, kind, &grid), phase.removed_mean)
                })
            },
        )
    } else {
        let options = AnalysisOptions {
            kind,
            grid: grid.clone(),
            fit: false,
            unit: RateUnit::RadPerSecond,
            sensor: RateUnit::RadPerSecond.sensor(),
        };
        let series = || AxisSeries::one_segment("0", tau0, y.clone());
        let result = time("analyse_axis:", runs, series, |s| {
            pool.install(|| analyse_axis("probe", s, &options))
        });
        (result.curve, result.mean)
    };
    if print {
        println!("mean {mean:e}");
        for p in &curve.points {
            println!(
                "{} {:.17e} {} {:?} {}",
                p.m, p.deviation, p.count, p.edf, p.alpha
            );
        }
    }
}
