//! `imulab allan`: Allan-family deviations with confidence intervals, noise-term fit,
//! thermal summary and JSON/CSV/HTML/PNG/Kalibr/MATLAB outputs, from plain files
//! (CSV/TSV, .npy). The input options are shared with `imulab report` and `imulab compare`.

use crate::allan::analysis::{analyse_axis, AllanReport, AnalysisOptions, AxisResult};
use crate::allan::bag_source::BagSource;
use crate::allan::columns::{
    detect_layout, fmt_sig, infer_time_unit, looks_like_column_group, median_step,
    parse_column_groups, role_of, unit_of_name, ColumnRole, TimeUnit,
};
use crate::allan::input::{
    open_file, read_axes, AxisSeries, DataKind, GapPolicy, SampleSource, Timing,
};
use crate::allan::session_source::SessionSource;
use crate::allan::thermal::{bias_versus_temperature, find_plateaus};
use crate::allan::timings::Stage;
use crate::allan::units::{RateUnit, SensorKind};
use crate::allan::{export, DeviationKind, TauGrid};
use crate::report;
use anyhow::{bail, Context};
use rayon::prelude::*;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Options that say how to read inputs and what to compute (shared by allan/report/compare).
#[derive(clap::Args, Debug, Clone)]
pub struct AnalysisArgs {
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
    /// Subtract the bias(T) of this thermal model (`imulab thermal --model`, docs/thermal.md)
    /// from every sample before the analysis, using the temperature channel.
    #[arg(long)]
    pub compensate: Option<PathBuf>,
    /// Correct the gyro and accel channels with this calibration file (`imulab calibrate`,
    /// docs/calibration.md) before the analysis (and before --compensate). Files need
    /// columns named gyro_x … accel_z in rad/s and m/s².
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example: imulab allan gyro.csv --time-column t --axes gx,gy,gz --units rad/s --fit --taus dense:10 --json out.json --html out.html"
)]
pub struct AllanArgs {
    /// Inputs: session directories, CSV/TSV/semicolon/space-aligned files (header optional)
    /// or NumPy .npy files (N or N×k); one device each (a session: every IMU in it).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    #[command(flatten)]
    pub analysis: AnalysisArgs,
    /// Write the JSON document (schema: docs/allan.md).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write a CSV table (one row per axis and τ).
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Write a self-contained HTML report.
    #[arg(long)]
    pub html: Option<PathBuf>,
    /// Write a PNG plot.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Write a Kalibr imu.yaml (needs --fit).
    #[arg(long)]
    pub kalibr: Option<PathBuf>,
    /// Write MATLAB imuSensor parameters as a .m script (needs --fit).
    #[arg(long)]
    pub matlab: Option<PathBuf>,
}

pub fn run(args: AllanArgs) -> anyhow::Result<()> {
    if args.analysis.device.is_some() && args.inputs.len() > 1 {
        bail!("--device names a single input; with several inputs the file names are used");
    }
    let _whole = Stage::start(|| "allan command".into());
    let report = analyse_inputs(&args.inputs, &args.analysis)?;
    let output = Stage::start(|| "output".into());
    print!("{}", summary_text(&report, true));
    for path in write_outputs(&report, &args)? {
        println!("wrote {}", path.display());
    }
    drop(output);
    Ok(())
}

/// Writes the requested outputs; returns the paths written.
fn write_outputs(report: &AllanReport, args: &AllanArgs) -> anyhow::Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    if let Some(path) = &args.json {
        let file =
            std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        serde_json::to_writer_pretty(std::io::BufWriter::new(file), report)?;
        written.push(path.clone());
    }
    if let Some(path) = &args.csv {
        report::write_csv(report, path).with_context(|| format!("writing {}", path.display()))?;
        written.push(path.clone());
    }
    if let Some(path) = &args.html {
        std::fs::write(path, report::html_report(report, "Allan analysis"))
            .with_context(|| format!("writing {}", path.display()))?;
        written.push(path.clone());
    }
    if let Some(path) = &args.png {
        report::write_png(report, path).with_context(|| format!("writing {}", path.display()))?;
        written.push(path.clone());
    }
    if (args.kalibr.is_some() || args.matlab.is_some()) && !args.analysis.fit {
        bail!("--kalibr and --matlab export fitted terms: add --fit");
    }
    if let Some(path) = &args.kalibr {
        std::fs::write(path, export::kalibr_yaml(&report.axes, "/imu0"))
            .with_context(|| format!("writing {}", path.display()))?;
        written.push(path.clone());
    }
    if let Some(path) = &args.matlab {
        std::fs::write(path, export::matlab_imu_sensor(&report.axes))
            .with_context(|| format!("writing {}", path.display()))?;
        written.push(path.clone());
    }
    Ok(written)
}

