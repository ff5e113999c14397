//! What to read of each input: the IMUs of a session (every one unless `--device` names
//! one), a session's axes by sensor, and a plain file's timing, temperature and analysed
//! channels with their units, decided from the column names unless the options name them
//! (see [`crate::columns`]).

use super::Options;
use crate::columns::{
    detect_layout, infer_time_unit, median_step, parse_column_groups, role_of, unit_of_name,
    ColumnRole, TimeUnit,
};
use crate::input::{InputError, SampleSource, Timing};
use crate::units::{RateUnit, SensorKind};
use anyhow::bail;
use std::path::{Path, PathBuf};

/// Session channel names for `--axes`/`--sensor`.
pub(super) fn session_axes(args: &Options) -> Vec<String> {
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
pub(super) fn expand_sessions(
    inputs: &[PathBuf],
    args: &Options,
) -> anyhow::Result<Vec<(PathBuf, Option<String>)>> {
    let mut out = Vec::new();
    for path in inputs {
        if !path.is_dir() || args.device.is_some() || imulab_bag::looks_like_bag(path) {
            out.push((path.clone(), args.device.clone()));
            continue;
        }
        let session = imulab_store::Session::open(path)?;
        let imus: Vec<String> = session
            .devices()
            .iter()
            .filter(|d| d.kind == imulab_store::DeviceKind::Imu)
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
pub(super) struct PlannedInput {
    pub(super) path: PathBuf,
    pub(super) source: Box<dyn SampleSource>,
    pub(super) axes: Vec<PlannedAxis>,
    pub(super) timing: Timing,
    pub(super) temperature: Option<usize>,
    pub(super) device: String,
}

/// An analysed channel with its unit and sensor.
pub(super) type PlannedAxis = (usize, RateUnit, Option<SensorKind>);

/// Rows read to find the median step of a time column.
const TIME_PROBE_ROWS: usize = 20_000;

/// The first values of channel `channel` (at most [`TIME_PROBE_ROWS`]).
fn probe_channel(source: &dyn SampleSource, channel: usize) -> anyhow::Result<Vec<f64>> {
    let mut values = Vec::with_capacity(TIME_PROBE_ROWS);
    let result = source.for_each_row(&[channel], &mut |_, v| {
        values.push(v[0]);
        if values.len() >= TIME_PROBE_ROWS {
            return Err(InputError::Stopped);
        }
        Ok(())
    });
    match result {
        Ok(()) | Err(InputError::Stopped) => Ok(values),
        Err(e) => Err(e.into()),
    }
}

/// Timing, temperature and analysed channels of a plain file: roles by column name (see
/// [`crate::columns`]) unless the options name them, units per column.
pub(super) fn plan_file(
    path: &Path,
    source: &dyn SampleSource,
    args: &Options,
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
