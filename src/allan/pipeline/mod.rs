//! The Allan analysis of whole inputs, as `imulab allan`, `report` and `compare` run it: open
//! each input (a session's IMUs, a bag's topic, a CSV/TSV or .npy file), decide its timing,
//! temperature and analysed channels ([`plan`]), read the axes in as few passes as the memory
//! budget allows, analyse them in parallel (with the thermal summary and per-plateau curves
//! when a temperature is read) and assemble one [`AllanReport`].
//!
//! Corrections this crate does not know (calibration, thermal compensation) plug in through
//! [`Corrections`]; the command line only parses arguments and prints.

mod plan;

use crate::analysis::{analyse_axis, AllanReport, AnalysisOptions, AxisResult};
use crate::bag_source::BagSource;
use crate::columns::{looks_like_column_group, parse_column_groups};
use crate::input::{open_file, read_axes, AxisSeries, DataKind, GapPolicy, SampleSource, Timing};
use crate::session_source::SessionSource;
use crate::thermal::{bias_versus_temperature, find_plateaus};
use crate::timings::Stage;
use crate::units::{RateUnit, SensorKind};
use crate::{DeviationKind, TauGrid};
use anyhow::bail;
use plan::{expand_sessions, plan_file, session_axes, PlannedInput};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// How to read the inputs and what to compute (the command-line options of `imulab allan`,
/// `report` and `compare`).
#[derive(clap::Args, Debug, Clone)]
pub struct Options {
    /// Session: the IMU device to analyse (default: the only one). Files: the device name
    /// in reports (default: the file's stem).
    #[arg(long)]
    pub device: Option<String>,
    /// Bag (ROS 1 .bag, ROS 2 MCAP): the sensor_msgs/Imu topic to analyse (default: the
    /// only one). Without it, or with one the bag lacks, the bag's topics are listed.
    #[arg(long)]
    pub topic: Option<String>,
    /// Session: start of the analysed range, seconds after the device's first sample.
    #[arg(long)]
    pub from: Option<f64>,
    /// Session: end of the analysed range, seconds after the device's first sample.
    #[arg(long)]
    pub to: Option<f64>,
    /// Sensor type of the channels (decides engineering units; implied by --units).
    #[arg(long, value_enum)]
    pub sensor: Option<SensorKind>,
    /// Channels to analyse, by name or 0-based index (default: every column that is not
    /// the time or the temperature by name; see docs/allan.md). With a session: x, y, z (of
    /// --sensor, default both sensors) or gyro_x … accel_z.
    #[arg(long, value_delimiter = ',')]
    pub axes: Vec<String>,
    /// Unit (and so sensor) per column: NAMES=UNIT, one group per occurrence or several in
    /// one quoted value, e.g. `--columns gx,gy,gz=deg/s --columns ax,ay,az=g` or
    /// `--columns 'gx,gy,gz=deg/s ax,ay,az=g'`. Columns not named take --units.
    #[arg(long, value_name = "NAMES=UNIT")]
    pub columns: Vec<String>,
    /// Deviation type.
    #[arg(long, value_enum, default_value = "oadev")]
    pub kind: DeviationKind,
    /// τ grid: octave, decade, dense:N (N per decade), all, or a list of taus in seconds.
    #[arg(long, default_value = "octave")]
    pub taus: TauGrid,
    /// Sample rate in Hz. τ0 is then 1/rate; a time column, if any, is checked against it
    /// (and its unit inferred from it) but not analysed.
    #[arg(long)]
    pub rate: Option<f64>,
    /// Channel with time stamps (name or index; default: the column named like a time,
    /// see docs/allan.md); without --rate, τ0 is the median interval.
    #[arg(long)]
    pub time_column: Option<String>,
    /// Unit of the time column: s, ms, us or ns (default: from its name, else inferred
    /// from its median step, with a warning when ambiguous).
    #[arg(long)]
    pub time_unit: Option<String>,
    /// Unit of the samples: rad/s, deg/s, deg/h, m/s2, g, mg, or none (results stay in input units).
    #[arg(long, default_value = "none")]
    pub units: RateUnit,
    /// Samples are rates/fractional frequency (default) or phase.
    #[arg(long, value_enum, default_value = "rate")]
    pub data: DataKind,
    /// What to do about gaps, NaN/Inf and non-uniform sampling (default: refuse).
    #[arg(long, value_enum, default_value = "error")]
    pub gaps: GapPolicy,
    /// Fit the IMU noise model (ADEV/OADEV/TOTDEV).
    #[arg(long)]
    pub fit: bool,
    /// Temperature channel (name or index) for bias-versus-temperature.
    #[arg(long)]
    pub temperature_column: Option<String>,
    /// Temperature bin width in °C.
    #[arg(long, default_value_t = 5.0)]
    pub temperature_bin: f64,
    /// Also compute one curve per temperature plateau (stepped profiles).
    #[arg(long)]
    pub plateaus: bool,
    /// Settling time excluded at the start of each plateau, seconds.
    #[arg(long, default_value_t = 600.0)]
    pub settling: f64,
    /// Memory for samples, in MiB: axes of one input are read together in one pass while
    /// they fit, otherwise one axis per pass (memory then follows the longest axis).
    #[arg(long, default_value_t = 1024)]
    pub memory_mib: u64,
}