/// Terminal summary: per axis one line, with `curves` followed by its τ table; then the
/// datasheet table if fitted.
pub fn summary_text(report: &AllanReport, curves: bool) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    if !curves {
        out.push_str(&device_lines(report));
    }
    for a in report.axes.iter().filter(|_| curves) {
        let _ = writeln!(
            out,
            "{} {} ({}; {} samples, tau0 {} s, gaps policy {:?}, {} gap(s) found on the {}){}",
            a.device,
            a.axis,
            a.curve.kind.name(),
            a.health.samples,
            fmt_sig(a.tau0),
            a.health.policy.unwrap_or_default(),
            a.health.gaps,
            a.health.clock.as_deref().unwrap_or("time stamps"),
            if curves { ":" } else { "" }
        );
        if let Some(t) = &a.thermal {
            if let Some(line) = report::thermal_coefficient_text(a, t) {
                let _ = writeln!(out, "  {line}");
            }
        }
        if let Some(e) = &a.fit_error {
            let _ = writeln!(out, "  fit: {e}");
        }
        let deviation = format!("dev [{}]", report::deviation_unit(a));
        let _ = writeln!(
            out,
            "  {:>12} {:>12} {:>12} {:>12} {:>9} {:>5}",
            "tau [s]", deviation, "low", "high", "edf", "alpha"
        );
        for p in &a.curve.points {
            let f = |v: Option<f64>| v.map(|v| format!("{v:.5e}")).unwrap_or_else(|| "-".into());
            let _ = writeln!(
                out,
                "  {:>12.5e} {:>12.5e} {:>12} {:>12} {:>9} {:>5}",
                p.tau,
                p.deviation,
                f(p.low),
                f(p.high),
                p.edf
                    .map(|e| format!("{e:.1}"))
                    .unwrap_or_else(|| "-".into()),
                p.alpha
            );
        }
    }
    if report.axes.iter().any(|a| a.fit.is_some()) {
        let axes: Vec<&AxisResult> = report.axes.iter().collect();
        let _ = writeln!(out, "\nNoise terms:");
        out.push_str(&report::datasheet_table_text(&axes));
    }
    out
}

/// One line per device (axes, samples, τ0, gaps and the clock they were found on), then
/// per axis only what needs saying: a fit that failed, a thermal coefficient.
fn device_lines(report: &AllanReport) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let mut devices: Vec<&str> = Vec::new();
    for a in &report.axes {
        if !devices.contains(&a.device.as_str()) {
            devices.push(&a.device);
        }
    }
    for device in devices {
        let axes: Vec<&AxisResult> = report.axes.iter().filter(|a| a.device == device).collect();
        let names: Vec<&str> = axes.iter().map(|a| a.axis.as_str()).collect();
        let samples: u64 = axes.iter().map(|a| a.health.samples).max().unwrap_or(0);
        let gaps: u64 = axes.iter().map(|a| a.health.gaps).sum();
        let first = axes[0];
        let _ = writeln!(
            out,
            "{device}: {} ({}), {samples} samples, tau0 {} s, {gaps} gap(s) found on the {}",
            names.join(", "),
            first.curve.kind.name(),
            fmt_sig(first.tau0),
            first.health.clock.as_deref().unwrap_or("time stamps")
        );
        for a in axes {
            if let Some(line) = a
                .thermal
                .as_ref()
                .and_then(|t| report::thermal_coefficient_text(a, t))
            {
                let _ = writeln!(out, "  {}: {line}", a.axis);
            }
            if let Some(e) = &a.fit_error {
                let _ = writeln!(out, "  {}: fit: {e}", a.axis);
            }
        }
    }
    out
}

