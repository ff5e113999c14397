//! A daemon built from its configuration the way `imulogd` builds it (the drivers'
//! transports through `connector_for`, the drivers' codecs through `decoder_for`), and the
//! status-file check that it has every pty open. Shared by the pty tests (`serial.rs`,
//! `end_to_end.rs`), the binary tests and the load benchmark.

use std::path::{Path, PathBuf};

use imulab::daemon::config::CheckedConfig;
use imulab::daemon::sink::RecordSink;
use imulab::daemon::source::{connector_for, decoder_for};
use imulab::daemon::status::{read_status_file, DeviceState, StatusReport};
use imulab::daemon::DaemonParts;

/// The daemon's parts for `config`, writing into `sink`, with unlimited free space.
pub fn parts_for(
    config: &CheckedConfig,
    sink: Box<dyn RecordSink>,
    session_dir: PathBuf,
) -> DaemonParts {
    DaemonParts {
        sink,
        session_dir,
        connectors: config
            .devices
            .iter()
            .map(|d| connector_for(d).unwrap_or_else(|e| panic!("{}: {e}", d.name)))
            .collect(),
        decoders: config
            .devices
            .iter()
            .map(|d| decoder_for(d).unwrap_or_else(|e| panic!("{}: {e}", d.name)))
            .collect(),
        free_space: Box::new(|| Ok(u64::MAX / 2)),
        status_path: config.status_path(),
    }
}

/// The status report, once the status file lists `devices` devices, all connected.
pub fn connected_report(status_path: &Path, devices: usize) -> Option<StatusReport> {
    read_status_file(status_path).ok().filter(|s| {
        s.devices.len() == devices && s.devices.iter().all(|d| d.state == DeviceState::Connected)
    })
}
