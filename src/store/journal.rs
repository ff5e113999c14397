//! The write-ahead journal of a chunk file being written: `chunk-NNNNNN.h5.journal0` and
//! `...journal1` (used in turn, see [`Journal`]), beside `chunk-NNNNNN.h5.partial`.
//!
//! Why: HDF5 chunks of one flush interval (1 s) were many and tiny (a 10 Hz GNSS column:
//! 80 bytes), and each one cost HDF5 metadata, a compressor reset and a write (measured,
//! docs/bench/store.md). The writer now makes chunks of one *chunk interval* (default 10 s)
//! and keeps the crash-safety promise (at most one flush interval lost) with this journal:
//! every flush interval the rows received since the last journal write are appended here
//! (and `fdatasync`ed when fsync is on); once chunks are complete they go to the HDF5 file,
//! which is flushed, and the writer switches to its other journal file, which gets only the
//! rows still not in the HDF5 file. `imulab recover` appends the journal's rows beyond those the HDF5 file
//! holds. Hand-written because the format is a few lines and no crate writes it.
//!
//! The file is a sequence of records, all integers little-endian:
//!
//! | field | bytes |
//! |---|---|
//! | magic `IMLJ` | 4 |
//! | version (2; 1 is read too) | 1 |
//! | length of the table id | 1 |
//! | table id, UTF-8 (`imu/imu0`, `gnss/gps`, `events`, `raw/x`, `raw/x/bytes`, ...) | n |
//! | index of the first row in the table (for `raw/x/bytes`: of the first byte) | 8 |
//! | rows (bytes) in the record | 4 |
//! | payload length in bytes | 4 |
//! | payload: the rows, row after row, each field little-endian (see `columns::Row`) | len |
//! | CRC-32 (zlib's) of everything above | 4 |
//!
//! A reader stops at the first record that is cut short, has a bad magic or version, or a
//! bad CRC: that is the tail a crash tore, and it is dropped.
//!
//! Version 2 rows of a GNSS table end with `heading_deg`; version 1 rows (written before that
//! column) do not, and read back with a NaN heading. Other tables are the same in both.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

use super::layout;
use super::manifest::fsync_dir;
use super::StoreError;

const MAGIC: [u8; 4] = *b"IMLJ";
const VERSION: u8 = 2;
/// The oldest record version read.
const OLDEST_VERSION: u8 = 1;
/// Bytes of a record before its table id, and after the id before the payload.
const HEAD: usize = 4 + 1 + 1;
const MID: usize = 8 + 4 + 4;

/// Paths of the two journal files of chunk file number `index` (see [`Journal`]).
pub(crate) fn journal_paths(dir: &Path, index: u32) -> [PathBuf; 2] {
    [0, 1].map(|g| dir.join(layout::journal_file_name(index, g)))
}

/// Appends one record for `count` rows of table `id`, starting at row `first`, whose
/// encoded rows are `payload`, to `out`.
pub(crate) fn put_record(out: &mut Vec<u8>, id: &str, first: u64, count: u32, payload: &[u8]) {
    let start = out.len();
    let id = &id.as_bytes()[..id.len().min(255)];
    out.extend_from_slice(&MAGIC);
    out.push(VERSION);
    out.push(id.len() as u8);
    out.extend_from_slice(id);
    out.extend_from_slice(&first.to_le_bytes());
    out.extend_from_slice(&count.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(payload);
    let crc = zlib_rs::crc32::crc32(0, &out[start..]);
    out.extend_from_slice(&crc.to_le_bytes());
}

/// One record read back.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Record {
    pub id: String,
    /// The record's format version (see the module doc).
    pub version: u8,
    pub first: u64,
    pub count: u32,
    pub payload: Vec<u8>,
}

/// The records of a journal, and how many bytes at its end were dropped as torn or corrupt.
#[derive(Debug, Default)]
pub(crate) struct Contents {
    pub records: Vec<Record>,
    pub dropped_bytes: u64,
}

/// Parses journal bytes: every record up to the first torn or corrupt one.
pub(crate) fn parse(bytes: &[u8]) -> Contents {
    let mut records = Vec::new();
    let mut at = 0;
    while let Some((rec, len)) = parse_one(&bytes[at..]) {
        records.push(rec);
        at += len;
    }
    Contents {
        records,
        dropped_bytes: (bytes.len() - at) as u64,
    }
}

