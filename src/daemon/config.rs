//! The imulogd configuration file (TOML): parsing, validation and the checked form the daemon
//! runs from.
//!
//! Parsing is two steps. Serde (with `deny_unknown_fields`, and `serde_path_to_error` for the
//! key path) rejects unknown keys and wrong types; [`Config::validate`] then checks values
//! and combinations. Every rejection names the key path (`device[1].serial.baud`), says what
//! is wrong and gives a hint.

use std::collections::HashSet;
use std::fmt;
use std::path::{Path, PathBuf};

use imulab_drivers::codec::csv_line::CsvLineConfig;
use imulab_drivers::codec::RowsFrom;
use nalgebra::Matrix3;

use imulab_ingest::mapping::ImuMapping;
use imulab_store::manifest::MAX_DEVICE_NAME_LEN;
use serde::{Deserialize, Serialize};

/// A rejected configuration: where, what, and how to fix it.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfigIssue {
    /// Key path, e.g. `device[0].serial.baud` (empty for a syntax error with no path).
    pub path: String,
    pub message: String,
    pub hint: Option<String>,
}

impl fmt::Display for ConfigIssue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.path.is_empty() {
            write!(f, "{}", self.message)?;
        } else {
            write!(f, "{}: {}", self.path, self.message)?;
        }
        if let Some(hint) = &self.hint {
            write!(f, " (hint: {hint})")?;
        }
        Ok(())
    }
}

/// Every problem found in one configuration file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub struct ConfigError {
    /// The file the configuration came from ("<string>" when parsed from memory).
    pub source_name: String,
    pub issues: Vec<ConfigIssue>,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "invalid configuration {}:", self.source_name)?;
        for issue in &self.issues {
            write!(f, "\n  {issue}")?;
        }
        Ok(())
    }
}

impl ConfigError {
    /// True when some issue's path starts with `path` and its message contains `needle`.
    pub fn has_issue(&self, path: &str, needle: &str) -> bool {
        self.issues
            .iter()
            .any(|i| i.path.starts_with(path) && i.message.contains(needle))
    }
}

/// The whole file.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    pub session: SessionConfig,
    #[serde(rename = "device", default)]
    pub devices: Vec<DeviceConfig>,
}

/// `[session]`: where and how the session is written.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SessionConfig {
    /// Directory the session directories are created in.
    pub output_dir: PathBuf,
    /// Session directory name; `{date}` (YYYYMMDD), `{time}` (HHMMSS, UTC) and `{host}` expand.
    #[serde(default = "default_session_name")]
    pub name: String,
    /// Start a new chunk file after this many minutes (0 = no time-based rotation).
    #[serde(default = "default_rotate_minutes")]
    pub rotate_minutes: f64,
    /// Start a new chunk file after this many MB (0 = no size-based rotation).
    #[serde(default = "default_rotate_mb")]
    pub rotate_mb: u64,
    /// Flush buffered rows to disk this often; at most this much is lost on SIGKILL.
    #[serde(default = "default_flush_interval_ms")]
    pub flush_interval_ms: u64,
    /// Rows per HDF5 chunk = rate × this interval; a whole multiple of the flush interval.
    /// Rows wait in the write-ahead journal until their chunk is complete (docs/session-format.md).
    /// Default: 10 s, rounded up to a multiple of the flush interval
    /// ([`SessionConfig::chunk_interval_ms`]).
    #[serde(default)]
    pub chunk_interval_ms: Option<u64>,
    /// Deflate level for the HDF5 datasets, 0 (off) to 9.
    #[serde(default = "default_deflate_level")]
    pub deflate_level: u8,
    /// Also keep the undecoded bytes (`/raw/<device>`), so the session can be decoded again.
    #[serde(default)]
    pub raw_journal: bool,
    /// Close the session cleanly and exit non-zero when free space falls below this.
    #[serde(default = "default_disk_reserve_mb")]
    pub disk_reserve_mb: u64,
    /// Where the status JSON is written every second (default `<output_dir>/imulogd-status.json`).
    #[serde(default)]
    pub status_file: Option<PathBuf>,
    /// Batches that may wait for the writer before readers start dropping (and counting) them.
    #[serde(default = "default_queue_capacity")]
    pub queue_capacity: usize,
}

/// Chunk interval when the config gives none: 10 s, rounded up to a whole number of flushes.
pub const DEFAULT_CHUNK_INTERVAL_MS: u64 = 10_000;

impl SessionConfig {
    /// The chunk interval in effect: the configured one, or the default rounded up to a
    /// whole multiple of the flush interval.
    pub fn chunk_interval_ms(&self) -> u64 {
        self.chunk_interval_ms.unwrap_or_else(|| {
            let flush = self.flush_interval_ms.max(1);
            DEFAULT_CHUNK_INTERVAL_MS.div_ceil(flush) * flush
        })
    }
}

fn default_session_name() -> String {
    "{date}-{time}".to_string()
}
fn default_rotate_minutes() -> f64 {
    10.0
}
fn default_rotate_mb() -> u64 {
    256
}
fn default_flush_interval_ms() -> u64 {
    1000
}
/// The session writer's own default (chosen by measurement: docs/bench/store.md).
fn default_deflate_level() -> u8 {
    imulab_store::WriterOptions::default().deflate_level
}
fn default_disk_reserve_mb() -> u64 {
    512
}
fn default_queue_capacity() -> usize {
    1024
}

/// Device protocols: the rows of the drivers' protocol table, by their names there.
pub use imulab_drivers::codec::Protocol;

/// `[device.serial]`: a serial port (or a pty standing in for one).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SerialConfig {
    pub port: PathBuf,
    #[serde(default = "default_baud")]
    pub baud: u32,
}
fn default_baud() -> u32 {
    115_200
}

/// `[device.tcp]`: a TCP byte stream (ser2net and the like).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TcpConfig {
    /// `host:port`.
    pub address: String,
}

/// `[device.can]`: a SocketCAN interface.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CanConfig {
    pub interface: String,
    /// Informational for SocketCAN (the interface's bitrate is set with `ip link`).
    #[serde(default)]
    pub bitrate: Option<u32>,
}

/// `[device.slcan]`: a Lawicel/slcan USB-CAN adapter on a serial port.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SlcanConfig {
    pub port: PathBuf,
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// CAN bitrate the adapter is opened at.
    pub bitrate: u32,
}

/// CAN bitrates an slcan adapter can be opened at (`S0`..`S8`).
pub const SLCAN_BITRATES: [u32; 9] = [
    10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000,
];

