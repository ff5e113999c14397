//! `imulab thermal SESSION|FILE`: thermal-chamber characterisation of each IMU axis (bias
//! against temperature with the order chosen from the data, hysteresis, warm-up, thermal
//! lag, per-plateau noise terms), printed as a summary, and optionally written as JSON, as
//! an HTML report section with plots, and as the compensation model (`--model`) that
//! `allan`, `report`, `export` and `replay` apply with `--compensate`.

use crate::allan::input::{
    open_file, read_axes, AxisSeries, DataKind, GapPolicy, SampleSource, Timing,
};
use crate::allan::session_source::SessionSource;
use crate::allan::units::{RateUnit, SensorKind};
use crate::sim::temperature::TemperatureProfile;
use crate::store::manifest::DeviceKind;
use crate::store::Session;
use crate::thermal::analysis::{
    analyse_axis_thermal, fit_lag, AxisThermal, DeviceMotion, ThermalOptions,
};
use crate::thermal::report::{html_page, summary_text, DeviceThermal, ThermalLag, ThermalReport};
use anyhow::{anyhow, bail, Context, Result};
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  imulab thermal runs/chamber --json thermal.json --html thermal.html --model thermal-model.json\n  imulab thermal icm.csv --rate 150 --temp-column temp --chamber-column chamber\n  imulab allan runs/chamber --compensate thermal-model.json"
)]
pub struct ThermalArgs {
    /// A session directory, or a CSV/TSV/.npy file with `gyro_*`/`accel_*` columns (rad/s,
    /// m/s²) and a temperature column.
    pub input: PathBuf,
    /// Session IMU to analyse (default: every IMU of the session).
    #[arg(long)]
    pub device: Option<String>,
    /// Channels to analyse (default: the six gyro and accel axes).
    #[arg(long, value_delimiter = ',')]
    pub axes: Vec<String>,
    /// Sample rate of a file, Hz (sessions use their own clock).
    #[arg(long)]
    pub rate: Option<f64>,
    /// Temperature column of a file (the sensor's own temperature, °C).
    #[arg(long, default_value = "temp")]
    pub temp_column: String,
    /// Chamber temperature column of a file, °C (sessions: the scene's chamber program).
    #[arg(long)]
    pub chamber_column: Option<String>,
    /// Polynomial order (default: chosen from the data by BIC, up to --max-order).
    #[arg(long)]
    pub order: Option<usize>,
    #[arg(long, default_value_t = 3)]
    pub max_order: usize,
    /// Temperature the coefficients refer to, °C.
    #[arg(long, default_value_t = 25.0)]
    pub reference_temp: f64,
    /// Warm-up tolerance in datasheet units (deg/h for gyros, mg for accelerometers);
    /// default 5 % of the fitted amplitude.
    #[arg(long)]
    pub warmup_tolerance: Option<f64>,
    /// Shortest soak analysed for noise terms, s.
    #[arg(long, default_value_t = 900.0)]
    pub plateau_min_s: f64,
    /// Write the JSON document here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write the HTML report (thermal section with plots) here.
    #[arg(long)]
    pub html: Option<PathBuf>,
    /// Write the compensation model (JSON, docs/thermal.md) here.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Correct the gyro and accel channels with this calibration file (`imulab calibrate`,
    /// docs/calibration.md) before the analysis.
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
}

/// `source`, corrected with `--calibration` when given (the file's channels are SI).
fn calibrated(
    source: Box<dyn SampleSource>,
    device: &str,
    args: &ThermalArgs,
) -> Result<Box<dyn SampleSource>> {
    let Some(path) = &args.calibration else {
        return Ok(source);
    };
    let corrector = crate::calib::Corrector::new(&crate::calib::Calibration::load(path)?, device)?;
    Ok(Box::new(crate::calib::source::CalibratedSource::new(
        source, corrector, true,
    )?))
}

const SESSION_AXES: [&str; 6] = [
    "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z",
];

fn sensor_of(axis: &str) -> Result<(SensorKind, RateUnit)> {
    if axis.starts_with("gyro") {
        Ok((SensorKind::Gyro, RateUnit::RadPerSecond))
    } else if axis.starts_with("accel") {
        Ok((SensorKind::Accel, RateUnit::MetrePerSecondSquared))
    } else {
        bail!("channel `{axis}`: name it gyro_* (rad/s) or accel_* (m/s²) so its unit is known")
    }
}

