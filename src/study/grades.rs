//! The sensor-grade study: how long a GNSS outage each IMU grade bridges within a horizontal
//! requirement. Monte Carlo over grades (simulator presets or Allan fits) and runs: each run
//! simulates the scene's drive with the grade's IMU (the simulator's models, seed = base
//! seed + run, the same for every grade so grades meet the same GNSS errors and the same
//! outage times), replays it through the filter with GNSS, and at several outage starts
//! forks the filter and runs the fork without GNSS for the longest outage length. The
//! largest horizontal drift within the first L seconds of a fork is the drift of an outage
//! of length L (a filter does not know how long an outage will last, so one fork serves
//! every length). Drift is the growth of the horizontal error since the outage start,
//! |e(t) − e(start)|, i.e. what the IMU adds, independent of the receiver's own error; the
//! absolute error is reported too.
//!
//! Outage starts are stratified over the drive after a settling time: the usable span is cut
//! into equal strata, one uniformly drawn start in each, so outages fall on turns, stops and
//! straights in proportion to the drive (the share that contains a turn is reported).
//!
//! Cost: the truth trajectory is integrated once per study ([`StudyDrive`]), the receiver
//! simulated once per run (shared by the grades), and per run and grade only the IMU errors
//! are simulated, streamed sample by sample into the main filter and the running forks (no
//! IMU data is stored). A fork applies no update, so it propagates no covariance (its
//! navigation solution is the same without; tested). Each fork branches off the converged
//! filter with GNSS up to its start, which is what an outage at that time is.
//!
//! Runs are independent and executed in parallel with rayon (and a run's grades too);
//! results are collected in run order, so they are identical for any thread count.

use crate::noise::{self, NoiseModel};
use anyhow::{bail, Context};
use imulab_fusion::config::FusionConfig;
use imulab_fusion::mechanisation::{ImuInput, NavState};
use imulab_fusion::navigator::{GnssObservation, Navigator, ReplayOptions};
use imulab_fusion::session::{observation, truth_at};
use imulab_sim::gnss_model::GnssSimulator;
use imulab_sim::imu_model::{Channels, ImuSimulator, ImuSpec};
use imulab_sim::motion::{static_truth, MotionGenerator, TruthSample};
use imulab_sim::scene::{GnssEntry, Motion, Scene, START_MONO_NS};
use imulab_sim::truth_file::TruthFileReader;
use imulab_store::{GnssRecord, ImuRecord};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Default horizontal requirements, m.
pub const DEFAULT_REQUIREMENTS_M: [f64; 3] = [0.1, 1.0, 10.0];
/// Bootstrap resamples (over runs) for the uncertainty of the longest bridged outage.
const BOOTSTRAP_RESAMPLES: usize = 400;
/// The relative precision `runs_for_5pct` is computed for (±5 % at 95 % confidence).
const TARGET_PRECISION: f64 = 0.05;
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
    pub fn parse(arg: &str, base: &imulab_fusion::config::ImuModel) -> anyhow::Result<Grade> {
        if let Some(spec) = imulab_sim::presets::imu_preset(arg) {
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
                imulab_sim::presets::imu_preset_names().join(", ")
            );
        }
        let report = noise::read_allan_report(Path::new(path))?;
        let mut grade = Grade::from_allan(&report, device, &format!("Allan fit {path}"), base)
            .with_context(|| format!("grade {arg}"))?;
        let stem = Path::new(path)
            .file_stem()
            .map_or(path.to_string(), |s| s.to_string_lossy().into_owned());
        grade.name = match device {
            Some(d) => format!("{stem}#{d}"),
            None => stem,
        };
        Ok(grade)
    }

    /// A grade from the fit of `device` (None: the only device) in an Allan report; named
    /// after the device. Fails when the fit does not give the white noise of both sensors.
    pub fn from_allan(
        report: &imulab_allan::analysis::AllanReport,
        device: Option<&str>,
        origin: &str,
        base: &imulab_fusion::config::ImuModel,
    ) -> anyhow::Result<Grade> {
        let fit = noise::allan_device(report, device, origin)?;
        let spec = noise::spec_from_allan(&fit)?;
        let noise = noise::model_from_allan(&fit, base, origin);
        Ok(Grade {
            name: fit.device.clone(),
            spec,
            noise,
        })
    }
}

