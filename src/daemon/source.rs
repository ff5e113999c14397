//! What a device task reads from: a [`Connector`] that opens a byte stream (serial port,
//! pty, TCP, or an in-memory stream in tests) and a [`FrameDecoder`] that turns the bytes
//! into frames. Both are traits so the pipeline can be tested without hardware or codecs.

use std::future::Future;
use std::io;
use std::path::PathBuf;
use std::pin::Pin;

use imulab_drivers::codec::gnss::{GnssDecoder, GnssFrame};
use imulab_drivers::codec::Decoder;
use imulab_drivers::types::{DecoderStats, GnssFix, ImuSample};
use tokio::io::AsyncRead;

use super::config::{DeviceSpec, Protocol, Transport};

/// One decoded frame, in the drivers crate's device-independent types.
#[derive(Debug, Clone, PartialEq)]
pub enum Frame {
    Imu(ImuSample),
    Gnss(GnssFix),
}

/// A sans-IO decoder as the daemon sees it: the codecs' `push`/`poll`/`stats`, with frames
/// already converted to [`Frame`].
pub trait FrameDecoder: Send {
    fn push(&mut self, bytes: &[u8]);
    fn poll(&mut self) -> Option<Frame>;
    fn stats(&self) -> DecoderStats;
    /// The input ended (device vanished, shutdown): frames the decoder held back.
    fn finish(&mut self) -> Option<Frame> {
        None
    }
}

/// The drivers' mixed NMEA + UBX decoder, yielding its merged navigation epochs. (Raw
/// sentences and messages are not rows; they stay in the raw journal.)
struct GnssEpochs(GnssDecoder);

impl FrameDecoder for GnssEpochs {
    fn push(&mut self, bytes: &[u8]) {
        Decoder::push(&mut self.0, bytes);
    }

    fn poll(&mut self) -> Option<Frame> {
        loop {
            if let GnssFrame::Fix(epoch) = Decoder::poll(&mut self.0)? {
                return Some(Frame::Gnss(epoch.fix));
            }
        }
    }

    fn stats(&self) -> DecoderStats {
        Decoder::stats(&self.0)
    }

    fn finish(&mut self) -> Option<Frame> {
        loop {
            if let GnssFrame::Fix(epoch) = Decoder::finish(&mut self.0)? {
                return Some(Frame::Gnss(epoch.fix));
            }
        }
    }
}

/// Makes a fresh decoder (one per connection, so a partial frame from before a disconnect
/// is not glued to the bytes after it).
pub type DecoderFactory = Box<dyn Fn() -> Box<dyn FrameDecoder> + Send + Sync>;

/// An open byte stream from a device.
pub type ByteStream = Box<dyn AsyncRead + Send + Unpin>;

/// A boxed future, so connectors can be trait objects.
pub type BoxFuture<'a, T> = Pin<Box<dyn Future<Output = T> + Send + 'a>>;

/// Opens (and after a vanish, reopens) a device's byte stream.
pub trait Connector: Send + Sync {
    fn connect(&self) -> BoxFuture<'_, io::Result<ByteStream>>;
    /// Where the bytes come from, for logs and events.
    fn describe(&self) -> String;
}

/// A serial port, or a pty standing in for one (the baud rate is a no-op there).
pub struct SerialConnector {
    pub port: PathBuf,
    pub baud: u32,
}

impl Connector for SerialConnector {
    fn connect(&self) -> BoxFuture<'_, io::Result<ByteStream>> {
        Box::pin(async move {
            let path = self.port.to_string_lossy().into_owned();
            let builder = tokio_serial::new(path, self.baud);
            let stream = tokio_serial::SerialStream::open(&builder).map_err(io::Error::from)?;
            Ok(Box::new(stream) as ByteStream)
        })
    }

    fn describe(&self) -> String {
        format!("serial {} @ {}", self.port.display(), self.baud)
    }
}

/// A TCP client (ser2net and the like).
pub struct TcpConnector {
    pub address: String,
}

impl Connector for TcpConnector {
    fn connect(&self) -> BoxFuture<'_, io::Result<ByteStream>> {
        Box::pin(async move {
            let stream = tokio::net::TcpStream::connect(&self.address).await?;
            stream.set_nodelay(true)?;
            Ok(Box::new(stream) as ByteStream)
        })
    }

    fn describe(&self) -> String {
        format!("tcp {}", self.address)
    }
}

/// The connector for a configured transport, or why this build cannot open it.
pub fn connector_for(device: &DeviceSpec) -> Result<Box<dyn Connector>, String> {
    match &device.transport {
        Transport::Serial(s) => Ok(Box::new(SerialConnector {
            port: s.port.clone(),
            baud: s.baud,
        })),
        Transport::Tcp(t) => Ok(Box::new(TcpConnector {
            address: t.address.clone(),
        })),
        Transport::Can(_) | Transport::Slcan(_) => Err(format!(
            "{} is not supported by this build of imulogd yet (CAN transports come with the \
             drivers' CAN support)",
            device.transport.describe()
        )),
    }
}

/// The decoder for a configured protocol, or why this build cannot decode it.
pub fn decoder_for(device: &DeviceSpec) -> Result<DecoderFactory, String> {
    match device.protocol {
        // One decoder for all three: it takes NMEA, UBX or both interleaved.
        Protocol::Nmea | Protocol::Ubx | Protocol::Gnss => Ok(Box::new(|| {
            Box::new(GnssEpochs(GnssDecoder::new())) as Box<dyn FrameDecoder>
        })),
        Protocol::Wit | Protocol::Xbus | Protocol::Csv | Protocol::CanDbc => Err(format!(
            "protocol `{}` has no decoder in this build of imulab-drivers yet",
            device.protocol.name()
        )),
    }
}
