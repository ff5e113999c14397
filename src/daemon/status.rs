//! Live counters shared by the device tasks and the writer, and the status file built from
//! them every second (JSON, replaced atomically) that `imulab status` prints.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};

use serde::{Deserialize, Serialize};

use super::config::DeviceSpec;

/// Where a device is in its life.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DeviceState {
    /// Not opened yet.
    #[default]
    Opening,
    /// Open and reading.
    Connected,
    /// Was connected, vanished, being retried.
    Reconnecting,
    /// Never opened successfully; being retried. An error in the status, not a crash.
    Absent,
    /// Stopped (shutdown).
    Stopped,
}

/// Counters of one device, updated by its task (and drop counts by its queue sender).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DeviceCounters {
    pub state: DeviceState,
    pub frames_ok: u64,
    /// Checksum failures, malformed and over-long frames.
    pub frames_bad: u64,
    pub bytes: u64,
    pub resyncs: u64,
    pub reconnects: u64,
    pub gaps: u64,
    pub imu_rows: u64,
    pub gnss_rows: u64,
    /// Frames of the other kind than the device's (e.g. IMU data from a GNSS receiver), not
    /// written because the session has no table for them.
    pub ignored_frames: u64,
    /// Batches the writer queue had no room for, and the rows/events in them.
    pub dropped_batches: u64,
    pub dropped_rows: u64,
    pub dropped_events: u64,
    pub last_sample_mono_ns: Option<i64>,
    pub last_error: Option<String>,
}

/// One device's shared status cell.
#[derive(Debug)]
pub struct DeviceShared {
    pub name: String,
    pub protocol: String,
    pub transport: String,
    pub expected_rate_hz: f64,
    /// The device a receiver's IMU rows are written as (`[device.imu]`); `None`: this one.
    pub imu_device: Option<String>,
    counters: Mutex<DeviceCounters>,
}

impl DeviceShared {
    pub fn new(name: &str, protocol: &str, transport: &str, expected_rate_hz: f64) -> Arc<Self> {
        Arc::new(DeviceShared {
            name: name.to_string(),
            protocol: protocol.to_string(),
            transport: transport.to_string(),
            expected_rate_hz,
            imu_device: None,
            counters: Mutex::new(DeviceCounters::default()),
        })
    }

    /// The status cell of a configured device: its rate is that of all its rows (a
    /// receiver's fixes and its IMU's samples).
    pub fn of(spec: &DeviceSpec) -> Arc<Self> {
        Arc::new(DeviceShared {
            name: spec.name.clone(),
            protocol: spec.protocol.name().to_string(),
            transport: spec.transport.describe(),
            expected_rate_hz: spec.rows_rate_hz(),
            imu_device: spec.imu.as_ref().map(|imu| imu.name.clone()),
            counters: Mutex::new(DeviceCounters::default()),
        })
    }

    /// The counters, for update or reading. Poisoning is ignored: counters stay usable.
    pub fn counters(&self) -> MutexGuard<'_, DeviceCounters> {
        self.counters.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// Counters of the writer thread.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct WriterCounters {
    pub session_dir: Option<PathBuf>,
    pub current_file: Option<PathBuf>,
    pub rows_written: u64,
    pub flushes: u64,
    pub rotations: u64,
    pub free_bytes: Option<u64>,
    pub reserve_bytes: u64,
    pub stopping: bool,
}

/// The writer's shared status cell.
#[derive(Debug, Default)]
pub struct WriterShared {
    counters: Mutex<WriterCounters>,
}

impl WriterShared {
    pub fn counters(&self) -> MutexGuard<'_, WriterCounters> {
        self.counters.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// The status file's content (version 1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StatusReport {
    pub version: u32,
    pub pid: u32,
    /// When this report was written, RFC 3339 UTC.
    pub written_at: String,
    pub uptime_s: f64,
    /// `running` or `stopping`.
    pub state: String,
    pub session_dir: Option<PathBuf>,
    pub current_file: Option<PathBuf>,
    pub rows_written: u64,
    pub free_bytes: Option<u64>,
    pub reserve_bytes: u64,
    pub devices: Vec<DeviceStatus>,
}

