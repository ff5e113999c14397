//! One channel of a [`SampleSource`] as a uniformly sampled series: timing, gaps, NaN,
//! health and the series builder.
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{InputError, SampleSource};

/// What to do about gaps, NaN/Inf and non-uniform sampling.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum GapPolicy {
    /// Refuse the data, saying where the first problem is.
    #[default]
    Error,
    /// Cut the series at each problem and pool the deviations of the uniform pieces.
    Split,
    /// Fill missing samples and invalid values by linear interpolation; treat jitter as uniform.
    Fill,
    /// Drop invalid values and close gaps as if the samples were contiguous.
    Ignore,
}

/// How the sample interval is known.
#[derive(Debug, Clone, PartialEq)]
pub enum Timing {
    /// Fixed rate in Hz.
    Rate(f64),
    /// A channel holding time stamps, scaled to seconds by `scale` (1 for s, 1e-9 for ns).
    TimeChannel { channel: usize, scale: f64 },
    /// A channel holding host arrival times (a session's `t_mono_ns`), scaled like
    /// `TimeChannel`. Frames of one read share an arrival time and the transport adds latency,
    /// so the intervals are judged on the sample clock [`ArrivalClock`] rebuilds from them.
    ArrivalTimes { channel: usize, scale: f64 },
    /// The sensor's own clock in channel `channel` (a session's `t_sensor`): a time in known
    /// units or a sample counter, unwrapped where it wraps (see [`SensorClock`]). The samples
    /// it misses are counted exactly, even one at a time; `arrival` (host arrival times,
    /// scaled to seconds by `arrival_scale`) gives τ0 for a counter.
    SensorTime {
        channel: usize,
        clock: SensorClock,
        arrival: usize,
        arrival_scale: f64,
    },
}

/// How to read a sensor's own clock channel.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorClock {
    /// Seconds per unit of the channel; `None` for a sample counter (one count per sample,
    /// seconds = count × τ0 with τ0 from the arrival times).
    pub unit_s: Option<f64>,
    /// The channel wraps to 0 after this many units. `None` for a counter whose modulus is
    /// not known: it is taken as the next power of two above the largest value seen.
    pub wrap: Option<f64>,
    /// What the report calls this clock, e.g. "sensor sample counter (t_sensor)".
    pub name: String,
}

impl Timing {
    /// What the report calls the clock that gaps are detected on.
    pub fn clock_name(&self) -> String {
        match self {
            Timing::Rate(hz) => format!("fixed rate {hz} Hz (gaps not detectable)"),
            Timing::TimeChannel { .. } => "time column".into(),
            Timing::ArrivalTimes { .. } => {
                "host arrival times (t_mono_ns; gaps under 50 ms not detectable)".into()
            }
            Timing::SensorTime { clock, .. } => clock.name.clone(),
        }
    }
}

/// Turns a wrapping sensor clock into a steadily increasing one, in seconds.
struct Unwrapper {
    unit_s: f64,
    wrap: Option<f64>,
    last: Option<f64>,
    offset: f64,
    largest: f64,
}

impl Unwrapper {
    fn new(unit_s: f64, wrap: Option<f64>) -> Self {
        Unwrapper {
            unit_s,
            wrap,
            last: None,
            offset: 0.0,
            largest: 0.0,
        }
    }

    /// Seconds of raw clock value `v`. A step back by more than half the modulus is a wrap;
    /// a smaller one is left as it is (the gap check then reports a step back).
    fn seconds(&mut self, v: f64) -> f64 {
        if !v.is_finite() {
            return v;
        }
        if let Some(prev) = self.last {
            if v < prev {
                let modulus = self
                    .wrap
                    .unwrap_or_else(|| (self.largest.max(1.0) + 1.0).log2().ceil().exp2());
                if prev - v > modulus / 2.0 {
                    self.offset += modulus;
                }
            }
        }
        self.largest = self.largest.max(v);
        self.last = Some(v);
        (v + self.offset) * self.unit_s
    }
}

/// Whether samples are rates (frequency) or phase (integrated: clock time error).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum DataKind {
    /// Rate or fractional-frequency samples (gyro rad/s, accel m/s², y).
    #[default]
    Rate,
    /// Phase samples (e.g. clock time error in seconds).
    Phase,
}

