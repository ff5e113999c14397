//! Writers for results: CSV, a self-contained HTML page (inline SVG drawn here, no
//! network, no fonts needed), PNG plots (plotters) and the datasheet-style comparison
//! table (rows: noise terms; columns: device × axis).
//!
//! The page opens with a summary (which IMU is better, by how much, and how long a GNSS
//! outage each bridges: [`outage`]) and ends with the data's health ([`health`]: gaps,
//! temperature and the daemon's events of every session input).
//!
//! The SVG is written by hand because plotters' text layout needs system fonts, which a
//! report must not depend on; PNG output uses plotters.

use crate::allan::analysis::{AllanReport, AxisResult};
use crate::allan::fit::{NoiseFit, Term};
use crate::allan::thermal::ThermalSummary;
use crate::allan::units::{thermal_coefficient_in_units, SensorKind};
use crate::fusion::study::{Bridge, StudyResult};
use health::SessionHealth;
use std::fmt::Write as _;
use std::path::Path;

pub mod health;
pub mod outage;

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

const COLORS: [&str; 8] = [
    "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2",
];

/// `text` with the characters HTML and SVG give meaning to (`&`, `<`, `>`, `"`) escaped.
pub fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// One identified noise term's own σ(τ) line (a straight line on log-log axes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TermLine {
    pub term: Term,
    /// End points (τ, σ) at the ends of the plotted τ range.
    pub from: (f64, f64),
    pub to: (f64, f64),
    /// Where the label goes: on the line, in the middle of the τ stretch where this term
    /// makes up (within 10 %) its largest share of the fitted total.
    pub label_at: (f64, f64),
}

/// The asymptote of every identified term of `fit` between `tau_lo` and `tau_hi`.
pub fn term_lines(fit: &NoiseFit, tau_lo: f64, tau_hi: f64) -> Vec<TermLine> {
    if !(tau_lo > 0.0 && tau_hi >= tau_lo && tau_hi.is_finite()) {
        return Vec::new();
    }
    const SAMPLES: usize = 64;
    let tau_at = |i: usize| tau_lo * (tau_hi / tau_lo).powf(i as f64 / (SAMPLES - 1) as f64);
    Term::ALL
        .iter()
        .filter_map(|&term| {
            let at = |tau: f64| fit.term_deviation(term, tau).filter(|d| *d > 0.0);
            let from = (tau_lo, at(tau_lo)?);
            let to = (tau_hi, at(tau_hi)?);
            let share = |tau: f64| {
                let total = fit.model_deviation(tau);
                at(tau).map_or(0.0, |d| d / total)
            };
            // Middle (in log τ) of where the term is within 10 % of its largest share of
            // the total: the stretch where its asymptote runs along the total curve, and
            // away from the plot's edges when the term dominates an end of the range.
            let shares: Vec<f64> = (0..SAMPLES).map(|i| share(tau_at(i))).collect();
            let peak = shares.iter().copied().fold(0.0, f64::max);
            let dominant: Vec<usize> = (0..SAMPLES).filter(|&i| shares[i] >= 0.9 * peak).collect();
            let best = tau_at(*dominant.get(dominant.len() / 2)?);
            Some(TermLine {
                term,
                from,
                to,
                label_at: (best, at(best)?),
            })
        })
        .collect()
}

/// Text under a plot that says what the line styles mean.
pub const LINE_STYLE_NOTE: &str =
    "solid: measured · band: 68 % interval · dashed: fitted total · dotted: fitted terms (Q quantization, N white noise/random walk, B bias instability, K rate random walk, R rate ramp)";

/// The namespace attribute of a standalone SVG (inline SVG in HTML goes without it).
pub const SVG_NAMESPACE: &str = r#" xmlns="http://www.w3.org/2000/svg""#;

/// [`LINE_STYLE_NOTE`] short enough for the foot of an SVG plot.
pub const SHORT_LINE_STYLE_NOTE: &str =
    "solid: measured · band: 68 % · dashed: fitted total · dotted: term lines (Q N B K R)";

