//! Input layer: a [`SampleSource`] streams rows of named channels (CSV/TSV, NumPy `.npy`,
//! and sessions through a small adapter); [`read_axis`] pulls one channel out of it as a
//! uniformly sampled rate series, checking for gaps, NaN/Inf and non-uniform sampling
//! under an explicit [`GapPolicy`]. Only one axis (plus an optional temperature channel)
//! is held in memory at a time.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

/// Errors of the input layer; each says where (file, row, column) and what.
#[derive(Debug, thiserror::Error)]
pub enum InputError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: row {row}: {message}")]
    Parse {
        path: PathBuf,
        row: u64,
        message: String,
    },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
    #[error("{0}")]
    Channel(String),
    #[error("{0}")]
    Sampling(String),
    /// A visitor asked to stop reading early; never returned to callers of this module.
    #[error("reading stopped early")]
    Stopped,
}

/// Callback receiving `(row_index, values)` for each streamed row.
pub type RowVisitor<'a> = dyn FnMut(u64, &[f64]) -> Result<(), InputError> + 'a;

/// Callback receiving `(first_row_index, columns)` for each streamed block of rows: one
/// slice per wanted channel, all of the same length.
pub type BlockVisitor<'a> = dyn FnMut(u64, &[&[f64]]) -> Result<(), InputError> + 'a;

/// Rows per block of [`SampleSource::for_each_block`].
pub const BLOCK_ROWS: usize = 1 << 16;

/// A source of rows of named numeric channels, streamed in time order.
pub trait SampleSource {
    /// Short description for reports (e.g. the file name).
    fn describe(&self) -> String;
    /// Channel names in order.
    fn channels(&self) -> &[String];
    /// Calls `visit(row_index, values)` for each row with the values of `wanted` channels
    /// (in the order given).
    fn for_each_row(&self, wanted: &[usize], visit: &mut RowVisitor<'_>) -> Result<(), InputError>;

    /// Calls `visit(first_row, columns)` for consecutive blocks of rows, one slice per
    /// `wanted` channel. Sources that hold columns (.npy, sessions) override this to hand
    /// out whole blocks without per-row work; the default gathers rows.
    fn for_each_block(
        &self,
        wanted: &[usize],
        visit: &mut BlockVisitor<'_>,
    ) -> Result<(), InputError> {
        let mut columns: Vec<Vec<f64>> = vec![Vec::with_capacity(BLOCK_ROWS); wanted.len()];
        let mut first = 0u64;
        let mut flush = |columns: &mut Vec<Vec<f64>>, first: u64| -> Result<(), InputError> {
            let slices: Vec<&[f64]> = columns.iter().map(Vec::as_slice).collect();
            visit(first, &slices)?;
            columns.iter_mut().for_each(Vec::clear);
            Ok(())
        };
        self.for_each_row(wanted, &mut |row, values| {
            if columns.first().is_some_and(Vec::is_empty) {
                first = row;
            }
            for (column, &v) in columns.iter_mut().zip(values) {
                column.push(v);
            }
            if columns.first().is_some_and(|c| c.len() >= BLOCK_ROWS) {
                flush(&mut columns, first)?;
            }
            Ok(())
        })?;
        if columns.first().is_some_and(|c| !c.is_empty()) {
            flush(&mut columns, first)?;
        }
        Ok(())
    }

    /// The device name when the source is a session device (names the results).
    fn as_any_session(&self) -> Option<&str> {
        None
    }

    /// Upper bound of the number of rows, when cheap to know (sizes buffers and decides how
    /// many axes one reading pass may hold within the memory budget).
    fn row_count_hint(&self) -> Option<u64> {
        None
    }

    /// How the source's own samples are timed when it knows (a session: its sensor clock
    /// where the protocol defines one, else the host arrival times); `None` for plain files,
    /// whose timing the user gives.
    fn native_timing(&self) -> Option<Timing> {
        None
    }

    /// The physical unit of a channel when the source knows it (sessions do).
    fn channel_unit(&self, _channel: usize) -> Option<crate::allan::units::RateUnit> {
        None
    }

    /// Resolves a channel given by name or by 0-based index.
    fn channel_index(&self, spec: &str) -> Result<usize, InputError> {
        let spec = spec.trim();
        if let Some(i) = self.channels().iter().position(|c| c == spec) {
            return Ok(i);
        }
        match spec.parse::<usize>() {
            Ok(i) if i < self.channels().len() => Ok(i),
            _ => Err(InputError::Channel(format!(
                "{}: no channel `{spec}` (channels: {})",
                self.describe(),
                self.channels().join(", ")
            ))),
        }
    }
}

// --- CSV / TSV ---------------------------------------------------------------------------

/// A delimited text file with an optional header row (detected: a first row that is not
/// all numbers is a header). The delimiter is detected from the first lines: tab (also for
/// `.tsv`/`.tab` names), semicolon, comma, or runs of whitespace. Lines starting with `#`
/// are comments. Semicolon files may use a decimal comma (`0,01;1,5`).
pub struct CsvSource {
    path: PathBuf,
    delimiter: Delimiter,
    has_header: bool,
    channels: Vec<String>,
}

/// How the fields of a line are separated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Delimiter {
    /// One byte (`,`, `;` or tab), read with the `csv` crate.
    Byte(u8),
    /// Runs of spaces or tabs (space-aligned columns). The `csv` crate takes one byte as
    /// the delimiter and would read every extra space as an empty field, so these lines are
    /// split here.
    Whitespace,
}

/// The delimiter that splits every one of `lines` into the same number (≥ 2) of fields,
/// trying tab, semicolon, comma, then whitespace; `None` for a single column.
fn detect_delimiter(lines: &[&str]) -> Option<Delimiter> {
    let consistent = |count: &dyn Fn(&str) -> usize| {
        let first = count(lines[0]);
        first >= 2 && lines.iter().all(|l| count(l) == first)
    };
    for byte in [b'\t', b';', b','] {
        let count = |l: &str| l.split(byte as char).count();
        // A header may carry one field more or less than the rows (a trailing delimiter).
        let header_fits = |rows: usize| count(lines[0]).abs_diff(rows) <= 1;
        let fits = match lines.get(1..).filter(|rows| !rows.is_empty()) {
            Some(rows) => {
                let n = count(rows[0]);
                n >= 2 && rows.iter().all(|l| count(l) == n) && header_fits(n)
            }
            None => consistent(&count),
        };
        if fits {
            return Some(Delimiter::Byte(byte));
        }
    }
    // Data lines (not the header, whose names may hold spaces) decide whitespace.
    let data = if lines.len() > 1 { &lines[1..] } else { lines };
    let fields = |l: &str| l.split_whitespace().count();
    let first = fields(data[0]);
    (first >= 2 && data.iter().all(|l| fields(l) == first)).then_some(Delimiter::Whitespace)
}

/// Splits a space-aligned header into `fields` names: on runs of two or more spaces (or
/// tabs) when that gives the right count (names such as `Time (s)` keep their space),
/// else on every run of whitespace.
fn split_whitespace_header(line: &str, fields: usize) -> Option<Vec<String>> {
    let wide: Vec<String> = line
        .split("  ")
        .flat_map(|p| p.split('\t'))
        .map(str::trim)
        .filter(|p| !p.is_empty())
        .map(String::from)
        .collect();
    if wide.len() == fields {
        return Some(wide);
    }
    let narrow: Vec<String> = line.split_whitespace().map(String::from).collect();
    (narrow.len() == fields).then_some(narrow)
}