/// Corrections applied to the data before the analysis, by models above this crate.
pub trait Corrections: Sync {
    /// Wraps an opened input named `device` (e.g. a calibration); `si` says its channels are in
    /// rad/s and m/s².
    fn correct_source(
        &self,
        source: Box<dyn SampleSource>,
        device: &str,
        si: bool,
    ) -> anyhow::Result<Box<dyn SampleSource>> {
        let _ = (device, si);
        Ok(source)
    }

    /// Adjusts one read axis of `device` before its analysis (e.g. a thermal compensation);
    /// `to_si` converts its samples to SI. Returns a warning to show, if any.
    fn compensate(
        &self,
        device: &str,
        series: &mut AxisSeries,
        to_si: f64,
    ) -> anyhow::Result<Option<String>> {
        let _ = (device, series, to_si);
        Ok(None)
    }

    /// Whether [`Corrections::compensate`] needs the temperature channel (a session's `temp`
    /// is then read unless another is named).
    fn needs_temperature(&self) -> bool {
        false
    }
}

/// No correction: the data as recorded.
pub struct AsRecorded;

impl Corrections for AsRecorded {}

/// Told how the analysis advances (the command line draws a progress bar from it).
pub trait Progress {
    /// The number of axes to analyse, once the inputs are planned.
    fn planned(&mut self, axes: usize) {
        let _ = axes;
    }
    /// One axis (`device axis`) is analysed.
    fn analysed(&mut self, label: &str) {
        let _ = label;
    }
}

impl Progress for () {}

/// Opens an input path: a session directory (one IMU of it: `device`, or its only one) or a
/// plain file.
pub fn open_input(
    path: &Path,
    device: Option<&str>,
    args: &Options,
    corrections: &dyn Corrections,
) -> anyhow::Result<Box<dyn SampleSource>> {
    let source: Box<dyn SampleSource> = if imulab_bag::looks_like_bag(path) {
        if args.from.is_some() || args.to.is_some() {
            bail!("--from/--to select a time range of a session; import the bag (imulab import) to use them");
        }
        Box::new(BagSource::open(path, args.topic.as_deref())?)
    } else if args.topic.is_some() {
        bail!(
            "{}: --topic selects a topic of a ROS bag or MCAP file",
            path.display()
        );
    } else if path.is_dir() {
        Box::new(SessionSource::open(path, device, args.from, args.to)?)
    } else {
        if args.from.is_some() || args.to.is_some() {
            bail!("--from/--to select a time range of a session; for files, cut the file instead");
        }
        open_file(path)?
    };
    let name = device_name(source.as_ref(), path, args);
    // A session's channels are SI; a file's are when no other unit is given for them.
    let si = path.is_dir()
        || (matches!(
            args.units,
            RateUnit::Unspecified | RateUnit::RadPerSecond | RateUnit::MetrePerSecondSquared
        ) && args.columns.is_empty());
    corrections.correct_source(source, &name, si)
}

/// The device an input's results are named by: a session's IMU, else `--device`, else the
/// file's stem.
fn device_name(source: &dyn SampleSource, path: &Path, args: &Options) -> String {
    match source.as_any_session() {
        Some(device) => device.to_string(),
        None => args.device.clone().unwrap_or_else(|| {
            path.file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "device".into())
        }),
    }
}