/// A log-log SVG of several axes' curves with confidence bands, the fitted total and each
/// identified term's own line, labelled.
pub fn svg_plot(axes: &[&AxisResult], title: &str) -> String {
    let (width, height) = (720.0, 480.0);
    let (left, right, top, bottom) = (80.0, 20.0, 34.0, 66.0);
    let mut tau_range = (f64::INFINITY, f64::NEG_INFINITY);
    let mut dev_range = (f64::INFINITY, f64::NEG_INFINITY);
    for a in axes {
        for p in &a.curve.points {
            if p.tau > 0.0 && p.deviation > 0.0 {
                tau_range = (tau_range.0.min(p.tau), tau_range.1.max(p.tau));
                let lo = p.low.unwrap_or(p.deviation).max(p.deviation * 1e-3);
                let hi = p.high.unwrap_or(p.deviation);
                dev_range = (dev_range.0.min(lo), dev_range.1.max(hi));
            }
        }
    }
    let mut svg = String::new();
    let _ = write!(
        svg,
        r#"<svg{SVG_NAMESPACE} width="{width}" height="{height}" viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="14">"#
    );
    let _ = write!(
        svg,
        r#"<text x="{}" y="20" font-size="16" font-weight="bold" text-anchor="middle">{}</text>"#,
        width / 2.0,
        escape(title)
    );
    if !tau_range.0.is_finite() || !dev_range.0.is_finite() {
        svg.push_str(r#"<text x="360" y="230" text-anchor="middle">no data</text></svg>"#);
        return svg;
    }
    let lx = (
        tau_range.0.log10().floor(),
        tau_range
            .1
            .log10()
            .ceil()
            .max(tau_range.0.log10().floor() + 1.0),
    );
    let ly = (
        dev_range.0.log10().floor(),
        dev_range
            .1
            .log10()
            .ceil()
            .max(dev_range.0.log10().floor() + 1.0),
    );
    let px = |tau: f64| left + (tau.log10() - lx.0) / (lx.1 - lx.0) * (width - left - right);
    let py = |dev: f64| top + (ly.1 - dev.log10()) / (ly.1 - ly.0) * (height - top - bottom);
    // Grid and labels at decades.
    for d in (lx.0 as i32)..=(lx.1 as i32) {
        let x = px(10f64.powi(d));
        let _ = write!(
            svg,
            r##"<line x1="{x:.1}" y1="{top}" x2="{x:.1}" y2="{:.1}" stroke="#ddd"/>"##,
            height - bottom
        );
        let _ = write!(
            svg,
            r#"<text x="{x:.1}" y="{:.1}" text-anchor="middle">10<tspan dy="-6" font-size="10">{d}</tspan></text>"#,
            height - bottom + 20.0
        );
    }
    for d in (ly.0 as i32)..=(ly.1 as i32) {
        let y = py(10f64.powi(d));
        let _ = write!(
            svg,
            r##"<line x1="{left}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#ddd"/>"##,
            width - right
        );
        let _ = write!(
            svg,
            r#"<text x="{:.1}" y="{:.1}" text-anchor="end">10<tspan dy="-6" font-size="10">{d}</tspan></text>"#,
            left - 6.0,
            y + 4.0
        );
    }
    let _ = write!(
        svg,
        r##"<rect x="{left}" y="{top}" width="{:.1}" height="{:.1}" fill="none" stroke="#444"/>"##,
        width - left - right,
        height - top - bottom
    );
    // Fitted lines run over the whole τ range and may leave the plot area: clip them.
    let clip = format!("plot-{:016x}", fnv1a(title));
    let _ = write!(
        svg,
        r#"<clipPath id="{clip}"><rect x="{left}" y="{top}" width="{:.1}" height="{:.1}"/></clipPath>"#,
        width - left - right,
        height - top - bottom
    );
    let _ = write!(
        svg,
        r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">averaging time τ [s]</text>"#,
        (left + width - right) / 2.0,
        height - 24.0
    );
    let unit = axes.first().map(|a| a.unit.symbol()).unwrap_or("");
    let kind = axes.first().map(|a| a.curve.kind.name()).unwrap_or("");
    let _ = write!(
        svg,
        r#"<text transform="translate(16,{:.1}) rotate(-90)" text-anchor="middle">{} [{}]</text>"#,
        (top + height - bottom) / 2.0,
        kind.to_uppercase(),
        escape(unit)
    );
    // Legend box, drawn over the curves at the end.
    let mut legend = String::new();
    let _ = write!(
        legend,
        r##"<rect x="{:.1}" y="{:.1}" width="170" height="{:.1}" fill="#fff" fill-opacity="0.85" stroke="#bbb"/>"##,
        width - right - 178.0,
        top + 4.0,
        18.0 * axes.len() as f64 + 6.0
    );
    for (i, a) in axes.iter().enumerate() {
        let color = COLORS[i % COLORS.len()];
        let pts: Vec<_> = a
            .curve
            .points
            .iter()
            .filter(|p| p.deviation > 0.0)
            .collect();
        // Confidence band.
        let upper: Vec<String> = pts
            .iter()
            .filter_map(|p| Some(format!("{:.1},{:.1}", px(p.tau), py(p.high?))))
            .collect();
        let lower: Vec<String> = pts
            .iter()
            .rev()
            .filter_map(|p| {
                Some(format!(
                    "{:.1},{:.1}",
                    px(p.tau),
                    py(p.low?.max(10f64.powf(ly.0)))
                ))
            })
            .collect();
        if !upper.is_empty() && upper.len() == lower.len() {
            let _ = write!(
                svg,
                r#"<polygon points="{} {}" fill="{color}" fill-opacity="0.15" stroke="none"/>"#,
                upper.join(" "),
                lower.join(" ")
            );
        }
        let line: Vec<String> = pts
            .iter()
            .map(|p| format!("{:.1},{:.1}", px(p.tau), py(p.deviation)))
            .collect();
        let _ = write!(
            svg,
            r#"<polyline points="{}" fill="none" stroke="{color}" stroke-width="1.5"/>"#,
            line.join(" ")
        );
        if let Some(fit) = &a.fit {
            let model: Vec<String> = pts
                .iter()
                .map(|p| fit.model_deviation(p.tau))
                .zip(&pts)
                .filter(|(d, _)| *d > 0.0)
                .map(|(d, p)| format!("{:.1},{:.1}", px(p.tau), py(d)))
                .collect();
            let _ = write!(
                svg,
                r#"<polyline points="{}" fill="none" stroke="{color}" stroke-dasharray="5,4" stroke-width="1"/>"#,
                model.join(" ")
            );
            if let (Some(first), Some(last)) = (pts.first(), pts.last()) {
                let mut labels = String::new();
                for line in term_lines(fit, first.tau, last.tau) {
                    let _ = write!(
                        svg,
                        r#"<line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="{color}" stroke-dasharray="1.5,2.5" stroke-width="1.2" clip-path="url(#{clip})"><title>{}</title></line>"#,
                        px(line.from.0),
                        py(line.from.1),
                        px(line.to.0),
                        py(line.to.1),
                        escape(&format!("{} {} {}", a.device, a.axis, line.term.symbol()))
                    );
                    // Below the line: the measured curve runs above the asymptotes.
                    let (x, y) = (px(line.label_at.0), py(line.label_at.1) + 14.0);
                    if (left..=width - right).contains(&x)
                        && (top + 8.0..=height - bottom).contains(&y)
                    {
                        let _ = write!(
                            labels,
                            r#"<text x="{x:.1}" y="{y:.1}" fill="{color}" font-weight="bold" text-anchor="middle">{}</text>"#,
                            line.term.symbol()
                        );
                    }
                }
                svg.push_str(&labels);
            }
        }
        let ly_text = top + 18.0 + 18.0 * i as f64;
        let _ = write!(
            legend,
            r#"<line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="{color}" stroke-width="2"/><text x="{:.1}" y="{:.1}">{}</text>"#,
            width - right - 170.0,
            ly_text - 4.0,
            width - right - 150.0,
            ly_text - 4.0,
            width - right - 145.0,
            ly_text,
            escape(&format!("{} {}", a.device, a.axis))
        );
    }
    svg.push_str(&legend);
    if axes.iter().any(|a| a.fit.is_some()) {
        // The full explanation for screen readers and anyone reading the SVG alone.
        let _ = write!(svg, "<desc>{}</desc>", escape(LINE_STYLE_NOTE));
    }
    let _ = write!(
        svg,
        r##"<text x="{left}" y="{:.1}" font-size="12" fill="#555">{}</text>"##,
        height - 4.0,
        escape(if axes.iter().any(|a| a.fit.is_some()) {
            SHORT_LINE_STYLE_NOTE
        } else {
            "solid: measured · band: 68 % interval"
        })
    );
    svg.push_str("</svg>");
    svg
}

/// FNV-1a hash, for element ids that are stable from run to run.
fn fnv1a(text: &str) -> u64 {
    text.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// A duration for people: seconds, minutes or hours.
fn duration(seconds: f64) -> String {
    if seconds >= 7200.0 {
        format!("{:.2} h", seconds / 3600.0)
    } else if seconds >= 120.0 {
        format!("{:.1} min", seconds / 60.0)
    } else {
        format!("{seconds:.1} s")
    }
}

/// A unit as printed in datasheets: `deg/sqrt(h)` → `°/√h`, `m/s^2` → `m/s²`.
pub fn pretty_unit(unit: &str) -> String {
    unit.replace("sqrt(", "√(")
        .replace("√(h)", "√h")
        .replace("√(Hz)", "√Hz")
        .replace("√(s)", "√s")
        .replace("deg", "°")
        .replace("^2", "²")
        .replace("^3", "³")
        .replace("ug", "µg")
}

/// Unit of an axis's deviations: the input unit (unit·s for TDEV); `input units` when the
/// input has none.
pub fn deviation_unit(a: &AxisResult) -> String {
    let base = match a.unit {
        crate::allan::units::RateUnit::Unspecified => "input units".to_string(),
        unit => pretty_unit(unit.symbol()),
    };
    if a.curve.kind == crate::allan::DeviationKind::Tdev {
        format!("{base}·s")
    } else {
        base
    }
}

/// The bias temperature coefficient of an axis in engineering units (°/h/°C, mg/°C) with its
/// standard error, e.g. `bias vs temperature: 1.52 ± 0.03 °/h/°C (4 bins of 5 °C)`.
pub fn thermal_coefficient_text(a: &AxisResult, t: &ThermalSummary) -> Option<String> {
    let c = thermal_coefficient_in_units(t.coefficient?, a.sensor, a.unit);
    let se = t
        .coefficient_std_error
        .map(|e| thermal_coefficient_in_units(e, a.sensor, a.unit).value);
    Some(format!(
        "bias vs temperature: {}{} {} ({} bins of {} °C)",
        sig3(c.value),
        se.map(|e| format!(" ± {}", sig3(e))).unwrap_or_default(),
        pretty_unit(&c.unit),
        t.bins.len(),
        t.bin_width
    ))
}

/// Formats a value with 3 significant digits.
fn sig3(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let e = v.abs().log10().floor();
    if (-3.0..5.0).contains(&e) {
        let decimals = (2.0 - e).max(0.0) as usize;
        format!("{v:.decimals$}")
    } else {
        format!("{v:.2e}")
    }
}

/// Datasheet rows: (label, sensor, term) in the order engineers read them.
const DATASHEET_ROWS: [(&str, SensorKind, Term); 8] = [
    (
        "Gyro bias instability",
        SensorKind::Gyro,
        Term::BiasInstability,
    ),
    ("Gyro ARW", SensorKind::Gyro, Term::RandomWalk),
    ("Gyro RRW", SensorKind::Gyro, Term::RateRandomWalk),
    ("Gyro rate ramp", SensorKind::Gyro, Term::RateRamp),
    (
        "Accel bias instability",
        SensorKind::Accel,
        Term::BiasInstability,
    ),
    ("Accel VRW", SensorKind::Accel, Term::RandomWalk),
    ("Accel AccRW", SensorKind::Accel, Term::RateRandomWalk),
    ("Accel ramp", SensorKind::Accel, Term::RateRamp),
];

/// The comparison table as HTML (rows: noise terms; columns: device × axis). Each cell:
/// value with its 95 % interval in the first engineering unit, or "n.i." with the bound.
pub fn datasheet_table_html(axes: &[&AxisResult]) -> String {
    datasheet_table(axes, false).0
}

/// The table; with `hide_unidentified`, rows that no axis identifies are left out and their
/// labels returned.
fn datasheet_table(axes: &[&AxisResult], hide_unidentified: bool) -> (String, Vec<&'static str>) {
    let mut hidden = Vec::new();
    let mut html = String::from("<table class=\"datasheet\"><thead><tr><th>term</th><th>unit</th>");
    for a in axes {
        let _ = write!(
            html,
            "<th>{}<br>{}</th>",
            escape(&a.device),
            escape(&a.axis)
        );
    }
    html.push_str("</tr></thead><tbody>");
    for (label, sensor, term) in DATASHEET_ROWS {
        let relevant: Vec<_> = axes.iter().filter(|a| a.sensor == Some(sensor)).collect();
        if relevant.is_empty() {
            continue;
        }
        let identified = relevant.iter().any(|a| {
            a.terms
                .iter()
                .any(|t| t.term == term && t.values.first().is_some_and(|v| v.value.is_some()))
        });
        if hide_unidentified && !identified {
            hidden.push(label);
            continue;
        }
        let unit = relevant
            .iter()
            .find_map(|a| {
                a.terms
                    .iter()
                    .find(|t| t.term == term)
                    .and_then(|t| t.values.first())
                    .map(|u| u.unit.clone())
            })
            .unwrap_or_default();
        let _ = write!(
            html,
            "<tr><td>{}</td><td>{}</td>",
            escape(label),
            escape(&pretty_unit(&unit))
        );
        for a in axes {
            let cell = if a.sensor != Some(sensor) {
                String::new()
            } else {
                match a
                    .terms
                    .iter()
                    .find(|t| t.term == term)
                    .and_then(|t| t.values.first())
                {
                    Some(v) => match v.value {
                        Some(value) => format!(
                            "{}<br><small>{} – {}</small>",
                            sig3(value),
                            sig3(v.low),
                            sig3(v.high)
                        ),
                        None => format!("n.i. <small>(&lt; {})</small>", sig3(v.high)),
                    },
                    None => "–".into(),
                }
            };
            let _ = write!(html, "<td>{cell}</td>");
        }
        html.push_str("</tr>");
    }
    // Generic rows for inputs without a sensor type.
    let generic: Vec<_> = axes.iter().filter(|a| a.sensor.is_none()).collect();
    if !generic.is_empty() {
        for term in Term::ALL {
            let _ = write!(html, "<tr><td>{}</td><td></td>", term.symbol());
            for a in axes {
                let cell = a
                    .terms
                    .iter()
                    .find(|t| t.term == term && a.sensor.is_none())
                    .and_then(|t| t.values.first())
                    .map(|v| match v.value {
                        Some(value) => format!("{} {}", sig3(value), escape(&v.unit)),
                        None => format!("n.i. (&lt; {} {})", sig3(v.high), escape(&v.unit)),
                    })
                    .unwrap_or_default();
                let _ = write!(html, "<td>{cell}</td>");
            }
            html.push_str("</tr>");
        }
    }
    html.push_str("</tbody></table>");
    (html, hidden)
}

/// Plain-text version of the comparison table for the terminal: one table per sensor (no
/// half-empty columns), columns grouped by device with the axis under it, `<bound` for a
/// term not identified. Six axes of two devices fit in 100 columns.
pub fn datasheet_table_text(axes: &[&AxisResult]) -> String {
    let mut out = String::new();
    for sensor in [Some(SensorKind::Gyro), Some(SensorKind::Accel), None] {
        let members: Vec<&AxisResult> = axes
            .iter()
            .copied()
            .filter(|a| a.sensor == sensor)
            .collect();
        if members.is_empty() {
            continue;
        }
        if !out.is_empty() {
            out.push('\n');
        }
        out.push_str(&sensor_table_text(&members, sensor));
    }
    if !out.is_empty() {
        out.push_str("(<x: not identified; x is the largest value the data allow)\n");
    }
    out
}

/// The axis name without its sensor prefix (`gyro_x` → `x`) for a table titled by sensor.
fn short_axis(axis: &str, sensor: Option<SensorKind>) -> &str {
    let prefixes: &[&str] = match sensor {
        Some(SensorKind::Gyro) => &["gyro_", "gyro"],
        Some(SensorKind::Accel) => &["accel_", "acc_", "accel"],
        None => &[],
    };
    prefixes
        .iter()
        .find_map(|p| axis.strip_prefix(p).filter(|rest| !rest.is_empty()))
        .unwrap_or(axis)
}

/// One sensor's rows of [`datasheet_table_text`].
fn sensor_table_text(axes: &[&AxisResult], sensor: Option<SensorKind>) -> String {
    let title = match sensor {
        Some(SensorKind::Gyro) => "Gyro",
        Some(SensorKind::Accel) => "Accel",
        None => "Terms",
    };
    let mut devices = vec![title.to_string(), String::new()];
    let mut names = vec![String::new(), "unit".to_string()];
    let mut previous: Option<&str> = None;
    for a in axes {
        let first = previous != Some(a.device.as_str());
        devices.push(if first {
            a.device.clone()
        } else {
            String::new()
        });
        names.push(short_axis(&a.axis, sensor).to_string());
        previous = Some(&a.device);
    }
    let mut rows = vec![devices, names];
    let terms: Vec<(String, Term)> = match sensor {
        Some(kind) => DATASHEET_ROWS
            .iter()
            .filter(|(_, s, _)| *s == kind)
            .map(|(label, _, term)| {
                let short = label
                    .strip_prefix("Gyro ")
                    .or_else(|| label.strip_prefix("Accel "))
                    .unwrap_or(label);
                (short.to_string(), *term)
            })
            .collect(),
        None => Term::ALL
            .iter()
            .map(|t| (t.symbol().to_string(), *t))
            .collect(),
    };
    for (label, term) in terms {
        let mut row = vec![label, String::new()];
        for a in axes {
            let v = a
                .terms
                .iter()
                .find(|t| t.term == term)
                .and_then(|t| t.values.first());
            if let Some(v) = v {
                row[1] = pretty_unit(&v.unit);
            }
            row.push(match v {
                Some(v) => v
                    .value
                    .map(sig3)
                    .unwrap_or_else(|| format!("<{}", sig3(v.high))),
                None => String::new(),
            });
        }
        rows.push(row);
    }
    let widths: Vec<usize> = (0..rows[0].len())
        .map(|c| {
            rows.iter()
                .map(|r| r.get(c).map_or(0, |s| s.chars().count()))
                .max()
                .unwrap_or(0)
        })
        .collect();
    let mut out = String::new();
    for r in rows {
        let line: Vec<String> = r
            .iter()
            .zip(&widths)
            .map(|(s, w)| format!("{s:<w$}"))
            .collect();
        let _ = writeln!(out, "{}", line.join("  ").trim_end());
    }
    out
}

/// The analysed axes' health: one sentence when every axis is clean, else the table.
fn axes_health_html(axes: &[&AxisResult]) -> String {
    let clean = |a: &&AxisResult| {
        let h = &a.health;
        h.gaps == 0 && h.invalid_values == 0 && h.nonuniform_intervals == 0 && h.segments <= 1
    };
    let mut html = String::from("<h3>Analysed axes</h3>");
    if !axes.is_empty() && axes.iter().all(clean) {
        let samples: Vec<u64> = axes.iter().map(|a| a.health.samples).collect();
        let (lo, hi) = (
            samples.iter().min().copied().unwrap_or(0),
            samples.iter().max().copied().unwrap_or(0),
        );
        let durations = axes.iter().map(|a| a.health.duration_s);
        let longest = durations.fold(0.0, f64::max);
        let _ = write!(
            html,
            "<p class=\"good\">All {} analysed axes are clean: {} samples each over up to {}, τ0 = {} ms, no gaps, no NaN/Inf, no irregular intervals.</p>",
            axes.len(),
            if lo == hi {
                lo.to_string()
            } else {
                format!("{lo}–{hi}")
            },
            duration(longest),
            sig3(axes[0].tau0 * 1e3)
        );
        return html;
    }
    html.push_str("<div class=\"scroll\">");
    html.push_str(&health_table_html(axes));
    html.push_str("</div>");
    html
}

fn health_table_html(axes: &[&AxisResult]) -> String {
    let mut html = String::from(
        "<table><thead><tr><th>device</th><th>axis</th><th>samples</th><th>duration</th><th>τ0</th><th>policy</th><th>gaps</th><th>gaps found on</th><th>missing</th><th>NaN/Inf</th><th>non-uniform</th><th>segments</th><th>temperature</th><th>first problem</th></tr></thead><tbody>",
    );
    for a in axes {
        let h = &a.health;
        let temp = match (h.temperature_min, h.temperature_max) {
            (Some(lo), Some(hi)) => format!("{lo:.1} … {hi:.1} °C"),
            _ => "–".into(),
        };
        let _ = write!(
            html,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{:.1} s</td><td>{} s</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            escape(&a.device),
            escape(&a.axis),
            h.samples,
            h.duration_s,
            sig3(a.tau0),
            h.policy.map(|p| format!("{p:?}").to_lowercase()).unwrap_or_default(),
            h.gaps,
            escape(h.clock.as_deref().unwrap_or("–")),
            h.missing_samples,
            h.invalid_values,
            h.nonuniform_intervals,
            h.segments,
            temp,
            escape(h.first_problem.as_deref().unwrap_or("none"))
        );
    }
    html.push_str("</tbody></table>");
    html
}

/// The report's plots: one per device and sensor, titled "device sensor", in input order.
pub fn plot_groups(report: &AllanReport) -> Vec<(String, Vec<&AxisResult>)> {
    let mut groups: Vec<(String, Option<SensorKind>)> = Vec::new();
    for a in &report.axes {
        let key = (a.device.clone(), a.sensor);
        if !groups.contains(&key) {
            groups.push(key);
        }
    }
    groups
        .into_iter()
        .map(|(device, sensor)| {
            let members: Vec<&AxisResult> = report
                .axes
                .iter()
                .filter(|a| a.device == device && a.sensor == sensor)
                .collect();
            let label = match sensor {
                Some(SensorKind::Gyro) => " gyro",
                Some(SensorKind::Accel) => " accel",
                None => "",
            };
            (format!("{device}{label}"), members)
        })
        .collect()
}

/// Page style: readable on a laptop and in print; wide tables scroll inside their box
/// instead of widening the page.
pub const PAGE_STYLE: &str = "body{font-family:sans-serif;margin:1.5em 2em;color:#222;max-width:1200px}\
h1{margin-bottom:0.2em}h2{margin-top:1.6em;border-bottom:1px solid #ccc;padding-bottom:0.2em}\
table{border-collapse:collapse;margin:0.6em 0}td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}\
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}\
.scroll{overflow-x:auto;max-width:100%}.meta{color:#555;font-size:0.9em}\
.verdict{font-size:1.15em;background:#eef6ee;border-left:4px solid #2ca02c;padding:0.5em 0.8em}\
.note{color:#555;font-size:0.9em;max-width:60em}.bad{background:#fde8e8;font-weight:bold}\
.good{color:#1a7f37}.health td{white-space:nowrap}\
.plots{display:grid;grid-template-columns:repeat(auto-fill,minmax(540px,1fr));gap:0.8em}\
.plots svg{width:100%;height:auto;border:1px solid #eee}\
small{color:#666}summary{margin:0.8em 0;font-weight:bold}";

/// The self-contained HTML report, in the order a reader needs it: summary (which IMU is
/// better, by how much, what it means for GNSS outages), the datasheet table, the curves,
/// then data health. No scripts, no external resources. The health of every session among
/// `report.input` is read from the session (events, temperature): see
/// [`html_report_with_sessions`] to pass it in instead.
pub fn html_report(report: &AllanReport, title: &str) -> String {
    html_report_with_sessions(report, title, &health::sessions_of_report(report), None)
}

/// [`html_report`] whose GNSS-outage headline is the filter-based answer of `study`
/// (`imulab study --json`), the closed-form figure shown as a labelled analytic bound.
pub fn html_report_with_study(report: &AllanReport, title: &str, study: &StudyResult) -> String {
    html_report_with_sessions(
        report,
        title,
        &health::sessions_of_report(report),
        Some(study),
    )
}

/// `page` (from [`html_report`]) with `section` (an HTML fragment) before the data health.
pub fn with_section(page: &str, section: &str) -> String {
    match page.find(DATA_HEALTH_HEADING) {
        Some(at) => format!("{}{section}{}", &page[..at], &page[at..]),
        None => page.replacen("</body>", &format!("{section}</body>"), 1),
    }
}

const DATA_HEALTH_HEADING: &str = "<h2>4. Data health</h2>";

/// [`html_report`] with the sessions' health given (an `Err` is shown as that input's
/// problem line).
pub fn html_report_with_sessions(
    report: &AllanReport,
    title: &str,
    sessions: &[Result<SessionHealth, String>],
    study: Option<&StudyResult>,
) -> String {
    let mut html = String::new();
    let _ = write!(
        html,
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title><style>{PAGE_STYLE}</style></head><body><h1>{}</h1>",
        escape(title),
        escape(title)
    );
    let _ = write!(
        html,
        "<p class=\"meta\">{} · input: {} · {} over the {} τ grid, curve bands {:.1} % (chi-squared, noise-type-aware EDF), fitted terms with 95 % intervals.</p>",
        escape(&report.generator),
        escape(&report.input.join(", ")),
        report.kind.name().to_uppercase(),
        escape(&report.grid),
        report.confidence * 100.0
    );
    html.push_str("<h2>1. Summary</h2>");
    html.push_str(&summary_html_with_study(report, study));
    let all: Vec<&AxisResult> = report.axes.iter().collect();
    html.push_str("<h2>2. Noise terms, datasheet style</h2><p class=\"note\">Each cell: fitted value, and under it <small>its 95 % interval</small>. <b>n.i.</b> = not identified: the curve does not show this term; the bound is the largest value the data allow (not zero, not a measurement).</p>");
    // One table per sensor, so no column is half empty.
    let mut hidden = Vec::new();
    for sensor in [Some(SensorKind::Gyro), Some(SensorKind::Accel), None] {
        let members: Vec<&AxisResult> =
            all.iter().copied().filter(|a| a.sensor == sensor).collect();
        if !members.is_empty() {
            let (table, h) = datasheet_table(&members, true);
            hidden.extend(h);
            let _ = write!(html, "<div class=\"scroll\">{table}</div>");
        }
    }
    if !hidden.is_empty() {
        let _ = write!(
            html,
            "<p class=\"note\">Not identified on any axis, so not shown: {} (a longer run may reveal them; their bounds are in the JSON).</p>",
            escape(&hidden.join(", "))
        );
    }
    html.push_str("<h2>3. Allan deviation curves</h2>");
    let _ = write!(
        html,
        "<p class=\"note\">One plot per device and sensor, log-log, in the input's units (rad/s for gyros and m/s² for accelerometers of a session; the tables above use datasheet units). {}</p><div class=\"plots\">",
        escape(LINE_STYLE_NOTE)
    );
    for (title, members) in plot_groups(report) {
        // Inline SVG in HTML needs no namespace; without it the page holds no URL at all.
        html.push_str(&svg_plot(&members, &title).replacen(SVG_NAMESPACE, "", 1));
    }
    html.push_str("</div>");
    html.push_str("<details><summary>Slope-line readings (MATLAB <code>allanvar</code> style, for comparison)</summary><div class=\"scroll\"><table><thead><tr><th>device</th><th>axis</th><th>N (τ=1 s on the −½ line)</th><th>B = minimum ÷ 0.664</th><th>minimum at τ [s]</th><th>K (τ=3 s on the +½ line)</th></tr></thead><tbody>");
    for a in &report.axes {
        if let Some(s) = &a.slopes {
            let f = |v: Option<f64>| v.map(sig3).unwrap_or_else(|| "–".into());
            let _ = write!(
                html,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                escape(&a.device),
                escape(&a.axis),
                f(s.random_walk),
                f(s.bias_instability),
                f(s.bias_instability_tau),
                f(s.rate_random_walk)
            );
        }
    }
    html.push_str("</tbody></table></div><p class=\"note\">Slope readings are in the input units (N in unit·√s, B in unit, K in unit/√s; rad/s for gyros and m/s² for accelerometers of a session).</p></details>");
    // Bias against temperature only says something when the run spans at least a bin width.
    let thermal: Vec<&AxisResult> = report
        .axes
        .iter()
        .filter(|a| {
            let span =
                a.health.temperature_max.unwrap_or(0.0) - a.health.temperature_min.unwrap_or(0.0);
            a.thermal
                .as_ref()
                .is_some_and(|t| t.bins.len() > 1 && span >= t.bin_width)
        })
        .collect();
    if !thermal.is_empty() {
        html.push_str("<h3>Bias against temperature</h3><div class=\"scroll\"><table><thead><tr><th>device</th><th>axis</th><th>coefficient</th><th>± (1σ)</th><th>unit</th><th>bins (T: mean ± spread)</th></tr></thead><tbody>");
        for a in thermal {
            if let Some(t) = &a.thermal {
                let bins: Vec<String> = t
                    .bins
                    .iter()
                    .map(|b| {
                        format!(
                            "{:.1} °C: {} ± {}",
                            b.temperature,
                            sig3(b.mean),
                            sig3(b.spread)
                        )
                    })
                    .collect();
                let in_units = |v: f64| thermal_coefficient_in_units(v, a.sensor, a.unit);
                let _ = write!(
                    html,
                    "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td style=\"text-align:left\">{}</td></tr>",
                    escape(&a.device),
                    escape(&a.axis),
                    t.coefficient.map(|c| sig3(in_units(c).value)).unwrap_or_else(|| "–".into()),
                    t.coefficient_std_error.map(|e| sig3(in_units(e).value)).unwrap_or_else(|| "–".into()),
                    escape(&pretty_unit(&in_units(0.0).unit)),
                    escape(&bins.join("; "))
                );
            }
        }
        html.push_str("</tbody></table></div>");
    }
    html.push_str(DATA_HEALTH_HEADING);
    for s in sessions {
        match s {
            Ok(s) => html.push_str(&session_health_html(s)),
            Err(e) => {
                let _ = write!(html, "<p class=\"bad\">{}</p>", escape(e));
            }
        }
    }
    html.push_str(&axes_health_html(&all));
    html.push_str("</body></html>\n");
    html
}

/// Headline terms of the summary: (label, sensor, term).
const HEADLINE_TERMS: [(&str, SensorKind, Term); 4] = [
    (
        "Gyro angle random walk (ARW)",
        SensorKind::Gyro,
        Term::RandomWalk,
    ),
    (
        "Gyro bias instability",
        SensorKind::Gyro,
        Term::BiasInstability,
    ),
    (
        "Accel velocity random walk (VRW)",
        SensorKind::Accel,
        Term::RandomWalk,
    ),
    (
        "Accel bias instability",
        SensorKind::Accel,
        Term::BiasInstability,
    ),
];

/// A device's headline value: mean over its axes of the first engineering unit, with how
/// many axes identified the term; or, with none identified, the largest bound.
#[derive(Debug, Clone, PartialEq)]
enum Headline {
    Value {
        value: f64,
        /// Means of the identified axes' 95 % bounds.
        low: f64,
        high: f64,
        unit: String,
        axes: usize,
        of: usize,
    },
    Bound {
        high: f64,
        unit: String,
    },
}

fn headline(
    report: &AllanReport,
    device: &str,
    sensor: SensorKind,
    term: Term,
) -> Option<Headline> {
    let values: Vec<&crate::allan::units::UnitValue> = report
        .axes
        .iter()
        .filter(|a| a.device == device && a.sensor == Some(sensor) && !a.axis.contains(" @ "))
        .filter_map(|a| a.terms.iter().find(|t| t.term == term)?.values.first())
        .collect();
    let unit = values.first()?.unit.clone();
    let identified: Vec<(f64, f64, f64)> = values
        .iter()
        .filter_map(|v| Some((v.value?, v.low, v.high)))
        .collect();
    if identified.is_empty() {
        let high = values.iter().map(|v| v.high).fold(0.0, f64::max);
        return Some(Headline::Bound { high, unit });
    }
    let n = identified.len() as f64;
    let mean = |f: fn(&(f64, f64, f64)) -> f64| identified.iter().map(f).sum::<f64>() / n;
    Some(Headline::Value {
        value: mean(|v| v.0),
        low: mean(|v| v.1),
        high: mean(|v| v.2),
        unit,
        axes: identified.len(),
        of: values.len(),
    })
}

/// The devices of a report, in input order.
fn devices(report: &AllanReport) -> Vec<&str> {
    let mut out: Vec<&str> = Vec::new();
    for a in &report.axes {
        if !out.contains(&a.device.as_str()) {
            out.push(&a.device);
        }
    }
    out
}

fn seconds(v: Option<f64>) -> String {
    match v {
        None => "–".into(),
        Some(t) if t >= 1e6 => "&gt; 10⁶ s".into(),
        Some(t) if t >= 120.0 => format!("{} s ({:.1} min)", sig3(t), t / 60.0),
        Some(t) => format!("{} s", sig3(t)),
    }
}

/// The summary: verdict, headline terms side by side with ratios, and the GNSS-outage
/// horizons of each device.
pub fn summary_html(report: &AllanReport) -> String {
    summary_html_with_study(report, None)
}

/// The study's answer for `device` at the requirement closest to 1 m: (requirement, bridge).
fn study_bridge<'a>(study: Option<&'a StudyResult>, device: &str) -> Option<&'a Bridge> {
    study?.grade_for(device)?.bridges.iter().min_by(|a, b| {
        (a.requirement_m - 1.0)
            .abs()
            .total_cmp(&(b.requirement_m - 1.0).abs())
    })
}

