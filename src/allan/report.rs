//! Writers for results: CSV, a self-contained HTML page (inline SVG drawn here, no
//! network, no fonts needed), PNG plots (plotters) and the datasheet-style comparison
//! table (rows: noise terms; columns: device × axis).
//!
//! The SVG is written by hand because plotters' text layout needs system fonts, which a
//! report must not depend on; PNG output uses plotters.

use super::analysis::{AllanReport, AxisResult};
use super::fit::{NoiseFit, Term};
use super::units::SensorKind;
use std::fmt::Write as _;
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

const COLORS: [&str; 8] = [
    "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2",
];

fn escape(text: &str) -> String {
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

/// A log-log SVG of several axes' curves with confidence bands, the fitted total and each
/// identified term's own line, labelled.
pub fn svg_plot(axes: &[&AxisResult], title: &str) -> String {
    let (width, height) = (720.0, 460.0);
    let (left, right, top, bottom) = (80.0, 20.0, 30.0, 50.0);
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
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="11">"#
    );
    let _ = write!(
        svg,
        r#"<text x="{}" y="18" font-size="13" text-anchor="middle">{}</text>"#,
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
            r#"<text x="{x:.1}" y="{:.1}" text-anchor="middle">1e{d}</text>"#,
            height - bottom + 16.0
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
            r#"<text x="{:.1}" y="{:.1}" text-anchor="end">1e{d}</text>"#,
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
        r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">τ [s]</text>"#,
        (left + width - right) / 2.0,
        height - 12.0
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
        let ly_text = top + 16.0 + 15.0 * i as f64;
        let _ = write!(
            svg,
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
    let _ = write!(
        svg,
        r##"<text x="{left}" y="{:.1}" font-size="9" fill="#555">{}</text>"##,
        height - 2.0,
        escape(if axes.iter().any(|a| a.fit.is_some()) {
            LINE_STYLE_NOTE
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
            escape(&unit)
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
                            "{} <small>[{} – {}]</small>",
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
    html
}

/// Plain-text version of the comparison table for the terminal.
pub fn datasheet_table_text(axes: &[&AxisResult]) -> String {
    let mut rows: Vec<Vec<String>> = vec![std::iter::once("term".to_string())
        .chain(std::iter::once("unit".to_string()))
        .chain(axes.iter().map(|a| format!("{} {}", a.device, a.axis)))
        .collect()];
    for (label, sensor, term) in DATASHEET_ROWS {
        if !axes.iter().any(|a| a.sensor == Some(sensor)) {
            continue;
        }
        let mut row = vec![label.to_string(), String::new()];
        for a in axes {
            let v = (a.sensor == Some(sensor))
                .then(|| {
                    a.terms
                        .iter()
                        .find(|t| t.term == term)
                        .and_then(|t| t.values.first())
                })
                .flatten();
            if let Some(v) = v {
                row[1] = v.unit.clone();
            }
            row.push(match v {
                Some(v) => match v.value {
                    Some(value) => sig3(value),
                    None => format!("n.i.(<{})", sig3(v.high)),
                },
                None => String::new(),
            });
        }
        rows.push(row);
    }
    if axes.iter().any(|a| a.sensor.is_none()) {
        for term in Term::ALL {
            let mut row = vec![term.symbol().to_string(), String::new()];
            for a in axes {
                let v = a
                    .terms
                    .iter()
                    .find(|t| t.term == term)
                    .and_then(|t| t.values.first());
                if let Some(v) = v {
                    row[1] = v.unit.clone();
                }
                row.push(match v {
                    Some(v) => v
                        .value
                        .map(sig3)
                        .unwrap_or_else(|| format!("n.i.(<{})", sig3(v.high))),
                    None => String::new(),
                });
            }
            rows.push(row);
        }
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

fn health_table_html(axes: &[&AxisResult]) -> String {
    let mut html = String::from(
        "<table><thead><tr><th>device</th><th>axis</th><th>samples</th><th>duration</th><th>τ0</th><th>policy</th><th>gaps</th><th>missing</th><th>NaN/Inf</th><th>non-uniform</th><th>segments</th><th>temperature</th><th>first problem</th></tr></thead><tbody>",
    );
    for a in axes {
        let h = &a.health;
        let temp = match (h.temperature_min, h.temperature_max) {
            (Some(lo), Some(hi)) => format!("{lo:.1} … {hi:.1} °C"),
            _ => "–".into(),
        };
        let _ = write!(
            html,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{:.1} s</td><td>{} s</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            escape(&a.device),
            escape(&a.axis),
            h.samples,
            h.duration_s,
            sig3(a.tau0),
            h.policy.map(|p| format!("{p:?}").to_lowercase()).unwrap_or_default(),
            h.gaps,
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

/// The self-contained HTML report: one plot per device and sensor, the datasheet table and
/// the data-health table. No scripts, no external resources.
pub fn html_report(report: &AllanReport, title: &str) -> String {
    let mut html = String::new();
    let _ = write!(
        html,
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>{}</title><style>\
body{{font-family:sans-serif;margin:2em;color:#222}}table{{border-collapse:collapse;margin:1em 0}}\
td,th{{border:1px solid #bbb;padding:3px 8px;text-align:right}}td:first-child{{text-align:left}}\
small{{color:#666}}.plots svg{{margin:0.5em;border:1px solid #eee}}</style></head><body><h1>{}</h1>",
        escape(title),
        escape(title)
    );
    let _ = write!(
        html,
        "<p>{} · {} · τ grid {} · intervals {:.1} % (chi-squared, noise-type-aware EDF) · fitted terms with 95 % intervals; n.i. = not identified by the data (upper bound given).</p>",
        escape(&report.generator),
        report.kind.name().to_uppercase(),
        escape(&report.grid),
        report.confidence * 100.0
    );
    let _ = write!(html, "<p>Input: {}</p>", escape(&report.input.join(", ")));
    html.push_str("<h2>Curves</h2><div class=\"plots\">");
    for (title, members) in plot_groups(report) {
        html.push_str(&svg_plot(&members, &title));
    }
    html.push_str("</div><h2>Noise terms</h2>");
    let all: Vec<&AxisResult> = report.axes.iter().collect();
    html.push_str(&datasheet_table_html(&all));
    html.push_str("<h2>Slope-line readings (MATLAB allanvar style)</h2><table><thead><tr><th>device</th><th>axis</th><th>N (τ=1 s, −½ line)</th><th>B = min/0.664</th><th>at τ</th><th>K (τ=3 s, +½ line)</th></tr></thead><tbody>");
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
    html.push_str("</tbody></table><p><small>Slope readings are in the input units (N in unit·√s, B in unit, K in unit/√s).</small></p>");
    let thermal: Vec<&AxisResult> = report.axes.iter().filter(|a| a.thermal.is_some()).collect();
    if !thermal.is_empty() {
        html.push_str("<h2>Bias against temperature</h2><table><thead><tr><th>device</th><th>axis</th><th>coefficient [unit/°C]</th><th>± (1σ)</th><th>bins (T: mean ± spread)</th></tr></thead><tbody>");
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
                let _ = write!(
                    html,
                    "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td style=\"text-align:left\">{}</td></tr>",
                    escape(&a.device),
                    escape(&a.axis),
                    t.coefficient.map(sig3).unwrap_or_else(|| "–".into()),
                    t.coefficient_std_error.map(sig3).unwrap_or_else(|| "–".into()),
                    escape(&bins.join("; "))
                );
            }
        }
        html.push_str("</tbody></table>");
    }
    html.push_str("<h2>Data health</h2>");
    html.push_str(&health_table_html(&all));
    html.push_str("</body></html>\n");
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
    let root = BitMapBackend::new(path, (1000, 700)).into_drawing_area();
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
    let (plot_area, note_area) = root.split_vertically(670);
    if axes.iter().any(|a| a.fit.is_some()) {
        note_area.draw(&Text::new(
            LINE_STYLE_NOTE,
            (15, 8),
            ("sans-serif", 12).into_font(),
        ))?;
    }
    let mut chart = ChartBuilder::on(&plot_area)
        .caption(title, ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(80)
        .build_cartesian_2d(
            (tau.0 / 1.5..tau.1 * 1.5).log_scale(),
            (y_range.0..y_range.1).log_scale(),
        )?;
    chart
        .configure_mesh()
        .x_desc("tau [s]")
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
        let color = Palette99::pick(i).to_rgba();
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
                                    ("sans-serif", 18).into_font().color(&color),
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
