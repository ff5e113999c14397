//! slcan (Lawicel CAN232/CANUSB ASCII protocol), both directions: host commands (`O` open,
//! `L` listen-only open, `C` close, `S0`–`S8` bitrate) and adapter output (`t`/`T`/`r`/`R`
//! frames with an optional 4-hex-digit millisecond timestamp, bare `\r` = OK, BEL = error,
//! `z`/`Z` = transmit acknowledged). Every message ends with `\r`; a leading `\n` (adapters
//! that send CR LF) is ignored.
//!
//! Frame syntax: `tiiil<data>` (11-bit id, 3 hex digits), `Tiiiiiiiil<data>` (29-bit id, 8
//! digits), `riiil` / `Tiiiiiiiil` remote; `l` is the DLC 0–8, data are 2·DLC hex digits,
//! then optionally `tttt` (ms, 0..0xEA5F from the adapter's timer).
//!
//! Bad-line rule (counted, never a panic): a line over [`MAX_LINE`] bytes is dropped up to
//! its `\r` (`frames_too_long`); a line that does not parse, or starts with a byte that is
//! not an slcan command, is dropped (`frames_malformed`, its bytes in `bytes_skipped`).

use super::can::{parse_hex_bytes, parse_hex_u32, write_hex, CanFrame, CanKind};
use super::{Decoder, EncodeError, Encoder, Reject, StreamBuffer};
use crate::types::DecoderStats;

/// Longest valid line without its `\r`: `T` + 8 id + 1 dlc + 16 data + 4 timestamp.
pub const MAX_LINE: usize = 30;
const CR: u8 = b'\r';
const BEL: u8 = 0x07;

/// Bitrate codes `S0`..`S8`, bit/s.
pub const BITRATES: [u32; 9] = [
    10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000,
];

/// The `Sn` code for a bitrate, if it is one of [`BITRATES`].
pub fn bitrate_code(bitrate: u32) -> Option<u8> {
    BITRATES.iter().position(|&b| b == bitrate).map(|i| i as u8)
}

/// One slcan message.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum SlcanMessage {
    /// A CAN frame (`t`, `T`, `r`, `R`) with the adapter's timestamp in ms, if enabled.
    Frame {
        frame: CanFrame,
        timestamp_ms: Option<u16>,
    },
    /// `O`: open the channel.
    Open,
    /// `L`: open the channel listen-only.
    ListenOnly,
    /// `C`: close the channel.
    Close,
    /// `Sn`: set the bitrate to [`BITRATES`]`[n]`.
    Bitrate(u8),
    /// A bare `\r`: the adapter's OK.
    Ok,
    /// BEL: the adapter's error reply.
    Error,
    /// `z` (standard) / `Z` (extended): frame transmitted.
    TransmitAck { extended: bool },
    /// Another Lawicel command or reply (`V`, `v`, `N`, `F`, `Z0`/`Z1`, `M`, `m`, `s`, `X`,
    /// `W`, `Q`, `U`, `E`), kept as text without the `\r`.
    Other(String),
}

const OTHER_COMMANDS: &[u8] = b"VvNFZMmsXWQUE";

fn parse_frame(line: &[u8]) -> Option<SlcanMessage> {
    let (extended, remote) = match line.first()? {
        b't' => (false, false),
        b'T' => (true, false),
        b'r' => (false, true),
        b'R' => (true, true),
        _ => return None,
    };
    let id_len = if extended { 8 } else { 3 };
    if line.len() < 1 + id_len + 1 {
        return None;
    }
    let id = parse_hex_u32(&line[1..1 + id_len])?;
    let dlc_char = line[1 + id_len];
    if !dlc_char.is_ascii_digit() {
        return None;
    }
    let dlc = dlc_char - b'0';
    if dlc > 8 {
        return None;
    }
    let rest = &line[2 + id_len..];
    let data_digits = if remote { 0 } else { 2 * usize::from(dlc) };
    let timestamp_ms = match rest.len().checked_sub(data_digits)? {
        0 => None,
        4 => Some(parse_hex_u32(&rest[data_digits..])? as u16),
        _ => return None,
    };
    let frame = if remote {
        CanFrame::remote(id, extended, dlc).ok()?
    } else {
        let mut bytes = [0u8; 64];
        let n = parse_hex_bytes(&rest[..data_digits], &mut bytes)?;
        CanFrame::data(id, extended, &bytes[..n]).ok()?
    };
    Some(SlcanMessage::Frame {
        frame,
        timestamp_ms,
    })
}

fn parse_line(line: &[u8]) -> Option<SlcanMessage> {
    match line {
        [] => Some(SlcanMessage::Ok),
        [b'O'] => Some(SlcanMessage::Open),
        [b'L'] => Some(SlcanMessage::ListenOnly),
        [b'C'] => Some(SlcanMessage::Close),
        [b'S', d @ b'0'..=b'8'] => Some(SlcanMessage::Bitrate(d - b'0')),
        [b'z'] => Some(SlcanMessage::TransmitAck { extended: false }),
        [b'Z'] => Some(SlcanMessage::TransmitAck { extended: true }),
        [b't' | b'T' | b'r' | b'R', ..] => parse_frame(line),
        [first, ..] if OTHER_COMMANDS.contains(first) => {
            let text = std::str::from_utf8(line).ok()?;
            text.bytes()
                .all(|b| b.is_ascii_graphic())
                .then(|| SlcanMessage::Other(text.to_string()))
        }
        _ => None,
    }
}

