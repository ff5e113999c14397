//! Readings: what a logger or a simulator needs of a protocol, whatever its frames are.
//!
//! A [`Reading`] is an IMU sample or a GNSS fix. Every protocol row of
//! [`PROTOCOLS`](super::PROTOCOLS) builds a [`ReadingDecoder`] (bytes or CAN frames in,
//! readings out: what `imulogd` logs) and, where the simulator serves it, a
//! [`ReadingEncoder`] (a reading and its device clock in, wire bytes out). A codec module
//! makes its frames readings by implementing [`ToReading`] for its frame type; acks,
//! register replies and raw messages are no reading.

use super::can::CanFrame;
use super::{Decoder, EncodeError};
use crate::types::{DecoderStats, GnssFix, ImuSample};

/// One decoded reading, in the drivers' device-independent types.
#[derive(Debug, Clone, PartialEq)]
pub enum Reading {
    Imu(ImuSample),
    Gnss(GnssFix),
}

/// What a protocol's readings are: IMU samples or GNSS fixes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    Imu,
    Gnss,
}

/// What a protocol's [`ReadingDecoder`] takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Link {
    /// A byte stream (serial port, pty, TCP, a capture file).
    Bytes,
    /// CAN frames (SocketCAN, an slcan adapter's decoded lines).
    Can,
}

/// What one receive from a device delivered.
#[derive(Debug, Clone, Copy)]
pub enum Input<'a> {
    /// Bytes from a byte stream.
    Bytes(&'a [u8]),
    /// One CAN frame.
    Can(&'a CanFrame),
}

/// A decoder of readings: the codecs' `push`/`poll`/`stats` with frames already readings.
pub trait ReadingDecoder: Send {
    /// Feeds one input. Input of the wrong [`Link`] (CAN frames to a byte decoder or the
    /// reverse) is counted as malformed.
    fn push(&mut self, input: Input<'_>);
    fn poll(&mut self) -> Option<Reading>;
    fn stats(&self) -> DecoderStats;
    /// The input ended: readings the decoder held back.
    fn finish(&mut self) -> Option<Reading> {
        None
    }
}

/// Makes a fresh decoder (one per connection, so a partial frame from before a disconnect is
/// not glued to the bytes after it). Files a protocol needs are read and checked once, when
/// the factory is built.
pub type ReadingDecoderFactory = Box<dyn Fn() -> Box<dyn ReadingDecoder> + Send + Sync>;

/// A frame type some of whose frames are readings.
pub trait ToReading {
    /// The reading this frame carries, `None` for frames that carry none (acks, replies).
    fn to_reading(self) -> Option<Reading>;
}

impl ToReading for ImuSample {
    fn to_reading(self) -> Option<Reading> {
        Some(Reading::Imu(self))
    }
}

/// A decoder whose frames are readings already (one that yields both kinds).
impl ToReading for Reading {
    fn to_reading(self) -> Option<Reading> {
        Some(self)
    }
}

/// Any byte decoder whose frames are [`ToReading`], seen as a [`ReadingDecoder`].
struct ByteReadings<D> {
    inner: D,
    /// CAN frames pushed to this byte decoder.
    wrong_input: u64,
}

impl<D> ReadingDecoder for ByteReadings<D>
where
    D: Decoder + Send,
    D::Frame: ToReading,
{
    fn push(&mut self, input: Input<'_>) {
        match input {
            Input::Bytes(bytes) => self.inner.push(bytes),
            Input::Can(_) => self.wrong_input += 1,
        }
    }

    fn poll(&mut self) -> Option<Reading> {
        loop {
            if let Some(reading) = self.inner.poll()?.to_reading() {
                return Some(reading);
            }
        }
    }

    fn stats(&self) -> DecoderStats {
        let mut stats = self.inner.stats();
        stats.frames_malformed += self.wrong_input;
        stats
    }

    fn finish(&mut self) -> Option<Reading> {
        loop {
            if let Some(reading) = self.inner.finish()?.to_reading() {
                return Some(reading);
            }
        }
    }
}

/// The factory of a byte protocol: each decoder is `make()`.
pub fn byte_readings<D, F>(make: F) -> ReadingDecoderFactory
where
    D: Decoder + Send + 'static,
    D::Frame: ToReading,
    F: Fn() -> D + Send + Sync + 'static,
{
    Box::new(move || {
        Box::new(ByteReadings {
            inner: make(),
            wrong_input: 0,
        })
    })
}

/// The device clock a reading goes out with (IMU protocols; GNSS fixes carry their time).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DeviceClock {
    /// Time since the device started, s: Xbus SampleTimeFine, VectorNav TimeStartup, the
    /// MIP reference timestamp, the CAN `TimeUs` signal.
    pub time_s: f64,
    /// Wall-clock time of the sample, ns since the Unix epoch (WitMotion's TIME packet).
    pub wall_ns: i64,
    /// The sample interval, s (the output period): what a device that sends delta theta /
    /// delta velocity integrates over; 0 when not known.
    pub interval_s: f64,
}

/// An encoder of readings: the wire bytes a device sends for one reading. The sample's
/// `sensor_time` is the device counter for protocols that carry one (the Xbus
/// PacketCounter, the time column of a CSV line).
pub trait ReadingEncoder: Send + Sync {
    /// Appends the frame(s) of `reading` to `out`. On error `out` is left as it was.
    fn encode(
        &self,
        reading: &Reading,
        clock: &DeviceClock,
        out: &mut Vec<u8>,
    ) -> Result<(), EncodeError>;
}

/// An encoder that appends the frames of one kind of reading, out as it was on error.
struct KindEncoder<F> {
    encode: F,
}

/// The [`ReadingEncoder`] of an IMU protocol, from a function that encodes one sample.
pub fn imu_encoder<F>(encode: F) -> Box<dyn ReadingEncoder>
where
    F: Fn(&ImuSample, &DeviceClock, &mut Vec<u8>) -> Result<(), EncodeError>
        + Send
        + Sync
        + 'static,
{
    Box::new(KindEncoder {
        encode: move |reading: &Reading, clock: &DeviceClock, out: &mut Vec<u8>| match reading {
            Reading::Imu(sample) => encode(sample, clock, out),
            Reading::Gnss(_) => Err(EncodeError::Invalid {
                field: "reading",
                reason: "an IMU protocol carries IMU samples, not GNSS fixes",
            }),
        },
    })
}

/// The [`ReadingEncoder`] of a GNSS protocol, from a function that encodes one fix.
pub fn gnss_encoder<F>(encode: F) -> Box<dyn ReadingEncoder>
where
    F: Fn(&GnssFix, &mut Vec<u8>) -> Result<(), EncodeError> + Send + Sync + 'static,
{
    Box::new(KindEncoder {
        encode: move |reading: &Reading, _: &DeviceClock, out: &mut Vec<u8>| match reading {
            Reading::Gnss(fix) => encode(fix, out),
            Reading::Imu(_) => Err(EncodeError::Invalid {
                field: "reading",
                reason: "a GNSS protocol carries fixes, not IMU samples",
            }),
        },
    })
}

impl<F> ReadingEncoder for KindEncoder<F>
where
    F: Fn(&Reading, &DeviceClock, &mut Vec<u8>) -> Result<(), EncodeError> + Send + Sync,
{
    fn encode(
        &self,
        reading: &Reading,
        clock: &DeviceClock,
        out: &mut Vec<u8>,
    ) -> Result<(), EncodeError> {
        let start = out.len();
        let result = (self.encode)(reading, clock, out);
        if result.is_err() {
            out.truncate(start);
        }
        result
    }
}