/// The drive a study of Allan fits runs on when no scene is given (`imulab report`, `imulab
/// demo`): 15 minutes at 150 Hz with a 10 Hz standalone receiver (a shorter
/// `fixtures/scenes/drive_30min.toml`; the study places its own outages). Its two bench IMUs
/// are what the demo replays; a study simulates each grade in their place.
pub const REFERENCE_DRIVE: &str = r#"# The reference drive of `imulab report` and `imulab demo`: 15 minutes with two bench IMUs
# and a 10 Hz standalone GNSS receiver (a replay withholds its own outages; a study places its own).
duration_s = 900
rate_hz = 150
seed = 7
start_utc = 2026-03-02T09:00:00Z

[location]
lat_deg = 48.1507
lon_deg = 11.5691
height_m = 520.0

[motion]
kind = "segments"
heading_deg = 90.0
speed_mps = 0.0
segments = [
    { kind = "stop", duration_s = 30 },
    { kind = "accelerate", dv_mps = 14, duration_s = 20 },
    { kind = "cruise", duration_s = 120 },
    { kind = "turn", angle_deg = 90, duration_s = 15 },
    { kind = "cruise", duration_s = 150 },
    { kind = "accelerate", dv_mps = 6, duration_s = 15 },
    { kind = "cruise", duration_s = 150 },
    { kind = "climb", dh_m = 30, duration_s = 60 },
    { kind = "cruise", duration_s = 100 },
    { kind = "turn", angle_deg = -120, duration_s = 40 },
    { kind = "cruise", duration_s = 80 },
    { kind = "accelerate", dv_mps = -20, duration_s = 25 },
    { kind = "stop", duration_s = 95 },
]

[temperature]
kind = "constant"
celsius = 25.0

[[imu]]
name = "cheap"
preset = "bench-cheap"

[[imu]]
name = "dear"
preset = "bench-dear"

[[gnss]]
name = "gnss"
preset = "standalone"
rate_hz = 10
latency_s = 0.08

[outputs]
truth_nav = true
truth_imu = false
truth_every = 15
"#;
/// Outage lengths (s) and horizontal requirements (m) of a study of Allan fits.
pub const FIT_STUDY_OUTAGES_S: [f64; 7] = [1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 60.0];
pub const FIT_STUDY_REQUIREMENTS_M: [f64; 2] = [0.1, 1.0];
/// Monte Carlo runs of a study of Allan fits unless told otherwise.
pub const FIT_STUDY_RUNS: usize = 8;