impl CsvSource {
    pub fn open(path: &Path) -> Result<Self, InputError> {
        let io = |source| InputError::Io {
            path: path.to_path_buf(),
            source,
        };
        let format = |message: String| InputError::Format {
            path: path.to_path_buf(),
            message,
        };
        let text_head = {
            use std::io::Read;
            let mut buf = vec![0u8; 64 * 1024];
            let mut f = File::open(path).map_err(io)?;
            let n = f.read(&mut buf).map_err(io)?;
            buf.truncate(n);
            String::from_utf8_lossy(&buf).into_owned()
        };
        // Whole lines only: the last one of the buffer may be cut.
        let complete = match text_head.rfind('\n') {
            Some(end) if text_head.len() == 64 * 1024 => &text_head[..end],
            _ => text_head.as_str(),
        };
        let lines: Vec<&str> = complete
            .lines()
            .map(|l| l.trim_end_matches('\r'))
            .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
            .take(20)
            .collect();
        let Some(first_line) = lines.first().copied() else {
            return Err(format("no data rows".into()));
        };
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        let delimiter = if ext.eq_ignore_ascii_case("tsv") || ext.eq_ignore_ascii_case("tab") {
            Delimiter::Byte(b'\t')
        } else {
            detect_delimiter(&lines).unwrap_or(Delimiter::Byte(b','))
        };
        let decimal_comma = delimiter == Delimiter::Byte(b';');
        let fields: Vec<String> = match delimiter {
            Delimiter::Byte(b) => first_line
                .split(b as char)
                .map(|f| f.trim().trim_matches('"').trim().to_string())
                .collect(),
            Delimiter::Whitespace => first_line.split_whitespace().map(String::from).collect(),
        };
        let has_header = fields
            .iter()
            .any(|f| parse_number(f, decimal_comma).is_none());
        let channels = match (has_header, delimiter) {
            (false, _) => {
                let n = match delimiter {
                    Delimiter::Whitespace => lines
                        .get(1)
                        .map_or(fields.len(), |l| l.split_whitespace().count()),
                    Delimiter::Byte(_) => fields.len(),
                };
                (0..n).map(|i| i.to_string()).collect()
            }
            (true, Delimiter::Whitespace) => {
                let n = lines
                    .get(1)
                    .map_or(fields.len(), |l| l.split_whitespace().count());
                split_whitespace_header(first_line, n).ok_or_else(|| {
                    format(format!(
                        "the header `{first_line}` does not split into the {n} columns of the data rows (separate names containing spaces by two spaces or a tab, or use commas)"
                    ))
                })?
            }
            (true, Delimiter::Byte(_)) => fields,
        };
        Ok(CsvSource {
            path: path.to_path_buf(),
            delimiter,
            has_header,
            channels,
        })
    }

    /// The detected delimiter.
    pub fn delimiter(&self) -> Delimiter {
        self.delimiter
    }

    fn parse_field(&self, c: usize, field: &[u8], line: u64) -> Result<f64, InputError> {
        let text = std::str::from_utf8(field).unwrap_or("");
        parse_number(text, self.delimiter == Delimiter::Byte(b';')).ok_or_else(|| {
            InputError::Parse {
                path: self.path.clone(),
                row: line,
                message: format!(
                    "column `{}`: `{}` is not a number",
                    self.channels[c],
                    String::from_utf8_lossy(field)
                ),
            }
        })
    }

    fn missing(&self, c: usize, line: u64, fields: usize) -> InputError {
        InputError::Parse {
            path: self.path.clone(),
            row: line,
            message: format!(
                "missing column `{}` (row has {fields} fields)",
                self.channels[c]
            ),
        }
    }

    /// Rows of a whitespace-separated file.
    fn for_each_whitespace_row(
        &self,
        wanted: &[usize],
        visit: &mut RowVisitor<'_>,
    ) -> Result<(), InputError> {
        use std::io::BufRead;
        let file = File::open(&self.path).map_err(|source| InputError::Io {
            path: self.path.clone(),
            source,
        })?;
        let reader = BufReader::with_capacity(1 << 20, file);
        let mut values = vec![0.0; wanted.len()];
        let mut header_pending = self.has_header;
        let mut row = 0u64;
        for (number, line) in reader.lines().enumerate() {
            let line = line.map_err(|source| InputError::Io {
                path: self.path.clone(),
                source,
            })?;
            let text = line.trim();
            if text.is_empty() || text.starts_with('#') {
                continue;
            }
            if header_pending {
                header_pending = false;
                continue;
            }
            let line_number = number as u64 + 1;
            let fields: Vec<&str> = text.split_whitespace().collect();
            for (slot, &c) in values.iter_mut().zip(wanted) {
                let field = fields
                    .get(c)
                    .ok_or_else(|| self.missing(c, line_number, fields.len()))?;
                *slot = self.parse_field(c, field.as_bytes(), line_number)?;
            }
            visit(row, &values)?;
            row += 1;
        }
        Ok(())
    }
}

impl SampleSource for CsvSource {
    fn describe(&self) -> String {
        self.path.display().to_string()
    }
    fn row_count_hint(&self) -> Option<u64> {
        // Every field takes at least one character and one delimiter or line end.
        let bytes = std::fs::metadata(&self.path).ok()?.len();
        Some(bytes / (2 * self.channels.len().max(1) as u64))
    }
    fn channels(&self) -> &[String] {
        &self.channels
    }
    fn for_each_row(&self, wanted: &[usize], visit: &mut RowVisitor<'_>) -> Result<(), InputError> {
        let Delimiter::Byte(delimiter) = self.delimiter else {
            return self.for_each_whitespace_row(wanted, visit);
        };
        let file = File::open(&self.path).map_err(|source| InputError::Io {
            path: self.path.clone(),
            source,
        })?;
        let mut reader = csv::ReaderBuilder::new()
            .delimiter(delimiter)
            .has_headers(self.has_header)
            .comment(Some(b'#'))
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(BufReader::with_capacity(1 << 20, file));
        let mut record = csv::ByteRecord::new();
        let mut values = vec![0.0; wanted.len()];
        let mut row = 0u64;
        loop {
            let more = reader
                .read_byte_record(&mut record)
                .map_err(|e| InputError::Parse {
                    path: self.path.clone(),
                    row: row + 1,
                    message: e.to_string(),
                })?;
            if !more {
                break;
            }
            let line = record.position().map(|p| p.line()).unwrap_or(row + 1);
            for (slot, &c) in values.iter_mut().zip(wanted) {
                let field = record
                    .get(c)
                    .ok_or_else(|| self.missing(c, line, record.len()))?;
                *slot = self.parse_field(c, field, line)?;
            }
            visit(row, &values)?;
            row += 1;
        }
        Ok(())
    }
}

/// Parses a number; empty fields and the usual NaN spellings read as NaN so the gap
/// policy (not the parser) decides what to do with them.
/// With `decimal_comma`, `1,5` reads as 1.5.
fn parse_number(text: &str, decimal_comma: bool) -> Option<f64> {
    let t = text.trim();
    if t.is_empty() || t.eq_ignore_ascii_case("nan") || t.eq_ignore_ascii_case("na") {
        return Some(f64::NAN);
    }
    match t.parse::<f64>() {
        Ok(v) => Some(v),
        Err(_) if decimal_comma && t.contains(',') => t.replace(',', ".").parse().ok(),
        Err(_) => None,
    }
}

// --- NumPy .npy --------------------------------------------------------------------------

/// A NumPy `.npy` array of shape (N,) or (N, k), float64 or float32 (promoted), either
/// memory order. Channels are named "0", "1", … by column.
pub struct NpySource {
    path: PathBuf,
    rows: u64,
    columns: usize,
    fortran: bool,
    single: bool,
    /// Byte order of the values (`>` in the dtype, or `=` on a big-endian machine).
    big_endian: bool,
    channels: Vec<String>,
}

