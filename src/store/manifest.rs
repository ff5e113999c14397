//! `session.toml`: what a session is (id, start, host, software, the full config used and the
//! devices recorded). Written once, atomically, when the session is created; chunk files are
//! found by listing the directory, so a crash can never leave the manifest out of step with them.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{StoreError, OLDEST_SESSION_SCHEMA_VERSION, SESSION_SCHEMA_VERSION};

/// File name of the manifest inside a session directory.
pub const MANIFEST_FILE: &str = "session.toml";

/// Longest device name accepted (it is stored in fixed-size event strings).
pub const MAX_DEVICE_NAME_LEN: usize = 63;

/// What kind of stream a device produces.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DeviceKind {
    Imu,
    Gnss,
}

impl DeviceKind {
    pub fn as_str(self) -> &'static str {
        match self {
            DeviceKind::Imu => "imu",
            DeviceKind::Gnss => "gnss",
        }
    }
}

/// One recorded device.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeviceInfo {
    /// Short name, also the HDF5 group name: letters, digits, `_`, `-`, `.`.
    pub name: String,
    pub kind: DeviceKind,
    #[serde(default)]
    pub model: String,
    #[serde(default)]
    pub serial: String,
    /// Where it was connected (`/dev/ttyUSB0`, `can0`, `sim`).
    #[serde(default)]
    pub port: String,
    /// Protocol/codec name.
    #[serde(default)]
    pub protocol: String,
    /// Nominal output rate, Hz. Sets the chunk size and the gap threshold.
    pub rate_hz: f64,
    /// How the device's axes are defined (e.g. `FRD`, `sensor`, `NED`).
    #[serde(default)]
    pub axis_frame: String,
    /// Anything else worth keeping (firmware, calibration id...).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub extra: BTreeMap<String, toml::Value>,
}

/// The manifest of a session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub schema_version: u32,
    pub id: String,
    pub start_time: chrono::DateTime<chrono::Utc>,
    #[serde(default)]
    pub host: String,
    #[serde(default)]
    pub software_version: String,
    /// Simulated sessions only: rate of `/truth/nav`, Hz. When set, the writer also creates
    /// `/truth/imu/<name>` for every IMU.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub truth_nav_rate_hz: Option<f64>,
    /// The full configuration the session was recorded with; opaque to the store.
    #[serde(default)]
    pub config: toml::Table,
    #[serde(default)]
    pub devices: Vec<DeviceInfo>,
}

impl Manifest {
    /// A manifest for a new session started now on this host, with the current schema and
    /// software version and an id made of the start time.
    pub fn new(devices: Vec<DeviceInfo>, config: toml::Table) -> Self {
        let start_time = chrono::Utc::now();
        let host = nix::unistd::gethostname()
            .ok()
            .and_then(|h| h.into_string().ok())
            .unwrap_or_default();
        Manifest {
            schema_version: SESSION_SCHEMA_VERSION,
            id: start_time.format("%Y%m%dT%H%M%S%.3fZ").to_string(),
            start_time,
            host,
            software_version: env!("CARGO_PKG_VERSION").to_string(),
            truth_nav_rate_hz: None,
            config,
            devices,
        }
    }

    pub fn device(&self, name: &str) -> Option<&DeviceInfo> {
        self.devices.iter().find(|d| d.name == name)
    }