/// The filter-based outage answer for the Allan fits of `devices` in `report`: a study on
/// [`REFERENCE_DRIVE`] with [`FIT_STUDY_OUTAGES_S`] and [`FIT_STUDY_REQUIREMENTS_M`], seed
/// = the drive's. Fails (naming the device) when a fit does not allow simulating the IMU.
pub fn fit_study(
    report: &imulab_allan::analysis::AllanReport,
    devices: &[&str],
    runs: usize,
    progress: bool,
) -> anyhow::Result<StudyResult> {
    let scene = Scene::parse(REFERENCE_DRIVE, Path::new(".")).context("reference drive")?;
    let mut config = FusionConfig {
        covariance_interval_s: 0.1,
        ..FusionConfig::default()
    };
    model_receiver_error(&mut config, &scene);
    let grades = devices
        .iter()
        .map(|d| {
            Grade::from_allan(report, Some(d), &format!("Allan fit of {d}"), &config.imu)
                .with_context(|| format!("device {d}"))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut options = StudyOptions::new(grades, FIT_STUDY_OUTAGES_S.to_vec(), runs, scene.seed);
    options.requirements_m = FIT_STUDY_REQUIREMENTS_M.to_vec();
    options.config = config;
    options.progress = progress;
    run_study(&scene, &options)
}

/// Gives the filter the scene receiver's correlated position error as three states
/// (`noise::gnss_error_from_spec` of its first receiver), unless the configuration already
/// sets one: how a study models the receiver by default.
pub fn model_receiver_error(config: &mut FusionConfig, scene: &Scene) {
    if config.gnss.position_error.enabled() {
        return;
    }
    if let Some(e) = scene
        .gnss
        .first()
        .and_then(|rx| crate::noise::gnss_error_from_spec(&rx.spec))
    {
        config.gnss.position_error = e;
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
    /// Show a progress bar on stderr (only when it is a terminal).
    pub progress: bool,
}

impl StudyOptions {
    /// Options with the defaults: requirements 0.1/1/10 m, no progress bar, one outage per 120 s after a
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
            progress: false,
        }
    }
}

/// The drift statistics of one grade at one outage length.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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

/// The answer for one requirement: the longest outage whose p95 drift is within it.
///
/// Found on the drift curves themselves, not on the grid of tested lengths: each outage's
/// running maximum drift is checked at 10 Hz and the time it first exceeds the requirement
/// is interpolated between two checks. The p95 drift at length L is within the requirement
/// exactly when at most n − ⌈0.95 n⌉ of the n outages exceeded it before L, so the longest
/// such L is that order statistic of the exceedance times. Its Monte Carlo uncertainty is a
/// bootstrap over runs (the outages of one run share its GNSS errors and IMU realisation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Bridge {
    pub requirement_m: f64,
    /// The longest outage within the requirement, s (None: no outage measured). When
    /// `beyond_horizon`, the drift stayed within it for the whole longest simulated outage
    /// and this is that length (a lower bound).
    pub longest_s: Option<f64>,
    pub beyond_horizon: bool,
    /// 95 % bootstrap interval over runs, s.
    pub ci95_s: Option<[f64; 2]>,
    /// Bootstrap standard deviation, s.
    pub std_s: f64,
    /// Runs that make the answer stable to ±5 % (95 % confidence), from the bootstrap σ
    /// scaled by 1/√runs (None when beyond the horizon or not measured).
    pub runs_for_5pct: Option<usize>,
}

/// Results of one grade.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
    /// Per requirement, the time since the outage start its drift first exceeded it, s
    /// (infinite: not within the longest length).
    exceed_s: Vec<f64>,
    turning: bool,
    standstill: bool,
}

/// What one run gave.
#[derive(Debug, Clone, PartialEq, Default)]
struct RunResult {
    samples: Vec<OutageSample>,
    skipped: usize,
}

/// The drive every run and grade of a study shares, computed once: the truth trajectory
/// with its error-free IMU input (the same for every run and grade: only the sensor errors
/// differ), the temperature, the receiver, and the truth navigation states the errors are
/// measured against. Each run then only adds its sensors' errors: the receiver's (once per
/// run, shared by the grades) and the IMU's (per run and grade).
///
/// The records it gives are the very ones `sim::runner::run` writes for the scene with the
/// grade's IMU and the seed (same simulators, same random streams; tested), without
/// integrating the trajectory again for every run and grade.
pub struct StudyDrive {
    rate_hz: f64,
    samples: u64,
    /// One truth sample per IMU sample (a single one for a static scene, reused).
    truth: Vec<TruthSample>,
    /// Temperature per sample (empty when constant).
    temps: Vec<f64>,
    constant_temp: f64,
    start_wall_ns: i64,
    imu_name: String,
    /// The receiver, its listed outages removed (the study places its own).
    gnss: GnssEntry,
    /// Truth navigation states at the check rate (times since the session start, s).
    truth_nav: Vec<NavState>,
}

/// Time since the session start of a simulator timestamp, s.
fn session_seconds(t_mono_ns: i64) -> f64 {
    t_mono_ns.saturating_sub(START_MONO_NS) as f64 * 1e-9
}

