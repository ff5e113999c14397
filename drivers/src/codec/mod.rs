//! Sans-IO codecs: bytes in, typed frames out, and the reverse.
//!
//! Every decoder follows the same shape: feed it bytes with [`Decoder::push`] in chunks of any
//! size (a split may fall anywhere, even inside a frame), then call [`Decoder::poll`] until it
//! returns `None`. Decoders never panic, resynchronise after corrupt bytes and count what they
//! dropped in [`DecoderStats`]. Every decoder has an [`Encoder`] for the same frame type.

use crate::types::DecoderStats;

pub mod can;
pub mod candump;
pub mod csv_line;
pub mod dbc;
pub mod slcan;
pub mod witmotion;
pub mod xbus;

/// A sans-IO decoder: bytes in with `push`, frames out with `poll`.
pub trait Decoder {
    /// What one decoded frame is.
    type Frame;
    /// Appends received bytes; they are kept until `poll` consumes them.
    fn push(&mut self, bytes: &[u8]);
    /// Returns the next complete frame, or `None` when more bytes are needed.
    fn poll(&mut self) -> Option<Self::Frame>;
    /// Counters since the decoder was created.
    fn stats(&self) -> DecoderStats;
}

/// A frame encoder: the inverse of a [`Decoder`] with the same `Frame` type.
pub trait Encoder {
    /// What one encoded frame is.
    type Frame;
    /// Appends the wire bytes of `frame` to `out`.
    fn encode(&self, frame: &Self::Frame, out: &mut Vec<u8>) -> Result<(), EncodeError>;
}

/// Why a frame could not be encoded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EncodeError {
    /// A value does not fit the protocol's field (range, resolution or NaN).
    #[error("{field}: value {value} cannot be represented ({reason})")]
    ValueOutOfRange {
        field: &'static str,
        value: f64,
        reason: &'static str,
    },
    /// The encoded frame would exceed the protocol's maximum length.
    #[error("frame of {len} bytes exceeds the protocol maximum of {max}")]
    TooLong { len: usize, max: usize },
    /// The frame is not valid for this protocol (for example a CAN id out of range).
    #[error("invalid frame: {0}")]
    Invalid(String),
}

/// A byte buffer for decoders: appended at the back, consumed from the front, compacted
/// lazily so consuming a frame is O(1) and no allocation happens per frame.
#[derive(Debug, Default, Clone)]
pub(crate) struct InputBuffer {
    bytes: Vec<u8>,
    start: usize,
}

impl InputBuffer {
    pub(crate) fn push(&mut self, input: &[u8]) {
        if self.start > 0 && (self.start >= self.bytes.len() || self.start > 4096) {
            self.bytes.drain(..self.start);
            self.start = 0;
        }
        self.bytes.extend_from_slice(input);
    }

    /// The unconsumed bytes.
    pub(crate) fn data(&self) -> &[u8] {
        &self.bytes[self.start..]
    }

    /// Marks `n` bytes at the front as consumed (clamped to what is there).
    pub(crate) fn consume(&mut self, n: usize) {
        self.start = (self.start + n).min(self.bytes.len());
        if self.start == self.bytes.len() {
            self.bytes.clear();
            self.start = 0;
        }
    }
}
