//! Opening the session a daemon run writes into: the directory name from the config's
//! pattern, and the record sink backed by the session store.

use std::path::PathBuf;

use super::config::{expand_session_name, CheckedConfig};
use super::sink::RecordSink;

/// The session directory for a run starting now.
pub fn session_dir(config: &CheckedConfig, now: chrono::DateTime<chrono::Utc>) -> PathBuf {
    let host = nix::unistd::gethostname()
        .ok()
        .and_then(|h| h.into_string().ok())
        .unwrap_or_else(|| "host".to_string());
    config
        .session
        .output_dir
        .join(expand_session_name(&config.session.name, now, &host))
}

/// Creates the session in `dir` and returns the sink that writes it.
pub fn open_session_sink(
    _config: &CheckedConfig,
    dir: &std::path::Path,
) -> anyhow::Result<Box<dyn RecordSink>> {
    anyhow::bail!(
        "cannot create session {}: the HDF5 session writer (imulab::store::SessionWriter) is not \
         part of this build yet",
        dir.display()
    )
}