impl StudyDrive {
    /// Prepares the shared drive of `scene` (its first IMU's name, its first receiver).
    pub fn new(scene: &Scene) -> anyhow::Result<StudyDrive> {
        let Some(rx) = scene.gnss.first() else {
            bail!("the scene has no GNSS receiver: a study needs one");
        };
        let mut gnss = rx.clone();
        gnss.spec.outages.clear();
        gnss.spec.periodic_outage = None;
        let samples = scene.samples();
        let count = usize::try_from(samples).context("too many samples for this machine")?;
        let loc = &scene.location;
        let truth: Vec<TruthSample> = match &scene.motion {
            Motion::Static { quat_nb } => vec![static_truth(
                loc.lat_deg.to_radians(),
                loc.lon_deg.to_radians(),
                loc.height_m,
                *quat_nb,
            )],
            Motion::Segments(spec) => {
                let generator = MotionGenerator::new(spec, scene.rate_hz)
                    .map_err(|e| anyhow::anyhow!("motion: {e}"))?;
                generator.take(count).collect()
            }
            Motion::TruthFile(path) => {
                let mut reader = TruthFileReader::open(path, scene.rate_hz)?;
                let mut v = Vec::with_capacity(count);
                while v.len() < count {
                    match reader.next_sample() {
                        Some(s) => v.push(s?),
                        None => break,
                    }
                }
                v
            }
            Motion::Tumble(_) | Motion::RateTable(_) => {
                bail!("the study drives a vehicle: a tumble or rate-table scene has no trajectory to navigate")
            }
        };
        if !matches!(scene.motion, Motion::Static { .. }) && truth.len() < count {
            bail!(
                "the motion ends after {} of the scene's {count} samples",
                truth.len()
            );
        }
        let constant = scene.temperature.is_constant();
        let temps = if constant {
            Vec::new()
        } else {
            (0..samples)
                .map(|k| scene.temperature.at(k as f64 / scene.rate_hz))
                .collect()
        };
        let every = ((scene.rate_hz / CHECK_RATE_HZ).round() as u64).max(1);
        let truth_nav = (0..samples)
            .step_by(every as usize)
            .map(|k| {
                let t = truth.get(k as usize).unwrap_or(&truth[0]);
                let q = t.quat_nb.quaternion();
                NavState {
                    t_s: session_seconds(START_MONO_NS + sample_ns(k, scene.rate_hz)),
                    quat_nb: UnitQuaternion::from_quaternion(Quaternion::new(q.w, q.i, q.j, q.k)),
                    ..crate::nav_state(t)
                }
            })
            .collect();
        Ok(StudyDrive {
            rate_hz: scene.rate_hz,
            samples,
            truth,
            temps,
            constant_temp: scene.temperature.at(0.0),
            start_wall_ns: scene.start_wall_ns,
            imu_name: scene
                .imus
                .first()
                .map_or_else(|| "imu".to_string(), |e| e.name.clone()),
            gnss,
            truth_nav,
        })
    }

    fn truth(&self, k: u64) -> &TruthSample {
        self.truth.get(k as usize).unwrap_or(&self.truth[0])
    }

    /// Time of the last sample since the session start, s.
    pub fn end_s(&self) -> f64 {
        self.samples.saturating_sub(1) as f64 / self.rate_hz
    }

    /// The truth navigation states the errors are measured against (check rate).
    pub fn truth_nav(&self) -> &[NavState] {
        &self.truth_nav
    }

    /// The IMU records of `spec` with run seed `seed`, sample by sample (nothing stored).
    pub fn imu_records<'a>(
        &'a self,
        spec: &ImuSpec,
        seed: u64,
    ) -> anyhow::Result<impl Iterator<Item = ImuRecord> + 'a> {
        let mut sim = ImuSimulator::new(spec, &self.imu_name, seed, self.rate_hz, Channels::ALL)
            .map_err(|e| anyhow::anyhow!("imu {}: {e}", self.imu_name))?;
        Ok((0..self.samples).filter_map(move |k| {
            let t = self.truth(k);
            let temp = self
                .temps
                .get(k as usize)
                .copied()
                .unwrap_or(self.constant_temp);
            sim.step(
                &t.gyro_b,
                &t.accel_b,
                temp,
                START_MONO_NS,
                self.start_wall_ns,
            )
            .record
        }))
    }

    /// The receiver's records with run seed `seed`.
    pub fn gnss_records(&self, seed: u64) -> anyhow::Result<Vec<GnssRecord>> {
        let mut sim = GnssSimulator::new(&self.gnss.spec, &self.gnss.name, seed)
            .map_err(|e| anyhow::anyhow!("gnss {}: {e}", self.gnss.name))?;
        let every = ((self.rate_hz / self.gnss.spec.rate_hz).round() as u64).max(1);
        Ok((0..self.samples)
            .step_by(every as usize)
            .map(|k| {
                let t = TruthSample {
                    t_s: k as f64 / self.rate_hz,
                    ..*self.truth(k)
                };
                sim.epoch(&t, START_MONO_NS, self.start_wall_ns)
            })
            .collect())
    }

    /// The receiver's fixes with run seed `seed` as the filter takes them.
    fn gnss_observations(&self, seed: u64) -> anyhow::Result<Vec<GnssObservation>> {
        Ok(self
            .gnss_records(seed)?
            .iter()
            .filter_map(|r| observation(r, START_MONO_NS))
            .collect())
    }
}