/// [`summary_html`] with the filter-based outage answer of `study` as the headline.
pub fn summary_html_with_study(report: &AllanReport, study: Option<&StudyResult>) -> String {
    let devices = devices(report);
    let outages = outage::device_outages(report);
    let mut html = String::new();
    // Verdict: which device wins more headline terms; by how much on the 1 m horizon.
    let mut wins: Vec<usize> = vec![0; devices.len()];
    let mut compared = 0;
    let mut rows = String::new();
    for (label, sensor, term) in HEADLINE_TERMS {
        let values: Vec<Option<Headline>> = devices
            .iter()
            .map(|d| headline(report, d, sensor, term))
            .collect();
        let Some(unit) = values
            .iter()
            .flatten()
            .map(|h| match h {
                Headline::Value { unit, .. } | Headline::Bound { unit, .. } => unit.clone(),
            })
            .next()
        else {
            continue;
        };
        let _ = write!(
            rows,
            "<tr><td>{}</td><td>{}</td>",
            escape(label),
            escape(&pretty_unit(&unit))
        );
        let numbers: Vec<Option<f64>> = values
            .iter()
            .map(|h| match h {
                Some(Headline::Value { value, .. }) => Some(*value),
                _ => None,
            })
            .collect();
        let bounds: Vec<Option<(f64, f64)>> = values
            .iter()
            .map(|h| match h {
                Some(Headline::Value { low, high, .. }) => Some((*low, *high)),
                _ => None,
            })
            .collect();
        let best = numbers
            .iter()
            .enumerate()
            .filter_map(|(i, v)| Some((i, (*v)?)))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        for (i, h) in values.iter().enumerate() {
            let cell = match h {
                Some(Headline::Value {
                    value, axes, of, ..
                }) => {
                    let mut text = sig3(*value);
                    if axes < of {
                        let _ = write!(text, " <small>({axes} of {of} axes)</small>");
                    }
                    if devices.len() > 1 && best.is_some_and(|(b, _)| b == i) {
                        format!("<b class=\"good\">{text}</b>")
                    } else {
                        text
                    }
                }
                Some(Headline::Bound { high, .. }) => {
                    format!("n.i. <small>(&lt; {})</small>", sig3(*high))
                }
                None => "–".into(),
            };
            let _ = write!(rows, "<td>{cell}</td>");
        }
        if devices.len() > 1 {
            let known: Vec<f64> = numbers.iter().flatten().copied().collect();
            let cell = match best {
                Some((b, low)) if known.len() > 1 && low > 0.0 => {
                    wins[b] += 1;
                    compared += 1;
                    let (w, worst) = numbers
                        .iter()
                        .enumerate()
                        .filter_map(|(i, v)| Some((i, (*v)?)))
                        .max_by(|a, b| a.1.total_cmp(&b.1))
                        .unwrap_or((b, low));
                    // Overlapping 95 % intervals: the difference is not established.
                    let overlap = match (bounds[b], bounds[w]) {
                        (Some((_, best_high)), Some((worst_low, _))) => worst_low <= best_high,
                        _ => false,
                    };
                    format!(
                        "<b>{}</b> {:.1}× lower{}",
                        escape(devices[b]),
                        worst / low,
                        if overlap {
                            " <small>(95 % intervals overlap)</small>"
                        } else {
                            ""
                        }
                    )
                }
                _ => "not comparable (term not identified)".into(),
            };
            let _ = write!(rows, "<td>{cell}</td>");
        }
        rows.push_str("</tr>");
    }
    // The 1 m horizon and whether it is only a lower bound (a term entered as its bound).
    let horizon = |d: &str| {
        outages
            .iter()
            .flatten()
            .find(|o| o.device == d)
            .and_then(|o| Some((o.one_metre_s?, !o.bounded.is_empty())))
    };
    if devices.len() > 1 && compared > 0 {
        let (best, n) = wins
            .iter()
            .enumerate()
            .max_by_key(|(_, w)| **w)
            .map(|(i, w)| (i, *w))
            .unwrap_or((0, 0));
        let mut verdict = format!(
            "<b>{}</b> is the better IMU: lower on {n} of the {compared} headline noise terms",
            escape(devices[best])
        );
        let filter_based: Option<Vec<&Bridge>> =
            devices.iter().map(|d| study_bridge(study, d)).collect();
        if let Some(bridges) = filter_based {
            // The filter-based answer; "longer" only where the 95 % intervals do not overlap.
            let b = bridges[best];
            let others: Vec<String> = devices
                .iter()
                .zip(&bridges)
                .enumerate()
                .filter(|(i, _)| *i != best)
                .map(|(_, (d, o))| {
                    let separated = match (b.ci95_s, o.ci95_s) {
                        (Some([lo, _]), Some([_, hi])) => lo > hi,
                        _ => false,
                    };
                    match (b.longest_s, o.longest_s) {
                        (Some(x), Some(y)) if separated && y > 0.0 => format!(
                            "{}{:.1}× as long as {} ({})",
                            if b.beyond_horizon { "at least " } else { "" },
                            x / y,
                            escape(d),
                            escape(&o.text())
                        ),
                        _ => format!(
                            "not established against {} ({}; 95 % intervals overlap)",
                            escape(d),
                            escape(&o.text())
                        ),
                    }
                })
                .collect();
            let _ = write!(
                verdict,
                "; in the filter-based study ({} runs) it bridges a GNSS outage within {} m for {}: {}",
                study.map_or(0, |s| s.runs),
                b.requirement_m,
                escape(&b.text()),
                others.join(", ")
            );
        } else if let Some((h_best, best_bounded)) = horizon(devices[best]) {
            let others: Vec<String> = devices
                .iter()
                .enumerate()
                .filter(|(i, _)| *i != best)
                .filter_map(|(_, d)| {
                    let (h, bounded) = horizon(d)?;
                    // A bound on the best device's horizon bounds the ratio from below; a
                    // bound on the other's leaves the ratio open.
                    let qualifier = match (best_bounded, bounded) {
                        (false, false) => "",
                        (true, false) => "at least ",
                        _ => "about ",
                    };
                    Some(format!(
                        "{qualifier}{:.1}× that of {}",
                        h_best / h,
                        escape(d)
                    ))
                })
                .collect();
            if !others.is_empty() {
                let _ = write!(
                    verdict,
                    " (its free-inertial analytic bound for a GNSS outage within 1 m is {}; no filter-based study)",
                    others.join(", ")
                );
            }
        }
        verdict.push('.');
        let _ = write!(html, "<p class=\"verdict\">{verdict}</p>");
    } else if devices.len() > 1 {
        html.push_str("<p class=\"verdict\">The devices cannot be ranked: the headline terms were not identified (see the table).</p>");
    }
    if !rows.is_empty() {
        html.push_str("<table><thead><tr><th>headline term (mean of the axes)</th><th>unit</th>");
        for d in &devices {
            let _ = write!(html, "<th>{}</th>", escape(d));
        }
        if devices.len() > 1 {
            html.push_str("<th>better</th>");
        }
        let _ = write!(html, "</tr></thead><tbody>{rows}</tbody></table>");
    }
    // Outage bridging.
    html.push_str("<h3>What this means for bridging a GNSS outage</h3>");
    if let Some(study) = study {
        let reqs = study.requirements_m();
        html.push_str("<p>Filter-based answer (<code>imulab study</code>: the GNSS/INS filter on a simulated drive, p95 of the outages, 95 % interval over runs):</p><table><thead><tr><th>device</th>");
        for r in &reqs {
            let _ = write!(html, "<th>within {r} m</th>");
        }
        html.push_str("</tr></thead><tbody>");
        for d in &devices {
            let _ = write!(html, "<tr><td>{}</td>", escape(d));
            match study.grade_for(d) {
                Some(g) => {
                    for b in &g.bridges {
                        let _ = write!(html, "<td>{}</td>", escape(&b.text()));
                    }
                }
                None => {
                    let _ = write!(
                        html,
                        "<td colspan=\"{}\">not in the study (grades: {})</td>",
                        reqs.len(),
                        escape(
                            &study
                                .grades
                                .iter()
                                .map(|g| g.name.as_str())
                                .collect::<Vec<_>>()
                                .join(", ")
                        )
                    );
                }
            }
            html.push_str("</tr>");
        }
        let _ = write!(
            html,
            "</tbody></table><p class=\"note\">{} runs of a {:.0} s drive, {} outages per run; \"≥\": within the requirement for the whole longest simulated outage.</p>",
            study.runs, study.scene_duration_s, study.outages_per_run
        );
    } else {
        html.push_str("<p>No filter-based study: <code>imulab report</code> runs one of the fitted IMUs unless <code>--study-runs 0</code>, or when a fit does not give the white noise of both sensors (or give one: <code>imulab study … --json STUDY.json</code>, then <code>imulab report … --study STUDY.json</code>); below is the analytic bound only.</p>");
    }
    html.push_str("<table><thead><tr><th>device</th><th>analytic bound, within 0.1 m (lane level)</th><th>analytic bound, within 1 m</th><th>largest error source at 1 m</th></tr></thead><tbody>");
    let mut any_bounded = false;
    for o in &outages {
        match o {
            Ok(o) => {
                let prefix = if o.bounded.is_empty() {
                    ""
                } else {
                    any_bounded = true;
                    "≥ "
                };
                let _ = write!(
                    html,
                    "<tr><td>{}</td><td>{prefix}{}</td><td>{prefix}{}</td><td>{}</td></tr>",
                    escape(&o.device),
                    seconds(o.lane_level_s),
                    seconds(o.one_metre_s),
                    o.one_metre_s.map(|t| o.terms.dominant(t)).unwrap_or("–")
                );
            }
            Err(e) => {
                let _ = write!(
                    html,
                    "<tr><td>{}</td><td colspan=\"3\" style=\"text-align:left\">no figure: {}</td></tr>",
                    escape(&e.device),
                    escape(&e.reason)
                );
            }
        }
    }
    html.push_str("</tbody></table>");
    let _ = write!(
        html,
        "<p class=\"note\">Analytic bound: longest GNSS outage during which the free-inertial horizontal position error (one horizontal channel, 1σ, straight and level, no aiding) stays within the limit, from the fitted terms of the x and y axes: accel bias ½·b·t², gyro bias through tilt g·b<sub>g</sub>·t³/6, VRW σ<sub>v</sub>·t<sup>3/2</sup>/√3, ARW through tilt g·N·t<sup>5/2</sup>/√20, added as a root sum of squares (Groves, <i>Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems</i>, 2nd ed., §5.7); the biases are the bias instabilities, i.e. what a filter could not have estimated before the outage.{} Initial attitude and velocity errors and the filter are left out, so this is not the answer to quote: the filter-based study is.</p>",
        if any_bounded {
            " ≥: a term was not identified and entered with its upper bound, so the real horizon is at least this long."
        } else {
            ""
        }
    );
    html
}

