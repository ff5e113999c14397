//! Where simulated data goes: the [`SimSink`] trait the runner emits into, an in-memory
//! sink for tests and studies, and a summary sink that keeps only counts and moments.
//! [`SessionSink`] writes a session in the daemon's HDF5 format plus `/truth`; a
//! byte-stream server would be one more sink.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, Result};

use super::scene::Scene;
use imulab_store::{
    DeviceInfo, DeviceKind, EventRecord, GnssRecord, ImuRecord, Manifest, SessionWriter,
    TruthImuRecord, TruthNavRecord, WriterOptions,
};

/// Receives simulated records block by block, in a deterministic order: per block, first
/// truth/nav, then each IMU (records, then its truth) in scene order, then each GNSS. A
/// block that holds a rotation time ([`SimSink::rotation_period`]) comes in that order twice:
/// the rows before it, then the rows from it on.
pub trait SimSink {
    fn imu(&mut self, device: &str, records: &[ImuRecord]) -> Result<()>;
    fn gnss(&mut self, device: &str, records: &[GnssRecord]) -> Result<()>;
    fn truth_nav(&mut self, records: &[TruthNavRecord]) -> Result<()>;
    fn truth_imu(&mut self, device: &str, records: &[TruthImuRecord]) -> Result<()>;
    fn event(&mut self, event: &EventRecord) -> Result<()>;
    /// The data time after which the sink starts a new file, counted from the scene's start
    /// (a session's `rotate_after`); `None` when it keeps everything together.
    fn rotation_period(&self) -> Option<std::time::Duration> {
        None
    }
}

/// Keeps everything in memory (for tests, studies and short runs).
#[derive(Debug, Default, Clone, PartialEq)]
pub struct MemorySink {
    pub imu: BTreeMap<String, Vec<ImuRecord>>,
    pub gnss: BTreeMap<String, Vec<GnssRecord>>,
    pub truth_nav: Vec<TruthNavRecord>,
    pub truth_imu: BTreeMap<String, Vec<TruthImuRecord>>,
    pub events: Vec<EventRecord>,
}

impl SimSink for MemorySink {
    fn imu(&mut self, device: &str, records: &[ImuRecord]) -> Result<()> {
        self.imu
            .entry(device.to_owned())
            .or_default()
            .extend_from_slice(records);
        Ok(())
    }
    fn gnss(&mut self, device: &str, records: &[GnssRecord]) -> Result<()> {
        self.gnss
            .entry(device.to_owned())
            .or_default()
            .extend_from_slice(records);
        Ok(())
    }
    fn truth_nav(&mut self, records: &[TruthNavRecord]) -> Result<()> {
        self.truth_nav.extend_from_slice(records);
        Ok(())
    }
    fn truth_imu(&mut self, device: &str, records: &[TruthImuRecord]) -> Result<()> {
        self.truth_imu
            .entry(device.to_owned())
            .or_default()
            .extend_from_slice(records);
        Ok(())
    }
    fn event(&mut self, event: &EventRecord) -> Result<()> {
        self.events.push(event.clone());
        Ok(())
    }
}

/// Running mean and spread of six channels (Welford's update).
#[derive(Debug, Default, Clone, Copy, PartialEq)]
pub struct Moments {
    pub count: u64,
    pub mean: [f64; 6],
    m2: [f64; 6],
}

impl Moments {
    fn add(&mut self, x: &[f64; 6]) {
        self.count += 1;
        let n = self.count as f64;
        for ((xi, mean), m2) in x.iter().zip(&mut self.mean).zip(&mut self.m2) {
            let d = xi - *mean;
            *mean += d / n;
            *m2 += d * (xi - *mean);
        }
    }

    /// Sample standard deviation of each channel (NaN with fewer than two samples).
    pub fn std(&self) -> [f64; 6] {
        let n = self.count as f64;
        self.m2.map(|m| {
            if self.count > 1 {
                (m / (n - 1.0)).sqrt()
            } else {
                f64::NAN
            }
        })
    }
}

/// Keeps counts and the mean/spread of each IMU's six channels: what `imulab sim` prints.
#[derive(Debug, Default, Clone, PartialEq)]
pub struct SummarySink {
    pub imu: BTreeMap<String, Moments>,
    /// Per receiver: (epochs with a fix, epochs without).
    pub gnss: BTreeMap<String, (u64, u64)>,
    pub truth_nav_rows: u64,
    pub truth_imu_rows: u64,
}

impl SimSink for SummarySink {
    fn imu(&mut self, device: &str, records: &[ImuRecord]) -> Result<()> {
        let m = self.imu.entry(device.to_owned()).or_default();
        for r in records {
            let [a, b, c] = r.gyro;
            let [d, e, f] = r.accel;
            m.add(&[a, b, c, d, e, f]);
        }
        Ok(())
    }
    fn gnss(&mut self, device: &str, records: &[GnssRecord]) -> Result<()> {
        let c = self.gnss.entry(device.to_owned()).or_default();
        for r in records {
            if r.lat_deg.is_nan() {
                c.1 += 1;
            } else {
                c.0 += 1;
            }
        }
        Ok(())
    }
    fn truth_nav(&mut self, records: &[TruthNavRecord]) -> Result<()> {
        self.truth_nav_rows += records.len() as u64;
        Ok(())
    }
    fn truth_imu(&mut self, _device: &str, records: &[TruthImuRecord]) -> Result<()> {
        self.truth_imu_rows += records.len() as u64;
        Ok(())
    }
    fn event(&mut self, _event: &EventRecord) -> Result<()> {
        Ok(())
    }
}

