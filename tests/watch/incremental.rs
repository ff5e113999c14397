//! The incremental ADEV equals a full recomputation of the same samples to 1e-12
//! relative, whatever the pieces the samples arrive in.

use imulab::allan::curve::compute_curve_from_rate;
use imulab::allan::{compute_curve, Curve, DeviationKind, Phase, TauGrid};
use imulab::watch::allan::AxisAllan;
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;

/// White noise, a random walk of the bias and a large offset (an accel axis).
fn series(n: usize, seed: u64, offset: f64) -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut walk = 0.0;
    (0..n)
        .map(|_| {
            let g: f64 = StandardNormal.sample(&mut rng);
            let w: f64 = StandardNormal.sample(&mut rng);
            walk += 2e-4 * w;
            offset + 0.01 * g + walk
        })
        .collect()
}

fn full(rate: &[f64], tau0: f64) -> Curve {
    compute_curve_from_rate(rate, tau0, DeviationKind::Adev, &TauGrid::Octave)
        .unwrap()
        .0
}

fn assert_same(incremental: &Curve, full: &Curve, tolerance: f64, what: &str) {
    assert_eq!(
        incremental.points.len(),
        full.points.len(),
        "{what}: number of τ"
    );
    assert!(!full.points.is_empty(), "{what}: empty curve");
    for (p, q) in incremental.points.iter().zip(&full.points) {
        assert_eq!((p.m, p.count), (q.m, q.count), "{what}: m = {}", q.m);
        let rel = (p.deviation - q.deviation).abs() / q.deviation;
        assert!(
            rel <= tolerance,
            "{what}: m = {}: {} vs {} ({rel:e} relative)",
            q.m,
            p.deviation,
            q.deviation
        );
        assert_eq!(p.alpha, q.alpha, "{what}: noise type at m = {}", q.m);
        match (p.edf, q.edf) {
            (Some(a), Some(b)) => assert!((a - b).abs() <= 1e-9 * b, "{what}: edf at m = {}", q.m),
            (a, b) => assert_eq!(a, b, "{what}: edf at m = {}", q.m),
        }
    }
}

#[test]
fn incremental_equals_full_recomputation_at_every_step() {
    let data = series(400_000, 5, 9.80665);
    let tau0 = 1.0 / 150.0;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(6);
    let mut state = AxisAllan::new();
    let mut at = 0;
    let mut checks = 0;
    while at < data.len() {
        // Pieces of any length, as looks at a live file find them.
        let piece = rng.random_range(1..20_000).min(data.len() - at);
        state.extend(&data[at..at + piece]);
        at += piece;
        assert_eq!(state.samples(), at as u64);
        if checks < 12 || at == data.len() {
            let what = format!("after {at} samples");
            assert_same(&state.curve(tau0), &full(&data[..at], tau0), 1e-12, &what);
            checks += 1;
        }
    }
    let mean = data.iter().sum::<f64>() / data.len() as f64;
    assert!((state.mean() - mean).abs() < 1e-12 * mean.abs());
}

#[test]
fn incremental_agrees_with_the_phase_based_curve() {
    // A second, independent full computation: the phase built and differenced.
    let data = series(100_003, 8, 0.0);
    let tau0 = 0.01;
    let mut state = AxisAllan::new();
    for piece in data.chunks(1_234) {
        state.extend(piece);
    }
    let phase = compute_curve(
        &Phase::from_rate(data.clone()),
        tau0,
        DeviationKind::Adev,
        &TauGrid::Octave,
    );
    let inc = state.curve(tau0);
    assert_eq!(inc.points.len(), phase.points.len());
    for (p, q) in inc.points.iter().zip(&phase.points) {
        assert_eq!(p.m, q.m);
        assert!(
            (p.deviation - q.deviation).abs() <= 1e-9 * q.deviation,
            "m = {}: {} vs {}",
            q.m,
            p.deviation,
            q.deviation
        );
    }
}

#[test]
fn short_series_before_the_offset_is_fixed() {
    // Fewer samples than the offset needs: the held samples are computed in full.
    let data = series(3_000, 9, 1.0);
    let mut state = AxisAllan::new();
    state.extend(&data);
    assert_same(&state.curve(0.01), &full(&data, 0.01), 0.0, "3000 samples");
}

#[test]
fn memory_stays_bounded() {
    let mut state = AxisAllan::new();
    let piece = series(1 << 16, 10, 0.0);
    for _ in 0..64 {
        state.extend(&piece);
    }
    // 4 Mi samples (7.8 h at 150 Hz): the state is its levels, not the samples.
    assert_eq!(state.samples(), 1 << 22);
    assert!(
        state.held_bytes() < 64 * 1024,
        "{} bytes",
        state.held_bytes()
    );
}
