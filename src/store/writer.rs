//! [`SessionWriter`]: appends rows to the current chunk file of a session, flushes on chunk
//! boundaries every flush interval of *data* time, rotates files by data time or size, and
//! finalises each file (flush, fsync, rename from `*.partial`, fsync the directory).
//!
//! Flushing and rotation happen inside the `append_*` calls, driven by the rows' `t_mono_ns`
//! (so a simulator writing 6 h of data in seconds rotates every 10 min of *data*). A live
//! writer whose devices go quiet should also call [`SessionWriter::maybe_flush_and_rotate`]
//! from a timer with the current monotonic time, so buffered rows still reach the disk and a
//! stalled device's incomplete chunk reaches the HDF5 file (appends write whole chunks only).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use hdf5::{Dataset, Group};

use super::chunkio::ChunkEncoder;
use super::columns::{
    create_column, put_1d, put_f64_attr, put_str_attr, put_u32_attr, ChunkSink, Column, EventRow,
    RawIndexRow, Row, EVENT_COLUMNS, FILL_T_MONO, RAW_BYTES, RAW_INDEX_COLUMNS,
};
use super::journal::{self, Journal};
use super::layout::{self, ATTR_AXIS_FRAME, ATTR_SCHEMA_VERSION};
use super::manifest::{fsync_dir, try_writer_lock, DeviceInfo, DeviceKind, Manifest};
use super::records::{
    EventKind, EventRecord, GnssRecord, ImuRecord, TruthImuRecord, TruthNavRecord,
};
use super::{StoreError, SCHEMA_VERSION};

/// How the writer chunks, compresses, flushes and rotates.
#[derive(Debug, Clone, PartialEq)]
pub struct WriterOptions {
    /// Start a new chunk file after this much data time (default 10 min).
    pub rotate_after: Duration,
    /// ... or once the current file reaches this many bytes (default 512 MiB).
    pub rotate_bytes: u64,
    /// Rows older than this (in data time) are always on disk: the most a crash can lose
    /// (default 1 s). Rows are appended to the write-ahead journal this often.
    pub flush_interval: Duration,
    /// Sets the HDF5 chunk size: rows per chunk = rate × this interval (default 10 s). When
    /// it is longer than `flush_interval`, rows wait in the journal until their chunk is
    /// complete, so a live `*.partial` file is up to this much behind (see `journal`). When
    /// it is not, the journal is off and every flush writes chunks of one flush interval
    /// (the layout before the journal; kept for comparison: docs/bench/store.md).
    pub chunk_interval: Duration,
    /// Deflate level 0..=9 (0 = no shuffle/deflate filters at all). Default 1: on IMU noise
    /// level 4 saves about 3.5 % of space for about 85 % more CPU (docs/bench/store.md).
    pub deflate_level: u8,
    /// Create `/raw/<device>` for every device so undecoded bytes can be kept (default off).
    pub raw_journal: bool,
    /// Override rows per HDF5 chunk for every device (default: rate_hz × chunk_interval).
    pub rows_per_chunk: Option<usize>,
    /// fsync the file after every periodic flush (protects against power loss, not only
    /// against a killed process). Default on. Finalised files are always fsynced.
    pub fsync_on_flush: bool,
}

impl Default for WriterOptions {
    fn default() -> Self {
        WriterOptions {
            rotate_after: Duration::from_secs(600),
            rotate_bytes: 512 << 20,
            flush_interval: Duration::from_secs(1),
            chunk_interval: Duration::from_secs(10),
            deflate_level: 1,
            raw_journal: false,
            rows_per_chunk: None,
            fsync_on_flush: true,
        }
    }
}

/// Chunks a table's datasets are grown by beyond the rows written, whenever a write would
/// pass their extent. Growing a dataset (`H5Dset_extent`) rewrites its object header at the
/// next flush; doing it once per 64 chunks instead of for every chunk saved ~1/4 of the
/// writes of each 1 s flush (measured, docs/bench/store.md). The rows past the written ones
/// are never allocated (no disk space) and read as the fill value (`t_mono_ns` = -2^63), which
/// readers already treat as "not yet written" in a live file; `finish` and `recover` cut the
/// datasets back to the rows written.
const GROW_AHEAD_CHUNKS: usize = 64;

/// Largest chunk of a table's widest column, in bytes. Chunks are one chunk interval of rows
/// up to this size, so a fast device (e.g. 10 kHz) does not keep seconds of rows in memory
/// and in the journal before they reach the HDF5 file (closing on a nearly full disk needs
/// room for them; tests/daemon/disk.rs), and readers decompress chunks of a sensible size.
/// 64 KiB is 2048 rows of an N×4 f64 column, more than 10 s at rates up to 200 Hz.
const MAX_CHUNK_BYTES: usize = 64 << 10;

/// Bytes of rows in complete chunks (and of raw reads) that may wait in memory for the data
/// time of a flush interval to pass. Rows stamped faster than they are timed (a replay at
/// `pace = "fast"` hands over minutes of data in a fraction of a second of arrival time)
/// would otherwise all wait until the file is closed and reach the disk at once, past any
/// free-space check of the caller's (tests/daemon/disk.rs); past this they are journaled
/// and written at the next append, so what a file takes grows with what was appended.
const MAX_WAITING_BYTES: usize = 1 << 20;

/// One table being appended: its datasets, chunk size and encoder, rows in the HDF5 file,
/// rows the datasets extend to, rows buffered (not yet in the HDF5 file) and how many of
/// those are already in the journal.
struct Table<R> {
    /// Table id in the journal: the group path without the leading `/`.
    id: String,
    ds: Vec<Dataset>,
    sink: ChunkSink,
    written: usize,
    extent: usize,
    buf: Vec<R>,
    journaled: usize,
}

impl<R: Row> Table<R> {
    fn create(
        group: &Group,
        chunk_rows: usize,
        deflate: u8,
        axis_frame: &str,
    ) -> hdf5::Result<Self> {
        let widest = R::COLUMNS
            .iter()
            .map(|c| 8 * c.width.max(1))
            .max()
            .unwrap_or(8);
        let chunk_rows = chunk_rows.clamp(1, (MAX_CHUNK_BYTES / widest).max(1));
        let ds = create_columns(group, R::COLUMNS, chunk_rows, deflate, axis_frame)?;
        Ok(Table {
            id: group.name().trim_start_matches('/').to_string(),
            ds,
            sink: ChunkSink {
                chunk_rows,
                enc: ChunkEncoder::new(deflate),
            },
            written: 0,
            extent: 0,
            buf: Vec::new(),
            journaled: 0,
        })
    }

    /// Time of the oldest buffered row not yet in the journal.
    fn oldest_unjournaled(&self) -> Option<i64> {
        self.buf.get(self.journaled).map(R::t_mono_ns)
    }