/// `[device.file]`: a capture played back through the daemon as if it were the device: a
/// raw byte capture (what a serial port sent), a candump log (for `can-dbc`), or a session
/// directory whose raw record (`/raw/<device>`, `raw_journal`) is replayed read by read.
/// Relative paths are relative to the configuration file. The device ends at the end of the
/// file (it is not reopened); the session ends once every device has ended.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FileConfig {
    pub path: PathBuf,
    /// `"recorded"` (the capture's own timing), `"fast"` (as fast as the writer takes it),
    /// or a factor (2 = twice the recorded pace).
    #[serde(default)]
    pub pace: PaceSetting,
    /// A raw byte capture has no time stamps: it is paced as a serial line at this baud
    /// (8N1: baud / 10 bytes per second).
    #[serde(default)]
    pub baud: Option<u32>,
    /// For a session directory: whose raw record to play (default: this device's name).
    #[serde(default)]
    pub device: Option<String>,
}

/// `pace` as written: a word or a number.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(untagged)]
pub enum PaceSetting {
    Word(String),
    Factor(f64),
}

impl Default for PaceSetting {
    fn default() -> Self {
        PaceSetting::Word("recorded".to_string())
    }
}

/// How fast a file source plays, after validation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pace {
    /// No waiting: as fast as the decoder and the writer go (the writer queue then waits
    /// instead of dropping).
    Fast,
    /// The recorded timing divided by this factor (1 = as recorded).
    Factor(f64),
}

/// A validated `[device.file]`.
#[derive(Debug, Clone, PartialEq)]
pub struct FileSource {
    pub path: PathBuf,
    pub pace: Pace,
    pub baud: Option<u32>,
    pub device: Option<String>,
}

/// `[device.dbc]`: the DBC file of a CAN IMU and the signal mapping (TOML, the drivers'
/// format: `fixtures/imu_can_mapping.toml`, `docs/protocols-imu-can.md`). Relative paths are
/// relative to the configuration file.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DbcConfig {
    pub file: PathBuf,
    pub mapping: PathBuf,
}

/// `[device.axes]`: how the sensor's axes map into the body frame. Give one of the two.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct AxesConfig {
    /// Body x, y, z as signed sensor axes, e.g. `["-y", "x", "z"]`.
    #[serde(default)]
    pub map: Option<[String; 3]>,
    /// Rotation matrix body ← sensor, row by row (proper rotation: orthonormal, det +1).
    #[serde(default)]
    pub rotation: Option<[[f64; 3]; 3]>,
}

/// Units the device's numbers are really in, when they are not what the codec assumes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
pub enum GyroUnit {
    #[default]
    #[serde(rename = "rad/s")]
    RadPerS,
    #[serde(rename = "deg/s")]
    DegPerS,
    #[serde(rename = "mrad/s")]
    MilliradPerS,
}

impl GyroUnit {
    /// Factor that converts a value in this unit to rad/s.
    pub fn to_si(self) -> f64 {
        match self {
            GyroUnit::RadPerS => 1.0,
            GyroUnit::DegPerS => std::f64::consts::PI / 180.0,
            GyroUnit::MilliradPerS => 1e-3,
        }
    }
}

/// Accelerometer units (see [`GyroUnit`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
pub enum AccelUnit {
    #[default]
    #[serde(rename = "m/s2")]
    MetrePerS2,
    #[serde(rename = "g")]
    StandardGravity,
    #[serde(rename = "mg")]
    MilliG,
}

/// Standard gravity, m/s² (the definition of 1 g, not local gravity).
pub const STANDARD_GRAVITY: f64 = 9.806_65;

impl AccelUnit {
    /// Factor that converts a value in this unit to m/s².
    pub fn to_si(self) -> f64 {
        match self {
            AccelUnit::MetrePerS2 => 1.0,
            AccelUnit::StandardGravity => STANDARD_GRAVITY,
            AccelUnit::MilliG => STANDARD_GRAVITY * 1e-3,
        }
    }
}

/// `[device.units]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, Default)]
#[serde(deny_unknown_fields)]
pub struct UnitsConfig {
    #[serde(default)]
    pub gyro: GyroUnit,
    #[serde(default)]
    pub accel: AccelUnit,
}

/// One `[[device]]`.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DeviceConfig {
    /// Name used for the HDF5 groups and the status (letters, digits, `-`, `_`).
    pub name: String,
    pub protocol: Protocol,
    /// Nominal output rate, Hz; used for gap detection and the status.
    pub rate_hz: f64,
    /// A pause longer than this many nominal periods is a gap event.
    #[serde(default = "default_gap_factor")]
    pub gap_factor: f64,
    #[serde(default)]
    pub serial: Option<SerialConfig>,
    #[serde(default)]
    pub tcp: Option<TcpConfig>,
    #[serde(default)]
    pub can: Option<CanConfig>,
    #[serde(default)]
    pub slcan: Option<SlcanConfig>,
    #[serde(default)]
    pub file: Option<FileConfig>,
    #[serde(default)]
    pub dbc: Option<DbcConfig>,
    /// The line format of a `csv` device (the drivers' [`CsvLineConfig`]); default layout
    /// `time,gx,gy,gz,ax,ay,az,temp` in SI units when absent.
    #[serde(default)]
    pub csv: Option<CsvLineConfig>,
    #[serde(default)]
    pub axes: Option<AxesConfig>,
    #[serde(default)]
    pub units: Option<UnitsConfig>,
    /// Gyro and accelerometer rows from the rates or from delta theta / delta velocity, for a
    /// VectorNav or MIP device that sends both; default: the rates.
    #[serde(default)]
    pub rows_from: Option<RowsFrom>,
    /// First retry delay after the device vanished or failed to open, ms.
    #[serde(default = "default_retry_initial_ms")]
    pub retry_initial_ms: u64,
    /// Longest retry delay (the delay doubles up to this), ms.
    #[serde(default = "default_retry_max_ms")]
    pub retry_max_ms: u64,
    /// Keep this device's undecoded bytes (`/raw/<name>`); default: `[session] raw_journal`.
    #[serde(default)]
    pub raw_journal: Option<bool>,
    /// For a u-blox dead-reckoning receiver (`ubx`, `gnss`): the IMU device its UBX ESF-RAW
    /// / ESF-MEAS samples on the same port are logged as.
    #[serde(default)]
    pub imu: Option<ReceiverImuConfig>,
}

