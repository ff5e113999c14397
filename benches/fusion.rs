//! Run time against error of the GNSS/INS replay (`cargo bench --bench fusion`): one
//! simulated MEMS drive, GNSS withheld for 60 s every 300 s, and the filter's options
//! varied one at a time; then the speed of a 1 h, 200 Hz IMU + 10 Hz GNSS replay (15 and 21
//! states); then the ANEES of each IMU preset over 50 seeds (`-- nees` runs only that;
//! `-- nees GRADE… --runs=N` some presets with N seeds; `white` runs the filter without the
//! receiver-error states, its fixes inflated by a correlation time instead;
//! `--one-bias-state` without the turn-on bias states; `--nhc-sigma=S` another NHC σ;
//! `--nhc-slip=K` another side-slip gradient, `--nhc-slip-sigma=S` another σ of it).
//! `-- drift` runs only the first table, `-- speed` only the speed.
//! Then imulab (NHC off and on) against KF-GINS on the same exported KF-GINS files (skipped
//! when the KF-GINS binary is absent; `-- kf-gins` runs only that part).
//! Prints markdown tables (copied into docs/bench/fusion.md). Run times are the thread's CPU
//! time (CLOCK_THREAD_CPUTIME_ID), so a busy shared machine does not inflate them.
//! `-- study` runs the release `imulab study` twice (the open-sky requirement study and the
//! 100-run study) with `--json` and times it. `speed`, `nees`, `kf-gins` and `study` write
//! their BENCHMARKS.md rows to `benches/results/fusion-<mode>.json`.

#[path = "support/results.rs"]
mod results;

use imulab::fusion::config::{Axes, FusionConfig};
use imulab::fusion::mechanisation::{ImuInput, IntegrationOrder, NavState};
use imulab::fusion::metrics::{errors, summarise};
use imulab::fusion::navigator::{replay, ReplayOptions};
use imulab::sim::motion::{MotionSpec, Segment};
use imulab_test_support::fusion_data as fusion_support;
use imulab_test_support::fusion_data::{mems_errors, simulate, SimData};
use nalgebra::Vector3;
use serde_json::json;
use std::time::Instant;

/// CPU time consumed by this thread, s.
fn thread_cpu_s() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime only writes the timespec we pass; CLOCK_THREAD_CPUTIME_ID is
    // always available on Linux.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    if rc != 0 {
        return f64::NAN;
    }
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

const LEVER: [f64; 3] = [0.6, 0.2, -1.1];

/// A drive of about `minutes` built from a repeated urban block.
fn drive(minutes: f64) -> MotionSpec {
    let block = [
        Segment::Accelerate {
            dv_mps: 15.0,
            duration_s: 10.0,
        },
        Segment::Cruise { duration_s: 40.0 },
        Segment::Turn {
            angle_deg: 90.0,
            duration_s: 8.0,
        },
        Segment::Cruise { duration_s: 30.0 },
        Segment::Turn {
            angle_deg: -90.0,
            duration_s: 10.0,
        },
        Segment::Climb {
            dh_m: 5.0,
            duration_s: 20.0,
        },
        Segment::Cruise { duration_s: 30.0 },
        Segment::Turn {
            angle_deg: 180.0,
            duration_s: 15.0,
        },
        Segment::Climb {
            dh_m: -5.0,
            duration_s: 20.0,
        },
        Segment::Cruise { duration_s: 20.0 },
        Segment::Turn {
            angle_deg: -60.0,
            duration_s: 6.0,
        },
        Segment::Cruise { duration_s: 25.0 },
        Segment::Stop { duration_s: 10.0 },
        Segment::Cruise { duration_s: 6.0 },
    ];
    let block_s = 250.0;
    let mut segments = vec![Segment::Cruise { duration_s: 10.0 }];
    for _ in 0..((minutes * 60.0 / block_s).ceil() as usize) {
        segments.extend(block.iter().cloned());
    }
    MotionSpec {
        // A car's body: side-slip in the turns and road heave, as docs/simulator.md says.
        vehicle: imulab::sim::motion::VehicleDynamics {
            slip_deg_per_mps2: 0.2,
            heave_mps: 0.03,
        },
        lat_deg: 47.4,
        lon_deg: 8.5,
        height_m: 420.0,
        heading_deg: 15.0,
        speed_mps: 0.0,
        segments,
    }
}

/// Sums `factor` consecutive increments (the IMU at a lower rate).
fn decimate(imu: &[ImuInput], factor: usize) -> Vec<ImuInput> {
    imu.chunks_exact(factor)
        .map(|c| {
            let mut dtheta = Vector3::zeros();
            let mut dvel = Vector3::zeros();
            let mut dt = 0.0;
            let mut t = 0.0;
            for s in c {
                if let ImuInput::Increments {
                    t_s,
                    dt_s,
                    dtheta: a,
                    dvel: v,
                } = *s
                {
                    dtheta += a;
                    dvel += v;
                    dt += dt_s;
                    t = t_s;
                }
            }
            ImuInput::Increments {
                t_s: t,
                dt_s: dt,
                dtheta,
                dvel,
            }
        })
        .collect()
}

struct Row {
    name: &'static str,
    seconds_per_hour: f64,
    outage_mean_max_m: f64,
    outage_worst_m: f64,
    horizontal_rms_m: f64,
}

fn run(
    name: &'static str,
    d: &SimData,
    imu: &[ImuInput],
    c: &FusionConfig,
    smooth: bool,
    outages: &[(f64, f64)],
) -> Row {
    let opts = ReplayOptions {
        initial: Some(imulab::study::nav_state(&d.truth[0])),
        outages: outages.to_vec(),
        smooth,
        ..Default::default()
    };
    let start = thread_cpu_s();
    let r = replay(c, imu.iter().copied(), d.gnss.iter().copied(), opts);
    let elapsed = thread_cpu_s() - start;
    let sol = if smooth { &r.smoothed } else { &r.filtered };
    let s = summarise(&errors(sol, |t| d.truth_at(t)), outages);
    let hours = d.truth.last().map_or(1.0, |t| t.t_s) / 3600.0;
    let n = s.outages.len().max(1) as f64;
    Row {
        name,
        seconds_per_hour: elapsed / hours,
        outage_mean_max_m: s.outages.iter().map(|o| o.max_horizontal_m).sum::<f64>() / n,
        outage_worst_m: s
            .outages
            .iter()
            .map(|o| o.max_horizontal_m)
            .fold(0.0, f64::max),
        horizontal_rms_m: s.horizontal.rms,
    }
}

/// The MEMS errors of the bench drives (constant biases, no scale factors).
fn bench_errors() -> fusion_support::ImuErrors {
    let mut e = mems_errors(11);
    e.gyro_scale = Vector3::zeros();
    e.accel_scale = Vector3::zeros();
    e
}

/// The filter of the bench drives: their GNSS errors are white and their biases constant,
/// and the filter is told so.
fn bench_config() -> FusionConfig {
    let mut base = FusionConfig::default();
    base.gnss.lever_arm_m = LEVER;
    base.gnss.position_correlation_s = 0.0;
    base.imu.gyro_bias.tau_s = 3600.0;
    base.imu.accel_bias.tau_s = 3600.0;
    base
}