    /// Appends a journal record of the buffered rows not yet in the journal to `out`
    /// (`scratch` holds the encoded rows). With `out` = `None` only marks them journaled.
    fn journal_new(&mut self, out: Option<&mut Vec<u8>>, scratch: &mut Vec<u8>) {
        if let Some(out) = out {
            journal_rows(
                &self.id,
                self.written + self.journaled,
                &self.buf[self.journaled..],
                out,
                scratch,
            );
        }
        self.journaled = self.buf.len();
    }

    /// Appends a journal record of every buffered row (for a fresh journal) to `out`.
    fn journal_all(&self, out: &mut Vec<u8>, scratch: &mut Vec<u8>) {
        journal_rows(
            &self.id,
            self.written,
            &self.buf[..self.journaled],
            out,
            scratch,
        );
    }

    /// Sets every column's row count to `rows`.
    fn resize_all(&self, rows: usize) -> hdf5::Result<()> {
        for (ds, c) in self.ds.iter().zip(R::COLUMNS) {
            if c.width == 0 {
                ds.resize(rows)?;
            } else {
                ds.resize((rows, c.width))?;
            }
        }
        Ok(())
    }

    /// Makes the datasets extend to at least `rows`, growing them well ahead.
    fn reserve(&mut self, rows: usize) -> hdf5::Result<()> {
        if rows <= self.extent {
            return Ok(());
        }
        let c = self.sink.chunk_rows;
        let grown = rows.div_ceil(c).saturating_add(GROW_AHEAD_CHUNKS) * c;
        self.resize_all(grown)?;
        self.extent = grown;
        Ok(())
    }

    /// Cuts the datasets back to the rows written (before the file is closed).
    fn trim(&mut self) -> hdf5::Result<()> {
        if self.extent != self.written {
            self.resize_all(self.written)?;
            self.extent = self.written;
        }
        Ok(())
    }

    /// Buffered rows that end on a chunk boundary: the rest of the chunk being filled, then
    /// whole chunks (0 when the chunk being filled is not complete yet).
    fn complete_rows(&self) -> usize {
        let chunk_rows = self.sink.chunk_rows;
        let to_boundary = chunk_rows - self.written % chunk_rows;
        if self.buf.len() < to_boundary {
            return 0;
        }
        to_boundary + (self.buf.len() - to_boundary) / chunk_rows * chunk_rows
    }

    /// Bytes of the buffered rows in complete chunks.
    fn complete_bytes(&self) -> usize {
        self.complete_rows() * std::mem::size_of::<R>()
    }

    /// Whether the incomplete chunk (the rows past the complete chunks) is due to be written
    /// before the file is closed: see [`Early`].
    fn incomplete_due(&self, e: &Early) -> bool {
        let Some(oldest) = self.buf.get(self.complete_rows()).map(R::t_mono_ns) else {
            return false;
        };
        e.due(oldest, self.buf.last().map_or(oldest, R::t_mono_ns))
    }

    /// Writes buffered rows so that writes end on chunk boundaries: everything up to the last
    /// complete chunk, and the incomplete rest too when `incomplete`. Returns the time of the
    /// oldest row written, if any.
    fn write_aligned(&mut self, incomplete: bool) -> hdf5::Result<Option<i64>> {
        let n = if incomplete {
            self.buf.len()
        } else {
            self.complete_rows()
        };
        if n == 0 {
            return Ok(None);
        }
        let oldest = self.buf[0].t_mono_ns();
        self.reserve(self.written + n)?;
        R::write(&self.buf[..n], &self.ds, self.written, &mut self.sink)?;
        self.written += n;
        self.buf.drain(..n);
        self.journaled = self.journaled.saturating_sub(n);
        Ok(Some(oldest))
    }
}

/// When a table's incomplete chunk is written before its file is closed, at data time `now`:
/// once its oldest row is `age_ns` old and the table has had no new row for `silent_ns` (a
/// stalled device), or once that row is `slow_age_ns` old (a device slower than its nominal
/// rate). With the journal these are a chunk interval, a flush interval and two chunk
/// intervals: a device streaming at about its rate fills its chunk by itself, and a chunk
/// written half and then again whole leaves its first copy as dead space in the file (a
/// reader delayed for a moment, or a device 1 % slow, made that of nearly every chunk).
/// Without the journal a row must not wait longer than a flush interval: all three are that.
#[derive(Debug, Clone, Copy)]
struct Early {
    now: i64,
    age_ns: i64,
    silent_ns: i64,
    slow_age_ns: i64,
}

impl Early {
    fn new(now: i64, flush_ns: i64, chunk_ns: i64) -> Self {
        if chunk_ns > flush_ns {
            Early {
                now,
                age_ns: chunk_ns,
                silent_ns: flush_ns,
                slow_age_ns: chunk_ns.saturating_mul(2),
            }
        } else {
            Early {
                now,
                age_ns: flush_ns,
                silent_ns: 0,
                slow_age_ns: flush_ns,
            }
        }
    }

    /// For an incomplete chunk whose rows span `oldest..=newest`.
    fn due(&self, oldest: i64, newest: i64) -> bool {
        let age = self.now.saturating_sub(oldest);
        let silent = self.now.saturating_sub(newest);
        age >= self.slow_age_ns || (age >= self.age_ns && silent >= self.silent_ns)
    }
}

/// Appends one journal record holding `rows`, the first of which is row `first` of table
/// `id`, to `out`.
fn journal_rows<R: Row>(
    id: &str,
    first: usize,
    rows: &[R],
    out: &mut Vec<u8>,
    scratch: &mut Vec<u8>,
) {
    if rows.is_empty() {
        return;
    }
    scratch.clear();
    for r in rows {
        r.encode(scratch);
    }
    // A table never holds 2^32 rows between two journal writes (one flush interval).
    let count = u32::try_from(rows.len()).unwrap_or(u32::MAX);
    journal::put_record(out, id, first as u64, count, scratch);
}

fn create_columns(
    group: &Group,
    cols: &[Column],
    chunk_rows: usize,
    deflate: u8,
    axis_frame: &str,
) -> hdf5::Result<Vec<Dataset>> {
    cols.iter()
        .map(|c| {
            let ds = create_column(group, c, chunk_rows, deflate)?;
            put_str_attr(&ds, ATTR_AXIS_FRAME, axis_frame)?;
            Ok(ds)
        })
        .collect()
}

/// `/raw/<device>`: the bytes dataset plus its (t_mono_ns, offset, len) index.
struct RawTable {
    index: Table<RawIndexRow>,
    bytes: Dataset,
    bytes_written: usize,
    bytes_buf: Vec<u8>,
    /// Bytes of `bytes_buf` already in the journal.
    bytes_journaled: usize,
}

impl RawTable {
    fn write_all(&mut self) -> hdf5::Result<Option<i64>> {
        if self.index.buf.is_empty() {
            return Ok(None);
        }
        put_1d(&self.bytes, self.bytes_written, &self.bytes_buf)?;
        self.bytes_written += self.bytes_buf.len();
        self.bytes_buf.clear();
        self.bytes_journaled = 0;
        self.index.write_aligned(true)
    }

