//! What a device task reads from, and how it decodes it.
//!
//! - A [`Connector`] opens (and after a vanish, reopens) a [`Link`]: the drivers' transports
//!   (serial port or pty, TCP, slcan adapter, SocketCAN), a capture played back
//!   ([`super::capture`]), or an in-memory stream in tests.
//! - A [`Link`] delivers [`Input`]: bytes from a byte stream, or CAN frames from a CAN
//!   transport. CAN frames go to the DBC decoder as frames; they are never turned into text.
//! - A [`FrameDecoder`] turns the input into [`Frame`]s: the reading decoder of the
//!   protocol's row in the drivers' table (`imulab_drivers::codec::PROTOCOLS`).
//!
//! Link and decoder are traits so the pipeline can also be tested without hardware.

use std::future::Future;
use std::path::Path;
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;

use imulab_drivers::codec::can::CanFrame;
use imulab_drivers::codec::{DecoderOptions, NamedText};
use imulab_drivers::transport::serial::{open_serial, SerialConfig as DriverSerialConfig};
use imulab_drivers::transport::slcan::SlcanTransport;
use imulab_drivers::transport::socketcan::SocketCanTransport;
use imulab_drivers::transport::tcp::connect_tcp;
use imulab_drivers::transport::{StreamTransport, TransportError};
use imulab_drivers::types::DecoderStats;
use tokio::io::{AsyncRead, AsyncWrite};

use super::capture::{capture_kind, CaptureConnector};
use super::config::{DeviceSpec, Transport};

/// How long a TCP connect may take before the attempt counts as failed (and is retried).
const TCP_CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

/// What one receive from a device delivered: bytes or one CAN frame.
pub use imulab_drivers::codec::reading::Input;
/// One decoded frame: an IMU sample or a GNSS fix.
pub use imulab_drivers::codec::reading::Reading as Frame;
/// A protocol's reading decoder, as the daemon runs it.
pub use imulab_drivers::codec::reading::ReadingDecoder as FrameDecoder;
/// Makes a fresh decoder (one per connection, so a partial frame from before a disconnect
/// is not glued to the bytes after it).
pub use imulab_drivers::codec::reading::ReadingDecoderFactory as DecoderFactory;

/// A boxed future, so links and connectors can be trait objects.
pub type BoxFuture<'a, T> = Pin<Box<dyn Future<Output = T> + Send + 'a>>;

/// What [`Link::receive`] got.
#[derive(Debug, Clone, Copy)]
pub enum Received {
    /// This many bytes, at the front of the buffer passed in.
    Bytes(usize),
    /// One CAN frame.
    Can(CanFrame),
    /// The source has nothing more and never will (a capture file at its end): the device
    /// ends instead of being reopened.
    End,
}

/// An open device.
pub trait Link: Send {
    /// Polls for the next data; `Pending` registers `cx`'s waker. Nothing is consumed unless
    /// it is returned, so the daemon can wait for it beside other events in one future of
    /// its own, without a future per read. A device that went away is
    /// [`TransportError::Vanished`].
    fn poll_receive(
        &mut self,
        cx: &mut Context<'_>,
        buffer: &mut [u8],
    ) -> Poll<Result<Received, TransportError>>;
    /// Counters of decoding done inside the link (an slcan adapter's line decoder).
    fn stats(&self) -> DecoderStats {
        DecoderStats::default()
    }
}

/// A byte stream (serial port, pty, TCP, or an in-memory stream in tests): polled directly,
/// the read path of the nominal benchmark.
impl<S: AsyncRead + AsyncWrite + Unpin + Send> Link for StreamTransport<S> {
    fn poll_receive(
        &mut self,
        cx: &mut Context<'_>,
        buffer: &mut [u8],
    ) -> Poll<Result<Received, TransportError>> {
        self.poll_read(cx, buffer).map_ok(Received::Bytes)
    }
}

/// A CAN transport, whose receive is an `async fn` of its own: [`CanLink`] runs it.
trait CanReceive: Send + Sized + 'static {
    /// Receives one frame; the future owns the transport and hands it back.
    fn receive_owned(self) -> BoxFuture<'static, (Self, Result<CanFrame, TransportError>)>;
    fn stats(&self) -> DecoderStats;
}

/// The [`Link`] of a CAN transport. Its receive future owns the transport while it runs and
/// hands it back with the frame, so a receive that is still waiting when the daemon polls
/// something else is kept, not restarted (one boxed future per frame; CAN devices only).
enum CanLink<T> {
    Idle(T),
    Receiving(BoxFuture<'static, (T, Result<CanFrame, TransportError>)>),
    /// Only if a receive future panicked.
    Lost,
}

impl<T: CanReceive> Link for CanLink<T> {
    fn poll_receive(
        &mut self,
        cx: &mut Context<'_>,
        _: &mut [u8],
    ) -> Poll<Result<Received, TransportError>> {
        let mut receiving = match std::mem::replace(self, CanLink::Lost) {
            CanLink::Idle(transport) => transport.receive_owned(),
            CanLink::Receiving(future) => future,
            CanLink::Lost => {
                return Poll::Ready(Err(TransportError::Config(
                    "the CAN link was lost by a failed receive".to_string(),
                )))
            }
        };
        match receiving.as_mut().poll(cx) {
            Poll::Ready((transport, result)) => {
                *self = CanLink::Idle(transport);
                Poll::Ready(result.map(Received::Can))
            }
            Poll::Pending => {
                *self = CanLink::Receiving(receiving);
                Poll::Pending
            }
        }
    }

