//! The `imulab` subcommands, one module each, plus what the binaries share: the command
//! line ([`app`]), error printing ([`errors`]) and the logging set-up.

pub mod allan;
pub mod app;
pub mod calibrate;
pub mod compare;
pub mod completions;
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
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .try_init();
}

pub mod decode;
pub mod demo;
pub mod errors;
pub mod export;
pub mod import;
pub mod inspect;
pub mod recover;
pub mod sim;
pub mod thermal;
pub mod watch;