impl NpySource {
    pub fn open(path: &Path) -> Result<Self, InputError> {
        let npy = open_npy(path)?;
        let format = |message: String| InputError::Format {
            path: path.to_path_buf(),
            message,
        };
        let shape = npy.shape().to_vec();
        let (rows, columns) = match shape.as_slice() {
            [n] => (*n, 1usize),
            [n, k] => (
                *n,
                usize::try_from(*k).map_err(|_| format("too many columns".into()))?,
            ),
            other => {
                return Err(format(format!(
                    "expected a 1-D or 2-D array, got shape {other:?}"
                )))
            }
        };
        let type_string = npy.dtype().descr();
        let dtype = type_string.trim_matches(|c| c == '\'' || c == '"');
        let single = match dtype {
            "<f8" | ">f8" | "=f8" => false,
            "<f4" | ">f4" | "=f4" => true,
            other => {
                return Err(format(format!(
                    "unsupported dtype {other}: use float64 or float32"
                )))
            }
        };
        let big_endian =
            dtype.starts_with('>') || (dtype.starts_with('=') && cfg!(target_endian = "big"));
        Ok(NpySource {
            path: path.to_path_buf(),
            rows,
            columns,
            fortran: matches!(npy.order(), npyz::Order::Fortran),
            single,
            big_endian,
            channels: (0..columns).map(|i| i.to_string()).collect(),
        })
    }

    /// Bytes per value.
    fn item(&self) -> usize {
        if self.single {
            4
        } else {
            8
        }
    }

    /// Appends to `out` the values at `raw[k·stride ..]`, one per (possibly partial last)
    /// `stride` of `raw`; each holds at least one value.
    fn decode_into(&self, raw: &[u8], stride: usize, out: &mut Vec<f64>) {
        let rows = raw.chunks(stride);
        match (self.single, self.big_endian) {
            (false, false) => out.extend(rows.map(|r| f64::from_le_bytes(bytes8(r)))),
            (false, true) => out.extend(rows.map(|r| f64::from_be_bytes(bytes8(r)))),
            (true, false) => out.extend(rows.map(|r| f64::from(f32::from_le_bytes(bytes4(r))))),
            (true, true) => out.extend(rows.map(|r| f64::from(f32::from_be_bytes(bytes4(r))))),
        }
    }

    fn truncated(&self, row: u64) -> InputError {
        InputError::Parse {
            path: self.path.clone(),
            row,
            message: "file is truncated (fewer values than its header declares)".into(),
        }
    }
}

fn bytes8(row: &[u8]) -> [u8; 8] {
    let mut b = [0u8; 8];
    b.copy_from_slice(&row[..8]);
    b
}

fn bytes4(row: &[u8]) -> [u8; 4] {
    let mut b = [0u8; 4];
    b.copy_from_slice(&row[..4]);
    b
}

/// Byte offset of the data in a .npy file: after the magic `\x93NUMPY`, the version and
/// the header length (2 bytes in version 1, 4 bytes in versions 2 and 3).
fn npy_data_offset(path: &Path) -> Result<u64, InputError> {
    use std::io::Read;
    let mut head = [0u8; 12];
    File::open(path)
        .and_then(|mut f| f.read_exact(&mut head))
        .map_err(|source| InputError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    if &head[..6] != b"\x93NUMPY" {
        return Err(InputError::Format {
            path: path.to_path_buf(),
            message: "not a NumPy .npy file (magic bytes missing)".into(),
        });
    }
    Ok(match head[6] {
        1 => 10 + u64::from(u16::from_le_bytes([head[8], head[9]])),
        _ => 12 + u64::from(u32::from_le_bytes([head[8], head[9], head[10], head[11]])),
    })
}

fn open_npy(path: &Path) -> Result<npyz::NpyFile<BufReader<File>>, InputError> {
    let io = |source| InputError::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = File::open(path).map_err(io)?;
    npyz::NpyFile::new(BufReader::with_capacity(1 << 20, file)).map_err(io)
}

impl SampleSource for NpySource {
    fn describe(&self) -> String {
        self.path.display().to_string()
    }
    fn row_count_hint(&self) -> Option<u64> {
        // The header's row count, but never more than the file can hold.
        let bytes = std::fs::metadata(&self.path).ok()?.len();
        let row_bytes =
            (self.columns.max(1) as u64).saturating_mul(if self.single { 4 } else { 8 });
        Some(self.rows.min(bytes / row_bytes))
    }
    fn channels(&self) -> &[String] {
        &self.channels
    }
    /// Whole blocks of rows from the memory-mapped file (pages populated in one call): a
    /// contiguous column of native float64 (one column, or any column of a Fortran-order
    /// array) is handed over as a slice of the mapping itself, with no copy; other layouts
    /// are decoded column by column per block (no per-value iterator, no per-row callback).
    fn for_each_block(
        &self,
        wanted: &[usize],
        visit: &mut BlockVisitor<'_>,
    ) -> Result<(), InputError> {
        let io = |source| InputError::Io {
            path: self.path.clone(),
            source,
        };
        let data = usize::try_from(npy_data_offset(&self.path)?).unwrap_or(usize::MAX);
        let file = File::open(&self.path).map_err(io)?;
        // SAFETY: the mapping is read-only and private to this call. Another process
        // shortening the file while it is mapped would fault the reads (SIGBUS); writing to
        // it would change the values read, as it would with read(2). Analysing a file that
        // is being rewritten is outside what this reader supports.
        let map = unsafe { memmap2::MmapOptions::new().populate().map(&file) }.map_err(io)?;
        let bytes: &[u8] = map.get(data..).unwrap_or(&[]);
        let item = self.item();
        let native_f64 = !self.single && self.big_endian == cfg!(target_endian = "big");
        let rows = usize::try_from(self.rows).unwrap_or(usize::MAX);
        let mut columns: Vec<Vec<f64>> = vec![Vec::with_capacity(BLOCK_ROWS); wanted.len()];
        let contiguous = self.columns <= 1 || self.fortran;
        // Byte offset of column c's first value, and the distance between rows.
        let (column_start, row_bytes) = if contiguous {
            (rows.saturating_mul(item), item)
        } else {
            (item, item * self.columns)
        };
        let complete_rows = if contiguous {
            // The last wanted column ends the file's useful part.
            let last = wanted.iter().copied().max().unwrap_or(0);
            (bytes
                .len()
                .saturating_sub(last.saturating_mul(column_start))
                / item)
                .min(rows)
        } else {
            (bytes.len() / row_bytes).min(rows)
        };
        let mut row = 0usize;
        while row < rows {
            let n = (rows - row).min(BLOCK_ROWS);
            let complete = complete_rows.saturating_sub(row).min(n);
            if complete > 0 {
                let mut zero_copy: Vec<Option<&[f64]>> = Vec::with_capacity(wanted.len());
                for (column, &c) in columns.iter_mut().zip(wanted) {
                    let first = c * column_start + row * row_bytes;
                    let raw = &bytes[first..first + (complete - 1) * row_bytes + item];
                    if contiguous && native_f64 {
                        // SAFETY: every bit pattern is a valid f64; `align_to` only hands out
                        // the correctly aligned middle part (npy data starts 64-byte aligned).
                        let (head, values, _) = unsafe { raw.align_to::<f64>() };
                        if head.is_empty() && values.len() == complete {
                            zero_copy.push(Some(values));
                            continue;
                        }
                    }
                    column.clear();
                    self.decode_into(raw, row_bytes, column);
                    zero_copy.push(None);
                }
                let slices: Vec<&[f64]> = zero_copy
                    .iter()
                    .zip(&columns)
                    .map(|(z, c)| z.unwrap_or(c.as_slice()))
                    .collect();
                visit(row as u64, &slices)?;
            }
            if complete < n {
                return Err(self.truncated((row + complete) as u64));
            }
            row += n;
        }
        Ok(())
    }
    fn for_each_row(&self, wanted: &[usize], visit: &mut RowVisitor<'_>) -> Result<(), InputError> {
        let io = |source| InputError::Io {
            path: self.path.clone(),
            source,
        };
        let bad = |e: npyz::DTypeError| InputError::Format {
            path: self.path.clone(),
            message: e.to_string(),
        };
        let npy = open_npy(&self.path)?;
        let mut values = vec![0.0; wanted.len()];
        if self.fortran && self.columns > 1 {
            // Column-major: each wanted column is a contiguous run; read them by seeking.
            let mut columns: Vec<Vec<f64>> = Vec::with_capacity(wanted.len());
            for &c in wanted {
                let mut reader = npy_reader(&self.path, self.single)?;
                reader.seek_to(c as u64 * self.rows).map_err(io)?;
                let mut column = Vec::with_capacity(self.rows as usize);
                for _ in 0..self.rows {
                    column.push(reader.next_value().map_err(io)?);
                }
                columns.push(column);
            }
            for r in 0..self.rows as usize {
                for (slot, column) in values.iter_mut().zip(&columns) {
                    *slot = column[r];
                }
                visit(r as u64, &values)?;
            }
            return Ok(());
        }
        let mut row = vec![0.0; self.columns];
        let mut fill = |r: u64, row: &[f64], values: &mut [f64]| -> Result<(), InputError> {
            for (slot, &c) in values.iter_mut().zip(wanted) {
                *slot = row[c];
            }
            visit(r, values)
        };
        if self.single {
            let mut data = npy.data::<f32>().map_err(bad)?;
            for r in 0..self.rows {
                for slot in row.iter_mut() {
                    *slot = f64::from(next_or_truncated(data.next(), &self.path, r)?);
                }
                fill(r, &row, &mut values)?;
            }
        } else {
            let mut data = npy.data::<f64>().map_err(bad)?;
            for r in 0..self.rows {
                for slot in row.iter_mut() {
                    *slot = next_or_truncated(data.next(), &self.path, r)?;
                }
                fill(r, &row, &mut values)?;
            }
        }
        Ok(())
    }
}

fn next_or_truncated<T>(
    item: Option<std::io::Result<T>>,
    path: &Path,
    row: u64,
) -> Result<T, InputError> {
    match item {
        Some(Ok(v)) => Ok(v),
        Some(Err(e)) => Err(InputError::Parse {
            path: path.to_path_buf(),
            row,
            message: format!("read error: {e}"),
        }),
        None => Err(InputError::Parse {
            path: path.to_path_buf(),
            row,
            message: "file is truncated (fewer values than its header declares)".into(),
        }),
    }
}

/// Random-access reader over either float width.
enum AnyNpyReader {
    F64(npyz::NpyReader<f64, BufReader<File>>),
    F32(npyz::NpyReader<f32, BufReader<File>>),
}

impl AnyNpyReader {
    fn seek_to(&mut self, index: u64) -> std::io::Result<()> {
        match self {
            AnyNpyReader::F64(r) => r.seek_to(index),
            AnyNpyReader::F32(r) => r.seek_to(index),
        }
    }
    fn next_value(&mut self) -> std::io::Result<f64> {
        let eof = || std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "file is truncated");
        match self {
            AnyNpyReader::F64(r) => r.next().ok_or_else(eof)?,
            AnyNpyReader::F32(r) => r.next().ok_or_else(eof)?.map(f64::from),
        }
    }
}

