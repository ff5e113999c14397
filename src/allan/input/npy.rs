//! NumPy `.npy` arrays (one column per channel, or one channel) as a [`SampleSource`].
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use super::{BlockVisitor, InputError, RowVisitor, SampleSource, BLOCK_ROWS};

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