fn main() {
    // `cargo bench --bench fusion -- kf-gins` runs only the KF-GINS comparison.
    if std::env::args().any(|a| a == "kf-gins") {
        kf_gins_anchor();
        return;
    }
    // `-- speed` runs only the replay speed.
    if std::env::args().any(|a| a == "speed") {
        speed_table(&bench_config(), &bench_errors());
        return;
    }
    // `-- study` runs only the two `imulab study` runs.
    if std::env::args().any(|a| a == "study") {
        study_runs();
        return;
    }
    // `-- nees` runs only the Monte Carlo consistency table.
    if std::env::args().any(|a| a == "nees") {
        nees_table();
        return;
    }
    // `-- drift` runs only the run-time-against-error table.
    let drift_only = std::env::args().any(|a| a == "drift");
    let e = bench_errors();
    let t0 = Instant::now();
    let d = simulate(
        &drive(30.0),
        200.0,
        20,
        &e,
        (0.3, 0.6, 0.05),
        Vector3::from(LEVER),
        11,
    );
    let end = d.truth.last().map_or(0.0, |t| t.t_s);
    eprintln!(
        "simulated {end:.0} s in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    let outages: Vec<(f64, f64)> = (0..)
        .map(|k| 120.0 + 300.0 * k as f64)
        .take_while(|&a| a + 60.0 < end)
        .map(|a| (a, a + 60.0))
        .collect();
    let base = bench_config();
    let first = {
        let mut c = base;
        c.mechanisation.order = IntegrationOrder::First;
        c
    };
    let no_cs = {
        let mut c = base;
        c.mechanisation.coning_sculling = false;
        c
    };
    let cov10 = FusionConfig {
        covariance_interval_s: 0.1,
        ..base
    };
    let cov20 = FusionConfig {
        covariance_interval_s: 0.2,
        ..base
    };
    let s21 = FusionConfig { states: 21, ..base };
    let imu100 = decimate(&d.imu, 2);
    let imu50 = decimate(&d.imu, 4);
    let rows = [
        run(
            "baseline: 15 states, 2nd order, coning/sculling, 200 Hz, covariance every 0.05 s",
            &d,
            &d.imu,
            &base,
            false,
            &outages,
        ),
        run("1st order integration", &d, &d.imu, &first, false, &outages),
        run("coning/sculling off", &d, &d.imu, &no_cs, false, &outages),
        run(
            "IMU decimated to 100 Hz",
            &d,
            &imu100,
            &base,
            false,
            &outages,
        ),
        run("IMU decimated to 50 Hz", &d, &imu50, &base, false, &outages),
        run(
            "21 states (scale factors)",
            &d,
            &d.imu,
            &s21,
            false,
            &outages,
        ),
        run(
            "covariance propagated every 0.1 s",
            &d,
            &d.imu,
            &cov10,
            false,
            &outages,
        ),
        run(
            "covariance propagated every 0.2 s",
            &d,
            &d.imu,
            &cov20,
            false,
            &outages,
        ),
        run("RTS smoother on", &d, &d.imu, &base, true, &outages),
    ];
    println!("Drive: {:.0} min, MEMS IMU (0.3°/√h, 20°/h, 5 mg), GNSS 10 Hz σ 0.3/0.6 m, {} outages of 60 s\n", end / 60.0, outages.len());
    println!("| configuration | run time, s per hour of data | 60 s outage: mean of max horiz. error, m | worst, m | overall horiz. RMS, m |");
    println!("|---|---:|---:|---:|---:|");
    for r in &rows {
        println!(
            "| {} | {:.3} | {:.3} | {:.3} | {:.3} |",
            r.name, r.seconds_per_hour, r.outage_mean_max_m, r.outage_worst_m, r.horizontal_rms_m
        );
    }

    if drift_only {
        return;
    }
    speed_table(&base, &e);
    nees_table();
    kf_gins_anchor();
}

/// Replay speed: 1 h of 200 Hz IMU + 10 Hz GNSS, 15 and 21 states.
fn speed_table(base: &FusionConfig, e: &fusion_support::ImuErrors) {
    let d = simulate(
        &drive(60.0),
        200.0,
        20,
        e,
        (0.3, 0.6, 0.05),
        Vector3::from(LEVER),
        12,
    );
    let hours = d.truth.last().map_or(0.0, |t| t.t_s) / 3600.0;
    let opts = ReplayOptions {
        initial: Some(imulab::study::nav_state(&d.truth[0])),
        ..Default::default()
    };
    println!("\nSpeed: {hours:.2} h of 200 Hz IMU ({} samples) + 10 Hz GNSS ({} fixes), one core, best of 3 (thread CPU time)\n", d.imu.len(), d.gnss.len());
    println!("| states | CPU s | IMU samples per CPU-second | target |");
    println!("|---|---:|---:|---:|");
    let mut rates = Vec::new();
    for (states, target) in [(15, "≥ 1 M"), (21, "≥ 0.7 M")] {
        let config = FusionConfig { states, ..*base };
        let mut best = f64::INFINITY;
        for _ in 0..3 {
            let start = thread_cpu_s();
            let r = replay(
                &config,
                d.imu.iter().copied(),
                d.gnss.iter().copied(),
                opts.clone(),
            );
            best = best.min(thread_cpu_s() - start);
            assert!(r.stats.gnss_used > 0);
        }
        println!(
            "| {states} | {best:.3} | {:.2} M | {target} |",
            d.imu.len() as f64 / best / 1e6
        );
        rates.push((states, best, d.imu.len() as f64 / best / 1e6));
    }
    let row = results::Row::new(
        "fusion-speed",
        results::FUSION,
        1,
        "replay speed",
        "docs/bench/fusion.md",
    )
    .data(format!("{hours:.0} h of 200 Hz IMU + 10 Hz GNSS"))
    .ours(format!(
        "15 states {:.2} M, 21 states {:.2} M samples/CPU-s",
        rates[0].2, rates[1].2
    ))
    .target("≥ 1 M / 0.7 M")
    .met(rates[0].2 >= 1.0 && rates[1].2 >= 0.7)
    .timed()
    .command("cargo bench --bench fusion -- speed");
    results::write(
        "fusion",
        "speed",
        json!({ "hours": hours, "imu_samples": d.imu.len(), "gnss_fixes": d.gnss.len(), "best_of": 3 }),
        json!({ "runs": rates.iter().map(|(states, cpu, m)| json!({
            "states": states, "cpu_s": cpu, "m_samples_per_cpu_s": m,
        })).collect::<Vec<_>>() }),
        &[row],
    );
}

/// The number after `prefix` in the first command-line argument that has it (`--nhc-slip=0.2`).
fn flag_value(prefix: &str) -> Option<f64> {
    std::env::args().find_map(|a| a.strip_prefix(prefix)?.parse::<f64>().ok())
}

/// Runs of the consistency table per grade and constraint set.
const NEES_RUNS: usize = 50;
/// The scene of the consistency table and its withheld GNSS: 60 s every 180 s.
const NEES_SCENE: &str = "fixtures/scenes/drive_30min_open_sky.toml";
const NEES_OUTAGE_EVERY_S: f64 = 180.0;
const NEES_OUTAGE_S: f64 = 60.0;
/// The bias consistency (`-- nees --biases`) is read from this second on, once the start's
/// alignment and first updates are behind.
const BIAS_SETTLED_S: usize = 300;
/// The true bias of an epoch is its mean over this window, s ([`true_biases`]).
const BIAS_TRUTH_WINDOW_S: f64 = 10.0;

/// NEES of one epoch: the 9 navigation states together, then position, velocity and
/// attitude (3 each) on their own blocks of the covariance.
fn block_nees(solution: &imulab::fusion::navigator::NavSolution, truth: &NavState) -> [f64; 4] {
    let e = imulab::fusion::metrics::epoch_error(solution, truth);
    let block = |i: usize, v: &Vector3<f64>| {
        let p = solution.cov_nav.fixed_view::<3, 3>(i, i).into_owned();
        nalgebra::Cholesky::new(p).map_or(f64::NAN, |c| v.dot(&c.solve(v)))
    };
    [
        e.nees,
        block(0, &e.pos_ned),
        block(3, &e.vel_ned),
        block(6, &e.att),
    ]
}

/// The true sensor biases of `spec` (gyro x, y, z in rad/s, then accelerometer in m/s²) at
/// each whole second of `drive` with seed `seed`, averaged over the [`BIAS_TRUTH_WINDOW_S`]
/// centred on it: the records of the spec's bias terms alone less those of an error-free
/// IMU. The simulator keys each term's random stream by its name, so the bias terms draw
/// what they draw in the full spec. Its flicker has components down to 0.07 s, which act as
/// noise and no filter estimates; the window leaves them out of the truth.
fn true_biases(
    drive: &imulab::study::grades::StudyDrive,
    spec: &imulab::sim::imu_model::ImuSpec,
    seed: u64,
) -> Vec<[f64; 6]> {
    use imulab::sim::imu_model::{AccelSpec, GyroSpec, ImuSpec};
    let (g, a) = (&spec.gyro, &spec.accel);
    let ideal = ImuSpec {
        gyro: GyroSpec {
            bias_instability_band_s: g.bias_instability_band_s,
            ..GyroSpec::default()
        },
        accel: AccelSpec {
            bias_instability_band_s: a.bias_instability_band_s,
            ..AccelSpec::default()
        },
        ..spec.clone()
    };
    let biased = ImuSpec {
        gyro: GyroSpec {
            bias_instability_dph: g.bias_instability_dph,
            rrw_dph_rth: g.rrw_dph_rth,
            rate_ramp_dph_per_h: g.rate_ramp_dph_per_h,
            bias_dph: g.bias_dph,
            turn_on_bias_sigma_dph: g.turn_on_bias_sigma_dph,
            g_sensitivity_dph_per_g: g.g_sensitivity_dph_per_g,
            ..ideal.gyro.clone()
        },
        accel: AccelSpec {
            bias_instability_mg: a.bias_instability_mg,
            rrw_mg_rth: a.rrw_mg_rth,
            rate_ramp_mg_per_h: a.rate_ramp_mg_per_h,
            bias_mg: a.bias_mg,
            turn_on_bias_sigma_mg: a.turn_on_bias_sigma_mg,
            ..ideal.accel.clone()
        },
        ..ideal.clone()
    };
    // Running sums of the difference, with each sample's time.
    let mut times = Vec::new();
    let mut sums = vec![[0.0; 6]];
    let records = drive.imu_records(&biased, seed).expect("imu");
    for (b, i) in records.zip(drive.imu_records(&ideal, seed).expect("imu")) {
        assert_eq!(
            b.t_mono_ns, i.t_mono_ns,
            "the two IMUs' samples differ in time"
        );
        times.push((b.t_mono_ns - imulab::sim::scene::START_MONO_NS) as f64 * 1e-9);
        let (last, now) = (sums[sums.len() - 1], gyro_accel(b.gyro, b.accel));
        let ideal = gyro_accel(i.gyro, i.accel);
        sums.push(std::array::from_fn(|j| last[j] + (now[j] - ideal[j])));
    }
    let half = 0.5 * BIAS_TRUTH_WINDOW_S;
    (0..=drive.end_s() as usize)
        .map(|k| {
            let from = times.partition_point(|t| *t < k as f64 - half);
            let to = times.partition_point(|t| *t <= k as f64 + half);
            if to <= from {
                return [f64::NAN; 6];
            }
            std::array::from_fn(|j| (sums[to][j] - sums[from][j]) / (to - from) as f64)
        })
        .collect()
}

/// A gyro triad then an accelerometer triad, as one row of six.
fn gyro_accel(gyro: [f64; 3], accel: [f64; 3]) -> [f64; 6] {
    std::array::from_fn(|j| if j < 3 { gyro[j] } else { accel[j - 3] })
}

/// One second of a consistency run: NEES of the navigation states ([`block_nees`]) and, when
/// the true biases are given, e²/σ² of each bias estimate (gyro x, y, z, accelerometer x,
/// y, z; NaN otherwise).
struct NeesEpoch {
    nees: [f64; 4],
    bias: [f64; 6],
}

/// Per-second consistency of one simulated run (index = whole second since the session
/// start; NaN before the filter starts).
fn nees_run<const N: usize>(
    drive: &imulab::study::grades::StudyDrive,
    spec: &imulab::sim::imu_model::ImuSpec,
    config: &FusionConfig,
    seed: u64,
    biases: Option<&[[f64; 6]]>,
) -> Vec<NeesEpoch> {
    use imulab::fusion::navigator::Navigator;
    let end = drive.end_s();
    let outages: Vec<(f64, f64)> = (1..)
        .map(|k| k as f64 * NEES_OUTAGE_EVERY_S)
        .take_while(|a| *a < end)
        .map(|a| (a, a + NEES_OUTAGE_S))
        .collect();
    let fixes: Vec<_> = drive
        .gnss_records(seed)
        .expect("gnss")
        .iter()
        .filter_map(|r| imulab::fusion::session::observation(r, imulab::sim::scene::START_MONO_NS))
        .collect();
    let options = ReplayOptions {
        outages,
        ..Default::default()
    };
    let mut nav = Navigator::<N>::new(config, options);
    let mut fixes = fixes.iter().peekable();
    for r in drive.imu_records(spec, seed).expect("imu") {
        let sample = ImuInput::Rates {
            t_s: (r.t_mono_ns - imulab::sim::scene::START_MONO_NS) as f64 * 1e-9,
            gyro: Vector3::from(r.gyro),
            accel: Vector3::from(r.accel),
        };
        while let Some(f) = fixes.next_if(|f| f.t_s < sample.t_s()) {
            nav.push_gnss(f);
        }
        nav.push_imu(&sample);
    }
    let r = nav.finish();
    let truth = drive.truth_nav();
    let mut epochs: Vec<NeesEpoch> = (0..=end as usize)
        .map(|_| NeesEpoch {
            nees: [f64::NAN; 4],
            bias: [f64::NAN; 6],
        })
        .collect();
    for s in &r.filtered {
        let k = s.nav.t_s.round();
        if (s.nav.t_s - k).abs() > 1e-6 || k < 0.0 || k as usize >= epochs.len() {
            continue;
        }
        let epoch = &mut epochs[k as usize];
        if let Some(t) = imulab::fusion::session::truth_at(truth, s.nav.t_s) {
            epoch.nees = block_nees(s, &t);
        }
        if let Some(b) = biases.and_then(|b| b.get(k as usize)) {
            let estimate = gyro_accel(s.sensors.gyro_bias.into(), s.sensors.accel_bias.into());
            let sigma = gyro_accel(s.sigma_sensors[0].into(), s.sigma_sensors[1].into());
            epoch.bias = std::array::from_fn(|j| ((estimate[j] - b[j]) / sigma[j]).powi(2));
        }
    }
    epochs
}

/// ANEES over [`NEES_RUNS`] seeds per IMU preset and constraint set, with its 95 % band.
fn nees_table() {
    use imulab::fusion::metrics::anees;
    use rayon::prelude::*;
    let scene = imulab::sim::scene::Scene::load(std::path::Path::new(NEES_SCENE)).expect("scene");
    let drive = imulab::study::grades::StudyDrive::new(&scene).expect("drive");
    // `-- nees GRADE… --runs=N` narrows the table to some presets and fewer seeds.
    let args: Vec<String> = std::env::args().collect();
    let all = ["consumer", "bench-cheap", "industrial", "tactical"];
    let picked: Vec<&str> = all
        .into_iter()
        .filter(|g| args.iter().any(|a| a == g))
        .collect();
    let grades = if picked.is_empty() {
        all.to_vec()
    } else {
        picked
    };
    let runs_per_row = args
        .iter()
        .find_map(|a| a.strip_prefix("--runs=")?.parse::<usize>().ok())
        .filter(|n| *n > 0)
        .unwrap_or(NEES_RUNS);
    // The receiver's correlated position error, as the filter's GNSS model (`-- nees
    // white` leaves it out: fixes white with the reported σ, inflated by the default
    // correlation time).
    let gnss_error = if args.iter().any(|a| a == "white") {
        None
    } else {
        imulab::study::noise::gnss_error_from_spec(&scene.gnss[0].spec)
    };
    // `--one-bias-state`: one bias state per axis for turn-on and in-run bias together.
    let one_bias_state = args.iter().any(|a| a == "--one-bias-state");
    let sets: [(&str, bool, bool); 3] = [
        ("GNSS only", false, false),
        ("NHC", true, false),
        ("NHC + ZUPT + ZARU", true, true),
    ];
    println!(
        "\nNEES consistency: {NEES_SCENE}, {runs_per_row} seeds per row, GNSS withheld {NEES_OUTAGE_S:.0} s every {NEES_OUTAGE_EVERY_S:.0} s, {}, NEES of the 9 navigation states once a second from the filter start\n",
        if one_bias_state {
            "one bias state per axis"
        } else {
            "in-run and turn-on bias states"
        }
    );
    println!("| IMU preset | constraints | ANEES (9 expected) | 95 % band of one epoch | epochs inside / below / above | largest epoch ANEES | position / velocity / attitude ANEES (3 each) | verdict |");
    println!("|---|---|---:|---:|---:|---:|---:|---|");
    // NHC as a user who measured this car would set it (what a consistency check asks: the
    // filter's model of the truth): the car's slip gradient, known to 10 %; as σ the RMS of
    // its true vertical body velocity while the constraint applies (its heave), and as the
    // lateral σ the RMS of its true lateral body velocity beyond the slip it expects, at
    // least 2 mm/s (here 0.15 mm/s: what is left of the slip model are the filter's own
    // errors in speed and yaw rate, which its Jacobian and gyro-noise term carry, and the
    // rest; at 1 mm/s the consumer preset is over-confident, ANEES 10.7). The defaults
    // (0.1 m/s, ±0.1 °/(m/s²)) are for a car nobody measured and are cautious here.
    let car = match &scene.motion {
        imulab::sim::scene::Motion::Segments(spec) => spec.vehicle,
        _ => panic!("{NEES_SCENE}: not a drive"),
    };
    let defaults = imulab::fusion::config::NhcOptions::default();
    let gradient = car.slip_deg_per_mps2.to_radians();
    let truth = drive.truth_nav();
    let (mut lateral, mut vertical, mut n) = (0.0, 0.0, 0usize);
    for w in truth.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        if b.vel_ned.norm() < defaults.min_speed_mps {
            continue;
        }
        let v = b.quat_nb.inverse() * b.vel_ned;
        // Yaw rate from the attitude's change: the turn the filter's gyro sees.
        let yaw_rate = (a.quat_nb.inverse() * b.quat_nb).scaled_axis().z / (b.t_s - a.t_s);
        let expected = -v.x * (gradient * v.x * yaw_rate).tan();
        lateral += (v.y - expected).powi(2);
        vertical += v.z * v.z;
        n += 1;
    }
    let rms = |sum: f64| (sum / n.max(1) as f64).sqrt().max(0.002);
    let nhc_told = imulab::fusion::config::NhcOptions {
        sigma_mps: rms(vertical),
        lateral_sigma_mps: Some(rms(lateral)),
        slip_deg_per_mps2: car.slip_deg_per_mps2,
        slip_sigma_deg_per_mps2: 0.1 * car.slip_deg_per_mps2,
        ..defaults
    };
    println!(
        "NHC told the car: σ vertical {:.4} m/s, lateral {:.4} m/s (its true body velocity RMS while moving, the lateral beyond the expected slip), slip gradient {} ± {:.3} °/(m/s²), unless flags say otherwise\n",
        nhc_told.sigma_mps,
        rms(lateral),
        nhc_told.slip_deg_per_mps2,
        nhc_told.slip_sigma_deg_per_mps2
    );
    // `--biases`: also e²/σ² of each bias estimate against the simulator's true bias.
    let show_biases = args.iter().any(|a| a == "--biases");
    let mut bias_rows = Vec::new();
    let mut cells = Vec::new();
    let all_grades = grades.len() == all.len();
    for grade in grades {
        let spec = imulab::sim::presets::imu_preset(grade).expect("preset");
        let noise = imulab::study::noise::model_from_spec(&spec, grade).expect("noise");
        for (name, nhc, still) in sets {
            let mut config = FusionConfig {
                imu: noise.model,
                output_interval_s: 1.0,
                nhc: nhc_told,
                ..FusionConfig::default()
            };
            config.nhc.enabled = nhc;
            if let Some(sigma) = flag_value("--nhc-sigma=") {
                config.nhc.sigma_mps = sigma;
                config.nhc.lateral_sigma_mps = None;
            }
            if let Some(slip) = flag_value("--nhc-slip=") {
                config.nhc.slip_deg_per_mps2 = slip;
            }
            if let Some(sigma) = flag_value("--nhc-slip-sigma=") {
                config.nhc.slip_sigma_deg_per_mps2 = sigma;
            }
            config.turn_on_states = !one_bias_state;
            config.zupt.enabled = still;
            config.zaru.enabled = still;
            if let Some(e) = gnss_error {
                config.gnss.position_error = e;
            }
            let seed0 = scene.seed;
            let runs: Vec<Vec<NeesEpoch>> = (0..runs_per_row as u64)
                .into_par_iter()
                .map(|k| {
                    let seed = seed0 + k;
                    let truth = show_biases.then(|| true_biases(&drive, &spec, seed));
                    let b = truth.as_deref();
                    match config.filter_states() {
                        24 => nees_run::<24>(&drive, &spec, &config, seed, b),
                        18 => nees_run::<18>(&drive, &spec, &config, seed, b),
                        _ => nees_run::<15>(&drive, &spec, &config, seed, b),
                    }
                })
                .collect();
            let part = |i: usize| -> Vec<Vec<f64>> {
                runs.iter()
                    .map(|r| r.iter().map(|e| e.nees[i]).collect())
                    .collect()
            };
            if show_biases {
                // Mean e²/σ² per bias axis over the seeds, from [`BIAS_SETTLED_S`] on.
                let mean = |j: usize| {
                    let v: Vec<f64> = runs
                        .iter()
                        .flat_map(|r| r.iter().skip(BIAS_SETTLED_S).map(move |e| e.bias[j]))
                        .filter(|v| v.is_finite())
                        .collect();
                    v.iter().sum::<f64>() / v.len().max(1) as f64
                };
                bias_rows.push(format!(
                    "| {grade} | {name} | {:.2} / {:.2} / {:.2} | {:.2} / {:.2} / {:.2} |",
                    mean(0),
                    mean(1),
                    mean(2),
                    mean(3),
                    mean(4),
                    mean(5)
                ));
            }
            let blocks = [1, 2, 3].map(|i| anees(&part(i), 3).map_or(f64::NAN, |a| a.mean));
            let verdict = |a: &imulab::fusion::metrics::Anees| {
                if a.mean < a.band.0 {
                    "cautious"
                } else if a.mean > a.band.1 {
                    "over-confident"
                } else {
                    "consistent"
                }
            };
            match anees(&part(0), 9) {
                Some(a) => {
                    cells.push(json!({
                        "grade": grade, "constraints": name, "anees": a.mean,
                        "band": [a.band.0, a.band.1], "inside": a.inside, "below": a.below,
                        "above": a.above, "max": a.max, "blocks": blocks, "verdict": verdict(&a),
                    }));
                    println!(
                        "| {grade} | {name} | {:.2} | [{:.2}, {:.2}] | {:.0} / {:.0} / {:.0} % | {:.1} | {:.2} / {:.2} / {:.2} | {} |",
                        a.mean,
                        a.band.0,
                        a.band.1,
                        100.0 * a.inside,
                        100.0 * a.below,
                        100.0 * a.above,
                        a.max,
                        blocks[0],
                        blocks[1],
                        blocks[2],
                        verdict(&a)
                    )
                }
                None => println!("| {grade} | {name} | no common epochs | | | | | |"),
            }
        }
    }
    if show_biases {
        println!("\nBias consistency: e²/σ² of each bias estimate (1 expected) against the true bias's {BIAS_TRUTH_WINDOW_S:.0} s mean, mean over seeds and the seconds from {BIAS_SETTLED_S} s on\n");
        println!("| IMU preset | constraints | gyro x / y / z | accelerometer x / y / z |");
        println!("|---|---|---:|---:|");
        for row in &bias_rows {
            println!("{row}");
        }
    }
    nees_results(
        &cells,
        runs_per_row,
        gnss_error.is_none(),
        all_grades && !one_bias_state && !args.iter().any(|a| a.starts_with("--nhc-")),
    );
}