/// Reads and analyses every selected axis of every input, one axis in memory at a time.
pub fn analyse_inputs(
    inputs: &[PathBuf],
    args: &Options,
    corrections: &dyn Corrections,
    progress: &mut dyn Progress,
) -> anyhow::Result<AllanReport> {
    if args.fit && !args.kind.is_allan_variance() {
        bail!(
            "--fit needs --kind adev, oadev or totdev (the noise model is an Allan-variance model)"
        );
    }
    if !(args.temperature_bin.is_finite() && args.temperature_bin > 0.0) {
        bail!("--temperature-bin must be a positive number of °C");
    }
    for path in inputs {
        let word = path.to_string_lossy();
        if !path.exists() && looks_like_column_group(&word) {
            bail!(
                "`{word}` is not a file but looks like a --columns group: --columns takes one group per occurrence (--columns gx,gy,gz=deg/s --columns ax,ay,az=g) or several in one quoted value (--columns 'gx,gy,gz=deg/s ax,ay,az=g')"
            );
        }
    }
    let sensor = args.sensor.or(args.units.sensor());
    let planning = Stage::start(|| "open and plan".into());
    let mut plan: Vec<PlannedInput> = Vec::new();
    for (path, device) in expand_sessions(inputs, args)? {
        let path = &path;
        let source = open_input(path, device.as_deref(), args, corrections)?;
        // Sessions and bags carry their own timing and units.
        let is_session = source.native_timing().is_some();
        let (timing, temperature, axes) = if is_session {
            if args.rate.is_some() || args.time_column.is_some() {
                bail!(
                    "{}: a session carries its own time stamps; drop --rate/--time-column",
                    path.display()
                );
            }
            let channel = source.channel_index("t")?;
            let timing = source.native_timing().unwrap_or(Timing::ArrivalTimes {
                channel,
                scale: 1.0,
            });
            // Compensation needs the temperature: a session's `temp` unless another is named.
            let temperature_column = match &args.temperature_column {
                None if corrections.needs_temperature() => Some("temp"),
                column => column.as_deref(),
            };
            let temperature = temperature_column
                .map(|c| source.channel_index(c))
                .transpose()?;
            let axes = session_axes(args)
                .iter()
                .map(|a| {
                    let c = source.channel_index(a)?;
                    // A session knows its channels' units, overriding --units.
                    let unit = source.channel_unit(c).unwrap_or(args.units);
                    let kind = if source.channel_unit(c).is_some() {
                        unit.sensor()
                    } else {
                        sensor
                    };
                    Ok((c, unit, kind))
                })
                .collect::<Result<Vec<_>, crate::input::InputError>>()?;
            (timing, temperature, axes)
        } else {
            plan_file(path, source.as_ref(), args)?
        };
        if axes.is_empty() {
            bail!("{}: no channels to analyse", path.display());
        }
        let device = device_name(source.as_ref(), path, args);
        plan.push(PlannedInput {
            path: path.clone(),
            source,
            axes,
            timing,
            temperature,
            device,
        });
    }
    let files: Vec<&PlannedInput> = plan
        .iter()
        .filter(|p| p.source.native_timing().is_none())
        .collect();
    for group in parse_column_groups(&args.columns).map_err(|e| anyhow::anyhow!(e))? {
        for c in &group.columns {
            if !files.iter().any(|p| p.source.channel_index(c).is_ok()) {
                let listed: Vec<String> = files
                    .iter()
                    .map(|p| format!("{}: {}", p.path.display(), p.source.channels().join(", ")))
                    .collect();
                bail!(
                    "--columns: no input has a column `{c}` ({})",
                    listed.join("; ")
                );
            }
        }
    }
    drop(planning);
    progress.planned(plan.iter().map(|p| p.axes.len()).sum());
    let mut results = Vec::new();
    for PlannedInput {
        path,
        source,
        axes,
        timing,
        temperature,
        device,
    } in &plan
    {
        let per_pass = axes_per_pass(source.row_count_hint(), args.memory_mib);
        for group in axes.chunks(per_pass) {
            let channels: Vec<usize> = group.iter().map(|a| a.0).collect();
            let reading = Stage::start(|| format!("read {}", path.display()));
            let mut series = read_axes(
                source.as_ref(),
                &channels,
                timing,
                args.gaps,
                args.data,
                *temperature,
            )
            .map_err(|e| anyhow::anyhow!(e).context(format!("reading {}", path.display())))?;
            drop(reading);
            for (&(_, unit, _), s) in group.iter().zip(series.iter_mut()) {
                if let Some(w) = corrections.compensate(device, s, unit.to_si())? {
                    tracing::warn!("{w}");
                }
            }
            let jobs: Vec<(AxisSeries, AnalysisOptions)> = group
                .iter()
                .zip(series)
                .map(|(&(_, unit, sensor), series)| {
                    let options = AnalysisOptions {
                        kind: args.kind,
                        grid: args.taus.clone(),
                        fit: args.fit,
                        unit,
                        sensor,
                    };
                    (series, options)
                })
                .collect();
            let names: Vec<String> = jobs.iter().map(|(s, _)| s.name.clone()).collect();
            // Axes in parallel as well as τ within each axis; results keep the axis order.
            let analysed: Vec<Vec<AxisResult>> = jobs
                .into_par_iter()
                .map(|(series, options)| analyse_with_thermal(device, series, &options, args))
                .collect();
            for (name, result) in names.into_iter().zip(analysed) {
                progress.analysed(&format!("{device} {name}"));
                results.extend(result);
            }
        }
    }
    Ok(AllanReport::new(
        inputs.iter().map(|p| p.display().to_string()).collect(),
        args.kind,
        &grid_label(&args.taus),
        results,
    ))
}

