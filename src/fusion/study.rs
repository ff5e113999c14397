//! The sensor-grade study: how long a GNSS outage each IMU grade bridges within a horizontal
//! requirement. Monte Carlo over grades (simulator presets or Allan fits) and runs: each run
//! simulates the scene's drive with the grade's IMU (the simulator's library API, seed =
//! base seed + run, the same for every grade so grades meet the same GNSS errors and the
//! same outage times), replays it through the filter with GNSS, and at several outage
//! starts forks the filter and runs the fork without GNSS for the longest outage length.
//! The largest horizontal drift within the first L seconds of a fork is the drift of an
//! outage of length L (a filter does not know how long an outage will last, so one fork
//! serves every length). Drift is the growth of the horizontal error since the outage
//! start, |e(t) − e(start)|, i.e. what the IMU adds, independent of the receiver's own
//! error; the absolute error is reported too.
//!
//! Outage starts are stratified over the drive after a settling time: the usable span is cut
//! into equal strata, one uniformly drawn start in each, so outages fall on turns, stops and
//! straights in proportion to the drive (the share that contains a turn is reported).
//!
//! Runs are independent and executed in parallel with rayon; results are collected in run
//! order, so they are identical for any thread count.

use crate::fusion::config::FusionConfig;
use crate::fusion::mechanisation::{ImuInput, NavState};
use crate::fusion::navigator::{GnssObservation, Navigator, ReplayOptions};
use crate::fusion::noise::{self, NoiseModel};
use crate::fusion::session::{observation, truth_at};
use crate::sim::imu_model::{Channels, ImuSpec};
use crate::sim::outputs::MemorySink;
use crate::sim::scene::{ImuEntry, Outputs, Scene};
use anyhow::{bail, Context};
use imulab_drivers::codec::Protocol;
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use serde::Serialize;
use std::path::Path;

/// Default horizontal requirements, m.
pub const DEFAULT_REQUIREMENTS_M: [f64; 3] = [0.1, 0.5, 1.5];
/// Drift is checked at this rate inside an outage, Hz.
const CHECK_RATE_HZ: f64 = 10.0;
/// A heading change above this inside an outage counts as a turn, degrees.
const TURN_DEG: f64 = 10.0;

/// One IMU grade: what is simulated and what the filter is told.
#[derive(Debug, Clone)]
pub struct Grade {
    pub name: String,
    /// The simulator's IMU.
    pub spec: ImuSpec,
    /// The filter's noise model (from the same preset or fit: datasheet / Allan values).
    pub noise: NoiseModel,
}

impl Grade {
    /// A grade from a preset name, or from an Allan fit JSON file (`FILE.json[#DEVICE]`).
    pub fn parse(arg: &str, base: &crate::fusion::config::ImuModel) -> anyhow::Result<Grade> {
        if let Some(spec) = crate::sim::presets::imu_preset(arg) {
            return Ok(Grade {
                name: arg.to_string(),
                noise: noise::model_from_spec(&spec, &format!("preset {arg}"))?,
                spec,
            });
        }
        let (path, device) = noise::split_device(arg);
        if !Path::new(path).exists() {
            bail!(
                "grade `{arg}` is neither an IMU preset ({}) nor an existing Allan-fit JSON file",
                crate::sim::presets::imu_preset_names().join(", ")
            );
        }
        let report = noise::read_allan_report(Path::new(path))?;
        let fit = noise::allan_device(&report, device, path)?;
        let spec = noise::spec_from_allan(&fit).with_context(|| format!("grade {arg}"))?;
        let noise = noise::model_from_allan(&fit, base, &format!("Allan fit {path}"));
        let stem = Path::new(path)
            .file_stem()
            .map_or(path.to_string(), |s| s.to_string_lossy().into_owned());
        Ok(Grade {
            name: match device {
                Some(d) => format!("{stem}#{d}"),
                None => stem,
            },
            spec,
            noise,
        })
    }
}

