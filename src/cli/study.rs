//! `imulab study`: the sensor-grade study (see [`crate::study::grades`]): Monte Carlo over IMU
//! grades and GNSS outage lengths on a scene's drive; prints and plots the horizontal drift
//! p50/p95 against outage length per grade and the longest outage each grade bridges within
//! each requirement.

use crate::fusion::config::FusionConfig;
use crate::sim::scene::Scene;
use crate::study::grades::{run_study, Grade, StudyOptions, StudyResult, DEFAULT_REQUIREMENTS_M};
use anyhow::Context;
use clap::Args;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
#[command(
    after_help = "Example: imulab study fixtures/scenes/drive_30min.toml --grades bench-cheap,bench-dear,industrial,tactical --outages 5,10,30,60 --runs 100 --json study.json --svg study.svg\n\
    A grade is an IMU preset (imulab sim --list-presets) or an Allan-fit JSON file written by\n\
    `imulab allan --json` / `imulab report --json` (FILE.json#DEVICE picks one device)."
)]
pub struct StudyArgs {
    /// Scene file (TOML, see docs/simulator.md) whose drive and GNSS receiver are used.
    pub scene: PathBuf,
    /// IMU grades: preset names or Allan-fit JSON files, comma-separated.
    #[arg(long, value_delimiter = ',', required = true)]
    pub grades: Vec<String>,
    /// Outage lengths, s, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "5,10,30,60")]
    pub outages: Vec<f64>,
    /// Monte Carlo runs per grade.
    #[arg(long, default_value_t = 20)]
    pub runs: usize,
    /// Horizontal requirements, m, comma-separated (default 0.1,1,10).
    #[arg(long, value_delimiter = ',')]
    pub require: Vec<f64>,
    /// Seed of run 0 (default: the scene's seed).
    #[arg(long)]
    pub seed: Option<u64>,
    /// One outage start per this much drive, s.
    #[arg(long, default_value_t = 120.0)]
    pub spacing: f64,
    /// No outage in the first this many seconds (alignment, convergence), s.
    #[arg(long, default_value_t = 180.0)]
    pub settle: f64,
    /// Filter configuration (TOML, see docs/fusion.md); its IMU noise is replaced by each
    /// grade's.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Take the GNSS fixes as white noise (inflated by `gnss.position_correlation_s`)
    /// instead of carrying the receiver's slowly varying position error as three filter
    /// states (the default: the `[gnss.position_error]` of --config, else the scene
    /// receiver's own, see docs/fusion.md).
    #[arg(long)]
    pub white_gnss: bool,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Write the results as JSON.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Plot drift p50/p95 against outage length as SVG.
    #[arg(long, value_name = "FILE")]
    pub svg: Option<PathBuf>,
    /// Plot as PNG (needs a system font).
    #[arg(long, value_name = "FILE")]
    pub png: Option<PathBuf>,
}

pub fn run(args: StudyArgs) -> anyhow::Result<()> {
    let scene = Scene::load(&args.scene)?;
    let mut config = FusionConfig {
        covariance_interval_s: 0.1,
        ..FusionConfig::default()
    };
    if let Some(p) = &args.config {
        config = FusionConfig::from_file(p)?;
    }
    if args.white_gnss {
        config.gnss.position_error = Default::default();
    } else {
        crate::study::grades::model_receiver_error(&mut config, &scene);
    }
    let grades = args
        .grades
        .iter()
        .map(|g| Grade::parse(g.trim(), &config.imu))
        .collect::<anyhow::Result<Vec<_>>>()?;
    for g in &grades {
        for w in &g.noise.warnings {
            tracing::warn!("{w}");
        }
    }
    let mut options = StudyOptions::new(
        grades,
        args.outages.clone(),
        args.runs,
        args.seed.unwrap_or(scene.seed),
    );
    if !args.require.is_empty() {
        options.requirements_m = args.require.clone();
    } else {
        options.requirements_m = DEFAULT_REQUIREMENTS_M.to_vec();
    }
    options.outage_spacing_s = args.spacing;
    options.settle_s = args.settle;
    options.config = config;
    options.progress = true;
    let result = match args.threads {
        Some(n) => rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .context("thread pool")?
            .install(|| run_study(&scene, &options))?,
        None => run_study(&scene, &options)?,
    };
    print!("{}", result.summary_text());
    if let Some(p) = &args.json {
        std::fs::write(p, serde_json::to_string_pretty(&result)?)
            .with_context(|| format!("writing {}", p.display()))?;
        println!("wrote {}", p.display());
    }
    if let Some(p) = &args.svg {
        let root = SVGBackend::new(p, (900, 600)).into_drawing_area();
        plot(&root, &result).with_context(|| format!("plotting {}", p.display()))?;
        root.present()
            .with_context(|| format!("writing {}", p.display()))?;
        println!("wrote {}", p.display());
    }
    if let Some(p) = &args.png {
        write_png(p, &result)?;
        println!("wrote {}", p.display());
    }
    Ok(())
}

