//! The session store: a session is a directory holding `session.toml` (the manifest) and
//! numbered HDF5 chunk files. See `docs/session-format.md` for the public layout.

pub mod records;

pub use records::{EventKind, EventRecord, GnssRecord, ImuRecord, TruthImuRecord, TruthNavRecord};
