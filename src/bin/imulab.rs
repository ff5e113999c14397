//! `imulab`: the offline analyser. Each subcommand lives in `imulab::cli::<name>`.

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "imulab",
    version,
    about = "Bench characterisation of inertial sensors"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Summarise a session: devices, counts, rates, gaps, events, files.
    Inspect(imulab::cli::inspect::InspectArgs),
    /// Export one device's rows (CSV), streamed.
    Export(imulab::cli::export::ExportArgs),
    /// Make the partial chunk file of a killed writer readable.
    Recover(imulab::cli::recover::RecoverArgs),
    /// GNSS/INS replay through the error-state Kalman filter.
    Replay(imulab::cli::replay::ReplayArgs),
    /// Sensor-grade study: how long a GNSS outage each IMU grade bridges.
    Study(imulab::cli::study::StudyArgs),
    /// Decode a capture file or live port to JSON lines (NMEA, UBX, … see --protocol).
    Decode(imulab::cli::decode::DecodeArgs),
    /// Simulate IMUs and GNSS receivers from a scene file.
    Sim(imulab::cli::sim::SimArgs),
    /// Print imulogd's status file as a table.
    Status(imulab::cli::status::StatusArgs),
    /// Allan-family deviations, confidence intervals and noise-term fit of a rate series.
    Allan(imulab::cli::allan::AllanArgs),
    /// Self-contained HTML noise report of one or more IMUs.
    Report(imulab::cli::report::ReportArgs),
    /// Datasheet-style comparison of two or more IMUs.
    Compare(imulab::cli::compare::CompareArgs),
    /// The bench workflow end to end on built-in simulated sensors.
    Demo(imulab::cli::demo::DemoArgs),
}

fn main() -> std::process::ExitCode {
    restore_default_sigpipe();
    imulab::cli::init_logging();
    let cli = Cli::parse();
    let result: anyhow::Result<()> = match cli.command {
        Command::Inspect(args) => imulab::cli::inspect::run(args),
        Command::Export(args) => imulab::cli::export::run(args),
        Command::Recover(args) => imulab::cli::recover::run(args),
        Command::Replay(args) => imulab::cli::replay::run(args),
        Command::Study(args) => imulab::cli::study::run(args),
        Command::Decode(args) => imulab::cli::decode::run(args),
        Command::Sim(args) => imulab::cli::sim::run(args),
        Command::Status(args) => imulab::cli::status::run(args),
        Command::Allan(args) => imulab::cli::allan::run(args),
        Command::Report(args) => imulab::cli::report::run(args),
        Command::Compare(args) => imulab::cli::compare::run(args),
        Command::Demo(args) => imulab::cli::demo::run(args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("imulab: {e:#}");
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