/// The NEES row: ANEES of the GNSS-only and NHC runs over the grades, in band or not.
/// `default_filter`: every grade with the table's own filter (turn-on states, default NHC σ).
fn nees_results(cells: &[serde_json::Value], runs: usize, white: bool, default_filter: bool) {
    let of = |set: &str| -> Vec<&serde_json::Value> {
        cells.iter().filter(|c| c["constraints"] == set).collect()
    };
    let span = |set: &str| {
        let v: Vec<f64> = of(set).iter().filter_map(|c| c["anees"].as_f64()).collect();
        let (lo, hi) = results::min_max(&v);
        results::range(lo, hi, 2)
    };
    let band = cells.first().map_or([f64::NAN; 2], |c| {
        [
            c["band"][0].as_f64().unwrap_or(f64::NAN),
            c["band"][1].as_f64().unwrap_or(f64::NAN),
        ]
    });
    let outside: Vec<String> = cells
        .iter()
        .filter(|c| c["verdict"] != "consistent")
        .map(|c| {
            format!(
                "{} {} {}",
                c["grade"].as_str().unwrap_or(""),
                c["constraints"].as_str().unwrap_or(""),
                c["verdict"].as_str().unwrap_or("")
            )
        })
        .collect();
    let met = if outside.is_empty() {
        "yes".to_string()
    } else {
        format!(
            "{} of {} rows; not: {}",
            cells.len() - outside.len(),
            cells.len(),
            outside.join(", ")
        )
    };
    let mut args = vec![format!("--runs={runs}")];
    if white {
        args.push("white".into());
    }
    // Only the full table (every grade, the default seeds, the receiver's error states) owns
    // the row.
    let row = results::Row::new(
        "fusion-nees",
        results::FUSION,
        4,
        "NEES",
        "docs/bench/fusion.md",
    )
    .data(format!(
        "{runs} seeds, {NEES_OUTAGE_S:.0} s outages; band [{:.2}, {:.2}]",
        band[0], band[1]
    ))
    .ours(format!(
        "GNSS only {}, NHC {}",
        span("GNSS only"),
        span("NHC")
    ))
    .target("in band")
    .met_text(met)
    .command("cargo bench --bench fusion -- nees");
    let owns = default_filter && runs == NEES_RUNS && !white;
    results::write(
        "fusion",
        if owns { "nees" } else { "nees-partial" },
        json!({ "scene": NEES_SCENE, "runs": runs, "outage_s": NEES_OUTAGE_S,
                "outage_every_s": NEES_OUTAGE_EVERY_S, "white_gnss": white }),
        json!({ "cells": cells }),
        if owns {
            std::slice::from_ref(&row)
        } else {
            &[]
        },
    );
}

