//! Runs a [`Scene`]: generates the truth block by block, advances every sensor's error
//! model over the block (IMUs in parallel, each on its own random streams, so results do
//! not depend on the thread count) and hands the records to a [`SimSink`].
//!
//! Only what the scene asks for is computed: a static scene evaluates its truth once and
//! integrates no trajectory, triads not listed in `channels` are skipped, GNSS is simulated
//! only for listed receivers, truth records only when `outputs` want them, and a constant
//! temperature is evaluated once.

use anyhow::{anyhow, bail, Context, Result};
use rayon::prelude::*;

use super::attitude::AttitudeProgram;
use super::gnss_model::GnssSimulator;
use super::imu_model::ImuSimulator;
use super::motion::{static_truth, MotionGenerator, TruthSample};
use super::outputs::SimSink;
use super::scene::{Motion, Scene, START_MONO_NS};
use super::truth_file::TruthFileReader;
use imulab_store::{EventKind, EventRecord, GnssRecord, ImuRecord, TruthImuRecord, TruthNavRecord};

/// Samples per block handed to the sink.
const BLOCK: usize = 4096;

/// What a run produced.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunStats {
    /// Truth/IMU epochs simulated.
    pub samples: u64,
    /// IMU records emitted (all IMUs, after drops).
    pub imu_records: u64,
    /// GNSS epochs emitted.
    pub gnss_records: u64,
}

enum TruthSource {
    Static(TruthSample),
    Generator(MotionGenerator),
    File(TruthFileReader),
    Attitude(AttitudeProgram, f64),
}

impl TruthSource {
    fn new(scene: &Scene) -> Result<Self> {
        let loc = &scene.location;
        Ok(match &scene.motion {
            Motion::Static { quat_nb } => TruthSource::Static(static_truth(
                loc.lat_deg.to_radians(),
                loc.lon_deg.to_radians(),
                loc.height_m,
                *quat_nb,
            )),
            Motion::Segments(spec) => {
                let generator =
                    MotionGenerator::new(spec, scene.rate_hz).map_err(|e| anyhow!("{e}"))?;
                let needed = scene.samples() as f64 / scene.rate_hz;
                if generator.duration_s() + 0.5 / scene.rate_hz < needed {
                    bail!(
                        "motion segments last {} s but duration_s is {} s: add a cruise or stop segment",
                        generator.duration_s(),
                        scene.duration_s
                    );
                }
                TruthSource::Generator(generator)
            }
            Motion::TruthFile(path) => {
                TruthSource::File(TruthFileReader::open(path, scene.rate_hz)?)
            }
            Motion::Tumble(spec) => TruthSource::Attitude(
                AttitudeProgram::tumble(spec, scene.seed, loc.lat_deg, loc.lon_deg, loc.height_m)
                    .map_err(|e| anyhow!("motion (tumble): {e}"))?,
                scene.rate_hz,
            ),
            Motion::RateTable(spec) => TruthSource::Attitude(
                AttitudeProgram::rate_table(spec, loc.lat_deg, loc.lon_deg, loc.height_m)
                    .map_err(|e| anyhow!("motion (rate_table): {e}"))?,
                scene.rate_hz,
            ),
        })
    }

    /// Fills `out` with the next `len` samples (static: leaves one sample, reused).
    fn fill(&mut self, out: &mut Vec<TruthSample>, first: u64, len: usize) -> Result<()> {
        out.clear();
        match self {
            TruthSource::Static(s) => out.push(*s),
            TruthSource::Generator(g) => {
                for _ in 0..len {
                    out.push(g.next().ok_or_else(|| anyhow!("motion ended early"))?);
                }
            }
            TruthSource::Attitude(program, rate_hz) => {
                out.extend((0..len).map(|i| program.at((first + i as u64) as f64 / *rate_hz)));
            }
            TruthSource::File(f) => {
                for i in 0..len {
                    let s = f.next_sample().ok_or_else(|| {
                        anyhow!(
                            "truth file ends after {} samples; the scene needs more",
                            first + i as u64
                        )
                    })??;
                    out.push(s);
                }
            }
        }
        Ok(())
    }
}

struct ImuRun {
    name: String,
    sim: ImuSimulator,
    records: Vec<ImuRecord>,
    truth: Vec<TruthImuRecord>,
}

