//! The error-state filter on simulated drives: NEES consistency, bias (and scale) convergence,
//! outage drift inside the predicted 3σ, the RTS smoother's gain, alignment from GNSS track.

use crate::support::{city_drive, mems_errors, simulate, ImuErrors, SimData};
use imulab::fusion::config::FusionConfig;
use imulab::fusion::metrics::{errors, summarise, ErrorSummary};
use imulab::fusion::navigator::{replay, ReplayOptions, ReplayResult};
use nalgebra::Vector3;

const LEVER: [f64; 3] = [0.6, 0.2, -1.1];

fn data(seed: u64, scale: bool) -> SimData {
    let mut e = mems_errors(seed);
    if !scale {
        e.gyro_scale = Vector3::zeros();
        e.accel_scale = Vector3::zeros();
    }
    simulate(
        &city_drive(),
        100.0,
        20,
        &e,
        (0.3, 0.6, 0.05),
        Vector3::from(LEVER),
        seed,
    )
}

fn config(states: usize) -> FusionConfig {
    let mut c = FusionConfig {
        states,
        ..FusionConfig::default()
    };
    c.gnss.lever_arm_m = LEVER;
    // The test data's GNSS errors are white and its biases constant over the drive.
    c.gnss.position_correlation_s = 0.0;
    c.imu.gyro_bias.tau_s = 3600.0;
    c.imu.accel_bias.tau_s = 3600.0;
    c
}

fn run(
    d: &SimData,
    c: &FusionConfig,
    outages: Vec<(f64, f64)>,
    smooth: bool,
) -> (ReplayResult, ErrorSummary) {
    let opts = ReplayOptions {
        initial: Some(imulab::study::nav_state(&d.truth[0])),
        outages: outages.clone(),
        smooth,
        ..Default::default()
    };
    let r = replay(c, d.imu.iter().copied(), d.gnss.iter().copied(), opts);
    let e = errors(&r.filtered, |t| d.truth_at(t));
    let s = summarise(&e, &outages);
    (r, s)
}

/// A run without rejected updates, 97 % of the errors inside 3σ, NEES 2-18, and every final
/// gyro and accelerometer bias within 3σ of the truth; the last output.
fn consistent_with_biases_inside_3_sigma<'a>(
    r: &'a ReplayResult,
    s: &ErrorSummary,
    truth: &ImuErrors,
) -> &'a imulab::fusion::navigator::NavSolution {
    assert_eq!(r.stats.filter.pd_events, 0);
    assert!(s.inside_3sigma > 0.97, "inside 3σ {}", s.inside_3sigma);
    assert!(
        s.nees_mean > 2.0 && s.nees_mean < 18.0,
        "NEES {}",
        s.nees_mean
    );
    let last = r.filtered.last().expect("output");
    for i in 0..3 {
        let eg = last.sensors.gyro_bias[i] - truth.gyro_bias[i];
        let ea = last.sensors.accel_bias[i] - truth.accel_bias[i];
        assert!(
            eg.abs() < 3.0 * last.sigma_sensors[0][i],
            "gyro bias {i}: err {eg}"
        );
        assert!(
            ea.abs() < 3.0 * last.sigma_sensors[1][i],
            "accel bias {i}: err {ea}"
        );
    }
    last
}

#[test]
fn fifteen_states_are_consistent_and_biases_converge() {
    for seed in [1, 2] {
        let d = data(seed, false);
        let truth_errors = mems_errors(seed);
        let c = config(15);
        let (r, s) = run(&d, &c, vec![], false);
        println!("seed {seed}: {s:?}\nstats {:?}", r.stats);
        assert_eq!(r.stats.gnss_used as usize, d.gnss.len());
        assert!(s.horizontal.rms < 0.5, "{:?}", s.horizontal);
        let last = consistent_with_biases_inside_3_sigma(&r, &s, &truth_errors);
        // Observable with turns and gravity: z gyro bias and vertical accel bias.
        assert!(last.sigma_sensors[0].z < 0.5 * c.imu.gyro_bias.sigma[2]);
        assert!(last.sigma_sensors[1].z < 0.2 * c.imu.accel_bias.sigma[2]);
    }
}

