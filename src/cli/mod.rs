//! The `imulab` subcommands, one module each, plus the command line ([`app`]). Error printing
//! ([`errors`]) and the logging set-up are the daemon crate's, which both binaries share.

pub mod allan;
pub mod app;
pub mod calibrate;
pub mod compare;
pub mod completions;
pub mod replay;
pub mod report;
pub mod status;
pub mod study;

pub use imulab_daemon::logging::init_logging;

pub mod decode;
pub mod demo;
pub use imulab_daemon::errors;
pub mod export;
pub mod import;
pub mod inspect;
pub mod recover;
pub mod sim;
pub mod thermal;
pub mod watch;