/// Nanoseconds of sample `k` since the session start, as the simulator stamps them.
fn sample_ns(k: u64, rate_hz: f64) -> i64 {
    (k as f64 / rate_hz * 1e9).round() as i64
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

/// One outage in progress: a fork of the filter that gets no GNSS, advanced sample by sample
/// alongside the main filter (so no IMU data is stored), for the longest outage length.
struct Fork<const N: usize> {
    nav: Navigator<N>,
    t0: f64,
    e0: Vector3<f64>,
    /// Samples pushed so far.
    j: usize,
    max_drift: f64,
    max_abs: f64,
    next_length: usize,
    drift: Vec<f64>,
    abs: Vec<f64>,
    /// The previous check: time since the start, running maximum drift.
    last_check: (f64, f64),
    exceed_s: Vec<f64>,
}

impl<const N: usize> Fork<N> {
    /// Forks `main` at time `t0` (before the sample at `t0` is pushed); None when the filter
    /// is not aligned yet. Without constraints the fork propagates no covariance: it applies
    /// no update, so its trajectory is the same without (see
    /// [`Navigator::set_covariance_propagation`]).
    fn start(
        main: &Navigator<N>,
        t0: f64,
        truth: &[NavState],
        lengths: &[f64],
        requirements: &[f64],
    ) -> Option<Self> {
        let e0 = horizontal_error(&main.ins()?.nav, truth)?;
        let mut nav = main.clone();
        nav.set_covariance_propagation(false);
        Some(Fork {
            nav,
            t0,
            max_abs: e0.norm(),
            e0,
            j: 0,
            max_drift: 0.0,
            next_length: 0,
            drift: vec![f64::NAN; lengths.len()],
            abs: vec![f64::NAN; lengths.len()],
            last_check: (0.0, 0.0),
            exceed_s: vec![f64::INFINITY; requirements.len()],
        })
    }

    /// Pushes one sample; true when the longest outage is complete.
    fn push(
        &mut self,
        sample: &ImuInput,
        truth: &[NavState],
        lengths: &[f64],
        requirements: &[f64],
        check_every: usize,
    ) -> bool {
        let t = sample.t_s();
        self.nav.push_imu(sample);
        let longest = lengths.last().copied().unwrap_or(0.0);
        let last = t - self.t0 >= longest - 1e-9;
        if self.j.is_multiple_of(check_every) || last {
            if let Some(e) = self
                .nav
                .ins()
                .and_then(|ins| horizontal_error(&ins.nav, truth))
            {
                self.max_drift = self.max_drift.max((e - self.e0).norm());
                self.max_abs = self.max_abs.max(e.norm());
                let (t_prev, d_prev) = self.last_check;
                let (t_now, d_now) = (t - self.t0, self.max_drift);
                for (x, &req) in self.exceed_s.iter_mut().zip(requirements) {
                    if x.is_infinite() && d_now > req {
                        // Linear between the two checks the requirement lies between.
                        *x = t_prev + (req - d_prev) / (d_now - d_prev) * (t_now - t_prev);
                    }
                }
                self.last_check = (t_now, d_now);
            }
            while self.next_length < lengths.len()
                && t - self.t0 >= lengths[self.next_length] - 1e-9
            {
                self.drift[self.next_length] = self.max_drift;
                self.abs[self.next_length] = self.max_abs;
                self.next_length += 1;
            }
        }
        self.j += 1;
        last
    }

    /// The outage's figures and the motion during it (from the truth); None when it did
    /// not reach every length.
    fn finish(self, truth: &[NavState], lengths: &[f64]) -> Option<OutageSample> {
        let longest = lengths.last().copied().unwrap_or(0.0);
        let i0 = truth.partition_point(|r| r.t_s < self.t0);
        let i1 = truth.partition_point(|r| r.t_s <= self.t0 + longest);
        let window = &truth[i0..i1.max(i0)];
        let heading = |r: &NavState| r.quat_nb.euler_angles().2;
        let turning = window.first().is_some_and(|a| {
            window.iter().any(|b| {
                imulab_fusion::mechanisation::wrap_pi(heading(b) - heading(a))
                    .to_degrees()
                    .abs()
                    > TURN_DEG
            })
        });
        let standstill = window.iter().any(|r| r.vel_ned.norm() < 0.5);
        (self.next_length == lengths.len()).then_some(OutageSample {
            drift_m: self.drift,
            abs_m: self.abs,
            exceed_s: self.exceed_s,
            turning,
            standstill,
        })
    }
}

/// What each fork measures: drift at these outage lengths (s, ascending), the exceedance
/// time of these requirements (m), checked every this many IMU samples.
struct Checks<'a> {
    lengths: &'a [f64],
    requirements: &'a [f64],
    every: usize,
}

