//! Statistical validation of the IMU error model: each noise term alone and all together,
//! recovered by an independent overlapping Allan deviation (tests/sim_support) within
//! tolerances of four standard errors derived from the equivalent degrees of freedom of the
//! data length used.

use crate::support::{edf, fit_terms, log_factors, oadev, tolerance, Noise};
use imulab::sim::imu_model::{Channels, ImuSimulator, ImuSpec};
use nalgebra::Vector3;

const DEG: f64 = std::f64::consts::PI / 180.0;
const G0: f64 = 9.806_65;
/// Standard errors allowed.
const K: f64 = 4.0;
/// Allowed ripple of the Gauss-Markov approximation of the flat floor (2.5 %).
const RIPPLE: f64 = 0.025;
/// The Allan floor of a bias instability B is √(2 ln 2 / π)·B (IEEE Std 952), written out
/// here rather than taken from the library so a wrong constant there is caught.
fn floor_of(b: f64) -> f64 {
    (2.0 * std::f64::consts::LN_2 / std::f64::consts::PI).sqrt() * b
}

/// Runs one IMU at rest with zero true inputs; returns gyro and accel per axis.
fn simulate(spec: &ImuSpec, rate_hz: f64, n: usize, seed: u64) -> ([Vec<f64>; 3], [Vec<f64>; 3]) {
    let both = Channels::ALL;
    let mut sim = ImuSimulator::new(spec, "dut", seed, rate_hz, both).expect("valid spec");
    let zero = Vector3::zeros();
    let mut gyro: [Vec<f64>; 3] = Default::default();
    let mut accel: [Vec<f64>; 3] = Default::default();
    for _ in 0..n {
        let e = sim.step(&zero, &zero, spec.reference_temp_c, 0, 0);
        let r = e.record.expect("no drops configured");
        for i in 0..3 {
            gyro[i].push(r.gyro[i]);
            accel[i].push(r.accel[i]);
        }
    }
    (gyro, accel)
}

fn check(label: &str, got: f64, want: f64, tol: f64) {
    let rel = got / want - 1.0;
    assert!(
        rel.abs() <= tol,
        "{label}: got {got:.4e}, want {want:.4e} ({:+.2} % > ±{:.2} %)",
        rel * 100.0,
        tol * 100.0
    );
}

#[test]
fn white_noise_alone_gives_arw_and_vrw() {
    let mut spec = ImuSpec::default();
    let arw = [0.36, 0.31, 0.30];
    let vrw = [6.6, 7.9, 8.5];
    spec.gyro.arw_deg_rth = Some(arw);
    spec.accel.vrw_mg_rth = Some(vrw);
    let (rate, n) = (100.0, 100_000);
    let (gyro, accel) = simulate(&spec, rate, n, 1);
    for m in [1, 10, 100, 1000] {
        let tau = m as f64 / rate;
        let tol = tolerance(edf(Noise::White, n, m), K);
        for i in 0..3 {
            // ARW °/√h → rad/√s: × DEG / 60; ADEV = N / √τ.
            let want_g = arw[i] * DEG / 60.0 / tau.sqrt();
            check(
                &format!("gyro {i} τ={tau}"),
                oadev(&gyro[i], 1.0 / rate, m),
                want_g,
                tol,
            );
            let want_a = vrw[i] * G0 * 1e-3 / 60.0 / tau.sqrt();
            check(
                &format!("accel {i} τ={tau}"),
                oadev(&accel[i], 1.0 / rate, m),
                want_a,
                tol,
            );
        }
    }
}

#[test]
fn bias_instability_alone_gives_a_flat_floor() {
    let mut spec = ImuSpec::default();
    let bi_g = [5.3, 4.8, 4.0];
    let bi_a = [0.029, 0.074, 0.043];
    spec.gyro.bias_instability_dph = bi_g;
    spec.accel.bias_instability_mg = bi_a;
    let (rate, n) = (10.0, 200_000);
    let (gyro, accel) = simulate(&spec, rate, n, 2);
    for tau in [1.0, 3.0, 10.0, 30.0, 100.0, 300.0] {
        let m = (tau * rate) as usize;
        let tol = tolerance(edf(Noise::Flicker, n, m), K) + RIPPLE;
        for i in 0..3 {
            let want_g = floor_of(bi_g[i] * DEG / 3600.0);
            check(
                &format!("gyro {i} τ={tau}"),
                oadev(&gyro[i], 0.1, m),
                want_g,
                tol,
            );
            let want_a = floor_of(bi_a[i] * G0 * 1e-3);
            check(
                &format!("accel {i} τ={tau}"),
                oadev(&accel[i], 0.1, m),
                want_a,
                tol,
            );
        }
    }
}