    /// Journal id of the bytes: the index's id and `/bytes`; its "rows" are bytes.
    fn bytes_id(&self) -> String {
        format!("{}/{}", self.index.id, RAW_BYTES.name)
    }

    /// Like [`Table::journal_new`]: the new bytes first, then the index rows that point at them.
    fn journal_new(&mut self, out: Option<&mut Vec<u8>>, scratch: &mut Vec<u8>) {
        if let Some(out) = out {
            let new = &self.bytes_buf[self.bytes_journaled..];
            if !new.is_empty() {
                let first = (self.bytes_written + self.bytes_journaled) as u64;
                let count = u32::try_from(new.len()).unwrap_or(u32::MAX);
                journal::put_record(out, &self.bytes_id(), first, count, new);
            }
            self.index.journal_new(Some(out), scratch);
        } else {
            self.index.journal_new(None, scratch);
        }
        self.bytes_journaled = self.bytes_buf.len();
    }

    fn journal_all(&self, out: &mut Vec<u8>, scratch: &mut Vec<u8>) {
        let held = &self.bytes_buf[..self.bytes_journaled];
        if !held.is_empty() {
            let count = u32::try_from(held.len()).unwrap_or(u32::MAX);
            journal::put_record(
                out,
                &self.bytes_id(),
                self.bytes_written as u64,
                count,
                held,
            );
        }
        self.index.journal_all(out, scratch);
    }
}

/// The chunk file being written and its tables.
struct ChunkFile {
    index: u32,
    partial_path: PathBuf,
    final_path: PathBuf,
    file: hdf5::File,
    sync_handle: std::fs::File,
    imu: HashMap<String, Table<ImuRecord>>,
    gnss: HashMap<String, Table<GnssRecord>>,
    truth_imu: HashMap<String, Table<TruthImuRecord>>,
    truth_nav: Option<Table<TruthNavRecord>>,
    events: Table<EventRow>,
    raw: HashMap<String, RawTable>,
    /// Data time of the first row in this file (rotation by time counts from it).
    first_t: Option<i64>,
    /// The write-ahead journal beside the file, and buffers for its records.
    journal: Journal,
    records: Vec<u8>,
    scratch: Vec<u8>,
}

impl ChunkFile {
    fn create(
        dir: &Path,
        index: u32,
        manifest: &Manifest,
        opts: &WriterOptions,
    ) -> Result<Self, StoreError> {
        let partial_path = dir.join(layout::partial_file_name(index));
        let final_path = dir.join(layout::chunk_file_name(index));
        if final_path.exists() {
            return Err(StoreError::Invalid(format!(
                "{} already exists; never writing over completed data",
                final_path.display()
            )));
        }
        let p = &partial_path;
        let h5 = |what: &str| {
            let what = what.to_string();
            move |e| StoreError::h5(p, what, e)
        };
        let file = hdf5::File::with_options()
            .with_fapl(|fapl| fapl.libver_v110().chunk_cache(1, 0, 1.0))
            .create_excl(p)
            .map_err(h5("creating the chunk file"))?;
        let deflate = opts.deflate_level.min(9);
        let chunk_s = opts.chunk_interval.as_secs_f64();
        let rows_for = |rate_hz: f64| -> usize {
            opts.rows_per_chunk
                .unwrap_or_else(|| (rate_hz * chunk_s).round().clamp(1.0, 1e6) as usize)
        };

        let build = || -> hdf5::Result<ChunkFile> {
            put_u32_attr(&file, ATTR_SCHEMA_VERSION, SCHEMA_VERSION)?;
            put_str_attr(&file, "session_id", &manifest.id)?;
            put_u32_attr(&file, "chunk_index", index)?;
            put_str_attr(&file, "software_version", &manifest.software_version)?;
            let mut imu = HashMap::new();
            let mut gnss = HashMap::new();
            let mut truth_imu = HashMap::new();
            let mut raw = HashMap::new();
            for d in &manifest.devices {
                let chunk = rows_for(d.rate_hz);
                match d.kind {
                    DeviceKind::Imu => {
                        let g = device_group(&file, &layout::imu_path(&d.name), d, &d.axis_frame)?;
                        imu.insert(
                            d.name.clone(),
                            Table::create(&g, chunk, deflate, &d.axis_frame)?,
                        );
                        // The true values come at the truth rate, not the device's.
                        if let Some(truth_rate) = manifest.truth_nav_rate_hz {
                            let g = device_group(
                                &file,
                                &layout::truth_imu_path(&d.name),
                                d,
                                &d.axis_frame,
                            )?;
                            truth_imu.insert(
                                d.name.clone(),
                                Table::create(&g, rows_for(truth_rate), deflate, &d.axis_frame)?,
                            );
                        }
                    }
                    DeviceKind::Gnss => {
                        let g = device_group(&file, &layout::gnss_path(&d.name), d, "NED")?;
                        gnss.insert(d.name.clone(), Table::create(&g, chunk, deflate, "NED")?);
                    }
                }
                if opts.raw_journal {
                    let g = device_group(&file, &layout::raw_path(&d.name), d, "")?;
                    let index = Table::create(&g, layout::EVENT_CHUNK_ROWS, deflate, "")?;
                    let bytes = create_column(&g, &RAW_BYTES, layout::RAW_BYTES_CHUNK, deflate)?;
                    put_str_attr(&bytes, ATTR_AXIS_FRAME, "")?;
                    raw.insert(
                        d.name.clone(),
                        RawTable {
                            index,
                            bytes,
                            bytes_written: 0,
                            bytes_buf: Vec::new(),
                            bytes_journaled: 0,
                        },
                    );
                }
            }
            let truth_nav = match manifest.truth_nav_rate_hz {
                Some(rate) => {
                    let g = plain_group(&file, layout::TRUTH_NAV_GROUP, "NED")?;
                    put_f64_attr(&g, "rate_hz", rate)?;
                    Some(Table::create(&g, rows_for(rate), deflate, "NED")?)
                }
                None => None,
            };
            let ev = plain_group(&file, layout::EVENTS_GROUP, "")?;
            let events = Table::create(&ev, layout::EVENT_CHUNK_ROWS, deflate, "")?;
            debug_assert_eq!(EVENT_COLUMNS.len(), events.ds.len());
            debug_assert_eq!(RAW_INDEX_COLUMNS.len(), 3);
            // Every object exists now; from here on readers may watch the file (SWMR).
            file.start_swmr()?;
            Ok(ChunkFile {
                index,
                partial_path: partial_path.clone(),
                final_path: final_path.clone(),
                file: file.clone(),
                sync_handle: std::fs::File::open(&partial_path)
                    .map_err(|e| hdf5::Error::from(e.to_string()))?,
                imu,
                gnss,
                truth_imu,
                truth_nav,
                events,
                raw,
                first_t: None,
                journal: Journal::new(journal::journal_paths(dir, index)),
                records: Vec::new(),
                scratch: Vec::new(),
            })
        };
        let chunk = build().map_err(h5("laying out groups and datasets"))?;
        fsync_dir(dir)?;
        Ok(chunk)
    }

