//! `imulab`: the offline analyser. The command line lives in `imulab::cli::app`, each
//! subcommand in `imulab::cli::<name>`.

use clap::Parser;

fn main() -> std::process::ExitCode {
    restore_default_sigpipe();
    imulab::cli::init_logging();
    let cli = imulab::cli::app::Cli::parse();
    match imulab::cli::app::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("imulab: {}", imulab::cli::errors::render(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// `imulab inspect SESSION | head` must end quietly, as Unix tools do, not panic in `println!`:
/// Rust ignores SIGPIPE by default, so a closed stdout would be an error on every write. The
/// analyser writes to no socket or pipe it must survive losing (ptys report a hang-up as EIO).
fn restore_default_sigpipe() {
    use nix::sys::signal::{signal, SigHandler, Signal};
    // SAFETY: called first thing in main, before any thread exists; SIG_DFL installs no handler.
    let _ = unsafe { signal(Signal::SIGPIPE, SigHandler::SigDfl) };
}
