//! Serial ports: opened and configured by `serialport` (baud rate, data bits, parity, stop
//! bits and flow control from a [`SerialConfig`]), read and written through tokio's reactor
//! by [`SerialStream`]. Works on USB-serial adapters and on Linux ptys (whose baud setting is
//! accepted and ignored by the kernel).

use std::io;
use std::os::fd::{AsRawFd, RawFd};
use std::pin::Pin;
use std::task::{ready, Context, Poll};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

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

/// An open serial port as a tokio byte stream: the port `serialport` opened and
/// configured, switched to non-blocking mode and registered with tokio's reactor.
///
/// Written here rather than taken from `tokio-serial` for one reason: its stream keeps the
/// port's read readiness after a read that returned fewer bytes than asked for, so every read
/// of a frame is followed by a second `read` that only returns `EAGAIN` before the task can
/// wait again (at the daemon's nominal rate, 310 frames a second, half of all its `read`
/// calls). A short read from a tty means its input queue was empty at that moment (the
/// n_tty line discipline hands over everything it holds, up to the size asked for), and
/// input arriving later raises a new edge-triggered epoll event, so readiness is cleared after
/// a short read, as tokio's own `TcpStream` does. Readiness cleared by mistake would stall the
/// reader; readiness kept by mistake only costs one `EAGAIN` read.
///
/// On a busy port (the previous short read less than [`BUSY_READ_GAP`] ago) readiness is
/// kept: there the next read usually finds input that arrived meanwhile, and going back to
/// `epoll_wait` instead put the reading thread to sleep ~25 % more often at 100× the
/// nominal rate (docs/bench/daemon.md, round 5).
#[derive(Debug)]
pub struct SerialStream {
    port: AsyncFd<serialport::TTYPort>,
    /// When the previous short read returned.
    last_short_read: Option<std::time::Instant>,
}

/// Short reads closer together than this mark a busy port (see [`SerialStream`]); at the
/// nominal rates (150 Hz and below per port) reads are several ms apart.
pub const BUSY_READ_GAP: Duration = Duration::from_millis(1);

impl SerialStream {
    /// Wraps a port opened by `serialport` (blocking mode), switching it to non-blocking.
    fn new(port: serialport::TTYPort) -> io::Result<Self> {
        let fd = port.as_raw_fd();
        // SAFETY: fcntl on an fd this port owns; F_GETFL/F_SETFL take no pointers.
        let flags = unsafe { libc::fcntl(fd, libc::F_GETFL) };
        if flags < 0 || unsafe { libc::fcntl(fd, libc::F_SETFL, flags | libc::O_NONBLOCK) } < 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: the TTYPort owns its descriptor and keeps it open, unchanged, until it is
        // dropped; the AsyncFd owns the TTYPort and deregisters before dropping it.
        let port = unsafe { AsyncFd::register(port) }.map_err(|e| e.into_parts().1)?;
        Ok(SerialStream {
            port,
            last_short_read: None,
        })
    }

    fn fd(&self) -> RawFd {
        self.port.get_ref().as_raw_fd()
    }
}

/// `read(2)` on a non-blocking fd, retried on EINTR.
fn read_fd(fd: RawFd, buf: &mut [u8]) -> io::Result<usize> {
    loop {
        // SAFETY: `buf` is valid for writes of `buf.len()` bytes for the whole call.
        let n = unsafe { libc::read(fd, buf.as_mut_ptr().cast(), buf.len()) };
        if n >= 0 {
            return Ok(n as usize);
        }
        let e = io::Error::last_os_error();
        if e.kind() != io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
}

/// `write(2)` on a non-blocking fd, retried on EINTR.
fn write_fd(fd: RawFd, buf: &[u8]) -> io::Result<usize> {
    loop {
        // SAFETY: `buf` is valid for reads of `buf.len()` bytes for the whole call.
        let n = unsafe { libc::write(fd, buf.as_ptr().cast(), buf.len()) };
        if n >= 0 {
            return Ok(n as usize);
        }
        let e = io::Error::last_os_error();
        if e.kind() != io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
}

impl AsyncRead for SerialStream {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let fd = this.fd();
        loop {
            let mut guard = ready!(this.port.poll_read_ready(cx))?;
            let unfilled = buf.initialize_unfilled();
            let asked = unfilled.len();
            match read_fd(fd, unfilled) {
                Ok(n) => {
                    if n > 0 && n < asked {
                        let now = std::time::Instant::now();
                        let busy = this
                            .last_short_read
                            .is_some_and(|t| now.duration_since(t) < BUSY_READ_GAP);
                        this.last_short_read = Some(now);
                        if !busy {
                            // The tty's input queue is empty: wait for the next epoll event
                            // instead of reading again only to get EAGAIN (see the type's doc).
                            guard.clear_ready();
                        }
                    }
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => guard.clear_ready(),
                Err(e) => return Poll::Ready(Err(e)),
            }
        }
    }
}

impl AsyncWrite for SerialStream {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let fd = self.fd();
        loop {
            let mut guard = ready!(self.port.poll_write_ready(cx))?;
            match write_fd(fd, buf) {
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => guard.clear_ready(),
                result => return Poll::Ready(result),
            }
        }
    }

    /// Waits until the port's output has been transmitted (`tcdrain`), as `tokio-serial`
    /// did: only device commands are written (slcan set-up), never in the read path.
    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let fd = self.fd();
        loop {
            // SAFETY: tcdrain on an fd this stream owns.
            if unsafe { libc::tcdrain(fd) } == 0 {
                return Poll::Ready(Ok(()));
            }
            let e = io::Error::last_os_error();
            if e.kind() != io::ErrorKind::Interrupted {
                return Poll::Ready(Err(e));
            }
        }
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        self.poll_flush(cx)
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
    let builder = tokio_serial::new(&config.path, config.baud)
        .data_bits(data_bits)
        .parity(parity)
        .stop_bits(stop_bits)
        .flow_control(flow);
    let port = serialport::TTYPort::open(&builder).map_err(|e| TransportError::Open {
        device: config.path.clone(),
        source: open_error(&config.path, e),
    })?;
    let stream = SerialStream::new(port).map_err(|source| TransportError::Open {
        device: config.path.clone(),
        source,
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
