//! `imulogd`'s command line as a library item, so `imulab man`/`imulab completions` can
//! render it and the tests can walk it; the binary (`src/bin/imulogd.rs`) parses it.

use std::path::PathBuf;

use clap::{CommandFactory, Parser};

#[derive(Parser, Debug)]
#[command(
    name = "imulogd",
    version,
    about = "Acquisition daemon: logs IMUs and GNSS receivers into HDF5 sessions",
    after_help = "Examples:\n  imulogd --check-config /etc/imulogd/imulogd.toml\n  imulogd --config /etc/imulogd/imulogd.toml\n\n\
Exit status: 0 after SIGTERM/SIGINT with the session closed, 1 on an error, 2 for a bad \
configuration, 3 when the disk reserve was reached (session closed cleanly)."
)]
pub struct Args {
    /// Run with this configuration file.
    #[arg(long, value_name = "FILE", required_unless_present = "check_config")]
    pub config: Option<PathBuf>,
    /// Check this configuration file, print what it would run, and exit.
    #[arg(long, value_name = "FILE", conflicts_with = "config")]
    pub check_config: Option<PathBuf>,
}

/// The clap command tree of `imulogd`.
pub fn command() -> clap::Command {
    Args::command()
}