    /// Called after every append, and by a live writer's timer (`timer`), with the newest
    /// data time `now`. Once the oldest row not yet in the journal is a flush interval old (a
    /// *tick*): appends every such row to the journal (fsynced when `fsync`), then writes the
    /// chunks that are complete to the HDF5 file, flushes it with one `H5Fflush` for all
    /// tables (fsynced when `fsync`) and replaces the journal by one holding only the rows
    /// still not in the HDF5 file. So after every call, every row at least one flush interval
    /// older than `now` is on disk, in the journal or in the HDF5 file. Without a journal
    /// (`chunk_ns <= flush_ns`) a tick writes and flushes every row that is due instead.
    ///
    /// A slow or stalled device's incomplete chunk is written early (see [`Early`]), but
    /// with the journal only on a `timer` call, which also ticks for that alone: only there
    /// does `now` say that every table's rows are in up to it. Appends come table by table
    /// (the simulator hands over 4096 samples of one table, then of the next), so the table
    /// next in line would look stalled, and its chunk would be written half and then again
    /// whole (measured: 9.5 % of a simulated file was such dead copies). Returns whether it
    /// ticked.
    fn tick(
        &mut self,
        now: i64,
        flush_ns: i64,
        chunk_ns: i64,
        fsync: bool,
        timer: bool,
    ) -> Result<bool, StoreError> {
        let use_journal = chunk_ns > flush_ns;
        let early = (timer || !use_journal).then(|| Early::new(now, flush_ns, chunk_ns));
        let journal_due = self
            .oldest_unjournaled()
            .is_some_and(|t| now.saturating_sub(t) >= flush_ns)
            || self.waiting_bytes() >= MAX_WAITING_BYTES;
        let incomplete_due = early.as_ref().is_some_and(|e| self.incomplete_due(e))
            || self.events_due(now, chunk_ns.max(flush_ns));
        if !journal_due && !incomplete_due {
            return Ok(false);
        }
        self.records.clear();
        self.journal_new(use_journal);
        if use_journal {
            self.journal.append(&self.records, fsync)?;
        }
        let wrote = self.write_due(now, chunk_ns.max(flush_ns), early.as_ref(), false)?;
        if wrote {
            self.flush_hdf5(fsync)?;
            if use_journal {
                self.records.clear();
                self.journal_all();
                self.journal.replace(&self.records, fsync)?;
            }
        }
        Ok(true)
    }

    /// Writes every buffered row to the HDF5 file and flushes it (fsynced when `fsync`);
    /// the journal is then emptied when `reset_journal`.
    fn write_all(&mut self, fsync: bool, reset_journal: bool) -> Result<(), StoreError> {
        self.write_due(0, 0, None, true)?;
        self.flush_hdf5(fsync)?;
        if reset_journal {
            self.journal.replace(&[], fsync)?;
        }
        Ok(())
    }

    fn flush_hdf5(&mut self, fsync: bool) -> Result<(), StoreError> {
        let path = &self.partial_path;
        self.file
            .flush()
            .map_err(|e| StoreError::h5(path, "flushing", e))?;
        if fsync {
            self.sync_handle
                .sync_data()
                .map_err(|e| StoreError::io(path, e))?;
        }
        Ok(())
    }

    /// Time of the oldest buffered row (of any table) not yet in the journal.
    fn oldest_unjournaled(&self) -> Option<i64> {
        let tables = self
            .imu
            .values()
            .map(Table::oldest_unjournaled)
            .chain(self.gnss.values().map(Table::oldest_unjournaled))
            .chain(self.truth_imu.values().map(Table::oldest_unjournaled))
            .chain(self.truth_nav.iter().map(Table::oldest_unjournaled))
            .chain(self.raw.values().map(|r| r.index.oldest_unjournaled()))
            .chain(std::iter::once(self.events.oldest_unjournaled()));
        tables.flatten().min()
    }

    /// Bytes waiting in memory that can be written now: rows of complete chunks and raw
    /// reads (see [`MAX_WAITING_BYTES`]).
    fn waiting_bytes(&self) -> usize {
        self.imu.values().map(Table::complete_bytes).sum::<usize>()
            + self.gnss.values().map(Table::complete_bytes).sum::<usize>()
            + self
                .truth_imu
                .values()
                .map(Table::complete_bytes)
                .sum::<usize>()
            + self
                .truth_nav
                .iter()
                .map(Table::complete_bytes)
                .sum::<usize>()
            + self
                .raw
                .values()
                .map(|r| r.bytes_buf.len() + r.index.buf.len() * std::mem::size_of::<RawIndexRow>())
                .sum::<usize>()
    }

    /// Whether any data table's incomplete chunk is due (events and raw reads come at no
    /// fixed rate: see [`ChunkFile::write_due`]).
    fn incomplete_due(&self, e: &Early) -> bool {
        self.imu.values().any(|t| t.incomplete_due(e))
            || self.gnss.values().any(|t| t.incomplete_due(e))
            || self.truth_imu.values().any(|t| t.incomplete_due(e))
            || self.truth_nav.iter().any(|t| t.incomplete_due(e))
    }

    /// Whether the incomplete `/events` chunk is due at data time `now`: its oldest event
    /// has waited `max_age_ns` (see [`ChunkFile::write_due`]).
    fn events_due(&self, now: i64, max_age_ns: i64) -> bool {
        let events = &self.events;
        events
            .buf
            .get(events.complete_rows())
            .is_some_and(|row| now.saturating_sub(row.t_mono_ns) >= max_age_ns)
    }

    /// Records every buffered row not yet in the journal into `self.records` (or, when
    /// `!use_journal`, only marks them as seen by this tick).
    fn journal_new(&mut self, use_journal: bool) {
        let (out, scratch) = (&mut self.records, &mut self.scratch);
        let mut out = use_journal.then_some(out);
        for t in self.imu.values_mut() {
            t.journal_new(out.as_deref_mut(), scratch);
        }
        for t in self.gnss.values_mut() {
            t.journal_new(out.as_deref_mut(), scratch);
        }
        for t in self.truth_imu.values_mut() {
            t.journal_new(out.as_deref_mut(), scratch);
        }
        if let Some(t) = self.truth_nav.as_mut() {
            t.journal_new(out.as_deref_mut(), scratch);
        }
        for r in self.raw.values_mut() {
            r.journal_new(out.as_deref_mut(), scratch);
        }
        self.events.journal_new(out, scratch);
    }

    /// Records every journaled row still buffered into `self.records` (a fresh journal).
    fn journal_all(&mut self) {
        let (out, scratch) = (&mut self.records, &mut self.scratch);
        for t in self.imu.values() {
            t.journal_all(out, scratch);
        }
        for t in self.gnss.values() {
            t.journal_all(out, scratch);
        }
        for t in self.truth_imu.values() {
            t.journal_all(out, scratch);
        }
        if let Some(t) = self.truth_nav.as_ref() {
            t.journal_all(out, scratch);
        }
        for r in self.raw.values() {
            r.journal_all(out, scratch);
        }
        self.events.journal_all(out, scratch);
    }

