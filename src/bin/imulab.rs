//! `imulab`: the offline analyser. Each subcommand lives in `imulab::cli::<name>`.

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "imulab", version, about = "Bench characterisation of inertial sensors")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Allan-family deviations, confidence intervals and noise-term fit of a rate series.
    Allan(imulab::cli::allan::AllanArgs),
}

fn main() -> std::process::ExitCode {
    imulab::cli::init_logging();
    let cli = Cli::parse();
    let result: anyhow::Result<()> = match cli.command {
        Command::Allan(args) => imulab::cli::allan::run(args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("imulab: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
