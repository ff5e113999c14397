//! candump log format (can-utils `candump -l`, read by `canplayer`), read and written:
//! `(1700000000.123456) can0 123#DEADBEEF`, one frame per line. Ids of 3 hex digits are
//! standard, 8 digits extended (with bit 0x20000000 set: an error frame); `123#R` or
//! `123#R5` is a remote frame (with DLC); `123##1DEADBEEF` is CAN FD, the digit after
//! `##` holding the flags (bit 0 BRS, bit 1 ESI). Data bytes may be separated by `.` on
//! input. A trailing direction token (` T`/` R`, newer can-utils) is accepted and ignored.
//!
//! Bad-line rule (counted, never a panic): lines longer than [`MAX_LINE`] are dropped
//! (`frames_too_long`), lines that do not parse are dropped (`frames_malformed`); blank
//! lines and lines starting with `#` are skipped silently.

use super::can::{hex_value, parse_hex_u32, write_hex, CanFrame, CanKind};
use super::{accepted_frames, Decoder, EncodeError, Encoder, Reject, StreamBuffer};
use crate::types::DecoderStats;

/// Longest accepted line (FD frame with 64 bytes plus a long timestamp and name fits).
pub const MAX_LINE: usize = 256;
const CAN_ERR_FLAG: u32 = 0x2000_0000;

/// A network interface name (1–15 printable ASCII bytes), stored inline.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct IfName {
    bytes: [u8; 15],
    len: u8,
}

impl IfName {
    /// Checks length and characters.
    pub fn new(name: &str) -> Result<Self, String> {
        if name.is_empty() || name.len() > 15 || !name.bytes().all(|b| b.is_ascii_graphic()) {
            return Err(format!(
                "interface name {name:?} must be 1-15 printable ASCII characters"
            ));
        }
        let mut bytes = [0u8; 15];
        bytes[..name.len()].copy_from_slice(name.as_bytes());
        Ok(IfName {
            bytes,
            len: name.len() as u8,
        })
    }

    pub fn as_str(&self) -> &str {
        // Only ASCII is ever stored, so this cannot fail.
        std::str::from_utf8(&self.bytes[..usize::from(self.len)]).unwrap_or("")
    }
}

impl std::fmt::Debug for IfName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:?}", self.as_str())
    }
}

impl serde::Serialize for IfName {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

/// One line of a candump log.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CandumpRecord {
    /// Reception time, microseconds since the Unix epoch.
    pub timestamp_us: u64,
    pub interface: IfName,
    pub frame: CanFrame,
}

impl CandumpRecord {
    /// Reception time in seconds since the Unix epoch.
    pub fn timestamp_s(&self) -> f64 {
        self.timestamp_us as f64 * 1e-6
    }
}

fn parse_timestamp(t: &[u8]) -> Option<u64> {
    let dot = memchr::memchr(b'.', t)?;
    let (sec, frac) = (&t[..dot], &t[dot + 1..]);
    if sec.is_empty() || sec.len() > 12 || frac.is_empty() || frac.len() > 9 {
        return None;
    }
    let digits = |d: &[u8]| -> Option<u64> {
        d.iter().try_fold(0u64, |acc, &c| {
            c.is_ascii_digit().then(|| acc * 10 + u64::from(c - b'0'))
        })
    };
    let sec = digits(sec)?;
    let mut frac_us = digits(frac)?;
    if frac.len() < 6 {
        frac_us *= 10u64.pow(6 - frac.len() as u32);
    } else {
        frac_us /= 10u64.pow(frac.len() as u32 - 6);
    }
    sec.checked_mul(1_000_000)?.checked_add(frac_us)
}

fn parse_data(digits: &[u8], out: &mut [u8; 64]) -> Option<usize> {
    let mut n = 0;
    let mut i = 0;
    while i < digits.len() {
        if digits[i] == b'.' {
            i += 1;
            continue;
        }
        let hi = hex_value(digits[i])?;
        let lo = hex_value(*digits.get(i + 1)?)?;
        *out.get_mut(n)? = (hi << 4) | lo;
        n += 1;
        i += 2;
    }
    Some(n)
}

