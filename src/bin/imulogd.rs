//! `imulogd`: the acquisition daemon. Logs IMUs and GNSS receivers into a session as the
//! configuration file says; see `docs/daemon.md`.

use std::path::Path;
use std::process::ExitCode;

use clap::Parser;
use imulab_daemon::{self as daemon, args::Args, config, source, writer::FreeSpaceFn, DaemonParts};

/// Exit status for a configuration that is rejected.
const EXIT_BAD_CONFIG: u8 = 2;

fn main() -> ExitCode {
    daemon::logging::init_logging();
    let args = Args::parse();
    if let Some(path) = args.check_config {
        return check_config(&path);
    }
    let Some(path) = args.config else {
        return ExitCode::from(EXIT_BAD_CONFIG);
    };
    let config = match config::load(&path) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("imulogd: {e}");
            return ExitCode::from(EXIT_BAD_CONFIG);
        }
    };
    if let Err(problems) = unsupported(&config) {
        eprintln!("imulogd: {}: {problems}", path.display());
        return ExitCode::from(EXIT_BAD_CONFIG);
    }
    let host = config::check_host(&config);
    if !host.issues.is_empty() {
        eprintln!("imulogd: {}", host_error(&path, host.issues));
        return ExitCode::from(EXIT_BAD_CONFIG);
    }
    match run(&config) {
        Ok(code) => ExitCode::from(code),
        Err(e) => {
            let message = daemon::errors::render(&e);
            tracing::error!("{message}");
            eprintln!("imulogd: {message}");
            ExitCode::FAILURE
        }
    }
}

/// Devices that cannot run (e.g. a DBC file that is missing or does not hold the mapped
/// signals), as one message.
fn unsupported(config: &config::CheckedConfig) -> Result<(), String> {
    let problems: Vec<String> = config
        .devices
        .iter()
        .enumerate()
        .flat_map(|(i, d)| {
            let connector = source::connector_for(d).err();
            let decoder = source::decoder_for(d).err();
            connector
                .into_iter()
                .chain(decoder)
                .map(move |p| format!("device[{i}] ({}): {p}", d.name))
        })
        .collect();
    if problems.is_empty() {
        Ok(())
    } else {
        Err(problems.join("; "))
    }
}

/// The host check's issues as a configuration error naming the file.
fn host_error(path: &Path, issues: Vec<config::ConfigIssue>) -> config::ConfigError {
    config::ConfigError {
        source_name: path.display().to_string(),
        issues,
    }
}

fn check_config(path: &Path) -> ExitCode {
    let config = match config::load(path) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("imulogd: {e}");
            return ExitCode::from(EXIT_BAD_CONFIG);
        }
    };
    let host = config::check_host(&config);
    if !host.issues.is_empty() {
        eprintln!("imulogd: {}", host_error(path, host.issues));
        return ExitCode::from(EXIT_BAD_CONFIG);
    }
    let s = &config.session;
    // Collected and written at once, so a closed pipe (`imulogd --check-config F | head`)
    // ends the listing quietly instead of panicking in `println!`.
    let mut text = format!("{}: configuration is valid\n", path.display());
    text += &format!(
        "session: {} in {} (flush {} ms, rotate {} min / {} MB, deflate {}, raw journal {}, reserve {} MB)\n",
        s.name,
        s.output_dir.display(),
        s.flush_interval_ms,
        s.rotate_minutes,
        s.rotate_mb,
        s.deflate_level,
        if s.raw_journal { "on" } else { "off" },
        s.disk_reserve_mb
    );
    if host.output_dir_created {
        text += &format!(
            "output dir: {} does not exist and will be created\n",
            s.output_dir.display()
        );
    }
    text += &format!("status file: {}\n", config.status_path().display());
    if host.status_dir_created {
        text += "status file: its directory does not exist and will be created\n";
    }
    for d in &config.devices {
        text += &format!(
            "device {}: {} over {}, {} Hz{}\n",
            d.name,
            d.protocol.name(),
            d.transport.describe(),
            d.rate_hz,
            if d.raw_journal {
                ", raw bytes kept"
            } else {
                ""
            }
        );
        if let Some(imu) = &d.imu {
            text += &format!(
                "device {}: the UBX ESF IMU of {}, {} Hz\n",
                imu.name, d.name, imu.rate_hz
            );
        }
    }
    if let Err(e) = std::io::Write::write_all(&mut std::io::stdout().lock(), text.as_bytes()) {
        if e.kind() != std::io::ErrorKind::BrokenPipe {
            eprintln!("imulogd: cannot write to stdout: {e}");
            return ExitCode::FAILURE;
        }
    }
    match unsupported(&config) {
        Ok(()) => ExitCode::SUCCESS,
        Err(problems) => {
            eprintln!("imulogd: valid, but it cannot run: {problems}");
            ExitCode::from(EXIT_BAD_CONFIG)
        }
    }
}

fn run(config: &config::CheckedConfig) -> anyhow::Result<u8> {
    let session_dir = daemon::session::session_dir(config, chrono::Utc::now());
    // Checked before the session directory exists, so a too-full disk leaves no empty session.
    let reserve_bytes = config.session.disk_reserve_mb.saturating_mul(1 << 20);
    let free_bytes = daemon::disk::free_bytes_for_new(&session_dir).map_err(|e| {
        anyhow::anyhow!("cannot read free space for {}: {e}", session_dir.display())
    })?;
    if free_bytes < reserve_bytes {
        let message = format!(
            "not started: {free_bytes} bytes free for {} is below the disk reserve of {reserve_bytes} bytes (disk_reserve_mb = {}); no session was created",
            config.session.output_dir.display(),
            config.session.disk_reserve_mb
        );
        tracing::error!("{message}");
        eprintln!("imulogd: {message}");
        return Ok(daemon::Outcome::DiskReserve {
            free_bytes,
            reserve_bytes,
        }
        .exit_code());
    }
    let sink = Box::new(daemon::session::open_session_sink(config, &session_dir)?);
    let status_path = config.status_path();
    if let Some(status_dir) = status_path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(status_dir).map_err(|e| {
            anyhow::anyhow!(
                "cannot create the status file's directory {}: {e}",
                status_dir.display()
            )
        })?;
    }
    let mut connectors = Vec::new();
    let mut decoders = Vec::new();
    for d in &config.devices {
        connectors.push(source::connector_for(d).map_err(anyhow::Error::msg)?);
        decoders.push(source::decoder_for(d).map_err(anyhow::Error::msg)?);
    }
    let space_dir = session_dir.clone();
    let free_space: FreeSpaceFn = Box::new(move || daemon::disk::free_bytes(&space_dir));
    let parts = DaemonParts {
        sink,
        session_dir: session_dir.clone(),
        connectors,
        decoders,
        free_space,
        status_path,
    };
    // One thread for every device task: their work is a read and a decode per frame, and
    // on one thread a frame's wake-up is one epoll return, where a multi-threaded runtime
    // also wakes its other workers (measured in docs/bench/daemon.md). The writer has its
    // own thread.
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    tracing::info!("logging into {}", session_dir.display());
    // Held for the whole run: only signals stop this daemon.
    let (_stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let outcome = runtime.block_on(daemon::run(config, parts, stop_rx));
    runtime.shutdown_timeout(std::time::Duration::from_millis(100));
    match &outcome {
        daemon::Outcome::Stopped => tracing::info!("session {} closed", session_dir.display()),
        failed => {
            let message = failed.message();
            tracing::error!("{message}");
            eprintln!("imulogd: {message}");
        }
    }
    Ok(outcome.exit_code())
}
