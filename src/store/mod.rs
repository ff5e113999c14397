//! The session store: a session is a directory holding `session.toml` (the manifest) and
//! numbered HDF5 chunk files. See `docs/session-format.md` for the public layout.
//!
//! - [`manifest`]: `session.toml` (what was recorded, with which devices and config).
//! - [`writer`]: [`SessionWriter`], rotating SWMR chunk files with crash-safe flushing.
//! - `chunkfile`: the chunk file being written, its tables and its journal.
//! - [`reader`]: [`Session`], the only way analyses read data: time-ordered blocks per device.
//! - `journal`: the write-ahead journal beside the chunk file being written.
//! - [`recover`]: makes the `*.partial` chunk of a killed writer readable and final.

mod chunkfile;
mod chunkio;
mod columns;
mod error;
mod journal;
pub mod layout;
pub mod manifest;
pub mod reader;
pub mod records;
pub mod recover;
pub mod writer;

pub use error::StoreError;
pub use manifest::{DeviceInfo, DeviceKind, Manifest};
pub use reader::{
    fix_type_from_code, ChunkFileInfo, GnssBlock, ImuBlock, ImuColumnReader, ImuColumnSet,
    ImuColumns, RawBlock, Session, StreamSummary, TimeRange, TruthImuBlock, TruthNavBlock,
};
pub use records::{EventKind, EventRecord, GnssRecord, ImuRecord, TruthImuRecord, TruthNavRecord};
pub use recover::{recover, RecoverReport};
pub use writer::{SessionWriter, WriterOptions};

/// Version of the HDF5 chunk file layout this build writes and reads. Bumped on any change a
/// reader must know about; readers refuse files with a version they do not know.
pub const SCHEMA_VERSION: u32 = 1;

/// Version of the session directory (`schema_version` in `session.toml`) this build writes.
/// 2 added the write-ahead journal beside the partial chunk file (docs/session-format.md):
/// the chunk files are unchanged, but a build that reads only version 1 would recover a
/// killed session without the journal's rows, so it must refuse version 2. Version 1
/// sessions (no journal) are still read and recovered.
pub const SESSION_SCHEMA_VERSION: u32 = 2;
/// Oldest session directory version this build reads.
pub const OLDEST_SESSION_SCHEMA_VERSION: u32 = 1;
