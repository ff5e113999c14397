//! Writes BENCHMARKS.md and its plots from `benches/results/*.json`.
//!
//! Run: `cargo run --example benchmarks_md`. `cargo test --test benchmarks_md` checks that the
//! committed BENCHMARKS.md is what this writes.

#[path = "../benches/support/benchmarks_md.rs"]
mod benchmarks_md;

use anyhow::{anyhow, Result};
use plotters::prelude::*;
use serde_json::Value;
use std::path::Path;

fn main() -> Result<()> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = benchmarks_md::render(root).map_err(|e| anyhow!(e))?;
    std::fs::write(root.join("BENCHMARKS.md"), &text)?;
    println!("wrote BENCHMARKS.md");
    let results = benchmarks_md::load(root).map_err(|e| anyhow!(e))?;
    if let (Some(ours), Some(peer)) = (
        benchmarks_md::figures(&results, "allan-speed"),
        benchmarks_md::figures(&results, "allan_vs_allantools-kernel"),
    ) {
        allan_plot(&root.join(benchmarks_md::ALLAN_PLOT), ours, peer)?;
        println!("wrote {}", benchmarks_md::ALLAN_PLOT);
    }
    if let Some(study) = benchmarks_md::figures(&results, "fusion-study") {
        study_plot(&root.join(benchmarks_md::STUDY_PLOT), study)?;
        println!("wrote {}", benchmarks_md::STUDY_PLOT);
    }
    Ok(())
}