/// Shows a progress bar on stderr once the work has taken more than a second, and only
/// when stderr is a terminal.
struct Progress {
    bar: indicatif::ProgressBar,
    started: Instant,
    visible: bool,
    terminal: bool,
}

impl Progress {
    fn new(total: u64) -> Self {
        let bar = indicatif::ProgressBar::with_draw_target(
            Some(total),
            indicatif::ProgressDrawTarget::hidden(),
        );
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} {msg}",
        ) {
            bar.set_style(style);
        }
        Progress {
            bar,
            started: Instant::now(),
            visible: false,
            terminal: std::io::stderr().is_terminal(),
        }
    }

    fn step(&mut self, message: String) {
        if self.terminal && !self.visible && self.started.elapsed() > Duration::from_secs(1) {
            self.bar
                .set_draw_target(indicatif::ProgressDrawTarget::stderr());
            self.visible = true;
        }
        self.bar.set_message(message);
        self.bar.inc(1);
    }

    fn finish(self) {
        self.bar.finish_and_clear();
    }
}

/// Opens an input path: a session directory (one IMU of it: `device`, or its only one) or a
/// plain file.
pub fn open_input(
    path: &Path,
    device: Option<&str>,
    args: &AnalysisArgs,
) -> anyhow::Result<Box<dyn SampleSource>> {
    let source: Box<dyn SampleSource> = if crate::bag::looks_like_bag(path) {
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
    let Some(cal_path) = &args.calibration else {
        return Ok(source);
    };
    let name = match source.as_any_session() {
        Some(d) => d.to_string(),
        None => args.device.clone().unwrap_or_else(|| {
            path.file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "device".into())
        }),
    };
    let corrector =
        crate::calib::Corrector::new(&crate::calib::Calibration::load(cal_path)?, &name)?;
    // A session's channels are SI; a file's are when no other unit is given for them.
    let si = path.is_dir()
        || (matches!(
            args.units,
            RateUnit::Unspecified | RateUnit::RadPerSecond | RateUnit::MetrePerSecondSquared
        ) && args.columns.is_empty());
    Ok(Box::new(crate::calib::source::CalibratedSource::new(
        source, corrector, si,
    )?))
}

