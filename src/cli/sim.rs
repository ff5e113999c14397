//! `imulab sim`: runs a scene file through the simulator, optionally writing a session
//! (`-o`, the daemon's HDF5 format plus `/truth`), and reports what it produced.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;

use crate::sim::gnss_model::GNSS_PRESETS;
use crate::sim::outputs::{SessionSink, SummarySink, Tee};
use crate::sim::presets::IMU_PRESETS;
use crate::sim::runner::run as run_scene;
use crate::sim::scene::Scene;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example: imulab sim fixtures/scenes/chamber_6h.toml -o /data/sim-chamber --seed 7"
)]
pub struct SimArgs {
    /// The scene file (TOML; see docs/simulator.md).
    #[arg(required_unless_present = "list_presets")]
    pub scene: Option<PathBuf>,
    /// Write the session into this directory (must not exist or be empty).
    #[arg(short = 'o', long = "output")]
    pub output: Option<PathBuf>,
    /// Override the scene's seed.
    #[arg(long, value_parser = clap::value_parser!(u64).range(0..=i64::MAX as u64))]
    pub seed: Option<u64>,
    /// List the IMU and GNSS presets with their sources, and exit.
    #[arg(long)]
    pub list_presets: bool,
}

pub fn run(args: SimArgs) -> Result<()> {
    if args.list_presets {
        println!("IMU presets:");
        for p in IMU_PRESETS {
            println!("  {:<12} {}", p.name, p.source);
        }
        println!("GNSS presets:");
        for (name, source) in GNSS_PRESETS {
            println!("  {name:<12} {source}");
        }
        return Ok(());
    }
    let Some(path) = args.scene else {
        anyhow::bail!("a scene file is required");
    };
    let mut scene = Scene::load(&path)?;
    if let Some(seed) = args.seed {
        scene.set_seed(seed);
    }
    let mut sink = SummarySink::default();
    let started = Instant::now();
    let stats = match &args.output {
        None => run_scene(&scene, &mut sink)?,
        Some(dir) => {
            let mut session = SessionSink::create(dir, &scene)?;
            let stats = run_scene(&scene, &mut Tee(&mut session, &mut sink))?;
            let dir = session.close()?;
            println!("session written to {}", dir.display());
            stats
        }
    };
    let secs = started.elapsed().as_secs_f64();
    println!(
        "{}: {} samples at {} Hz ({} s simulated) in {secs:.3} s, seed {}",
        path.display(),
        stats.samples,
        scene.rate_hz,
        scene.duration_s,
        scene.seed
    );
    for (name, m) in &sink.imu {
        let sd = m.std();
        println!(
            "  imu {name}: {} records; mean gyro [{:.3e} {:.3e} {:.3e}] rad/s, accel [{:.4} {:.4} {:.4}] m/s²; std gyro [{:.2e} {:.2e} {:.2e}], accel [{:.2e} {:.2e} {:.2e}]",
            m.count, m.mean[0], m.mean[1], m.mean[2], m.mean[3], m.mean[4], m.mean[5],
            sd[0], sd[1], sd[2], sd[3], sd[4], sd[5]
        );
    }
    for (name, (fix, nofix)) in &sink.gnss {
        println!("  gnss {name}: {fix} fixes, {nofix} epochs without fix");
    }
    println!(
        "  truth: {} nav rows, {} imu rows",
        sink.truth_nav_rows, sink.truth_imu_rows
    );
    Ok(())
}
