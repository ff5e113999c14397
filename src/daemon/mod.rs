//! imulogd: the acquisition daemon.
//!
//! - [`args`]: the `imulogd` command line.
//! - [`config`]: the TOML configuration, validated with key paths and hints.
//! - [`device`]: one tokio task per device (open, read, timestamp, decode, gaps, retry).
//! - [`writer`]: the blocking writer thread behind a bounded, never-blocking queue.
//! - [`cadence`]: the grid on which device tasks hand batches to the writer, and it flushes.
//! - [`sink`]: the [`sink::RecordSink`] the writer writes to (session store or memory).
//! - [`source`]: device links through the drivers' transports ([`source::Connector`], bytes or
//!   CAN frames) and the drivers' codecs behind [`source::FrameDecoder`].
//! - [`capture`]: captures (raw bytes, candump logs, a session's raw record) played back as a
//!   device.
//! - [`clock`], [`mapping`]: arrival stamps and frames to rows (crate `imulab-ingest`, shared
//!   with the simulator).
//! - [`pathwatch`]: inotify on a device path, so a returning device is reopened at once.
//! - [`timerel`]: the GNSS-time ↔ host-time relation.
//! - [`status`]: live counters and the status file.
//! - [`run`]: signals, systemd notification, start and clean stop.
//! - [`errors`], [`logging`]: how both binaries print an error and set up logging.

pub mod args;
pub mod backoff;
pub mod cadence;
pub mod capture;
pub use imulab_ingest::clock;
pub mod config;
pub mod device;
pub mod disk;
pub mod errors;
pub mod gap;
pub mod logging;
pub use imulab_ingest::mapping;
pub mod pathwatch;
pub mod run;
pub mod session;
pub mod sink;
pub mod source;
pub mod status;
pub mod timerel;
pub mod watchdog;
pub mod writer;

pub use config::{CheckedConfig, ConfigError};
pub use run::{run, DaemonParts, Outcome};
