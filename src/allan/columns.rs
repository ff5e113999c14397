//! Column roles of a plain file: which column holds time stamps, which a temperature and
//! which are sensor axes (gyro or accelerometer), decided from the header names; the unit
//! of the time column, inferred from its median step against a stated or detected rate;
//! and the per-column unit spec of `--columns` (`gx,gy,gz=deg/s ax,ay,az=g`).
//!
//! The names recognised are listed in docs/allan.md ("Column names").

use super::units::{RateUnit, SensorKind};
use std::fmt;

/// What a column holds, as told by its name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColumnRole {
    /// Time stamps; the unit when the name says it (`millis`, `t_ms`, `Time (s)`).
    Time(Option<TimeUnit>),
    /// A temperature.
    Temperature,
    /// A sensor axis; the sensor when the name says it (`gx`, `acc_x`, …).
    Axis(Option<SensorKind>),
}

/// Unit of a time column.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeUnit {
    Seconds,
    Milliseconds,
    Microseconds,
    Nanoseconds,
}

impl TimeUnit {
    pub const ALL: [TimeUnit; 4] = [
        TimeUnit::Seconds,
        TimeUnit::Milliseconds,
        TimeUnit::Microseconds,
        TimeUnit::Nanoseconds,
    ];

    /// Seconds per unit.
    pub fn scale(self) -> f64 {
        match self {
            TimeUnit::Seconds => 1.0,
            TimeUnit::Milliseconds => 1e-3,
            TimeUnit::Microseconds => 1e-6,
            TimeUnit::Nanoseconds => 1e-9,
        }
    }

    pub fn symbol(self) -> &'static str {
        match self {
            TimeUnit::Seconds => "s",
            TimeUnit::Milliseconds => "ms",
            TimeUnit::Microseconds => "µs",
            TimeUnit::Nanoseconds => "ns",
        }
    }

    /// Parses `s`, `ms`, `us`/`µs` or `ns`.
    pub fn parse(text: &str) -> Option<TimeUnit> {
        Some(match text.trim() {
            "s" | "sec" | "secs" | "seconds" => TimeUnit::Seconds,
            "ms" | "millis" | "msec" => TimeUnit::Milliseconds,
            "us" | "µs" | "μs" | "micros" | "usec" => TimeUnit::Microseconds,
            "ns" | "nanos" | "nsec" => TimeUnit::Nanoseconds,
            _ => return None,
        })
    }
}

impl fmt::Display for TimeUnit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.symbol())
    }
}

/// Splits `Time (s)`, `gyro_x [deg/s]` or `temp(C)` into the lowercase base name and the
/// unit in brackets, if any.
fn split_name(name: &str) -> (String, Option<String>) {
    let name = name.trim();
    if let Some(open) = name.find(['(', '[']) {
        let close = name[open..].find([')', ']']).map(|c| open + c);
        let unit = close.map(|c| name[open + 1..c].trim().to_string());
        return (name[..open].trim().to_lowercase(), unit);
    }
    (name.to_lowercase(), None)
}

/// The rate unit a header name gives in brackets (`gyro_x (rad/s)`, `Acceleration x
/// (m/s^2)`, `ax [g]`), if it is one [`RateUnit`] knows.
pub fn unit_of_name(name: &str) -> Option<RateUnit> {
    let (_, unit) = split_name(name);
    unit?
        .parse::<RateUnit>()
        .ok()
        .filter(|u| *u != RateUnit::Unspecified)
}