#[test]
fn twenty_one_states_estimate_scale_factors_consistently() {
    let seed = 3;
    let d = data(seed, true);
    let truth_errors = mems_errors(seed);
    let c = config(21);
    let (r, s) = run(&d, &c, vec![], false);
    println!("{s:?}");
    assert!(s.inside_3sigma > 0.97, "inside 3σ {}", s.inside_3sigma);
    assert!(s.nees_mean < 18.0, "NEES {}", s.nees_mean);
    let last = r.filtered.last().expect("output");
    let err_sg = last.sensors.gyro_scale.z - truth_errors.gyro_scale.z;
    println!(
        "gyro z scale {} true {} σ {}",
        last.sensors.gyro_scale.z, truth_errors.gyro_scale.z, last.sigma_sensors[2].z
    );
    assert!(err_sg.abs() < 3.0 * last.sigma_sensors[2].z);
    assert!(last.sigma_sensors[2].z < 0.8 * c.imu.gyro_scale.sigma[2]);
    // A 15-state filter on the same data (scale errors unmodelled) is worse in heading.
    let (_, s15) = run(&d, &config(15), vec![], false);
    println!("15 states: {s15:?}");
    assert!(s.attitude_rms_deg[2] <= s15.attitude_rms_deg[2] * 1.05);
}

#[test]
fn outage_drift_stays_inside_predicted_sigma_and_smoother_closes_it() {
    let d = data(4, false);
    let outages = vec![(60.0, 90.0), (150.0, 180.0)];
    let (r, s) = run(&d, &config(15), outages.clone(), true);
    println!("filtered {s:?}");
    // GNSS at 5 Hz: two 30 s outages withhold 300 fixes.
    assert_eq!(r.stats.gnss_withheld_outage, 300);
    for o in &s.outages {
        assert!(
            o.max_horizontal_m > 0.05,
            "an outage without drift is suspicious: {o:?}"
        );
        assert!(o.max_horizontal_m < 30.0, "{o:?}");
    }
    assert!(s.inside_3sigma > 0.97, "inside 3σ {}", s.inside_3sigma);
    let es = errors(&r.smoothed, |t| d.truth_at(t));
    let ss = summarise(&es, &outages);
    println!("smoothed {ss:?}");
    assert!(ss.epochs + 5 >= s.epochs, "{} vs {}", ss.epochs, s.epochs);
    assert_eq!(r.stats.smoother_skipped, 0);
    for (f, m) in s.outages.iter().zip(&ss.outages) {
        assert!(
            m.max_horizontal_m < 0.5 * f.max_horizontal_m,
            "smoothed {m:?} filtered {f:?}"
        );
    }
    assert!(
        ss.inside_3sigma > 0.97,
        "smoothed inside 3σ {}",
        ss.inside_3sigma
    );
}

#[test]
fn aligns_from_levelling_and_gnss_track() {
    let d = data(5, false);
    let c = config(15);
    let r = replay(
        &c,
        d.imu.iter().copied(),
        d.gnss.iter().copied(),
        ReplayOptions::default(),
    );
    let aligned = r.stats.aligned_at_s.expect("aligned");
    // Static for 10 s, then accelerating: 3 m/s is reached a few seconds later.
    assert!(aligned > 10.0 && aligned < 20.0, "aligned at {aligned}");
    let e = errors(&r.filtered, |t| d.truth_at(t));
    let late: Vec<_> = e
        .iter()
        .filter(|x| x.t_s > aligned + 60.0)
        .copied()
        .collect();
    let s = summarise(&late, &[]);
    println!("after alignment: {s:?}");
    assert!(
        s.attitude_rms_deg[2] < 0.5,
        "heading {:?}",
        s.attitude_rms_deg
    );
    assert!(s.horizontal.max < 1.0);
}