/// `[device.imu]`: the IMU of a dead-reckoning receiver, a second device of the session fed
/// from the receiver's port (its rows: `/imu/<name>`, protocol `ubx-esf`).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ReceiverImuConfig {
    /// The IMU device's name (its HDF5 group), distinct from every device's.
    pub name: String,
    /// Its nominal sample rate, Hz (gap detection, chunk size, the status).
    pub rate_hz: f64,
}

/// `gap_factor` when a device does not set it (also what `imulab inspect` uses for a
/// session whose configuration does not record it).
pub const DEFAULT_GAP_FACTOR: f64 = 3.0;

fn default_gap_factor() -> f64 {
    DEFAULT_GAP_FACTOR
}
fn default_retry_initial_ms() -> u64 {
    250
}
fn default_retry_max_ms() -> u64 {
    8000
}

/// Where a device's bytes or frames come from, after validation.
#[derive(Debug, Clone, PartialEq)]
pub enum Transport {
    Serial(SerialConfig),
    Tcp(TcpConfig),
    Can(CanConfig),
    Slcan(SlcanConfig),
    File(FileSource),
}

impl Transport {
    /// A short human description (`serial /dev/ttyUSB0 @ 115200`).
    pub fn describe(&self) -> String {
        match self {
            Transport::Serial(s) => format!("serial {} @ {}", s.port.display(), s.baud),
            Transport::Tcp(t) => format!("tcp {}", t.address),
            Transport::Can(c) => format!("can {}", c.interface),
            Transport::Slcan(s) => format!("slcan {} @ {} bit/s", s.port.display(), s.bitrate),
            Transport::File(f) => {
                let pace = match f.pace {
                    Pace::Fast => "fast".to_string(),
                    Pace::Factor(1.0) => "recorded pace".to_string(),
                    Pace::Factor(x) => format!("{x}x recorded pace"),
                };
                format!("file {} ({pace})", f.path.display())
            }
        }
    }

    /// True for a file source: it ends at the end of the file and is never reopened.
    pub fn is_file(&self) -> bool {
        matches!(self, Transport::File(_))
    }
}

/// A device ready to run: transport resolved, axis rotation and unit factors computed.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceSpec {
    pub name: String,
    pub protocol: Protocol,
    pub transport: Transport,
    pub rate_hz: f64,
    pub gap_factor: f64,
    /// Body ← sensor rotation applied to gyro and accel.
    pub body_from_sensor: Matrix3<f64>,
    pub gyro_scale: f64,
    pub accel_scale: f64,
    pub dbc: Option<DbcConfig>,
    pub csv: Option<CsvLineConfig>,
    pub rows_from: RowsFrom,
    pub retry_initial_ms: u64,
    pub retry_max_ms: u64,
    /// Whether this device's undecoded bytes are kept (`/raw/<name>`).
    pub raw_journal: bool,
    /// The receiver's IMU, logged as a device of its own from this device's port.
    pub imu: Option<ReceiverImuConfig>,
}

impl DeviceSpec {
    /// How this device's frames become rows (its axis rotation and unit scales).
    pub fn imu_mapping(&self) -> ImuMapping {
        ImuMapping {
            body_from_sensor: self.body_from_sensor,
            gyro_scale: self.gyro_scale,
            accel_scale: self.accel_scale,
        }
    }

    /// Rows per second the device delivers at its nominal rates (its own and its IMU's).
    pub fn rows_rate_hz(&self) -> f64 {
        self.rate_hz + self.imu.as_ref().map_or(0.0, |imu| imu.rate_hz)
    }
}

/// The validated configuration the daemon runs from.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckedConfig {
    pub session: SessionConfig,
    pub devices: Vec<DeviceSpec>,
    /// The file as written (all keys, defaults not filled in), for the session manifest.
    pub table: toml::Table,
}

impl CheckedConfig {
    /// True when some device keeps its undecoded bytes (the session then has `/raw/<name>`
    /// groups).
    pub fn any_raw_journal(&self) -> bool {
        self.devices.iter().any(|d| d.raw_journal)
    }

    /// Where the status JSON goes.
    pub fn status_path(&self) -> PathBuf {
        self.session
            .status_file
            .clone()
            .unwrap_or_else(|| self.session.output_dir.join("imulogd-status.json"))
    }
}

/// Reads, parses and validates a configuration file.
pub fn load(path: &Path) -> Result<CheckedConfig, ConfigError> {
    let source_name = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| ConfigError {
        source_name: source_name.clone(),
        issues: vec![ConfigIssue {
            path: String::new(),
            message: format!("cannot read the file: {e}"),
            hint: Some("give the path of an existing, readable TOML file".into()),
        }],
    })?;
    let mut checked = parse(&text, &source_name)?;
    // DBC files are named relative to the configuration file, not the working directory
    // (which is `/` under systemd).
    let base = path.parent().unwrap_or(Path::new(""));
    for device in &mut checked.devices {
        if let Some(dbc) = &mut device.dbc {
            dbc.file = base.join(&dbc.file);
            dbc.mapping = base.join(&dbc.mapping);
        }
        if let Transport::File(f) = &mut device.transport {
            f.path = base.join(&f.path);
        }
    }
    let clashes = shared_port_issues(&checked.devices);
    if !clashes.is_empty() {
        return Err(ConfigError {
            source_name,
            issues: clashes,
        });
    }
    Ok(checked)
}

/// What a device holds exclusively: a serial port (serial or slcan, after following
/// symlinks such as udev names), or a CAN interface together with the DBC mapping that
/// selects its frames (two devices decoding the same frames would each record them).
#[derive(Debug, PartialEq, Eq)]
enum Endpoint {
    SerialPort(PathBuf),
    CanFrames { interface: String, mapping: PathBuf },
}

fn canonical_or_given(path: &Path) -> PathBuf {
    std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf())
}

fn endpoint(spec: &DeviceSpec) -> Option<Endpoint> {
    match &spec.transport {
        Transport::Serial(s) => Some(Endpoint::SerialPort(canonical_or_given(&s.port))),
        Transport::Slcan(s) => Some(Endpoint::SerialPort(canonical_or_given(&s.port))),
        Transport::Can(c) => Some(Endpoint::CanFrames {
            interface: c.interface.clone(),
            mapping: spec
                .dbc
                .as_ref()
                .map(|d| canonical_or_given(&d.mapping))
                .unwrap_or_default(),
        }),
        // A TCP server (ser2net and the like) may serve several clients; a file can be read
        // by several devices (a session's devices from one session directory).
        Transport::Tcp(_) | Transport::File(_) => None,
    }
}