fn npy_reader(path: &Path, single: bool) -> Result<AnyNpyReader, InputError> {
    let npy = open_npy(path)?;
    let bad = |e: npyz::DTypeError| InputError::Format {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    Ok(if single {
        AnyNpyReader::F32(npy.data::<f32>().map_err(bad)?)
    } else {
        AnyNpyReader::F64(npy.data::<f64>().map_err(bad)?)
    })
}

/// The first bytes of every HDF5 file (its superblock signature).
const HDF5_SIGNATURE: [u8; 8] = [0x89, b'H', b'D', b'F', b'\r', b'\n', 0x1a, b'\n'];

/// Refuses an HDF5 file, which is no delimited text: sessions are read as directories.
fn refuse_hdf5(path: &Path) -> Result<(), InputError> {
    use std::io::Read;
    let mut head = [0u8; 8];
    let is_hdf5 = File::open(path)
        .and_then(|mut f| f.read_exact(&mut head))
        .is_ok()
        && head == HDF5_SIGNATURE;
    if !is_hdf5 {
        return Ok(());
    }
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
    let message = if crate::store::layout::parse_chunk_file_name(name).is_some() {
        let dir = path.parent().unwrap_or(Path::new("."));
        format!(
            "an HDF5 chunk file of an imulab session; give the session directory instead: \
             imulab allan {}",
            dir.display()
        )
    } else {
        "an HDF5 file that is not an imulab session; `allan` reads imulab session \
         directories, CSV/TSV and .npy files (export the series to one of those)"
            .into()
    };
    Err(InputError::Format {
        path: path.to_path_buf(),
        message,
    })
}

/// Opens a plain file by extension: `.npy` or delimited text (HDF5 files are refused).
pub fn open_file(path: &Path) -> Result<Box<dyn SampleSource>, InputError> {
    refuse_hdf5(path)?;
    let is_npy = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("npy"));
    Ok(if is_npy {
        Box::new(NpySource::open(path)?)
    } else {
        Box::new(CsvSource::open(path)?)
    })
}

// --- One axis as a uniform series --------------------------------------------------------

/// What to do about gaps, NaN/Inf and non-uniform sampling.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum GapPolicy {
    /// Refuse the data, saying where the first problem is.
    #[default]
    Error,
    /// Cut the series at each problem and pool the deviations of the uniform pieces.
    Split,
    /// Fill missing samples and invalid values by linear interpolation; treat jitter as uniform.
    Fill,
    /// Drop invalid values and close gaps as if the samples were contiguous.
    Ignore,
}

/// How the sample interval is known.
#[derive(Debug, Clone, PartialEq)]
pub enum Timing {
    /// Fixed rate in Hz.
    Rate(f64),
    /// A channel holding time stamps, scaled to seconds by `scale` (1 for s, 1e-9 for ns).
    TimeChannel { channel: usize, scale: f64 },
    /// A channel holding host arrival times (a session's `t_mono_ns`), scaled like
    /// `TimeChannel`. Frames of one read share an arrival time and the transport adds latency,
    /// so the intervals are judged on the sample clock [`ArrivalClock`] rebuilds from them.
    ArrivalTimes { channel: usize, scale: f64 },
    /// The sensor's own clock in channel `channel` (a session's `t_sensor`): a time in known
    /// units or a sample counter, unwrapped where it wraps (see [`SensorClock`]). The samples
    /// it misses are counted exactly, even one at a time; `arrival` (host arrival times,
    /// scaled to seconds by `arrival_scale`) gives τ0 for a counter.
    SensorTime {
        channel: usize,
        clock: SensorClock,
        arrival: usize,
        arrival_scale: f64,
    },
}

/// How to read a sensor's own clock channel.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorClock {
    /// Seconds per unit of the channel; `None` for a sample counter (one count per sample,
    /// seconds = count × τ0 with τ0 from the arrival times).
    pub unit_s: Option<f64>,
    /// The channel wraps to 0 after this many units. `None` for a counter whose modulus is
    /// not known: it is taken as the next power of two above the largest value seen.
    pub wrap: Option<f64>,
    /// What the report calls this clock, e.g. "sensor sample counter (t_sensor)".
    pub name: String,
}

impl Timing {
    /// What the report calls the clock that gaps are detected on.
    pub fn clock_name(&self) -> String {
        match self {
            Timing::Rate(hz) => format!("fixed rate {hz} Hz (gaps not detectable)"),
            Timing::TimeChannel { .. } => "time column".into(),
            Timing::ArrivalTimes { .. } => {
                "host arrival times (t_mono_ns; gaps under 50 ms not detectable)".into()
            }
            Timing::SensorTime { clock, .. } => clock.name.clone(),
        }
    }
}