/// The chamber program of a simulated session (its scene's `[temperature]`), if any.
fn session_chamber(dir: &Path) -> Result<Option<TemperatureProfile>> {
    let session = Session::open(dir).map_err(|e| anyhow!("{}: {e}", dir.display()))?;
    let Some(table) = session.manifest().config.get("temperature") else {
        return Ok(None);
    };
    let profile: TemperatureProfile = table
        .clone()
        .try_into()
        .map_err(|e| anyhow!("{}: the session's [config.temperature]: {e}", dir.display()))?;
    profile
        .validate()
        .map_err(|e| anyhow!("{}: the session's [config.temperature]: {e}", dir.display()))?;
    Ok(Some(profile))
}

fn session_imus(dir: &Path) -> Result<Vec<String>> {
    let session = Session::open(dir).map_err(|e| anyhow!("{}: {e}", dir.display()))?;
    Ok(session
        .devices()
        .iter()
        .filter(|d| d.kind == DeviceKind::Imu)
        .map(|d| d.name.clone())
        .collect())
}

/// Reads one axis with its temperature as one uniform series (gaps filled).
fn read_one(
    source: &dyn SampleSource,
    axis: &str,
    timing: &Timing,
    temp: usize,
) -> Result<AxisSeries> {
    let channel = source.channel_index(axis)?;
    let mut series = read_axes(
        source,
        &[channel],
        timing,
        GapPolicy::Fill,
        DataKind::Rate,
        Some(temp),
    )?;
    series
        .pop()
        .ok_or_else(|| anyhow!("{}: nothing read for `{axis}`", source.describe()))
}

fn timing_of(source: &dyn SampleSource, rate: Option<f64>, is_session: bool) -> Result<Timing> {
    if is_session {
        let t = source.channel_index("t")?;
        return Ok(source.native_timing().unwrap_or(Timing::ArrivalTimes {
            channel: t,
            scale: 1.0,
        }));
    }
    match rate {
        Some(hz) => Ok(Timing::Rate(hz)),
        None => bail!(
            "{}: give the sample rate with --rate HZ (a file has no clock imulab knows)",
            source.describe()
        ),
    }
}

/// Analyses one device (a session IMU or a file).
fn analyse_device(
    source: &dyn SampleSource,
    device: &str,
    args: &ThermalArgs,
    chamber_profile: Option<&TemperatureProfile>,
    is_session: bool,
) -> Result<DeviceThermal> {
    let timing = timing_of(source, args.rate, is_session)?;
    let temp = source.channel_index(&args.temp_column).map_err(|_| {
        anyhow!(
            "{}: no temperature column `{}` (channels: {}): thermal analysis needs the sensor's own temperature per sample; name it with --temp-column",
            source.describe(),
            args.temp_column,
            source.channels().join(", ")
        )
    })?;
    let axes: Vec<String> = if args.axes.is_empty() {
        SESSION_AXES
            .iter()
            .filter(|a| source.channels().iter().any(|c| c == *a))
            .map(|a| a.to_string())
            .collect()
    } else {
        args.axes.clone()
    };
    if axes.is_empty() {
        bail!(
            "{}: no gyro_*/accel_* channels (channels: {}); choose them with --axes",
            source.describe(),
            source.channels().join(", ")
        );
    }
    // The chamber: a file's column (read like an axis), or the session's scene program.
    let chamber_column: Option<Vec<f64>> = match &args.chamber_column {
        None => None,
        Some(name) => {
            let c = source.channel_index(name)?;
            let mut s = read_axes(source, &[c], &timing, GapPolicy::Fill, DataKind::Rate, None)?;
            s.pop().map(|s| s.segments.concat())
        }
    };
    let options = ThermalOptions {
        reference_c: args.reference_temp,
        order: args.order,
        max_order: args.max_order,
        plateau_min_s: args.plateau_min_s,
        ..ThermalOptions::default()
    };
    let mut results = Vec::new();
    let mut lag = None;
    let mut range = [f64::INFINITY, f64::NEG_INFINITY];
    // The accelerometers first: the blocks where they find the device turned stay out of
    // the gyros' bias fits too.
    let mut order: Vec<&String> = axes.iter().collect();
    order.sort_by_key(|a| !matches!(sensor_of(a), Ok((SensorKind::Accel, _))));
    let mut motion = DeviceMotion::default();
    for axis in order {
        let (sensor, unit) = sensor_of(axis)?;
        let series = match read_one(source, axis, &timing, temp) {
            Ok(series) => series,
            // A session lists all six channels; a triad the device does not have is all NaN.
            Err(e) if args.axes.is_empty() && e.to_string().contains("no valid samples") => {
                eprintln!("{device} {axis}: skipped, no valid samples");
                continue;
            }
            Err(e) => return Err(e),
        };
        let tau0 = series.tau0;
        let from_column = chamber_column.as_ref().map(|c| {
            move |t: f64| {
                let i = ((t / tau0).floor().max(0.0) as usize).min(c.len().saturating_sub(1));
                c.get(i).copied().unwrap_or(f64::NAN)
            }
        });
        let from_profile = chamber_profile.map(|p| move |t: f64| p.at(t));
        let chamber: Option<&dyn Fn(f64) -> f64> = match (&from_column, &from_profile) {
            (Some(f), _) => Some(f),
            (None, Some(f)) => Some(f),
            (None, None) => None,
        };
        let options = ThermalOptions {
            warmup_tolerance: args
                .warmup_tolerance
                .map(|t| t / crate::thermal::analysis::datasheet_unit(sensor, unit).1),
            ..options.clone()
        };
        let (result, temps) =
            analyse_axis_thermal(device, series, sensor, unit, chamber, &options, &mut motion)
                .map_err(|e| anyhow!("{}: {e}", source.describe()))?;
        range[0] = range[0].min(result.fit.range_c[0]);
        range[1] = range[1].max(result.fit.range_c[1]);
        if lag.is_none() && !temps.chamber_c.is_empty() {
            lag =
                fit_lag(&temps.t_s, &temps.chamber_c, &temps.sensor_c).map(|(tau, offset, rms)| {
                    ThermalLag {
                        time_constant_s: tau,
                        offset_c: offset,
                        rms_c: rms,
                    }
                });
        }
        results.push(result);
    }
    if results.is_empty() {
        bail!("{}: no axis with valid samples", source.describe());
    }
    results.sort_by_key(|r: &AxisThermal| axes.iter().position(|a| *a == r.axis));
    Ok(DeviceThermal {
        device: device.to_string(),
        temperature_range_c: range,
        chamber: match (&args.chamber_column, chamber_profile) {
            (Some(c), _) => Some(format!("column `{c}`")),
            (None, Some(_)) => Some("the session's chamber program ([config.temperature])".into()),
            (None, None) => None,
        },
        lag,
        axes: results,
    })
}