/// Devices that would open the same port: the second would retry forever at run time.
fn shared_port_issues(devices: &[DeviceSpec]) -> Vec<ConfigIssue> {
    let endpoints: Vec<Option<Endpoint>> = devices.iter().map(endpoint).collect();
    let mut issues = Vec::new();
    for (j, later) in endpoints.iter().enumerate() {
        let Some(later) = later else { continue };
        let Some(i) = endpoints[..j]
            .iter()
            .position(|e| e.as_ref() == Some(later))
        else {
            continue;
        };
        let (what, hint) = match later {
            Endpoint::SerialPort(port) => (
                format!("the port {}", port.display()),
                "a serial port can be opened by one device only; give each device its own port",
            ),
            Endpoint::CanFrames { interface, .. } => (
                format!("the CAN interface {interface} with the same DBC mapping"),
                "both would decode the same frames; give one device per mapped CAN IMU",
            ),
        };
        issues.push(ConfigIssue {
            path: format!("device[{j}]"),
            message: format!(
                "devices `{}` (device[{i}]) and `{}` (device[{j}]) both use {what}",
                devices[i].name, devices[j].name
            ),
            hint: Some(hint.to_string()),
        });
    }
    issues
}

/// Parses and validates configuration text; `source_name` is used in the error.
pub fn parse(text: &str, source_name: &str) -> Result<CheckedConfig, ConfigError> {
    let fail = |issues| ConfigError {
        source_name: source_name.to_string(),
        issues,
    };
    let deserializer = toml::Deserializer::parse(text).map_err(|e| {
        fail(vec![ConfigIssue {
            path: String::new(),
            message: format!("TOML syntax error: {}", e.to_string().trim_end()),
            hint: Some("see systemd/imulogd.toml for a complete example".into()),
        }])
    })?;
    let config: Config = serde_path_to_error::deserialize(deserializer).map_err(|e| {
        let path = e.path().to_string();
        let message = e.inner().message().trim_end().to_string();
        let line = e
            .inner()
            .span()
            .map(|span| 1 + text[..span.start.min(text.len())].matches('\n').count());
        let hint = hint_for_serde_message(&message);
        fail(vec![ConfigIssue {
            path: if path == "." { String::new() } else { path },
            message: match line {
                Some(line) => format!("{message} (line {line})"),
                None => message,
            },
            hint,
        }])
    })?;
    let mut checked = config.validate().map_err(fail)?;
    // The text parsed above as a Config, so it is a valid table too.
    checked.table = toml::from_str(text).unwrap_or_default();
    Ok(checked)
}

/// Turns serde's "unknown field `x`, expected one of `a`, `b`" into a "did you mean" hint.
fn hint_for_serde_message(message: &str) -> Option<String> {
    let quoted: Vec<&str> = message.split('`').skip(1).step_by(2).collect();
    let (given, expected) = quoted.split_first()?;
    if message.starts_with("unknown field") || message.starts_with("unknown variant") {
        let best = expected
            .iter()
            .min_by_key(|candidate| edit_distance(given, candidate))?;
        let close = edit_distance(given, best) <= 2.max(given.len() / 3);
        let contained = expected
            .iter()
            .find(|c| c.len() >= 3 && (given.contains(**c) || c.contains(given)));
        if let Some(c) = contained.filter(|_| !close) {
            return Some(format!("did you mean `{c}`?"));
        }
        if close {
            return Some(format!("did you mean `{best}`?"));
        }
        return Some(format!("allowed: {}", expected.join(", ")));
    }
    None
}

/// Levenshtein distance, for "did you mean" hints on a handful of short key names.
fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut previous: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut current = vec![i + 1; b.len() + 1];
        for (j, cb) in b.iter().enumerate() {
            let substitution = previous[j] + usize::from(ca != *cb);
            current[j + 1] = substitution.min(previous[j + 1] + 1).min(current[j] + 1);
        }
        previous = current;
    }
    previous[b.len()]
}

/// Collects issues while validating.
struct Issues(Vec<ConfigIssue>);

impl Issues {
    fn add(&mut self, path: impl Into<String>, message: impl Into<String>, hint: &str) {
        self.0.push(ConfigIssue {
            path: path.into(),
            message: message.into(),
            hint: (!hint.is_empty()).then(|| hint.to_string()),
        });
    }
}

impl Config {
    /// Checks values and combinations; returns the runnable form or every issue found.
    pub fn validate(&self) -> Result<CheckedConfig, Vec<ConfigIssue>> {
        let mut issues = Issues(Vec::new());
        self.validate_session(&mut issues);
        if self.devices.is_empty() {
            issues.add(
                "device",
                "no devices configured",
                "add at least one [[device]] table with name, protocol, rate_hz and a transport",
            );
        }
        let mut names = HashSet::new();
        let mut devices = Vec::new();
        for (index, device) in self.devices.iter().enumerate() {
            let path = format!("device[{index}]");
            if !names.insert(device.name.as_str()) {
                issues.add(
                    format!("{path}.name"),
                    format!("duplicate device name `{}`", device.name),
                    "every device needs its own name; it names the HDF5 group",
                );
            }
            if let Some(spec) = validate_device(device, &path, &self.session, &mut issues) {
                devices.push(spec);
            }
        }
        self.validate_imu_names(&mut issues);
        if issues.0.is_empty() {
            let (floor_mb, set_by_fast) = reserve_floor(&self.session, &devices);
            if self.session.disk_reserve_mb < floor_mb {
                let hint = if set_by_fast {
                    format!(
                        "use at least {floor_mb}: a pace = \"fast\" replay writes as fast as the writer goes, so free space is checked after every 1/{RESERVE_CHECKS_PER_RESERVE} of the reserve written, and the reserve must hold {RESERVE_CHECKS_PER_RESERVE} of the largest batches a device hands over (or play at a factor, e.g. pace = 50, whose floor follows from the rates)"
                    )
                } else {
                    format!(
                        "use at least {floor_mb}: rows (HDF5 and journal) and raw bytes at the configured rates times each replay's pace factor over max(flush_interval_ms, {} ms); below that the disk can fill before the daemon stops",
                        RESERVE_CHECK_INTERVAL_MS
                    )
                };
                issues.add(
                    "session.disk_reserve_mb",
                    format!(
                        "{} MB is less than the {floor_mb} MB the configured devices can write between two free-space checks",
                        self.session.disk_reserve_mb
                    ),
                    &hint,
                );
                return Err(issues.0);
            }
            Ok(CheckedConfig {
                session: self.session.clone(),
                devices,
                table: toml::Table::new(),
            })
        } else {
            Err(issues.0)
        }
    }