/// Streaming slcan decoder. Counting follows the one rule of [`StreamBuffer`] (CR and LF
/// are line framing, never skipped bytes).
#[derive(Debug, Clone)]
pub struct SlcanDecoder {
    buf: StreamBuffer,
    discarding: bool,
}

impl Default for SlcanDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl SlcanDecoder {
    pub fn new() -> Self {
        SlcanDecoder {
            buf: StreamBuffer::text(),
            discarding: false,
        }
    }
}

impl Decoder for SlcanDecoder {
    type Frame = SlcanMessage;

    fn push(&mut self, bytes: &[u8]) {
        self.buf.push(bytes);
    }

    fn poll(&mut self) -> Option<SlcanMessage> {
        loop {
            let data = self.buf.data();
            if !self.discarding && data.first() == Some(&b'\n') {
                self.buf.pass(1);
                continue;
            }
            let end = memchr::memchr2(CR, BEL, data);
            if self.discarding {
                let n = end.map_or(data.len(), |e| e + usize::from(data[e] == CR));
                self.buf.skip(n);
                end?;
                self.discarding = false;
                continue;
            }
            let Some(end) = end else {
                if data.len() > MAX_LINE {
                    // Counted now; its bytes are skipped as they arrive.
                    self.buf.reject(0, Reject::TooLong);
                    self.discarding = true;
                    continue;
                }
                return None;
            };
            if data[end] == BEL {
                if end > MAX_LINE {
                    // Counted like a long line seen in pieces, so splits do not matter.
                    self.buf.reject(end, Reject::TooLong);
                } else if end > 0 {
                    // Bytes before a BEL with no CR: an unterminated line, dropped.
                    self.buf.reject(end, Reject::Malformed);
                }
                self.buf.accept(1);
                return Some(SlcanMessage::Error);
            }
            if end > MAX_LINE {
                self.buf.reject(end + 1, Reject::TooLong);
                continue;
            }
            match parse_line(&data[..end]) {
                Some(message) => {
                    self.buf.accept(end + 1);
                    return Some(message);
                }
                None => self.buf.reject(end + 1, Reject::Malformed),
            }
        }
    }

    fn stats(&self) -> DecoderStats {
        self.buf.stats()
    }
}

/// slcan encoder (upper-case hex, `\r` terminated).
#[derive(Debug, Default, Clone, Copy)]
pub struct SlcanEncoder;

impl Encoder for SlcanEncoder {
    type Frame = SlcanMessage;

    fn encode(&self, message: &SlcanMessage, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        match message {
            SlcanMessage::Frame {
                frame,
                timestamp_ms,
            } => {
                let (letter, id_digits) = match (frame.kind(), frame.is_extended()) {
                    (CanKind::Data, false) => (b't', 3),
                    (CanKind::Data, true) => (b'T', 8),
                    (CanKind::Remote, false) => (b'r', 3),
                    (CanKind::Remote, true) => (b'R', 8),
                    _ => {
                        return Err(EncodeError::Invalid {
                            field: "frame",
                            reason: "slcan carries classic data and remote frames only",
                        })
                    }
                };
                out.push(letter);
                write_hex(out, frame.id(), id_digits);
                out.push(b'0' + frame.len() as u8);
                for &b in frame.payload() {
                    write_hex(out, u32::from(b), 2);
                }
                if let Some(t) = timestamp_ms {
                    write_hex(out, u32::from(*t), 4);
                }
            }
            SlcanMessage::Open => out.push(b'O'),
            SlcanMessage::ListenOnly => out.push(b'L'),
            SlcanMessage::Close => out.push(b'C'),
            SlcanMessage::Bitrate(code) => {
                if *code > 8 {
                    return Err(EncodeError::Invalid {
                        field: "bitrate",
                        reason: "slcan bitrate code must be S0-S8",
                    });
                }
                out.extend_from_slice(&[b'S', b'0' + code]);
            }
            SlcanMessage::Ok => {}
            SlcanMessage::Error => {
                out.push(BEL);
                return Ok(());
            }
            SlcanMessage::TransmitAck { extended } => out.push(if *extended { b'Z' } else { b'z' }),
            SlcanMessage::Other(text) => {
                let valid = text.len() <= MAX_LINE
                    && text.bytes().all(|b| b.is_ascii_graphic())
                    && text
                        .bytes()
                        .next()
                        .is_some_and(|b| OTHER_COMMANDS.contains(&b))
                    && parse_line(text.as_bytes()) == Some(message.clone());
                if !valid {
                    return Err(EncodeError::Invalid {
                        field: "other",
                        reason: "not an slcan command this codec passes through",
                    });
                }
                out.extend_from_slice(text.as_bytes());
            }
        }
        out.push(CR);
        Ok(())
    }
}

/// Auto-detection score: CAN frame lines in `sample` (acks and bare CRs do not count).
pub fn detect_score(sample: &[u8]) -> u32 {
    let mut d = SlcanDecoder::new();
    d.push(sample);
    let mut frames = 0u32;
    while let Some(m) = d.poll() {
        if matches!(m, SlcanMessage::Frame { .. }) {
            frames = frames.saturating_add(1);
        }
    }
    frames
}