/// What to study.
#[derive(Debug, Clone)]
pub struct StudyOptions {
    pub grades: Vec<Grade>,
    /// Outage lengths, s (any order; reported ascending).
    pub outages_s: Vec<f64>,
    /// Monte Carlo runs per grade.
    pub runs: usize,
    /// Horizontal requirements, m.
    pub requirements_m: Vec<f64>,
    /// Seed of run 0 (run r uses seed + r).
    pub seed: u64,
    /// One outage start per this much usable drive, s.
    pub outage_spacing_s: f64,
    /// No outage starts in the first this many seconds (alignment and convergence), s.
    pub settle_s: f64,
    /// The filter configuration; its IMU model is replaced by each grade's.
    pub config: FusionConfig,
}

impl StudyOptions {
    /// Options with the defaults: requirements 0.1/0.5/1.5 m, one outage per 120 s after a
    /// 180 s settling time, default filter configuration, covariance every 0.1 s.
    pub fn new(grades: Vec<Grade>, outages_s: Vec<f64>, runs: usize, seed: u64) -> Self {
        Self {
            grades,
            outages_s,
            runs,
            requirements_m: DEFAULT_REQUIREMENTS_M.to_vec(),
            seed,
            outage_spacing_s: 120.0,
            settle_s: 180.0,
            config: FusionConfig {
                covariance_interval_s: 0.1,
                ..FusionConfig::default()
            },
        }
    }
}

/// The drift statistics of one grade at one outage length.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LengthStats {
    pub outage_s: f64,
    /// Outages measured (runs × starts that were aligned).
    pub count: usize,
    /// Horizontal drift (error growth since the outage start), m.
    pub p50_m: f64,
    pub p95_m: f64,
    pub max_m: f64,
    /// p95 of the absolute horizontal error inside the outage, m.
    pub abs_p95_m: f64,
}

/// The answer for one requirement.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Bridge {
    pub requirement_m: f64,
    /// Longest tested outage whose p95 drift is within the requirement (None: not even the
    /// shortest).
    pub longest_s: Option<f64>,
}

/// Results of one grade.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GradeResult {
    pub name: String,
    pub noise_origin: String,
    pub warnings: Vec<String>,
    pub lengths: Vec<LengthStats>,
    pub bridges: Vec<Bridge>,
    /// Outage starts skipped because the filter was not aligned yet.
    pub skipped: usize,
}

/// Results of a study.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StudyResult {
    pub scene_duration_s: f64,
    pub runs: usize,
    pub seed: u64,
    /// Outage starts per run.
    pub outages_per_run: usize,
    /// Share of outages (longest length) that contain a turn of more than 10°.
    pub turning_share: f64,
    /// Share of outages (longest length) that contain a standstill (speed < 0.5 m/s).
    pub standstill_share: f64,
    pub grades: Vec<GradeResult>,
}

/// One outage of one run: drift and absolute error maxima per length.
#[derive(Debug, Clone, PartialEq)]
struct OutageSample {
    drift_m: Vec<f64>,
    abs_m: Vec<f64>,
    turning: bool,
    standstill: bool,
}

/// What one run gave.
#[derive(Debug, Clone, PartialEq, Default)]
struct RunResult {
    samples: Vec<OutageSample>,
    skipped: usize,
}

/// The simulated data of one run as the filter takes it.
struct RunData {
    imu: Vec<ImuInput>,
    gnss: Vec<GnssObservation>,
    truth: Vec<NavState>,
}

