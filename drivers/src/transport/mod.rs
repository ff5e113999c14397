//! Thin async transports (tokio) that move bytes or CAN frames between a device and a codec:
//! serial ports ([`serial`]), TCP clients ([`tcp`]), SocketCAN ([`socketcan`]), slcan
//! adapters ([`slcan`]) and file replay ([`replay`]).
//!
//! Every failure is a [`TransportError`]. A device that disappears (pty closed, USB adapter
//! unplugged, CAN interface down, peer closed the TCP connection) is
//! [`TransportError::Vanished`], and a device that stays silent longer than the configured
//! idle timeout is [`TransportError::Timeout`]; both are [`TransportError::is_retryable`],
//! so the daemon reopens instead of hanging.

use std::future::Future;
use std::io;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

pub mod replay;
pub mod serial;
pub mod slcan;
pub mod socketcan;
pub mod tcp;

/// Why a transport operation failed.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// The device could not be opened (missing, permission denied, busy, bad settings).
    #[error("cannot open {device}: {source}")]
    Open {
        device: String,
        #[source]
        source: io::Error,
    },
    /// The device went away while in use: end of stream, EIO/ENXIO/ENODEV, network down,
    /// connection reset. Reopen and retry.
    #[error("{device} vanished: {reason}")]
    Vanished { device: String, reason: String },
    /// No data for longer than the idle timeout.
    #[error("{device}: no data for {after:?}")]
    Timeout { device: String, after: Duration },
    /// The device answered, but not as the protocol requires (e.g. slcan replied BEL).
    #[error("{device}: protocol error: {reason}")]
    Protocol { device: String, reason: String },
    /// Invalid settings, detected before touching the device.
    #[error("invalid transport configuration: {0}")]
    Config(String),
    /// Any other I/O error.
    #[error("{device}: I/O error: {source}")]
    Io {
        device: String,
        #[source]
        source: io::Error,
    },
}

impl TransportError {
    /// True when reopening the device later may succeed (vanished, timeout, open failure).
    pub fn is_retryable(&self) -> bool {
        matches!(
            self,
            TransportError::Vanished { .. }
                | TransportError::Timeout { .. }
                | TransportError::Open { .. }
        )
    }

    /// Classifies an I/O error on an open device: errors that mean "the device is gone"
    /// become [`TransportError::Vanished`].
    pub fn from_io(device: &str, error: io::Error) -> Self {
        use io::ErrorKind as K;
        let gone_kind = matches!(
            error.kind(),
            K::UnexpectedEof
                | K::BrokenPipe
                | K::ConnectionReset
                | K::ConnectionAborted
                | K::NotConnected
        );
        let gone_errno = matches!(
            error.raw_os_error(),
            Some(libc_errno::EIO)
                | Some(libc_errno::ENXIO)
                | Some(libc_errno::ENODEV)
                | Some(libc_errno::ENETDOWN)
                | Some(libc_errno::EBADF)
        );
        if gone_kind || gone_errno {
            TransportError::Vanished {
                device: device.to_string(),
                reason: error.to_string(),
            }
        } else {
            TransportError::Io {
                device: device.to_string(),
                source: error,
            }
        }
    }
}

/// Linux errno values we classify (stable ABI numbers; avoids a libc dependency).
mod libc_errno {
    pub const EBADF: i32 = 9;
    pub const EIO: i32 = 5;
    pub const ENXIO: i32 = 6;
    pub const ENODEV: i32 = 19;
    pub const ENETDOWN: i32 = 100;
}

/// A source of bytes (serial port, TCP, file replay).
pub trait ByteSource {
    /// Reads at least one byte into `buf`. `Ok(0)` only from finite sources (file replay)
    /// at their end; a live device that ends is [`TransportError::Vanished`].
    fn read(
        &mut self,
        buf: &mut [u8],
    ) -> impl Future<Output = Result<usize, TransportError>> + Send;
}

/// A byte stream on an open device, with the device's name for errors and an optional idle
/// timeout.
#[derive(Debug)]
pub struct StreamTransport<S> {
    stream: S,
    device: String,
    idle_timeout: Option<Duration>,
}

impl<S: AsyncRead + AsyncWrite + Unpin + Send> StreamTransport<S> {
    /// Wraps an open stream.
    pub fn new(stream: S, device: impl Into<String>, idle_timeout: Option<Duration>) -> Self {
        StreamTransport {
            stream,
            device: device.into(),
            idle_timeout,
        }
    }

    /// The device name used in errors.
    pub fn device(&self) -> &str {
        &self.device
    }

    /// Writes all of `bytes` (e.g. encoder output or device commands).
    pub async fn write_all(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        let write = async {
            self.stream.write_all(bytes).await?;
            self.stream.flush().await
        };
        let result = match self.idle_timeout {
            Some(t) => match tokio::time::timeout(t, write).await {
                Ok(r) => r,
                Err(_) => {
                    return Err(TransportError::Timeout {
                        device: self.device.clone(),
                        after: t,
                    })
                }
            },
            None => write.await,
        };
        result.map_err(|e| TransportError::from_io(&self.device, e))
    }

    /// The wrapped stream.
    pub fn into_inner(self) -> S {
        self.stream
    }
}

impl<S: AsyncRead + AsyncWrite + Unpin + Send> ByteSource for StreamTransport<S> {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, TransportError> {
        if buf.is_empty() {
            return Ok(0);
        }
        let read = self.stream.read(buf);
        let result = match self.idle_timeout {
            Some(t) => match tokio::time::timeout(t, read).await {
                Ok(r) => r,
                Err(_) => {
                    return Err(TransportError::Timeout {
                        device: self.device.clone(),
                        after: t,
                    })
                }
            },
            None => read.await,
        };
        match result {
            Ok(0) => Err(TransportError::Vanished {
                device: self.device.clone(),
                reason: "end of stream".into(),
            }),
            Ok(n) => Ok(n),
            Err(e) => Err(TransportError::from_io(&self.device, e)),
        }
    }
}
