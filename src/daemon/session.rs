//! Opening the session a daemon run writes into: the directory name from the config's
//! pattern, the manifest (devices and the whole config), and [`StoreSink`], the thin adapter
//! that lets the writer thread write through `imulab::store::SessionWriter`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use imulab_store::{
    DeviceInfo, DeviceKind, EventRecord, GnssRecord, ImuRecord, Manifest, SessionWriter,
    WriterOptions,
};

use super::config::{expand_session_name, CheckedConfig, DeviceSpec, Transport};
use super::sink::RecordSink;

/// The session directory for a run starting now.
pub fn session_dir(config: &CheckedConfig, now: chrono::DateTime<chrono::Utc>) -> PathBuf {
    let host = nix::unistd::gethostname()
        .ok()
        .and_then(|h| h.into_string().ok())
        .unwrap_or_else(|| "host".to_string());
    config
        .session
        .output_dir
        .join(expand_session_name(&config.session.name, now, &host))
}

/// Whether a device's rows go to `/imu/<name>` or `/gnss/<name>`.
pub fn device_kind(spec: &DeviceSpec) -> DeviceKind {
    if spec.protocol.is_gnss() {
        DeviceKind::Gnss
    } else {
        DeviceKind::Imu
    }
}

/// The devices of the session: each configured device, and after a receiver its IMU.
pub fn device_infos(devices: &[DeviceSpec]) -> Vec<DeviceInfo> {
    devices
        .iter()
        .flat_map(|spec| std::iter::once(device_info(spec)).chain(receiver_imu_info(spec)))
        .collect()
}

/// A receiver's IMU (`[device.imu]`): an IMU device of protocol `ubx-esf` on the receiver's
/// port, whose rows take the receiver's `[device.axes]`; `receiver` names the device whose
/// port and counters it shares.
fn receiver_imu_info(spec: &DeviceSpec) -> Option<DeviceInfo> {
    let imu = spec.imu.as_ref()?;
    let mut info = device_info(spec);
    info.name = imu.name.clone();
    info.kind = DeviceKind::Imu;
    info.protocol = imulab_drivers::codec::Protocol::UbxEsf.name().to_string();
    info.rate_hz = imu.rate_hz;
    info.extra.insert(
        "receiver".to_string(),
        toml::Value::String(spec.name.clone()),
    );
    Some(info)
}

fn device_info(spec: &DeviceSpec) -> DeviceInfo {
    let port = match &spec.transport {
        Transport::Serial(s) => s.port.display().to_string(),
        Transport::Slcan(s) => s.port.display().to_string(),
        Transport::Tcp(t) => t.address.clone(),
        Transport::Can(c) => c.interface.clone(),
        Transport::File(f) => f.path.display().to_string(),
    };
    let mut extra = BTreeMap::new();
    let rotated = spec.body_from_sensor != nalgebra::Matrix3::identity();
    if rotated {
        let rows: Vec<toml::Value> = (0..3)
            .map(|r| {
                toml::Value::Array(
                    (0..3)
                        .map(|c| toml::Value::Float(spec.body_from_sensor[(r, c)]))
                        .collect(),
                )
            })
            .collect();
        extra.insert("body_from_sensor".to_string(), toml::Value::Array(rows));
    }
    extra.insert(
        "transport".to_string(),
        toml::Value::String(spec.transport.describe()),
    );
    if let Some(imu) = &spec.imu {
        extra.insert("imu".to_string(), toml::Value::String(imu.name.clone()));
    }
    DeviceInfo {
        name: spec.name.clone(),
        kind: device_kind(spec),
        model: String::new(),
        serial: String::new(),
        port,
        protocol: spec.protocol.name().to_string(),
        rate_hz: spec.rate_hz,
        axis_frame: if rotated { "body" } else { "sensor" }.to_string(),
        extra,
    }
}

/// The store's writer options for this config.
pub fn writer_options(config: &CheckedConfig) -> WriterOptions {
    let s = &config.session;
    // 0 turns a rotation trigger off; the store wants a positive limit, so use "never".
    let never = Duration::from_secs(100 * 365 * 86_400);
    WriterOptions {
        rotate_after: if s.rotate_minutes > 0.0 {
            Duration::from_secs_f64(s.rotate_minutes * 60.0)
        } else {
            never
        },
        rotate_bytes: if s.rotate_mb > 0 {
            s.rotate_mb.saturating_mul(1 << 20)
        } else {
            u64::MAX
        },
        flush_interval: super::run::writer_flush_interval(s.flush_interval_ms),
        chunk_interval: std::time::Duration::from_millis(s.chunk_interval_ms()),
        deflate_level: s.deflate_level,
        raw_journal: config.any_raw_journal(),
        rows_per_chunk: None,
        fsync_on_flush: true,
    }
}

/// Creates the session in `dir` and returns the sink that writes it.
pub fn open_session_sink(config: &CheckedConfig, dir: &Path) -> anyhow::Result<StoreSink> {
    let devices = device_infos(&config.devices);
    let manifest = Manifest::new(devices, config.table.clone());
    let writer = SessionWriter::create(dir, manifest, writer_options(config))
        .map_err(|e| anyhow::anyhow!("cannot create session {}: {e}", dir.display()))?;
    Ok(StoreSink {
        writer: Some(writer),
    })
}

/// [`RecordSink`] over the session store's writer.
pub struct StoreSink {
    writer: Option<SessionWriter>,
}

impl StoreSink {
    fn writer(&mut self) -> anyhow::Result<&mut SessionWriter> {
        self.writer
            .as_mut()
            .ok_or_else(|| anyhow::anyhow!("the session is already closed"))
    }
}

impl RecordSink for StoreSink {
    fn append_imu(&mut self, device: &str, rows: &[ImuRecord]) -> anyhow::Result<()> {
        Ok(self.writer()?.append_imu(device, rows)?)
    }

    fn append_gnss(&mut self, device: &str, rows: &[GnssRecord]) -> anyhow::Result<()> {
        Ok(self.writer()?.append_gnss(device, rows)?)
    }

    fn append_event(&mut self, event: &EventRecord) -> anyhow::Result<()> {
        Ok(self.writer()?.append_event(event)?)
    }

    fn append_raw(&mut self, device: &str, t_mono_ns: i64, bytes: &[u8]) -> anyhow::Result<()> {
        Ok(self.writer()?.append_raw(device, t_mono_ns, bytes)?)
    }

    /// The store writes on chunk boundaries by itself; this is its idle timer, so rows of a
    /// quiet device still reach the disk within a flush interval and time rotation happens.
    /// Given the grid point rather than the time of the call: every device's rows are in up
    /// to that point, so a chunk the next hand-over completes is not written half first.
    fn flush(&mut self, now_mono_ns: i64) -> anyhow::Result<()> {
        Ok(self.writer()?.maybe_flush_and_rotate(now_mono_ns)?)
    }

    fn write_buffered(&mut self) -> anyhow::Result<()> {
        Ok(self.writer()?.flush()?)
    }

    fn rotate(&mut self) -> anyhow::Result<()> {
        Ok(self.writer()?.rotate()?)
    }

    fn close(&mut self) -> anyhow::Result<()> {
        let writer = self
            .writer
            .take()
            .ok_or_else(|| anyhow::anyhow!("the session is already closed"))?;
        let dir = writer.close()?;
        tracing::info!("session {} closed", dir.display());
        Ok(())
    }

    fn current_file(&self) -> Option<PathBuf> {
        self.writer
            .as_ref()
            .and_then(|w| w.current_file())
            .map(Path::to_path_buf)
    }
}