    /// Writes to the HDF5 file what is due: complete chunks, incomplete ones that are due by
    /// `early` (see [`Early`]), everything when `force`. `/events` is written in whole chunks
    /// (`layout::EVENT_CHUNK_ROWS` events) as they fill, and its incomplete chunk once the
    /// oldest event in it is `max_age_ns` (a chunk interval; without the journal a flush
    /// interval) older than `now`, so the file is as far behind in events as in rows.
    /// Written with every data chunk, as before, a trickle of events had its incomplete chunk
    /// stored again at nearly every flush that wrote a data chunk (up to once per table and
    /// chunk interval), each earlier copy left as dead space: 5.4 % of a 5-minute
    /// daemon-like file with one event a second (docs/bench/store.md). Until then the
    /// journal holds the events, as it holds rows. Raw reads come at no fixed rate either:
    /// they are written with the chunks, or once the oldest is `max_age_ns` older than
    /// `now`. Returns whether it wrote anything.
    fn write_due(
        &mut self,
        now: i64,
        max_age_ns: i64,
        early: Option<&Early>,
        force: bool,
    ) -> Result<bool, StoreError> {
        let path = self.partial_path.clone();
        let mut wrote = false;
        let events_due = self.events_due(now, max_age_ns);
        let mut go = || -> hdf5::Result<()> {
            fn table<R: Row>(
                t: &mut Table<R>,
                early: Option<&Early>,
                force: bool,
            ) -> hdf5::Result<bool> {
                let incomplete = force || early.is_some_and(|e| t.incomplete_due(e));
                Ok(t.write_aligned(incomplete)?.is_some())
            }
            for t in self.imu.values_mut() {
                wrote |= table(t, early, force)?;
            }
            for t in self.gnss.values_mut() {
                wrote |= table(t, early, force)?;
            }
            for t in self.truth_imu.values_mut() {
                wrote |= table(t, early, force)?;
            }
            if let Some(t) = self.truth_nav.as_mut() {
                wrote |= table(t, early, force)?;
            }
            let stale =
                |first: Option<i64>| first.is_some_and(|t| now.saturating_sub(t) >= max_age_ns);
            for r in self.raw.values_mut() {
                if force
                    || wrote
                    || r.bytes_buf.len() >= MAX_WAITING_BYTES
                    || stale(r.index.buf.first().map(|row| row.t_mono_ns))
                {
                    wrote |= r.write_all()?.is_some();
                }
            }
            let incomplete = force || events_due;
            wrote |= self.events.write_aligned(incomplete)?.is_some();
            Ok(())
        };
        go().map_err(|e| StoreError::h5(&path, "writing rows", e))?;
        Ok(wrote)
    }

    /// Cuts every table back to the rows written (they were grown ahead).
    fn trim(&mut self) -> hdf5::Result<()> {
        for t in self.imu.values_mut() {
            t.trim()?;
        }
        for t in self.gnss.values_mut() {
            t.trim()?;
        }
        for t in self.truth_imu.values_mut() {
            t.trim()?;
        }
        if let Some(t) = self.truth_nav.as_mut() {
            t.trim()?;
        }
        for r in self.raw.values_mut() {
            r.index.trim()?;
        }
        self.events.trim()
    }

    /// Flushes everything, closes, fsyncs, renames to the final name and fsyncs the directory.
    /// The journal goes last, once the renamed file is durable (an orphan journal beside a
    /// completed file, left by a crash just before, is removed by `recover`).
    fn finish(mut self, dir: &Path) -> Result<PathBuf, StoreError> {
        self.write_all(false, false)?;
        self.trim()
            .map_err(|e| StoreError::h5(&self.partial_path, "trimming tables", e))?;
        let ChunkFile {
            partial_path,
            final_path,
            file,
            sync_handle,
            journal,
            ..
        } = self;
        file.close()
            .map_err(|e| StoreError::h5(&partial_path, "closing", e))?;
        sync_handle
            .sync_all()
            .map_err(|e| StoreError::io(&partial_path, e))?;
        drop(sync_handle);
        std::fs::rename(&partial_path, &final_path).map_err(|e| StoreError::io(&final_path, e))?;
        fsync_dir(dir)?;
        journal.remove()?;
        Ok(final_path)
    }
}

/// Creates `path`: a closed chunk file number `index` laid out for `manifest` (with
/// `/raw/<device>` tables when `raw`) and holding no rows, for `recover` to rebuild a chunk
/// that is beyond repair into. The layout is made by [`ChunkFile`] itself (one way to lay a
/// file out), in a scratch directory beside `path` that is removed again.
pub(crate) fn create_empty_chunk(
    path: &Path,
    index: u32,
    manifest: &Manifest,
    raw: bool,
) -> Result<(), StoreError> {
    let scratch = path.with_extension("layout");
    let _ = std::fs::remove_dir_all(&scratch);
    std::fs::create_dir(&scratch).map_err(|e| StoreError::io(&scratch, e))?;
    let opts = WriterOptions {
        raw_journal: raw,
        ..WriterOptions::default()
    };
    let made = ChunkFile::create(&scratch, index, manifest, &opts)
        .and_then(|chunk| chunk.finish(&scratch))
        .and_then(|file| std::fs::rename(&file, path).map_err(|e| StoreError::io(path, e)));
    let _ = std::fs::remove_dir_all(&scratch);
    made
}

fn plain_group(file: &hdf5::File, path: &str, axis_frame: &str) -> hdf5::Result<Group> {
    let g = match file.group(path) {
        Ok(g) => g,
        Err(_) => {
            // Create parents first (e.g. `truth` for `truth/nav`), tagging each.
            if let Some((parent, _)) = path.rsplit_once('/') {
                if file.group(parent).is_err() {
                    plain_group(file, parent, "")?;
                }
            }
            let g = file.create_group(path)?;
            put_u32_attr(&g, ATTR_SCHEMA_VERSION, SCHEMA_VERSION)?;
            put_str_attr(&g, ATTR_AXIS_FRAME, axis_frame)?;
            g
        }
    };
    Ok(g)
}

fn device_group(
    file: &hdf5::File,
    path: &str,
    d: &DeviceInfo,
    axis_frame: &str,
) -> hdf5::Result<Group> {
    let g = plain_group(file, path, axis_frame)?;
    put_str_attr(&g, "kind", d.kind.as_str())?;
    put_str_attr(&g, "model", &d.model)?;
    put_str_attr(&g, "serial", &d.serial)?;
    put_str_attr(&g, "protocol", &d.protocol)?;
    put_f64_attr(&g, "rate_hz", d.rate_hz)?;
    Ok(g)
}

