//! The page's opening summary: which IMU is better on each headline term, by how much,
//! and how long a GNSS outage each bridges.

use super::text::{escape, pretty_unit, seconds, sig3};
use crate::allan::analysis::AllanReport;
use crate::allan::fit::Term;
use crate::allan::units::SensorKind;
use crate::study::grades::{Bridge, StudyResult};
use std::fmt::Write as _;

/// Headline terms of the summary: (label, sensor, term).
pub(super) const HEADLINE_TERMS: [(&str, SensorKind, Term); 4] = [
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
pub(super) enum Headline {
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

pub(super) fn headline(
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
pub(super) fn devices(report: &AllanReport) -> Vec<&str> {
    let mut out: Vec<&str> = Vec::new();
    for a in &report.axes {
        if !out.contains(&a.device.as_str()) {
            out.push(&a.device);
        }
    }
    out
}

/// The study's answer for `device` at the requirement closest to 1 m: (requirement, bridge).
pub(super) fn study_bridge<'a>(study: Option<&'a StudyResult>, device: &str) -> Option<&'a Bridge> {
    study?.grade_for(device)?.bridges.iter().min_by(|a, b| {
        (a.requirement_m - 1.0)
            .abs()
            .total_cmp(&(b.requirement_m - 1.0).abs())
    })
}

/// The summary: verdict, headline terms side by side with ratios, and the GNSS-outage
/// horizons of each device.
pub fn summary_html(report: &AllanReport) -> String {
    summary_html_with_study(report, None)
}

/// [`summary_html`] with the filter-based outage answer of `study` as the headline.
pub fn summary_html_with_study(report: &AllanReport, study: Option<&StudyResult>) -> String {
    let devices = devices(report);
    let outages = super::outage::device_outages(report);
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
