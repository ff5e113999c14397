//! The CSV table of an analysis: one row per axis and τ.

use crate::allan::analysis::AllanReport;
use std::path::Path;

/// CSV: one row per axis and τ.
pub fn write_csv(report: &AllanReport, path: &Path) -> anyhow::Result<()> {
    let mut w = csv::Writer::from_path(path)?;
    w.write_record([
        "device",
        "axis",
        "kind",
        "m",
        "tau_s",
        "deviation",
        "low",
        "high",
        "edf",
        "count",
        "alpha",
    ])?;
    for axis in &report.axes {
        for p in &axis.curve.points {
            let opt = |v: Option<f64>| v.map(|v| format!("{v:.10e}")).unwrap_or_default();
            w.write_record([
                axis.device.clone(),
                axis.axis.clone(),
                axis.curve.kind.name().to_string(),
                p.m.to_string(),
                format!("{:.10e}", p.tau),
                format!("{:.10e}", p.deviation),
                opt(p.low),
                opt(p.high),
                opt(p.edf),
                p.count.to_string(),
                p.alpha.to_string(),
            ])?;
        }
    }
    w.flush()?;
    Ok(())
}