/// Simulates `scene` into `sink`.
pub fn run(scene: &Scene, sink: &mut dyn SimSink) -> Result<RunStats> {
    let mut truth_source = TruthSource::new(scene)?;
    let mut imus: Vec<ImuRun> = scene
        .imus
        .iter()
        .map(|e| {
            Ok(ImuRun {
                name: e.name.clone(),
                sim: ImuSimulator::new(&e.spec, &e.name, scene.seed, scene.rate_hz, e.channels)
                    .map_err(|m| anyhow!("imu {}: {m}", e.name))?,
                records: Vec::with_capacity(BLOCK),
                truth: Vec::new(),
            })
        })
        .collect::<Result<_>>()?;
    let mut receivers: Vec<(String, GnssSimulator, u64)> = scene
        .gnss
        .iter()
        .map(|e| {
            let every = (scene.rate_hz / e.spec.rate_hz).round() as u64;
            GnssSimulator::new(&e.spec, &e.name, scene.seed)
                .map(|g| (e.name.clone(), g, every.max(1)))
                .map_err(|m| anyhow!("gnss {}: {m}", e.name))
        })
        .collect::<Result<_>>()?;
    let outputs = scene.outputs;
    let truth_every = u64::from(outputs.truth_every);
    let constant_temp = scene
        .temperature
        .is_constant()
        .then(|| scene.temperature.at(0.0));
    let wall0 = scene.start_wall_ns;
    let samples = scene.samples();
    let mut stats = RunStats {
        samples,
        ..RunStats::default()
    };
    sink.event(&EventRecord {
        t_mono_ns: START_MONO_NS,
        t_wall_ns: wall0,
        device: String::new(),
        kind: EventKind::SessionStart,
        detail: format!("simulated scene, seed {}", scene.seed),
    })?;

    let mut truth = Vec::with_capacity(BLOCK);
    let mut temps = Vec::with_capacity(BLOCK);
    let mut nav = Vec::new();
    let mut fixes: Vec<Vec<GnssRecord>> = vec![Vec::new(); receivers.len()];
    let rotation_ns = sink
        .rotation_period()
        .map(|p| i64::try_from(p.as_nanos()).unwrap_or(i64::MAX).max(1));
    let mut first = 0u64;
    while first < samples {
        let len = (samples - first).min(BLOCK as u64) as usize;
        truth_source
            .fill(&mut truth, first, len)
            .with_context(|| format!("truth at sample {first}"))?;
        temps.clear();
        if constant_temp.is_none() {
            temps.extend((0..len).map(|i| {
                scene
                    .temperature
                    .at((first + i as u64) as f64 / scene.rate_hz)
            }));
        }
        let truth_at = |i: usize| -> &TruthSample { truth.get(i).unwrap_or(&truth[0]) };
        let temp_at = |i: usize| constant_temp.unwrap_or_else(|| temps[i]);

        let advance = |imu: &mut ImuRun| {
            imu.records.clear();
            imu.truth.clear();
            for i in 0..len {
                let t = truth_at(i);
                let epoch = imu
                    .sim
                    .step(&t.gyro_b, &t.accel_b, temp_at(i), START_MONO_NS, wall0);
                if let Some(r) = epoch.record {
                    imu.records.push(r);
                }
                if outputs.truth_imu && (first + i as u64).is_multiple_of(truth_every) {
                    imu.truth.push(epoch.truth);
                }
            }
        };
        if imus.len() > 1 {
            imus.par_iter_mut().for_each(advance);
        } else {
            imus.iter_mut().for_each(advance);
        }

        if outputs.truth_nav {
            nav.clear();
            for i in 0..len {
                let k = first + i as u64;
                if !k.is_multiple_of(truth_every) {
                    continue;
                }
                let t = truth_at(i);
                let q = t.quat_nb.quaternion();
                nav.push(TruthNavRecord {
                    t_mono_ns: START_MONO_NS + sample_ns(k, scene.rate_hz),
                    lat_deg: t.lat_rad.to_degrees(),
                    lon_deg: t.lon_rad.to_degrees(),
                    height_m: t.height_m,
                    vel_ned: t.vel_ned.into(),
                    quat_nb: [q.w, q.i, q.j, q.k],
                });
            }
        }
        for ((_, sim, every), fixes) in receivers.iter_mut().zip(&mut fixes) {
            fixes.clear();
            for i in 0..len {
                let k = first + i as u64;
                if k.is_multiple_of(*every) {
                    let t = TruthSample {
                        t_s: k as f64 / scene.rate_hz,
                        ..*truth_at(i)
                    };
                    fixes.push(sim.epoch(&t, START_MONO_NS, wall0));
                }
            }
            stats.gnss_records += fixes.len() as u64;
        }
        for imu in &imus {
            stats.imu_records += imu.records.len() as u64;
        }
        // The rows before each rotation time in this block, then the rest (see `SimSink`):
        // every table's rows of one file's span reach the sink before any row of the next,
        // so the 4096-sample blocks do not decide where files end.
        let mut from = i64::MIN;
        for to in rotation_times(rotation_ns, block_span(&nav, &imus, &fixes))
            .chain(std::iter::once(i64::MAX))
        {
            if outputs.truth_nav {
                sink.truth_nav(between(&nav, |r| r.t_mono_ns, from, to))?;
            }
            for imu in &imus {
                sink.imu(&imu.name, between(&imu.records, |r| r.t_mono_ns, from, to))?;
                if outputs.truth_imu {
                    sink.truth_imu(&imu.name, between(&imu.truth, |r| r.t_mono_ns, from, to))?;
                }
            }
            for ((name, _, _), fixes) in receivers.iter().zip(&fixes) {
                sink.gnss(name, between(fixes, |r| r.t_mono_ns, from, to))?;
            }
            from = to;
        }
        first += len as u64;
    }
    let end_ns = sample_ns(samples, scene.rate_hz);
    sink.event(&EventRecord {
        t_mono_ns: START_MONO_NS + end_ns,
        t_wall_ns: wall0 + end_ns,
        device: String::new(),
        kind: EventKind::SessionStop,
        detail: format!(
            "{} samples, {} IMU records, {} GNSS epochs",
            stats.samples, stats.imu_records, stats.gnss_records
        ),
    })?;
    Ok(stats)
}