    /// A receiver's IMU is a device of the session: its name may be no other device's (nor
    /// another receiver's IMU's).
    fn validate_imu_names(&self, issues: &mut Issues) {
        for (index, device) in self.devices.iter().enumerate() {
            let Some(imu) = &device.imu else { continue };
            let device_clash = self.devices.iter().position(|d| d.name == imu.name);
            let imu_clash = self.devices[..index]
                .iter()
                .position(|d| d.imu.as_ref().is_some_and(|other| other.name == imu.name));
            let owner = match (device_clash, imu_clash) {
                (Some(j), _) if j == index => "this device's own name".to_string(),
                (Some(j), _) => format!("the name of device[{j}]"),
                (None, Some(j)) => format!("the name of device[{j}]'s imu"),
                (None, None) => continue,
            };
            issues.add(
                format!("device[{index}].imu.name"),
                format!("`{}` is already {owner}", imu.name),
                "the receiver's IMU is a device of its own: give it a name no other device has (it names its HDF5 group)",
            );
        }
    }

    fn validate_session(&self, issues: &mut Issues) {
        let s = &self.session;
        if s.output_dir.as_os_str().is_empty() {
            issues.add(
                "session.output_dir",
                "is empty",
                "give the directory sessions are written in, e.g. /var/lib/imulogd",
            );
        }
        if s.name.is_empty() || s.name.contains('/') || s.name.contains('\0') {
            issues.add(
                "session.name",
                format!("`{}` is not a valid directory name", s.name),
                "use letters, digits, -, _ and the placeholders {date}, {time}, {host}",
            );
        } else if let Err(bad) = check_placeholders(&s.name) {
            issues.add(
                "session.name",
                format!("unknown placeholder `{{{bad}}}`"),
                "allowed placeholders: {date}, {time}, {host}",
            );
        }
        if !s.rotate_minutes.is_finite() || s.rotate_minutes < 0.0 {
            issues.add(
                "session.rotate_minutes",
                format!("{} is not a duration in minutes", s.rotate_minutes),
                "use a number >= 0 (0 turns time-based rotation off)",
            );
        }
        if !(10..=60_000).contains(&s.flush_interval_ms) {
            issues.add(
                "session.flush_interval_ms",
                format!("{} is out of range", s.flush_interval_ms),
                "use 10 to 60000 ms; at most one interval of data is lost on a hard kill",
            );
        }
        if let Some(chunk) = s.chunk_interval_ms {
            let flush = s.flush_interval_ms.max(1);
            if !(flush..=600_000).contains(&chunk) || chunk % flush != 0 {
                issues.add(
                    "session.chunk_interval_ms",
                    format!(
                        "{chunk} is not a whole multiple (1x to 600000 ms) of flush_interval_ms = {}",
                        s.flush_interval_ms
                    ),
                    &format!(
                        "use e.g. {} (10 s rounded up to whole flushes), or leave it out for that default",
                        DEFAULT_CHUNK_INTERVAL_MS.div_ceil(flush) * flush
                    ),
                );
            }
        }
        if s.deflate_level > 9 {
            issues.add(
                "session.deflate_level",
                format!("{} is out of range", s.deflate_level),
                "use 0 (no compression) to 9",
            );
        }
        if s.queue_capacity == 0 || s.queue_capacity > 1_000_000 {
            issues.add(
                "session.queue_capacity",
                format!("{} is out of range", s.queue_capacity),
                "use 1 to 1000000 batches",
            );
        }
        if let Some(status) = &s.status_file {
            if status.as_os_str().is_empty() || status.file_name().is_none() {
                issues.add(
                    "session.status_file",
                    "is not a file path",
                    "e.g. /run/imulogd/status.json, or leave it out",
                );
            }
        }
    }
}

/// How often the daemon checks free space.
pub const RESERVE_CHECK_INTERVAL_MS: u64 = 1000;
/// Free space is also checked after every `reserve / RESERVE_CHECKS_PER_RESERVE` bytes
/// written, whatever the rate ([`super::writer::WriterSettings::disk_check_bytes`]).
pub const RESERVE_CHECKS_PER_RESERVE: u64 = 4;

/// How many times its configured rate a device can deliver: a file source's pace factor
/// (`Some(1)` for a live device), `None` for `pace = "fast"` (no rate bounds it).
fn speed_up(transport: &Transport) -> Option<f64> {
    match transport {
        Transport::File(FileSource {
            pace: Pace::Fast, ..
        }) => None,
        Transport::File(FileSource {
            pace: Pace::Factor(x),
            ..
        }) => Some(*x),
        _ => Some(1.0),
    }
}

/// The smallest safe `disk_reserve_mb`, and whether a `pace = "fast"` replay set it.
///
/// What every device can write in the longest time between two timed free-space checks, at
/// its configured rate times its replay speed-up (a file source's `pace` factor). A row is
/// counted twice (its HDF5 dataset and the write-ahead journal) at its in-memory size (no
/// compression assumed: `deflate_level` may be 0); with a device's `raw_journal`, a serial
/// line adds its top byte rate (baud / 10, 8N1), other transports their row rate × the
/// largest frame.
///
/// A `pace = "fast"` replay has no rate: the writer goes as fast as it can. For it the
/// writer's check by volume (free space looked at after every quarter of the reserve
/// written) is what holds, and that needs the reserve to take four of the largest batches a
/// device hands over ([`super::device::max_batch_disk_bytes`]): between two checks at most a
/// quarter of the reserve and one batch are written, so half the reserve is still free when
/// the daemon stops, for what is queued and for closing.
pub fn reserve_floor(session: &SessionConfig, devices: &[DeviceSpec]) -> (u64, bool) {
    const LARGEST_FRAME_BYTES: f64 = 256.0;
    let window_s = session.flush_interval_ms.max(RESERVE_CHECK_INTERVAL_MS) as f64 / 1000.0;
    let mut fast = false;
    let bytes_per_s: f64 = devices
        .iter()
        .map(|d| {
            let Some(speed_up) = speed_up(&d.transport) else {
                fast = true;
                return 0.0;
            };
            let imu_row = std::mem::size_of::<imulab_store::ImuRecord>() as f64;
            let row = if d.protocol.is_gnss() {
                std::mem::size_of::<imulab_store::GnssRecord>() as f64
            } else {
                imu_row
            };
            let imu_rows = d.imu.as_ref().map_or(0.0, |imu| imu.rate_hz * imu_row);
            let raw = match (&d.transport, d.raw_journal) {
                (_, false) => 0.0,
                (Transport::Serial(s), true) => f64::from(s.baud) / 10.0,
                (Transport::Slcan(s), true) => f64::from(s.baud) / 10.0,
                (
                    Transport::File(FileSource {
                        baud: Some(baud), ..
                    }),
                    true,
                ) => f64::from(*baud) / 10.0,
                (_, true) => d.rate_hz * LARGEST_FRAME_BYTES,
            };
            speed_up * (2.0 * (d.rate_hz * row + imu_rows) + raw)
        })
        .sum();
    let mib = f64::from(1u32 << 20);
    let by_rate = (bytes_per_s * window_s / mib).ceil() as u64;
    if !fast {
        return (by_rate, false);
    }
    let by_volume =
        (RESERVE_CHECKS_PER_RESERVE as f64 * super::device::max_batch_disk_bytes() as f64 / mib)
            .ceil() as u64;
    (by_rate.max(by_volume), by_volume >= by_rate)
}

