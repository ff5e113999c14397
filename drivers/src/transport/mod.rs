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
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadBuf};

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
    /// The idle timer of [`StreamTransport::poll_read`] (made at its first wait, only with an
    /// idle timeout), and whether bytes were read since it was last armed.
    idle: Option<Pin<Box<tokio::time::Sleep>>>,
    read_since_armed: bool,
}

impl<S: AsyncRead + AsyncWrite + Unpin + Send> StreamTransport<S> {
    /// Wraps an open stream.
    pub fn new(stream: S, device: impl Into<String>, idle_timeout: Option<Duration>) -> Self {
        StreamTransport {
            stream,
            device: device.into(),
            idle_timeout,
            idle: None,
            read_since_armed: false,
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

impl<S: AsyncRead + Unpin> StreamTransport<S> {
    /// The poll form of [`ByteSource::read`], for a caller that waits for a read together
    /// with other events in one future of its own (the daemon's device loop): no future is
    /// made per read. Reads at least one byte into `buf`; the end of the stream is
    /// [`TransportError::Vanished`]. `Pending` consumes nothing and wakes `cx` when bytes
    /// come.
    ///
    /// With an idle timeout, silence is timed by one timer kept in the transport and re-armed
    /// at the first wait after bytes were read (not at every read), so a poll that is still
    /// waiting after the timeout since the last bytes is [`TransportError::Timeout`]; the timer
    /// is then re-armed, so a caller that goes on polling gets a timeout per period of silence.
    pub fn poll_read(
        &mut self,
        cx: &mut Context<'_>,
        buf: &mut [u8],
    ) -> Poll<Result<usize, TransportError>> {
        if buf.is_empty() {
            return Poll::Ready(Ok(0));
        }
        let mut read = ReadBuf::new(buf);
        match Pin::new(&mut self.stream).poll_read(cx, &mut read) {
            Poll::Ready(Ok(())) => {
                let n = read.filled().len();
                if n == 0 {
                    return Poll::Ready(Err(TransportError::Vanished {
                        device: self.device.clone(),
                        reason: "end of stream".into(),
                    }));
                }
                self.read_since_armed = true;
                Poll::Ready(Ok(n))
            }
            Poll::Ready(Err(e)) => Poll::Ready(Err(TransportError::from_io(&self.device, e))),
            Poll::Pending => {
                let Some(after) = self.idle_timeout else {
                    return Poll::Pending;
                };
                let rearm = std::mem::take(&mut self.read_since_armed);
                let timer = self
                    .idle
                    .get_or_insert_with(|| Box::pin(tokio::time::sleep(after)));
                if rearm {
                    timer.as_mut().reset(tokio::time::Instant::now() + after);
                }
                if timer.as_mut().poll(cx).is_pending() {
                    return Poll::Pending;
                }
                timer.as_mut().reset(tokio::time::Instant::now() + after);
                Poll::Ready(Err(TransportError::Timeout {
                    device: self.device.clone(),
                    after,
                }))
            }
        }
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::future::poll_fn;
    use tokio::io::{duplex, AsyncWriteExt};
    use tokio::time::Instant;

    #[tokio::test]
    async fn poll_read_delivers_bytes_then_the_end_as_a_vanish() {
        let (mut far, near) = duplex(64);
        let mut link = StreamTransport::new(near, "mem", None);
        let mut buf = [0u8; 16];
        far.write_all(b"abc").await.unwrap();
        let n = poll_fn(|cx| link.poll_read(cx, &mut buf)).await.unwrap();
        assert_eq!(&buf[..n], b"abc");
        drop(far);
        let end = poll_fn(|cx| link.poll_read(cx, &mut buf)).await;
        assert!(
            matches!(end, Err(TransportError::Vanished { .. })),
            "{end:?}"
        );
    }

    #[tokio::test]
    async fn poll_read_times_silence_from_the_last_bytes() {
        let after = Duration::from_millis(60);
        let (mut far, near) = duplex(64);
        let mut link = StreamTransport::new(near, "mem", Some(after));
        let mut buf = [0u8; 16];
        // Bytes every 30 ms for 240 ms: four timeouts' worth of time, none of silence.
        let writer = tokio::spawn(async move {
            for _ in 0..8 {
                tokio::time::sleep(Duration::from_millis(30)).await;
                far.write_all(b"x").await.unwrap();
            }
            far
        });
        for _ in 0..8 {
            let n = poll_fn(|cx| link.poll_read(cx, &mut buf)).await.unwrap();
            assert_eq!(n, 1);
        }
        let _far = writer.await.unwrap();
        // Then silence: a timeout about `after` after the last byte, and another one later.
        let t = Instant::now();
        let silent = poll_fn(|cx| link.poll_read(cx, &mut buf)).await;
        assert!(
            matches!(silent, Err(TransportError::Timeout { .. })),
            "{silent:?}"
        );
        assert!(
            t.elapsed() >= after - Duration::from_millis(5),
            "{:?}",
            t.elapsed()
        );
        let again = poll_fn(|cx| link.poll_read(cx, &mut buf)).await;
        assert!(matches!(again, Err(TransportError::Timeout { .. })));
        assert!(t.elapsed() >= 2 * after - Duration::from_millis(5));
    }
}