/// Writes a session: see the module documentation for when it flushes and rotates.
pub struct SessionWriter {
    dir: PathBuf,
    manifest: Manifest,
    opts: WriterOptions,
    current: Option<ChunkFile>,
    next_index: u32,
    /// Newest data time seen, ns.
    max_t: Option<i64>,
    /// Data time of the last check of the file size against `rotate_bytes`.
    last_size_check_t: Option<i64>,
    /// Last row time per stream (`imu/name`...), to refuse rows going back in time.
    last_t: HashMap<String, i64>,
    rotate_pending: bool,
    /// Events at or past the time the current file is due to rotate, while no data row has
    /// come for the next file yet: they go into the next file when it starts, or into the
    /// current one when the session closes first (see [`SessionWriter::append_event`]).
    held_events: Vec<EventRow>,
    /// The session's writer lock, held while this writer lives.
    lock: Option<nix::fcntl::Flock<std::fs::File>>,
}

impl SessionWriter {
    /// Creates the session directory `dir` (which must not exist or be empty), writes the
    /// manifest and opens chunk file 0.
    pub fn create(dir: &Path, manifest: Manifest, opts: WriterOptions) -> Result<Self, StoreError> {
        manifest.validate(&dir.join(super::manifest::MANIFEST_FILE))?;
        if opts.flush_interval.is_zero()
            || opts.rotate_after.is_zero()
            || opts.chunk_interval.is_zero()
        {
            return Err(StoreError::Invalid(
                "flush_interval, chunk_interval and rotate_after must be positive".into(),
            ));
        }
        std::fs::create_dir_all(dir).map_err(|e| StoreError::io(dir, e))?;
        let not_empty = std::fs::read_dir(dir)
            .map_err(|e| StoreError::io(dir, e))?
            .next()
            .is_some();
        if not_empty {
            return Err(StoreError::Invalid(format!(
                "{} is not empty; a new session needs a new directory",
                dir.display()
            )));
        }
        manifest.save(dir)?;
        keep_freed_heap();
        let lock = try_writer_lock(dir)?.ok_or_else(|| {
            StoreError::Invalid(format!(
                "{}: another writer holds the session lock",
                dir.display()
            ))
        })?;
        let first = ChunkFile::create(dir, 0, &manifest, &opts)?;
        Ok(SessionWriter {
            dir: dir.to_path_buf(),
            manifest,
            opts,
            current: Some(first),
            next_index: 1,
            max_t: None,
            last_size_check_t: None,
            last_t: HashMap::new(),
            rotate_pending: false,
            held_events: Vec::new(),
            lock: Some(lock),
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// Path of the chunk file being written.
    pub fn current_file(&self) -> Option<&Path> {
        self.current.as_ref().map(|c| c.partial_path.as_path())
    }

    fn flush_ns(&self) -> i64 {
        i64::try_from(self.opts.flush_interval.as_nanos()).unwrap_or(i64::MAX)
    }

    /// Checks that `times` are usable and do not go back in time for `stream`.
    fn check_times(
        &mut self,
        stream: &str,
        times: impl Iterator<Item = i64>,
    ) -> Result<(), StoreError> {
        let mut last = self.last_t.get(stream).copied();
        for (i, t) in times.enumerate() {
            if t == FILL_T_MONO {
                return Err(StoreError::Invalid(format!(
                    "{stream}: row {i}: t_mono_ns = i64::MIN is reserved"
                )));
            }
            if let Some(l) = last {
                if t < l {
                    return Err(StoreError::Invalid(format!(
                        "{stream}: row {i}: t_mono_ns {t} goes back in time (previous {l})"
                    )));
                }
            }
            last = Some(t);
        }
        if let Some(l) = last {
            self.last_t.insert(stream.to_string(), l);
        }
        Ok(())
    }

    /// Makes sure a file is open for rows starting at data time `t`, rotating first if the
    /// current file is due (by data time or size).
    fn file_for(&mut self, t: i64) -> Result<&mut ChunkFile, StoreError> {
        let span_start = self.next_span_start(t);
        if self.current.is_none() || span_start.is_some() || self.rotate_pending {
            self.rotate_at(Some(t))?;
        }
        let chunk = self
            .current
            .as_mut()
            .ok_or_else(|| StoreError::Invalid("writer has no open chunk file".into()))?;
        match span_start {
            Some(start) => chunk.first_t = Some(start),
            None => {
                chunk.first_t.get_or_insert(t);
            }
        }
        Ok(chunk)
    }

    /// Whether a row at data time `t` is past the current file's time span (`rotate_after`
    /// from its start).
    fn due_by_time(&self, t: i64) -> bool {
        self.next_span_start(t).is_some()
    }

    /// When data time `t` is past the current file's span: the start of the span that holds
    /// `t` on the grid the first file started (its start + k × `rotate_after`). Rotations by
    /// data time keep to that grid, so the spans follow each other whatever the times of the
    /// rows that happen to start the files (arrival jitter, latency) and the sizes of the
    /// appends; a writer that hands rows over in pieces ending at those times (the
    /// simulator: [`SessionWriter::rotate_after`]) gets files of exactly `rotate_after`.
    fn next_span_start(&self, t: i64) -> Option<i64> {
        let rotate_ns = i64::try_from(self.opts.rotate_after.as_nanos())
            .unwrap_or(i64::MAX)
            .max(1);
        let first = self.current.as_ref()?.first_t?;
        let since = t.saturating_sub(first);
        (since >= rotate_ns).then(|| first.saturating_add(since / rotate_ns * rotate_ns))
    }

    /// The data time after which a new chunk file starts (see [`WriterOptions::rotate_after`]).
    pub fn rotate_after(&self) -> Duration {
        self.opts.rotate_after
    }

    fn note_time(&mut self, t: i64) {
        self.max_t = Some(self.max_t.map_or(t, |m| m.max(t)));
    }

    /// Appends IMU rows for `device` (rows must be in time order).
    pub fn append_imu(&mut self, device: &str, rows: &[ImuRecord]) -> Result<(), StoreError> {
        self.manifest
            .device_of_kind(device, Some(DeviceKind::Imu))?;
        self.check_times(&layout::imu_path(device), rows.iter().map(|r| r.t_mono_ns))?;
        let (Some(first), Some(last)) = (rows.first(), rows.last()) else {
            return Ok(());
        };
        let chunk = self.file_for(first.t_mono_ns)?;
        table_of(&mut chunk.imu, device)?
            .buf
            .extend_from_slice(rows);
        self.note_time(last.t_mono_ns);
        self.maybe_flush(false)
    }

    /// Appends GNSS rows for `device` (rows must be in time order).
    pub fn append_gnss(&mut self, device: &str, rows: &[GnssRecord]) -> Result<(), StoreError> {
        self.manifest
            .device_of_kind(device, Some(DeviceKind::Gnss))?;
        self.check_times(&layout::gnss_path(device), rows.iter().map(|r| r.t_mono_ns))?;
        let (Some(first), Some(last)) = (rows.first(), rows.last()) else {
            return Ok(());
        };
        let chunk = self.file_for(first.t_mono_ns)?;
        table_of(&mut chunk.gnss, device)?
            .buf
            .extend_from_slice(rows);
        self.note_time(last.t_mono_ns);
        self.maybe_flush(false)
    }

    /// Appends one event to `/events` (written at the next flush).
    ///
    /// An event never starts a file by itself: one timed at or past the current file's
    /// rotation time is held until a data row starts the next file (or a live writer's
    /// timer does), and goes into the current file if the session closes first. So a run
    /// that ends exactly on a rotation time (a simulation of 20 min with 10 min files, whose
    /// `session_stop` is timed at its end) has no last file holding only that event.
    pub fn append_event(&mut self, ev: &EventRecord) -> Result<(), StoreError> {
        let row = EventRow::from_record(ev).map_err(StoreError::Invalid)?;
        if self.due_by_time(ev.t_mono_ns) && !self.rotate_pending {
            self.held_events.push(row);
            self.note_time(ev.t_mono_ns);
            return Ok(());
        }
        let chunk = self.file_for(ev.t_mono_ns)?;
        chunk.events.buf.push(row);
        self.note_time(ev.t_mono_ns);
        self.maybe_flush(false)
    }

    /// Appends one read of undecoded bytes to `/raw/<device>` (needs `raw_journal`).
    pub fn append_raw(
        &mut self,
        device: &str,
        t_mono_ns: i64,
        bytes: &[u8],
    ) -> Result<(), StoreError> {
        self.manifest.device_of_kind(device, None)?;
        if !self.opts.raw_journal {
            return Err(StoreError::Invalid(format!(
                "raw bytes for {device:?} but the writer was created without raw_journal"
            )));
        }
        let len = u32::try_from(bytes.len()).map_err(|_| {
            StoreError::Invalid(format!("raw read of {} bytes is too long", bytes.len()))
        })?;
        self.check_times(&layout::raw_path(device), std::iter::once(t_mono_ns))?;
        let chunk = self.file_for(t_mono_ns)?;
        let raw = chunk
            .raw
            .get_mut(device)
            .ok_or_else(|| StoreError::UnknownDevice {
                device: device.into(),
                msg: "no raw journal group".into(),
            })?;
        let offset = (raw.bytes_written + raw.bytes_buf.len()) as u64;
        raw.index.buf.push(RawIndexRow {
            t_mono_ns,
            offset,
            len,
        });
        raw.bytes_buf.extend_from_slice(bytes);
        self.note_time(t_mono_ns);
        self.maybe_flush(false)
    }

    /// Appends true trajectory epochs (simulated sessions: manifest `truth_nav_rate_hz`).
    pub fn append_truth_nav(&mut self, rows: &[TruthNavRecord]) -> Result<(), StoreError> {
        if self.manifest.truth_nav_rate_hz.is_none() {
            return Err(StoreError::Invalid(
                "truth rows for a session whose manifest has no truth_nav_rate_hz".into(),
            ));
        }
        self.check_times(layout::TRUTH_NAV_GROUP, rows.iter().map(|r| r.t_mono_ns))?;
        let (Some(first), Some(last)) = (rows.first(), rows.last()) else {
            return Ok(());
        };
        let chunk = self.file_for(first.t_mono_ns)?;
        chunk
            .truth_nav
            .as_mut()
            .ok_or_else(|| StoreError::Invalid("no /truth/nav in this file".into()))?
            .buf
            .extend_from_slice(rows);
        self.note_time(last.t_mono_ns);
        self.maybe_flush(false)
    }

    /// Appends true IMU error states for IMU `device` (simulated sessions).
    pub fn append_truth_imu(
        &mut self,
        device: &str,
        rows: &[TruthImuRecord],
    ) -> Result<(), StoreError> {
        self.manifest
            .device_of_kind(device, Some(DeviceKind::Imu))?;
        if self.manifest.truth_nav_rate_hz.is_none() {
            return Err(StoreError::Invalid(
                "truth rows for a session whose manifest has no truth_nav_rate_hz".into(),
            ));
        }
        self.check_times(
            &layout::truth_imu_path(device),
            rows.iter().map(|r| r.t_mono_ns),
        )?;
        let (Some(first), Some(last)) = (rows.first(), rows.last()) else {
            return Ok(());
        };
        let chunk = self.file_for(first.t_mono_ns)?;
        table_of(&mut chunk.truth_imu, device)?
            .buf
            .extend_from_slice(rows);
        self.note_time(last.t_mono_ns);
        self.maybe_flush(false)
    }

    /// Writes what is due after every append (and, with `timer`, from the idle timer):
    /// completed chunks at once, and any table's rows once the oldest has waited a flush
    /// interval (so at most one interval of data is ever only in memory; see
    /// [`ChunkFile::tick`]). Checks the file size for rotation once per flush interval.
    fn maybe_flush(&mut self, timer: bool) -> Result<(), StoreError> {
        let Some(now) = self.max_t else { return Ok(()) };
        let (flush_ns, fsync) = (self.flush_ns(), self.opts.fsync_on_flush);
        let chunk_ns = i64::try_from(self.opts.chunk_interval.as_nanos()).unwrap_or(i64::MAX);
        let Some(chunk) = self.current.as_mut() else {
            return Ok(());
        };
        chunk.tick(now, flush_ns, chunk_ns, fsync, timer)?;
        let size_check_due = self
            .last_size_check_t
            .is_none_or(|last| now.saturating_sub(last) >= flush_ns);
        if size_check_due {
            self.last_size_check_t = Some(now);
            let size = std::fs::metadata(&chunk.partial_path)
                .map_err(|e| StoreError::io(&chunk.partial_path, e))?
                .len();
            if size >= self.opts.rotate_bytes {
                self.rotate_pending = true;
            }
        }
        Ok(())
    }

    /// For a live writer's idle timer: treats `now_mono_ns` as the current data time, so
    /// rows of a device that went quiet still reach the disk within a flush interval, and a
    /// file due for rotation by time is finalised even when no new rows arrive. The caller
    /// says that every device's rows are in up to `now_mono_ns`: only here is a stalled or
    /// slow device's incomplete chunk written to the HDF5 file early (see `Early`; appends
    /// alone write whole chunks).
    pub fn maybe_flush_and_rotate(&mut self, now_mono_ns: i64) -> Result<(), StoreError> {
        self.note_time(now_mono_ns);
        self.maybe_flush(true)?;
        let span_start = self.next_span_start(now_mono_ns);
        if span_start.is_some() || self.rotate_pending {
            self.rotate_at(None)?;
        }
        if let (Some(start), Some(c)) = (span_start, self.current.as_mut()) {
            c.first_t = Some(start);
        }
        Ok(())
    }

    /// Writes every buffered row to the current HDF5 file and flushes (and fsyncs) it now,
    /// so it is readable there (not only in the journal).
    pub fn flush(&mut self) -> Result<(), StoreError> {
        let fsync = self.opts.fsync_on_flush;
        if let Some(chunk) = self.current.as_mut() {
            chunk.write_all(fsync, true)?;
        }
        self.last_size_check_t = self.max_t;
        Ok(())
    }

    /// Finalises the current chunk file and starts the next one now.
    pub fn rotate(&mut self) -> Result<(), StoreError> {
        self.rotate_at(None)
    }

    fn rotate_at(&mut self, t: Option<i64>) -> Result<(), StoreError> {
        let previous = match self.current.take() {
            Some(c) => {
                let idx = c.index;
                c.finish(&self.dir)?;
                release_freed_memory();
                Some(idx)
            }
            None => None,
        };
        self.rotate_pending = false;
        let index = self.next_index;
        let chunk = ChunkFile::create(&self.dir, index, &self.manifest, &self.opts)?;
        self.next_index += 1;
        self.current = Some(chunk);
        // Held events (see `append_event`) are the first rows of the new file.
        let t = t
            .or(self.max_t)
            .map(|t| self.held_events.first().map_or(t, |h| h.t_mono_ns.min(t)));
        if let (Some(prev), Some(t)) = (previous, t) {
            let detail = format!(
                "{} finished; {} started",
                layout::chunk_file_name(prev),
                layout::chunk_file_name(index)
            );
            let ev = EventRecord {
                t_mono_ns: t,
                t_wall_ns: wall_clock_ns(),
                device: String::new(),
                kind: EventKind::Rotation,
                detail,
            };
            let row = EventRow::from_record(&ev).map_err(StoreError::Invalid)?;
            if let Some(c) = self.current.as_mut() {
                c.events.buf.push(row);
            }
        }
        if let Some(c) = self.current.as_mut() {
            if let Some(first) = self.held_events.first() {
                c.first_t.get_or_insert(first.t_mono_ns);
            }
            c.events.buf.append(&mut self.held_events);
        }
        Ok(())
    }

    /// Writes everything, finalises the current chunk file and returns the session directory.
    pub fn close(mut self) -> Result<PathBuf, StoreError> {
        self.finish_current()?;
        self.release_lock();
        Ok(std::mem::take(&mut self.dir))
    }

    /// Finalises the current chunk file, with the events held for a next file that never
    /// came (see [`SessionWriter::append_event`]).
    fn finish_current(&mut self) -> Result<(), StoreError> {
        match self.current.take() {
            Some(mut c) => {
                c.events.buf.append(&mut self.held_events);
                c.finish(&self.dir).map(|_| ())
            }
            None => Ok(()),
        }
    }

    fn release_lock(&mut self) {
        if self.lock.take().is_some() {
            let _ = std::fs::remove_file(self.dir.join(layout::WRITER_LOCK_FILE));
        }
    }
}

fn table_of<'a, R>(
    map: &'a mut HashMap<String, Table<R>>,
    device: &str,
) -> Result<&'a mut Table<R>, StoreError> {
    map.get_mut(device)
        .ok_or_else(|| StoreError::UnknownDevice {
            device: device.into(),
            msg: "no group for it in the current chunk file".into(),
        })
}

/// HDF5's deflate filter sets up a fresh zlib stream (about 256 KiB, partly zeroed) for
/// every chunk it compresses (now only partial chunks; whole ones go through `chunkio`).
/// With glibc's default trim threshold each free shrinks the heap and the next chunk faults
/// the pages back in: measured in the first pass, that churn cost 15 % of the writer's CPU
/// on 30 min of data. Keeping up to 64 MiB of freed heap stops it. Process-wide and
/// harmless for other code; done once.
fn keep_freed_heap() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        static ONCE: std::sync::Once = std::sync::Once::new();
        ONCE.call_once(|| {
            // SAFETY: mallopt only changes allocator tuning parameters; any value is valid.
            unsafe {
                libc::mallopt(libc::M_TRIM_THRESHOLD, 64 << 20);
                libc::mallopt(libc::M_TOP_PAD, 16 << 20);
            }
        });
    }
}

