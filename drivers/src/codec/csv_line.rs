//! Configurable ASCII/CSV line format for home-built IMUs: one sample per line, fields split
//! by a separator, a column map saying which field is time, gyro x/y/z, accel x/y/z,
//! temperature and status, and a scale and offset per column (SI = raw × scale + offset, so
//! raw = (SI − offset) / scale). Lines starting with the comment prefix and blank lines are
//! ignored; `\r\n` and `\n` both end a line.
//!
//! Rules for bad lines (counted, never a panic): a line longer than `max_line_len` is
//! dropped up to its newline (`frames_too_long`); a line that is not UTF-8, lacks a mapped
//! column, or has a mapped field that is not a finite number is dropped
//! (`frames_malformed`). A header line is thus counted as malformed unless it is commented.

use serde::{Deserialize, Serialize};

use super::{Decoder, EncodeError, Encoder, Reject, StreamBuffer};
use crate::types::{DecoderStats, ImuSample};

/// Where one quantity is in the line and how to turn it into SI.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CsvColumn {
    /// Zero-based field index.
    pub index: usize,
    /// SI = raw × scale + offset.
    #[serde(default = "one")]
    pub scale: f64,
    #[serde(default)]
    pub offset: f64,
}

fn one() -> f64 {
    1.0
}

impl CsvColumn {
    /// A column with unit scale and no offset.
    pub fn at(index: usize) -> Self {
        CsvColumn {
            index,
            scale: 1.0,
            offset: 0.0,
        }
    }
    /// A column with a scale and no offset.
    pub fn scaled(index: usize, scale: f64) -> Self {
        CsvColumn {
            index,
            scale,
            offset: 0.0,
        }
    }
}

/// The line format. Deserialise it from the `[csv]` table of a device config, e.g.
///
/// ```toml
/// separator = ","
/// comment_prefix = "#"
/// time = { index = 0, scale = 1e-6 }          # microseconds -> s
/// gyro = [ { index = 1, scale = 0.0174532925 }, { index = 2, scale = 0.0174532925 }, { index = 3, scale = 0.0174532925 } ]
/// accel = [ { index = 4 }, { index = 5 }, { index = 6 } ]
/// temp = { index = 7 }
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CsvLineConfig {
    /// Field separator (one ASCII character, e.g. `,`, `;`, tab or space).
    #[serde(default = "default_separator")]
    pub separator: char,
    /// Lines starting with this are ignored; empty string disables comments.
    #[serde(default = "default_comment")]
    pub comment_prefix: String,
    #[serde(default)]
    pub time: Option<CsvColumn>,
    #[serde(default)]
    pub gyro: Option<[CsvColumn; 3]>,
    #[serde(default)]
    pub accel: Option<[CsvColumn; 3]>,
    #[serde(default)]
    pub temp: Option<CsvColumn>,
    /// Status word column (integer, decimal or `0x` hex).
    #[serde(default)]
    pub status: Option<usize>,
    /// Longest accepted line, bytes.
    #[serde(default = "default_max_line")]
    pub max_line_len: usize,
}

fn default_separator() -> char {
    ','
}
fn default_comment() -> String {
    "#".to_string()
}
fn default_max_line() -> usize {
    1024
}

impl Default for CsvLineConfig {
    /// `time,gx,gy,gz,ax,ay,az,temp` in s, rad/s, m/s², °C.
    fn default() -> Self {
        CsvLineConfig {
            separator: ',',
            comment_prefix: "#".to_string(),
            time: Some(CsvColumn::at(0)),
            gyro: Some([CsvColumn::at(1), CsvColumn::at(2), CsvColumn::at(3)]),
            accel: Some([CsvColumn::at(4), CsvColumn::at(5), CsvColumn::at(6)]),
            temp: Some(CsvColumn::at(7)),
            status: None,
            max_line_len: default_max_line(),
        }
    }
}