/// Data health of one axis, as reported.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Health {
    pub policy: Option<GapPolicy>,
    /// The clock gaps were detected on (see [`Timing::clock_name`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clock: Option<String>,
    pub samples: u64,
    pub duration_s: f64,
    /// Intervals longer than 1.5 τ0.
    pub gaps: u64,
    /// Samples missing in those gaps.
    pub missing_samples: u64,
    /// NaN or infinite values.
    pub invalid_values: u64,
    /// Intervals off the nominal τ0 by more than 10 % (but not gaps), or not increasing.
    pub nonuniform_intervals: u64,
    /// Uniform pieces the series was split into (1 when nothing was wrong).
    pub segments: usize,
    /// First problem found, with its position.
    pub first_problem: Option<String>,
    pub temperature_min: Option<f64>,
    pub temperature_max: Option<f64>,
}

/// One axis, ready for analysis: rate samples in uniform segments.
#[derive(Debug, Clone)]
pub struct AxisSeries {
    pub name: String,
    pub tau0: f64,
    /// Uniform pieces of rate samples (one piece unless the policy is `split`).
    pub segments: Vec<Vec<f64>>,
    /// Temperature per sample, aligned with the concatenated segments, if requested.
    pub temperature: Option<Vec<f32>>,
    pub health: Health,
}

impl AxisSeries {
    /// One axis of uniform `rate` samples every `tau0` seconds, in one segment, with the
    /// health of a clean read (no gaps, no invalid values): how a series built in memory
    /// (a simulation, a benchmark, a test) enters the analysis.
    pub fn one_segment(name: impl Into<String>, tau0: f64, rate: Vec<f64>) -> Self {
        AxisSeries {
            name: name.into(),
            tau0,
            health: Health {
                samples: rate.len() as u64,
                duration_s: rate.len() as f64 * tau0,
                segments: 1,
                ..Health::default()
            },
            segments: vec![rate],
            temperature: None,
        }
    }

    pub fn sample_count(&self) -> usize {
        self.segments.iter().map(Vec::len).sum()
    }
}

/// Fractional deviation of an interval from nominal that still counts as uniform.
const JITTER_TOLERANCE: f64 = 0.1;

/// Reads channel `axis` of `source` as a uniform rate series (see [`read_axes`]).
pub fn read_axis(
    source: &dyn SampleSource,
    axis: usize,
    timing: &Timing,
    policy: GapPolicy,
    data: DataKind,
    temperature: Option<usize>,
) -> Result<AxisSeries, InputError> {
    let mut series = read_axes(source, &[axis], timing, policy, data, temperature)?;
    series.pop().ok_or_else(|| {
        InputError::Channel(format!("{}: no channel index {axis}", source.describe()))
    })
}

