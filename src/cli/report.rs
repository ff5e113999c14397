//! `imulab report`: one self-contained HTML page for one or more inputs (sessions or plain
//! files): log-log curves with confidence bands and fitted lines, the datasheet-style
//! noise-term table (rows: terms; columns: device × axis) and the data's health, after a
//! summary of which IMU is better and what that means for GNSS outages: the filter-based
//! answer of a small sensor-grade study of the fitted IMUs (or of a given study JSON), the
//! free-inertial figure only as a labelled analytic bound.

use super::allan::{analyse_inputs, summary_text, AnalysisArgs};
use crate::allan::analysis::AllanReport;
use crate::report::{html_report, plot_groups, write_png_axes};
use anyhow::Context;
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  imulab report runs/chamber --html report.html --png plots.png\n  imulab report imu_a.csv imu_b.npy --rate 200 --units rad/s --kind oadev --html report.html --png curves.png"
)]
pub struct ReportArgs {
    /// Inputs: sessions (every IMU in them) or CSV/TSV/.npy files (one device each).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    #[command(flatten)]
    pub analysis: AnalysisArgs,
    /// Output HTML file.
    #[arg(long, default_value = "allan-report.html")]
    pub html: PathBuf,
    /// Also write the JSON document.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Also write the page's plots as PNG (plotters bitmap): this file for a single plot,
    /// otherwise one file per device and sensor named `<stem>-<device>-<sensor>.png`.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// A sensor-grade study of these IMUs (`imulab study --grades FIT.json#DEVICE,... --json`):
    /// its filter-based answer becomes the report's GNSS-outage headline, instead of the
    /// small study the report runs itself.
    #[arg(long, value_name = "STUDY.json")]
    pub study: Option<PathBuf>,
    /// Monte Carlo runs of the report's own sensor-grade study of the fitted IMUs (the
    /// reference 15-minute drive; 0 = none, the analytic bound only).
    #[arg(long, default_value_t = crate::study::grades::FIT_STUDY_RUNS, conflicts_with = "study")]
    pub study_runs: usize,
    /// Page title.
    #[arg(long, default_value = "IMU noise report")]
    pub title: String,
    /// Also print each axis's τ table.
    #[arg(short, long, conflicts_with = "quiet")]
    pub verbose: bool,
    /// Print nothing but errors.
    #[arg(short, long)]
    pub quiet: bool,
}

pub fn run(mut args: ReportArgs) -> anyhow::Result<()> {
    // A report always carries the noise terms.
    args.analysis.options.fit = args.analysis.options.kind.is_allan_variance();
    if args.analysis.options.device.is_some() && args.inputs.len() > 1 {
        anyhow::bail!("--device names a single input; with several inputs the file names are used");
    }
    // The health section shows each IMU's temperature: read it with the rates (same pass)
    // when every input is a session (they all have a `temp` channel).
    if args.analysis.options.temperature_column.is_none() && args.inputs.iter().all(|p| p.is_dir())
    {
        args.analysis.options.temperature_column = Some("temp".into());
    }
    let given = match &args.study {
        Some(p) => Some(crate::study::grades::StudyResult::from_json_file(p)?),
        None => None,
    };
    let report = analyse_inputs(&args.inputs, &args.analysis)?;
    let study = match given {
        Some(s) => Some(s),
        None if args.study_runs > 0 => own_study(&report, args.study_runs, args.quiet),
        None => None,
    };
    let mut page = match &study {
        Some(s) => crate::report::html_report_with_study(&report, &args.title, s),
        None => html_report(&report, &args.title),
    };
    let thermal = thermal_sections(&args.inputs, &report, args.quiet);
    if !thermal.is_empty() {
        page = crate::report::with_section(&page, &thermal);
    }
    std::fs::write(&args.html, page).with_context(|| format!("writing {}", args.html.display()))?;
    if let Some(path) = &args.json {
        let file =
            std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        serde_json::to_writer_pretty(std::io::BufWriter::new(file), &report)?;
    }
    let mut written = vec![args.html.clone()];
    written.extend(args.json.iter().cloned());
    if let Some(path) = &args.png {
        written.extend(write_pngs(&report, path)?);
    }
    if !args.quiet {
        print!("{}", summary_text(&report, args.verbose));
        for path in written {
            println!("wrote {}", path.display());
        }
    }
    Ok(())
}

/// Sessions whose temperature spans at least this get the thermal section, °C.
pub const THERMAL_SECTION_SPAN_C: f64 = 5.0;

/// The thermal section (`imulab thermal`'s, with its defaults) of the session inputs when an
/// analysed IMU's temperature spans at least [`THERMAL_SECTION_SPAN_C`]; a session the
/// analysis refuses gets one line on stderr saying why.
fn thermal_sections(inputs: &[PathBuf], report: &AllanReport, quiet: bool) -> String {
    let spans =
        report.axes.iter().any(
            |a| match (a.health.temperature_min, a.health.temperature_max) {
                (Some(lo), Some(hi)) => hi - lo >= THERMAL_SECTION_SPAN_C,
                _ => false,
            },
        );
    let mut html = String::new();
    for input in inputs.iter().filter(|p| spans && p.is_dir()) {
        match super::thermal::analyse_input(&super::thermal::ThermalArgs::for_session(input)) {
            Ok(t) => html.push_str(&crate::thermal::report::html_section(&t)),
            Err(e) => {
                if !quiet {
                    eprintln!("{}: no thermal section: {e:#}", input.display());
                }
            }
        }
    }
    html
}

/// The filter-based outage answer for the report's devices: a small study of their fits
/// (`study::grades::fit_study`). None, with one line saying why, when a fit does not allow
/// it (the page then shows the analytic bound only).
fn own_study(
    report: &AllanReport,
    runs: usize,
    quiet: bool,
) -> Option<crate::study::grades::StudyResult> {
    let mut devices: Vec<&str> = Vec::new();
    for a in &report.axes {
        if !devices.contains(&a.device.as_str()) {
            devices.push(&a.device);
        }
    }
    if !quiet {
        eprintln!(
            "GNSS-outage study of {}: {runs} simulated drives of 15 min per IMU (--study-runs 0: none)",
            devices.join(", ")
        );
    }
    match crate::study::grades::fit_study(report, &devices, runs, !quiet) {
        Ok(s) => {
            if !quiet {
                for (k, req) in s.requirements_m().iter().enumerate() {
                    let per: Vec<String> = s
                        .grades
                        .iter()
                        .filter_map(|g| Some(format!("{} {}", g.name, g.bridges.get(k)?.text())))
                        .collect();
                    println!(
                        "longest GNSS outage within {req} m (p95, filter-based): {}",
                        per.join("; ")
                    );
                }
            }
            Some(s)
        }
        Err(e) => {
            if !quiet {
                eprintln!(
                    "no filter-based outage study: {e:#}; the report shows the analytic bound only"
                );
            }
            None
        }
    }
}

/// The HTML page's plots as PNG files; returns the paths written.
fn write_pngs(report: &AllanReport, path: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let groups = plot_groups(report);
    let single = groups.len() == 1;
    let mut written = Vec::new();
    for (title, axes) in groups {
        let target = if single {
            path.to_path_buf()
        } else {
            let stem = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "report".into());
            let name: String = title
                .chars()
                .map(|c| if c.is_ascii_alphanumeric() { c } else { '-' })
                .collect();
            path.with_file_name(format!("{stem}-{name}.png"))
        };
        write_png_axes(&axes, &title, &target)
            .with_context(|| format!("writing {}", target.display()))?;
        written.push(target);
    }
    Ok(written)
}