fn parse_frame(text: &[u8]) -> Option<CanFrame> {
    let hash = memchr::memchr(b'#', text)?;
    let id_digits = &text[..hash];
    let raw_id = parse_hex_u32(id_digits)?;
    let extended = match id_digits.len() {
        3 => false,
        8 => true,
        _ => return None,
    };
    let rest = &text[hash + 1..];
    let mut bytes = [0u8; 64];
    if extended && raw_id & CAN_ERR_FLAG != 0 {
        let n = parse_data(rest, &mut bytes)?;
        return CanFrame::error(raw_id & !CAN_ERR_FLAG & 0x1FFF_FFFF, &bytes[..n]).ok();
    }
    match rest {
        [b'#', flags, data @ ..] => {
            let flags = hex_value(*flags)?;
            let n = parse_data(data, &mut bytes)?;
            CanFrame::fd(
                raw_id,
                extended,
                flags & 1 != 0,
                flags & 2 != 0,
                &bytes[..n],
            )
            .ok()
        }
        [b'R'] => CanFrame::remote(raw_id, extended, 0).ok(),
        [b'R', d] if d.is_ascii_digit() => CanFrame::remote(raw_id, extended, d - b'0').ok(),
        data => {
            let n = parse_data(data, &mut bytes)?;
            CanFrame::data(raw_id, extended, &bytes[..n]).ok()
        }
    }
}

/// Parses one line (without its line end). `None` when it is not a candump record.
pub fn parse_line(line: &[u8]) -> Option<CandumpRecord> {
    let mut fields = line
        .split(|&b| b == b' ' || b == b'\t')
        .filter(|f| !f.is_empty());
    let ts = fields.next()?;
    let ts = ts.strip_prefix(b"(")?.strip_suffix(b")")?;
    let timestamp_us = parse_timestamp(ts)?;
    let interface = IfName::new(std::str::from_utf8(fields.next()?).ok()?).ok()?;
    let frame = parse_frame(fields.next()?)?;
    match fields.next() {
        None | Some(b"T") | Some(b"R") => {}
        Some(_) => return None,
    }
    if fields.next().is_some() {
        return None;
    }
    Some(CandumpRecord {
        timestamp_us,
        interface,
        frame,
    })
}

/// Streaming candump log decoder. Counting follows the one rule of [`StreamBuffer`] (line
/// ends, blank lines and `#` comments are framing, never skipped bytes).
#[derive(Debug, Clone)]
pub struct CandumpDecoder {
    buf: StreamBuffer,
    discarding: bool,
}

impl Default for CandumpDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl CandumpDecoder {
    pub fn new() -> Self {
        CandumpDecoder {
            buf: StreamBuffer::text(),
            discarding: false,
        }
    }
}

impl Decoder for CandumpDecoder {
    type Frame = CandumpRecord;

    fn push(&mut self, bytes: &[u8]) {
        self.buf.push(bytes);
    }

    fn poll(&mut self) -> Option<CandumpRecord> {
        loop {
            let pos = self.buf.next_line(MAX_LINE, &mut self.discarding)?;
            let data = self.buf.data();
            let mut line = &data[..pos];
            if let Some(stripped) = line.strip_suffix(b"\r") {
                line = stripped;
            }
            let blank = line.iter().all(|b| b.is_ascii_whitespace());
            if blank || line.first() == Some(&b'#') {
                self.buf.pass(pos + 1);
                continue;
            }
            match parse_line(line) {
                Some(record) => {
                    self.buf.accept(pos + 1);
                    return Some(record);
                }
                None => self.buf.reject(pos + 1, Reject::Malformed),
            }
        }
    }

    fn stats(&self) -> DecoderStats {
        self.buf.stats()
    }
}

/// candump log writer (upper-case hex like can-utils, `\n` line end).
#[derive(Debug, Default, Clone, Copy)]
pub struct CandumpEncoder;

impl Encoder for CandumpEncoder {
    type Frame = CandumpRecord;

    fn encode(&self, record: &CandumpRecord, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        use std::io::Write;
        let frame = &record.frame;
        // Writing into a Vec cannot fail.
        let _ = write!(
            out,
            "({}.{:06}) {} ",
            record.timestamp_us / 1_000_000,
            record.timestamp_us % 1_000_000,
            record.interface.as_str()
        );
        let id_digits = if frame.is_extended() { 8 } else { 3 };
        match frame.kind() {
            CanKind::Error => write_hex(out, frame.id() | CAN_ERR_FLAG, 8),
            _ => write_hex(out, frame.id(), id_digits),
        }
        out.push(b'#');
        match frame.kind() {
            CanKind::Remote => {
                out.push(b'R');
                if !frame.is_empty() {
                    out.push(b'0' + frame.len() as u8);
                }
            }
            CanKind::Fd { brs, esi } => {
                out.push(b'#');
                write_hex(out, u32::from(brs) | (u32::from(esi) << 1), 1);
            }
            CanKind::Data | CanKind::Error => {}
        }
        for &b in frame.payload() {
            write_hex(out, u32::from(b), 2);
        }
        out.push(b'\n');
        Ok(())
    }
}

/// Auto-detection score: candump records in `sample`.
pub fn detect_score(sample: &[u8]) -> u32 {
    accepted_frames(CandumpDecoder::new(), sample)
}