/// Reads channels `axes` of `source` as uniform rate series in one pass over the source
/// (so a session is decompressed once for all of them); memory is the sum of the axes.
///
/// `temperature`: optional channel carried along (for thermal analysis). With a time
/// channel, τ0 is the median of the first 10 000 intervals. Each axis has its own gap
/// bookkeeping, since NaN values are per channel.
pub fn read_axes(
    source: &dyn SampleSource,
    axes: &[usize],
    timing: &Timing,
    policy: GapPolicy,
    data: DataKind,
    temperature: Option<usize>,
) -> Result<Vec<AxisSeries>, InputError> {
    let names: Vec<String> = axes
        .iter()
        .map(|&axis| {
            source.channels().get(axis).cloned().ok_or_else(|| {
                InputError::Channel(format!("{}: no channel index {axis}", source.describe()))
            })
        })
        .collect::<Result<_, _>>()?;
    let (tau0, time_channel) = match timing {
        Timing::Rate(hz) => {
            if !(hz.is_finite() && *hz > 0.0) {
                return Err(InputError::Sampling(format!(
                    "sample rate {hz} Hz must be positive"
                )));
            }
            (1.0 / hz, None)
        }
        Timing::TimeChannel { channel, scale } => (
            nominal_interval(source, *channel, *scale)?,
            Some((*channel, *scale)),
        ),
        Timing::ArrivalTimes { channel, scale } => (
            arrival_interval(source, *channel, *scale)?,
            Some((*channel, *scale)),
        ),
        Timing::SensorTime {
            channel,
            clock,
            arrival,
            arrival_scale,
        } => match clock.unit_s {
            Some(unit) => (
                nominal_interval(source, *channel, unit)?,
                Some((*channel, 1.0)),
            ),
            None => (
                arrival_interval(source, *arrival, *arrival_scale)?,
                Some((*channel, 1.0)),
            ),
        },
    };
    let mut clock = matches!(timing, Timing::ArrivalTimes { .. }).then(|| ArrivalClock::new(tau0));
    let mut unwrapper = match timing {
        Timing::SensorTime { clock, .. } => {
            Some(Unwrapper::new(clock.unit_s.unwrap_or(tau0), clock.wrap))
        }
        _ => None,
    };
    let mut wanted = axes.to_vec();
    let time_slot = time_channel.map(|(c, _)| {
        wanted.push(c);
        wanted.len() - 1
    });
    let temp_slot = temperature.map(|t| {
        wanted.push(t);
        wanted.len() - 1
    });
    // Reserve the expected length once (capped, so a lying header cannot demand memory).
    let expected = source
        .row_count_hint()
        .map_or(0, |rows| rows.min(1 << 32) as usize);
    let mut builders: Vec<(SeriesBuilder, Option<Vec<f32>>)> = names
        .iter()
        .map(|name| {
            let mut builder = SeriesBuilder::new(tau0, policy, name, source.describe());
            builder.clock = timing.clock_name();
            // Ignoring a failed reservation is fine: the vector then grows as it goes. One
            // more than the rows: the phase built in place adds a point (no reallocation).
            if builder.current.try_reserve_exact(expected + 1).is_ok() {
                crate::memory::advise_huge_pages(&mut builder.current);
            }
            (builder, temperature.map(|_| Vec::new()))
        })
        .collect();
    // Whole blocks per column: the clean stretches (every value finite, every interval
    // within tolerance) are appended in bulk, only blocks with a problem go row by row.
    let mut times: Vec<f64> = Vec::new();
    source.for_each_block(&wanted, &mut |first_row, columns| {
        let time = match (time_slot, time_channel) {
            (Some(slot), Some((_, scale))) => {
                times.clear();
                match (clock.as_mut(), unwrapper.as_mut()) {
                    (Some(clock), _) => {
                        times.extend(columns[slot].iter().map(|t| clock.sample_time(t * scale)))
                    }
                    (None, Some(u)) => times.extend(columns[slot].iter().map(|&t| u.seconds(t))),
                    (None, None) => times.extend(columns[slot].iter().map(|t| t * scale)),
                }
                Some(times.as_slice())
            }
            _ => None,
        };
        let temp = temp_slot.map(|s| columns[s]);
        // The time stamps' own intervals are checked once for all axes; each axis then
        // appends its column on the rayon pool (results taken in axis order, so the first
        // axis with a problem is the one reported, as when they ran one after the other).
        let steady = time.is_none_or(|t| steady_intervals(tau0, t));
        let results: Vec<Result<(), InputError>> = builders
            .par_iter_mut()
            .enumerate()
            .map(|(i, (builder, temps))| {
                builder.push_block(first_row, time, steady, columns[i], temp, temps.as_mut())
            })
            .collect();
        results.into_iter().collect()
    })?;
    builders
        .into_iter()
        .zip(names)
        .map(|((builder, temps), name)| {
            let (segments, mut health) = builder.finish()?;
            health.clock = Some(timing.clock_name());
            if let Some(t) = &temps {
                let finite = t.iter().filter(|v| v.is_finite());
                health.temperature_min = finite.clone().copied().reduce(f32::min).map(f64::from);
                health.temperature_max = finite.copied().reduce(f32::max).map(f64::from);
            }
            let segments = match data {
                DataKind::Rate => segments,
                DataKind::Phase => segments
                    .into_iter()
                    .map(|s| s.windows(2).map(|w| (w[1] - w[0]) / tau0).collect())
                    .collect(),
            };
            Ok(AxisSeries {
                name,
                tau0,
                segments,
                temperature: temps,
                health,
            })
        })
        .collect()
}