/// Where the KF-GINS binary is: `KF_GINS_BIN`, else the build under /work/peers.
fn kf_gins_binary() -> Option<std::path::PathBuf> {
    let path = std::env::var_os("KF_GINS_BIN")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| "/work/peers/KF-GINS/bin/KF-GINS".into());
    path.is_file().then_some(path)
}

/// The true state nearest to `t` (within 0.1 ms: KF-GINS prints times rounded).
fn truth_near(d: &SimData, t: f64) -> Option<NavState> {
    let k = (t * d.imu_rate).round();
    if k < 0.0 || (k / d.imu_rate - t).abs() > 1e-4 {
        return None;
    }
    d.truth.get(k as usize).map(imulab::study::nav_state)
}

/// Writes one simulated drive in KF-GINS's input formats under `dir`: IMU increments, the
/// GNSS fixes with every epoch inside `outages` removed (KF-GINS has no switch to withhold
/// GNSS), the truth `.nav` and a configuration naming the filter's noise model `model`.
fn write_kf_gins_inputs(
    dir: &std::path::Path,
    d: &SimData,
    model: &imulab::fusion::config::ImuModel,
    outages: &[(f64, f64)],
) -> std::io::Result<std::path::PathBuf> {
    use std::io::Write;
    std::fs::create_dir_all(dir)?;
    let mut imu = std::io::BufWriter::new(std::fs::File::create(dir.join("imu.txt"))?);
    for s in &d.imu {
        if let ImuInput::Increments {
            t_s, dtheta, dvel, ..
        } = *s
        {
            writeln!(
                imu,
                "{t_s:.6} {:.12e} {:.12e} {:.12e} {:.12e} {:.12e} {:.12e}",
                dtheta.x, dtheta.y, dtheta.z, dvel.x, dvel.y, dvel.z
            )?;
        }
    }
    imu.flush()?;
    // The same IMU rows with the wheel speed in column 8 (the true forward speed plus white
    // noise of ODOMETER_SIGMA_MPS), for imulab's odometer updates; KF-GINS has none.
    let mut odo = std::io::BufWriter::new(std::fs::File::create(dir.join("imu_odometer.txt"))?);
    let mut rng = <rand_xoshiro::Xoshiro256PlusPlus as rand::SeedableRng>::seed_from_u64(77);
    for (s, t) in d.imu.iter().zip(d.truth.iter().skip(1)) {
        if let ImuInput::Increments {
            t_s, dtheta, dvel, ..
        } = *s
        {
            let v_b = t.quat_nb.inverse() * t.vel_ned;
            let noise: f64 =
                rand_distr::Distribution::sample(&rand_distr::StandardNormal, &mut rng);
            writeln!(
                odo,
                "{t_s:.6} {:.12e} {:.12e} {:.12e} {:.12e} {:.12e} {:.12e} {:.5}",
                dtheta.x,
                dtheta.y,
                dtheta.z,
                dvel.x,
                dvel.y,
                dvel.z,
                v_b.x + ODOMETER_SIGMA_MPS * noise
            )?;
        }
    }
    odo.flush()?;
    let mut gnss = std::io::BufWriter::new(std::fs::File::create(dir.join("gnss.txt"))?);
    for g in d
        .gnss
        .iter()
        .filter(|g| !outages.iter().any(|&(a, b)| g.t_s >= a && g.t_s < b))
    {
        writeln!(
            gnss,
            "{:.6} {:.10} {:.10} {:.4} {:.4} {:.4} {:.4}",
            g.t_s,
            g.lat_rad.to_degrees(),
            g.lon_rad.to_degrees(),
            g.height_m,
            g.sigma_ned_m.x,
            g.sigma_ned_m.y,
            g.sigma_ned_m.z
        )?;
    }
    gnss.flush()?;
    let mut truth = std::io::BufWriter::new(std::fs::File::create(dir.join("truth.nav"))?);
    for t in &d.truth {
        writeln!(
            truth,
            "{}",
            imulab::fusion::kfgins::format_nav_line(0, &imulab::study::nav_state(t))
        )?;
    }
    truth.flush()?;
    // KF-GINS starts at the first IMU row, so the initial state is the truth there.
    let t0 = d.imu[0].t_s();
    let init = truth_near(d, t0).expect("truth at the first IMU epoch");
    let (roll, pitch, yaw) = init.quat_nb.euler_angles();
    let v3 = |a: Axes, unit: f64| {
        format!(
            "[{:.9}, {:.9}, {:.9}]",
            a[0] * unit,
            a[1] * unit,
            a[2] * unit
        )
    };
    let yaml = format!(
        "imupath: \"{imu}\"\ngnsspath: \"{gnss}\"\noutputpath: \"{out}\"\nimudatalen: 7\nimudatarate: {rate}\n\
starttime: {t0:.6}\nendtime: -1\n\
initpos: [{lat:.10}, {lon:.10}, {h:.4}]\ninitvel: [{vn:.6}, {ve:.6}, {vd:.6}]\ninitatt: [{r:.8}, {p:.8}, {y:.8}]\n\
initgyrbias: [0, 0, 0]\ninitaccbias: [0, 0, 0]\ninitgyrscale: [0, 0, 0]\ninitaccscale: [0, 0, 0]\n\
initposstd: [0.1, 0.1, 0.2]\ninitvelstd: [0.05, 0.05, 0.05]\ninitattstd: [0.5, 0.5, 1.0]\n\
imunoise:\n  arw: {arw}\n  vrw: {vrw}\n  gbstd: {gb}\n  abstd: {ab}\n  gsstd: {gs}\n  asstd: {as_}\n  corrtime: {ct:.6}\n\
antlever: [{l0}, {l1}, {l2}]\n",
        imu = dir.join("imu.txt").display(),
        gnss = dir.join("gnss.txt").display(),
        out = dir.display(),
        rate = d.imu_rate,
        lat = init.lat_rad.to_degrees(),
        lon = init.lon_rad.to_degrees(),
        h = init.height_m,
        vn = init.vel_ned.x,
        ve = init.vel_ned.y,
        vd = init.vel_ned.z,
        r = roll.to_degrees(),
        p = pitch.to_degrees(),
        y = yaw.to_degrees().rem_euclid(360.0),
        arw = v3(model.arw_rad_per_sqrt_s, 1f64.to_degrees() * 60.0),
        vrw = v3(model.vrw_mps_per_sqrt_s, 60.0),
        gb = v3(model.gyro_bias.sigma, 1f64.to_degrees() * 3600.0),
        ab = v3(model.accel_bias.sigma, 1e5),
        gs = v3(model.gyro_scale.sigma, 1e6),
        as_ = v3(model.accel_scale.sigma, 1e6),
        ct = model.gyro_bias.tau_s / 3600.0,
        l0 = LEVER[0],
        l1 = LEVER[1],
        l2 = LEVER[2],
    );
    let path = dir.join("kf-gins.yaml");
    std::fs::write(&path, yaml)?;
    Ok(path)
}

