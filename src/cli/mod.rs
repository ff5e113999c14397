//! The `imulab` subcommands, one module each, plus the logging set-up the binaries share.

pub mod allan;
pub mod compare;
pub mod replay;
pub mod report;
pub mod status;
pub mod study;

/// Logs to stderr through `tracing`, filtered by `RUST_LOG` (default `info`).
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}

pub mod decode;
pub mod demo;
pub mod export;
pub mod inspect;
pub mod recover;
pub mod sim;
