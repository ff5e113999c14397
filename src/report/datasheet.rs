//! The datasheet-style table of fitted noise terms (rows: terms in engineering units;
//! columns: device × axis), as HTML and as terminal text.

use super::text::{escape, pretty_unit, sig3};
use crate::allan::analysis::AxisResult;
use crate::allan::fit::Term;
use crate::allan::units::SensorKind;
use std::fmt::Write as _;

/// Datasheet rows: (label, sensor, term) in the order engineers read them.
pub(super) const DATASHEET_ROWS: [(&str, SensorKind, Term); 8] = [
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
pub(super) fn datasheet_table(
    axes: &[&AxisResult],
    hide_unidentified: bool,
) -> (String, Vec<&'static str>) {
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
pub(super) fn short_axis(axis: &str, sensor: Option<SensorKind>) -> &str {
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
pub(super) fn sensor_table_text(axes: &[&AxisResult], sensor: Option<SensorKind>) -> String {
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