/// RMS of the per-outage max horizontal drift and the GNSS-on horizontal RMS of a
/// trajectory against the drive's truth.
fn drift_metrics(d: &SimData, sol: &[NavState], outages: &[(f64, f64)]) -> (f64, f64, usize) {
    let solutions: Vec<imulab::fusion::navigator::NavSolution> = sol
        .iter()
        .map(|nav| imulab::fusion::navigator::NavSolution {
            nav: *nav,
            sensors: Default::default(),
            cov_nav: nalgebra::SMatrix::identity(),
            sigma_sensors: [Vector3::repeat(f64::NAN); 4],
        })
        .collect();
    let s = summarise(&errors(&solutions, |t| truth_near(d, t)), outages);
    let n = s.outages.len();
    let rms = (s
        .outages
        .iter()
        .map(|o| o.max_horizontal_m.powi(2))
        .sum::<f64>()
        / n.max(1) as f64)
        .sqrt();
    (rms, s.horizontal_gnss.rms, n)
}

/// σ of the simulated wheel speed, m/s.
const ODOMETER_SIGMA_MPS: f64 = 0.05;

/// imulab (NHC off and on, and NHC with the odometer) against KF-GINS on the same exported
/// files, per IMU grade.
fn kf_gins_anchor() {
    let Some(bin) = kf_gins_binary() else {
        println!("\nKF-GINS comparison skipped: no KF-GINS binary (set KF_GINS_BIN or build it at /work/peers/KF-GINS/bin/KF-GINS); benches/results/fusion-kf-gins.json left as it is");
        return;
    };
    // `--nhc-slip=K --nhc-slip-sigma=S`: the NHC rows with another side-slip gradient and σ
    // (then benches/results is left as it is).
    let (slip, slip_sigma) = (flag_value("--nhc-slip="), flag_value("--nhc-slip-sigma="));
    let mut per_grade = Vec::new();
    println!("\nAgainst KF-GINS ({}): 30 min drive, 200 Hz IMU, 10 Hz GNSS position σ 0.3/0.6 m, GNSS removed from the file for 60 s every 180 s\n", bin.display());
    println!("| IMU grade | filter | RMS of per-outage max horiz. drift, m | GNSS-on horiz. RMS, m | outages |");
    println!("|---|---|---:|---:|---:|");
    for (k, grade) in ["industrial", "tactical"].into_iter().enumerate() {
        let model = imulab::study::noise::model_from_preset(grade)
            .expect("preset")
            .model;
        let mut rng_errors = mems_errors(21 + k as u64);
        let base = FusionConfig::default().imu;
        // The errors drawn for the default model, rescaled axis by axis to the preset's σ.
        let ratio =
            |x: Axes, y: Axes| Vector3::from_fn(|i, _| if y[i] > 0.0 { x[i] / y[i] } else { 0.0 });
        rng_errors.arw = model.arw_rad_per_sqrt_s.max();
        rng_errors.vrw = model.vrw_mps_per_sqrt_s.max();
        rng_errors.gyro_bias = rng_errors
            .gyro_bias
            .component_mul(&ratio(model.gyro_bias.sigma, base.gyro_bias.sigma));
        rng_errors.accel_bias = rng_errors
            .accel_bias
            .component_mul(&ratio(model.accel_bias.sigma, base.accel_bias.sigma));
        rng_errors.gyro_scale = rng_errors
            .gyro_scale
            .component_mul(&ratio(model.gyro_scale.sigma, base.gyro_scale.sigma));
        rng_errors.accel_scale = rng_errors
            .accel_scale
            .component_mul(&ratio(model.accel_scale.sigma, base.accel_scale.sigma));
        let d = simulate(
            &drive(30.0),
            200.0,
            20,
            &rng_errors,
            (0.3, 0.6, 0.05),
            Vector3::from(LEVER),
            31 + k as u64,
        );
        let end = d.truth.last().map_or(0.0, |t| t.t_s);
        let outages: Vec<(f64, f64)> = (0..)
            .map(|i| 120.0 + 180.0 * i as f64)
            .take_while(|&a| a + 60.0 < end)
            .map(|a| (a, a + 60.0))
            .collect();
        let dir = std::env::temp_dir().join(format!("imulab-kf-gins-{grade}"));
        let yaml = write_kf_gins_inputs(&dir, &d, &model, &outages).expect("write KF-GINS files");
        let status = std::process::Command::new(&bin)
            .arg(&yaml)
            .stdout(std::process::Stdio::null())
            .status();
        let theirs = match status {
            Ok(s) if s.success() => {
                imulab::fusion::kfgins::read_nav(&dir.join("KF_GINS_Navresult.nav"))
                    .map(|rows| rows.into_iter().map(|r| r.nav).collect::<Vec<_>>())
                    .map_err(|e| e.to_string())
            }
            Ok(s) => Err(format!("exited with {s}")),
            Err(e) => Err(e.to_string()),
        };
        let config = imulab::fusion::kfgins::KfGinsConfig::from_file(&yaml, &dir)
            .expect("read back the exported configuration");
        let mut rows = Vec::new();
        for (name, nhc, odometer) in [
            ("imulab, NHC off", false, false),
            ("imulab, NHC on", true, false),
            ("imulab, NHC + odometer", true, true),
        ] {
            let mut fusion = config.fusion_config();
            fusion.nhc.enabled = nhc;
            if let Some(k) = slip {
                fusion.nhc.slip_deg_per_mps2 = k;
            }
            if let Some(s) = slip_sigma {
                fusion.nhc.slip_sigma_deg_per_mps2 = s;
            }
            fusion.odometer.enabled = odometer;
            fusion.odometer.sigma_mps = ODOMETER_SIGMA_MPS;
            let mut files = config.clone();
            if odometer {
                files.imu_path = dir.join("imu_odometer.txt");
            }
            let r = imulab::fusion::kfgins::replay_files_with(&files, &fusion, &[], false)
                .expect("replay the exported files");
            if odometer {
                assert!(r.stats.odometer_updates > 0, "{:?}", r.stats);
            }
            let nav: Vec<NavState> = r.filtered.iter().map(|s| s.nav).collect();
            rows.push((name, drift_metrics(&d, &nav, &outages)));
        }
        match theirs {
            Ok(nav) => rows.push(("KF-GINS", drift_metrics(&d, &nav, &outages))),
            Err(e) => println!("| {grade} | KF-GINS failed: {e} | | | |"),
        }
        for (name, (drift, gnss_rms, n)) in &rows {
            println!("| {grade} | {name} | {drift:.2} | {gnss_rms:.3} | {n} |");
        }
        per_grade.push(json!({
            "grade": grade,
            "runs": rows.iter().map(|(name, (drift, rms, n))| json!({
                "filter": name, "rms_drift_m": drift, "gnss_on_rms_m": rms, "outages": n,
            })).collect::<Vec<_>>(),
        }));
        if let Some((_, (kf_drift, kf_rms, _))) = rows.iter().find(|r| r.0 == "KF-GINS") {
            for (label, i) in [("NHC on", 1), ("NHC + odometer", 2)] {
                let (ours_drift, ours_rms, _) = rows[i].1;
                println!(
                    "| {grade} | ratio {label} / KF-GINS | {:.2} | {:.2} | |",
                    ours_drift / kf_drift,
                    ours_rms / kf_rms
                );
            }
        }
    }
    if slip.is_none() && slip_sigma.is_none() {
        kf_gins_results(&bin, &per_grade);
    }
}