/// Turns a wrapping sensor clock into a steadily increasing one, in seconds.
struct Unwrapper {
    unit_s: f64,
    wrap: Option<f64>,
    last: Option<f64>,
    offset: f64,
    largest: f64,
}

impl Unwrapper {
    fn new(unit_s: f64, wrap: Option<f64>) -> Self {
        Unwrapper {
            unit_s,
            wrap,
            last: None,
            offset: 0.0,
            largest: 0.0,
        }
    }

    /// Seconds of raw clock value `v`. A step back by more than half the modulus is a wrap;
    /// a smaller one is left as it is (the gap check then reports a step back).
    fn seconds(&mut self, v: f64) -> f64 {
        if !v.is_finite() {
            return v;
        }
        if let Some(prev) = self.last {
            if v < prev {
                let modulus = self
                    .wrap
                    .unwrap_or_else(|| (self.largest.max(1.0) + 1.0).log2().ceil().exp2());
                if prev - v > modulus / 2.0 {
                    self.offset += modulus;
                }
            }
        }
        self.largest = self.largest.max(v);
        self.last = Some(v);
        (v + self.offset) * self.unit_s
    }
}

/// Whether samples are rates (frequency) or phase (integrated: clock time error).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum DataKind {
    /// Rate or fractional-frequency samples (gyro rad/s, accel m/s², y).
    #[default]
    Rate,
    /// Phase samples (e.g. clock time error in seconds).
    Phase,
}

/// Data health of one axis, as reported.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Health {
    pub policy: Option<GapPolicy>,
    /// The clock gaps were detected on (see [`Timing::clock_name`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clock: Option<String>,
    pub samples: u64,
    pub duration_s: f64,
    /// Intervals longer than 1.5 τ0.
    pub gaps: u64,
    /// Samples missing in those gaps.
    pub missing_samples: u64,
    /// NaN or infinite values.
    pub invalid_values: u64,
    /// Intervals off the nominal τ0 by more than 10 % (but not gaps), or not increasing.
    pub nonuniform_intervals: u64,
    /// Uniform pieces the series was split into (1 when nothing was wrong).
    pub segments: usize,
    /// First problem found, with its position.
    pub first_problem: Option<String>,
    pub temperature_min: Option<f64>,
    pub temperature_max: Option<f64>,
}

/// One axis, ready for analysis: rate samples in uniform segments.
#[derive(Debug, Clone)]
pub struct AxisSeries {
    pub name: String,
    pub tau0: f64,
    /// Uniform pieces of rate samples (one piece unless the policy is `split`).
    pub segments: Vec<Vec<f64>>,
    /// Temperature per sample, aligned with the concatenated segments, if requested.
    pub temperature: Option<Vec<f32>>,
    pub health: Health,
}

impl AxisSeries {
    /// One axis of uniform `rate` samples every `tau0` seconds, in one segment, with the
    /// health of a clean read (no gaps, no invalid values): how a series built in memory
    /// (a simulation, a benchmark, a test) enters the analysis.
    pub fn one_segment(name: impl Into<String>, tau0: f64, rate: Vec<f64>) -> Self {
        AxisSeries {
            name: name.into(),
            tau0,
            health: Health {
                samples: rate.len() as u64,
                duration_s: rate.len() as f64 * tau0,
                segments: 1,
                ..Health::default()
            },
            segments: vec![rate],
            temperature: None,
        }
    }

    pub fn sample_count(&self) -> usize {
        self.segments.iter().map(Vec::len).sum()
    }
}

/// Fractional deviation of an interval from nominal that still counts as uniform.
const JITTER_TOLERANCE: f64 = 0.1;

/// Reads channel `axis` of `source` as a uniform rate series (see [`read_axes`]).
pub fn read_axis(
    source: &dyn SampleSource,
    axis: usize,
    timing: &Timing,
    policy: GapPolicy,
    data: DataKind,
    temperature: Option<usize>,
) -> Result<AxisSeries, InputError> {
    let mut series = read_axes(source, &[axis], timing, policy, data, temperature)?;
    series.pop().ok_or_else(|| {
        InputError::Channel(format!("{}: no channel index {axis}", source.describe()))
    })
}

/// Reads channels `axes` of `source` as uniform rate series in one pass over the source
/// (so a session is decompressed once for all of them); memory is the sum of the axes.
///
/// `temperature`: optional channel carried along (for thermal analysis). With a time
/// channel, τ0 is the median of the first 10 000 intervals. Each axis has its own gap
/// bookkeeping, since NaN values are per channel.
pub fn read_axes(
    source: &dyn SampleSource,
    axes: &[usize],
    timing: &Timing,
    policy: GapPolicy,
    data: DataKind,
    temperature: Option<usize>,
) -> Result<Vec<AxisSeries>, InputError> {
    let names: Vec<String> = axes
        .iter()
        .map(|&axis| {
            source.channels().get(axis).cloned().ok_or_else(|| {
                InputError::Channel(format!("{}: no channel index {axis}", source.describe()))
            })
        })
        .collect::<Result<_, _>>()?;
    let (tau0, time_channel) = match timing {
        Timing::Rate(hz) => {
            if !(hz.is_finite() && *hz > 0.0) {
                return Err(InputError::Sampling(format!(
                    "sample rate {hz} Hz must be positive"
                )));
            }
            (1.0 / hz, None)
        }
        Timing::TimeChannel { channel, scale } => (
            nominal_interval(source, *channel, *scale)?,
            Some((*channel, *scale)),
        ),
        Timing::ArrivalTimes { channel, scale } => (
            arrival_interval(source, *channel, *scale)?,
            Some((*channel, *scale)),
        ),
        Timing::SensorTime {
            channel,
            clock,
            arrival,
            arrival_scale,
        } => match clock.unit_s {
            Some(unit) => (
                nominal_interval(source, *channel, unit)?,
                Some((*channel, 1.0)),
            ),
            None => (
                arrival_interval(source, *arrival, *arrival_scale)?,
                Some((*channel, 1.0)),
            ),
        },
    };
    let mut clock = matches!(timing, Timing::ArrivalTimes { .. }).then(|| ArrivalClock::new(tau0));
    let mut unwrapper = match timing {
        Timing::SensorTime { clock, .. } => {
            Some(Unwrapper::new(clock.unit_s.unwrap_or(tau0), clock.wrap))
        }
        _ => None,
    };
    let mut wanted = axes.to_vec();
    let time_slot = time_channel.map(|(c, _)| {
        wanted.push(c);
        wanted.len() - 1
    });
    let temp_slot = temperature.map(|t| {
        wanted.push(t);
        wanted.len() - 1
    });
    // Reserve the expected length once (capped, so a lying header cannot demand memory).
    let expected = source
        .row_count_hint()
        .map_or(0, |rows| rows.min(1 << 32) as usize);
    let mut builders: Vec<(SeriesBuilder, Option<Vec<f32>>)> = names
        .iter()
        .map(|name| {
            let mut builder = SeriesBuilder::new(tau0, policy, name, source.describe());
            builder.clock = timing.clock_name();
            // Ignoring a failed reservation is fine: the vector then grows as it goes. One
            // more than the rows: the phase built in place adds a point (no reallocation).
            if builder.current.try_reserve_exact(expected + 1).is_ok() {
                super::memory::advise_huge_pages(&mut builder.current);
            }
            (builder, temperature.map(|_| Vec::new()))
        })
        .collect();
    // Whole blocks per column: the clean stretches (every value finite, every interval
    // within tolerance) are appended in bulk, only blocks with a problem go row by row.
    let mut times: Vec<f64> = Vec::new();
    source.for_each_block(&wanted, &mut |first_row, columns| {
        let time = match (time_slot, time_channel) {
            (Some(slot), Some((_, scale))) => {
                times.clear();
                match (clock.as_mut(), unwrapper.as_mut()) {
                    (Some(clock), _) => {
                        times.extend(columns[slot].iter().map(|t| clock.sample_time(t * scale)))
                    }
                    (None, Some(u)) => times.extend(columns[slot].iter().map(|&t| u.seconds(t))),
                    (None, None) => times.extend(columns[slot].iter().map(|t| t * scale)),
                }
                Some(times.as_slice())
            }
            _ => None,
        };
        let temp = temp_slot.map(|s| columns[s]);
        // The time stamps' own intervals are checked once for all axes; each axis then
        // appends its column on the rayon pool (results taken in axis order, so the first
        // axis with a problem is the one reported, as when they ran one after the other).
        let steady = time.is_none_or(|t| steady_intervals(tau0, t));
        let results: Vec<Result<(), InputError>> = builders
            .par_iter_mut()
            .enumerate()
            .map(|(i, (builder, temps))| {
                builder.push_block(first_row, time, steady, columns[i], temp, temps.as_mut())
            })
            .collect();
        results.into_iter().collect()
    })?;
    builders
        .into_iter()
        .zip(names)
        .map(|((builder, temps), name)| {
            let (segments, mut health) = builder.finish()?;
            health.clock = Some(timing.clock_name());
            if let Some(t) = &temps {
                let finite = t.iter().filter(|v| v.is_finite());
                health.temperature_min = finite.clone().copied().reduce(f32::min).map(f64::from);
                health.temperature_max = finite.copied().reduce(f32::max).map(f64::from);
            }
            let segments = match data {
                DataKind::Rate => segments,
                DataKind::Phase => segments
                    .into_iter()
                    .map(|s| s.windows(2).map(|w| (w[1] - w[0]) / tau0).collect())
                    .collect(),
            };
            Ok(AxisSeries {
                name,
                tau0,
                segments,
                temperature: temps,
                health,
            })
        })
        .collect()
}