/// Median of the first 10 000 time-stamp intervals.
fn nominal_interval(
    source: &dyn SampleSource,
    channel: usize,
    scale: f64,
) -> Result<f64, InputError> {
    let mut intervals = Vec::with_capacity(10_000);
    let mut last: Option<f64> = None;
    let result = source.for_each_row(&[channel], &mut |_, v| {
        let t = v[0] * scale;
        if let Some(prev) = last {
            let dt = t - prev;
            if dt.is_finite() && dt > 0.0 {
                intervals.push(dt);
            }
        }
        last = Some(t);
        if intervals.len() >= 10_000 {
            return Err(InputError::Stopped);
        }
        Ok(())
    });
    match result {
        Ok(()) | Err(InputError::Stopped) => {}
        Err(e) => return Err(e),
    }
    if intervals.is_empty() {
        return Err(InputError::Sampling(format!(
            "{}: the time column has no increasing time stamps",
            source.describe()
        )));
    }
    intervals.sort_by(f64::total_cmp);
    Ok(intervals[intervals.len() / 2])
}

/// τ0 from host arrival times: the median of the mean intervals of windows of 1 000 rows over
/// the first 20 000 rows. Batched arrivals make single intervals useless (many are 0); a window
/// spans many batches, and the median ignores a window holding a gap.
fn arrival_interval(
    source: &dyn SampleSource,
    channel: usize,
    scale: f64,
) -> Result<f64, InputError> {
    const WINDOW: usize = 1_000;
    let mut times = Vec::with_capacity(20 * WINDOW + 1);
    let result = source.for_each_row(&[channel], &mut |_, v| {
        let t = v[0] * scale;
        if t.is_finite() {
            times.push(t);
        }
        if times.len() > 20 * WINDOW {
            return Err(InputError::Stopped);
        }
        Ok(())
    });
    match result {
        Ok(()) | Err(InputError::Stopped) => {}
        Err(e) => return Err(e),
    }
    let window = WINDOW.min(times.len().saturating_sub(1)).max(1);
    let mut means: Vec<f64> = times
        .windows(window + 1)
        .step_by(window)
        .map(|w| (w[window] - w[0]) / window as f64)
        .filter(|dt| *dt > 0.0)
        .collect();
    if means.is_empty() {
        return Err(InputError::Sampling(format!(
            "{}: the arrival times do not increase",
            source.describe()
        )));
    }
    means.sort_by(f64::total_cmp);
    Ok(means[means.len() / 2])
}

/// Host latency an arrival may carry before a pause counts as a gap: a USB serial adapter
/// delivers every 16 ms and the daemon reads in batches; the daemon's own arrival-pause event
/// uses the same 50 ms.
const ARRIVAL_SLACK_S: f64 = 0.05;

/// Rebuilds the sample clock from host arrival times. The clock advances τ0 per sample and
/// follows the lower envelope of the arrivals (a sample cannot arrive before it was taken): it
/// slews down to an earlier arrival by at most 5 % of τ0 per sample and creeps up by 0.1 % of
/// τ0 per sample while arrivals are late, so it follows a sensor clock off nominal by up to
/// 1e-3. An arrival later than the clock by more than τ0/2 + [`ARRIVAL_SLACK_S`] is a gap: the
/// clock jumps by the whole samples missing (counted to within the host latency). A gap
/// shorter than the slack cannot be told from latency by host time alone.
struct ArrivalClock {
    tau0: f64,
    last: Option<f64>,
}

impl ArrivalClock {
    fn new(tau0: f64) -> Self {
        ArrivalClock { tau0, last: None }
    }

    fn sample_time(&mut self, arrival: f64) -> f64 {
        if !arrival.is_finite() {
            return arrival;
        }
        let Some(last) = self.last else {
            self.last = Some(arrival);
            return arrival;
        };
        let predicted = last + self.tau0;
        let late = arrival - predicted;
        let t = if late > 0.5 * self.tau0 + ARRIVAL_SLACK_S {
            predicted + (late / self.tau0).round() * self.tau0
        } else if late < 0.0 {
            predicted + late.max(-0.05 * self.tau0)
        } else {
            predicted + late.min(1e-3 * self.tau0)
        };
        self.last = Some(t);
        t
    }
}

/// Whether an interval `dt` counts as one nominal sample step: the same tests as
/// `SeriesBuilder::push`, so the bulk and the row-by-row paths classify every interval alike.
#[inline(always)]
fn steady_interval(tau0: f64, dt: f64) -> bool {
    let ratio = dt / tau0;
    ratio < 1.5 && dt > 0.0 && (ratio - 1.0).abs() <= JITTER_TOLERANCE
}