/// Checks that every `{...}` in a session name is a known placeholder.
fn check_placeholders(name: &str) -> Result<(), String> {
    let mut rest = name;
    while let Some(open) = rest.find('{') {
        let after = &rest[open + 1..];
        let Some(close) = after.find('}') else {
            return Err(after.to_string());
        };
        let key = &after[..close];
        if !matches!(key, "date" | "time" | "host") {
            return Err(key.to_string());
        }
        rest = &after[close + 1..];
    }
    Ok(())
}

fn validate_device(
    d: &DeviceConfig,
    path: &str,
    session: &SessionConfig,
    issues: &mut Issues,
) -> Option<DeviceSpec> {
    let before = issues.0.len();
    if !valid_device_name(&d.name) {
        issues.add(
            format!("{path}.name"),
            format!("`{}` is not a valid device name", d.name),
            "use 1 to 63 letters, digits, - or _",
        );
    }
    if !d.rate_hz.is_finite() || d.rate_hz <= 0.0 || d.rate_hz > 100_000.0 {
        issues.add(
            format!("{path}.rate_hz"),
            format!("{} is not a usable rate", d.rate_hz),
            "give the device's nominal output rate in Hz, above 0 and at most 100000",
        );
    }
    if !d.gap_factor.is_finite() || d.gap_factor < 1.5 || d.gap_factor > 1000.0 {
        issues.add(
            format!("{path}.gap_factor"),
            format!("{} is out of range", d.gap_factor),
            "use 1.5 to 1000 nominal periods (default 3)",
        );
    }
    if d.retry_initial_ms == 0 || d.retry_initial_ms > d.retry_max_ms {
        issues.add(
            format!("{path}.retry_initial_ms"),
            format!(
                "{} ms must be above 0 and at most retry_max_ms ({} ms)",
                d.retry_initial_ms, d.retry_max_ms
            ),
            "e.g. retry_initial_ms = 250, retry_max_ms = 8000",
        );
    }
    if d.retry_max_ms > 600_000 {
        issues.add(
            format!("{path}.retry_max_ms"),
            format!("{} ms is more than 10 minutes", d.retry_max_ms),
            "a long wait loses data after the device comes back; use at most 600000",
        );
    }

    let transport = validate_transport(d, path, issues);
    validate_dbc(d, path, issues);
    validate_csv(d, path, issues);
    if d.rows_from.is_some() && !matches!(d.protocol, Protocol::Vectornav | Protocol::Mip) {
        issues.add(
            format!("{path}.rows_from"),
            format!(
                "protocol `{}` sends no delta theta / delta velocity to choose",
                d.protocol.name()
            ),
            "remove rows_from, or use it with protocol = \"vectornav\" or \"mip\"",
        );
    }
    if let Some(imu) = &d.imu {
        validate_receiver_imu(d.protocol, imu, &format!("{path}.imu"), issues);
    }
    let body_from_sensor = match &d.axes {
        None => Matrix3::identity(),
        Some(axes) => validate_axes(axes, &format!("{path}.axes"), issues),
    };
    let units = d.units.unwrap_or_default();
    if issues.0.len() > before {
        return None;
    }
    Some(DeviceSpec {
        name: d.name.clone(),
        protocol: d.protocol,
        transport: transport?,
        rate_hz: d.rate_hz,
        gap_factor: d.gap_factor,
        body_from_sensor,
        gyro_scale: units.gyro.to_si(),
        accel_scale: units.accel.to_si(),
        dbc: d.dbc.clone(),
        csv: d.csv.clone(),
        rows_from: d.rows_from.unwrap_or_default(),
        retry_initial_ms: d.retry_initial_ms,
        retry_max_ms: d.retry_max_ms,
        raw_journal: d.raw_journal.unwrap_or(session.raw_journal),
        imu: d.imu.clone(),
    })
}

/// Whether `name` can name a device (it names HDF5 groups and fits the event records).
fn valid_device_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= MAX_DEVICE_NAME_LEN
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
}

/// `[device.imu]` of a device with `protocol`: a u-blox receiver's port, a usable name and
/// rate (their clashes with other devices' names are checked with all devices).
fn validate_receiver_imu(
    protocol: Protocol,
    imu: &ReceiverImuConfig,
    path: &str,
    issues: &mut Issues,
) {
    if !matches!(protocol, Protocol::Ubx | Protocol::Gnss) {
        issues.add(
            path.to_string(),
            format!(
                "protocol `{}` carries no UBX ESF messages to log as an IMU",
                protocol.name()
            ),
            "use imu with protocol = \"ubx\" or \"gnss\" (a u-blox dead-reckoning receiver's port), or log an IMU-only port with protocol = \"ubx-esf\"",
        );
    }
    if !valid_device_name(&imu.name) {
        issues.add(
            format!("{path}.name"),
            format!("`{}` is not a valid device name", imu.name),
            "use 1 to 63 letters, digits, - or _",
        );
    }
    if !imu.rate_hz.is_finite() || imu.rate_hz <= 0.0 || imu.rate_hz > 100_000.0 {
        issues.add(
            format!("{path}.rate_hz"),
            format!("{} is not a usable rate", imu.rate_hz),
            "give the receiver's ESF sample rate in Hz (e.g. 100), above 0 and at most 100000",
        );
    }
}