impl CsvLineConfig {
    /// Checks the configuration; the message names the offending key.
    pub fn validate(&self) -> Result<(), String> {
        if !self.separator.is_ascii() || self.separator == '\n' || self.separator == '\r' {
            return Err(format!(
                "csv.separator: {:?} must be one ASCII character other than a line end",
                self.separator
            ));
        }
        let mut columns: Vec<(&str, CsvColumn)> = Vec::new();
        columns.extend(self.time.map(|c| ("csv.time", c)));
        if let Some(g) = self.gyro {
            columns.extend(g.iter().map(|&c| ("csv.gyro", c)));
        }
        if let Some(a) = self.accel {
            columns.extend(a.iter().map(|&c| ("csv.accel", c)));
        }
        columns.extend(self.temp.map(|c| ("csv.temp", c)));
        for (key, c) in &columns {
            if !c.scale.is_finite() || c.scale == 0.0 || !c.offset.is_finite() {
                return Err(format!(
                    "{key}: scale must be finite and non-zero and offset finite (got scale {}, offset {})",
                    c.scale, c.offset
                ));
            }
        }
        let mut indices: Vec<usize> = columns.iter().map(|(_, c)| c.index).collect();
        indices.extend(self.status);
        let n = indices.len();
        indices.sort_unstable();
        indices.dedup();
        if indices.len() != n {
            return Err("csv: two quantities map to the same column index".to_string());
        }
        if n == 0 {
            return Err("csv: no columns mapped".to_string());
        }
        if self.max_line_len == 0 {
            return Err("csv.max_line_len must be positive".to_string());
        }
        Ok(())
    }

    fn column_count(&self) -> usize {
        let mut max = 0;
        let mut see = |i: usize| max = max.max(i + 1);
        self.time.iter().for_each(|c| see(c.index));
        self.gyro.iter().flatten().for_each(|c| see(c.index));
        self.accel.iter().flatten().for_each(|c| see(c.index));
        self.temp.iter().for_each(|c| see(c.index));
        self.status.iter().for_each(|&i| see(i));
        max
    }
}

/// Most fields a line may have that we look at.
const MAX_FIELDS: usize = 64;

/// Streaming decoder for CSV lines into [`ImuSample`]s.
#[derive(Debug, Clone)]
pub struct CsvLineDecoder {
    config: CsvLineConfig,
    buf: StreamBuffer,
    /// True while discarding the rest of an over-long line.
    discarding: bool,
}

impl CsvLineDecoder {
    /// A decoder for `config`; fails with the offending key when the config is invalid.
    pub fn new(config: CsvLineConfig) -> Result<Self, String> {
        config.validate()?;
        if config.column_count() > MAX_FIELDS {
            return Err(format!("csv: column index above {}", MAX_FIELDS - 1));
        }
        Ok(CsvLineDecoder {
            config,
            buf: StreamBuffer::text(),
            discarding: false,
        })
    }

    fn parse_line(&self, line: &[u8]) -> Result<Option<ImuSample>, ()> {
        let Ok(text) = std::str::from_utf8(line) else {
            return Err(());
        };
        let text = text.trim();
        if text.is_empty()
            || (!self.config.comment_prefix.is_empty()
                && text.starts_with(self.config.comment_prefix.as_str()))
        {
            return Ok(None);
        }
        let mut fields: [&str; MAX_FIELDS] = [""; MAX_FIELDS];
        let mut count = 0;
        let needed = self.config.column_count();
        if self.config.separator == ' ' {
            for piece in text.split_ascii_whitespace().take(needed) {
                fields[count] = piece;
                count += 1;
            }
        } else {
            for piece in text.split(self.config.separator).take(needed) {
                fields[count] = piece.trim();
                count += 1;
            }
        }
        if count < needed {
            return Err(());
        }
        let value = |c: &CsvColumn| -> Result<f64, ()> {
            let raw: f64 = fields[c.index].parse().map_err(|_| ())?;
            let si = raw * c.scale + c.offset;
            if si.is_finite() {
                Ok(si)
            } else {
                Err(())
            }
        };
        let vec3 = |cols: &[CsvColumn; 3]| -> Result<[f64; 3], ()> {
            Ok([value(&cols[0])?, value(&cols[1])?, value(&cols[2])?])
        };
        let status = match self.config.status {
            None => 0,
            Some(i) => {
                let f = fields[i];
                match f.strip_prefix("0x").or_else(|| f.strip_prefix("0X")) {
                    Some(hex) => u32::from_str_radix(hex, 16).map_err(|_| ())?,
                    None => f.parse().map_err(|_| ())?,
                }
            }
        };
        Ok(Some(ImuSample {
            sensor_time: self.config.time.as_ref().map(value).transpose()?,
            gyro: self.config.gyro.as_ref().map(vec3).transpose()?,
            accel: self.config.accel.as_ref().map(vec3).transpose()?,
            temp_c: self.config.temp.as_ref().map(value).transpose()?,
            status,
        }))
    }
}

impl Decoder for CsvLineDecoder {
    type Frame = ImuSample;

    fn push(&mut self, bytes: &[u8]) {
        self.buf.push(bytes);
    }