/// The role of a column from its header name.
pub fn role_of(name: &str) -> ColumnRole {
    let (base, bracket_unit) = split_name(name);
    let compact: String = base
        .chars()
        .filter(|c| !matches!(c, '_' | ' ' | '-' | '.'))
        .collect();
    // Time: the name alone, or with its unit as a suffix (`t_ms`, `time_us`, `timestamp_ns`).
    const TIME: [&str; 9] = [
        "t",
        "time",
        "timestamp",
        "ts",
        "stamp",
        "elapsed",
        "tmono",
        "timestamps",
        "sampletime",
    ];
    const TIME_WORDS: [(&str, TimeUnit); 5] = [
        ("millis", TimeUnit::Milliseconds),
        ("micros", TimeUnit::Microseconds),
        ("nanos", TimeUnit::Nanoseconds),
        ("seconds", TimeUnit::Seconds),
        ("secs", TimeUnit::Seconds),
    ];
    if TIME.contains(&compact.as_str()) {
        return ColumnRole::Time(bracket_unit.as_deref().and_then(TimeUnit::parse));
    }
    if let Some((_, unit)) = TIME_WORDS.iter().find(|(w, _)| compact == *w) {
        return ColumnRole::Time(Some(*unit));
    }
    for stem in TIME {
        if let Some(unit) = compact.strip_prefix(stem).and_then(TimeUnit::parse) {
            return ColumnRole::Time(Some(unit));
        }
    }
    const TEMPERATURE: [&str; 8] = [
        "temp",
        "temperature",
        "tempc",
        "temperaturec",
        "dietemp",
        "imutemp",
        "gyrotemp",
        "sensortemp",
    ];
    if TEMPERATURE.contains(&compact.as_str()) {
        return ColumnRole::Temperature;
    }
    ColumnRole::Axis(sensor_of(&compact))
}

/// The sensor a (compacted, lowercase) axis name belongs to: `gx`, `gyrox`, `gyrx`, `wx`,
/// `omegax`, `rotx` for a gyro; `ax`, `accx`, `accelx`, `accelerationx`, `linaccx` for an
/// accelerometer (each for x, y and z).
fn sensor_of(compact: &str) -> Option<SensorKind> {
    let stem = compact.strip_suffix(['x', 'y', 'z'])?;
    const GYRO: [&str; 7] = ["g", "gyro", "gyr", "w", "omega", "rot", "gyroscope"];
    const ACCEL: [&str; 7] = [
        "a",
        "acc",
        "accel",
        "acceleration",
        "linacc",
        "accelerometer",
        "imuacc",
    ];
    if GYRO.contains(&stem) {
        Some(SensorKind::Gyro)
    } else if ACCEL.contains(&stem) {
        Some(SensorKind::Accel)
    } else {
        None
    }
}

/// Roles of every column of a file, as found by name.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    names: Vec<String>,
    /// Columns named like a time, with the unit the name gives.
    pub times: Vec<(usize, Option<TimeUnit>)>,
    /// Columns named like a temperature.
    pub temperatures: Vec<usize>,
    /// Every other column with the sensor its name gives.
    pub axes: Vec<(usize, Option<SensorKind>)>,
}

/// Finds the roles of `names` (a file's header).
pub fn detect_layout(names: &[String]) -> Layout {
    let mut layout = Layout {
        names: names.to_vec(),
        times: Vec::new(),
        temperatures: Vec::new(),
        axes: Vec::new(),
    };
    for (i, name) in names.iter().enumerate() {
        match role_of(name) {
            ColumnRole::Time(unit) => layout.times.push((i, unit)),
            ColumnRole::Temperature => layout.temperatures.push(i),
            ColumnRole::Axis(sensor) => layout.axes.push((i, sensor)),
        }
    }
    layout
}