    /// The device `name`, which must be of `kind` when one is given; else an error naming
    /// it and, when it is not in the manifest, the devices that are (for the writer's appends
    /// and the reader's streams alike).
    pub fn device_of_kind(
        &self,
        name: &str,
        kind: Option<DeviceKind>,
    ) -> Result<&DeviceInfo, StoreError> {
        match self.device(name) {
            Some(d) if kind.is_none_or(|k| k == d.kind) => Ok(d),
            Some(d) => Err(StoreError::UnknownDevice {
                device: name.into(),
                msg: format!(
                    "is a {} device, not {}",
                    d.kind.as_str(),
                    kind.map_or("", DeviceKind::as_str)
                ),
            }),
            None => Err(StoreError::UnknownDevice {
                device: name.into(),
                msg: format!(
                    "not in the session manifest (devices: {})",
                    self.devices
                        .iter()
                        .map(|d| d.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            }),
        }
    }

    /// Checks what the store relies on: known schema, usable and unique device names,
    /// finite positive rates. `path` is only used in the error.
    pub fn validate(&self, path: &Path) -> Result<(), StoreError> {
        let bad = |msg: String| StoreError::Manifest {
            path: path.to_path_buf(),
            msg,
        };
        if !(OLDEST_SESSION_SCHEMA_VERSION..=SESSION_SCHEMA_VERSION).contains(&self.schema_version)
        {
            return Err(StoreError::UnknownSchema {
                path: path.to_path_buf(),
                found: self.schema_version,
                supported: SESSION_SCHEMA_VERSION,
            });
        }
        if self.id.trim().is_empty() {
            return Err(bad("empty session id".into()));
        }
        if let Some(rate) = self.truth_nav_rate_hz {
            if !(rate.is_finite() && rate > 0.0) {
                return Err(bad(format!(
                    "truth_nav_rate_hz = {rate} is not a positive rate"
                )));
            }
        }
        for (i, d) in self.devices.iter().enumerate() {
            if !valid_device_name(&d.name) {
                return Err(bad(format!(
                    "device {:?}: name must be 1..={MAX_DEVICE_NAME_LEN} characters of letters, digits, '_', '-', '.'",
                    d.name
                )));
            }
            if self.devices[..i].iter().any(|o| o.name == d.name) {
                return Err(bad(format!("device {:?} listed twice", d.name)));
            }
            if !(d.rate_hz.is_finite() && d.rate_hz > 0.0) {
                return Err(bad(format!(
                    "device {:?}: rate_hz = {} is not a positive rate",
                    d.name, d.rate_hz
                )));
            }
        }
        Ok(())
    }

    /// Reads and validates `dir/session.toml`.
    pub fn load(dir: &Path) -> Result<Self, StoreError> {
        let not_a_session = |msg: String| StoreError::NotASession {
            path: dir.to_path_buf(),
            msg,
        };
        if !dir.exists() {
            return Err(not_a_session(
                "no such directory (check the path: a session is the directory imulogd \
                 or `imulab sim -o` wrote)"
                    .into(),
            ));
        }
        if !dir.is_dir() {
            return Err(not_a_session(format!(
                "it is a file; give the session directory (the one holding {MANIFEST_FILE})"
            )));
        }
        let path = dir.join(MANIFEST_FILE);
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(not_a_session(format!(
                    "no {MANIFEST_FILE} in it; give a session's own directory (it holds \
                     {MANIFEST_FILE} and chunk-*.h5 files)"
                )))
            }
            Err(e) => return Err(StoreError::io(path, e)),
        };
        // Look at the schema version first so a newer layout gets the right message rather
        // than a complaint about a field this build does not know.
        if let Ok(table) = text.parse::<toml::Table>() {
            if let Some(v) = table.get("schema_version").and_then(|v| v.as_integer()) {
                let known =
                    i64::from(OLDEST_SESSION_SCHEMA_VERSION)..=i64::from(SESSION_SCHEMA_VERSION);
                if !known.contains(&v) {
                    return Err(StoreError::UnknownSchema {
                        path,
                        found: u32::try_from(v).unwrap_or(u32::MAX),
                        supported: SESSION_SCHEMA_VERSION,
                    });
                }
            }
        }
        let manifest: Manifest = toml::from_str(&text).map_err(|e| StoreError::Manifest {
            path: path.clone(),
            msg: e.message().to_string()
                + &e.span()
                    .map(|s| format!(" (at byte {})", s.start))
                    .unwrap_or_default(),
        })?;
        manifest.validate(&path)?;
        Ok(manifest)
    }

    /// Writes `dir/session.toml` atomically: temp file, fsync, rename, fsync the directory.
    pub fn save(&self, dir: &Path) -> Result<PathBuf, StoreError> {
        let path = dir.join(MANIFEST_FILE);
        self.validate(&path)?;
        let text = toml::to_string(self).map_err(|e| StoreError::Manifest {
            path: path.clone(),
            msg: format!("cannot serialise: {e}"),
        })?;
        let tmp = dir.join(format!("{MANIFEST_FILE}.tmp"));
        let mut f = std::fs::File::create(&tmp).map_err(|e| StoreError::io(&tmp, e))?;
        f.write_all(text.as_bytes())
            .and_then(|_| f.sync_all())
            .map_err(|e| StoreError::io(&tmp, e))?;
        std::fs::rename(&tmp, &path).map_err(|e| StoreError::io(&path, e))?;
        fsync_dir(dir)?;
        Ok(path)
    }
}

fn valid_device_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= MAX_DEVICE_NAME_LEN
        && name != "."
        && name != ".."
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-' || b == b'.')
}

/// Takes the session's writer lock without waiting; `Ok(None)` when another process (a live
/// writer) holds it.
pub(crate) fn try_writer_lock(
    dir: &Path,
) -> Result<Option<nix::fcntl::Flock<std::fs::File>>, StoreError> {
    let path = dir.join(super::layout::WRITER_LOCK_FILE);
    let file = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .map_err(|e| StoreError::io(&path, e))?;
    match nix::fcntl::Flock::lock(file, nix::fcntl::FlockArg::LockExclusiveNonblock) {
        Ok(lock) => Ok(Some(lock)),
        Err((_, nix::errno::Errno::EWOULDBLOCK)) => Ok(None),
        Err((_, e)) => Err(StoreError::io(&path, std::io::Error::from(e))),
    }
}

/// Makes a rename or create in `dir` durable.
pub(crate) fn fsync_dir(dir: &Path) -> Result<(), StoreError> {
    std::fs::File::open(dir)
        .and_then(|d| d.sync_all())
        .map_err(|e| StoreError::io(dir, e))
}
