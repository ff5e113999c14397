//! `imulab completions SHELL` and `imulab man DIR`: shell completion scripts and man pages
//! generated from the clap definitions of both binaries (`imulab` in [`super::app`],
//! `imulogd` in [`crate::daemon::args`]), so they never drift from the real options.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;
use clap_complete::Shell;

/// Which program the completions are for.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Program {
    Imulab,
    Imulogd,
}

impl Program {
    fn command(self) -> clap::Command {
        match self {
            Program::Imulab => super::app::command(),
            Program::Imulogd => crate::daemon::args::command(),
        }
    }

    fn name(self) -> &'static str {
        match self {
            Program::Imulab => "imulab",
            Program::Imulogd => "imulogd",
        }
    }
}

#[derive(clap::Args, Debug)]
#[command(after_help = "Examples:\n  \
    imulab completions bash > /etc/bash_completion.d/imulab\n  \
    imulab completions bash --program imulogd > /etc/bash_completion.d/imulogd\n  \
    imulab completions zsh > ~/.zfunc/_imulab     # with fpath+=~/.zfunc in ~/.zshrc\n  \
    imulab completions fish > ~/.config/fish/completions/imulab.fish")]
pub struct CompletionsArgs {
    /// Shell to write the script for.
    #[arg(value_enum)]
    pub shell: Shell,
    /// Program the script completes.
    #[arg(long, value_enum, default_value = "imulab")]
    pub program: Program,
}

#[derive(clap::Args, Debug)]
#[command(after_help = "Example: imulab man /usr/local/share/man/man1 && man imulab-allan")]
pub struct ManArgs {
    /// Directory to write the pages into (created if missing): imulab.1, imulab-<command>.1
    /// for every subcommand, and imulogd.1.
    pub dir: PathBuf,
}

/// Writes the completion script to stdout.
pub fn run_completions(args: CompletionsArgs) -> anyhow::Result<()> {
    let mut cmd = args.program.command();
    let mut script = Vec::new();
    clap_complete::generate(args.shell, &mut cmd, args.program.name(), &mut script);
    let mut out = std::io::stdout().lock();
    out.write_all(&script)
        .and_then(|()| out.flush())
        .context("writing the completion script to stdout")
}

/// Writes one man page per (sub)command of `imulab`, plus `imulogd.1`, and lists them.
pub fn run_man(args: ManArgs) -> anyhow::Result<()> {
    let dir = &args.dir;
    if dir.exists() && !dir.is_dir() {
        anyhow::bail!(
            "{}: is a file, not a directory; give a directory for the man pages",
            dir.display()
        );
    }
    std::fs::create_dir_all(dir)
        .with_context(|| format!("{}: cannot create the directory", dir.display()))?;
    clap_mangen::generate_to(super::app::command(), dir)
        .with_context(|| format!("{}: cannot write the imulab man pages", dir.display()))?;
    clap_mangen::Man::new(crate::daemon::args::command())
        .generate_to(dir)
        .with_context(|| format!("{}: cannot write the imulogd man page", dir.display()))?;
    let mut pages: Vec<String> = std::fs::read_dir(dir)
        .with_context(|| format!("{}: cannot list the directory", dir.display()))?
        .filter_map(|e| e.ok())
        .filter_map(|e| e.file_name().into_string().ok())
        .filter(|n| n.starts_with("imulab") || n.starts_with("imulogd"))
        .collect();
    pages.sort();
    println!(
        "{} man pages in {}: {}",
        pages.len(),
        dir.display(),
        pages.join(" ")
    );
    Ok(())
}
