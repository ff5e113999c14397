//! Simulated data with known noise terms: the fit must recover each term within the
//! interval it reports, call the absent terms "not identified", and the slope-line
//! readings must land near the truth. The simulator's presets (bench-cheap, bench-dear,
//! tactical) must come back as their datasheet numbers: B as IEEE Std 952's bias
//! instability, whose Allan floor is 0.664·B.

use imulab::allan::fit::{fit_noise_terms, slope_readings, NoiseFit, Term};
use imulab::allan::{compute_curve, DeviationKind, Phase, TauGrid};
use imulab::sim::imu_model::{Channels, ImuSimulator, ImuSpec};
use imulab::sim::presets::imu_preset;
use nalgebra::Vector3;
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

const DEG: f64 = std::f64::consts::PI / 180.0;
const MG: f64 = 9.806_65e-3;

/// One triad of `spec` at rest for `hours` at `rate_hz`: the rate samples of x, y and z.
fn simulate_triad(
    spec: &ImuSpec,
    gyro: bool,
    rate_hz: f64,
    hours: f64,
    seed: u64,
) -> [Vec<f64>; 3] {
    let channels = if gyro {
        Channels::GYRO
    } else {
        Channels::ACCEL
    };
    let mut sim = ImuSimulator::new(spec, "dut", seed, rate_hz, channels).expect("valid spec");
    let n = (hours * 3600.0 * rate_hz).round() as usize;
    let zero = Vector3::zeros();
    let mut out: [Vec<f64>; 3] = Default::default();
    for _ in 0..n {
        let r = sim
            .step(&zero, &zero, spec.reference_temp_c, 0, 0)
            .record
            .expect("no drops configured");
        let y = if gyro { r.gyro } else { r.accel };
        for (axis, v) in out.iter_mut().zip(y) {
            axis.push(v);
        }
    }
    out
}

/// The OADEV octave fit of one axis (what `imulab report` does).
fn fit_axis(y: Vec<f64>, rate_hz: f64) -> NoiseFit {
    let curve = compute_curve(
        &Phase::from_rate(y),
        1.0 / rate_hz,
        DeviationKind::Oadev,
        &TauGrid::Octave,
    );
    fit_noise_terms(&curve).expect("fit")
}

/// `term` is identified, its 95 % interval holds `truth` and spans at most `max_width`
/// (high/low); returns the width.
fn assert_recovered(fit: &NoiseFit, term: Term, truth: f64, max_width: f64, label: &str) -> f64 {
    let t = fit.get(term).expect("every term is reported");
    let value = t
        .value
        .unwrap_or_else(|| panic!("{label}: {term:?} not identified: {t:?}"));
    let width = t.high / t.low;
    println!(
        "{label} {term:?}: {:.4} [{:.4}, {:.4}] truth 1, interval high/low {width:.2}",
        value / truth,
        t.low / truth,
        t.high / truth
    );
    assert!(
        t.low <= truth && truth <= t.high,
        "{label}: {term:?} = {value:.4e} [{:.4e}, {:.4e}] misses the truth {truth:.4e}",
        t.low,
        t.high
    );
    assert!(
        width < max_width,
        "{label}: {term:?} interval too wide: {t:?}"
    );
    width
}

/// Per preset and sensor: run length (h), rate (Hz), widest B interval allowed (high/low).
/// The rate only sets the shortest τ (the white density, not the per-sample σ, is the
/// spec), so 10 Hz keeps the test fast. (Much lower rates add white noise: the fastest
/// Gauss-Markov process of the flicker model, T = 0.07 s, is then point-sampled; at 2 Hz
/// N reads about 1 % high, outside its interval.) The lengths reach well past the τ where
/// the floor 0.664·B crosses the white noise N²/τ (bench gyros ~40 s, tactical gyro
/// ~740 s); the widths allowed are about 1.25× the widest seen over 20 seeds.
const PRESET_RUNS: [(&str, bool, f64, f64, f64); 6] = [
    ("bench-cheap", true, 6.0, 10.0, 1.5),
    ("bench-cheap", false, 6.0, 10.0, 1.5),
    ("bench-dear", true, 6.0, 10.0, 1.5),
    ("bench-dear", false, 6.0, 10.0, 1.5),
    ("tactical", true, 24.0, 10.0, 2.2),
    ("tactical", false, 6.0, 10.0, 1.5),
];

#[test]
fn presets_bias_instability_and_white_noise_come_back_within_the_fit_intervals() {
    for (preset, gyro, hours, rate, max_b_width) in PRESET_RUNS {
        let spec = imu_preset(preset).expect("preset");
        let (b_si, n_si) = if gyro {
            let arw = spec.gyro.arw_deg_rth.expect("preset gives ARW");
            (
                spec.gyro.bias_instability_dph.map(|b| b * DEG / 3600.0),
                arw.map(|a| a * DEG / 60.0),
            )
        } else {
            let vrw = spec.accel.vrw_mg_rth.expect("preset gives VRW");
            (
                spec.accel.bias_instability_mg.map(|b| b * MG),
                vrw.map(|v| v * MG / 60.0),
            )
        };
        let axes = simulate_triad(&spec, gyro, rate, hours, 1);
        for (i, y) in axes.into_iter().enumerate() {
            let label = format!(
                "{preset} {} {} ({hours} h)",
                if gyro { "gyro" } else { "accel" },
                ["x", "y", "z"][i]
            );
            let fit = fit_axis(y, rate);
            assert_recovered(&fit, Term::BiasInstability, b_si[i], max_b_width, &label);
            assert_recovered(&fit, Term::RandomWalk, n_si[i], 1.1, &label);
            // No rate random walk, quantization or ramp is simulated: none may be claimed.
            for absent in [Term::RateRandomWalk, Term::Quantization, Term::RateRamp] {
                let t = fit.get(absent).expect("reported");
                assert!(t.value.is_none(), "{label}: {absent:?} claimed: {t:?}");
            }
        }
    }
}

#[test]
fn bias_instability_and_rate_random_walk_are_told_apart() {
    // bench-cheap gyro plus a rate random walk of 20 °/h/√h, which overtakes the floor
    // (0.664·B ≈ 3.5 °/h) at τ = 3·floor²/K² ≈ 330 s: the fit must give each term its own
    // share instead of lifting B. K is identified only when it dominates the curve's tail
    // over about two decades (in 6 h it is identified in about half the runs, and then
    // "not identified" with an upper bound above the truth), hence 24 h.
    let mut spec = imu_preset("bench-cheap").expect("preset");
    let rrw = [20.0; 3];
    spec.gyro.rrw_dph_rth = rrw;
    let (hours, rate) = (24.0, 10.0);
    let axes = simulate_triad(&spec, true, rate, hours, 1);
    for (i, y) in axes.into_iter().enumerate() {
        let label = format!("bench-cheap gyro {} + RRW", ["x", "y", "z"][i]);
        let fit = fit_axis(y, rate);
        let b = spec.gyro.bias_instability_dph[i] * DEG / 3600.0;
        let n = spec.gyro.arw_deg_rth.expect("ARW")[i] * DEG / 60.0;
        assert_recovered(&fit, Term::BiasInstability, b, 1.6, &label);
        assert_recovered(&fit, Term::RandomWalk, n, 1.1, &label);
        assert_recovered(
            &fit,
            Term::RateRandomWalk,
            rrw[i] * DEG / 3600.0 / 60.0,
            3.0,
            &label,
        );
    }
}
