//! Input layer: a [`SampleSource`] streams rows of named channels; [`read_axis`] pulls one
//! channel out of it as a uniformly sampled rate series, checking for gaps, NaN/Inf and
//! non-uniform sampling under an explicit [`GapPolicy`]. Only one axis (plus an optional
//! temperature channel) is held in memory at a time.
//!
//! - `csv`: delimited text; `npy`: NumPy arrays (sessions and bags have their own adapters,
//!   `session_source` and `bag_source`);
//! - `series`: timing (sensor clock, arrival times), gaps, health and the series builder.

use std::fs::File;
use std::path::{Path, PathBuf};

mod csv;
mod npy;
mod series;

pub use csv::{CsvSource, Delimiter};
pub use npy::NpySource;
pub use series::*;

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
    fn channel_unit(&self, _channel: usize) -> Option<crate::units::RateUnit> {
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
    let message = if imulab_store::layout::parse_chunk_file_name(name).is_some() {
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