/// Called after each rotation, when the finished file's HDF5 state (metadata cache, chunk
/// index, B-tree nodes) has just been freed: gives freed memory back to the system so a
/// daemon's RSS stays flat over days. Measured (docs/bench/daemon.md, soak): the heap in use
/// was flat across rotations, but RSS crept up because nothing freed was ever returned:
/// HDF5 keeps every block it frees on its own free lists (no limit by default; ~1.4 MiB
/// here) and glibc keeps up to 64 MiB of freed heap (see [`keep_freed_heap`]), whose
/// resident pages wander up with fragmentation. `H5garbage_collect` hands HDF5's free
/// lists to malloc, `malloc_trim` unmaps every whole free page. Once per rotation (10 min by
/// default) the cost is a walk over the free lists and some page faults later.
fn release_freed_memory() {
    // SAFETY: H5garbage_collect takes no arguments and only frees blocks on HDF5's own free
    // lists (no live object uses them); the global HDF5 lock is held.
    let rc = hdf5::sync::sync(|| unsafe { hdf5_sys::h5::H5garbage_collect() });
    if rc < 0 {
        tracing::warn!("H5garbage_collect failed after rotation; memory kept, data unaffected");
    }
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only releases free memory of the allocator; any pad is valid.
    unsafe {
        libc::malloc_trim(0);
    }
}

