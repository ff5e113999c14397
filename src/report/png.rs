//! PNG plots of the deviation curves, drawn with plotters.

use super::svg::{term_lines, COLORS, LINE_STYLE_NOTE};
use crate::allan::analysis::{AllanReport, AxisResult};
use std::path::Path;

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
pub(super) fn clip_log_segment(
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