impl Layout {
    fn quoted(&self, columns: impl Iterator<Item = usize>) -> String {
        columns
            .map(|i| format!("`{}`", self.names[i]))
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// The time column, if one is named like a time; two or more cannot be decided and the
    /// error names them.
    pub fn time(&self) -> Result<Option<(usize, Option<TimeUnit>)>, String> {
        match self.times.as_slice() {
            [] => Ok(None),
            [one] => Ok(Some(*one)),
            several => Err(format!(
                "columns {} all look like time stamps: choose one with --time-column NAME",
                self.quoted(several.iter().map(|t| t.0))
            )),
        }
    }

    /// The temperature column, like [`Self::time`].
    pub fn temperature(&self) -> Result<Option<usize>, String> {
        match self.temperatures.as_slice() {
            [] => Ok(None),
            [one] => Ok(Some(*one)),
            several => Err(format!(
                "columns {} all look like temperatures: choose one with --temperature-column NAME",
                self.quoted(several.iter().copied())
            )),
        }
    }
}

/// Plausible sample rates of a bench logger, Hz: a time unit is accepted on its own only
/// when it puts the rate in this range.
const PLAUSIBLE_RATE_HZ: (f64, f64) = (0.5, 20_000.0);

/// How far the rate the time stamps give may be from a stated `--rate` (relative).
const RATE_TOLERANCE: f64 = 0.2;

/// The unit of a time column decided from its median step, with a warning when the choice
/// was a guess.
#[derive(Debug, Clone, PartialEq)]
pub struct TimeUnitChoice {
    pub unit: TimeUnit,
    pub warning: Option<String>,
}

/// Decides the unit of time column `column` whose median step is `step` (in the column's
/// own numbers). A stated `rate` (Hz) decides: the unit whose step is within 20 % of
/// 1/rate, or an error saying what the column gives. Otherwise the name's unit (`named`)
/// is taken when it gives a plausible rate; else the one unit giving a plausible rate
/// (0.5 Hz–20 kHz), and when several do, the one nearest 100 Hz, with a warning.
pub fn infer_time_unit(
    column: &str,
    step: f64,
    rate: Option<f64>,
    named: Option<TimeUnit>,
) -> Result<TimeUnitChoice, String> {
    if !(step.is_finite() && step > 0.0) {
        return Err(format!(
            "time column `{column}`: its median step is {step}, not a positive interval: give --rate HZ (and --time-column if `{column}` is not the time)"
        ));
    }
    let rate_of = |u: TimeUnit| 1.0 / (step * u.scale());
    let describe = |u: TimeUnit| format!("{} {u} = {}", fmt_sig(step), fmt_rate(rate_of(u)));
    if let Some(hz) = rate {
        let fits = |u: &TimeUnit| ((rate_of(*u) / hz) - 1.0).abs() <= RATE_TOLERANCE;
        let candidates: Vec<TimeUnit> = match named {
            Some(u) => vec![u],
            None => TimeUnit::ALL.to_vec(),
        };
        return match candidates.iter().find(|u| fits(u)) {
            Some(&unit) => Ok(TimeUnitChoice {
                unit,
                warning: None,
            }),
            None => Err(format!(
                "time column `{column}`: its median step {} does not match the stated {} (--rate){}; check --rate, or give --time-column/--time-unit",
                fmt_sig(step),
                fmt_rate(hz),
                match named {
                    Some(u) => format!(": read in {u} as its name says, it gives {}", describe(u)),
                    None => format!(
                        " in any unit (as s: {})",
                        fmt_rate(rate_of(TimeUnit::Seconds))
                    ),
                }
            )),
        };
    }
    let plausible = |u: &TimeUnit| {
        let r = rate_of(*u);
        (PLAUSIBLE_RATE_HZ.0..=PLAUSIBLE_RATE_HZ.1).contains(&r)
    };
    if let Some(u) = named {
        if plausible(&u) {
            return Ok(TimeUnitChoice {
                unit: u,
                warning: None,
            });
        }
        return Err(format!(
            "time column `{column}`: read in {u} as its name says, its median step is {}, which is not a plausible sample rate: give --rate HZ or --time-unit",
            describe(u)
        ));
    }
    let candidates: Vec<TimeUnit> = TimeUnit::ALL.into_iter().filter(plausible).collect();
    let nearest_100hz = |u: &&TimeUnit| {
        let distance = (rate_of(**u) / 100.0).log10().abs();
        (distance * 1e6) as u64
    };
    match candidates.as_slice() {
        [] => Err(format!(
            "time column `{column}`: its median step {} gives no plausible sample rate in s, ms, µs or ns: give --rate HZ or --time-unit",
            fmt_sig(step)
        )),
        [unit] => Ok(TimeUnitChoice {
            unit: *unit,
            warning: None,
        }),
        several => {
            let unit = *several.iter().min_by_key(nearest_100hz).expect("not empty");
            let others: Vec<String> = several
                .iter()
                .filter(|u| **u != unit)
                .map(|u| describe(*u))
                .collect();
            Ok(TimeUnitChoice {
                unit,
                warning: Some(format!(
                    "time column `{column}`: unit ambiguous, read as {unit} ({}); it could also be {}: give --rate HZ or --time-unit to decide",
                    describe(unit),
                    others.join(" or ")
                )),
            })
        }
    }
}

/// Median of the positive steps between consecutive finite values (NaN when none).
pub fn median_step(values: &[f64]) -> f64 {
    let mut steps: Vec<f64> = values
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| d.is_finite())
        .collect();
    if steps.is_empty() {
        return f64::NAN;
    }
    let mid = steps.len() / 2;
    let (_, m, _) = steps.select_nth_unstable_by(mid, f64::total_cmp);
    *m
}