fn wall_clock_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX))
        .unwrap_or(0)
}

impl Drop for SessionWriter {
    /// A writer dropped without `close` (e.g. on an error path) still finalises its file.
    fn drop(&mut self) {
        if let Err(e) = self.finish_current() {
            tracing::error!("closing session {}: {e}", self.dir.display());
        }
        self.release_lock();
    }
}

#[cfg(test)]
mod tests {
    use super::Early;

    const S: i64 = 1_000_000_000;

    #[test]
    fn incomplete_chunks_are_written_early_for_stalled_and_slow_devices_only() {
        // Journal on: 1 s flushes, 10 s chunks; a chunk whose first row came at 0.
        let at = |now: i64| Early::new(now, S, 10 * S);
        // A device streaming at about its rate (newest row 0.2 s old): its chunk is not
        // written half at 10 s (it completes by itself), only once 20 s old (too slow).
        assert!(!at(10 * S).due(0, 10 * S - S / 5));
        assert!(!at(19 * S).due(0, 19 * S - S / 5));
        assert!(at(20 * S).due(0, 20 * S - S / 5));
        // Silent for a flush interval: stalled, written once the chunk is 10 s old.
        assert!(!at(10 * S - 1).due(0, 3 * S));
        assert!(at(10 * S).due(0, 3 * S));
        assert!(!at(10 * S).due(0, 9 * S + 1));
        // Journal off (chunks of one flush interval): everything a flush interval old.
        let off = Early::new(S, S, S);
        assert!(off.due(0, S));
        assert!(!off.due(1, S));
    }
}