/// The two KF-GINS rows (NHC, NHC + odometer; industrial / tactical) when KF-GINS ran for
/// both grades.
fn kf_gins_results(bin: &std::path::Path, per_grade: &[serde_json::Value]) {
    let get = |g: &serde_json::Value, filter: &str| {
        g["runs"].as_array().and_then(|r| {
            let r = r.iter().find(|r| r["filter"] == filter)?;
            Some((r["rms_drift_m"].as_f64()?, r["gnss_on_rms_m"].as_f64()?))
        })
    };
    let mut rows = Vec::new();
    let kf: Option<Vec<(f64, f64)>> = per_grade.iter().map(|g| get(g, "KF-GINS")).collect();
    if let Some(kf) = kf.filter(|k| k.len() == 2) {
        let pair = |v: [f64; 2], digits: usize| format!("{:.digits$} / {:.digits$}", v[0], v[1]);
        let peer = format!(
            "KF-GINS {} m; {} m",
            pair([kf[0].0, kf[1].0], 2),
            pair([kf[0].1, kf[1].1], 3)
        );
        for (i, (id, filter, measured, data)) in [
            (
                "fusion-kf-gins-nhc",
                "imulab, NHC on",
                "drift vs KF-GINS, NHC",
                "30 min drive, 11 × 60 s outages, industrial / tactical",
            ),
            (
                "fusion-kf-gins-odometer",
                "imulab, NHC + odometer",
                "drift vs KF-GINS, NHC + odometer",
                "same, wheel speed",
            ),
        ]
        .into_iter()
        .enumerate()
        {
            let Some(ours): Option<Vec<(f64, f64)>> =
                per_grade.iter().map(|g| get(g, filter)).collect()
            else {
                continue;
            };
            let drift = [ours[0].0 / kf[0].0, ours[1].0 / kf[1].0];
            let rms = [ours[0].1 / kf[0].1, ours[1].1 / kf[1].1];
            let ok = drift.iter().all(|r| *r <= 0.5) && rms.iter().all(|r| *r <= 1.0);
            let ours_text = format!(
                "{}{} m; {} m",
                if i == 0 { "RMS drift " } else { "" },
                pair([ours[0].0, ours[1].0], 2),
                pair([ours[0].1, ours[1].1], 3)
            );
            rows.push(
                results::Row::new(
                    id,
                    results::FUSION,
                    2 + i as u32,
                    measured,
                    "docs/bench/fusion.md",
                )
                .data(data)
                .ours(ours_text)
                .peer(if i == 0 { peer.clone() } else { "same".into() })
                .ratio(format!("{}; {}", pair(drift, 2), pair(rms, 2)))
                .target("≤ 0.5×; ≤ 1×")
                .met(ok)
                .command(if i == 0 {
                    "KF_GINS_BIN=… cargo bench --bench fusion -- kf-gins"
                } else {
                    "same"
                }),
            );
        }
    }
    results::write(
        "fusion",
        "kf-gins",
        json!({ "kf_gins_bin": bin.display().to_string(), "drive_min": 30, "outage_s": 60, "every_s": 180 }),
        json!({ "grades": per_grade }),
        &rows,
    );
}