fn write_png(path: &Path, result: &StudyResult) -> anyhow::Result<()> {
    let root = BitMapBackend::new(path, (900, 600)).into_drawing_area();
    plot(&root, result).with_context(|| {
        format!(
            "plotting {} (PNG needs a system font; try --svg)",
            path.display()
        )
    })?;
    root.present()
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Drift p95 (solid) and p50 (dashed) against outage length per grade, log-log, with the
/// requirements as grey horizontal lines.
pub fn plot<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    result: &StudyResult,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow::anyhow!("{e:?}");
    root.fill(&WHITE).map_err(err)?;
    let values = || {
        result
            .grades
            .iter()
            .flat_map(|g| g.lengths.iter().flat_map(|l| [l.p50_m, l.p95_m]))
            .chain(
                result
                    .grades
                    .iter()
                    .flat_map(|g| g.bridges.iter().map(|b| b.requirement_m)),
            )
            .filter(|v| v.is_finite() && *v > 0.0)
    };
    let y_min = values().fold(f64::INFINITY, f64::min).max(1e-4) / 1.5;
    let y_max = values().fold(0.0f64, f64::max).max(y_min * 10.0) * 1.5;
    let lengths: Vec<f64> = result
        .grades
        .first()
        .map(|g| g.lengths.iter().map(|l| l.outage_s).collect())
        .unwrap_or_default();
    let x_min = lengths.first().copied().unwrap_or(1.0) / 1.3;
    let x_max = lengths.last().copied().unwrap_or(10.0) * 1.3;
    let mut chart = ChartBuilder::on(root)
        .caption(
            format!(
                "Horizontal drift during GNSS outages ({} runs; solid p95, dashed p50)",
                result.runs
            ),
            ("sans-serif", 20),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(65)
        .build_cartesian_2d((x_min..x_max).log_scale(), (y_min..y_max).log_scale())
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("outage length, s")
        .y_desc("horizontal drift, m")
        .draw()
        .map_err(err)?;
    for req in result.requirements_m() {
        chart
            .draw_series(LineSeries::new(
                [(x_min, req), (x_max, req)],
                RGBColor(160, 160, 160).stroke_width(1),
            ))
            .map_err(err)?;
    }
    for (i, g) in result.grades.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        let pts = |f: fn(&crate::study::grades::LengthStats) -> f64| -> Vec<(f64, f64)> {
            g.lengths
                .iter()
                .map(|l| (l.outage_s, f(l)))
                .filter(|(_, y)| y.is_finite() && *y > 0.0)
                .collect()
        };
        chart
            .draw_series(LineSeries::new(pts(|l| l.p95_m), color.stroke_width(2)))
            .map_err(err)?
            .label(g.name.clone())
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], color.stroke_width(2)));
        chart
            .draw_series(DashedLineSeries::new(
                pts(|l| l.p50_m),
                6,
                4,
                color.stroke_width(1),
            ))
            .map_err(err)?;
        chart
            .draw_series(
                pts(|l| l.p95_m)
                    .into_iter()
                    .map(|p| Circle::new(p, 3, color.filled())),
            )
            .map_err(err)?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperLeft)
        .draw()
        .map_err(err)?;
    Ok(())
}
