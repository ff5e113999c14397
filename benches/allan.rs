//! Allan analyser benchmark: run time per deviation type on 6 h × 150 Hz (3.24 M samples),
//! one and six axes; a full six-axis OADEV report with fit; and run time against error
//! (dense vs octave grid for the fitted terms, f32 vs f64 input and accumulation).
//! Writes the simulated data to `target/allan-bench/data.npy` for
//! `benches/allan_vs_allantools.sh`. Run: `cargo bench --bench allan`.

use imulab::allan::fit::{fit_noise_terms, Term};
use imulab::allan::{compute_curve, DeviationKind, Phase, TauGrid};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::time::Instant;

const RATE_HZ: f64 = 150.0;
const SAMPLES: usize = 6 * 3600 * 150;
const N_TRUE: f64 = 2e-3;
const K_TRUE: f64 = 5e-5;

fn simulate(seed: u64) -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let tau0 = 1.0 / RATE_HZ;
    let mut walk = 0.0;
    (0..SAMPLES)
        .map(|_| {
            let w: f64 = StandardNormal.sample(&mut rng);
            let s: f64 = StandardNormal.sample(&mut rng);
            walk += K_TRUE * tau0.sqrt() * s;
            N_TRUE / tau0.sqrt() * w + walk
        })
        .collect()
}

fn best_of<T>(runs: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..runs {
        let t = Instant::now();
        let r = f();
        best = best.min(t.elapsed().as_secs_f64());
        out = Some(r);
    }
    (best, out.expect("runs > 0"))
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

fn main() {
    let axes: Vec<Vec<f64>> = (0..6).map(|a| simulate(100 + a)).collect();
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/allan-bench");
    std::fs::create_dir_all(&dir).expect("bench dir");
    write_npy(&dir.join("data.npy"), &axes);
    let threads = rayon::current_num_threads();
    println!(
        "# Allan benchmark: {SAMPLES} samples per axis at {RATE_HZ} Hz, {threads} rayon threads\n"
    );

    // 1. Per deviation type, one axis and six axes (phase building included).
    println!("| deviation | grid | taus | 1 axis [s] | 6 axes [s] |");
    println!("|---|---|---|---|---|");
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
    for (kind, grid, label) in &cases {
        let (one, curve) = best_of(3, || {
            compute_curve(
                &Phase::from_rate(axes[0].clone()),
                1.0 / RATE_HZ,
                *kind,
                grid,
            )
        });
        let (six, _) = best_of(2, || {
            axes.iter()
                .map(|a| {
                    compute_curve(&Phase::from_rate(a.clone()), 1.0 / RATE_HZ, *kind, grid)
                        .points
                        .len()
                })
                .sum::<usize>()
        });
        println!(
            "| {} | {label} | {} | {one:.3} | {six:.3} |",
            kind.name(),
            curve.points.len()
        );
    }

    // 2. Full six-axis OADEV report with fit (phase, curve with EDF/CI/noise id, IRLS fit).
    let (report, fits) = best_of(3, || {
        axes.iter()
            .map(|a| {
                let curve = compute_curve(
                    &Phase::from_rate(a.clone()),
                    1.0 / RATE_HZ,
                    DeviationKind::Oadev,
                    &TauGrid::Octave,
                );
                fit_noise_terms(&curve).ok()
            })
            .collect::<Vec<_>>()
    });
    println!(
        "\nSix-axis OADEV octave report with fit: {report:.3} s ({} fits)\n",
        fits.iter().flatten().count()
    );

    // 3. Run time against error: grid density and the fitted terms (mean |error| over 6 axes).
    println!(
        "| grid | taus | time 6 axes [s] | mean abs error N | mean abs error K | K identified |"
    );
    println!("|---|---|---|---|---|---|");
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
    // Naive f32 accumulation: phase as a plain f32 running sum without mean removal.
    let (tn, naive) = best_of(3, || naive_f32_oadev(&with_g, &reference));
    println!(
        "| naive f32 phase (no mean removal, plain sum) | {tn:.3} | {:.2e} |",
        naive
    );

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
}

fn max_rel(a: &imulab::allan::Curve, b: &imulab::allan::Curve) -> f64 {
    a.points
        .iter()
        .zip(&b.points)
        .map(|(p, q)| (p.deviation - q.deviation).abs() / p.deviation)
        .fold(0.0, f64::max)
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
