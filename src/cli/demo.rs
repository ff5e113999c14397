//! `imulab demo`: the bench workflow end to end on built-in simulated sensors, no hardware.
//!
//! This slice runs: simulate the motivating bench study (a ~25 EUR IMU and one ten times
//! dearer, static in a 25 °C chamber at 150 Hz) into a session, inspect it, and write the Allan
//! report comparing the two IMUs. Logging through `imulogd` over ptys and the fusion study join
//! it as the simulator's `--serve` and `imulab study` land.

use crate::allan::analysis::AllanReport;
use crate::allan::report::html_report;
use crate::allan::units::TermInUnits;
use anyhow::Context;
use clap::Parser;
use std::path::{Path, PathBuf};

/// The built-in chamber scene; `--minutes` replaces its duration.
const CHAMBER_SCENE: &str = include_str!("../../fixtures/scenes/chamber_6h.toml");

#[derive(clap::Args, Debug)]
#[command(after_help = "Example: imulab demo --minutes 360 --out /tmp/imulab-demo")]
pub struct DemoArgs {
    /// Length of the simulated chamber run, minutes (360 reproduces the full six-hour run).
    #[arg(long, default_value_t = 20.0)]
    pub minutes: f64,
    /// Output directory (created; must not hold a previous demo's session).
    #[arg(long, default_value = "imulab-demo")]
    pub out: PathBuf,
    /// Seed of the simulated sensors.
    #[arg(long)]
    pub seed: Option<u64>,
}

/// Parses one subcommand's arguments exactly as the command line would.
#[derive(Parser)]
struct Sub<T: clap::Args> {
    #[command(flatten)]
    args: T,
}

fn sub_args<T: clap::Args>(argv: &[&str]) -> anyhow::Result<T> {
    Ok(Sub::<T>::try_parse_from(std::iter::once("imulab").chain(argv.iter().copied()))?.args)
}

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    if !(args.minutes.is_finite() && args.minutes >= 1.0) {
        anyhow::bail!("--minutes must be at least 1 (the Allan curve needs some length)");
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let scene = args.out.join("chamber.toml");
    let session = args.out.join("session");
    let html = args.out.join("report.html");
    let json = args.out.join("report.json");
    if session.exists() {
        anyhow::bail!(
            "{} already holds a session: remove it or give another --out",
            session.display()
        );
    }
    write_scene(&scene, args.minutes * 60.0)?;
    let (scene_s, session_s) = (path_str(&scene)?, path_str(&session)?);

    stage(1, "simulating the chamber run (two IMUs, 150 Hz, 25 °C)");
    let mut sim = vec![scene_s, "-o", session_s];
    let seed = args.seed.map(|s| s.to_string());
    if let Some(seed) = &seed {
        sim.extend(["--seed", seed.as_str()]);
    }
    super::sim::run(sub_args(&sim)?)?;

    stage(2, "inspecting the session");
    super::inspect::run(sub_args(&[session_s])?)?;

    stage(3, "Allan deviation and noise-term fit per IMU and axis");
    let mut analysis: super::allan::AnalysisArgs = sub_args(&[])?;
    analysis.fit = true;
    let report = super::allan::analyse_inputs(std::slice::from_ref(&session), &analysis)?;
    std::fs::write(
        &html,
        html_report(&report, "imulab demo: bench IMUs in a 25 °C chamber"),
    )
    .with_context(|| format!("writing {}", html.display()))?;
    let file =
        std::fs::File::create(&json).with_context(|| format!("creating {}", json.display()))?;
    serde_json::to_writer_pretty(std::io::BufWriter::new(file), &report)?;

    println!();
    println!("session  {}", session.display());
    println!("report   {}", html.display());
    println!("json     {}", json.display());
    for line in findings(&report) {
        println!("{line}");
    }
    Ok(())
}

fn stage(n: u32, what: &str) {
    eprintln!("[{n}/3] {what}");
}

fn path_str(p: &Path) -> anyhow::Result<&str> {
    p.to_str()
        .with_context(|| format!("{}: the demo needs a UTF-8 path", p.display()))
}

fn write_scene(path: &Path, duration_s: f64) -> anyhow::Result<()> {
    let mut scene: toml::Table = CHAMBER_SCENE.parse().context("the built-in scene")?;
    scene.insert("duration_s".into(), toml::Value::Float(duration_s));
    let text = format!(
        "# The built-in bench scene of `imulab demo`, {:.0} minutes long.\n{}",
        duration_s / 60.0,
        toml::to_string(&scene)?
    );
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

/// Mean over a device's axes of the named term in `unit`, for the sensor prefix.
fn mean_term(
    report: &AllanReport,
    device: &str,
    sensor: &str,
    name: &str,
    unit: &str,
) -> Option<(f64, String)> {
    let values: Vec<(f64, String)> = report
        .axes
        .iter()
        .filter(|a| a.device == device && a.axis.starts_with(sensor))
        .filter_map(|a| {
            a.terms
                .iter()
                .find(|t: &&TermInUnits| t.name == name && t.identified)
        })
        .filter_map(|t| t.values.iter().find(|v| v.unit == unit))
        .filter_map(|v| v.value.map(|x| (x, v.unit.clone())))
        .collect();
    if values.is_empty() {
        return None;
    }
    let mean = values.iter().map(|v| v.0).sum::<f64>() / values.len() as f64;
    Some((mean, values[0].1.clone()))
}

/// One line per headline term: each device's mean over axes and which is better by how much.
fn findings(report: &AllanReport) -> Vec<String> {
    let mut devices: Vec<&str> = report.axes.iter().map(|a| a.device.as_str()).collect();
    devices.dedup();
    let rows = [
        ("gyro", "ARW", "deg/sqrt(h)", "gyro angle random walk"),
        ("gyro", "bias instability", "deg/h", "gyro bias instability"),
        ("accel", "VRW", "mg/sqrt(h)", "accel velocity random walk"),
    ];
    rows.iter()
        .filter_map(|(sensor, name, unit, label)| {
            let per: Vec<(&str, f64, String)> = devices
                .iter()
                .filter_map(|d| mean_term(report, d, sensor, name, unit).map(|(v, u)| (*d, v, u)))
                .collect();
            let best = per.iter().min_by(|a, b| a.1.total_cmp(&b.1))?;
            let worst = per.iter().max_by(|a, b| a.1.total_cmp(&b.1))?;
            let listed: Vec<String> = per
                .iter()
                .map(|(d, v, u)| format!("{d} {v:.3} {u}"))
                .collect();
            Some(format!(
                "{label}: {} (mean of axes): {} is {:.1}× better than {}",
                listed.join(", "),
                best.0,
                worst.1 / best.1,
                worst.0
            ))
        })
        .collect()
}