/// A number with up to 6 significant digits and no trailing zeros: `0.01`, not
/// `0.009999999999999787`.
pub fn fmt_sig(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let magnitude = v.abs().log10().floor() as i32;
    if !(-6..=9).contains(&magnitude) {
        return format!("{v:.5e}");
    }
    let decimals = (5 - magnitude).max(0) as usize;
    let text = format!("{v:.decimals$}");
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        text
    }
}

/// A rate as `100 Hz` or `1.5 kHz`.
fn fmt_rate(hz: f64) -> String {
    if hz >= 1000.0 {
        format!("{} kHz", fmt_sig(hz / 1000.0))
    } else {
        format!("{} Hz", fmt_sig(hz))
    }
}

/// One group of `--columns`: the named columns are in `unit` (which implies the sensor).
#[derive(Debug, Clone, PartialEq)]
pub struct ColumnGroup {
    pub columns: Vec<String>,
    pub unit: RateUnit,
}

/// Parses the values of `--columns`: each value holds one or more groups separated by
/// whitespace, each `NAME[,NAME…]=UNIT` (e.g. `gx,gy,gz=deg/s ax,ay,az=g`).
pub fn parse_column_groups(values: &[String]) -> Result<Vec<ColumnGroup>, String> {
    let mut groups = Vec::new();
    for group in values.iter().flat_map(|v| v.split_whitespace()) {
        let Some((names, unit)) = group.rsplit_once('=') else {
            return Err(format!(
                "--columns `{group}`: expected NAME[,NAME…]=UNIT, e.g. gx,gy,gz=deg/s"
            ));
        };
        let unit: RateUnit = unit
            .parse()
            .map_err(|e: String| format!("--columns `{group}`: {e}"))?;
        let columns: Vec<String> = names
            .split(',')
            .map(str::trim)
            .filter(|n| !n.is_empty())
            .map(String::from)
            .collect();
        if columns.is_empty() {
            return Err(format!("--columns `{group}`: no column names before `=`"));
        }
        groups.push(ColumnGroup { columns, unit });
    }
    let mut seen: Vec<&str> = Vec::new();
    for name in groups.iter().flat_map(|g| &g.columns) {
        if seen.contains(&name.as_str()) {
            return Err(format!("--columns: column `{name}` is given twice"));
        }
        seen.push(name);
    }
    Ok(groups)
}