/// One run of one grade: the main filter with GNSS over the whole drive and, from each
/// outage start on, a fork without GNSS; all fed sample by sample as the IMU is simulated.
fn replay_run<const N: usize>(
    imu: impl Iterator<Item = ImuRecord>,
    gnss: &[GnssObservation],
    truth: &[NavState],
    config: &FusionConfig,
    starts: &[f64],
    checks: &Checks,
) -> RunResult {
    let Checks {
        lengths,
        requirements,
        every: check_every,
    } = *checks;
    let mut nav = Navigator::<N>::new(config, ReplayOptions::default());
    let mut fixes = gnss.iter().peekable();
    let mut next_start = 0;
    let mut forks: Vec<Fork<N>> = Vec::new();
    let mut out = RunResult::default();
    for r in imu {
        let sample = ImuInput::Rates {
            t_s: session_seconds(r.t_mono_ns),
            gyro: Vector3::from(r.gyro),
            accel: Vector3::from(r.accel),
        };
        let t = sample.t_s();
        while let Some(f) = fixes.next_if(|f| f.t_s < t) {
            nav.push_gnss(f);
        }
        while next_start < starts.len() && t >= starts[next_start] {
            match Fork::start(&nav, t, truth, lengths, requirements) {
                Some(f) => forks.push(f),
                None => out.skipped += 1,
            }
            next_start += 1;
        }
        nav.push_imu(&sample);
        let mut k = 0;
        while k < forks.len() {
            if forks[k].push(&sample, truth, lengths, requirements, check_every) {
                match forks.remove(k).finish(truth, lengths) {
                    Some(s) => out.samples.push(s),
                    None => out.skipped += 1,
                }
            } else {
                k += 1;
            }
        }
    }
    out.skipped += forks.len() + starts.len() - next_start;
    out
}