/// Median of the first 10 000 time-stamp intervals.
fn nominal_interval(
    source: &dyn SampleSource,
    channel: usize,
    scale: f64,
) -> Result<f64, InputError> {
    let mut intervals = Vec::with_capacity(10_000);
    let mut last: Option<f64> = None;
    let result = source.for_each_row(&[channel], &mut |_, v| {
        let t = v[0] * scale;
        if let Some(prev) = last {
            let dt = t - prev;
            if dt.is_finite() && dt > 0.0 {
                intervals.push(dt);
            }
        }
        last = Some(t);
        if intervals.len() >= 10_000 {
            return Err(InputError::Stopped);
        }
        Ok(())
    });
    match result {
        Ok(()) | Err(InputError::Stopped) => {}
        Err(e) => return Err(e),
    }
    if intervals.is_empty() {
        return Err(InputError::Sampling(format!(
            "{}: the time column has no increasing time stamps",
            source.describe()
        )));
    }
    intervals.sort_by(f64::total_cmp);
    Ok(intervals[intervals.len() / 2])
}

/// τ0 from host arrival times: the median of the mean intervals of windows of 1 000 rows over
/// the first 20 000 rows. Batched arrivals make single intervals useless (many are 0); a window
/// spans many batches, and the median ignores a window holding a gap.
fn arrival_interval(
    source: &dyn SampleSource,
    channel: usize,
    scale: f64,
) -> Result<f64, InputError> {
    const WINDOW: usize = 1_000;
    let mut times = Vec::with_capacity(20 * WINDOW + 1);
    let result = source.for_each_row(&[channel], &mut |_, v| {
        let t = v[0] * scale;
        if t.is_finite() {
            times.push(t);
        }
        if times.len() > 20 * WINDOW {
            return Err(InputError::Stopped);
        }
        Ok(())
    });
    match result {
        Ok(()) | Err(InputError::Stopped) => {}
        Err(e) => return Err(e),
    }
    let window = WINDOW.min(times.len().saturating_sub(1)).max(1);
    let mut means: Vec<f64> = times
        .windows(window + 1)
        .step_by(window)
        .map(|w| (w[window] - w[0]) / window as f64)
        .filter(|dt| *dt > 0.0)
        .collect();
    if means.is_empty() {
        return Err(InputError::Sampling(format!(
            "{}: the arrival times do not increase",
            source.describe()
        )));
    }
    means.sort_by(f64::total_cmp);
    Ok(means[means.len() / 2])
}

/// Host latency an arrival may carry before a pause counts as a gap: a USB serial adapter
/// delivers every 16 ms and the daemon reads in batches; the daemon's own arrival-pause event
/// uses the same 50 ms.
const ARRIVAL_SLACK_S: f64 = 0.05;

/// Rebuilds the sample clock from host arrival times. The clock advances τ0 per sample and
/// follows the lower envelope of the arrivals (a sample cannot arrive before it was taken): it
/// slews down to an earlier arrival by at most 5 % of τ0 per sample and creeps up by 0.1 % of
/// τ0 per sample while arrivals are late, so it follows a sensor clock off nominal by up to
/// 1e-3. An arrival later than the clock by more than τ0/2 + [`ARRIVAL_SLACK_S`] is a gap: the
/// clock jumps by the whole samples missing (counted to within the host latency). A gap
/// shorter than the slack cannot be told from latency by host time alone.
struct ArrivalClock {
    tau0: f64,
    last: Option<f64>,
}

impl ArrivalClock {
    fn new(tau0: f64) -> Self {
        ArrivalClock { tau0, last: None }
    }

    fn sample_time(&mut self, arrival: f64) -> f64 {
        if !arrival.is_finite() {
            return arrival;
        }
        let Some(last) = self.last else {
            self.last = Some(arrival);
            return arrival;
        };
        let predicted = last + self.tau0;
        let late = arrival - predicted;
        let t = if late > 0.5 * self.tau0 + ARRIVAL_SLACK_S {
            predicted + (late / self.tau0).round() * self.tau0
        } else if late < 0.0 {
            predicted + late.max(-0.05 * self.tau0)
        } else {
            predicted + late.min(1e-3 * self.tau0)
        };
        self.last = Some(t);
        t
    }
}

/// Whether an interval `dt` counts as one nominal sample step: the same tests as
/// `SeriesBuilder::push`, so the bulk and the row-by-row paths classify every interval alike.
#[inline(always)]
fn steady_interval(tau0: f64, dt: f64) -> bool {
    let ratio = dt / tau0;
    ratio < 1.5 && dt > 0.0 && (ratio - 1.0).abs() <= JITTER_TOLERANCE
}

/// Whether the time stamps `t` are all finite and every interval between them is within the
/// jitter tolerance of τ0 (no gap, no step back). Folds without early exit, so that the
/// divisions and tests vectorise.
fn steady_intervals(tau0: f64, t: &[f64]) -> bool {
    t.iter().fold(true, |ok, v| ok & v.is_finite())
        && t.windows(2)
            .fold(true, |ok, w| ok & steady_interval(tau0, w[1] - w[0]))
}

/// Streams samples into uniform segments under a gap policy.
struct SeriesBuilder {
    tau0: f64,
    policy: GapPolicy,
    label: String,
    segments: Vec<Vec<f64>>,
    current: Vec<f64>,
    last_time: Option<f64>,
    first_time: Option<f64>,
    /// Number of trailing invalid values waiting for the next valid one (fill policy).
    pending_invalid: usize,
    health: Health,
    /// The clock the time stamps come from, for messages.
    clock: String,
}

