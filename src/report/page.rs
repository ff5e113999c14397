//! The self-contained HTML page (no network, no fonts needed): summary, plots, datasheet
//! table, per-axis health and the data health of every session input.

use super::datasheet::datasheet_table;
use super::health::SessionHealth;
use super::summary::summary_html_with_study;
use super::svg::{svg_plot, LINE_STYLE_NOTE, SVG_NAMESPACE};
use super::text::{duration, escape, pretty_unit, sig3};
use crate::allan::analysis::{AllanReport, AxisResult};
use crate::allan::units::{thermal_coefficient_in_units, SensorKind};
use crate::study::grades::StudyResult;
use std::fmt::Write as _;

/// The analysed axes' health: one sentence when every axis is clean, else the table.
pub(super) fn axes_health_html(axes: &[&AxisResult]) -> String {
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

pub(super) fn health_table_html(axes: &[&AxisResult]) -> String {
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
    html_report_with_sessions(
        report,
        title,
        &super::health::sessions_of_report(report),
        None,
    )
}

/// [`html_report`] whose GNSS-outage headline is the filter-based answer of `study`
/// (`imulab study --json`), the closed-form figure shown as a labelled analytic bound.
pub fn html_report_with_study(report: &AllanReport, title: &str, study: &StudyResult) -> String {
    html_report_with_sessions(
        report,
        title,
        &super::health::sessions_of_report(report),
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

pub(super) const DATA_HEALTH_HEADING: &str = "<h2>4. Data health</h2>";

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

/// The data-health tables of one session: its devices and their events.
pub(super) fn session_health_html(s: &SessionHealth) -> String {
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
        for kind in super::health::PROBLEM_EVENTS {
            if let Some(n) = d.events.get(kind).filter(|n| **n > 0) {
                problem = true;
                events.push(format!("<b>{} {n}</b>", kind.replace('_', " ")));
            }
        }
        for (k, n) in d
            .events
            .iter()
            .filter(|(k, _)| !super::health::PROBLEM_EVENTS.contains(&k.as_str()))
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
