//! `imulab allan`: the arguments of the Allan analysis, the corrections they name
//! (`--calibration`, `--compensate`) and what the command prints and writes (terminal summary,
//! JSON/CSV/HTML/PNG/Kalibr/MATLAB). The analysis itself is the library's
//! [`crate::allan::pipeline`]; the input options are shared with `imulab report` and
//! `imulab compare`.

use crate::allan::analysis::{AllanReport, AxisResult};
use crate::allan::columns::fmt_sig;
use crate::allan::export;
use crate::allan::input::{AxisSeries, SampleSource};
use crate::allan::pipeline::{self, Corrections, Options, Progress};
use crate::allan::timings::Stage;
use crate::report;
use anyhow::{bail, Context};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Options that say how to read inputs and what to compute (shared by allan/report/compare):
/// the pipeline's own, and the corrections applied before it.
#[derive(clap::Args, Debug, Clone)]
pub struct AnalysisArgs {
    #[command(flatten)]
    pub options: Options,
    /// Subtract the change of bias with temperature, bias(T) − bias(reference), of this
    /// thermal model (`imulab thermal --model`, docs/thermal.md) from every sample before the
    /// analysis, using the temperature channel.
    #[arg(long)]
    pub compensate: Option<PathBuf>,
    /// Correct the gyro and accel channels with this calibration file (`imulab calibrate`,
    /// docs/calibration.md) before the analysis (and before --compensate). Files need
    /// columns named gyro_x … accel_z in rad/s and m/s².
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example: imulab allan gyro.csv --time-column t --axes gx,gy,gz --units rad/s --fit --taus dense:10 --json out.json --html out.html"
)]
pub struct AllanArgs {
    /// Inputs: session directories, CSV/TSV/semicolon/space-aligned files (header optional)
    /// or NumPy .npy files (N or N×k); one device each (a session: every IMU in it).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    #[command(flatten)]
    pub analysis: AnalysisArgs,
    /// Write the JSON document (schema: docs/allan.md).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write a CSV table (one row per axis and τ).
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Write a self-contained HTML report.
    #[arg(long)]
    pub html: Option<PathBuf>,
    /// Write a PNG plot.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Write a Kalibr imu.yaml (needs --fit).
    #[arg(long)]
    pub kalibr: Option<PathBuf>,
    /// Write MATLAB imuSensor parameters as a .m script (needs --fit).
    #[arg(long)]
    pub matlab: Option<PathBuf>,
}

pub fn run(args: AllanArgs) -> anyhow::Result<()> {
    if args.analysis.options.device.is_some() && args.inputs.len() > 1 {
        bail!("--device names a single input; with several inputs the file names are used");
    }
    let _whole = Stage::start(|| "allan command".into());
    let report = analyse_inputs(&args.inputs, &args.analysis)?;
    let output = Stage::start(|| "output".into());
    print!("{}", summary_text(&report, true));
    for path in write_outputs(&report, &args)? {
        println!("wrote {}", path.display());
    }
    drop(output);
    Ok(())
}

/// Writes the requested outputs; returns the paths written.
fn write_outputs(report: &AllanReport, args: &AllanArgs) -> anyhow::Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    if let Some(path) = &args.json {
        let file =
            std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        serde_json::to_writer_pretty(std::io::BufWriter::new(file), report)?;
        written.push(path.clone());
    }
    if let Some(path) = &args.csv {
        report::write_csv(report, path).with_context(|| format!("writing {}", path.display()))?;
        written.push(path.clone());
    }
    if let Some(path) = &args.html {
        std::fs::write(path, report::html_report(report, "Allan analysis"))
            .with_context(|| format!("writing {}", path.display()))?;
        written.push(path.clone());
    }
    if let Some(path) = &args.png {
        report::write_png(report, path).with_context(|| format!("writing {}", path.display()))?;
        written.push(path.clone());
    }
    if (args.kalibr.is_some() || args.matlab.is_some()) && !args.analysis.options.fit {
        bail!("--kalibr and --matlab export fitted terms: add --fit");
    }
    if let Some(path) = &args.kalibr {
        std::fs::write(path, export::kalibr_yaml(&report.axes, "/imu0"))
            .with_context(|| format!("writing {}", path.display()))?;
        written.push(path.clone());
    }
    if let Some(path) = &args.matlab {
        std::fs::write(path, export::matlab_imu_sensor(&report.axes))
            .with_context(|| format!("writing {}", path.display()))?;
        written.push(path.clone());
    }
    Ok(written)
}