impl SeriesBuilder {
    fn new(tau0: f64, policy: GapPolicy, axis: &str, source: String) -> Self {
        SeriesBuilder {
            tau0,
            policy,
            label: format!("{source}: channel `{axis}`"),
            segments: Vec::new(),
            current: Vec::new(),
            last_time: None,
            first_time: None,
            pending_invalid: 0,
            health: Health {
                policy: Some(policy),
                ..Health::default()
            },
            clock: String::new(),
        }
    }

    fn problem(&mut self, message: String) -> Result<(), InputError> {
        if self.health.first_problem.is_none() {
            self.health.first_problem = Some(message.clone());
        }
        if self.policy == GapPolicy::Error {
            return Err(InputError::Sampling(format!(
                "{}: {message} (choose --gaps split|fill|ignore to proceed)",
                self.label
            )));
        }
        Ok(())
    }

    fn cut(&mut self) {
        if !self.current.is_empty() {
            self.segments.push(std::mem::take(&mut self.current));
        }
    }

    fn push(
        &mut self,
        row: u64,
        time: Option<f64>,
        value: f64,
        temperature: Option<f64>,
        temps: Option<&mut Vec<f32>>,
    ) -> Result<(), InputError> {
        self.health.samples += 1;
        if let Some(t) = time {
            if !t.is_finite() {
                self.problem(format!("sample {row}: time stamp is {t}"))?;
                return Ok(());
            }
            self.first_time.get_or_insert(t);
            if let Some(prev) = self.last_time {
                let dt = t - prev;
                let ratio = dt / self.tau0;
                if ratio >= 1.5 {
                    let missing = (ratio.round() as u64).saturating_sub(1);
                    self.health.gaps += 1;
                    self.health.missing_samples += missing;
                    self.problem(format!(
                        "sample {row}: gap of {dt:.6} s at t = {t:.6} s ({missing} samples missing at τ0 = {:.6} s, found on the {})",
                        self.tau0, self.clock
                    ))?;
                    match self.policy {
                        GapPolicy::Split => self.cut(),
                        GapPolicy::Fill => {
                            if let Some(&before) = self.current.last() {
                                if value.is_finite() {
                                    for k in 1..=missing {
                                        let f = k as f64 / (missing + 1) as f64;
                                        self.current.push(before + f * (value - before));
                                    }
                                } else {
                                    self.pending_invalid += missing as usize;
                                }
                            }
                        }
                        _ => {}
                    }
                } else if dt <= 0.0 {
                    self.health.nonuniform_intervals += 1;
                    self.problem(format!("sample {row}: time stamp {t:.6} s does not increase (previous {prev:.6} s)"))?;
                    if self.policy == GapPolicy::Split {
                        self.cut();
                    }
                } else if (ratio - 1.0).abs() > JITTER_TOLERANCE {
                    self.health.nonuniform_intervals += 1;
                    self.problem(format!(
                        "sample {row}: interval {dt:.6} s at t = {t:.6} s is off the nominal {:.6} s (non-uniform sampling)",
                        self.tau0
                    ))?;
                    if self.policy == GapPolicy::Split {
                        self.cut();
                    }
                }
            }
            self.last_time = Some(t);
            self.health.duration_s = t - self.first_time.unwrap_or(t);
        } else {
            self.health.duration_s = self.health.samples as f64 * self.tau0;
        }
        if !value.is_finite() {
            self.health.invalid_values += 1;
            self.problem(format!("sample {row}: value is {value}"))?;
            match self.policy {
                GapPolicy::Split => self.cut(),
                GapPolicy::Fill => self.pending_invalid += 1,
                _ => {}
            }
            return Ok(());
        }
        if self.pending_invalid > 0 {
            // Leading invalid values (nothing before them) are dropped.
            if let Some(before) = self.current.last().copied() {
                let n = self.pending_invalid;
                for k in 1..=n {
                    let f = k as f64 / (n + 1) as f64;
                    self.current.push(before + f * (value - before));
                }
            }
            self.pending_invalid = 0;
        }
        self.current.push(value);
        if let (Some(temps), Some(temp)) = (temps, temperature) {
            temps.push(temp as f32);
        }
        Ok(())
    }

    /// Appends a block of rows starting at `first_row`. When every value is finite and
    /// every interval (including the one from the previous block) is within the jitter
    /// tolerance, the block is appended in bulk, with exactly the bookkeeping [`Self::push`]
    /// would do; otherwise it goes through `push` row by row.
    ///
    /// `steady`: whether `times` (when given) are all finite with every interval between
    /// them within the tolerance ([`steady_intervals`], computed once for all axes).
    fn push_block(
        &mut self,
        first_row: u64,
        times: Option<&[f64]>,
        steady: bool,
        values: &[f64],
        temperatures: Option<&[f64]>,
        mut temps: Option<&mut Vec<f32>>,
    ) -> Result<(), InputError> {
        // Folds without early exit, so that the checks vectorise.
        let clean = self.pending_invalid == 0
            && values.iter().fold(true, |ok, v| ok & v.is_finite())
            && times.is_none_or(|t| steady && self.continues(t));
        if !clean {
            for (k, &value) in values.iter().enumerate() {
                self.push(
                    first_row + k as u64,
                    times.map(|t| t[k]),
                    value,
                    temperatures.map(|t| t[k]),
                    temps.as_deref_mut(),
                )?;
            }
            return Ok(());
        }
        if values.is_empty() {
            return Ok(());
        }
        self.health.samples += values.len() as u64;
        match times {
            Some(t) => {
                let first = *self.first_time.get_or_insert(t[0]);
                let last = t[t.len() - 1];
                self.last_time = Some(last);
                self.health.duration_s = last - first;
            }
            None => self.health.duration_s = self.health.samples as f64 * self.tau0,
        }
        self.current.extend_from_slice(values);
        if let (Some(temps), Some(temperatures)) = (temps, temperatures) {
            temps.extend(temperatures.iter().map(|&t| t as f32));
        }
        Ok(())
    }

    /// Whether the interval from the last time stamp seen to the first of `t` is within the
    /// jitter tolerance of τ0 (the rest of `t` is [`steady_intervals`]' business).
    fn continues(&self, t: &[f64]) -> bool {
        self.last_time.is_none_or(|prev| {
            t.first()
                .is_none_or(|&f| steady_interval(self.tau0, f - prev))
        })
    }