/// Runs the release `imulab study` with `--json` into a temporary file, timed; its JSON is
/// kept whole in the results.
fn study_run(args: &[&str]) -> (f64, serde_json::Value) {
    let json_path = std::env::temp_dir().join(format!("imulab-study-{}.json", std::process::id()));
    let root = results::workspace_root();
    let t = Instant::now();
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_imulab"))
        .current_dir(&root)
        .arg("study")
        .args(args)
        .arg("--json")
        .arg(&json_path)
        .stdout(std::process::Stdio::null())
        .status()
        .expect("run imulab study");
    let wall = t.elapsed().as_secs_f64();
    assert!(status.success(), "imulab study {args:?}: {status}");
    let text = std::fs::read_to_string(&json_path).expect("read the study JSON");
    let _ = std::fs::remove_file(&json_path);
    (wall, serde_json::from_str(&text).expect("the study JSON"))
}

/// The open-sky requirement study (longest outage within 1 m per grade, and the drift curves
/// of the plot) and the 100-run study's wall time.
fn study_runs() {
    let sky_args = [
        "fixtures/scenes/drive_30min_open_sky.toml",
        "--grades",
        "consumer,bench-cheap,industrial,tactical",
        "--outages",
        "5,10,30,60,120",
        "--require",
        "0.1,1,10",
        "--runs",
        "20",
    ];
    let (sky_s, sky) = study_run(&sky_args);
    println!("open-sky study: {sky_s:.1} s");
    let time_args = [
        "fixtures/scenes/drive_30min.toml",
        "--grades",
        "bench-cheap,bench-dear,industrial,tactical",
        "--outages",
        "5,10,30,60",
        "--runs",
        "100",
    ];
    let (time_s, timed) = study_run(&time_args);
    println!("100-run study: {time_s:.1} s");
    // Longest outage within 1 m, by grade, ascending.
    let mut within: Vec<(String, f64, bool)> = sky["grades"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|g| {
            let b = g["bridges"]
                .as_array()?
                .iter()
                .find(|b| b["requirement_m"] == 1.0)?;
            Some((
                g["name"].as_str()?.to_string(),
                b["longest_s"].as_f64()?,
                b["beyond_horizon"].as_bool().unwrap_or(false),
            ))
        })
        .collect();
    within.sort_by(|a, b| a.1.total_cmp(&b.1));
    let separated = within.windows(2).all(|w| w[1].1 > w[0].1);
    let grades = within.len();
    let runs = sky["runs"].as_u64().unwrap_or(0);
    let sky_row = results::Row::new(
        "study-within-1m",
        results::FUSION,
        5,
        "longest outage within 1 m",
        "docs/bench/fusion.md",
    )
    .data(format!(
        "`{}`, {grades} presets × {runs} runs",
        sky_args[0].trim_start_matches("fixtures/scenes/")
    ))
    .ours(format!(
        "{} s ({})",
        within
            .iter()
            .map(|w| format!("{}{:.1}", if w.2 { "≥ " } else { "" }, w.1))
            .collect::<Vec<_>>()
            .join(" / "),
        within
            .iter()
            .map(|w| w.0.as_str())
            .collect::<Vec<_>>()
            .join(" / ")
    ))
    .target("grades separated")
    .met(separated)
    .command("cargo bench --bench fusion -- study");
    let n_grades = timed["grades"].as_array().map_or(0, Vec::len);
    let n_outages = time_args[4].split(',').count();
    let time_row = results::Row::new(
        "study-time",
        results::FUSION,
        6,
        "study time",
        "docs/bench/fusion.md",
    )
    .data(format!(
        "`{}`, {} runs × {n_grades} grades × {n_outages} outages",
        time_args[0].trim_start_matches("fixtures/scenes/"),
        timed["runs"].as_u64().unwrap_or(0)
    ))
    .ours(format!("{time_s:.1} s"))
    .target("< 1 min")
    .met(time_s < 60.0)
    .timed()
    .command("same");
    results::write(
        "fusion",
        "study",
        json!({ "binary": "imulab (bench profile)", "open_sky": sky_args, "timed": time_args }),
        json!({
            "open_sky": { "wall_s": sky_s, "requirements_m": [0.1, 1.0, 10.0], "study": sky },
            "timed": { "wall_s": time_s, "study": timed },
        }),
        &[sky_row, time_row],
    );
}