/// Terminal summary: per axis one line, with `curves` followed by its τ table; then the
/// datasheet table if fitted.
pub fn summary_text(report: &AllanReport, curves: bool) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    if !curves {
        out.push_str(&device_lines(report));
    }
    for a in report.axes.iter().filter(|_| curves) {
        let _ = writeln!(
            out,
            "{} {} ({}; {} samples, tau0 {} s, gaps policy {:?}, {} gap(s) found on the {}){}",
            a.device,
            a.axis,
            a.curve.kind.name(),
            a.health.samples,
            fmt_sig(a.tau0),
            a.health.policy.unwrap_or_default(),
            a.health.gaps,
            a.health.clock.as_deref().unwrap_or("time stamps"),
            if curves { ":" } else { "" }
        );
        if let Some(t) = &a.thermal {
            if let Some(line) = report::thermal_coefficient_text(a, t) {
                let _ = writeln!(out, "  {line}");
            }
        }
        if let Some(e) = &a.fit_error {
            let _ = writeln!(out, "  fit: {e}");
        }
        let deviation = format!("dev [{}]", report::deviation_unit(a));
        let _ = writeln!(
            out,
            "  {:>12} {:>12} {:>12} {:>12} {:>9} {:>5}",
            "tau [s]", deviation, "low", "high", "edf", "alpha"
        );
        for p in &a.curve.points {
            let f = |v: Option<f64>| v.map(|v| format!("{v:.5e}")).unwrap_or_else(|| "-".into());
            let _ = writeln!(
                out,
                "  {:>12.5e} {:>12.5e} {:>12} {:>12} {:>9} {:>5}",
                p.tau,
                p.deviation,
                f(p.low),
                f(p.high),
                p.edf
                    .map(|e| format!("{e:.1}"))
                    .unwrap_or_else(|| "-".into()),
                p.alpha
            );
        }
    }
    if report.axes.iter().any(|a| a.fit.is_some()) {
        let axes: Vec<&AxisResult> = report.axes.iter().collect();
        let _ = writeln!(out, "\nNoise terms:");
        out.push_str(&report::datasheet_table_text(&axes));
    }
    out
}

/// One line per device (axes, samples, τ0, gaps and the clock they were found on), then
/// per axis only what needs saying: a fit that failed, a thermal coefficient.
fn device_lines(report: &AllanReport) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let mut devices: Vec<&str> = Vec::new();
    for a in &report.axes {
        if !devices.contains(&a.device.as_str()) {
            devices.push(&a.device);
        }
    }
    for device in devices {
        let axes: Vec<&AxisResult> = report.axes.iter().filter(|a| a.device == device).collect();
        let names: Vec<&str> = axes.iter().map(|a| a.axis.as_str()).collect();
        let samples: u64 = axes.iter().map(|a| a.health.samples).max().unwrap_or(0);
        let gaps: u64 = axes.iter().map(|a| a.health.gaps).sum();
        let first = axes[0];
        let _ = writeln!(
            out,
            "{device}: {} ({}), {samples} samples, tau0 {} s, {gaps} gap(s) found on the {}",
            names.join(", "),
            first.curve.kind.name(),
            fmt_sig(first.tau0),
            first.health.clock.as_deref().unwrap_or("time stamps")
        );
        for a in axes {
            if let Some(line) = a
                .thermal
                .as_ref()
                .and_then(|t| report::thermal_coefficient_text(a, t))
            {
                let _ = writeln!(out, "  {}: {line}", a.axis);
            }
            if let Some(e) = &a.fit_error {
                let _ = writeln!(out, "  {}: fit: {e}", a.axis);
            }
        }
    }
    out
}

/// Shows a progress bar on stderr once the work has taken more than a second, and only
/// when stderr is a terminal.
struct ProgressBar {
    bar: indicatif::ProgressBar,
    started: Instant,
    visible: bool,
    terminal: bool,
}

impl ProgressBar {
    fn new() -> Self {
        let bar = indicatif::ProgressBar::hidden();
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} {msg}",
        ) {
            bar.set_style(style);
        }
        ProgressBar {
            bar,
            started: Instant::now(),
            visible: false,
            terminal: std::io::stderr().is_terminal(),
        }
    }
}

impl Progress for ProgressBar {
    fn planned(&mut self, axes: usize) {
        self.bar.set_length(axes as u64);
    }

    fn analysed(&mut self, label: &str) {
        if self.terminal && !self.visible && self.started.elapsed() > Duration::from_secs(1) {
            self.bar
                .set_draw_target(indicatif::ProgressDrawTarget::stderr());
            self.visible = true;
        }
        self.bar.set_message(label.to_string());
        self.bar.inc(1);
    }
}

/// The calibration and thermal model named by `--calibration` and `--compensate`.
struct FileCorrections {
    calibration: Option<crate::calib::Calibration>,
    model: Option<crate::thermal::model::ThermalModel>,
}

impl Corrections for FileCorrections {
    fn correct_source(
        &self,
        source: Box<dyn SampleSource>,
        device: &str,
        si: bool,
    ) -> anyhow::Result<Box<dyn SampleSource>> {
        let Some(calibration) = &self.calibration else {
            return Ok(source);
        };
        let corrector = crate::calib::Corrector::new(calibration, device)?;
        Ok(Box::new(crate::calib::source::CalibratedSource::new(
            source, corrector, si,
        )?))
    }

    fn compensate(
        &self,
        device: &str,
        series: &mut AxisSeries,
        to_si: f64,
    ) -> anyhow::Result<Option<String>> {
        match &self.model {
            Some(model) => Ok(model.compensate_series(device, series, to_si)?.1),
            None => Ok(None),
        }
    }

    fn needs_temperature(&self) -> bool {
        self.model.is_some()
    }
}

/// Reads and analyses every selected axis of every input ([`pipeline::analyse_inputs`]) with
/// the corrections the arguments name, drawing a progress bar on a terminal.
pub fn analyse_inputs(inputs: &[PathBuf], args: &AnalysisArgs) -> anyhow::Result<AllanReport> {
    let corrections = FileCorrections {
        calibration: args
            .calibration
            .as_deref()
            .map(crate::calib::Calibration::load)
            .transpose()?,
        model: args
            .compensate
            .as_deref()
            .map(crate::thermal::model::ThermalModel::load)
            .transpose()?,
    };
    let mut progress = ProgressBar::new();
    let report = pipeline::analyse_inputs(inputs, &args.options, &corrections, &mut progress);
    progress.bar.finish_and_clear();
    report
}