/// The data-health tables of one session: its devices and their events.
fn session_health_html(s: &SessionHealth) -> String {
    let mut html = String::new();
    let _ = write!(
        html,
        "<p class=\"meta\">Session <code>{}</code> · id {} · started {} on {} · {} chunk file(s).</p>",
        escape(&s.path),
        escape(&s.id),
        escape(&s.start_time),
        escape(&s.host),
        s.files
    );
    html.push_str("<div class=\"scroll\"><table class=\"health\"><thead><tr><th>device</th><th>model (protocol)</th><th>samples</th><th>span</th><th>rate: nominal / effective</th><th>gaps (missing samples)</th><th>NaN/Inf</th><th>temperature: min / mean / max</th><th>logger events</th></tr></thead><tbody>");
    for d in &s.devices {
        let gaps = match (d.gaps, d.missing_samples) {
            (Some(0), _) => "none".into(),
            (Some(g), Some(m)) => format!("{g} ({m})"),
            (Some(g), None) => g.to_string(),
            _ => "–".into(),
        };
        let bad = |n: u64| if n > 0 { " class=\"bad\"" } else { "" };
        let temperature = d
            .temperature
            .map(|t| format!("{:.1} / {:.1} / {:.1} °C", t.min, t.mean, t.max))
            .unwrap_or_else(|| "–".into());
        // Problems first (highlighted), then the routine events.
        let mut events: Vec<String> = Vec::new();
        let mut problem = false;
        for kind in health::PROBLEM_EVENTS {
            if let Some(n) = d.events.get(kind).filter(|n| **n > 0) {
                problem = true;
                events.push(format!("<b>{} {n}</b>", kind.replace('_', " ")));
            }
        }
        for (k, n) in d
            .events
            .iter()
            .filter(|(k, _)| !health::PROBLEM_EVENTS.contains(&k.as_str()))
        {
            events.push(format!("{} {n}", escape(&k.replace('_', " "))));
        }
        if !problem {
            events.insert(0, "no problems".into());
        }
        let _ = write!(
            html,
            "<tr><td>{}</td><td style=\"text-align:left\">{} ({})</td><td>{}</td><td>{}</td><td>{} / {} Hz</td><td{}>{gaps}</td><td{}>{}</td><td>{temperature}</td><td{} style=\"text-align:left;white-space:normal\">{}</td></tr>",
            escape(&d.name),
            escape(&d.model),
            escape(&d.protocol),
            d.rows,
            duration(d.span_s),
            sig3(d.nominal_rate_hz),
            d.effective_rate_hz.map(sig3).unwrap_or_else(|| "–".into()),
            bad(d.gaps.unwrap_or(0)),
            bad(d.invalid_values.unwrap_or(0)),
            d.invalid_values.map(|n| n.to_string()).unwrap_or_else(|| "–".into()),
            bad(u64::from(problem)),
            events.join(", ")
        );
    }
    html.push_str("</tbody></table></div>");
    let session_events: Vec<String> = s
        .session_events
        .iter()
        .map(|(k, n)| format!("{} {n}", k.replace('_', " ")))
        .collect();
    let _ = write!(
        html,
        "<p class=\"note\">Logger events are counted from the session's <code>/events</code> (an event whose detail says <code>count=N</code> counts N frames): gaps, resyncs, checksum errors, queue overflows (dropped frames), disconnects and low disk are problems. Session-wide events: {}.</p>",
        if session_events.is_empty() {
            "none".to_string()
        } else {
            escape(&session_events.join(", "))
        }
    );
    if s.problems.is_empty() {
        html.push_str("<p class=\"good\">Every chunk file was readable.</p>");
    } else {
        html.push_str("<ul>");
        for p in &s.problems {
            let _ = write!(html, "<li class=\"bad\">{}</li>", escape(p));
        }
        html.push_str("</ul>");
    }
    html
}