fn parse_one(b: &[u8]) -> Option<(Record, usize)> {
    if b.len() < HEAD || b[..4] != MAGIC || !(OLDEST_VERSION..=VERSION).contains(&b[4]) {
        return None;
    }
    let id_len = usize::from(b[5]);
    let mid = HEAD + id_len;
    let m = b.get(mid..mid + MID)?;
    let first = u64::from_le_bytes(m[0..8].try_into().ok()?);
    let count = u32::from_le_bytes(m[8..12].try_into().ok()?);
    let len = u32::from_le_bytes(m[12..16].try_into().ok()?) as usize;
    let body_end = (mid + MID).checked_add(len)?;
    let crc = u32::from_le_bytes(b.get(body_end..body_end + 4)?.try_into().ok()?);
    if zlib_rs::crc32::crc32(0, &b[..body_end]) != crc {
        return None;
    }
    let id = std::str::from_utf8(&b[HEAD..mid]).ok()?.to_string();
    Some((
        Record {
            id,
            version: b[4],
            first,
            count,
            payload: b[mid + MID..body_end].to_vec(),
        },
        body_end + 4,
    ))
}

/// Reads and parses the journal files at `paths` (missing ones count as empty): all their
/// records, and the torn or corrupt tail bytes dropped from each.
pub(crate) fn read(paths: &[PathBuf]) -> Result<Contents, StoreError> {
    let mut all = Contents::default();
    for path in paths {
        match std::fs::read(path) {
            Ok(bytes) => {
                let c = parse(&bytes);
                all.records.extend(c.records);
                all.dropped_bytes += c.dropped_bytes;
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(StoreError::io(path, e)),
        }
    }
    Ok(all)
}

/// The writer's side. Two files are used in turn: records are appended to the current one;
/// once the rows are in the HDF5 file, the rows still pending are written to the other one
/// (emptied first), made durable when asked, and it becomes the current one. A crash at
/// any point leaves every row in one of them (or the HDF5 file); `recover` reads both and
/// skips rows the HDF5 file holds. Measured: replacing one file by a rename instead cost
/// 11 % of the writer's CPU, because ext4 writes a file renamed over another out at once
/// (`auto_da_alloc`). Files are created at their first use.
pub(crate) struct Journal {
    paths: [PathBuf; 2],
    files: [Option<File>; 2],
    current: usize,
}

impl Journal {
    pub fn new(paths: [PathBuf; 2]) -> Self {
        Journal {
            paths,
            files: [None, None],
            current: 0,
        }
    }

    /// The open file number `i`, created (and its directory entry made durable when
    /// `fsync`) at first use.
    fn file(&mut self, i: usize, fsync: bool) -> Result<&mut File, StoreError> {
        let path = &self.paths[i];
        if self.files[i].is_none() {
            let f = File::options()
                .create(true)
                .append(true)
                .open(path)
                .map_err(|e| StoreError::io(path, e))?;
            if fsync {
                if let Some(dir) = path.parent() {
                    fsync_dir(dir)?;
                }
            }
            self.files[i] = Some(f);
        }
        self.files[i]
            .as_mut()
            .ok_or_else(|| StoreError::Invalid("journal file not open".into()))
    }

    /// Appends `records` (made by [`put_record`]) and, when `fsync`, makes them durable.
    pub fn append(&mut self, records: &[u8], fsync: bool) -> Result<(), StoreError> {
        if records.is_empty() {
            return Ok(());
        }
        let i = self.current;
        let path = self.paths[i].clone();
        let file = self.file(i, fsync)?;
        file.write_all(records)
            .map_err(|e| StoreError::io(&path, e))?;
        if fsync {
            file.sync_data().map_err(|e| StoreError::io(&path, e))?;
        }
        Ok(())
    }

    /// Starts the other file with only `records` (rows not yet in the HDF5 file, which has
    /// been flushed) and makes it the current one.
    pub fn replace(&mut self, records: &[u8], fsync: bool) -> Result<(), StoreError> {
        let other = 1 - self.current;
        if records.is_empty() && self.files[other].is_none() {
            // Nothing pending and nothing stale there: an empty, absent file will do.
            self.truncate_current_if_all_written(fsync)?;
            return Ok(());
        }
        let path = self.paths[other].clone();
        let file = self.file(other, fsync)?;
        file.set_len(0).map_err(|e| StoreError::io(&path, e))?;
        file.write_all(records)
            .map_err(|e| StoreError::io(&path, e))?;
        if fsync {
            file.sync_data().map_err(|e| StoreError::io(&path, e))?;
        }
        self.current = other;
        Ok(())
    }

    /// With nothing pending, the current file's rows are all in the HDF5 file: starting the
    /// other (absent) file would also do, but emptying the current one keeps one file.
    fn truncate_current_if_all_written(&mut self, fsync: bool) -> Result<(), StoreError> {
        let i = self.current;
        let path = self.paths[i].clone();
        if let Some(f) = self.files[i].as_mut() {
            f.set_len(0).map_err(|e| StoreError::io(&path, e))?;
            if fsync {
                f.sync_data().map_err(|e| StoreError::io(&path, e))?;
            }
        }
        Ok(())
    }

    /// Removes both files (their chunk file is complete and renamed).
    pub fn remove(mut self) -> Result<(), StoreError> {
        self.files = [None, None];
        for path in &self.paths {
            match std::fs::remove_file(path) {
                Ok(()) => {}
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => return Err(StoreError::io(path, e)),
            }
        }
        Ok(())
    }
}

/// Little-endian field reader over a record's payload, for `columns::Row::decode`.
pub(crate) struct Cursor<'a> {
    pub bytes: &'a [u8],
    /// The record's format version: what fields its rows have.
    pub version: u8,
}

