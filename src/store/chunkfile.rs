//! [`ChunkFile`]: one HDF5 chunk file of a session being written, with its tables (IMU, GNSS,
//! truth, events, raw reads), the write-ahead journal beside it and the growing, chunking
//! and early writing of its datasets. [`super::writer::SessionWriter`] owns the current one
//! and decides when it flushes, rotates and finishes.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use hdf5::{Dataset, Group};

use super::chunkio::ChunkEncoder;
use super::columns::{
    create_column, put_1d, put_f64_attr, put_str_attr, put_u32_attr, ChunkSink, Column, EventRow,
    RawIndexRow, Row, EVENT_COLUMNS, RAW_BYTES, RAW_INDEX_COLUMNS,
};
use super::journal::{self, Journal};
use super::layout::{self, ATTR_AXIS_FRAME, ATTR_SCHEMA_VERSION};
use super::manifest::{fsync_dir, DeviceInfo, DeviceKind, Manifest};
use super::records::{GnssRecord, ImuRecord, TruthImuRecord, TruthNavRecord};
use super::writer::WriterOptions;
use super::{StoreError, SCHEMA_VERSION};

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
pub(super) struct Table<R> {
    /// Table id in the journal: the group path without the leading `/`.
    pub(super) id: String,
    pub(super) ds: Vec<Dataset>,
    pub(super) sink: ChunkSink,
    pub(super) written: usize,
    pub(super) extent: usize,
    pub(super) buf: Vec<R>,
    pub(super) journaled: usize,
}