/// Writes the simulated records as a session (same format as the daemon's, plus `/truth`).
pub struct SessionSink {
    writer: SessionWriter,
}

impl SessionSink {
    /// Creates the session directory `dir` for `scene` (it must not exist or be empty).
    pub fn create(dir: &Path, scene: &Scene) -> Result<Self> {
        Self::with_manifest(dir, session_manifest(scene)?)
    }

    /// Creates the session directory `dir` with this manifest.
    pub fn with_manifest(dir: &Path, manifest: Manifest) -> Result<Self> {
        // A simulation has no crash to survive: skip the per-second fsync of a live writer.
        let opts = WriterOptions {
            fsync_on_flush: false,
            ..WriterOptions::default()
        };
        let writer = SessionWriter::create(dir, manifest, opts)
            .with_context(|| format!("cannot create session {}", dir.display()))?;
        Ok(SessionSink { writer })
    }

    /// Writes what is buffered and finalises the session; returns its directory.
    pub fn close(self) -> Result<std::path::PathBuf> {
        Ok(self.writer.close()?)
    }
}

/// The manifest of a simulated session: one device per sensor, the scene's start time, the
/// truth rate when truth is wanted, and the scene file itself as the configuration.
pub fn session_manifest(scene: &Scene) -> Result<Manifest> {
    let mut devices = Vec::new();
    for imu in &scene.imus {
        let preset = scene
            .source
            .get("imu")
            .and_then(|v| v.as_array())
            .and_then(|a| {
                a.iter()
                    .find(|t| t.get("name").and_then(|n| n.as_str()) == Some(imu.name.as_str()))
            })
            .and_then(|t| t.get("preset"))
            .and_then(|p| p.as_str())
            .unwrap_or("custom");
        devices.push(DeviceInfo {
            name: imu.name.clone(),
            kind: DeviceKind::Imu,
            model: format!("simulated {preset}"),
            serial: String::new(),
            port: "sim".into(),
            protocol: "sim".into(),
            rate_hz: scene.rate_hz,
            axis_frame: "FRD".into(),
            extra: BTreeMap::new(),
        });
    }
    for rx in &scene.gnss {
        devices.push(DeviceInfo {
            name: rx.name.clone(),
            kind: DeviceKind::Gnss,
            model: "simulated GNSS".into(),
            serial: String::new(),
            port: "sim".into(),
            protocol: "sim".into(),
            rate_hz: rx.spec.rate_hz,
            axis_frame: "NED".into(),
            extra: BTreeMap::new(),
        });
    }
    let mut manifest = Manifest::new(devices, scene.source.clone());
    let start = chrono::DateTime::from_timestamp_nanos(scene.start_wall_ns);
    manifest.start_time = start;
    manifest.id = format!("sim-{}-seed{}", start.format("%Y%m%dT%H%M%SZ"), scene.seed);
    if scene.outputs.truth_nav || scene.outputs.truth_imu {
        manifest.truth_nav_rate_hz = Some(scene.rate_hz / f64::from(scene.outputs.truth_every));
    }
    Ok(manifest)
}

impl SimSink for SessionSink {
    fn imu(&mut self, device: &str, records: &[ImuRecord]) -> Result<()> {
        Ok(self.writer.append_imu(device, records)?)
    }
    fn rotation_period(&self) -> Option<std::time::Duration> {
        Some(self.writer.rotate_after())
    }
    fn gnss(&mut self, device: &str, records: &[GnssRecord]) -> Result<()> {
        Ok(self.writer.append_gnss(device, records)?)
    }
    fn truth_nav(&mut self, records: &[TruthNavRecord]) -> Result<()> {
        Ok(self.writer.append_truth_nav(records)?)
    }
    fn truth_imu(&mut self, device: &str, records: &[TruthImuRecord]) -> Result<()> {
        Ok(self.writer.append_truth_imu(device, records)?)
    }
    fn event(&mut self, event: &EventRecord) -> Result<()> {
        Ok(self.writer.append_event(event)?)
    }
}

/// Hands every record to two sinks, first `.0` then `.1` (e.g. a session and a summary).
pub struct Tee<'a>(pub &'a mut dyn SimSink, pub &'a mut dyn SimSink);

impl SimSink for Tee<'_> {
    fn imu(&mut self, device: &str, records: &[ImuRecord]) -> Result<()> {
        self.0.imu(device, records)?;
        self.1.imu(device, records)
    }
    fn gnss(&mut self, device: &str, records: &[GnssRecord]) -> Result<()> {
        self.0.gnss(device, records)?;
        self.1.gnss(device, records)
    }
    fn truth_nav(&mut self, records: &[TruthNavRecord]) -> Result<()> {
        self.0.truth_nav(records)?;
        self.1.truth_nav(records)
    }
    fn truth_imu(&mut self, device: &str, records: &[TruthImuRecord]) -> Result<()> {
        self.0.truth_imu(device, records)?;
        self.1.truth_imu(device, records)
    }
    fn event(&mut self, event: &EventRecord) -> Result<()> {
        self.0.event(event)?;
        self.1.event(event)
    }
    /// The first sink's, else the second's (a tee feeds at most one session).
    fn rotation_period(&self) -> Option<std::time::Duration> {
        self.0.rotation_period().or(self.1.rotation_period())
    }
}
