//! Simulated data with known noise terms: the fit must recover each term within the
//! interval it reports, call the absent terms "not identified", and the slope-line
//! readings must land near the truth.

use imulab::allan::fit::{fit_noise_terms, slope_readings, Term};
use imulab::allan::{compute_curve, DeviationKind, Phase, TauGrid};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;

/// Rate samples at `rate_hz` with white rate noise of density `n` (unit·√s), a rate random
/// walk `k` (unit/√s) and white angle noise `q` (unit·s, quantization-like).
fn simulate(samples: usize, rate_hz: f64, n: f64, k: f64, q: f64, seed: u64) -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let tau0 = 1.0 / rate_hz;
    let mut walk = 0.0;
    let mut previous_angle_noise = 0.0;
    (0..samples)
        .map(|_| {
            let white: f64 = StandardNormal.sample(&mut rng);
            let step: f64 = StandardNormal.sample(&mut rng);
            let angle: f64 = StandardNormal.sample(&mut rng);
            walk += k * tau0.sqrt() * step;
            let angle_noise = q * angle;
            let quantization_rate = (angle_noise - previous_angle_noise) / tau0;
            previous_angle_noise = angle_noise;
            n / tau0.sqrt() * white + walk + quantization_rate
        })
        .collect()
}

fn check_recovery(kind: DeviationKind, grid: TauGrid, seed: u64, with_q: bool) {
    // Crossover of N and K at τ = √3·N/K ≈ 7 s: two decades of each slope in 6000 s.
    let (n, k, q) = (2e-3, 5e-4, if with_q { 3e-4 } else { 0.0 });
    let y = simulate(600_000, 100.0, n, k, q, seed);
    let curve = compute_curve(&Phase::from_rate(y), 0.01, kind, &grid);
    let fit = fit_noise_terms(&curve).expect("fit");
    let mut truths = vec![(Term::RandomWalk, n), (Term::RateRandomWalk, k)];
    if with_q {
        truths.push((Term::Quantization, q));
    }
    for (term, truth) in truths {
        let t = fit.get(term).unwrap();
        let value = t
            .value
            .unwrap_or_else(|| panic!("seed {seed} {kind:?}: {term:?} not identified: {t:?}"));
        assert!(
            t.low <= truth && truth <= t.high,
            "seed {seed} {kind:?}: {term:?} = {value:.4e} [{:.4e}, {:.4e}] misses truth {truth:.4e}",
            t.low,
            t.high
        );
        // And the interval is informative, not a blanket.
        assert!(
            t.high / t.low < 3.0,
            "seed {seed}: {term:?} interval too wide: {t:?}"
        );
    }
    for absent in [Term::BiasInstability, Term::RateRamp] {
        let t = fit.get(absent).unwrap();
        assert!(
            t.value.is_none(),
            "seed {seed} {kind:?}: {absent:?} should be unidentified: {t:?}"
        );
    }
    if !with_q {
        assert!(fit.get(Term::Quantization).unwrap().value.is_none());
    }
}

#[test]
fn white_noise_and_random_walk_recovered_oadev_octave() {
    for seed in 1..=6 {
        check_recovery(DeviationKind::Oadev, TauGrid::Octave, seed, false);
    }
}

#[test]
fn three_terms_recovered_dense_grid_and_totdev() {
    check_recovery(DeviationKind::Oadev, TauGrid::Dense(8), 11, true);
    check_recovery(DeviationKind::Totdev, TauGrid::Octave, 12, false);
}

#[test]
fn slope_line_reading_of_white_noise_is_close() {
    let n = 1e-3;
    let y = simulate(200_000, 200.0, n, 0.0, 0.0, 5);
    let curve = compute_curve(
        &Phase::from_rate(y),
        0.005,
        DeviationKind::Oadev,
        &TauGrid::Octave,
    );
    let r = slope_readings(&curve);
    let read = r.random_walk.expect("a -1/2 slope exists");
    assert!((read / n - 1.0).abs() < 0.03, "{read}");
}
