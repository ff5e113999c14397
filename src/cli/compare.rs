//! `imulab compare`: two or more IMUs side by side as a datasheet-style table (rows: bias
//! stability, ARW/VRW, RRW/AccRW, …; columns: device × axis), on the terminal and
//! optionally as HTML: the report's summary (which IMU is better, outage horizons), the table
//! and the curves overlaid.

use super::allan::{analyse_inputs, AnalysisArgs};
use crate::allan::analysis::AxisResult;
use crate::allan::units::SensorKind;
use crate::report::{
    datasheet_table_html, datasheet_table_text, plot_groups, summary_html, svg_plot, PAGE_STYLE,
    SVG_NAMESPACE,
};
use anyhow::{bail, Context};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(
    after_help = "Examples:\n  imulab compare bench_a.csv bench_b.csv --time-column t --units rad/s --html compare.html\n  imulab compare /data/chamber            # every IMU of a session"
)]
pub struct CompareArgs {
    /// Inputs: plain files (one device each) or sessions (every IMU in them); two or more
    /// devices in all.
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    #[command(flatten)]
    pub analysis: AnalysisArgs,
    /// Also write an HTML page with the table and the overlaid curves.
    #[arg(long)]
    pub html: Option<PathBuf>,
}

pub fn run(mut args: CompareArgs) -> anyhow::Result<()> {
    if !args.analysis.options.kind.is_allan_variance() {
        bail!("compare fits the noise model: use --kind adev, oadev or totdev");
    }
    args.analysis.options.fit = true;
    args.analysis.options.device = None;
    let report = analyse_inputs(&args.inputs, &args.analysis)?;
    let mut devices: Vec<&str> = report.axes.iter().map(|a| a.device.as_str()).collect();
    devices.sort_unstable();
    devices.dedup();
    if devices.len() < 2 {
        bail!(
            "compare needs at least two devices; the inputs hold {}",
            devices.join(", ")
        );
    }
    let axes: Vec<&AxisResult> = report.axes.iter().collect();
    print!("{}", datasheet_table_text(&axes));
    if let Some(path) = &args.html {
        let mut page = format!(
            "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>IMU comparison</title><style>{PAGE_STYLE}</style></head><body><h1>IMU comparison</h1><h2>Summary</h2>"
        );
        page.push_str(&summary_html(&report));
        page.push_str("<h2>Noise terms</h2>");
        // One table per sensor (no half-empty columns), then one plot per device and sensor
        // (a gyro and an accelerometer do not share a unit).
        for sensor in [Some(SensorKind::Gyro), Some(SensorKind::Accel), None] {
            let members: Vec<&AxisResult> = axes
                .iter()
                .copied()
                .filter(|a| a.sensor == sensor)
                .collect();
            if !members.is_empty() {
                page.push_str("<div class=\"scroll\">");
                page.push_str(&datasheet_table_html(&members));
                page.push_str("</div>");
            }
        }
        page.push_str("<h2>Curves</h2><div class=\"plots\">");
        for (title, members) in plot_groups(&report) {
            page.push_str(&svg_plot(&members, &title).replacen(SVG_NAMESPACE, "", 1));
        }
        page.push_str("</div></body></html>\n");
        std::fs::write(path, page).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
