//! The deviation plot as inline SVG: curves, confidence bands and the fitted terms'
//! lines. Written by hand because plotters' text layout needs system fonts, which a report
//! must not depend on.

use super::text::escape;
use crate::allan::analysis::AxisResult;
use crate::allan::fit::{NoiseFit, Term};
use std::fmt::Write as _;

pub(super) const COLORS: [&str; 8] = [
    "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2",
];

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
pub(super) fn fnv1a(text: &str) -> u64 {
    text.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}