    fn stats(&self) -> DecoderStats {
        match self {
            CanLink::Idle(transport) => transport.stats(),
            // The daemon reads the counters after a receive returned, when the transport is
            // back; during one they are inside its future.
            CanLink::Receiving(_) | CanLink::Lost => DecoderStats::default(),
        }
    }
}

/// A SocketCAN interface. A frame the kernel hands over that is not a valid CAN frame (the
/// transport's `Protocol` error) is counted as malformed and skipped, not a reason to reopen.
struct SocketCanLink {
    transport: SocketCanTransport,
    stats: DecoderStats,
}

impl CanReceive for SocketCanLink {
    fn receive_owned(mut self) -> BoxFuture<'static, (Self, Result<CanFrame, TransportError>)> {
        Box::pin(async move {
            loop {
                match self.transport.recv().await {
                    Ok(frame) => return (self, Ok(frame)),
                    Err(TransportError::Protocol { device, reason }) => {
                        self.stats.frames_malformed += 1;
                        tracing::debug!("{device}: skipped a frame: {reason}");
                    }
                    Err(e) => return (self, Err(e)),
                }
            }
        })
    }

    fn stats(&self) -> DecoderStats {
        self.stats
    }
}

impl CanReceive for SlcanTransport {
    fn receive_owned(mut self) -> BoxFuture<'static, (Self, Result<CanFrame, TransportError>)> {
        // The adapter's own timestamp (if enabled) is coarse (ms, wrapping each minute); the
        // host arrival time is what the rows carry.
        Box::pin(async move {
            let result = self.recv().await.map(|(frame, _)| frame);
            (self, result)
        })
    }

    fn stats(&self) -> DecoderStats {
        SlcanTransport::stats(self)
    }
}

/// Opens (and after a vanish, reopens) a device.
pub trait Connector: Send + Sync {
    fn connect(&self) -> BoxFuture<'_, Result<Box<dyn Link>, TransportError>>;
    /// Where the data come from, for logs and events.
    fn describe(&self) -> String;
}

/// Opens a configured transport through the drivers crate.
struct TransportConnector {
    transport: Transport,
}

fn serial_config(port: &Path, baud: u32) -> DriverSerialConfig {
    DriverSerialConfig::new(port.to_string_lossy().into_owned(), baud)
}

impl Connector for TransportConnector {
    fn connect(&self) -> BoxFuture<'_, Result<Box<dyn Link>, TransportError>> {
        Box::pin(async move {
            Ok(match &self.transport {
                Transport::Serial(s) => {
                    Box::new(open_serial(&serial_config(&s.port, s.baud))?) as Box<dyn Link>
                }
                Transport::Tcp(t) => {
                    Box::new(connect_tcp(&t.address, TCP_CONNECT_TIMEOUT, None).await?)
                }
                Transport::Slcan(s) => Box::new(CanLink::Idle(
                    SlcanTransport::open(&serial_config(&s.port, s.baud), s.bitrate, false).await?,
                )),
                Transport::Can(c) => Box::new(CanLink::Idle(SocketCanLink {
                    transport: SocketCanTransport::open(&c.interface, None)?,
                    stats: DecoderStats::default(),
                })),
                // Made by `connector_for` as a `CaptureConnector`, never here.
                Transport::File(f) => {
                    return Err(TransportError::Config(format!(
                        "{} is a capture file, not a device",
                        f.path.display()
                    )))
                }
            })
        })
    }

    fn describe(&self) -> String {
        self.transport.describe()
    }
}

/// The connector for a configured transport. Every transport the configuration accepts has
/// one; the `Result` is kept for transports a build may lack.
pub fn connector_for(device: &DeviceSpec) -> Result<Box<dyn Connector>, String> {
    if let Transport::File(source) = &device.transport {
        let kind = capture_kind(source, &device.name, device.protocol.is_can())?;
        return Ok(Box::new(CaptureConnector {
            source: source.clone(),
            kind,
        }));
    }
    Ok(Box::new(TransportConnector {
        transport: device.transport.clone(),
    }))
}

fn read_text(what: &str, path: &Path) -> Result<NamedText, String> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("cannot read the {what} {}: {e}", path.display()))?;
    Ok(NamedText {
        name: path.display().to_string(),
        text,
    })
}

/// The decoder factory for a configured protocol, from its row of the drivers' table. Reads
/// and checks the files a protocol needs (the DBC and its signal mapping) once, so a bad file
/// is reported at start-up and by `--check-config`, not on every connection.
pub fn decoder_for(device: &DeviceSpec) -> Result<DecoderFactory, String> {
    let mut options = DecoderOptions {
        rows_from: device.rows_from,
        esf_imu: device.imu.is_some(),
        ..DecoderOptions::default()
    };
    if let Some(dbc) = &device.dbc {
        options.dbc = Some(read_text("DBC file", &dbc.file)?);
        options.config = Some(read_text("DBC signal mapping", &dbc.mapping)?);
    }
    if let Some(csv) = &device.csv {
        options.config = Some(NamedText {
            name: format!("device `{}` [device.csv]", device.name),
            text: toml::to_string(csv).map_err(|e| format!("[device.csv]: {e}"))?,
        });
    }
    device
        .protocol
        .readings(&options)
        .map_err(|e| e.to_string())
}