fn validate_transport(d: &DeviceConfig, path: &str, issues: &mut Issues) -> Option<Transport> {
    let mut given = Vec::new();
    if let Some(s) = &d.serial {
        given.push(("serial", Transport::Serial(s.clone())));
    }
    if let Some(t) = &d.tcp {
        given.push(("tcp", Transport::Tcp(t.clone())));
    }
    if let Some(c) = &d.can {
        given.push(("can", Transport::Can(c.clone())));
    }
    if let Some(s) = &d.slcan {
        given.push(("slcan", Transport::Slcan(s.clone())));
    }
    if let Some(f) = &d.file {
        let pace = match &f.pace {
            PaceSetting::Word(w) if w == "recorded" => Some(Pace::Factor(1.0)),
            PaceSetting::Word(w) if w == "fast" => Some(Pace::Fast),
            PaceSetting::Factor(x) if x.is_finite() && *x > 0.0 && *x <= 1e6 => {
                Some(Pace::Factor(*x))
            }
            other => {
                let shown = match other {
                    PaceSetting::Word(w) => format!("`{w}`"),
                    PaceSetting::Factor(x) => x.to_string(),
                };
                issues.add(
                    format!("{path}.file.pace"),
                    format!("{shown} is not a pace"),
                    "use \"recorded\", \"fast\" or a speed factor above 0, e.g. 4",
                );
                None
            }
        };
        if f.path.as_os_str().is_empty() {
            issues.add(
                format!("{path}.file.path"),
                "is empty",
                "the capture to play: a raw byte file, a candump log or a session directory",
            );
        }
        if let Some(baud) = f.baud {
            check_baud(baud, &format!("{path}.file.baud"), issues);
        }
        given.push((
            "file",
            Transport::File(FileSource {
                path: f.path.clone(),
                pace: pace.unwrap_or(Pace::Fast),
                baud: f.baud,
                device: f.device.clone(),
            }),
        ));
    }
    if given.len() != 1 {
        let names: Vec<&str> = given.iter().map(|(n, _)| *n).collect();
        issues.add(
            path.to_string(),
            if given.is_empty() {
                "no transport given".to_string()
            } else {
                format!("more than one transport given ({})", names.join(", "))
            },
            "give exactly one of [device.serial], [device.tcp], [device.can], [device.slcan], [device.file]",
        );
        return None;
    }
    let (kind, transport) = given.pop()?;
    let on_can = matches!(transport, Transport::Can(_) | Transport::Slcan(_));
    // A file carries either: bytes, or (for `can-dbc`) a candump log of frames.
    if !transport.is_file() && d.protocol.is_can() != on_can {
        issues.add(
            format!("{path}.{kind}"),
            format!(
                "protocol `{}` cannot run over a {kind} transport",
                d.protocol.name()
            ),
            if on_can {
                "CAN transports carry protocol `can-dbc`"
            } else {
                "protocol `can-dbc` needs [device.can] or [device.slcan]"
            },
        );
    }
    match &transport {
        Transport::Serial(s) => {
            check_port(&s.port, &format!("{path}.serial.port"), issues);
            check_baud(s.baud, &format!("{path}.serial.baud"), issues);
        }
        Transport::Slcan(s) => {
            check_port(&s.port, &format!("{path}.slcan.port"), issues);
            check_baud(s.baud, &format!("{path}.slcan.baud"), issues);
            if !SLCAN_BITRATES.contains(&s.bitrate) {
                issues.add(
                    format!("{path}.slcan.bitrate"),
                    format!("{} bit/s is not an slcan bitrate", s.bitrate),
                    "use one of 10000, 20000, 50000, 100000, 125000, 250000, 500000, 800000, 1000000",
                );
            }
        }
        Transport::Tcp(t) => {
            let port_ok = t
                .address
                .rsplit_once(':')
                .is_some_and(|(host, port)| !host.is_empty() && port.parse::<u16>().is_ok());
            if !port_ok {
                issues.add(
                    format!("{path}.tcp.address"),
                    format!("`{}` is not host:port", t.address),
                    "e.g. \"192.168.1.20:4001\" or \"[::1]:4001\"",
                );
            }
        }
        // Checked in full against the file system when the source is made
        // (`source::connector_for`, also run by --check-config).
        Transport::File(_) => {}
        Transport::Can(c) => {
            if c.interface.is_empty()
                || c.interface.len() > 15
                || c.interface.contains('/')
                || c.interface.chars().any(char::is_whitespace)
            {
                issues.add(
                    format!("{path}.can.interface"),
                    format!("`{}` is not a network interface name", c.interface),
                    "e.g. \"can0\" or \"vcan0\" (at most 15 characters)",
                );
            }
        }
    }
    Some(transport)
}

fn check_port(port: &Path, path: &str, issues: &mut Issues) {
    if !port.is_absolute() {
        issues.add(
            path.to_string(),
            format!("`{}` is not an absolute device path", port.display()),
            "e.g. /dev/ttyUSB0 or a stable udev name such as /dev/imu-A1B2C3",
        );
    }
}

fn check_baud(baud: u32, path: &str, issues: &mut Issues) {
    if !(300..=12_000_000).contains(&baud) {
        issues.add(
            path.to_string(),
            format!("{baud} is not a serial baud rate"),
            "use 300 to 12000000, e.g. 115200 or 921600",
        );
    }
}

fn validate_dbc(d: &DeviceConfig, path: &str, issues: &mut Issues) {
    match (&d.dbc, d.protocol.entry().dbc) {
        (None, true) => issues.add(
            format!("{path}.dbc"),
            format!("protocol `{}` needs a DBC mapping", d.protocol.name()),
            "add dbc = { file = \"imu.dbc\", mapping = \"imu_mapping.toml\" }",
        ),
        (Some(_), false) => issues.add(
            format!("{path}.dbc"),
            format!("protocol `{}` does not use a DBC file", d.protocol.name()),
            "remove [device.dbc] or set protocol = \"can-dbc\"",
        ),
        (Some(dbc), true) => {
            for (key, file) in [("file", &dbc.file), ("mapping", &dbc.mapping)] {
                if file.as_os_str().is_empty() {
                    issues.add(
                        format!("{path}.dbc.{key}"),
                        "is empty",
                        "path of the DBC file and of its signal mapping (TOML)",
                    );
                }
            }
        }
        (None, false) => {}
    }
}

fn validate_csv(d: &DeviceConfig, path: &str, issues: &mut Issues) {
    match (&d.csv, d.protocol) {
        (Some(csv), Protocol::Csv) => {
            if let Err(e) = csv.validate() {
                // The drivers' message starts with the key (`csv.separator: ...`).
                let (key, message) = match e.split_once(": ") {
                    Some((key, message)) if key.starts_with("csv") => {
                        (key.to_string(), message.to_string())
                    }
                    _ => ("csv".to_string(), e.clone()),
                };
                issues.add(
                    format!("{path}.{key}"),
                    message,
                    "see [device.csv] in docs/daemon.md: separator, comment_prefix, time, gyro, accel, temp, status",
                );
            }
        }
        (Some(_), protocol) => issues.add(
            format!("{path}.csv"),
            format!(
                "protocol `{}` does not use a CSV line format",
                protocol.name()
            ),
            "remove [device.csv] or set protocol = \"csv\"",
        ),
        (None, _) => {}
    }
}

