//! Serial ports through `tokio-serial`: baud rate, data bits, parity, stop bits and flow
//! control from a [`SerialConfig`]. Works on USB-serial adapters and on Linux ptys (whose
//! baud setting is accepted and ignored by the kernel).

use std::io;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use tokio_serial::{SerialPortBuilderExt, SerialStream};

use super::{StreamTransport, TransportError};

/// Parity setting.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Parity {
    #[default]
    None,
    Odd,
    Even,
}

/// Flow control setting.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FlowControl {
    #[default]
    None,
    /// XON/XOFF.
    Software,
    /// RTS/CTS.
    Hardware,
}

/// How to open a serial port.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SerialConfig {
    /// Device path, e.g. `/dev/ttyUSB0` or a `/dev/serial/by-id/...` link.
    pub path: String,
    pub baud: u32,
    #[serde(default = "default_data_bits")]
    pub data_bits: u8,
    #[serde(default)]
    pub parity: Parity,
    #[serde(default = "default_stop_bits")]
    pub stop_bits: u8,
    #[serde(default)]
    pub flow_control: FlowControl,
    /// Silence longer than this is a [`TransportError::Timeout`]; `None` waits forever.
    #[serde(default, with = "opt_secs")]
    pub idle_timeout: Option<Duration>,
}

fn default_data_bits() -> u8 {
    8
}
fn default_stop_bits() -> u8 {
    1
}

mod opt_secs {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};
    use std::time::Duration;

    pub fn serialize<S: Serializer>(d: &Option<Duration>, s: S) -> Result<S::Ok, S::Error> {
        d.map(|d| d.as_secs_f64()).serialize(s)
    }
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Duration>, D::Error> {
        let secs: Option<f64> = Option::deserialize(d)?;
        secs.map(|s| {
            Duration::try_from_secs_f64(s).map_err(|_| {
                serde::de::Error::custom(format!(
                    "idle_timeout {s} is not a valid duration in seconds"
                ))
            })
        })
        .transpose()
    }
}

impl SerialConfig {
    /// 8N1, no flow control, no idle timeout.
    pub fn new(path: impl Into<String>, baud: u32) -> Self {
        SerialConfig {
            path: path.into(),
            baud,
            data_bits: 8,
            parity: Parity::None,
            stop_bits: 1,
            flow_control: FlowControl::None,
            idle_timeout: None,
        }
    }
}

/// An open serial port.
pub type SerialTransport = StreamTransport<SerialStream>;

/// Opens the port. Must run inside a tokio runtime.
pub fn open_serial(config: &SerialConfig) -> Result<SerialTransport, TransportError> {
    let data_bits = match config.data_bits {
        5 => tokio_serial::DataBits::Five,
        6 => tokio_serial::DataBits::Six,
        7 => tokio_serial::DataBits::Seven,
        8 => tokio_serial::DataBits::Eight,
        n => {
            return Err(TransportError::Config(format!(
                "serial.data_bits: {n} (valid 5-8)"
            )))
        }
    };
    let stop_bits = match config.stop_bits {
        1 => tokio_serial::StopBits::One,
        2 => tokio_serial::StopBits::Two,
        n => {
            return Err(TransportError::Config(format!(
                "serial.stop_bits: {n} (valid 1, 2)"
            )))
        }
    };
    if config.baud == 0 {
        return Err(TransportError::Config(
            "serial.baud: must be positive".into(),
        ));
    }
    let parity = match config.parity {
        Parity::None => tokio_serial::Parity::None,
        Parity::Odd => tokio_serial::Parity::Odd,
        Parity::Even => tokio_serial::Parity::Even,
    };
    let flow = match config.flow_control {
        FlowControl::None => tokio_serial::FlowControl::None,
        FlowControl::Software => tokio_serial::FlowControl::Software,
        FlowControl::Hardware => tokio_serial::FlowControl::Hardware,
    };
    let stream = tokio_serial::new(&config.path, config.baud)
        .data_bits(data_bits)
        .parity(parity)
        .stop_bits(stop_bits)
        .flow_control(flow)
        .open_native_async()
        .map_err(|e| TransportError::Open {
            device: config.path.clone(),
            source: open_error(&config.path, e),
        })?;
    Ok(StreamTransport::new(
        stream,
        config.path.clone(),
        config.idle_timeout,
    ))
}

/// Turns a failed open of the serial port `path` into an error that says what happened and
/// what to do (busy, permission, missing). `serialport` keeps only the text of the errno, so
/// the errno is read again by opening `path` as it does (read-write, `O_NOCTTY | O_NONBLOCK`,
/// no exclusive lock), closing it at once if that works; then the original error is kept.
pub fn open_error(path: &str, err: tokio_serial::Error) -> io::Error {
    let original = io::Error::from(err);
    let Some(errno) = probe_open_errno(path) else {
        return original;
    };
    let (kind, msg) = match errno {
        libc::EBUSY => (
            io::ErrorKind::ResourceBusy,
            format!(
                "in use by another process; find it with `fuser {path}` (or `fuser -v {path}`), \
                 stop it, then try again"
            ),
        ),
        libc::EACCES | libc::EPERM => (
            io::ErrorKind::PermissionDenied,
            "permission denied; add yourself to the dialout group: sudo usermod -aG dialout \
             $USER, then log in again"
                .to_string(),
        ),
        libc::ENOENT | libc::ENODEV | libc::ENXIO => (
            io::ErrorKind::NotFound,
            "no such device; check it is plugged in and the path (ls -l /dev/serial/by-id/)"
                .to_string(),
        ),
        _ => return original,
    };
    io::Error::new(kind, msg)
}

#[cfg(unix)]
fn probe_open_errno(path: &str) -> Option<i32> {
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(libc::O_NOCTTY | libc::O_NONBLOCK)
        .open(path)
        .err()
        .and_then(|e| e.raw_os_error())
}

#[cfg(not(unix))]
fn probe_open_errno(_path: &str) -> Option<i32> {
    None
}