fn num(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

/// Smallest relative difference shown on the log axis (identical results sit on it).
const FLOOR: f64 = 1e-16;

/// Run time on one axis against the largest relative difference of the deviation: each
/// deviation kind of ours and of allantools (the same difference, their disagreement), and
/// OADEV computed in lower precision against our compensated f64 result.
fn allan_plot(path: &Path, ours: &Value, peer: &Value) -> Result<()> {
    let mut pairs = Vec::new();
    for p in peer["kinds"].as_array().into_iter().flatten() {
        let (kind, grid) = (p["kind"].as_str().unwrap_or(""), p["grid"].as_str());
        let Some(o) = ours["kinds"]
            .as_array()
            .into_iter()
            .flatten()
            .find(|o| o["kind"].as_str() == Some(kind) && o["grid"].as_str() == grid)
        else {
            continue;
        };
        let err = num(&p["max_rel_diff_vs_imulab"]).max(FLOOR);
        let label = format!(
            "{}{}",
            kind.to_uppercase(),
            if grid == Some("octave") {
                String::new()
            } else {
                format!(" {}", grid.unwrap_or(""))
            }
        );
        pairs.push((label, num(&o["one_axis_s"]), num(&p["one_axis_s"]), err));
    }
    let precision: Vec<(String, f64, f64)> = ours["precision"]
        .as_array()
        .into_iter()
        .flatten()
        .filter(|v| v["max_rel_err"].is_number())
        .map(|v| {
            (
                v["variant"].as_str().unwrap_or("").to_string(),
                num(&v["time_s"]),
                num(&v["max_rel_err"]).max(FLOOR),
            )
        })
        .collect();
    let times = pairs
        .iter()
        .flat_map(|p| [p.1, p.2])
        .chain(precision.iter().map(|p| p.1));
    let errs = pairs
        .iter()
        .map(|p| p.3)
        .chain(precision.iter().map(|p| p.2));
    let (t_lo, t_hi) = times.fold((f64::INFINITY, 0.0f64), |(a, b), t| (a.min(t), b.max(t)));
    let (e_lo, e_hi) = errs.fold((f64::INFINITY, 0.0f64), |(a, b), e| (a.min(e), b.max(e)));
    let root = SVGBackend::new(path, (900, 600)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Allan deviation, 3.24 M samples, one axis: run time against error",
            ("sans-serif", 20),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(
            (t_lo / 2.0..t_hi * 2.0).log_scale(),
            (e_lo / 10.0..e_hi * 10.0).log_scale(),
        )?;
    chart
        .configure_mesh()
        .x_desc("run time, one axis [s]")
        .y_desc("max relative difference of the deviation")
        .y_label_formatter(&|v| format!("{v:.0e}"))
        .draw()?;
    for (i, (label, t_ours, t_peer, err)) in pairs.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        chart
            .draw_series(LineSeries::new([(*t_ours, *err), (*t_peer, *err)], color))?
            .label(format!("{label}: imulab (●) vs allantools (○)"))
            .legend(move |(x, y)| Circle::new((x + 10, y), 4, color.filled()));
        chart.draw_series([Circle::new((*t_ours, *err), 5, color.filled())])?;
        chart.draw_series([Circle::new((*t_peer, *err), 5, color)])?;
    }
    for (label, t, e) in &precision {
        chart
            .draw_series([TriangleMarker::new((*t, *e), 6, BLACK.filled())])?
            .label(format!("OADEV, {label}, vs our f64"))
            .legend(|(x, y)| TriangleMarker::new((x + 10, y), 5, BLACK.filled()));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperLeft)
        .label_font(("sans-serif", 12))
        .draw()?;
    root.present()?;
    Ok(())
}

/// A grade's name and its (outage length s, p50 drift m, p95 drift m) points.
type GradeCurve = (String, Vec<(f64, f64, f64)>);

/// p95 and p50 horizontal drift against outage length per grade, with the requirements.
fn study_plot(path: &Path, figures: &Value) -> Result<()> {
    let study = &figures["open_sky"]["study"];
    let requirements: Vec<f64> = figures["open_sky"]["requirements_m"]
        .as_array()
        .into_iter()
        .flatten()
        .map(num)
        .collect();
    let grades: Vec<GradeCurve> = study["grades"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|g| {
            let points = g["lengths"]
                .as_array()
                .into_iter()
                .flatten()
                .map(|l| (num(&l["outage_s"]), num(&l["p50_m"]), num(&l["p95_m"])))
                .collect();
            (g["name"].as_str().unwrap_or("").to_string(), points)
        })
        .collect();
    let all = grades.iter().flat_map(|g| g.1.iter());
    let (x_lo, x_hi) = all.clone().fold((f64::INFINITY, 0.0f64), |(a, b), p| {
        (a.min(p.0), b.max(p.0))
    });
    let (y_lo, y_hi) = all
        .map(|p| (p.1, p.2))
        .chain(requirements.iter().map(|&r| (r, r)))
        .fold((f64::INFINITY, 0.0f64), |(a, b), p| {
            (a.min(p.0), b.max(p.1))
        });
    let root = SVGBackend::new(path, (900, 600)).into_drawing_area();
    root.fill(&WHITE)?;
    let runs = study["runs"].as_u64().unwrap_or(0);
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!("Horizontal drift against GNSS outage length, {runs} runs of a 30 min drive"),
            ("sans-serif", 20),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(
            (x_lo / 1.2..x_hi * 1.2).log_scale(),
            (y_lo / 2.0..y_hi * 2.0).log_scale(),
        )?;
    chart
        .configure_mesh()
        .x_desc("outage length [s]")
        .y_desc("horizontal drift [m]: p95 (solid), p50 (dashed)")
        .draw()?;
    for &r in &requirements {
        let grey = RGBColor(150, 150, 150);
        chart.draw_series(DashedLineSeries::new(
            [(x_lo / 1.2, r), (x_hi * 1.2, r)],
            4,
            4,
            grey.into(),
        ))?;
        chart.draw_series([Text::new(
            format!("{r} m"),
            (x_lo / 1.15, r * 1.1),
            ("sans-serif", 12).into_font().color(&grey),
        )])?;
    }
    for (i, (name, points)) in grades.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        chart
            .draw_series(LineSeries::new(
                points.iter().map(|p| (p.0, p.2)),
                color.stroke_width(2),
            ))?
            .label(name.as_str())
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], color.stroke_width(2)));
        chart.draw_series(
            points
                .iter()
                .map(|p| Circle::new((p.0, p.2), 3, color.filled())),
        )?;
        chart.draw_series(DashedLineSeries::new(
            points.iter().map(|p| (p.0, p.1)),
            5,
            4,
            color.into(),
        ))?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperLeft)
        .draw()?;
    root.present()?;
    Ok(())
}