/// Parses one signed axis name (`x`, `-y`, `+z`) into (index, sign).
fn parse_axis(name: &str) -> Option<(usize, f64)> {
    let (sign, axis) = match name.trim().as_bytes() {
        [b'-', a] => (-1.0, *a),
        [b'+', a] | [a] => (1.0, *a),
        _ => return None,
    };
    let index = match axis.to_ascii_lowercase() {
        b'x' => 0,
        b'y' => 1,
        b'z' => 2,
        _ => return None,
    };
    Some((index, sign))
}

fn validate_axes(axes: &AxesConfig, path: &str, issues: &mut Issues) -> Matrix3<f64> {
    let matrix = match (&axes.map, &axes.rotation) {
        (Some(_), Some(_)) | (None, None) => {
            issues.add(
                path.to_string(),
                "give exactly one of `map` and `rotation`",
                "map = [\"-y\", \"x\", \"z\"] or rotation = [[0,-1,0],[1,0,0],[0,0,1]]",
            );
            return Matrix3::identity();
        }
        (Some(map), None) => {
            let mut m = Matrix3::zeros();
            let mut used = [false; 3];
            for (row, name) in map.iter().enumerate() {
                match parse_axis(name) {
                    Some((col, sign)) if !used[col] => {
                        used[col] = true;
                        m[(row, col)] = sign;
                    }
                    Some(_) => issues.add(
                        format!("{path}.map[{row}]"),
                        format!("sensor axis `{name}` is used twice"),
                        "each of x, y, z appears exactly once",
                    ),
                    None => issues.add(
                        format!("{path}.map[{row}]"),
                        format!("`{name}` is not an axis"),
                        "use x, y, z with an optional sign, e.g. \"-y\"",
                    ),
                }
            }
            m
        }
        (None, Some(rows)) => Matrix3::from_fn(|r, c| rows[r][c]),
    };
    if matrix.iter().any(|v| !v.is_finite()) {
        issues.add(
            format!("{path}.rotation"),
            "contains a non-finite number",
            "",
        );
        return Matrix3::identity();
    }
    let orthonormal_error = (matrix * matrix.transpose() - Matrix3::identity()).amax();
    if axes.rotation.is_some() && orthonormal_error > 1e-6 {
        issues.add(
            format!("{path}.rotation"),
            format!("is not orthonormal (|R·Rᵀ − I| = {orthonormal_error:.2e})"),
            "give a rotation matrix body ← sensor with unit, orthogonal rows",
        );
    } else if matrix.determinant() < 0.0 {
        issues.add(
            path.to_string(),
            "describes a reflection (determinant −1), not a rotation",
            "flip the sign of one axis: a right-handed sensor frame stays right-handed",
        );
    }
    matrix
}

/// Expands `{date}`, `{time}` and `{host}` in a session name.
pub fn expand_session_name(
    pattern: &str,
    now: chrono::DateTime<chrono::Utc>,
    host: &str,
) -> String {
    pattern
        .replace("{date}", &now.format("%Y%m%d").to_string())
        .replace("{time}", &now.format("%H%M%S").to_string())
        .replace("{host}", host)
}

/// What the host says about the configured paths; the part of the check that cannot be done
/// from the text alone. Run by `--check-config` and before a session is created.
#[derive(Debug, Clone, PartialEq)]
pub struct HostCheck {
    /// Problems that would only show at run time, as config issues.
    pub issues: Vec<ConfigIssue>,
    /// True when `output_dir` does not exist yet and will be created.
    pub output_dir_created: bool,
    /// True when the status file's directory (other than `output_dir`) will be created.
    pub status_dir_created: bool,
}

/// Checks `output_dir` (an existing writable directory, or creatable under one) and
/// `status_file` (its directory likewise, and an existing file there must be an imulogd
/// status file: the daemon replaces it every second).
pub fn check_host(config: &CheckedConfig) -> HostCheck {
    let mut issues = Issues(Vec::new());
    let output_dir = &config.session.output_dir;
    let output_dir_created = check_writable_dir(output_dir, "session.output_dir", &mut issues);
    let status = config.status_path();
    let status_dir = status
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let status_dir_created = status_dir != output_dir.as_path()
        && check_writable_dir(status_dir, "session.status_file", &mut issues);
    if status.is_dir() {
        issues.add(
            "session.status_file",
            format!("{} is a directory", status.display()),
            "give a file path, e.g. /run/imulogd/status.json",
        );
    } else if status.exists() {
        if let Err(e) = super::status::read_status_file(&status) {
            issues.add(
                "session.status_file",
                format!("refusing to replace {}: {e:#}", status.display()),
                "the daemon rewrites this file every second; point status_file at a new path or remove the file",
            );
        }
    }
    HostCheck {
        issues: issues.0,
        output_dir_created,
        status_dir_created,
    }
}

/// Checks that `dir` is a directory files can be created in, or that it can be created.
/// Returns true when it does not exist yet. Writability is tried with a real file (a
/// permission check would pass for root on a read-only mount).
fn check_writable_dir(dir: &Path, key: &str, issues: &mut Issues) -> bool {
    let mut existing = dir;
    while !existing.exists() {
        match existing.parent() {
            Some(parent) if !parent.as_os_str().is_empty() => existing = parent,
            _ => {
                existing = Path::new(".");
                break;
            }
        }
    }
    let missing = existing != dir;
    if !existing.is_dir() {
        issues.add(
            key,
            if missing {
                format!(
                    "{} cannot be created: {} is not a directory",
                    dir.display(),
                    existing.display()
                )
            } else {
                format!("{} is not a directory", dir.display())
            },
            "give a directory path",
        );
        return missing;
    }
    let probe = existing.join(format!(".imulogd-write-check-{}", std::process::id()));
    match std::fs::File::create(&probe) {
        Ok(_) => {
            let _ = std::fs::remove_file(&probe);
        }
        Err(e) => issues.add(
            key,
            if missing {
                format!(
                    "{} cannot be created: cannot write in {}: {e}",
                    dir.display(),
                    existing.display()
                )
            } else {
                format!("cannot write in {}: {e}", dir.display())
            },
            "give a directory the daemon's user can write (ReadWritePaths= in the unit)",
        ),
    }
    missing
}
