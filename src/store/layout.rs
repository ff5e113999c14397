//! Names on disk: chunk file names and the HDF5 paths of each stream. Shared by the writer,
//! the reader and `recover`, so the layout is spelled in exactly one place.

/// Chunk files are `chunk-NNNNNN.h5`; the one being written carries this extra suffix.
pub const PARTIAL_SUFFIX: &str = ".partial";
const CHUNK_PREFIX: &str = "chunk-";
const CHUNK_EXT: &str = ".h5";

/// Final name of chunk file number `index`.
pub fn chunk_file_name(index: u32) -> String {
    format!("{CHUNK_PREFIX}{index:06}{CHUNK_EXT}")
}

/// Name of chunk file number `index` while it is being written.
pub fn partial_file_name(index: u32) -> String {
    chunk_file_name(index) + PARTIAL_SUFFIX
}

/// Name of the file `imulab recover` builds chunk file number `index` in before renaming it
/// to its final name (not a chunk file name: readers ignore it).
pub fn recovering_file_name(index: u32) -> String {
    chunk_file_name(index) + ".recovering"
}

/// Suffix of the two write-ahead journal files beside a chunk file (see `journal`), to which
/// `0` or `1` is added.
pub const JOURNAL_SUFFIX: &str = ".journal";

/// Name of journal file `gen` (0 or 1) of chunk file number `index`.
pub fn journal_file_name(index: u32, gen: u8) -> String {
    format!("{}{JOURNAL_SUFFIX}{gen}", chunk_file_name(index))
}

/// Parses a journal file name: `Some(index)` for `chunk-NNNNNN.h5.journal0` or `...1`.
pub fn parse_journal_file_name(name: &str) -> Option<u32> {
    let stem = name
        .strip_suffix(".journal0")
        .or_else(|| name.strip_suffix(".journal1"))?;
    match parse_chunk_file_name(stem) {
        Some((index, false)) => Some(index),
        _ => None,
    }
}

/// Parses a chunk file name: `Some((index, is_partial))`, or `None` for other files.
pub fn parse_chunk_file_name(name: &str) -> Option<(u32, bool)> {
    let (stem, partial) = match name.strip_suffix(PARTIAL_SUFFIX) {
        Some(s) => (s, true),
        None => (name, false),
    };
    let digits = stem.strip_prefix(CHUNK_PREFIX)?.strip_suffix(CHUNK_EXT)?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok().map(|i| (i, partial))
}

/// Replay trajectories written into a session by `imulab replay` are `replay-<name>.h5`
/// (not chunk files: the reader ignores them; `imulab inspect` lists them).
const REPLAY_PREFIX: &str = "replay-";

/// File name of the replay trajectory called `name`.
pub fn replay_file_name(name: &str) -> String {
    format!("{REPLAY_PREFIX}{name}{CHUNK_EXT}")
}

/// Parses a replay file name: `Some(name)` for `replay-<name>.h5`, `None` for other files.
pub fn parse_replay_file_name(file: &str) -> Option<&str> {
    file.strip_prefix(REPLAY_PREFIX)?
        .strip_suffix(CHUNK_EXT)
        .filter(|n| !n.is_empty())
}

/// Held (flock, exclusive) by a live writer for its lifetime, so `recover` never touches
/// the file of a writer that is still running. The kernel drops the lock when the writer dies.
pub const WRITER_LOCK_FILE: &str = "writer.lock";

pub const IMU_GROUP: &str = "imu";
pub const GNSS_GROUP: &str = "gnss";
pub const EVENTS_GROUP: &str = "events";
pub const RAW_GROUP: &str = "raw";
pub const TRUTH_GROUP: &str = "truth";
pub const TRUTH_NAV_GROUP: &str = "truth/nav";
pub const TRUTH_IMU_GROUP: &str = "truth/imu";

/// Attribute holding the layout version, on the root, every group and every dataset.
pub const ATTR_SCHEMA_VERSION: &str = "schema_version";
pub const ATTR_UNITS: &str = "units";
pub const ATTR_AXIS_FRAME: &str = "axis_frame";
pub const ATTR_DESCRIPTION: &str = "description";

/// Bytes of the raw journal per HDF5 chunk (see docs/session-format.md for why).
pub const RAW_BYTES_CHUNK: usize = 1024;
/// Rows per HDF5 chunk for events and the raw journal index.
pub const EVENT_CHUNK_ROWS: usize = 64;

pub fn imu_path(device: &str) -> String {
    format!("{IMU_GROUP}/{device}")
}
pub fn gnss_path(device: &str) -> String {
    format!("{GNSS_GROUP}/{device}")
}
pub fn raw_path(device: &str) -> String {
    format!("{RAW_GROUP}/{device}")
}
pub fn truth_imu_path(device: &str) -> String {
    format!("{TRUTH_IMU_GROUP}/{device}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunk_names_round_trip_and_reject_strangers() {
        assert_eq!(chunk_file_name(7), "chunk-000007.h5");
        assert_eq!(parse_chunk_file_name("chunk-000007.h5"), Some((7, false)));
        assert_eq!(
            parse_chunk_file_name(&partial_file_name(12)),
            Some((12, true))
        );
        for bad in [
            "chunk-.h5",
            "chunk-12a.h5",
            "chunk-1.h5.tmp",
            "session.toml",
            "x-000001.h5",
            "chunk-000001.h5.journal0",
        ] {
            assert_eq!(parse_chunk_file_name(bad), None, "{bad}");
        }
        assert_eq!(parse_journal_file_name(&journal_file_name(3, 0)), Some(3));
        assert_eq!(parse_journal_file_name(&journal_file_name(3, 1)), Some(3));
        assert_eq!(parse_journal_file_name("chunk-000003.h5.journal"), None);
        assert_eq!(
            parse_journal_file_name("chunk-000003.h5.partial.journal0"),
            None
        );
        assert_eq!(parse_journal_file_name("chunk-000003.h5"), None);
    }
}
