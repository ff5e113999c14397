//! Run time against error of the GNSS/INS replay (`cargo bench --bench fusion`): one
//! simulated MEMS drive, GNSS withheld for 60 s every 300 s, and the options of issue 8
//! varied one at a time; then the speed of a 1 h, 200 Hz IMU + 10 Hz GNSS replay.
//! Prints markdown tables (copied into docs/bench/fusion.md). Run times are the thread's CPU
//! time (CLOCK_THREAD_CPUTIME_ID), so a busy shared machine does not inflate them.

#[path = "../tests/fusion/support.rs"]
mod fusion_support;

use fusion_support::{mems_errors, simulate, SimData};
use imulab::fusion::config::FusionConfig;
use imulab::fusion::mechanisation::{ImuInput, IntegrationOrder, NavState};
use imulab::fusion::metrics::{errors, summarise};
use imulab::fusion::navigator::{replay, ReplayOptions};
use imulab::sim::motion::{MotionSpec, Segment};
use nalgebra::Vector3;
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
        initial: Some(NavState::from(&d.truth[0])),
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

fn main() {
    let mut e = mems_errors(11);
    e.gyro_scale = Vector3::zeros();
    e.accel_scale = Vector3::zeros();
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
    let mut base = FusionConfig::default();
    base.gnss.lever_arm_m = LEVER;
    // This drive's GNSS errors are white and its biases constant: tell the filter so (and
    // keep the table comparable with the first round).
    base.gnss.position_correlation_s = 0.0;
    base.imu.gyro_bias.tau_s = 3600.0;
    base.imu.accel_bias.tau_s = 3600.0;
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

    let d = simulate(
        &drive(60.0),
        200.0,
        20,
        &e,
        (0.3, 0.6, 0.05),
        Vector3::from(LEVER),
        12,
    );
    let hours = d.truth.last().map_or(0.0, |t| t.t_s) / 3600.0;
    let opts = ReplayOptions {
        initial: Some(NavState::from(&d.truth[0])),
        ..Default::default()
    };
    let mut best = f64::INFINITY;
    for _ in 0..3 {
        let start = thread_cpu_s();
        let r = replay(
            &base,
            d.imu.iter().copied(),
            d.gnss.iter().copied(),
            opts.clone(),
        );
        best = best.min(thread_cpu_s() - start);
        assert!(r.stats.gnss_used > 0);
    }
    println!("\nSpeed: {hours:.2} h of 200 Hz IMU ({} samples) + 10 Hz GNSS ({} fixes), 15 states, one core: best of 3 = {best:.3} s CPU", d.imu.len(), d.gnss.len());
}