fn mean_outage_drift(s: &ErrorSummary) -> f64 {
    s.outages.iter().map(|o| o.max_horizontal_m).sum::<f64>() / s.outages.len().max(1) as f64
}

#[test]
fn non_holonomic_constraint_reduces_outage_drift() {
    let d = data(6, false);
    let outages = vec![(60.0, 90.0), (150.0, 180.0), (215.0, 245.0)];
    let (_, off) = run(&d, &config(15), outages.clone(), false);
    let mut c = config(15);
    c.nhc.enabled = true;
    let (r, on) = run(&d, &c, outages.clone(), false);
    println!("NHC off {:?}\nNHC on {:?}", off.outages, on.outages);
    assert!(r.stats.nhc_updates > 500, "{:?}", r.stats);
    assert!(mean_outage_drift(&on) < 0.7 * mean_outage_drift(&off));
    assert!(on.inside_3sigma > 0.97, "{}", on.inside_3sigma);
}

/// The test car slips 0.2° per m/s² of lateral acceleration in its turns: an NHC that expects
/// no slip turns the slip into heading and velocity errors it believes it knows.
#[test]
fn non_holonomic_constraint_expects_the_side_slip_of_a_turn() {
    let d = data(6, false);
    let outages = vec![(60.0, 90.0), (150.0, 180.0), (215.0, 245.0)];
    let mut c = config(15);
    c.nhc.enabled = true;
    let (_, expected) = run(&d, &c, outages.clone(), false);
    c.nhc.slip_deg_per_mps2 = 0.0;
    c.nhc.slip_sigma_deg_per_mps2 = 0.0;
    let (_, ignored) = run(&d, &c, outages.clone(), false);
    println!(
        "slip expected: NEES {:.2}, inside 3σ {:.3}, drift {:.2} m\nslip ignored: NEES {:.2}, inside 3σ {:.3}, drift {:.2} m",
        expected.nees_mean,
        expected.inside_3sigma,
        mean_outage_drift(&expected),
        ignored.nees_mean,
        ignored.inside_3sigma,
        mean_outage_drift(&ignored)
    );
    assert!(expected.inside_3sigma > 0.97, "{}", expected.inside_3sigma);
    assert!(ignored.nees_mean > 1.5 * expected.nees_mean);
    assert!(mean_outage_drift(&expected) < mean_outage_drift(&ignored));
}

#[test]
fn zero_velocity_updates_hold_the_solution_during_a_stop() {
    let d = data(7, false);
    // The drive stops at 150–170 s; GNSS is out from 140 to 200 s.
    let outages = vec![(140.0, 200.0)];
    let (_, off) = run(&d, &config(15), outages.clone(), false);
    let mut c = config(15);
    c.zupt.enabled = true;
    let (r, on) = run(&d, &c, outages.clone(), false);
    if std::env::var_os("FUSION_DEBUG").is_some() {
        let e = errors(&r.filtered, |t| d.truth_at(t));
        for x in e
            .iter()
            .filter(|x| x.t_s > 130.0 && x.t_s < 205.0)
            .step_by(10)
        {
            println!(
                "{:.1} pos {:?} vel {:?}",
                x.t_s,
                x.pos_ned.as_slice(),
                x.vel_ned.as_slice()
            );
        }
    }
    println!(
        "ZUPT off {:?}\nZUPT on {:?}\n{:?}",
        off.outages, on.outages, r.stats
    );
    // Stops at 0–10, 150–170 and 275–289 s give ZUPTs every 0.5 s.
    assert!(
        r.stats.zupt_updates >= 50 && r.stats.zupt_updates <= 100,
        "{}",
        r.stats.zupt_updates
    );
    assert!(on.outages[0].max_horizontal_m < 0.7 * off.outages[0].max_horizontal_m);
    assert!(on.inside_3sigma > 0.97, "{}", on.inside_3sigma);
}