impl<'a> Cursor<'a> {
    pub fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        if self.bytes.len() < n {
            return Err(format!(
                "row data ends early ({} bytes left, {n} needed)",
                self.bytes.len()
            ));
        }
        let (head, rest) = self.bytes.split_at(n);
        self.bytes = rest;
        Ok(head)
    }
    pub fn array<const N: usize>(&mut self) -> Result<[u8; N], String> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }
    pub fn i64(&mut self) -> Result<i64, String> {
        Ok(i64::from_le_bytes(self.array()?))
    }
    pub fn u64(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.array()?))
    }
    pub fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_le_bytes(self.array()?))
    }
    pub fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.array()?))
    }
    pub fn u16(&mut self) -> Result<u16, String> {
        Ok(u16::from_le_bytes(self.array()?))
    }
    pub fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1)?[0])
    }
    pub fn f64s<const W: usize>(&mut self) -> Result<[f64; W], String> {
        let mut a = [0.0; W];
        for v in &mut a {
            *v = self.f64()?;
        }
        Ok(a)
    }
    /// A string stored as a u16 length and its bytes.
    pub fn str(&mut self) -> Result<&'a str, String> {
        let n = usize::from(self.u16()?);
        std::str::from_utf8(self.take(n)?).map_err(|e| format!("string field: {e}"))
    }
}

/// Writes a string as a u16 length and its bytes (the reader of [`Cursor::str`]).
pub(crate) fn put_str(out: &mut Vec<u8>, s: &str) {
    let b = &s.as_bytes()[..s.len().min(usize::from(u16::MAX))];
    out.extend_from_slice(&(b.len() as u16).to_le_bytes());
    out.extend_from_slice(b);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Vec<u8> {
        let mut out = Vec::new();
        put_record(&mut out, "imu/a", 0, 2, &[1, 2, 3, 4]);
        put_record(&mut out, "gnss/g", 7, 1, &[9; 20]);
        put_record(&mut out, "imu/a", 2, 1, &[5, 6]);
        out
    }

    #[test]
    fn records_round_trip() {
        let c = parse(&sample());
        assert_eq!(c.dropped_bytes, 0);
        assert_eq!(c.records.len(), 3);
        assert_eq!(c.records[1].id, "gnss/g");
        assert_eq!(c.records[1].first, 7);
        assert_eq!(c.records[1].count, 1);
        assert_eq!(c.records[1].payload, vec![9; 20]);
        assert_eq!(c.records[2].payload, vec![5, 6]);
    }

    /// Every cut of the last record, and every flipped byte in it, drops exactly that record.
    #[test]
    fn torn_or_corrupt_tail_is_dropped() {
        let all = sample();
        let two = {
            let mut out = Vec::new();
            put_record(&mut out, "imu/a", 0, 2, &[1, 2, 3, 4]);
            put_record(&mut out, "gnss/g", 7, 1, &[9; 20]);
            out.len()
        };
        for cut in two..all.len() {
            let c = parse(&all[..cut]);
            assert_eq!(c.records.len(), 2, "cut at {cut}");
            assert_eq!(c.dropped_bytes, (cut - two) as u64);
        }
        for i in two..all.len() {
            let mut bad = all.clone();
            bad[i] ^= 0x40;
            let c = parse(&bad);
            assert_eq!(c.records.len(), 2, "flipped byte {i}");
        }
    }

    #[test]
    fn replace_switches_files_and_both_are_read() {
        let dir = tempfile::tempdir().expect("tempdir");
        let paths = journal_paths(dir.path(), 4);
        let mut j = Journal::new(paths.clone());
        j.append(&sample(), true).expect("append");
        assert_eq!(read(&paths).expect("read").records.len(), 3);
        let mut one = Vec::new();
        put_record(&mut one, "imu/a", 3, 1, &[1]);
        j.replace(&one, true).expect("replace");
        j.append(&one, false).expect("append after replace");
        // The old file still holds its (now stale) records; the new one the pending rows.
        assert_eq!(
            parse(&std::fs::read(&paths[1]).expect("new")).records.len(),
            2
        );
        assert_eq!(read(&paths).expect("read").records.len(), 5);
        // The next switch empties the old file first.
        j.replace(&[], false).expect("empty");
        assert_eq!(std::fs::read(&paths[0]).expect("old").len(), 0);
        j.append(&one, false).expect("append");
        assert_eq!(read(&paths).expect("read").records.len(), 3);
        j.remove().expect("remove");
        assert!(paths.iter().all(|p| !p.exists()));
    }
}
