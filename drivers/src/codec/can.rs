//! The CAN frame type shared by the slcan, candump, SocketCAN and DBC code: classic CAN 2.0
//! (data, remote, error) and CAN FD frames, validated on construction.

use serde::ser::SerializeStruct;
use serde::{Serialize, Serializer};

/// Largest standard (11-bit) identifier.
pub const MAX_STANDARD_ID: u32 = 0x7FF;
/// Largest extended (29-bit) identifier.
pub const MAX_EXTENDED_ID: u32 = 0x1FFF_FFFF;
/// Data lengths a CAN FD frame may have.
pub const FD_LENGTHS: [usize; 16] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64];

/// What kind of CAN frame this is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CanKind {
    /// Classic data frame, 0–8 bytes.
    Data,
    /// Classic remote request: no data, `len` is the requested DLC (0–8).
    Remote,
    /// SocketCAN error frame: `id` holds the error class bits, data the details (8 bytes).
    Error,
    /// CAN FD data frame, length in [`FD_LENGTHS`].
    Fd { brs: bool, esi: bool },
}

/// One CAN frame. Construct with [`CanFrame::data`], [`CanFrame::remote`], [`CanFrame::fd`]
/// or [`CanFrame::error`], which check id and length, so a `CanFrame` is always valid.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct CanFrame {
    id: u32,
    extended: bool,
    kind: CanKind,
    len: u8,
    bytes: [u8; 64],
}

impl std::fmt::Debug for CanFrame {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CanFrame")
            .field("id", &format_args!("{:#x}", self.id))
            .field("extended", &self.extended)
            .field("kind", &self.kind)
            .field("len", &self.len)
            .field("data", &self.payload())
            .finish()
    }
}

impl Serialize for CanFrame {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut s = serializer.serialize_struct("CanFrame", 5)?;
        s.serialize_field("id", &self.id)?;
        s.serialize_field("extended", &self.extended)?;
        s.serialize_field("kind", &self.kind)?;
        s.serialize_field("len", &self.len)?;
        s.serialize_field("data", self.payload())?;
        s.end()
    }
}

fn check_id(id: u32, extended: bool) -> Result<(), String> {
    let max = if extended {
        MAX_EXTENDED_ID
    } else {
        MAX_STANDARD_ID
    };
    if id > max {
        return Err(format!(
            "CAN id {id:#x} exceeds the {} maximum {max:#x}",
            if extended { "extended" } else { "standard" }
        ));
    }
    Ok(())
}

impl CanFrame {
    fn build(id: u32, extended: bool, kind: CanKind, payload: &[u8], len: u8) -> Self {
        let mut bytes = [0u8; 64];
        bytes[..payload.len()].copy_from_slice(payload);
        CanFrame {
            id,
            extended,
            kind,
            len,
            bytes,
        }
    }

    /// A classic data frame with 0–8 bytes.
    pub fn data(id: u32, extended: bool, payload: &[u8]) -> Result<Self, String> {
        check_id(id, extended)?;
        if payload.len() > 8 {
            return Err(format!(
                "classic CAN frame has {} data bytes (max 8)",
                payload.len()
            ));
        }
        Ok(Self::build(
            id,
            extended,
            CanKind::Data,
            payload,
            payload.len() as u8,
        ))
    }

    /// A classic remote frame requesting `dlc` (0–8) bytes.
    pub fn remote(id: u32, extended: bool, dlc: u8) -> Result<Self, String> {
        check_id(id, extended)?;
        if dlc > 8 {
            return Err(format!("remote frame DLC {dlc} exceeds 8"));
        }
        Ok(Self::build(id, extended, CanKind::Remote, &[], dlc))
    }

    /// A CAN FD data frame; `payload.len()` must be one of [`FD_LENGTHS`].
    pub fn fd(
        id: u32,
        extended: bool,
        brs: bool,
        esi: bool,
        payload: &[u8],
    ) -> Result<Self, String> {
        check_id(id, extended)?;
        if !FD_LENGTHS.contains(&payload.len()) {
            return Err(format!(
                "CAN FD frame has {} data bytes (allowed: {FD_LENGTHS:?})",
                payload.len()
            ));
        }
        Ok(Self::build(
            id,
            extended,
            CanKind::Fd { brs, esi },
            payload,
            payload.len() as u8,
        ))
    }

    /// A SocketCAN error frame: `class` are the error class bits (29 bits), 0–8 data bytes.
    pub fn error(class: u32, payload: &[u8]) -> Result<Self, String> {
        check_id(class, true)?;
        if payload.len() > 8 {
            return Err(format!(
                "error frame has {} data bytes (max 8)",
                payload.len()
            ));
        }
        Ok(Self::build(
            class,
            true,
            CanKind::Error,
            payload,
            payload.len() as u8,
        ))
    }

    /// Identifier without flag bits.
    pub fn id(&self) -> u32 {
        self.id
    }
    /// True for a 29-bit identifier.
    pub fn is_extended(&self) -> bool {
        self.extended
    }
    /// What kind of frame this is.
    pub fn kind(&self) -> CanKind {
        self.kind
    }
    /// Data length; for a remote frame the requested DLC.
    pub fn len(&self) -> usize {
        usize::from(self.len)
    }
    /// True when [`CanFrame::len`] is 0.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// The data bytes (empty for a remote frame).
    pub fn payload(&self) -> &[u8] {
        match self.kind {
            CanKind::Remote => &[],
            _ => &self.bytes[..usize::from(self.len)],
        }
    }
}

/// Parses one hex digit.
pub(crate) fn hex_value(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'a'..=b'f' => Some(c - b'a' + 10),
        b'A'..=b'F' => Some(c - b'A' + 10),
        _ => None,
    }
}

/// Parses a run of hex digits (at most 8) as a number.
pub(crate) fn parse_hex_u32(digits: &[u8]) -> Option<u32> {
    if digits.is_empty() || digits.len() > 8 {
        return None;
    }
    digits
        .iter()
        .try_fold(0u32, |acc, &c| Some((acc << 4) | u32::from(hex_value(c)?)))
}

/// Parses pairs of hex digits into `out`, returning how many bytes were written.
pub(crate) fn parse_hex_bytes(digits: &[u8], out: &mut [u8; 64]) -> Option<usize> {
    if !digits.len().is_multiple_of(2) || digits.len() / 2 > out.len() {
        return None;
    }
    for (i, pair) in digits.chunks_exact(2).enumerate() {
        out[i] = (hex_value(pair[0])? << 4) | hex_value(pair[1])?;
    }
    Some(digits.len() / 2)
}

const HEX_UPPER: &[u8; 16] = b"0123456789ABCDEF";

/// Appends `value` as exactly `digits` upper-case hex digits.
pub(crate) fn write_hex(out: &mut Vec<u8>, value: u32, digits: u32) {
    for shift in (0..digits).rev() {
        out.push(HEX_UPPER[((value >> (shift * 4)) & 0xF) as usize]);
    }
}