/// Propagating the covariance once per GNSS interval (one transition from the interval's
/// mean rates, as the study does) instead of at every IMU step keeps the filter's σ and its
/// errors: the largest position σ during a 30 s outage, the NEES and the horizontal RMS agree
/// within a few per cent.
#[test]
fn covariance_at_the_gnss_rate_matches_covariance_at_the_imu_rate() {
    let d = data(4, false);
    let outages = vec![(90.0, 120.0)];
    let mut every_step = config(15);
    every_step.covariance_interval_s = 0.01; // every 100 Hz IMU step
    let mut gnss_rate = config(15);
    gnss_rate.covariance_interval_s = 0.2; // GNSS at 5 Hz
    let (r1, s1) = run(&d, &every_step, outages.clone(), false);
    let (r2, s2) = run(&d, &gnss_rate, outages.clone(), false);
    assert!(r2.stats.filter.covariance_steps * 5 < r1.stats.filter.covariance_steps);
    let peak_sigma = |r: &ReplayResult| {
        r.filtered
            .iter()
            .filter(|s| s.nav.t_s >= 90.0 && s.nav.t_s < 120.0)
            .map(|s| s.cov_nav[(0, 0)].max(s.cov_nav[(1, 1)]).sqrt())
            .fold(0.0, f64::max)
    };
    let (p1, p2) = (peak_sigma(&r1), peak_sigma(&r2));
    println!(
        "every step: σ {p1:.3} m, NEES {:.2}, RMS {:.3}; GNSS rate: σ {p2:.3} m, NEES {:.2}, RMS {:.3}",
        s1.nees_mean, s1.horizontal.rms, s2.nees_mean, s2.horizontal.rms
    );
    assert!(p1 > 0.5, "the outage grows the σ: {p1}");
    assert!((p2 / p1 - 1.0).abs() < 0.03, "σ {p2} vs {p1}");
    assert!((s2.nees_mean / s1.nees_mean - 1.0).abs() < 0.1);
    assert!((s2.horizontal.rms / s1.horizontal.rms - 1.0).abs() < 0.05);
}

/// An output epoch that coincides with a fix carries that fix's update: the first epoch after
/// an outage reports the corrected solution, not the drift the outage left, so the GNSS-on
/// figures (which count that epoch) are the filter's accuracy with GNSS.
#[test]
fn an_output_at_a_fix_epoch_carries_the_fix_update() {
    let d = data(4, false);
    let outages = vec![(60.0, 90.0), (150.0, 180.0)];
    let (r, s) = run(&d, &config(15), outages.clone(), false);
    let e = errors(&r.filtered, |t| d.truth_at(t));
    for &(_, end) in &outages {
        // The fix at the outage end has the time of an IMU sample and of an output epoch.
        assert!(d.gnss.iter().any(|f| (f.t_s - end).abs() < 1e-9));
        let at = e
            .iter()
            .find(|x| (x.t_s - end).abs() < 1e-6)
            .expect("an output epoch at the first fix after the outage");
        let before = e
            .iter()
            .rev()
            .find(|x| x.t_s < end - 1e-6)
            .expect("an output epoch inside the outage");
        let sigma = |t: f64| {
            let sol = r
                .filtered
                .iter()
                .find(|x| (x.nav.t_s - t).abs() < 1e-6)
                .expect("solution");
            (sol.cov_nav[(0, 0)] + sol.cov_nav[(1, 1)]).sqrt()
        };
        println!(
            "outage end {end}: error {:.3} m (σ {:.3}) at the fix, {:.3} m (σ {:.3}) just before",
            at.horizontal_m(),
            sigma(at.t_s),
            before.horizontal_m(),
            sigma(before.t_s)
        );
        assert!(before.horizontal_m() > 0.5, "the outage drifted");
        // Written before the update, the epoch would keep the outage's σ (ratio ≈ 1).
        assert!(
            sigma(at.t_s) < 0.2 * sigma(before.t_s),
            "the epoch at the fix still carries the outage's state"
        );
        assert!(at.horizontal_m() < before.horizontal_m());
        assert!(at.horizontal_m() < 3.0 * sigma(at.t_s));
    }
    // GNSS-on figures count those epochs; with the update in them they stay at the
    // filter's accuracy with GNSS (0.3 m receiver σ here).
    assert!(s.horizontal_gnss.rms < 0.5, "{:?}", s.horizontal_gnss);
}

