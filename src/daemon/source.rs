//! What a device task reads from, and how it decodes it.
//!
//! - A [`Connector`] opens (and after a vanish, reopens) a [`Link`]: the drivers' transports
//!   (serial port or pty, TCP, slcan adapter, SocketCAN), a capture played back
//!   ([`super::capture`]), or an in-memory stream in tests.
//! - A [`Link`] delivers [`Input`]: bytes from a byte stream, or CAN frames from a CAN
//!   transport. CAN frames go to the DBC decoder as frames; they are never turned into text.
//! - A [`FrameDecoder`] turns the input into [`Frame`]s: the drivers' codecs (WitMotion,
//!   Xbus, VectorNav, MIP, CSV lines, NMEA/UBX, a CAN IMU through a DBC file) behind one small trait.
//!
//! Link and decoder are traits so the pipeline can also be tested without hardware.

use std::collections::VecDeque;
use std::future::Future;
use std::path::Path;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use imulab_drivers::codec::can::CanFrame;
use imulab_drivers::codec::csv_line::CsvLineDecoder;
use imulab_drivers::codec::dbc::{DbcImu, DbcImuMapping};
use imulab_drivers::codec::gnss::{GnssDecoder, GnssFrame};
use imulab_drivers::codec::mip::{MipDecoder, MipPacket};
use imulab_drivers::codec::ubx::UbxMessage;
use imulab_drivers::codec::vectornav::{VnDecoder, VnFrame};
use imulab_drivers::codec::witmotion::WitImuDecoder;
use imulab_drivers::codec::xbus::{XbusDecoder, XbusMessage};
use imulab_drivers::codec::Decoder;
use imulab_drivers::transport::serial::{open_serial, SerialConfig as DriverSerialConfig};
use imulab_drivers::transport::slcan::SlcanTransport;
use imulab_drivers::transport::socketcan::SocketCanTransport;
use imulab_drivers::transport::tcp::connect_tcp;
use imulab_drivers::transport::{StreamTransport, TransportError};
use imulab_drivers::types::{DecoderStats, GnssFix, ImuSample};
use tokio::io::{AsyncRead, AsyncWrite};

use super::capture::{capture_kind, CaptureConnector};
use super::config::{DeviceSpec, Protocol, Transport};

/// How long a TCP connect may take before the attempt counts as failed (and is retried).
const TCP_CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

/// One decoded frame, in the drivers crate's device-independent types.
#[derive(Debug, Clone, PartialEq)]
pub enum Frame {
    Imu(ImuSample),
    Gnss(GnssFix),
}