impl ThermalArgs {
    /// The defaults of `imulab thermal DIR` for a session (every IMU, sensor temperature,
    /// the scene's chamber program), writing nothing.
    pub fn for_session(dir: &Path) -> Self {
        ThermalArgs {
            input: dir.to_path_buf(),
            device: None,
            axes: Vec::new(),
            rate: None,
            temp_column: "temp".into(),
            chamber_column: None,
            order: None,
            max_order: 3,
            reference_temp: 25.0,
            warmup_tolerance: None,
            plateau_min_s: 900.0,
            json: None,
            html: None,
            model: None,
            calibration: None,
        }
    }
}

/// The thermal characterisation of `args.input` (a session or a file).
pub fn analyse_input(args: &ThermalArgs) -> Result<ThermalReport> {
    let input = &args.input;
    let devices = if input.is_dir() {
        let chamber = session_chamber(input)?;
        let names = match &args.device {
            Some(d) => vec![d.clone()],
            None => session_imus(input)?,
        };
        if names.is_empty() {
            bail!("{}: the session has no IMU", input.display());
        }
        let mut out = Vec::new();
        for name in names {
            let source = calibrated(
                Box::new(SessionSource::open(input, Some(&name), None, None)?),
                &name,
                args,
            )?;
            out.push(analyse_device(
                source.as_ref(),
                &name,
                args,
                chamber.as_ref(),
                true,
            )?);
        }
        out
    } else {
        if args.device.is_some() {
            bail!(
                "--device chooses an IMU of a session; {} is a file",
                input.display()
            );
        }
        let name = input
            .file_stem()
            .map_or("file".into(), |s| s.to_string_lossy().into_owned());
        let source = calibrated(open_file(input)?, &name, args)?;
        vec![analyse_device(source.as_ref(), &name, args, None, false)?]
    };
    Ok(ThermalReport::new(input.display().to_string(), devices))
}

pub fn run(args: ThermalArgs) -> Result<()> {
    let report = analyse_input(&args)?;
    print!("{}", summary_text(&report));
    if let Some(path) = &args.json {
        let file =
            std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        serde_json::to_writer_pretty(std::io::BufWriter::new(file), &report)?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &args.html {
        std::fs::write(path, html_page(&report, "IMU thermal characterisation"))
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &args.model {
        let file =
            std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        serde_json::to_writer_pretty(std::io::BufWriter::new(file), &report.model())?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