    fn poll(&mut self) -> Option<ImuSample> {
        loop {
            let pos = self
                .buf
                .next_line(self.config.max_line_len, &mut self.discarding)?;
            let data = self.buf.data();
            match self.parse_line(&data[..pos]) {
                Ok(Some(sample)) => {
                    self.buf.accept(pos + 1);
                    return Some(sample);
                }
                Ok(None) => self.buf.pass(pos + 1),
                Err(()) => self.buf.reject(pos + 1, Reject::Malformed),
            }
        }
    }

    fn stats(&self) -> DecoderStats {
        self.buf.stats()
    }
}

/// Shortest text that parses back to exactly `v`: plain notation for everyday magnitudes,
/// scientific notation for very large or small ones (plain would run to hundreds of digits).
fn format_number(v: f64) -> String {
    let magnitude = v.abs();
    if v == 0.0 || (1e-5..1e16).contains(&magnitude) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// Writes samples as lines in the configured format (fields not mapped are left empty,
/// values printed in Rust's shortest round-trip form, unmapped columns as `0`, `\n` line
/// end). Encoding allocates; it is for simulators and tests, not a hot path.
#[derive(Debug, Clone)]
pub struct CsvLineEncoder {
    config: CsvLineConfig,
}

impl CsvLineEncoder {
    pub fn new(config: CsvLineConfig) -> Result<Self, String> {
        config.validate()?;
        Ok(CsvLineEncoder { config })
    }
}

impl Encoder for CsvLineEncoder {
    type Frame = ImuSample;

    fn encode(&self, sample: &ImuSample, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        use std::io::Write;
        let n = self.config.column_count();
        let mut fields: Vec<Option<String>> = vec![None; n];
        let mut put = |field: &'static str, c: &CsvColumn, si: Option<f64>| {
            let si = si.ok_or(EncodeError::Invalid {
                field,
                reason: "mapped to a column but missing from the sample",
            })?;
            let raw = (si - c.offset) / c.scale;
            if !raw.is_finite() {
                return Err(EncodeError::OutOfRange { field, value: si });
            }
            fields[c.index] = Some(format_number(raw));
            Ok(())
        };
        if let Some(c) = &self.config.time {
            put("time", c, sample.sensor_time)?;
        }
        if let Some(cols) = &self.config.gyro {
            for (i, c) in cols.iter().enumerate() {
                put("gyro", c, sample.gyro.map(|g| g[i]))?;
            }
        }
        if let Some(cols) = &self.config.accel {
            for (i, c) in cols.iter().enumerate() {
                put("accel", c, sample.accel.map(|a| a[i]))?;
            }
        }
        if let Some(c) = &self.config.temp {
            put("temp", c, sample.temp_c)?;
        }
        if let Some(i) = self.config.status {
            fields[i] = Some(sample.status.to_string());
        }
        let sep = self.config.separator.to_string();
        // Unmapped columns are written as 0 so whitespace-separated lines keep their layout.
        let line: Vec<String> = fields
            .into_iter()
            .map(|f| f.unwrap_or_else(|| "0".to_string()))
            .collect();
        // Writing into a Vec cannot fail.
        let _ = writeln!(out, "{}", line.join(&sep));
        Ok(())
    }
}

fn open_error(reason: String) -> super::OpenError {
    super::OpenError {
        protocol: "csv",
        reason,
    }
}

/// The decoder of the column map of `options.config` (TOML, see [`CsvLineConfig`]), else
/// of the default layout.
fn decoder_of(options: &super::DecoderOptions) -> Result<CsvLineDecoder, super::OpenError> {
    let config = match &options.config {
        None => CsvLineConfig::default(),
        Some(file) => {
            toml::from_str(&file.text).map_err(|e| open_error(format!("{}: {e}", file.name)))?
        }
    };
    CsvLineDecoder::new(config).map_err(open_error)
}

/// Builds the decoder for `imulab decode --protocol csv`.
pub fn open_json(
    options: &super::DecoderOptions,
) -> Result<Box<dyn super::JsonDecoder>, super::OpenError> {
    Ok(Box::new(decoder_of(options)?))
}

/// Readings of CSV lines in the column map of `options`.
pub fn readings(
    options: &super::DecoderOptions,
) -> Result<super::reading::ReadingDecoderFactory, super::OpenError> {
    let template = decoder_of(options)?;
    Ok(super::reading::byte_readings(move || template.clone()))
}

/// The line a CSV IMU sends for one sample, in the column map of `options` (the time
/// column is the sample's `sensor_time`).
pub fn encoder(
    options: &super::DecoderOptions,
) -> Result<Box<dyn super::reading::ReadingEncoder>, super::OpenError> {
    let encoder = CsvLineEncoder {
        config: decoder_of(options)?.config,
    };
    Ok(super::reading::imu_encoder(move |sample, _, out| {
        encoder.encode(sample, out)
    }))
}