/// What one receive from a device delivered.
#[derive(Debug, Clone, Copy)]
pub enum Input<'a> {
    /// Bytes from a byte stream (serial, pty, TCP).
    Bytes(&'a [u8]),
    /// One CAN frame (SocketCAN, or an slcan adapter's decoded line).
    Can(&'a CanFrame),
}

/// A sans-IO decoder as the daemon sees it: the codecs' `push`/`poll`/`stats`, with frames
/// already converted to [`Frame`].
pub trait FrameDecoder: Send {
    /// Feeds one input. Input of the wrong kind (CAN frames to a byte decoder or the reverse)
    /// is counted as malformed; configuration validation keeps it from happening.
    fn push(&mut self, input: Input<'_>);
    fn poll(&mut self) -> Option<Frame>;
    fn stats(&self) -> DecoderStats;
    /// The input ended (device vanished, shutdown): frames the decoder held back.
    fn finish(&mut self) -> Option<Frame> {
        None
    }
}

/// Any drivers' byte decoder, with a function that picks the frames the daemon logs.
struct ByteDecoder<D: Decoder> {
    inner: D,
    convert: fn(D::Frame) -> Option<Frame>,
    /// CAN frames pushed to this byte decoder (never with a validated config).
    wrong_input: u64,
}

impl<D: Decoder + Send> FrameDecoder for ByteDecoder<D> {
    fn push(&mut self, input: Input<'_>) {
        match input {
            Input::Bytes(bytes) => self.inner.push(bytes),
            Input::Can(_) => self.wrong_input += 1,
        }
    }

    fn poll(&mut self) -> Option<Frame> {
        loop {
            let frame = self.inner.poll()?;
            if let Some(frame) = (self.convert)(frame) {
                return Some(frame);
            }
        }
    }

    fn stats(&self) -> DecoderStats {
        let mut stats = self.inner.stats();
        stats.frames_malformed += self.wrong_input;
        stats
    }

    fn finish(&mut self) -> Option<Frame> {
        loop {
            let frame = self.inner.finish()?;
            if let Some(frame) = (self.convert)(frame) {
                return Some(frame);
            }
        }
    }
}

fn boxed<D: Decoder + Send + 'static>(
    inner: D,
    convert: fn(D::Frame) -> Option<Frame>,
) -> Box<dyn FrameDecoder> {
    Box::new(ByteDecoder {
        inner,
        convert,
        wrong_input: 0,
    })
}

/// Merged navigation epochs are the rows; raw sentences and messages stay in the journal.
fn gnss_epoch(frame: GnssFrame) -> Option<Frame> {
    match frame {
        GnssFrame::Fix(epoch) => Some(Frame::Gnss(epoch.fix)),
        _ => None,
    }
}

fn imu_sample(sample: ImuSample) -> Option<Frame> {
    Some(Frame::Imu(sample))
}

/// MTData2 messages are samples; other Xbus messages (acks, errors) are not rows.
fn xbus_sample(message: XbusMessage) -> Option<Frame> {
    match message {
        XbusMessage::MtData2 { data, .. } => Some(Frame::Imu(data.to_imu_sample())),
        _ => None,
    }
}

/// Binary packets and ASCII sentences with angular rate or acceleration are samples;
/// attitude-only output and register replies are not rows.
fn vectornav_sample(frame: VnFrame) -> Option<Frame> {
    frame.to_imu_sample().map(Frame::Imu)
}

/// IMU data packets with accelerometer or gyro are samples; command replies are not rows.
fn mip_sample(packet: MipPacket) -> Option<Frame> {
    packet.to_imu_sample().map(Frame::Imu)
}

/// The IMU of a u-blox dead-reckoning receiver: ESF-RAW (several samples per message) and
/// ESF-MEAS (one) become samples; fixes, other UBX messages and NMEA are not rows of it.
struct EsfImuDecoder {
    gnss: GnssDecoder,
    ready: VecDeque<ImuSample>,
    /// CAN frames pushed to this byte decoder (never with a validated config).
    wrong_input: u64,
}

impl EsfImuDecoder {
    fn take(&mut self, frame: GnssFrame) {
        match frame {
            GnssFrame::Ubx(UbxMessage::EsfRaw(raw)) => self.ready.extend(raw.to_imu_samples()),
            GnssFrame::Ubx(UbxMessage::EsfMeas(meas)) => self.ready.extend(meas.to_imu_sample()),
            _ => {}
        }
    }
}

impl FrameDecoder for EsfImuDecoder {
    fn push(&mut self, input: Input<'_>) {
        match input {
            Input::Bytes(bytes) => self.gnss.push(bytes),
            Input::Can(_) => self.wrong_input += 1,
        }
    }

    fn poll(&mut self) -> Option<Frame> {
        while self.ready.is_empty() {
            let frame = self.gnss.poll()?;
            self.take(frame);
        }
        self.ready.pop_front().map(Frame::Imu)
    }

    fn stats(&self) -> DecoderStats {
        let mut stats = self.gnss.stats();
        stats.frames_malformed += self.wrong_input;
        stats
    }

    fn finish(&mut self) -> Option<Frame> {
        while self.ready.is_empty() {
            let frame = self.gnss.finish()?;
            self.take(frame);
        }
        self.ready.pop_front().map(Frame::Imu)
    }
}

/// A CAN IMU: CAN frames through the DBC mapping into samples.
struct CanImuDecoder {
    imu: DbcImu,
    ready: VecDeque<ImuSample>,
    /// Byte input pushed to this CAN decoder (never with a validated config).
    wrong_input: u64,
}

impl FrameDecoder for CanImuDecoder {
    fn push(&mut self, input: Input<'_>) {
        match input {
            Input::Can(frame) => {
                if let Some(sample) = self.imu.push_frame(frame) {
                    self.ready.push_back(sample);
                }
            }
            Input::Bytes(_) => self.wrong_input += 1,
        }
    }

    fn poll(&mut self) -> Option<Frame> {
        self.ready.pop_front().map(Frame::Imu)
    }

    fn stats(&self) -> DecoderStats {
        let mut stats = self.imu.stats();
        stats.frames_malformed += self.wrong_input;
        stats
    }

    fn finish(&mut self) -> Option<Frame> {
        self.ready
            .pop_front()
            .or_else(|| self.imu.finish())
            .map(Frame::Imu)
    }
}

/// Makes a fresh decoder (one per connection, so a partial frame from before a disconnect
/// is not glued to the bytes after it).
pub type DecoderFactory = Box<dyn Fn() -> Box<dyn FrameDecoder> + Send + Sync>;

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

fn read_text(what: &str, path: &Path) -> Result<String, String> {
    std::fs::read_to_string(path)
        .map_err(|e| format!("cannot read the {what} {}: {e}", path.display()))
}

/// The decoder factory for a configured protocol. Reads and checks the files a protocol
/// needs (the DBC and its signal mapping) once, so a bad file is reported at start-up and by
/// `--check-config`, not on every connection.
pub fn decoder_for(device: &DeviceSpec) -> Result<DecoderFactory, String> {
    Ok(match device.protocol {
        // One decoder for all three: it takes NMEA, UBX or both interleaved.
        Protocol::Nmea | Protocol::Ubx | Protocol::Gnss => {
            Box::new(|| boxed(GnssDecoder::new(), gnss_epoch))
        }
        Protocol::UbxEsf => Box::new(|| {
            Box::new(EsfImuDecoder {
                gnss: GnssDecoder::new(),
                ready: VecDeque::new(),
                wrong_input: 0,
            }) as Box<dyn FrameDecoder>
        }),
        Protocol::Wit => Box::new(|| boxed(WitImuDecoder::new(), imu_sample)),
        Protocol::Xbus => Box::new(|| boxed(XbusDecoder::new(), xbus_sample)),
        Protocol::Vectornav => Box::new(|| boxed(VnDecoder::new(), vectornav_sample)),
        Protocol::Mip => Box::new(|| boxed(MipDecoder::new(), mip_sample)),
        Protocol::Csv => {
            let config = device.csv.clone().unwrap_or_default();
            // Checked once here so the factory below cannot fail.
            let template = CsvLineDecoder::new(config).map_err(|e| format!("device.{e}"))?;
            Box::new(move || boxed(template.clone(), imu_sample))
        }
        Protocol::CanDbc => {
            let dbc = device
                .dbc
                .as_ref()
                .ok_or("protocol `can-dbc` needs [device.dbc]")?;
            let dbc_text = read_text("DBC file", &dbc.file)?;
            let mapping_text = read_text("DBC signal mapping", &dbc.mapping)?;
            let mapping = DbcImuMapping::from_toml_str(&mapping_text)
                .map_err(|e| format!("{}: {e}", dbc.mapping.display()))?;
            let template = Arc::new(DbcImu::new(&dbc_text, &mapping).map_err(|e| {
                format!(
                    "{} with mapping {}: {e}",
                    dbc.file.display(),
                    dbc.mapping.display()
                )
            })?);
            Box::new(move || {
                Box::new(CanImuDecoder {
                    imu: (*template).clone(),
                    ready: VecDeque::new(),
                    wrong_input: 0,
                }) as Box<dyn FrameDecoder>
            })
        }
    })
}
