//! Delimited text (CSV, TSV, semicolon- or whitespace-separated) as a [`SampleSource`].
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use super::{InputError, RowVisitor, SampleSource};

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

    /// Parses field `field` of column `c`; `first` is the column's first integer beyond
    /// f64's exact range, if any ([`relative_large_integer`]).
    fn parse_field(
        &self,
        c: usize,
        field: &[u8],
        line: u64,
        first: &mut Option<i64>,
    ) -> Result<f64, InputError> {
        let text = std::str::from_utf8(field).unwrap_or("");
        if let Some(v) = relative_large_integer(text.trim(), first) {
            return Ok(v);
        }
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
        let mut firsts = vec![None; wanted.len()];
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
            for ((slot, first), &c) in values.iter_mut().zip(&mut firsts).zip(wanted) {
                let field = fields
                    .get(c)
                    .ok_or_else(|| self.missing(c, line_number, fields.len()))?;
                *slot = self.parse_field(c, field.as_bytes(), line_number, first)?;
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
        let mut firsts = vec![None; wanted.len()];
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
            for ((slot, first), &c) in values.iter_mut().zip(&mut firsts).zip(wanted) {
                let field = record
                    .get(c)
                    .ok_or_else(|| self.missing(c, line, record.len()))?;
                *slot = self.parse_field(c, field, line, first)?;
            }
            visit(row, &values)?;
            row += 1;
        }
        Ok(())
    }
}

/// An integer beyond 2⁵³ (epoch nanoseconds are ~1.7·10¹⁸) has no exact f64: read as one,
/// 10 ms steps come out as 9.999872 or 10.000128 ms. Such a column is read relative to its
/// first integer (`first`, set on the first), so its intervals stay exact; None for any
/// other text.
fn relative_large_integer(text: &str, first: &mut Option<i64>) -> Option<f64> {
    const EXACT: i64 = 1 << 53;
    let v: i64 = text.parse().ok()?;
    if first.is_none() && v.abs() <= EXACT {
        return None;
    }
    let base = *first.get_or_insert(v);
    Some(v.checked_sub(base)? as f64)
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