/// Session channel names for `--axes`/`--sensor`.
fn session_axes(args: &AnalysisArgs) -> Vec<String> {
    let sensors: Vec<&str> = match args.sensor {
        Some(SensorKind::Gyro) => vec!["gyro"],
        Some(SensorKind::Accel) => vec!["accel"],
        None => vec!["gyro", "accel"],
    };
    let axes: Vec<String> = if args.axes.is_empty() {
        vec!["x".into(), "y".into(), "z".into()]
    } else {
        args.axes.clone()
    };
    sensors
        .iter()
        .flat_map(|s| {
            axes.iter().map(move |a| {
                if a.contains('_') {
                    a.clone()
                } else {
                    format!("{s}_{a}")
                }
            })
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold(Vec::new(), |mut acc, a| {
            if !acc.contains(&a) {
                acc.push(a);
            }
            acc
        })
}

/// Pairs each input with the IMU to read from it: `--device` when given, otherwise every IMU
/// of a session (so `imulab report SESSION` compares all of them), and none for plain files.
fn expand_sessions(
    inputs: &[PathBuf],
    args: &AnalysisArgs,
) -> anyhow::Result<Vec<(PathBuf, Option<String>)>> {
    let mut out = Vec::new();
    for path in inputs {
        if !path.is_dir() || args.device.is_some() || crate::bag::looks_like_bag(path) {
            out.push((path.clone(), args.device.clone()));
            continue;
        }
        let session = crate::store::Session::open(path)?;
        let imus: Vec<String> = session
            .devices()
            .iter()
            .filter(|d| d.kind == crate::store::DeviceKind::Imu)
            .map(|d| d.name.clone())
            .collect();
        if imus.is_empty() {
            bail!("{}: this session has no IMU to analyse", path.display());
        }
        out.extend(imus.into_iter().map(|d| (path.clone(), Some(d))));
    }
    Ok(out)
}

/// One opened input with its resolved channels.
struct PlannedInput {
    path: PathBuf,
    source: Box<dyn SampleSource>,
    axes: Vec<PlannedAxis>,
    timing: Timing,
    temperature: Option<usize>,
    device: String,
}

/// An analysed channel with its unit and sensor.
type PlannedAxis = (usize, RateUnit, Option<SensorKind>);

/// Rows read to find the median step of a time column.
const TIME_PROBE_ROWS: usize = 20_000;

/// The first values of channel `channel` (at most [`TIME_PROBE_ROWS`]).
fn probe_channel(source: &dyn SampleSource, channel: usize) -> anyhow::Result<Vec<f64>> {
    let mut values = Vec::with_capacity(TIME_PROBE_ROWS);
    let result = source.for_each_row(&[channel], &mut |_, v| {
        values.push(v[0]);
        if values.len() >= TIME_PROBE_ROWS {
            return Err(crate::allan::input::InputError::Stopped);
        }
        Ok(())
    });
    match result {
        Ok(()) | Err(crate::allan::input::InputError::Stopped) => Ok(values),
        Err(e) => Err(e.into()),
    }
}

/// Timing, temperature and analysed channels of a plain file: roles by column name (see
/// [`crate::allan::columns`]) unless the options name them, units per column.
fn plan_file(
    path: &Path,
    source: &dyn SampleSource,
    args: &AnalysisArgs,
) -> anyhow::Result<(Timing, Option<usize>, Vec<PlannedAxis>)> {
    let file = path.display();
    let names = source.channels().to_vec();
    let layout = detect_layout(&names);
    let named_unit = |i: usize| match role_of(&names[i]) {
        ColumnRole::Time(unit) => unit,
        _ => None,
    };
    let time = match &args.time_column {
        Some(c) => {
            let i = source.channel_index(c)?;
            Some((i, named_unit(i)))
        }
        None => layout.time().map_err(|e| anyhow::anyhow!("{file}: {e}"))?,
    };
    let temperature = match &args.temperature_column {
        Some(c) => Some(source.channel_index(c)?),
        None => layout
            .temperature()
            .map_err(|e| anyhow::anyhow!("{file}: {e}"))?,
    };
    let stated_unit = args
        .time_unit
        .as_deref()
        .map(|u| {
            TimeUnit::parse(u)
                .ok_or_else(|| anyhow::anyhow!("--time-unit `{u}`: use s, ms, us or ns"))
        })
        .transpose()?;
    if let Some(hz) = args.rate {
        if !(hz.is_finite() && hz > 0.0) {
            bail!("--rate {hz}: give the sample rate as a positive number of Hz");
        }
    }
    let timing = match (time, args.rate) {
        (Some((channel, named)), rate) => {
            let column = &names[channel];
            let unit = match stated_unit {
                Some(u) => u,
                None => {
                    let step = median_step(&probe_channel(source, channel)?);
                    let choice = infer_time_unit(column, step, rate, named)
                        .map_err(|e| anyhow::anyhow!("{file}: {e}"))?;
                    if let Some(w) = choice.warning {
                        eprintln!("warning: {file}: {w}");
                    }
                    choice.unit
                }
            };
            match rate {
                // The stated rate sets τ0; the time column was only checked.
                Some(hz) => Timing::Rate(hz),
                None => Timing::TimeChannel {
                    channel,
                    scale: unit.scale(),
                },
            }
        }
        (None, Some(hz)) => Timing::Rate(hz),
        (None, None) => bail!(
            "{file}: the sample rate is unknown: no column is named like a time (columns: {}; recognised: time, t, timestamp, millis, micros, Time (s), … see docs/allan.md): give --rate HZ or --time-column NAME",
            names.join(", ")
        ),
    };
    let groups = parse_column_groups(&args.columns).map_err(|e| anyhow::anyhow!(e))?;
    let mut unit_of: Vec<Option<RateUnit>> = vec![None; names.len()];
    // Names absent here may be another input's (checked over all inputs by the caller).
    for g in &groups {
        for c in &g.columns {
            if let Ok(i) = source.channel_index(c) {
                unit_of[i] = Some(g.unit);
            }
        }
    }
    let by_name: Vec<Option<SensorKind>> = (0..names.len())
        .map(|i| match role_of(&names[i]) {
            ColumnRole::Axis(kind) => kind,
            _ => None,
        })
        .collect();
    let time_channel = time.map(|t| t.0);
    let chosen: Vec<usize> = if args.axes.is_empty() {
        // Every column not named like a time or a temperature, nor chosen as one.
        let mut axes: Vec<usize> = layout.axes.iter().map(|a| a.0).collect();
        axes.retain(|&c| Some(c) != time_channel && Some(c) != temperature);
        axes
    } else {
        args.axes
            .iter()
            .map(|a| source.channel_index(a))
            .collect::<Result<_, _>>()?
    };
    let mut axes = Vec::with_capacity(chosen.len());
    for c in chosen {
        if Some(c) == time_channel {
            bail!(
                "{file}: column `{}` is the time column and cannot be analysed as an axis",
                names[c]
            );
        }
        // --columns, then --units, then a unit in the header name (`gyro_x (rad/s)`).
        if unit_of[c].is_none() && args.units == RateUnit::Unspecified {
            unit_of[c] = unit_of_name(&names[c]);
        }
        let unit = unit_of[c].unwrap_or(args.units);
        let sensor = if unit_of[c].is_some() {
            unit.sensor()
        } else {
            args.sensor.or(args.units.sensor())
        };
        if unit_of[c].is_none() {
            if let (Some(given), Some(named)) = (sensor, by_name[c]) {
                if given != named {
                    bail!(
                        "{file}: column `{}` is {} by its name but --units {} / --sensor say {}: give each sensor's unit with --columns, e.g. --columns 'gx,gy,gz=deg/s ax,ay,az=g'",
                        names[c],
                        sensor_word(named),
                        args.units.symbol(),
                        sensor_word(given)
                    );
                }
            }
        }
        axes.push((c, unit, sensor));
    }
    Ok((timing, temperature, axes))
}

fn sensor_word(kind: SensorKind) -> &'static str {
    match kind {
        SensorKind::Gyro => "a gyro",
        SensorKind::Accel => "an accelerometer",
    }
}

/// Reads and analyses every selected axis of every input, one axis in memory at a time.
pub fn analyse_inputs(inputs: &[PathBuf], args: &AnalysisArgs) -> anyhow::Result<AllanReport> {
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
        let source = open_input(path, device.as_deref(), args)?;
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
            let temperature_column = match (&args.temperature_column, &args.compensate) {
                (None, Some(_)) => Some("temp"),
                (column, _) => column.as_deref(),
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
                .collect::<Result<Vec<_>, crate::allan::input::InputError>>()?;
            (timing, temperature, axes)
        } else {
            plan_file(path, source.as_ref(), args)?
        };
        if axes.is_empty() {
            bail!("{}: no channels to analyse", path.display());
        }
        let device = if let Some(session) = source.as_any_session() {
            session.to_string()
        } else {
            args.device.clone().unwrap_or_else(|| {
                path.file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_else(|| "device".into())
            })
        };
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
    let model = args
        .compensate
        .as_deref()
        .map(crate::thermal::model::ThermalModel::load)
        .transpose()?;
    drop(planning);
    let total: usize = plan.iter().map(|p| p.axes.len()).sum();
    let mut progress = Progress::new(total as u64);
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
            .with_context(|| format!("reading {}", path.display()))?;
            drop(reading);
            if let Some(model) = &model {
                for (&(_, unit, _), s) in group.iter().zip(series.iter_mut()) {
                    let to_si = unit.to_si();
                    let (_, warning) = model.compensate_series(device, s, to_si)?;
                    if let Some(w) = warning {
                        tracing::warn!("{w}");
                    }
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
                progress.step(format!("{device} {name}"));
                results.extend(result);
            }
        }
    }
    progress.finish();
    Ok(AllanReport::new(
        inputs.iter().map(|p| p.display().to_string()).collect(),
        args.kind,
        &grid_label(&args.taus),
        results,
    ))
}

/// How many axes one reading pass may hold: all of them while their samples (8 bytes per
/// row each) and the analysis's decimation buffer (half an axis, see
/// [`crate::allan::numerics::for_each_decimation`]) fit in `memory_mib`, at least one. Unknown lengths read
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
    args: &AnalysisArgs,
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
                health: crate::allan::input::Health {
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
