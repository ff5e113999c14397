//! `imulab sim`: runs a scene file through the simulator, optionally writing a session
//! (`-o`, the daemon's HDF5 format plus `/truth`), and reports what it produced; with
//! `--serve`, serves the scene's sensors as device byte streams on ptys instead.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;

use crate::sim::gnss_model::GNSS_PRESETS;
use crate::sim::outputs::{session_manifest, SessionSink, SimSink, SummarySink, Tee};
use crate::sim::presets::IMU_PRESETS;
use crate::sim::runner::run as run_scene;
use crate::sim::scene::Scene;
use crate::sim::serve::{Sent, ServeOptions, Server, Speed, StartWhen};

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  imulab sim fixtures/scenes/chamber_6h.toml -o /data/sim-chamber --seed 7\n  imulab sim fixtures/scenes/serve_bench.toml --serve --speed 10 --link-dir /tmp/imulab-dev --json"
)]
pub struct SimArgs {
    /// The scene file (TOML; see docs/simulator.md).
    #[arg(required_unless_present = "list_presets")]
    pub scene: Option<PathBuf>,
    /// Write the session into this directory (must not exist or be empty). With --serve:
    /// the reference session of what was sent (the rows a reader of every frame stores).
    #[arg(short = 'o', long = "output")]
    pub output: Option<PathBuf>,
    /// Override the scene's seed.
    #[arg(long, value_parser = clap::value_parser!(u64).range(0..=i64::MAX as u64))]
    pub seed: Option<u64>,
    /// List the IMU and GNSS presets with their sources, and exit.
    #[arg(long)]
    pub list_presets: bool,
    /// Serve each sensor in its device protocol on a pty (paths printed) instead of writing
    /// a session.
    #[arg(long)]
    pub serve: bool,
    /// Serving speed: a factor (1 = real time, 100 = 100x faster) or `max`.
    #[arg(long, default_value = "1", requires = "serve")]
    pub speed: Speed,
    /// Create stable symlinks DIR/<sensor> to the ptys (kept across reopen faults).
    #[arg(long, requires = "serve")]
    pub link_dir: Option<PathBuf>,
    /// Print one JSON object per endpoint (sensor, protocol, path, pty) instead of text.
    #[arg(long, requires = "serve")]
    pub json: bool,
    /// Start writing only once a reader has opened every pty.
    #[arg(long, requires = "serve")]
    pub wait_readers: bool,
    /// Seconds to keep the ptys open after the last frame, so readers can drain them.
    #[arg(long, default_value_t = 1.0, requires = "serve")]
    pub linger_s: f64,
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
    let Some(path) = args.scene.clone() else {
        anyhow::bail!("a scene file is required");
    };
    let mut scene = Scene::load(&path)?;
    if let Some(seed) = args.seed {
        scene.set_seed(seed);
    }
    if args.serve {
        return serve(scene, &args);
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

fn serve(scene: Scene, args: &SimArgs) -> Result<()> {
    use std::io::Write;
    if !(args.linger_s.is_finite() && args.linger_s >= 0.0) {
        anyhow::bail!("--linger-s must be >= 0, got {}", args.linger_s);
    }
    let options = ServeOptions {
        speed: args.speed,
        link_dir: args.link_dir.clone(),
        start: if args.wait_readers {
            StartWhen::ReadersAttached
        } else {
            StartWhen::Now
        },
        // The reference session needs every frame.
        record_sent: args.output.is_some(),
        faults: Vec::new(),
    };
    let reference = match &args.output {
        Some(dir) => Some((
            dir.clone(),
            reference_manifest(&scene, args.link_dir.as_deref())?,
        )),
        None => None,
    };
    let mut server = Server::start(scene, options)?;
    let mut out = std::io::stdout().lock();
    for e in server.endpoints() {
        if args.json {
            let line = serde_json::json!({
                "sensor": e.sensor,
                "protocol": e.protocol.name(),
                "path": e.path(),
                "pty": e.pty,
            });
            writeln!(out, "{line}")?;
        } else {
            writeln!(
                out,
                "{} ({}): {}{}",
                e.sensor,
                e.protocol.name(),
                e.path().display(),
                if e.link.is_some() {
                    format!(" -> {}", e.pty.display())
                } else {
                    String::new()
                }
            )?;
        }
    }
    out.flush()?;
    drop(out);
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let interrupted = runtime.block_on(async {
        loop {
            tokio::select! {
                _ = tokio::signal::ctrl_c() => return true,
                _ = tokio::time::sleep(std::time::Duration::from_millis(50)) => {
                    if server.is_finished() {
                        return false;
                    }
                }
            }
        }
    });
    if interrupted {
        server.stop();
    }
    let report = server.finish()?;
    for s in &report.streams {
        eprintln!(
            "{} ({}): {} frames, {} bytes, {} garbage bytes, {} unplugged, {} overflowed, {} encode errors{}",
            s.sensor,
            s.protocol.name(),
            s.frames,
            s.bytes,
            s.garbage_bytes,
            s.frames_unplugged,
            s.frames_overflowed,
            s.encode_errors,
            s.first_encode_error
                .as_ref()
                .map(|e| format!(" (first: {e})"))
                .unwrap_or_default()
        );
    }
    eprintln!(
        "served {:.3} s of scene in {:.3} s{}",
        report.scene_end_s,
        report.elapsed.as_secs_f64(),
        if report.stopped { " (interrupted)" } else { "" }
    );
    if let Some((dir, manifest)) = reference {
        let mut session = SessionSink::with_manifest(&dir, manifest)?;
        for s in &report.streams {
            match s.sent {
                Sent::Imu(_) => session.imu(&s.sensor, &s.expected_imu_rows())?,
                Sent::Gnss(_) => session.gnss(&s.sensor, &s.expected_gnss_rows())?,
            }
        }
        let dir = session.close()?;
        eprintln!("reference session of what was sent: {}", dir.display());
    }
    if !interrupted {
        std::thread::sleep(std::time::Duration::from_secs_f64(args.linger_s));
    }
    Ok(())
}

/// The manifest of the reference session of a serve: the simulated session's, with each
/// device's protocol and port as served.
fn reference_manifest(
    scene: &Scene,
    link_dir: Option<&std::path::Path>,
) -> Result<crate::store::Manifest> {
    let mut manifest = session_manifest(scene)?;
    let protocols = scene
        .imus
        .iter()
        .map(|i| (i.name.as_str(), i.protocol))
        .chain(scene.gnss.iter().map(|g| (g.name.as_str(), g.protocol)));
    for (name, protocol) in protocols {
        if let Some(d) = manifest.devices.iter_mut().find(|d| d.name == name) {
            d.protocol = protocol.name().into();
            d.port = match link_dir {
                Some(dir) => dir.join(name).display().to_string(),
                None => "pty".into(),
            };
        }
    }
    manifest.id = format!("{}-served", manifest.id);
    // A serve simulates no truth.
    manifest.truth_nav_rate_hz = None;
    Ok(manifest)
}
