//! The one error type of the store: every variant names the file (or device) and the problem.

use std::path::PathBuf;

/// What went wrong in the store, always with the file or device it concerns.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: HDF5 error while {what}: {source}", path.display())]
    Hdf5 {
        path: PathBuf,
        what: String,
        #[source]
        source: hdf5::Error,
    },
    #[error("{}: bad manifest: {msg}", path.display())]
    Manifest { path: PathBuf, msg: String },
    #[error("{}: not a session directory: {msg}", path.display())]
    NotASession { path: PathBuf, msg: String },
    #[error("{}: unknown schema version {found} (this build reads version {supported})", path.display())]
    UnknownSchema {
        path: PathBuf,
        found: u32,
        supported: u32,
    },
    #[error("{}: corrupt chunk file: {msg}", path.display())]
    Corrupt { path: PathBuf, msg: String },
    #[error("unknown device {device:?}: {msg}")]
    UnknownDevice { device: String, msg: String },
    #[error("invalid input: {0}")]
    Invalid(String),
}

impl StoreError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        StoreError::Io {
            path: path.into(),
            source,
        }
    }

    pub(crate) fn h5(
        path: impl Into<PathBuf>,
        what: impl Into<String>,
        source: hdf5::Error,
    ) -> Self {
        StoreError::Hdf5 {
            path: path.into(),
            what: what.into(),
            source,
        }
    }
}