/// Whether the time stamps `t` are all finite and every interval between them is within the
/// jitter tolerance of τ0 (no gap, no step back). Folds without early exit, so that the
/// divisions and tests vectorise.
fn steady_intervals(tau0: f64, t: &[f64]) -> bool {
    t.iter().fold(true, |ok, v| ok & v.is_finite())
        && t.windows(2)
            .fold(true, |ok, w| ok & steady_interval(tau0, w[1] - w[0]))
}

/// Streams samples into uniform segments under a gap policy.
struct SeriesBuilder {
    tau0: f64,
    policy: GapPolicy,
    label: String,
    segments: Vec<Vec<f64>>,
    current: Vec<f64>,
    last_time: Option<f64>,
    first_time: Option<f64>,
    /// Number of trailing invalid values waiting for the next valid one (fill policy).
    pending_invalid: usize,
    health: Health,
    /// The clock the time stamps come from, for messages.
    clock: String,
}

impl SeriesBuilder {
    fn new(tau0: f64, policy: GapPolicy, axis: &str, source: String) -> Self {
        SeriesBuilder {
            tau0,
            policy,
            label: format!("{source}: channel `{axis}`"),
            segments: Vec::new(),
            current: Vec::new(),
            last_time: None,
            first_time: None,
            pending_invalid: 0,
            health: Health {
                policy: Some(policy),
                ..Health::default()
            },
            clock: String::new(),
        }
    }

    fn problem(&mut self, message: String) -> Result<(), InputError> {
        if self.health.first_problem.is_none() {
            self.health.first_problem = Some(message.clone());
        }
        if self.policy == GapPolicy::Error {
            return Err(InputError::Sampling(format!(
                "{}: {message} (choose --gaps split|fill|ignore to proceed)",
                self.label
            )));
        }
        Ok(())
    }

    fn cut(&mut self) {
        if !self.current.is_empty() {
            self.segments.push(std::mem::take(&mut self.current));
        }
    }

    fn push(
        &mut self,
        row: u64,
        time: Option<f64>,
        value: f64,
        temperature: Option<f64>,
        temps: Option<&mut Vec<f32>>,
    ) -> Result<(), InputError> {
        self.health.samples += 1;
        if let Some(t) = time {
            if !t.is_finite() {
                self.problem(format!("sample {row}: time stamp is {t}"))?;
                return Ok(());
            }
            self.first_time.get_or_insert(t);
            if let Some(prev) = self.last_time {
                let dt = t - prev;
                let ratio = dt / self.tau0;
                if ratio >= 1.5 {
                    let missing = (ratio.round() as u64).saturating_sub(1);
                    self.health.gaps += 1;
                    self.health.missing_samples += missing;
                    self.problem(format!(
                        "sample {row}: gap of {dt:.6} s at t = {t:.6} s ({missing} samples missing at τ0 = {:.6} s, found on the {})",
                        self.tau0, self.clock
                    ))?;
                    match self.policy {
                        GapPolicy::Split => self.cut(),
                        GapPolicy::Fill => {
                            if let Some(&before) = self.current.last() {
                                if value.is_finite() {
                                    for k in 1..=missing {
                                        let f = k as f64 / (missing + 1) as f64;
                                        self.current.push(before + f * (value - before));
                                    }
                                } else {
                                    self.pending_invalid += missing as usize;
                                }
                            }
                        }
                        _ => {}
                    }
                } else if dt <= 0.0 {
                    self.health.nonuniform_intervals += 1;
                    self.problem(format!("sample {row}: time stamp {t:.6} s does not increase (previous {prev:.6} s)"))?;
                    if self.policy == GapPolicy::Split {
                        self.cut();
                    }
                } else if (ratio - 1.0).abs() > JITTER_TOLERANCE {
                    self.health.nonuniform_intervals += 1;
                    self.problem(format!(
                        "sample {row}: interval {dt:.6} s at t = {t:.6} s is off the nominal {:.6} s (non-uniform sampling)",
                        self.tau0
                    ))?;
                    if self.policy == GapPolicy::Split {
                        self.cut();
                    }
                }
            }
            self.last_time = Some(t);
            self.health.duration_s = t - self.first_time.unwrap_or(t);
        } else {
            self.health.duration_s = self.health.samples as f64 * self.tau0;
        }
        if !value.is_finite() {
            self.health.invalid_values += 1;
            self.problem(format!("sample {row}: value is {value}"))?;
            match self.policy {
                GapPolicy::Split => self.cut(),
                GapPolicy::Fill => self.pending_invalid += 1,
                _ => {}
            }
            return Ok(());
        }
        if self.pending_invalid > 0 {
            // Leading invalid values (nothing before them) are dropped.
            if let Some(before) = self.current.last().copied() {
                let n = self.pending_invalid;
                for k in 1..=n {
                    let f = k as f64 / (n + 1) as f64;
                    self.current.push(before + f * (value - before));
                }
            }
            self.pending_invalid = 0;
        }
        self.current.push(value);
        if let (Some(temps), Some(temp)) = (temps, temperature) {
            temps.push(temp as f32);
        }
        Ok(())
    }