/// PNG plot of all axes of a report (plotters; needs a system font for the labels).
pub fn write_png(report: &AllanReport, path: &Path) -> anyhow::Result<()> {
    let axes: Vec<&AxisResult> = report.axes.iter().collect();
    write_png_axes(
        &axes,
        &format!("{} ({})", report.kind.title(), report.grid),
        path,
    )
}

/// PNG of `axes`: curves, confidence bands, fitted total and labelled term lines.
pub fn write_png_axes(axes: &[&AxisResult], title: &str, path: &Path) -> anyhow::Result<()> {
    use plotters::prelude::*;
    // Slide size (3:2) with fonts readable when the image is shrunk into a slide or mail.
    let root = BitMapBackend::new(path, (1200, 800)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut tau = (f64::INFINITY, f64::NEG_INFINITY);
    let mut dev = (f64::INFINITY, f64::NEG_INFINITY);
    for a in axes {
        for p in a.curve.points.iter().filter(|p| p.deviation > 0.0) {
            tau = (tau.0.min(p.tau), tau.1.max(p.tau));
            dev = (
                dev.0
                    .min(p.low.unwrap_or(p.deviation).max(p.deviation * 1e-3)),
                dev.1.max(p.high.unwrap_or(p.deviation)),
            );
        }
    }
    anyhow::ensure!(tau.0.is_finite() && dev.0.is_finite(), "nothing to plot");
    let y_range = (dev.0 / 1.5, dev.1 * 1.5);
    let (plot_area, note_area) = root.split_vertically(764);
    if axes.iter().any(|a| a.fit.is_some()) {
        note_area.draw(&Text::new(
            LINE_STYLE_NOTE,
            (15, 6),
            ("sans-serif", 15).into_font(),
        ))?;
    }
    let mut chart = ChartBuilder::on(&plot_area)
        .caption(title, ("sans-serif", 30))
        .margin(20)
        .x_label_area_size(60)
        .y_label_area_size(100)
        .build_cartesian_2d(
            (tau.0 / 1.5..tau.1 * 1.5).log_scale(),
            (y_range.0..y_range.1).log_scale(),
        )?;
    chart
        .configure_mesh()
        .x_desc("averaging time tau [s]")
        .label_style(("sans-serif", 18))
        .axis_desc_style(("sans-serif", 20))
        .y_desc(format!(
            "{} [{}]",
            axes.first()
                .map(|a| a.curve.kind.name().to_uppercase())
                .unwrap_or_default(),
            axes.first().map(|a| a.unit.symbol()).unwrap_or("")
        ))
        .x_label_formatter(&|v| format!("{v:.0e}"))
        .y_label_formatter(&|v| format!("{v:.0e}"))
        .draw()?;
    for (i, a) in axes.iter().enumerate() {
        // The page's colours, so a PNG and its SVG look alike.
        let hex = COLORS[i % COLORS.len()];
        let channel = |at: usize| u8::from_str_radix(&hex[at..at + 2], 16).unwrap_or(0);
        let color = RGBColor(channel(1), channel(3), channel(5)).to_rgba();
        let pts: Vec<_> = a
            .curve
            .points
            .iter()
            .filter(|p| p.deviation > 0.0)
            .collect();
        let band: Vec<(f64, f64)> = pts
            .iter()
            .filter_map(|p| Some((p.tau, p.high?)))
            .chain(
                pts.iter()
                    .rev()
                    .filter_map(|p| Some((p.tau, p.low?.max(dev.0 / 1.5)))),
            )
            .collect();
        if band.len() > 2 {
            chart.draw_series(std::iter::once(Polygon::new(band, color.mix(0.15))))?;
        }
        chart
            .draw_series(LineSeries::new(
                pts.iter().map(|p| (p.tau, p.deviation)),
                color.stroke_width(2),
            ))?
            .label(format!("{} {}", a.device, a.axis))
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
            });
        if let Some(fit) = &a.fit {
            chart.draw_series(DashedLineSeries::new(
                pts.iter()
                    .map(|p| (p.tau, fit.model_deviation(p.tau)))
                    .filter(|(_, d)| *d > 0.0),
                6,
                4,
                color.stroke_width(1),
            ))?;
            if let (Some(first), Some(last)) = (pts.first(), pts.last()) {
                for line in term_lines(fit, first.tau, last.tau) {
                    // Clip by hand: plotters draws outside the axis range otherwise.
                    let Some((from, to)) = clip_log_segment(line.from, line.to, y_range) else {
                        continue;
                    };
                    chart.draw_series(DashedLineSeries::new(
                        [from, to],
                        3,
                        4,
                        color.stroke_width(2),
                    ))?;
                    if (y_range.0..=y_range.1).contains(&line.label_at.1) {
                        // Below the line: the measured curve runs above the asymptotes.
                        chart.draw_series(std::iter::once(
                            EmptyElement::at(line.label_at)
                                + Text::new(
                                    line.term.symbol().to_string(),
                                    (-5, 6),
                                    ("sans-serif", 22).into_font().color(&color),
                                ),
                        ))?;
                    }
                }
            }
        }
    }
    chart
        .configure_series_labels()
        // Allan curves are bowls: the top middle is the emptiest place.
        .position(SeriesLabelPosition::UpperMiddle)
        .label_font(("sans-serif", 18))
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}

/// Clips the log-log straight segment `from`–`to` to `lo ≤ σ ≤ hi` (None when outside).
fn clip_log_segment(
    from: (f64, f64),
    to: (f64, f64),
    (lo, hi): (f64, f64),
) -> Option<((f64, f64), (f64, f64))> {
    let (x0, y0, x1, y1) = (from.0.ln(), from.1.ln(), to.0.ln(), to.1.ln());
    let (lo, hi) = (lo.ln(), hi.ln());
    let at = |y: f64| {
        if y1 == y0 {
            x0
        } else {
            x0 + (x1 - x0) * (y - y0) / (y1 - y0)
        }
    };
    let clamp_point = |x: f64, y: f64| -> (f64, f64) {
        if y < lo {
            (at(lo), lo)
        } else if y > hi {
            (at(hi), hi)
        } else {
            (x, y)
        }
    };
    if (y0 < lo && y1 < lo) || (y0 > hi && y1 > hi) {
        return None;
    }
    let a = clamp_point(x0, y0);
    let b = clamp_point(x1, y1);
    Some(((a.0.exp(), a.1.exp()), (b.0.exp(), b.1.exp())))
}