/// The turn-on bias states change nothing where the turn-on σ is zero: the same trajectory
/// as one state per axis, to rounding (the sensor's bias is the sum of the two states).
#[test]
fn turn_on_states_without_a_turn_on_bias_replay_as_one_state() {
    let d = data(4, false);
    let mut one = config(15);
    // Random constants, so that neither filter's estimate decays.
    one.imu.gyro_bias.tau_s = 0.0;
    one.imu.accel_bias.tau_s = 0.0;
    let two = FusionConfig {
        turn_on_states: true,
        ..one
    };
    assert_eq!(two.filter_states(), 21);
    let (a, _) = run(&d, &one, vec![(300.0, 60.0)], true);
    let (b, _) = run(&d, &two, vec![(300.0, 60.0)], true);
    assert_eq!(a.filtered.len(), b.filtered.len());
    let worst = |x: &[imulab::fusion::navigator::NavSolution],
                 y: &[imulab::fusion::navigator::NavSolution]| {
        x.iter()
            .zip(y)
            .map(|(p, q)| {
                let (n, e, dn) = (
                    (p.nav.lat_rad - q.nav.lat_rad) * 6.4e6,
                    (p.nav.lon_rad - q.nav.lon_rad) * 6.4e6,
                    p.nav.height_m - q.nav.height_m,
                );
                (n * n + e * e + dn * dn).sqrt()
                    + (p.sensors.gyro_bias - q.sensors.gyro_bias).norm() * 1e3
                    + (p.sigma_sensors[0] - q.sigma_sensors[0]).norm() * 1e3
            })
            .fold(0.0, f64::max)
    };
    let (filtered, smoothed) = (
        worst(&a.filtered, &b.filtered),
        worst(&a.smoothed, &b.smoothed),
    );
    println!("largest difference: filtered {filtered:.2e}, smoothed {smoothed:.2e}");
    assert!(
        filtered < 1e-6 && smoothed < 1e-6,
        "{filtered:e} {smoothed:e}"
    );
}

/// With a turn-on bias far above the in-run one, the turn-on states estimate the sum: every
/// bias inside 3σ of the total, the z gyro and vertical accelerometer observed, NEES sane.
#[test]
fn turn_on_states_estimate_the_whole_bias_inside_its_sigma() {
    let seed = 5;
    let d = data(seed, false);
    let truth_errors = mems_errors(seed);
    let mut c = config(15);
    c.turn_on_states = true;
    // The test IMU's biases are constant: a small in-run part, the rest turn-on.
    c.imu.gyro_bias_initial_sigma = Some(c.imu.gyro_bias.sigma);
    c.imu.accel_bias_initial_sigma = Some(c.imu.accel_bias.sigma);
    c.imu.gyro_bias.sigma *= 0.1;
    c.imu.accel_bias.sigma *= 0.1;
    let (r, s) = run(&d, &c, vec![], false);
    println!("{s:?}");
    let last = consistent_with_biases_inside_3_sigma(&r, &s, &truth_errors);
    let total = c.imu.gyro_bias_sigma0(2);
    assert!(last.sigma_sensors[0].z < 0.5 * total);
    assert!(last.sigma_sensors[1].z < 0.2 * c.imu.accel_bias_sigma0(2));
}