    /// Appends a block of rows starting at `first_row`. When every value is finite and
    /// every interval (including the one from the previous block) is within the jitter
    /// tolerance, the block is appended in bulk, with exactly the bookkeeping [`Self::push`]
    /// would do; otherwise it goes through `push` row by row.
    ///
    /// `steady`: whether `times` (when given) are all finite with every interval between
    /// them within the tolerance ([`steady_intervals`], computed once for all axes).
    fn push_block(
        &mut self,
        first_row: u64,
        times: Option<&[f64]>,
        steady: bool,
        values: &[f64],
        temperatures: Option<&[f64]>,
        mut temps: Option<&mut Vec<f32>>,
    ) -> Result<(), InputError> {
        // Folds without early exit, so that the checks vectorise.
        let clean = self.pending_invalid == 0
            && values.iter().fold(true, |ok, v| ok & v.is_finite())
            && times.is_none_or(|t| steady && self.continues(t));
        if !clean {
            for (k, &value) in values.iter().enumerate() {
                self.push(
                    first_row + k as u64,
                    times.map(|t| t[k]),
                    value,
                    temperatures.map(|t| t[k]),
                    temps.as_deref_mut(),
                )?;
            }
            return Ok(());
        }
        if values.is_empty() {
            return Ok(());
        }
        self.health.samples += values.len() as u64;
        match times {
            Some(t) => {
                let first = *self.first_time.get_or_insert(t[0]);
                let last = t[t.len() - 1];
                self.last_time = Some(last);
                self.health.duration_s = last - first;
            }
            None => self.health.duration_s = self.health.samples as f64 * self.tau0,
        }
        self.current.extend_from_slice(values);
        if let (Some(temps), Some(temperatures)) = (temps, temperatures) {
            temps.extend(temperatures.iter().map(|&t| t as f32));
        }
        Ok(())
    }

    /// Whether the interval from the last time stamp seen to the first of `t` is within the
    /// jitter tolerance of τ0 (the rest of `t` is [`steady_intervals`]' business).
    fn continues(&self, t: &[f64]) -> bool {
        self.last_time.is_none_or(|prev| {
            t.first()
                .is_none_or(|&f| steady_interval(self.tau0, f - prev))
        })
    }

    fn finish(mut self) -> Result<(Vec<Vec<f64>>, Health), InputError> {
        self.cut();
        self.health.segments = self.segments.len();
        if self.segments.is_empty() {
            return Err(InputError::Sampling(format!(
                "{}: no valid samples",
                self.label
            )));
        }
        Ok((self.segments, self.health))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sensor_clock_unwraps_known_and_guessed_moduli() {
        // Known modulus 1000, one count per 0.01 s; a small step back is not a wrap.
        let mut u = Unwrapper::new(0.01, Some(1000.0));
        let got: Vec<f64> = [998.0, 999.0, 1.0, 2.0, 1.0]
            .iter()
            .map(|&v| u.seconds(v))
            .collect();
        assert_eq!(got, [9.98, 9.99, 10.01, 10.02, 10.01]);
        // Unknown modulus: the next power of two above the largest value seen (65 536).
        let mut u = Unwrapper::new(1.0, None);
        let got: Vec<f64> = [65_534.0, 65_535.0, 0.0, 3.0]
            .iter()
            .map(|&v| u.seconds(v))
            .collect();
        assert_eq!(got, [65_534.0, 65_535.0, 65_536.0, 65_539.0]);
        // Seconds wrapping (Xsens SampleTimeFine), a sample lost across the wrap.
        let wrap = 4_294_967_296.0 / 10_000.0;
        let mut u = Unwrapper::new(1.0, Some(wrap));
        let a = u.seconds(wrap - 0.01);
        let b = u.seconds(0.0033);
        assert!((b - a - 0.0133).abs() < 1e-9, "{}", b - a);
    }
}