fn simulate(scene: &Scene, grade: &Grade, seed: u64) -> anyhow::Result<RunData> {
    let mut sc = scene.clone();
    let (name, protocol) = scene.imus.first().map_or_else(
        || ("imu".to_string(), Protocol::Wit),
        |e| (e.name.clone(), e.protocol),
    );
    sc.imus = vec![ImuEntry {
        name: name.clone(),
        spec: grade.spec.clone(),
        channels: Channels::ALL,
        protocol,
    }];
    sc.gnss.truncate(1);
    let Some(rx) = sc.gnss.first_mut() else {
        bail!("the scene has no GNSS receiver: a study needs one");
    };
    // The study places its own outages.
    rx.spec.outages.clear();
    rx.spec.periodic_outage = None;
    let rx_name = rx.name.clone();
    sc.set_seed(seed);
    sc.outputs = Outputs {
        truth_nav: true,
        truth_imu: false,
        truth_every: ((sc.rate_hz / CHECK_RATE_HZ).round() as u32).max(1),
    };
    let mut sink = MemorySink::default();
    crate::sim::runner::run(&sc, &mut sink).context("simulating the scene")?;
    let records = sink.imu.remove(&name).unwrap_or_default();
    let Some(t0) = records.first().map(|r| r.t_mono_ns) else {
        bail!("the simulated IMU produced no samples");
    };
    let secs = |t: i64| t.saturating_sub(t0) as f64 * 1e-9;
    let imu = records
        .iter()
        .map(|r| ImuInput::Rates {
            t_s: secs(r.t_mono_ns),
            gyro: Vector3::from(r.gyro),
            accel: Vector3::from(r.accel),
        })
        .collect();
    let gnss = sink
        .gnss
        .remove(&rx_name)
        .unwrap_or_default()
        .iter()
        .filter_map(|r| observation(r, t0))
        .collect();
    let truth = sink
        .truth_nav
        .iter()
        .map(|r| NavState {
            t_s: secs(r.t_mono_ns),
            lat_rad: r.lat_deg.to_radians(),
            lon_rad: r.lon_deg.to_radians(),
            height_m: r.height_m,
            vel_ned: Vector3::from(r.vel_ned),
            quat_nb: UnitQuaternion::from_quaternion(Quaternion::new(
                r.quat_nb[0],
                r.quat_nb[1],
                r.quat_nb[2],
                r.quat_nb[3],
            )),
        })
        .collect();
    Ok(RunData { imu, gnss, truth })
}

/// Stratified outage starts in [settle, end − longest − 1]: `count` strata, one uniform
/// draw each. Depends only on the seed and run, not on the grade.
fn outage_starts(seed: u64, run: usize, from: f64, to: f64, spacing: f64) -> Vec<f64> {
    if to <= from {
        return Vec::new();
    }
    let count = (((to - from) / spacing).floor() as usize).max(1);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(
        seed.wrapping_add(run as u64)
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ 0x5757_0a6e,
    );
    let width = (to - from) / count as f64;
    (0..count)
        .map(|k| from + (k as f64 + rng.random::<f64>()) * width)
        .collect()
}

fn horizontal_error(nav: &NavState, truth: &[NavState]) -> Option<Vector3<f64>> {
    let t = truth_at(truth, nav.t_s)?;
    let e = nav.ned_offset_from(t.lat_rad, t.lon_rad, t.height_m);
    Some(Vector3::new(e.x, e.y, 0.0))
}

/// Runs one fork without GNSS from sample `first` for the longest outage; None when the
/// filter was not aligned at the start.
fn outage_fork<const N: usize>(
    mut nav: Navigator<N>,
    data: &RunData,
    first: usize,
    lengths: &[f64],
    check_every: usize,
) -> Option<OutageSample> {
    let start_nav = nav.ins()?.nav;
    let e0 = horizontal_error(&start_nav, &data.truth)?;
    let t0 = data.imu.get(first)?.t_s();
    let longest = *lengths.last()?;
    let mut drift = vec![f64::NAN; lengths.len()];
    let mut abs = vec![f64::NAN; lengths.len()];
    let (mut max_drift, mut max_abs) = (0.0f64, e0.norm());
    let mut next_length = 0;
    for (j, sample) in data.imu[first..].iter().enumerate() {
        let t = sample.t_s();
        nav.push_imu(sample);
        let last = t - t0 >= longest - 1e-9;
        if j % check_every == 0 || last {
            if let Some(e) = nav
                .ins()
                .and_then(|ins| horizontal_error(&ins.nav, &data.truth))
            {
                max_drift = max_drift.max((e - e0).norm());
                max_abs = max_abs.max(e.norm());
            }
            while next_length < lengths.len() && t - t0 >= lengths[next_length] - 1e-9 {
                drift[next_length] = max_drift;
                abs[next_length] = max_abs;
                next_length += 1;
            }
        }
        if last {
            break;
        }
    }
    // Motion during the outage, from the truth.
    let i0 = data.truth.partition_point(|r| r.t_s < t0);
    let i1 = data.truth.partition_point(|r| r.t_s <= t0 + longest);
    let window = &data.truth[i0..i1.max(i0)];
    let heading = |r: &NavState| r.quat_nb.euler_angles().2;
    let turning = window.first().is_some_and(|a| {
        window.iter().any(|b| {
            crate::fusion::mechanisation::wrap_pi(heading(b) - heading(a))
                .to_degrees()
                .abs()
                > TURN_DEG
        })
    });
    let standstill = window.iter().any(|r| r.vel_ned.norm() < 0.5);
    (next_length == lengths.len()).then_some(OutageSample {
        drift_m: drift,
        abs_m: abs,
        turning,
        standstill,
    })
}

