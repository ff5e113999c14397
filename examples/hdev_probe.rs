//! Times `analyse_axis` (no fit) for one deviation kind on the octave grid, on axis 0 of
//! the Allan benchmark's data (6 h × 150 Hz simulated with the bench's seed 100), in a
//! rayon pool of 1 or 2 threads; the copy of the input is not timed. With `phase` it
//! times the phase path instead (`Phase::from_rate` + `compute_curve`), which ADEV and
//! HDEV took before `compute_curve_from_rate`. Prints min and median CPU and wall time.
//!
//! `cargo run --release --example hdev_probe -- KIND [RUNS] [THREADS] [phase] [print]`
//! (KIND hdev, adev or oadev).
use imulab::allan::analysis::{analyse_axis, AnalysisOptions};
use imulab::allan::input::AxisSeries;
use imulab::allan::units::RateUnit;
use imulab::allan::{DeviationKind, TauGrid};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use std::time::Instant;

const RATE_HZ: f64 = 150.0;
const SAMPLES: usize = 6 * 3600 * 150;

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

fn cpu(id: nix::time::ClockId) -> f64 {
    nix::time::clock_gettime(id)
        .map(|t| t.tv_sec() as f64 + t.tv_nsec() as f64 * 1e-9)
        .unwrap_or(f64::NAN)
}

fn series(rate: Vec<f64>) -> AxisSeries {
    AxisSeries::one_segment("0", 1.0 / RATE_HZ, rate)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let kind = match args.first().map(String::as_str) {
        Some("adev") => DeviationKind::Adev,
        Some("oadev") => DeviationKind::Oadev,
        _ => DeviationKind::Hdev,
    };
    let runs: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(10);
    let threads: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1);
    let y = simulate(100);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let options = AnalysisOptions {
        kind,
        grid: TauGrid::Octave,
        fit: false,
        unit: RateUnit::RadPerSecond,
        sensor: RateUnit::RadPerSecond.sensor(),
    };
    let mut cpus = Vec::new();
    let mut walls = Vec::new();
    let mut last = None;
    for _ in 0..runs {
        let input = y.clone();
        let (t, c) = (
            Instant::now(),
            cpu(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID),
        );
        let r = if args.iter().any(|a| a == "phase") {
            // The phase path (before this change): phase, then the curve from it.
            pool.install(|| {
                let phase = imulab::allan::Phase::from_rate(input);
                let curve =
                    imulab::allan::compute_curve(&phase, 1.0 / RATE_HZ, kind, &TauGrid::Octave);
                let mut r = analyse_axis("probe", series(vec![0.0; 8]), &options);
                r.curve = curve;
                r.mean = phase.removed_mean;
                r
            })
        } else {
            pool.install(|| analyse_axis("probe", series(input), &options))
        };
        walls.push(t.elapsed().as_secs_f64() * 1e3);
        cpus.push((cpu(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID) - c) * 1e3);
        last = Some(r);
    }
    let r = last.unwrap();
    let mut sc = cpus.clone();
    sc.sort_by(f64::total_cmp);
    let mut sw = walls.clone();
    sw.sort_by(f64::total_cmp);
    println!(
        "{} threads={threads} runs={runs}: cpu ms min {:.3} med {:.3}; wall ms min {:.3} med {:.3}",
        kind.name(),
        sc[0],
        sc[runs / 2],
        sw[0],
        sw[runs / 2]
    );
    if args.iter().any(|a| a == "print") {
        println!("mean {:e}", r.mean);
        for p in &r.curve.points {
            println!(
                "{} {:.17e} {} {:?} {}",
                p.m, p.deviation, p.count, p.edf, p.alpha
            );
        }
    }
}