impl<R: Row> Table<R> {
    pub(super) fn create(
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
    pub(super) fn oldest_unjournaled(&self) -> Option<i64> {
        self.buf.get(self.journaled).map(R::t_mono_ns)
    }

    /// Appends a journal record of the buffered rows not yet in the journal to `out`
    /// (`scratch` holds the encoded rows). With `out` = `None` only marks them journaled.
    pub(super) fn journal_new(&mut self, out: Option<&mut Vec<u8>>, scratch: &mut Vec<u8>) {
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
    pub(super) fn journal_all(&self, out: &mut Vec<u8>, scratch: &mut Vec<u8>) {
        journal_rows(
            &self.id,
            self.written,
            &self.buf[..self.journaled],
            out,
            scratch,
        );
    }

    /// Sets every column's row count to `rows`.
    pub(super) fn resize_all(&self, rows: usize) -> hdf5::Result<()> {
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
    pub(super) fn reserve(&mut self, rows: usize) -> hdf5::Result<()> {
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
    pub(super) fn trim(&mut self) -> hdf5::Result<()> {
        if self.extent != self.written {
            self.resize_all(self.written)?;
            self.extent = self.written;
        }
        Ok(())
    }

    /// Buffered rows that end on a chunk boundary: the rest of the chunk being filled, then
    /// whole chunks (0 when the chunk being filled is not complete yet).
    pub(super) fn complete_rows(&self) -> usize {
        let chunk_rows = self.sink.chunk_rows;
        let to_boundary = chunk_rows - self.written % chunk_rows;
        if self.buf.len() < to_boundary {
            return 0;
        }
        to_boundary + (self.buf.len() - to_boundary) / chunk_rows * chunk_rows
    }

    /// Bytes of the buffered rows in complete chunks.
    pub(super) fn complete_bytes(&self) -> usize {
        self.complete_rows() * std::mem::size_of::<R>()
    }

    /// Whether the incomplete chunk (the rows past the complete chunks) is due to be written
    /// before the file is closed: see [`Early`].
    pub(super) fn incomplete_due(&self, e: &Early) -> bool {
        let Some(oldest) = self.buf.get(self.complete_rows()).map(R::t_mono_ns) else {
            return false;
        };
        e.due(oldest, self.buf.last().map_or(oldest, R::t_mono_ns))
    }

    /// Writes buffered rows so that writes end on chunk boundaries: everything up to the last
    /// complete chunk, and the incomplete rest too when `incomplete`. Returns the time of the
    /// oldest row written, if any.
    pub(super) fn write_aligned(&mut self, incomplete: bool) -> hdf5::Result<Option<i64>> {
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
pub(super) struct Early {
    pub(super) now: i64,
    pub(super) age_ns: i64,
    pub(super) silent_ns: i64,
    pub(super) slow_age_ns: i64,
}

impl Early {
    pub(super) fn new(now: i64, flush_ns: i64, chunk_ns: i64) -> Self {
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
    pub(super) fn due(&self, oldest: i64, newest: i64) -> bool {
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
pub(super) struct RawTable {
    pub(super) index: Table<RawIndexRow>,
    pub(super) bytes: Dataset,
    pub(super) bytes_written: usize,
    pub(super) bytes_buf: Vec<u8>,
    /// Bytes of `bytes_buf` already in the journal.
    pub(super) bytes_journaled: usize,
}

impl RawTable {
    pub(super) fn write_all(&mut self) -> hdf5::Result<Option<i64>> {
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
    pub(super) fn bytes_id(&self) -> String {
        format!("{}/{}", self.index.id, RAW_BYTES.name)
    }

    /// Like [`Table::journal_new`]: the new bytes first, then the index rows that point at them.
    pub(super) fn journal_new(&mut self, out: Option<&mut Vec<u8>>, scratch: &mut Vec<u8>) {
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

    pub(super) fn journal_all(&self, out: &mut Vec<u8>, scratch: &mut Vec<u8>) {
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
pub(super) struct ChunkFile {
    pub(super) index: u32,
    pub(super) partial_path: PathBuf,
    pub(super) final_path: PathBuf,
    pub(super) file: hdf5::File,
    pub(super) sync_handle: std::fs::File,
    pub(super) imu: HashMap<String, Table<ImuRecord>>,
    pub(super) gnss: HashMap<String, Table<GnssRecord>>,
    pub(super) truth_imu: HashMap<String, Table<TruthImuRecord>>,
    pub(super) truth_nav: Option<Table<TruthNavRecord>>,
    pub(super) events: Table<EventRow>,
    pub(super) raw: HashMap<String, RawTable>,
    /// Data time of the first row in this file (rotation by time counts from it).
    pub(super) first_t: Option<i64>,
    /// The write-ahead journal beside the file, and buffers for its records.
    pub(super) journal: Journal,
    pub(super) records: Vec<u8>,
    pub(super) scratch: Vec<u8>,
}

impl ChunkFile {
    pub(super) fn create(
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
    pub(super) fn tick(
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
    pub(super) fn write_all(&mut self, fsync: bool, reset_journal: bool) -> Result<(), StoreError> {
        self.write_due(0, 0, None, true)?;
        self.flush_hdf5(fsync)?;
        if reset_journal {
            self.journal.replace(&[], fsync)?;
        }
        Ok(())
    }

    pub(super) fn flush_hdf5(&mut self, fsync: bool) -> Result<(), StoreError> {
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
    pub(super) fn oldest_unjournaled(&self) -> Option<i64> {
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
    pub(super) fn waiting_bytes(&self) -> usize {
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
    pub(super) fn incomplete_due(&self, e: &Early) -> bool {
        self.imu.values().any(|t| t.incomplete_due(e))
            || self.gnss.values().any(|t| t.incomplete_due(e))
            || self.truth_imu.values().any(|t| t.incomplete_due(e))
            || self.truth_nav.iter().any(|t| t.incomplete_due(e))
    }

    /// Whether the incomplete `/events` chunk is due at data time `now`: its oldest event
    /// has waited `max_age_ns` (see [`ChunkFile::write_due`]).
    pub(super) fn events_due(&self, now: i64, max_age_ns: i64) -> bool {
        let events = &self.events;
        events
            .buf
            .get(events.complete_rows())
            .is_some_and(|row| now.saturating_sub(row.t_mono_ns) >= max_age_ns)
    }

    /// Records every buffered row not yet in the journal into `self.records` (or, when
    /// `!use_journal`, only marks them as seen by this tick).
    pub(super) fn journal_new(&mut self, use_journal: bool) {
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
    pub(super) fn journal_all(&mut self) {
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
    pub(super) fn write_due(
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
    pub(super) fn trim(&mut self) -> hdf5::Result<()> {
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
    pub(super) fn finish(mut self, dir: &Path) -> Result<PathBuf, StoreError> {
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

#[cfg(test)]
mod tests {
    use super::Early;

    const S: i64 = 1_000_000_000;

    #[test]
    pub(super) fn incomplete_chunks_are_written_early_for_stalled_and_slow_devices_only() {
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