/// How many axes one reading pass may hold: all of them while their samples (8 bytes per
/// row each) and the analysis's decimation buffer (half an axis, see
/// [`crate::numerics::for_each_decimation`]) fit in `memory_mib`, at least one. Unknown lengths read
/// one axis per pass.
fn axes_per_pass(rows: Option<u64>, memory_mib: u64) -> usize {
    let Some(rows) = rows else { return 1 };
    let budget = memory_mib.saturating_mul(1 << 20);
    let axis_bytes = rows.saturating_mul(12).max(1);
    usize::try_from(budget / axis_bytes)
        .unwrap_or(usize::MAX)
        .max(1)
}

fn grid_label(grid: &TauGrid) -> String {
    match grid {
        TauGrid::Octave => "octave".into(),
        TauGrid::Decade => "decade".into(),
        TauGrid::Dense(n) => format!("dense:{n}"),
        TauGrid::All => "all".into(),
        TauGrid::List(l) => l
            .iter()
            .map(|t| t.to_string())
            .collect::<Vec<_>>()
            .join(","),
    }
}

/// The axis itself plus, with a temperature channel, its thermal summary and (with
/// `--plateaus`) one extra result per temperature plateau.
fn analyse_with_thermal(
    device: &str,
    mut series: AxisSeries,
    options: &AnalysisOptions,
    args: &Options,
) -> Vec<AxisResult> {
    let Some(temps) = series.temperature.take() else {
        return vec![analyse_axis(device, series, options)];
    };
    let rate: Vec<f64> = series.segments.concat();
    let mut thermal = bias_versus_temperature(&rate, &temps, args.temperature_bin);
    let mut extra = Vec::new();
    if args.plateaus {
        let settling = (args.settling / series.tau0).round() as usize;
        let min_len = settling.max((600.0 / series.tau0) as usize);
        thermal.plateaus = find_plateaus(&temps, 0.5, min_len, settling);
        for p in &thermal.plateaus {
            let piece = AxisSeries {
                name: format!("{} @ {:.1} °C", series.name, p.temperature),
                tau0: series.tau0,
                segments: vec![rate[p.start..p.end].to_vec()],
                temperature: None,
                health: crate::input::Health {
                    samples: (p.end - p.start) as u64,
                    duration_s: (p.end - p.start) as f64 * series.tau0,
                    segments: 1,
                    first_problem: Some(format!(
                        "plateau: samples {}..{}, first {} samples ({} s) excluded as settling",
                        p.start, p.end, p.settling_samples, args.settling
                    )),
                    ..series.health.clone()
                },
            };
            extra.push(analyse_axis(device, piece, options));
        }
    }
    drop(rate);
    let mut main = analyse_axis(device, series, options);
    main.thermal = Some(thermal);
    let mut out = vec![main];
    out.extend(extra);
    out
}