/// The rows of the time-ordered `rows` with `from <= t < to`.
fn between<R>(rows: &[R], t: impl Fn(&R) -> i64, from: i64, to: i64) -> &[R] {
    let start = rows.partition_point(|r| t(r) < from);
    let end = rows.partition_point(|r| t(r) < to).max(start);
    &rows[start..end]
}

/// Earliest and latest row time of a block, over every table.
fn block_span(
    nav: &[TruthNavRecord],
    imus: &[ImuRun],
    fixes: &[Vec<GnssRecord>],
) -> Option<(i64, i64)> {
    /// First and last time of time-ordered rows.
    fn ends<R>(rows: &[R], t: impl Fn(&R) -> i64) -> Option<(i64, i64)> {
        Some((t(rows.first()?), t(rows.last()?)))
    }
    std::iter::once(ends(nav, |r| r.t_mono_ns))
        .chain(imus.iter().flat_map(|imu| {
            [
                ends(&imu.records, |r| r.t_mono_ns),
                ends(&imu.truth, |r| r.t_mono_ns),
            ]
        }))
        .chain(fixes.iter().map(|f| ends(f, |r| r.t_mono_ns)))
        .flatten()
        .reduce(|(lo, hi), (a, b)| (lo.min(a), hi.max(b)))
}

/// The rotation times `START_MONO_NS + k × period` (k ≥ 1) in `(lo, hi]` of `span`.
fn rotation_times(period_ns: Option<i64>, span: Option<(i64, i64)>) -> impl Iterator<Item = i64> {
    let (first_k, last_k, period) = match (period_ns, span) {
        (Some(p), Some((lo, hi))) => (
            (lo.saturating_sub(START_MONO_NS)).div_euclid(p).max(0) + 1,
            (hi.saturating_sub(START_MONO_NS)).div_euclid(p),
            p,
        ),
        _ => (1, 0, 1),
    };
    (first_k..=last_k).map(move |k| START_MONO_NS.saturating_add(k.saturating_mul(period)))
}

fn sample_ns(k: u64, rate_hz: f64) -> i64 {
    (k as f64 / rate_hz * 1e9).round() as i64
}
