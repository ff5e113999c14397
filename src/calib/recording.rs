//! What a calibration reads: one IMU's time, gyro (rad/s) and accelerometer (m/s²) rows in
//! memory, from a session device or from a CSV/TSV/.npy file with `gyro_x … accel_z`
//! columns in SI units, and, for a simulated session, where the scene stood (for local
//! gravity).

use anyhow::{anyhow, bail, Context, Result};
use std::path::Path;

use imulab_allan::input::{open_file, SampleSource};
use imulab_allan::session_source::SessionSource;

/// The channel names a file must have, in this order after the time.
pub const TRIAD_CHANNELS: [&str; 6] = [
    "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z",
];

/// One IMU's samples.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    /// What was read (path and device), for reports.
    pub source: String,
    /// The path as given (a rate-table CSV's `input` column can name it).
    pub name: String,
    /// Device name.
    pub device: String,
    /// Whether `device` is the recording's own (a session's device, `--device`, in memory)
    /// rather than a file's stem.
    pub device_named: bool,
    /// Seconds from the first sample.
    pub t: Vec<f64>,
    pub gyro: Vec<[f64; 3]>,
    pub accel: Vec<[f64; 3]>,
    /// Latitude (rad) and height (m) where it was recorded, when the session says.
    pub place: Option<(f64, f64)>,
}

impl Recording {
    pub fn len(&self) -> usize {
        self.t.len()
    }

    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    /// Median sample interval, s.
    pub fn dt(&self) -> f64 {
        let mut steps: Vec<f64> = self.t.windows(2).map(|w| w[1] - w[0]).collect();
        if steps.is_empty() {
            return f64::NAN;
        }
        let mid = steps.len() / 2;
        *steps.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
    }

    /// A recording of records in memory (a simulation run, a benchmark).
    pub fn from_records(device: &str, records: &[imulab_store::ImuRecord]) -> Recording {
        let t0 = records.first().map_or(0, |r| r.t_mono_ns);
        Recording {
            source: format!("{device} (in memory)"),
            name: device.into(),
            device: device.into(),
            device_named: true,
            t: records
                .iter()
                .map(|r| (r.t_mono_ns - t0) as f64 * 1e-9)
                .collect(),
            gyro: records.iter().map(|r| r.gyro).collect(),
            accel: records.iter().map(|r| r.accel).collect(),
            place: None,
        }
    }

    /// Reads a session directory's IMU `device` (or its only IMU), or a file whose columns
    /// are named `gyro_x … accel_z` (SI units) with a time column `t` (s) or `rate_hz`.
    pub fn read(path: &Path, device: Option<&str>, rate_hz: Option<f64>) -> Result<Recording> {
        if path.is_dir() {
            let source = SessionSource::open(path, device, None, None)?;
            let device = source.device().to_string();
            let mut rec = read_source(&source, 0, None)
                .with_context(|| format!("reading {}", path.display()))?;
            rec.source = format!("{} [{device}]", path.display());
            rec.name = path.display().to_string();
            rec.device = device;
            rec.device_named = true;
            rec.place = session_place(path);
            return Ok(rec);
        }
        let source = open_file(path)?;
        let time = match (rate_hz, source.channel_index("t")) {
            (Some(hz), _) => {
                if !(hz.is_finite() && hz > 0.0) {
                    bail!("--rate must be a positive number of Hz, got {hz}");
                }
                None
            }
            (None, Ok(c)) => Some(c),
            (None, Err(_)) => bail!(
                "{}: no time column `t` (seconds); give the sample rate with --rate HZ",
                path.display()
            ),
        };
        let mut rec = read_source(source.as_ref(), time.unwrap_or(usize::MAX), rate_hz)
            .with_context(|| format!("reading {}", path.display()))?;
        rec.source = path.display().to_string();
        rec.name = rec.source.clone();
        rec.device_named = device.is_some();
        rec.device = device.map(str::to_string).unwrap_or_else(|| {
            path.file_stem()
                .map_or("imu".into(), |s| s.to_string_lossy().into_owned())
        });
        Ok(rec)
    }
}

/// Reads the six triad channels (and the time channel `time`, or times from `rate_hz`).
fn read_source(source: &dyn SampleSource, time: usize, rate_hz: Option<f64>) -> Result<Recording> {
    let mut wanted = Vec::with_capacity(7);
    for name in TRIAD_CHANNELS {
        wanted.push(source.channel_index(name).map_err(|_| {
            anyhow!(
                "{}: no channel `{name}`; calibration needs gyro_x, gyro_y, gyro_z (rad/s) and accel_x, accel_y, accel_z (m/s²) (channels: {})",
                source.describe(),
                source.channels().join(", ")
            )
        })?);
    }
    if rate_hz.is_none() {
        wanted.push(time);
    }
    let mut rec = Recording::default();
    source.for_each_block(&wanted, &mut |first, columns| {
        let rows = columns.first().map_or(0, |c| c.len());
        (0..rows).for_each(|i| {
            rec.gyro.push([columns[0][i], columns[1][i], columns[2][i]]);
            rec.accel
                .push([columns[3][i], columns[4][i], columns[5][i]]);
            rec.t.push(match rate_hz {
                Some(hz) => (first + i as u64) as f64 / hz,
                None => columns[6][i],
            });
        });
        Ok(())
    })?;
    if rec.is_empty() {
        bail!("{}: no rows", source.describe());
    }
    if let Some(row) = rec
        .gyro
        .iter()
        .zip(&rec.accel)
        .position(|(g, a)| g.iter().chain(a).any(|v| !v.is_finite()))
    {
        bail!(
            "{}: row {row} (t = {:.3} s) has a missing or non-finite gyro/accel value; calibration needs every axis of every row (cut the range or fill the gap)",
            source.describe(),
            rec.t[row]
        );
    }
    if let Some(k) = rec
        .t
        .windows(2)
        .position(|w| w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater))
    {
        bail!(
            "{}: time does not increase at row {} ({} s then {} s)",
            source.describe(),
            k + 1,
            rec.t[k],
            rec.t[k + 1]
        );
    }
    let t0 = rec.t[0];
    rec.t.iter_mut().for_each(|t| *t -= t0);
    Ok(rec)
}

/// Latitude (rad) and height of a simulated session's scene, from its `[location]`.
fn session_place(dir: &Path) -> Option<(f64, f64)> {
    let session = imulab_store::Session::open(dir).ok()?;
    let loc = session.manifest().config.get("location")?;
    let lat = loc.get("lat_deg")?;
    let lat = lat
        .as_float()
        .or_else(|| lat.as_integer().map(|i| i as f64))?;
    let h = loc.get("height_m")?;
    let h = h.as_float().or_else(|| h.as_integer().map(|i| i as f64))?;
    Some((lat.to_radians(), h))
}