    fn finish(mut self) -> Result<(Vec<Vec<f64>>, Health), InputError> {
        self.cut();
        self.health.segments = self.segments.len();
        if self.segments.is_empty() {
            return Err(InputError::Sampling(format!(
                "{}: no valid samples",
                self.label
            )));
        }
        Ok((self.segments, self.health))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn write_file(dir: &Path, name: &str, text: &str) -> PathBuf {
        let path = dir.join(name);
        std::fs::File::create(&path)
            .unwrap()
            .write_all(text.as_bytes())
            .unwrap();
        path
    }

    /// Arrival times of a 150 Hz sensor whose clock runs 5e-4 slow, read in batches of 5
    /// frames (27 ms) with 0-20 ms more latency, with 20 samples lost after sample 6 000.
    fn batched_arrivals(n: usize) -> String {
        let period = (1.0 + 5e-4) / 150.0;
        let mut csv = String::from("t,g\n");
        for i in 0..n {
            // Sample i is the j-th the sensor took; a batch of 5 is delivered when its last
            // frame is taken, plus a varying latency.
            let j = if i < 6_000 { i } else { i + 20 };
            let latency = 0.02 * ((j / 5 * 7919) % 100) as f64 / 100.0;
            let arrival = (j / 5 * 5 + 4) as f64 * period + latency;
            csv.push_str(&format!("{arrival:.9},{}\n", i as f64));
        }
        csv
    }

    #[test]
    fn arrival_times_in_batches_give_one_gap_and_no_false_alarm() {
        let dir = tempfile::tempdir().unwrap();
        let n = 30_000;
        let csv = batched_arrivals(n);
        let path = write_file(dir.path(), "a.csv", &csv);
        let src = CsvSource::open(&path).unwrap();
        let (t, g) = (
            src.channel_index("t").unwrap(),
            src.channel_index("g").unwrap(),
        );
        let arrival = Timing::ArrivalTimes {
            channel: t,
            scale: 1.0,
        };
        let s = read_axis(&src, g, &arrival, GapPolicy::Split, DataKind::Rate, None).unwrap();
        assert!((s.tau0 * 150.0 - 1.0).abs() < 2e-3, "τ0 {}", s.tau0);
        assert_eq!(s.health.gaps, 1, "{:?}", s.health);
        // Counted to within the host latency (47 ms, 7 samples at most).
        assert!(
            (20..=27).contains(&s.health.missing_samples),
            "{:?}",
            s.health
        );
        assert_eq!(s.health.nonuniform_intervals, 0, "{:?}", s.health);
        assert_eq!(
            s.segments.iter().map(Vec::len).collect::<Vec<_>>(),
            vec![6_000, n - 6_000]
        );
        // The same stamps read as exact sample times fail at once.
        let exact = Timing::TimeChannel {
            channel: t,
            scale: 1.0,
        };
        let err = read_axis(&src, g, &exact, GapPolicy::Error, DataKind::Rate, None).unwrap_err();
        assert!(err.to_string().contains("time stamp"), "{err}");
    }

    #[test]
    fn sensor_clock_unwraps_known_and_guessed_moduli() {
        // Known modulus 1000, one count per 0.01 s; a small step back is not a wrap.
        let mut u = Unwrapper::new(0.01, Some(1000.0));
        let got: Vec<f64> = [998.0, 999.0, 1.0, 2.0, 1.0]
            .iter()
            .map(|&v| u.seconds(v))
            .collect();
        assert_eq!(got, [9.98, 9.99, 10.01, 10.02, 10.01]);
        // Unknown modulus: the next power of two above the largest value seen (65 536).
        let mut u = Unwrapper::new(1.0, None);
        let got: Vec<f64> = [65_534.0, 65_535.0, 0.0, 3.0]
            .iter()
            .map(|&v| u.seconds(v))
            .collect();
        assert_eq!(got, [65_534.0, 65_535.0, 65_536.0, 65_539.0]);
        // Seconds wrapping (Xsens SampleTimeFine), a sample lost across the wrap.
        let wrap = 4_294_967_296.0 / 10_000.0;
        let mut u = Unwrapper::new(1.0, Some(wrap));
        let a = u.seconds(wrap - 0.01);
        let b = u.seconds(0.0033);
        assert!((b - a - 0.0133).abs() < 1e-9, "{}", b - a);
    }

    #[test]
    fn csv_with_header_and_time_column() {
        let dir = tempfile::tempdir().unwrap();
        let path = write_file(
            dir.path(),
            "a.csv",
            "# comment\nt,gx,gy\n0,1,2\n0.1,3,4\n0.2,5,6\n",
        );
        let src = CsvSource::open(&path).unwrap();
        assert_eq!(src.channels(), &["t", "gx", "gy"]);
        let gy = src.channel_index("gy").unwrap();
        let t = src.channel_index("t").unwrap();
        let s = read_axis(
            &src,
            gy,
            &Timing::TimeChannel {
                channel: t,
                scale: 1.0,
            },
            GapPolicy::Error,
            DataKind::Rate,
            None,
        )
        .unwrap();
        assert!((s.tau0 - 0.1).abs() < 1e-12);
        assert_eq!(s.segments, vec![vec![2.0, 4.0, 6.0]]);
        assert!(src
            .channel_index("gz")
            .unwrap_err()
            .to_string()
            .contains("no channel `gz`"));
    }

    #[test]
    fn gaps_are_errors_by_default_and_handled_by_policy() {
        let dir = tempfile::tempdir().unwrap();
        let path = write_file(dir.path(), "g.tsv", "0\t1\n1\t2\n4\t5\n5\tnan\n6\t7\n");
        let src = CsvSource::open(&path).unwrap();
        let timing = Timing::TimeChannel {
            channel: 0,
            scale: 1.0,
        };
        let err = read_axis(&src, 1, &timing, GapPolicy::Error, DataKind::Rate, None).unwrap_err();
        assert!(
            err.to_string().contains("sample 2: gap of 3.000000 s"),
            "{err}"
        );
        let split = read_axis(&src, 1, &timing, GapPolicy::Split, DataKind::Rate, None).unwrap();
        assert_eq!(split.segments, vec![vec![1.0, 2.0], vec![5.0], vec![7.0]]);
        assert_eq!(split.health.gaps, 1);
        assert_eq!(split.health.missing_samples, 2);
        assert_eq!(split.health.invalid_values, 1);
        let fill = read_axis(&src, 1, &timing, GapPolicy::Fill, DataKind::Rate, None).unwrap();
        assert_eq!(fill.segments, vec![vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]]);
        let ignore = read_axis(&src, 1, &timing, GapPolicy::Ignore, DataKind::Rate, None).unwrap();
        assert_eq!(ignore.segments, vec![vec![1.0, 2.0, 5.0, 7.0]]);
    }

    fn write_npy<T: npyz::AutoSerialize + Copy>(
        path: &Path,
        shape: &[u64],
        order: npyz::Order,
        data: &[T],
    ) {
        use npyz::WriterBuilder;
        let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(shape)
            .order(order)
            .writer(file)
            .begin_nd()
            .unwrap();
        w.extend(data.iter().copied()).unwrap();
        w.finish().unwrap();
    }

    #[test]
    fn npy_columns_in_both_orders_and_f32_promoted() {
        let dir = tempfile::tempdir().unwrap();
        let c_path = dir.path().join("c.npy");
        write_npy(
            &c_path,
            &[3, 2],
            npyz::Order::C,
            &[1.0f64, 10.0, 2.0, 20.0, 3.0, 30.0],
        );
        let f_path = dir.path().join("f.npy");
        write_npy(
            &f_path,
            &[3, 2],
            npyz::Order::Fortran,
            &[1.0f32, 2.0, 3.0, 10.0, 20.0, 30.0],
        );
        for path in [&c_path, &f_path] {
            let src = open_file(path).unwrap();
            assert_eq!(src.channels().len(), 2);
            let s = read_axis(
                src.as_ref(),
                1,
                &Timing::Rate(100.0),
                GapPolicy::Error,
                DataKind::Rate,
                None,
            )
            .unwrap();
            assert_eq!(
                s.segments,
                vec![vec![10.0, 20.0, 30.0]],
                "{}",
                path.display()
            );
        }
    }

    #[test]
    fn truncated_npy_is_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.npy");
        write_npy(&path, &[100], npyz::Order::C, &vec![1.0f64; 100]);
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 80]).unwrap();
        let src = open_file(&path).unwrap();
        let err = read_axis(
            src.as_ref(),
            0,
            &Timing::Rate(1.0),
            GapPolicy::Error,
            DataKind::Rate,
            None,
        )
        .unwrap_err();
        assert!(err.to_string().contains("row 90"), "{err}");
    }

    #[test]
    fn garbage_cell_names_row_and_column() {
        let dir = tempfile::tempdir().unwrap();
        let path = write_file(dir.path(), "b.csv", "x,y\n1,2\n3,oops\n");
        let src = CsvSource::open(&path).unwrap();
        let err = read_axis(
            &src,
            1,
            &Timing::Rate(10.0),
            GapPolicy::Error,
            DataKind::Rate,
            None,
        )
        .unwrap_err();
        let text = err.to_string();
        assert!(
            text.contains("row 3") && text.contains("`y`") && text.contains("oops"),
            "{text}"
        );
    }
}