/// Whether a command-line word looks like a `--columns` group rather than a file name (used
/// to explain a group that the shell passed as an input).
pub fn looks_like_column_group(word: &str) -> bool {
    word.rsplit_once('=')
        .is_some_and(|(_, unit)| unit.parse::<RateUnit>().is_ok())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roles_from_logger_names() {
        for name in [
            "t",
            "time",
            "Time",
            "timestamp",
            "TimeStamp",
            "ts",
            "elapsed",
        ] {
            assert_eq!(role_of(name), ColumnRole::Time(None), "{name}");
        }
        assert_eq!(
            role_of("Time (s)"),
            ColumnRole::Time(Some(TimeUnit::Seconds))
        );
        assert_eq!(
            role_of("millis"),
            ColumnRole::Time(Some(TimeUnit::Milliseconds))
        );
        assert_eq!(
            role_of("t_us"),
            ColumnRole::Time(Some(TimeUnit::Microseconds))
        );
        assert_eq!(
            role_of("timestamp_ns"),
            ColumnRole::Time(Some(TimeUnit::Nanoseconds))
        );
        assert_eq!(
            role_of("time [ms]"),
            ColumnRole::Time(Some(TimeUnit::Milliseconds))
        );
        for name in [
            "Temp",
            "temperature",
            "temp_c",
            "Temperature (°C)",
            "die_temp",
        ] {
            assert_eq!(role_of(name), ColumnRole::Temperature, "{name}");
        }
        for name in [
            "gx",
            "GyroX",
            "gyro_y",
            "gyr_z",
            "wx",
            "omega_z",
            "gx (deg/s)",
        ] {
            assert_eq!(
                role_of(name),
                ColumnRole::Axis(Some(SensorKind::Gyro)),
                "{name}"
            );
        }
        for name in ["ax", "acc_y", "AccelZ", "accel_x", "linacc_x"] {
            assert_eq!(
                role_of(name),
                ColumnRole::Axis(Some(SensorKind::Accel)),
                "{name}"
            );
        }
        assert_eq!(
            unit_of_name("Gyroscope x (rad/s)"),
            Some(RateUnit::RadPerSecond)
        );
        assert_eq!(
            role_of("Gyroscope x (rad/s)"),
            ColumnRole::Axis(Some(SensorKind::Gyro))
        );
        assert_eq!(
            unit_of_name("Acceleration z (m/s^2)"),
            Some(RateUnit::MetrePerSecondSquared)
        );
        assert_eq!(unit_of_name("Time (s)"), None);
        for name in ["mag_x", "value", "tx", "y"] {
            assert_eq!(role_of(name), ColumnRole::Axis(None), "{name}");
        }
    }

    #[test]
    fn two_time_columns_are_named_in_the_error() {
        let names: Vec<String> = ["time", "timestamp", "gx"].map(String::from).to_vec();
        let err = detect_layout(&names).time().unwrap_err();
        assert!(err.contains("`time`, `timestamp`"), "{err}");
    }

    #[test]
    fn time_unit_from_step() {
        let unit = |step, rate, named| infer_time_unit("t", step, rate, named).unwrap();
        // 100 Hz in each unit, rate stated.
        for (step, u) in [
            (0.01, TimeUnit::Seconds),
            (10.0, TimeUnit::Milliseconds),
            (1e4, TimeUnit::Microseconds),
            (1e7, TimeUnit::Nanoseconds),
        ] {
            assert_eq!(unit(step, Some(100.0), None).unit, u);
            assert!(unit(step, Some(100.0), None).warning.is_none());
        }
        // No rate: 0.01 can only be seconds, 10 only ms; 1e7 only ns.
        assert_eq!(unit(0.01, None, None).unit, TimeUnit::Seconds);
        assert_eq!(unit(10.0, None, None).unit, TimeUnit::Milliseconds);
        assert_eq!(unit(1e7, None, None).unit, TimeUnit::Nanoseconds);
        // 1000: 1 Hz in ms or 1 kHz in µs: a guess with a warning.
        let guess = unit(1000.0, None, None);
        assert_eq!(guess.unit, TimeUnit::Microseconds);
        assert!(guess.warning.unwrap().contains("ambiguous"));
        // The name's unit wins when plausible; a stated rate that fits no unit is an error.
        assert_eq!(
            unit(1.0, None, Some(TimeUnit::Milliseconds)).unit,
            TimeUnit::Milliseconds
        );
        let err =
            infer_time_unit("Time (s)", 0.02, Some(100.0), Some(TimeUnit::Seconds)).unwrap_err();
        assert!(err.contains("`Time (s)`") && err.contains("50 Hz"), "{err}");
    }

    #[test]
    fn sig_formatting() {
        assert_eq!(fmt_sig(0.009999999999999787), "0.01");
        assert_eq!(fmt_sig(1.0 / 150.0), "0.00666667");
        assert_eq!(fmt_sig(100.0), "100");
        assert_eq!(fmt_sig(0.5), "0.5");
    }

    #[test]
    fn column_groups() {
        let one = parse_column_groups(&["gx,gy,gz=deg/s ax,ay,az=g".into()]).unwrap();
        let two = parse_column_groups(&["gx,gy,gz=deg/s".into(), "ax,ay,az=g".into()]).unwrap();
        assert_eq!(one, two);
        assert_eq!(one[1].unit, RateUnit::StandardGravity);
        assert!(parse_column_groups(&["gx=furlongs".into()]).is_err());
        assert!(parse_column_groups(&["gx=g gx=g".into()])
            .unwrap_err()
            .contains("twice"));
        assert!(looks_like_column_group("ax,ay,az=g"));
        assert!(!looks_like_column_group("a=b.csv"));
    }
}