#[test]
fn rate_random_walk_alone_grows_as_sqrt_tau() {
    let mut spec = ImuSpec::default();
    let rrw_g = [20.0, 10.0, 5.0];
    let rrw_a = [0.5, 0.2, 0.1];
    spec.gyro.rrw_dph_rth = rrw_g;
    spec.accel.rrw_mg_rth = rrw_a;
    // 2 Hz so the 1 s random-walk update is interpolated between knots.
    let (rate, n) = (2.0, 200_000);
    let (gyro, accel) = simulate(&spec, rate, n, 3);
    for tau in [20.0, 100.0, 300.0] {
        let m = (tau * rate) as usize;
        let tol = tolerance(edf(Noise::RandomWalk, n, m), K);
        for i in 0..3 {
            // K in unit/√h → unit/√s: / 60; ADEV = K √(τ/3).
            let want_g = rrw_g[i] * DEG / 3600.0 / 60.0 * (tau / 3.0).sqrt();
            check(
                &format!("gyro {i} τ={tau}"),
                oadev(&gyro[i], 0.5, m),
                want_g,
                tol,
            );
            let want_a = rrw_a[i] * G0 * 1e-3 / 60.0 * (tau / 3.0).sqrt();
            check(
                &format!("accel {i} τ={tau}"),
                oadev(&accel[i], 0.5, m),
                want_a,
                tol,
            );
        }
    }
}

#[test]
fn rate_ramp_alone_is_exact() {
    let mut spec = ImuSpec::default();
    spec.gyro.rate_ramp_dph_per_h = [10.0, -5.0, 0.0];
    spec.accel.rate_ramp_mg_per_h = [0.0, 0.3, 1.0];
    spec.gyro.bias_dph = [100.0; 3];
    let (rate, n) = (10.0, 20_000);
    let (gyro, accel) = simulate(&spec, rate, n, 4);
    for tau in [1.0, 10.0, 100.0] {
        let m = (tau * rate) as usize;
        let g = [10.0, -5.0, 0.0].map(|r: f64| r.abs() * DEG / 3600.0 / 3600.0 * tau / 2f64.sqrt());
        let a = [0.0, 0.3, 1.0].map(|r: f64| r * G0 * 1e-3 / 3600.0 * tau / 2f64.sqrt());
        for i in 0..3 {
            for (name, y, want) in [("gyro", &gyro[i], g[i]), ("accel", &accel[i], a[i])] {
                let got = oadev(y, 0.1, m);
                if want == 0.0 {
                    assert!(got < 1e-15, "{name} {i}: constant output has ADEV {got}");
                } else {
                    check(&format!("{name} {i} τ={tau}"), got, want, 1e-6);
                }
            }
        }
    }
}

