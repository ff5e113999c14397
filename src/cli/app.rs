//! The `imulab` command line as a library item: the clap definition of every subcommand and
//! the dispatch to `imulab::cli::<name>::run`. The binary (`src/bin/imulab.rs`) only parses
//! and prints errors; `imulab completions`/`imulab man` and the tests walk this tree.

use clap::{CommandFactory, Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "imulab",
    version,
    about = "Bench characterisation of inertial sensors",
    after_help = "Example: imulab inspect /data/chamber   (see `imulab help COMMAND` for each command)"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// Summarise a session: devices, counts, rates, gaps, events, files.
    Inspect(super::inspect::InspectArgs),
    /// Export one device's rows (CSV), streamed.
    Export(super::export::ExportArgs),
    /// Write a ROS bag or MCAP file (IMU, GNSS fix, temperature, velocity topics) as a session.
    Import(super::import::ImportArgs),
    /// Make the partial chunk file of a killed writer readable.
    Recover(super::recover::RecoverArgs),
    /// GNSS/INS replay through the error-state Kalman filter.
    Replay(super::replay::ReplayArgs),
    /// Sensor-grade study: how long a GNSS outage each IMU grade bridges.
    Study(super::study::StudyArgs),
    /// Decode a capture file or live port to JSON lines (NMEA, UBX, … see --protocol).
    Decode(super::decode::DecodeArgs),
    /// Simulate IMUs and GNSS receivers from a scene file.
    Sim(super::sim::SimArgs),
    /// Print imulogd's status file as a table.
    Status(super::status::StatusArgs),
    /// Allan-family deviations, confidence intervals and noise-term fit of a rate series.
    Allan(super::allan::AllanArgs),
    /// Thermal-chamber characterisation: bias against temperature, hysteresis, warm-up, lag.
    Thermal(super::thermal::ThermalArgs),
    /// IMU calibration: multi-position tumble, six-position or rate table, to a calibration file.
    Calibrate(super::calibrate::CalibrateArgs),
    /// Live page of a session being recorded: data health, Allan curves, when to stop.
    Watch(super::watch::WatchArgs),
    /// Self-contained HTML noise report of one or more IMUs.
    Report(super::report::ReportArgs),
    /// Datasheet-style comparison of two or more IMUs.
    Compare(super::compare::CompareArgs),
    /// The bench workflow end to end on built-in simulated sensors.
    Demo(super::demo::DemoArgs),
    /// Shell completion script for imulab or imulogd, on stdout.
    Completions(super::completions::CompletionsArgs),
    /// Man pages of imulab, each subcommand, and imulogd, written into a directory.
    Man(super::completions::ManArgs),
}

/// The clap command tree of `imulab` (for completions, man pages and tests).
pub fn command() -> clap::Command {
    Cli::command()
}

/// Runs one parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Inspect(args) => super::inspect::run(args),
        Command::Export(args) => super::export::run(args),
        Command::Import(args) => super::import::run(args),
        Command::Recover(args) => super::recover::run(args),
        Command::Replay(args) => super::replay::run(args),
        Command::Study(args) => super::study::run(args),
        Command::Decode(args) => super::decode::run(args),
        Command::Sim(args) => super::sim::run(args),
        Command::Status(args) => super::status::run(args),
        Command::Allan(args) => super::allan::run(args),
        Command::Thermal(args) => super::thermal::run(args),
        Command::Calibrate(args) => super::calibrate::run(args),
        Command::Watch(args) => super::watch::run(args),
        Command::Report(args) => super::report::run(args),
        Command::Compare(args) => super::compare::run(args),
        Command::Demo(args) => super::demo::run(args),
        Command::Completions(args) => super::completions::run_completions(args),
        Command::Man(args) => super::completions::run_man(args),
    }
}