/// One grade on one run's data.
fn one_run(
    drive: &StudyDrive,
    grade: &Grade,
    seed: u64,
    gnss: &[GnssObservation],
    options: &StudyOptions,
    starts: &[f64],
    lengths: &[f64],
) -> anyhow::Result<RunResult> {
    let imu = drive.imu_records(&grade.spec, seed)?;
    let mut config = options.config;
    config.imu = grade.noise.model;
    // The study never reads the trajectory output: one epoch is enough.
    config.output_interval_s = f64::MAX / 4.0;
    let check_every = ((drive.rate_hz / CHECK_RATE_HZ).round() as usize).max(1);
    let truth = drive.truth_nav();
    let checks = Checks {
        lengths,
        requirements: &options.requirements_m,
        every: check_every,
    };
    Ok(match config.filter_states() {
        30 => replay_run::<30>(imu, gnss, truth, &config, starts, &checks),
        27 => replay_run::<27>(imu, gnss, truth, &config, starts, &checks),
        24 => replay_run::<24>(imu, gnss, truth, &config, starts, &checks),
        21 => replay_run::<21>(imu, gnss, truth, &config, starts, &checks),
        18 => replay_run::<18>(imu, gnss, truth, &config, starts, &checks),
        _ => replay_run::<15>(imu, gnss, truth, &config, starts, &checks),
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

/// The longest outage whose p95 drift stays within requirement `k`: the order statistic
/// n − ⌈0.95 n⌉ (0-based) of the exceedance times (see [`Bridge`]); infinite when that many
/// outages never exceeded it.
fn longest_within(samples: &mut [f64]) -> Option<f64> {
    let n = samples.len();
    if n == 0 {
        return None;
    }
    let rank = ((0.95 * n as f64).ceil() as usize).clamp(1, n);
    let (_, x, _) = samples.select_nth_unstable_by(n - rank, f64::total_cmp);
    Some(*x)
}

/// The answer for requirement `k` over `runs` (each a run's outages), with its bootstrap
/// uncertainty over runs; `horizon` is the longest simulated outage.
fn bridge(runs: &[RunResult], k: usize, requirement_m: f64, horizon: f64, seed: u64) -> Bridge {
    let times = |r: &RunResult| {
        r.samples
            .iter()
            .map(|s| s.exceed_s[k])
            .collect::<Vec<f64>>()
    };
    let mut all: Vec<f64> = runs.iter().flat_map(times).collect();
    let point = longest_within(&mut all);
    let beyond_horizon = point.is_some_and(f64::is_infinite);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0xb0075 ^ k as u64);
    let mut boot: Vec<f64> = (0..BOOTSTRAP_RESAMPLES)
        .filter_map(|_| {
            let mut pick: Vec<f64> = (0..runs.len())
                .flat_map(|_| times(&runs[rng.random_range(0..runs.len())]))
                .collect();
            longest_within(&mut pick).map(|x| x.min(horizon))
        })
        .collect();
    boot.sort_by(f64::total_cmp);
    let mean = boot.iter().sum::<f64>() / boot.len().max(1) as f64;
    let std_s = (boot.iter().map(|x| (x - mean).powi(2)).sum::<f64>()
        / (boot.len().max(2) - 1) as f64)
        .sqrt();
    let longest_s = point.map(|x| x.min(horizon));
    let runs_for_5pct = longest_s.filter(|l| !beyond_horizon && *l > 0.0).map(|l| {
        let rel = 1.96 * std_s / (TARGET_PRECISION * l);
        ((runs.len() as f64 * rel * rel).ceil() as usize).max(1)
    });
    Bridge {
        requirement_m,
        longest_s,
        beyond_horizon,
        ci95_s: (!boot.is_empty()).then(|| [percentile(&boot, 0.025), percentile(&boot, 0.975)]),
        std_s,
        runs_for_5pct,
    }
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
    if options
        .requirements_m
        .iter()
        .any(|r| !(r.is_finite() && *r > 0.0))
    {
        bail!(
            "requirements must be positive numbers of metres, got {:?}",
            options.requirements_m
        );
    }
    let drive = StudyDrive::new(scene)?;
    let end = drive.end_s();
    let progress = if options.progress && std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        indicatif::ProgressBar::new((options.runs * options.grades.len()) as u64).with_style(
            indicatif::ProgressStyle::with_template(
                "study {bar:40} {pos}/{len} grade-runs, {elapsed} elapsed, ~{eta} left",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        )
    } else {
        indicatif::ProgressBar::hidden()
    };
    // Runs in parallel, and within a run its grades (they share the run's GNSS fixes);
    // collected in order, so the result does not depend on the thread count.
    let results: Vec<anyhow::Result<Vec<RunResult>>> = (0..options.runs)
        .into_par_iter()
        .map(|run| {
            let seed = options.seed.wrapping_add(run as u64);
            let gnss = drive
                .gnss_observations(seed)
                .with_context(|| format!("run {run}: simulating the receiver"))?;
            let starts = outage_starts(
                options.seed,
                run,
                options.settle_s,
                end - longest - 1.0,
                options.outage_spacing_s,
            );
            options
                .grades
                .par_iter()
                .map(|grade| {
                    let r = one_run(&drive, grade, seed, &gnss, options, &starts, &lengths)
                        .with_context(|| format!("grade {}, run {run}", grade.name));
                    progress.inc(1);
                    r
                })
                .collect()
        })
        .collect();
    progress.finish_and_clear();
    // Per grade, its runs in order.
    let mut per_run: Vec<Vec<RunResult>> = vec![Vec::new(); options.grades.len()];
    for result in results {
        for (g, r) in result?.into_iter().enumerate() {
            per_run[g].push(r);
        }
    }
    let per_grade: Vec<RunResult> = per_run
        .iter()
        .map(|runs| RunResult {
            samples: runs.iter().flat_map(|r| r.samples.clone()).collect(),
            skipped: runs.iter().map(|r| r.skipped).sum(),
        })
        .collect();
    let reference = &per_grade[0];
    let share = |f: fn(&OutageSample) -> bool| {
        reference.samples.iter().filter(|s| f(s)).count() as f64
            / reference.samples.len().max(1) as f64
    };
    let outages_per_run = outage_starts(
        options.seed,
        0,
        options.settle_s,
        end - longest - 1.0,
        options.outage_spacing_s,
    )
    .len();
    let grades = options
        .grades
        .iter()
        .zip(per_grade.iter().zip(&per_run))
        .map(|(grade, (runs, by_run))| {
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
                .enumerate()
                .map(|(k, &req)| bridge(by_run, k, req, longest, options.seed))
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

impl Bridge {
    /// "12.3 s [11.1, 13.6], ±5 % with 140 runs", or "≥ 60 s (the longest simulated outage)".
    pub fn text(&self) -> String {
        match (self.longest_s, self.beyond_horizon) {
            (None, _) => "no outage measured".to_string(),
            (Some(l), true) => format!("≥ {l:.0} s (within it for the whole longest simulated outage; simulate longer outages with --outages)"),
            (Some(l), false) => {
                let ci = self
                    .ci95_s
                    .map_or(String::new(), |[a, b]| format!(" [{a:.1}, {b:.1}]"));
                let runs = self
                    .runs_for_5pct
                    .map_or(String::new(), |n| format!(", ±5 % with {n} runs"));
                format!("{l:.1} s{ci}{runs}")
            }
        }
    }
}

impl StudyResult {
    /// Reads a study written by `imulab study --json`.
    pub fn from_json_file(path: &Path) -> anyhow::Result<StudyResult> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading study {}", path.display()))?;
        serde_json::from_str(&text).with_context(|| {
            format!(
                "{}: not a study written by `imulab study --json`",
                path.display()
            )
        })
    }

    /// The grade studied for `device`: named like it, or an Allan fit `FILE.json#device`.
    pub fn grade_for(&self, device: &str) -> Option<&GradeResult> {
        self.grades
            .iter()
            .find(|g| g.name == device || g.name.rsplit('#').next() == Some(device))
    }

    /// The horizontal requirements the grades were judged against, m (every grade has a
    /// bridge per requirement, in the same order).
    pub fn requirements_m(&self) -> Vec<f64> {
        self.grades.first().map_or_else(Vec::new, |g| {
            g.bridges.iter().map(|b| b.requirement_m).collect()
        })
    }

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
        for (k, req) in self.requirements_m().iter().enumerate() {
            let _ = writeln!(
                s,
                "Longest outage each grade bridges within {req} m (p95 drift of {n} outages over {} runs; 95 % interval over runs; runs for ±5 %):",
                self.runs
            );
            for g in &self.grades {
                let answer = g
                    .bridges
                    .get(k)
                    .map_or_else(|| "n/a".to_string(), Bridge::text);
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
