//! `imulab recover SESSION`: makes the `*.partial` chunk file of a killed or crashed writer
//! readable (clears the SWMR superblock flag, trims unwritten rows, adds the journal's rows,
//! rebuilds it from the journal when it is beyond repair) and gives it its final name.

use std::path::PathBuf;

use crate::store::recover;

#[derive(clap::Args, Debug)]
#[command(after_help = "Example: imulab recover runs/2026-11-23-chamber")]
pub struct RecoverArgs {
    /// Session directory.
    pub session: PathBuf,
}

pub fn run(args: RecoverArgs) -> anyhow::Result<()> {
    let report = recover(&args.session)?;
    if report.files.is_empty() {
        println!("{}: nothing to recover", args.session.display());
    }
    for f in &report.files {
        println!(
            "{} -> {}{}",
            f.from.display(),
            f.to.display(),
            if f.superblock_flags_cleared {
                " (superblock flags cleared)"
            } else {
                ""
            }
        );
        if let Some(why) = &f.rebuilt {
            println!("  rebuilt from the journal: the HDF5 file was beyond repair ({why})");
        }
        if f.journal_bytes_dropped > 0 {
            println!(
                "  journal: dropped a torn tail of {} bytes",
                f.journal_bytes_dropped
            );
        }
        for t in &f.tables {
            println!(
                "  /{:<24} saved {:>9} rows ({} from the journal), lost {}",
                t.group, t.rows_kept, t.rows_from_journal, t.rows_dropped
            );
        }
    }
    Ok(())
}
