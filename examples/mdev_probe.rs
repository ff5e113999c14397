//! Times the pieces of one MDEV or TDEV curve on axis 0 of the Allan benchmark's data
//! (6 h × 150 Hz simulated with the bench's seed 100) in a rayon pool of 1 or 2 threads:
//! the phase (`Phase::from_rate`, input copy not timed), the window sums of all grid
//! factors (`variances_with`, the MDEV/TDEV kernel alone), and the whole `analyse_axis`
//! (phase, sums, noise identification, EDF and intervals). Prints min and median process
//! CPU time and wall time of each.
//!
//! `cargo run --release --example mdev_probe -- [mdev|tdev] [RUNS] [THREADS] [octave|dense:N]`
use imulab::allan::analysis::{analyse_axis, AnalysisOptions};
use imulab::allan::deviation::variances_with;
use imulab::allan::input::AxisSeries;
use imulab::allan::numerics::Simd;
use imulab::allan::units::RateUnit;
use imulab::allan::{DeviationKind, Phase, TauGrid};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use std::time::Instant;

const RATE_HZ: f64 = 150.0;
const SAMPLES: usize = 6 * 3600 * 150;

/// The bench's simulation (white rate noise N = 2e-3 plus rate random walk K = 5e-5).
fn simulate(seed: u64) -> Vec<f64> {
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
    let tau0 = 1.0 / RATE_HZ;
    let mut walk = 0.0;
    (0..SAMPLES)
        .map(|_| {
            let w: f64 = StandardNormal.sample(&mut rng);
            let s: f64 = StandardNormal.sample(&mut rng);
            walk += 5e-5 * tau0.sqrt() * s;
            2e-3 / tau0.sqrt() * w + walk
        })
        .collect()
}

fn cpu_ms() -> f64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID)
        .map(|t| t.tv_sec() as f64 * 1e3 + t.tv_nsec() as f64 * 1e-6)
        .unwrap_or(f64::NAN)
}

/// Min and median CPU and wall milliseconds of `runs` calls of `f(prepare())`, only
/// `f` timed.
fn time<P, T>(runs: usize, prepare: impl Fn() -> P, f: impl Fn(P) -> T) -> (String, T) {
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
    let text = format!(
        "cpu ms min {:.2} med {:.2}; wall ms min {:.2} med {:.2}",
        cpus[0],
        cpus[runs / 2],
        walls[0],
        walls[runs / 2]
    );
    (text, last.expect("at least one run"))
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let kind = match args.first().map(String::as_str) {
        Some("tdev") => DeviationKind::Tdev,
        _ => DeviationKind::Mdev,
    };
    let runs: usize = args
        .get(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(10)
        .max(1);
    let threads: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1);
    let grid = match args.get(3).and_then(|g| g.strip_prefix("dense:")) {
        Some(n) => TauGrid::Dense(n.parse().expect("dense:N with a number N")),
        None => TauGrid::Octave,
    };
    let y = simulate(100);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool");
    let (phase_time, phase) = time(runs, || y.clone(), |r| pool.install(|| Phase::from_rate(r)));
    let factors = grid.factors(kind, phase.len(), 1.0 / RATE_HZ);
    let (sums_time, _) = time(
        runs,
        || (),
        |()| pool.install(|| variances_with(kind, &phase, &factors, Simd::detected())),
    );
    let options = AnalysisOptions {
        kind,
        grid: grid.clone(),
        fit: false,
        unit: RateUnit::RadPerSecond,
        sensor: RateUnit::RadPerSecond.sensor(),
    };
    let series = |rate: Vec<f64>| AxisSeries::one_segment("0", 1.0 / RATE_HZ, rate);
    let (axis_time, _) = time(
        runs,
        || series(y.clone()),
        |s| pool.install(|| analyse_axis("probe", s, &options)),
    );
    println!(
        "{} {} τ, threads={threads}, runs={runs}\n  phase:        {phase_time}\n  window sums:  {sums_time}\n  analyse_axis: {axis_time}",
        kind.name(),
        factors.len()
    );
}