fn replay_run<const N: usize>(
    data: &RunData,
    config: &FusionConfig,
    starts: &[f64],
    lengths: &[f64],
    check_every: usize,
) -> RunResult {
    let options = ReplayOptions::default();
    let mut nav = Navigator::<N>::new(config, options);
    let mut fixes = data.gnss.iter().peekable();
    let mut next_start = 0;
    let mut out = RunResult::default();
    for (i, sample) in data.imu.iter().enumerate() {
        let t = sample.t_s();
        while let Some(f) = fixes.next_if(|f| f.t_s < t) {
            nav.push_gnss(f);
        }
        while next_start < starts.len() && t >= starts[next_start] {
            match outage_fork(nav.clone(), data, i, lengths, check_every) {
                Some(s) => out.samples.push(s),
                None => out.skipped += 1,
            }
            next_start += 1;
        }
        nav.push_imu(sample);
    }
    out.skipped += starts.len() - next_start;
    out
}

fn one_run(
    scene: &Scene,
    grade: &Grade,
    run: usize,
    options: &StudyOptions,
    lengths: &[f64],
) -> anyhow::Result<RunResult> {
    let data = simulate(scene, grade, options.seed.wrapping_add(run as u64))
        .with_context(|| format!("grade {}, run {run}", grade.name))?;
    let end = data.imu.last().map_or(0.0, |s| s.t_s());
    let longest = lengths.last().copied().unwrap_or(0.0);
    let starts = outage_starts(
        options.seed,
        run,
        options.settle_s,
        end - longest - 1.0,
        options.outage_spacing_s,
    );
    let mut config = options.config;
    config.imu = grade.noise.model;
    // The study never reads the trajectory output: one epoch is enough.
    config.output_interval_s = f64::MAX / 4.0;
    let check_every = ((scene.rate_hz / CHECK_RATE_HZ).round() as usize).max(1);
    Ok(match config.states {
        21 => replay_run::<21>(&data, &config, &starts, lengths, check_every),
        _ => replay_run::<15>(&data, &config, &starts, lengths, check_every),
    })
}