/// One device's line in the status.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DeviceStatus {
    pub name: String,
    pub protocol: String,
    pub transport: String,
    pub state: DeviceState,
    /// Rows per second expected: the device's rate, plus its IMU's for a receiver with one.
    pub expected_rate_hz: f64,
    /// A receiver's IMU device (`[device.imu]`), whose rows are counted here.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub imu_device: Option<String>,
    /// Rows per second over the last status interval.
    pub rate_hz: f64,
    /// Seconds since the last decoded sample (None before the first).
    pub last_sample_age_s: Option<f64>,
    pub frames_ok: u64,
    pub frames_bad: u64,
    pub bytes: u64,
    pub resyncs: u64,
    pub reconnects: u64,
    pub gaps: u64,
    pub dropped_rows: u64,
    #[serde(default)]
    pub ignored_frames: u64,
    pub last_error: Option<String>,
}

/// Builds reports; remembers the previous row counts to measure rates.
pub struct StatusTracker {
    devices: Vec<Arc<DeviceShared>>,
    writer: Arc<WriterShared>,
    started_mono_ns: i64,
    previous: Option<(i64, Vec<u64>)>,
}

impl StatusTracker {
    pub fn new(
        devices: Vec<Arc<DeviceShared>>,
        writer: Arc<WriterShared>,
        now_mono_ns: i64,
    ) -> Self {
        StatusTracker {
            devices,
            writer,
            started_mono_ns: now_mono_ns,
            previous: None,
        }
    }

    /// The report as of `now_mono_ns` (CLOCK_MONOTONIC) and `now_wall` (for `written_at`).
    pub fn report(
        &mut self,
        now_mono_ns: i64,
        now_wall: chrono::DateTime<chrono::Utc>,
    ) -> StatusReport {
        let snapshots: Vec<DeviceCounters> =
            self.devices.iter().map(|d| d.counters().clone()).collect();
        let rows: Vec<u64> = snapshots.iter().map(|c| c.imu_rows + c.gnss_rows).collect();
        let (since_ns, before) = match &self.previous {
            Some((t, counts)) => (*t, counts.clone()),
            None => (self.started_mono_ns, vec![0; rows.len()]),
        };
        let dt_s = (now_mono_ns - since_ns) as f64 * 1e-9;
        let devices = self
            .devices
            .iter()
            .zip(&snapshots)
            .enumerate()
            .map(|(i, (d, c))| DeviceStatus {
                name: d.name.clone(),
                protocol: d.protocol.clone(),
                transport: d.transport.clone(),
                state: c.state,
                expected_rate_hz: d.expected_rate_hz,
                imu_device: d.imu_device.clone(),
                rate_hz: if dt_s > 0.0 {
                    rows[i].saturating_sub(before[i]) as f64 / dt_s
                } else {
                    0.0
                },
                last_sample_age_s: c
                    .last_sample_mono_ns
                    .map(|t| ((now_mono_ns - t) as f64 * 1e-9).max(0.0)),
                frames_ok: c.frames_ok,
                frames_bad: c.frames_bad,
                bytes: c.bytes,
                resyncs: c.resyncs,
                reconnects: c.reconnects,
                gaps: c.gaps,
                dropped_rows: c.dropped_rows,
                ignored_frames: c.ignored_frames,
                last_error: c.last_error.clone(),
            })
            .collect();
        self.previous = Some((now_mono_ns, rows));
        let w = self.writer.counters().clone();
        StatusReport {
            version: 1,
            pid: std::process::id(),
            written_at: now_wall.to_rfc3339_opts(chrono::SecondsFormat::Millis, true),
            uptime_s: (now_mono_ns - self.started_mono_ns) as f64 * 1e-9,
            state: if w.stopping { "stopping" } else { "running" }.to_string(),
            session_dir: w.session_dir,
            current_file: w.current_file,
            rows_written: w.rows_written,
            free_bytes: w.free_bytes,
            reserve_bytes: w.reserve_bytes,
            devices,
        }
    }
}

/// Writes the report next to `path` and renames it over `path`, so a reader never sees a
/// half-written file.
pub fn write_status_file(path: &Path, report: &StatusReport) -> std::io::Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    // Serialised in memory and written at once: straight into the file, the serialiser's
    // small pieces were ~500 write calls per report.
    let mut text = serde_json::to_vec_pretty(report)?;
    text.push(b'\n');
    std::fs::File::create(&tmp)?.write_all(&text)?;
    std::fs::rename(&tmp, path)
}

/// Reads a status file written by [`write_status_file`].
pub fn read_status_file(path: &Path) -> anyhow::Result<StatusReport> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| anyhow::anyhow!("cannot read status file {}: {e}", path.display()))?;
    serde_json::from_str(&text)
        .map_err(|e| anyhow::anyhow!("{} is not an imulogd status file: {e}", path.display()))
}