#[test]
fn quantisation_rounds_to_the_lsb_and_adds_q2_over_12() {
    let mut spec = ImuSpec::default();
    let lsb = 0.01; // °/s
    let rate: f64 = 100.0;
    // White noise of one LSB per sample: density · √rate = lsb.
    spec.gyro.noise_density_dps_rthz = Some([lsb / rate.sqrt(); 3]);
    spec.gyro.lsb_dps = Some(lsb);
    let n = 100_000;
    let (gyro, _) = simulate(&spec, rate, n, 5);
    let q = lsb * DEG;
    for (i, axis) in gyro.iter().enumerate() {
        assert!(axis
            .iter()
            .all(|y| ((y / q) - (y / q).round()).abs() < 1e-9));
        let mean = axis.iter().sum::<f64>() / n as f64;
        let var = axis.iter().map(|y| (y - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        // Rounding adds q²/12 to σ² = q²; the variance estimate has relative error √(2/n).
        let want = q * q * (1.0 + 1.0 / 12.0);
        check(
            &format!("axis {i} variance"),
            var,
            want,
            K * (2.0 / n as f64).sqrt(),
        );
    }
}

#[test]
fn all_terms_together_add_and_fit_back() {
    let mut spec = ImuSpec::default();
    let (arw, bi, rrw, ramp) = (0.36, 5.3, 20.0, 2.0); // gyro X: °/√h, °/h, °/h/√h, °/h/h
    let (vrw, bi_a, rrw_a) = (6.6, 0.029, 0.2); // accel X: mg/√h, mg, mg/√h
    spec.gyro.arw_deg_rth = Some([arw; 3]);
    spec.gyro.bias_instability_dph = [bi; 3];
    spec.gyro.rrw_dph_rth = [rrw; 3];
    spec.gyro.rate_ramp_dph_per_h = [ramp; 3];
    spec.gyro.bias_dph = [50.0; 3];
    spec.accel.vrw_mg_rth = Some([vrw; 3]);
    spec.accel.bias_instability_mg = [bi_a; 3];
    spec.accel.rrw_mg_rth = [rrw_a; 3];
    let (rate, n) = (20.0, 400_000);
    let dt = 1.0 / rate;
    let (gyro, accel) = simulate(&spec, rate, n, 6);

    let dph = DEG / 3600.0;
    // The support fit's B is the flat floor (AVAR = … + b² + …), so compare with 0.664·B.
    let gyro_terms = [
        arw * DEG / 60.0,
        floor_of(bi * dph),
        rrw * dph / 60.0,
        ramp * dph / 3600.0,
    ];
    let mg = G0 * 1e-3;
    let accel_terms = [vrw * mg / 60.0, floor_of(bi_a * mg), rrw_a * mg / 60.0, 0.0];
    for (name, y, t) in [
        ("gyro", &gyro[0], gyro_terms),
        ("accel", &accel[0], accel_terms),
    ] {
        let mut points = Vec::new();
        for m in log_factors(n, 4.0, 20) {
            let tau = m as f64 * dt;
            let parts = [t[0] * t[0] / tau, t[1] * t[1], t[2] * t[2] * tau / 3.0];
            let ramp_part = t[3] * t[3] * tau * tau / 2.0;
            let total = parts.iter().sum::<f64>() + ramp_part;
            // The least certain noise type that contributes at least 10 % sets the tolerance.
            let kinds = [Noise::White, Noise::Flicker, Noise::RandomWalk];
            let worst_edf = parts
                .iter()
                .zip(kinds)
                .filter(|(p, _)| **p >= 0.1 * total)
                .map(|(_, k)| edf(k, n, m))
                .fold(f64::INFINITY, f64::min);
            let got = oadev(y, dt, m);
            check(
                &format!("{name} τ={tau}"),
                got,
                total.sqrt(),
                tolerance(worst_edf, K) + RIPPLE,
            );
            points.push((tau, got));
        }
        let (fn_, fb, fk, _) = fit_terms(&points);
        println!(
            "{name}: fitted N {fn_:.4e} (set {:.4e}), B {fb:.4e} (set {:.4e}), K {fk:.4e} (set {:.4e})",
            t[0], t[1], t[2]
        );
        // The fit is dominated by short τ for N (thousands of degrees of freedom) and by
        // the floor region for B; K rests on the few longest clusters.
        check(&format!("{name} fitted N"), fn_, t[0], 0.05);
        check(&format!("{name} fitted B"), fb, t[1], 0.2);
        check(&format!("{name} fitted K"), fk, t[2], 0.5);
    }
}

#[test]
fn turn_on_bias_has_its_spread_across_runs() {
    let mut spec = ImuSpec::default();
    spec.gyro.bias_dph = [10.0, 0.0, 0.0];
    spec.gyro.turn_on_bias_sigma_dph = [30.0, 0.0, 0.0];
    let runs = 500;
    let first: Vec<f64> = (0..runs)
        .map(|seed| {
            let ch = Channels::GYRO;
            let mut sim = ImuSimulator::new(&spec, "dut", seed, 100.0, ch).unwrap();
            let z = Vector3::zeros();
            sim.step(&z, &z, 25.0, 0, 0).truth.gyro_bias[0] / (DEG / 3600.0)
        })
        .collect();
    let mean = first.iter().sum::<f64>() / runs as f64;
    let sd = (first.iter().map(|b| (b - mean).powi(2)).sum::<f64>() / (runs - 1) as f64).sqrt();
    assert!(
        (mean - 10.0).abs() < K * 30.0 / (runs as f64).sqrt(),
        "mean {mean}"
    );
    check("turn-on sigma", sd, 30.0, tolerance((runs - 1) as f64, K));
}