/// Nearest-rank percentile of sorted values.
fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = ((p * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    sorted[rank - 1]
}

/// Runs the study. Errors name the grade and run that failed.
pub fn run_study(scene: &Scene, options: &StudyOptions) -> anyhow::Result<StudyResult> {
    if options.grades.is_empty() {
        bail!("no grades to study");
    }
    if options.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let mut lengths = options.outages_s.clone();
    if lengths.is_empty() || lengths.iter().any(|l| !(l.is_finite() && *l > 0.0)) {
        bail!("outage lengths must be positive numbers of seconds, got {lengths:?}");
    }
    lengths.sort_by(f64::total_cmp);
    lengths.dedup();
    let longest = lengths[lengths.len() - 1];
    if scene.duration_s < options.settle_s + longest + 1.0 {
        bail!(
            "the scene lasts {} s: too short for a {} s settling time and a {longest} s outage",
            scene.duration_s,
            options.settle_s
        );
    }
    options
        .config
        .validate()
        .context("study filter configuration")?;
    let jobs: Vec<(usize, usize)> = (0..options.grades.len())
        .flat_map(|g| (0..options.runs).map(move |r| (g, r)))
        .collect();
    let results: Vec<anyhow::Result<RunResult>> = jobs
        .par_iter()
        .map(|&(g, r)| one_run(scene, &options.grades[g], r, options, &lengths))
        .collect();
    let mut per_grade: Vec<RunResult> = vec![RunResult::default(); options.grades.len()];
    for (&(g, _), result) in jobs.iter().zip(results) {
        let r = result?;
        per_grade[g].samples.extend(r.samples);
        per_grade[g].skipped += r.skipped;
    }
    let reference = &per_grade[0];
    let share = |f: fn(&OutageSample) -> bool| {
        reference.samples.iter().filter(|s| f(s)).count() as f64
            / reference.samples.len().max(1) as f64
    };
    let outages_per_run = outage_starts(
        options.seed,
        0,
        options.settle_s,
        scene.duration_s - longest - 1.0,
        options.outage_spacing_s,
    )
    .len();
    let grades = options
        .grades
        .iter()
        .zip(&per_grade)
        .map(|(grade, runs)| {
            let stats: Vec<LengthStats> = lengths
                .iter()
                .enumerate()
                .map(|(k, &l)| {
                    let mut d: Vec<f64> = runs.samples.iter().map(|s| s.drift_m[k]).collect();
                    let mut a: Vec<f64> = runs.samples.iter().map(|s| s.abs_m[k]).collect();
                    d.sort_by(f64::total_cmp);
                    a.sort_by(f64::total_cmp);
                    LengthStats {
                        outage_s: l,
                        count: d.len(),
                        p50_m: percentile(&d, 0.5),
                        p95_m: percentile(&d, 0.95),
                        max_m: d.last().copied().unwrap_or(f64::NAN),
                        abs_p95_m: percentile(&a, 0.95),
                    }
                })
                .collect();
            let bridges = options
                .requirements_m
                .iter()
                .map(|&req| Bridge {
                    requirement_m: req,
                    longest_s: stats
                        .iter()
                        .take_while(|s| s.p95_m <= req)
                        .last()
                        .map(|s| s.outage_s),
                })
                .collect();
            GradeResult {
                name: grade.name.clone(),
                noise_origin: grade.noise.origin.clone(),
                warnings: grade.noise.warnings.clone(),
                lengths: stats,
                bridges,
                skipped: runs.skipped,
            }
        })
        .collect();
    Ok(StudyResult {
        scene_duration_s: scene.duration_s,
        runs: options.runs,
        seed: options.seed,
        outages_per_run,
        turning_share: share(|s| s.turning),
        standstill_share: share(|s| s.standstill),
        grades,
    })
}

impl StudyResult {
    /// The table and the answer as text.
    pub fn summary_text(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{} runs of a {:.0} s drive, {} outage starts per run ({:.0} % with a turn, {:.0} % with a standstill); horizontal drift = error growth since the outage start",
            self.runs,
            self.scene_duration_s,
            self.outages_per_run,
            100.0 * self.turning_share,
            100.0 * self.standstill_share
        );
        let _ = writeln!(
            s,
            "{:<24} {:>9} {:>6} {:>10} {:>10} {:>10} {:>12}",
            "grade", "outage s", "n", "p50 m", "p95 m", "max m", "abs p95 m"
        );
        for g in &self.grades {
            for l in &g.lengths {
                let _ = writeln!(
                    s,
                    "{:<24} {:>9.1} {:>6} {:>10.3} {:>10.3} {:>10.3} {:>12.3}",
                    g.name, l.outage_s, l.count, l.p50_m, l.p95_m, l.max_m, l.abs_p95_m
                );
            }
        }
        let n = self
            .grades
            .first()
            .and_then(|g| g.lengths.first())
            .map_or(0, |l| l.count);
        for (k, req) in self
            .grades
            .first()
            .map(|g| {
                g.bridges
                    .iter()
                    .map(|b| b.requirement_m)
                    .collect::<Vec<_>>()
            })
            .unwrap_or_default()
            .iter()
            .enumerate()
        {
            let _ = writeln!(
                s,
                "Longest outage each grade bridges within {req} m (95 % of {n} outages over {} runs):",
                self.runs
            );
            for g in &self.grades {
                let answer = match g.bridges.get(k).and_then(|b| b.longest_s) {
                    Some(l) => format!("{l} s"),
                    None => format!(
                        "none of the tested lengths (p95 at {} s: {:.3} m)",
                        g.lengths.first().map_or(f64::NAN, |l| l.outage_s),
                        g.lengths.first().map_or(f64::NAN, |l| l.p95_m)
                    ),
                };
                let _ = writeln!(s, "  {:<24} {answer}", g.name);
            }
        }
        for g in &self.grades {
            if g.skipped > 0 {
                let _ = writeln!(
                    s,
                    "note: {}: {} outage starts skipped (filter not aligned yet)",
                    g.name, g.skipped
                );
            }
        }
        s
    }
}
