//! The watch page: HTML rendered on the server from a [`Snapshot`], the Allan plots by
//! the report's [`svg_plot`], the temperature as a small inline SVG. The live page
//! carries a few lines of script that fetch `/fragment` every refresh and swap it in; the
//! static page (`--once --html`) has no script. Nothing is loaded from anywhere else.

use super::snapshot::{AxisView, DeviceView, Snapshot, TermView};
use super::stop::Prediction;
use crate::allan::units::SensorKind;
use crate::report::{escape, svg_plot, LINE_STYLE_NOTE, PAGE_STYLE};
use std::fmt::Write;

/// Extra style of the watch page.
const WATCH_STYLE: &str = ".live{color:#1a7f37;font-weight:bold}.done{color:#555;font-weight:bold}\
.warn{background:#fff4d6}.stale{color:#b00;font-weight:bold}#conn{color:#b00}\
.temp svg{width:100%;max-width:720px;height:auto;border:1px solid #eee}\
.health td.wrap{white-space:normal;min-width:8em;max-width:14em;text-align:left}";

/// The whole page. `refresh_s`: the live page fetches a new fragment this often; `None`
/// writes a static page.
pub fn page(s: &Snapshot, refresh_s: Option<f64>) -> String {
    let mut out = String::new();
    let title = format!("imulab watch: {}", s.session_id);
    let _ = write!(
        out,
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title>\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\
         <style>{PAGE_STYLE}{WATCH_STYLE}</style></head><body>",
        escape(&title)
    );
    let _ = write!(
        out,
        "<h1>{}</h1><p id=\"conn\"></p><main id=\"main\">",
        escape(&title)
    );
    out.push_str(&fragment(s));
    out.push_str("</main>");
    if let Some(r) = refresh_s {
        let ms = (r * 1000.0).round().max(200.0) as u64;
        // Swaps in the current state; says so when the server stops answering.
        let _ = write!(
            out,
            "<script>\
             async function tick(){{const c=document.getElementById('conn');\
             try{{const r=await fetch('fragment',{{cache:'no-store'}});\
             if(!r.ok)throw new Error(r.status);\
             document.getElementById('main').innerHTML=await r.text();c.textContent='';}}\
             catch(e){{c.textContent='imulab watch is not answering ('+e.message+'): the page shows the last state it sent.';}}}}\
             setInterval(tick,{ms});</script>"
        );
    }
    out.push_str("</body></html>\n");
    out
}

/// The part of the page that changes (the content of `<main>`).
pub fn fragment(s: &Snapshot) -> String {
    let mut out = String::new();
    let state = if s.live {
        "<span class=\"live\">recording</span> (a writer holds the session)"
    } else {
        "<span class=\"done\">finished</span> (no writer holds the session)"
    };
    let _ = write!(
        out,
        "<p class=\"meta\" id=\"summary\">Session <b>{}</b> in {} · host {} · started {} · {} · \
         {} chunk file(s){} · updated {} (look {}, {:.0} ms)</p>",
        escape(&s.session_id),
        escape(&s.dir),
        escape(&s.host),
        escape(&s.start_time),
        state,
        s.files,
        if s.partial_files > 0 {
            format!(", {} being written", s.partial_files)
        } else {
            String::new()
        },
        escape(&s.generated_at),
        s.looks,
        s.compute_ms
    );
    if let Some(d) = &s.daemon {
        let age = d.age_s.map_or(String::new(), |a| format!(", {a:.0} s ago"));
        let class = if d.age_s.is_some_and(|a| a > 5.0) {
            " class=\"stale\""
        } else {
            ""
        };
        let _ = write!(
            out,
            "<p class=\"meta\"{class}>imulogd status: {} (written {}{age}){}</p>",
            escape(&d.state),
            escape(&d.written_at),
            d.free_bytes.map_or(String::new(), |b| format!(
                " · {:.1} GB free",
                b as f64 / 1e9
            ))
        );
    }
    health_table(&mut out, s);
    stop_table(&mut out, s);
    for d in &s.devices {
        device_section(&mut out, d);
    }
    if !s.session_events.is_empty() {
        out.push_str("<h2>Session events</h2><p>");
        let list: Vec<String> = s
            .session_events
            .iter()
            .map(|(k, v)| format!("{} {v}", escape(k)))
            .collect();
        out.push_str(&list.join(" · "));
        out.push_str("</p>");
    }
    if !s.problems.is_empty() {
        out.push_str("<h2>Problems</h2><ul>");
        for p in &s.problems {
            let _ = write!(out, "<li>{}</li>", escape(p));
        }
        out.push_str("</ul>");
    }
    out
}

fn health_table(out: &mut String, s: &Snapshot) {
    // Two-line cells (a figure, then its detail in small type) keep the table within 1200 px
    // with two IMUs and a receiver, live or finished.
    out.push_str(
        "<h2>Data health</h2><div class=\"scroll\"><table class=\"health\" id=\"health\"><tr><th>device</th>\
         <th>rows</th><th>span</th><th>rate now<br>(10 s)</th><th>mean<br>rate</th><th>nominal</th>\
         <th>last sample<br>age</th><th>gaps<br>(missing)</th><th>resyncs</th><th>checksum<br>errors</th>\
         <th>other events</th><th>temperature</th></tr>",
    );
    for d in &s.devices {
        let off = |r: Option<f64>| {
            r.is_some_and(|r| d.nominal_rate_hz > 0.0 && (r / d.nominal_rate_hz - 1.0).abs() > 0.02)
        };
        let cell = |bad: bool, text: String| {
            format!("<td{}>{text}</td>", if bad { " class=\"bad\"" } else { "" })
        };
        let rate = |r: Option<f64>| r.map_or("–".to_string(), |r| format!("{r:.2} Hz"));
        let age = match (&d.daemon, d.last_sample_age_s) {
            (Some(x), Some(file)) => format!(
                "{} <small>(daemon)</small><br><small>{file:.1} s in the files</small>",
                x.last_sample_age_s
                    .map_or("–".into(), |a| format!("{a:.1} s"))
            ),
            (_, Some(file)) => format!("{file:.1} s ago"),
            _ if s.live => "–".to_string(),
            _ => "finished".to_string(),
        };
        let stale = d.last_sample_age_s.is_some_and(|a| a > 30.0);
        let event = |k: &str| d.events.get(k).copied().unwrap_or(0);
        let others: Vec<String> = d
            .events
            .iter()
            .filter(|(k, _)| !["resync", "checksum_error", "gap"].contains(&k.as_str()))
            .map(|(k, v)| format!("{} {v}", escape(k)))
            .collect();
        let gaps = d.gaps + event("gap");
        let temp = match (d.temperature.last(), temperature_range(d)) {
            (Some(last), Some((lo, hi))) => {
                format!("{:.2} °C<br><small>range {lo:.2}–{hi:.2}</small>", last.1)
            }
            _ => "–".to_string(),
        };
        let _ = write!(
            out,
            "<tr><td>{}<br><small>{} {}</small></td><td>{}</td><td>{}</td>{}{}<td>{:.2} Hz</td>{}{}{}{}<td class=\"wrap\">{}</td><td>{temp}</td></tr>",
            escape(&d.name),
            escape(&d.kind),
            escape(&d.model),
            d.rows,
            duration(d.span_s),
            cell(off(d.recent_rate_hz), rate(d.recent_rate_hz)),
            cell(off(d.mean_rate_hz), rate(d.mean_rate_hz)),
            d.nominal_rate_hz,
            cell(stale, age),
            cell(gaps > 0, format!("{gaps} ({})", d.missing_samples)),
            cell(event("resync") > 0, event("resync").to_string()),
            cell(event("checksum_error") > 0, event("checksum_error").to_string()),
            if others.is_empty() { "–".to_string() } else { others.join(" · ") },
        );
    }
    out.push_str(
        "</table></div><p class=\"note\">Rates from the rows in the session files. A live \
         chunk file is behind the device by up to the writer's chunk interval (the rows wait in \
         its journal until their chunk is complete). Gaps: intervals of at least 1.5 nominal \
         periods in the time stamps, plus gap events. The Allan curves join the rows across \
         gaps.</p>",
    );
}

fn temperature_range(d: &DeviceView) -> Option<(f64, f64)> {
    let lo = d.temperature.iter().map(|t| t.2).reduce(f64::min)?;
    let hi = d.temperature.iter().map(|t| t.3).reduce(f64::max)?;
    Some((lo, hi))
}

/// The "when can I stop" table: one row per targeted term and axis.
fn stop_table(out: &mut String, s: &Snapshot) {
    if s.targets.is_empty() {
        return;
    }
    let goals: Vec<String> = s
        .targets
        .iter()
        .map(|t| {
            format!(
                "{} ±{:.0} %",
                super::stop::term_name(t.term),
                t.relative * 100.0
            )
        })
        .collect();
    let _ = write!(
        out,
        "<h2>When can I stop?</h2><p>Targets: {} (95 % interval of the fitted term).</p>\
         <div class=\"scroll\"><table id=\"stop\"><tr><th>device</th><th>axis</th><th>term</th>\
         <th>estimate</th><th>95 % interval</th><th>width</th><th>target</th><th>more run time</th></tr>",
        goals.join(", ")
    );
    let mut longest: Option<f64> = Some(0.0);
    let mut rows = 0;
    for d in &s.devices {
        for a in &d.axes {
            for t in a.terms.iter().filter(|t| t.target.is_some()) {
                let _ = write!(
                    out,
                    "<tr><td>{}</td><td>{}</td>{}</tr>",
                    escape(&d.name),
                    escape(&a.result.axis),
                    term_cells(t, true)
                );
                rows += 1;
                longest = match (longest, t.prediction) {
                    (Some(l), Some(Prediction::Reached)) => Some(l),
                    (Some(l), Some(Prediction::After { extra_s })) => Some(l.max(extra_s)),
                    _ => None,
                };
            }
        }
    }
    out.push_str("</table></div>");
    let verdict = match longest {
        _ if rows == 0 => "No IMU axis has a fit yet.".to_string(),
        Some(l) if l <= 0.0 => "Every target is reached: the run can stop.".to_string(),
        Some(l) => format!("All targets reached in about {} more.", duration(l)),
        None => "Some targets cannot be predicted yet (term not identified, or beyond 4096× the current run)."
            .to_string(),
    };
    let _ = write!(
        out,
        "<p class=\"verdict\" id=\"verdict\">{verdict}</p><p class=\"note\">The prediction refits \
         the fitted model's curve with the EDF each τ would have after a longer run (about \
         proportional to run length over τ), so a width shrinks roughly as 1/√(run length); it \
         assumes no new noise term appears at the longer τ. See docs/watch.md.</p>"
    );
}

fn term_cells(t: &TermView, with_target: bool) -> String {
    let value = t.value.map_or("not identified".to_string(), |v| {
        format!("{} {}", sig(v), escape(&t.unit))
    });
    let interval = format!("{} – {}", sig(t.low), sig(t.high));
    let width = t
        .relative_width
        .map_or("–".to_string(), |w| format!("±{:.1} %", w * 100.0));
    let mut cells = format!(
        "<td>{} ({})</td><td>{value}</td><td>{interval}</td><td>{width}</td>",
        escape(&t.name),
        escape(t.key)
    );
    if with_target {
        let target = t
            .target
            .map_or("–".into(), |x| format!("±{:.0} %", x * 100.0));
        let (class, prediction) = match t.prediction {
            Some(Prediction::Reached) => (" class=\"good\"", "reached".to_string()),
            Some(Prediction::After { extra_s }) => ("", format!("about {}", duration(extra_s))),
            Some(Prediction::Beyond) => (" class=\"bad\"", "more than 4096× the run so far".into()),
            Some(Prediction::NotIdentified) | None => ("", "term not identified yet".into()),
        };
        let _ = write!(cells, "<td>{target}</td><td{class}>{prediction}</td>");
    }
    cells
}

fn device_section(out: &mut String, d: &DeviceView) {
    let _ = write!(out, "<h2 id=\"dev-{0}\">{0}</h2>", escape(&d.name));
    if !d.temperature.is_empty() {
        let _ = write!(out, "<div class=\"temp\">{}</div>", temperature_svg(d));
    }
    if d.axes.is_empty() {
        return;
    }
    let gyro: Vec<&AxisView> = d
        .axes
        .iter()
        .filter(|a| a.result.sensor == Some(SensorKind::Gyro))
        .collect();
    let accel: Vec<&AxisView> = d
        .axes
        .iter()
        .filter(|a| a.result.sensor == Some(SensorKind::Accel))
        .collect();
    out.push_str("<div class=\"plots\">");
    for (group, label) in [(&gyro, "gyro, rad/s"), (&accel, "accel, m/s²")] {
        if group.is_empty() {
            continue;
        }
        let results: Vec<_> = group.iter().map(|a| &a.result).collect();
        let title = format!("{} {label}: ADEV (non-overlapping, octave τ)", d.name);
        out.push_str(&svg_plot(&results, &title));
    }
    out.push_str("</div>");
    let _ = write!(out, "<p class=\"note\">{}</p>", escape(LINE_STYLE_NOTE));
    out.push_str(
        "<div class=\"scroll\"><table><tr><th>axis</th><th>samples</th><th>term</th><th>estimate</th>\
         <th>95 % interval</th><th>width</th></tr>",
    );
    for a in &d.axes {
        let samples = a.result.health.samples;
        if a.terms.is_empty() {
            let why = a
                .result
                .fit_error
                .clone()
                .unwrap_or_else(|| "no term identified yet".into());
            let _ = write!(
                out,
                "<tr><td>{}</td><td>{samples}</td><td colspan=\"4\">{}</td></tr>",
                escape(&a.result.axis),
                escape(&why)
            );
        }
        for t in &a.terms {
            let _ = write!(
                out,
                "<tr><td>{}</td><td>{samples}</td>{}</tr>",
                escape(&a.result.axis),
                term_cells(t, false)
            );
        }
    }
    out.push_str("</table></div>");
}

/// Temperature against time: the bin means as a line, their min–max as a band.
fn temperature_svg(d: &DeviceView) -> String {
    let (w, h) = (720.0, 180.0);
    let (left, right, top, bottom) = (60.0, 16.0, 24.0, 34.0);
    let t_max = d.temperature.last().map_or(1.0, |t| t.0).max(1.0);
    let (mut lo, mut hi) = temperature_range(d).unwrap_or((0.0, 1.0));
    if hi - lo < 0.1 {
        lo -= 0.05;
        hi += 0.05;
    }
    let px = |t: f64| left + t / t_max * (w - left - right);
    let py = |v: f64| top + (hi - v) / (hi - lo) * (h - top - bottom);
    let mut svg = format!(
        "<svg width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\" font-family=\"sans-serif\" font-size=\"12\">\
         <text x=\"{}\" y=\"15\" text-anchor=\"middle\" font-weight=\"bold\">{} temperature, °C</text>",
        w / 2.0,
        escape(&d.name)
    );
    let band: Vec<String> = d
        .temperature
        .iter()
        .map(|t| format!("{:.1},{:.1}", px(t.0), py(t.3)))
        .chain(
            d.temperature
                .iter()
                .rev()
                .map(|t| format!("{:.1},{:.1}", px(t.0), py(t.2))),
        )
        .collect();
    let line: Vec<String> = d
        .temperature
        .iter()
        .map(|t| format!("{:.1},{:.1}", px(t.0), py(t.1)))
        .collect();
    let _ = write!(
        svg,
        "<polygon points=\"{}\" fill=\"#d62728\" fill-opacity=\"0.15\"/>\
         <polyline points=\"{}\" fill=\"none\" stroke=\"#d62728\" stroke-width=\"1.5\"/>",
        band.join(" "),
        line.join(" ")
    );
    for (v, y) in [(hi, py(hi)), (lo, py(lo))] {
        let _ = write!(
            svg,
            "<text x=\"{}\" y=\"{:.1}\" text-anchor=\"end\">{v:.2}</text>",
            left - 6.0,
            y + 4.0
        );
    }
    let _ = write!(
        svg,
        "<line x1=\"{left}\" y1=\"{0}\" x2=\"{1}\" y2=\"{0}\" stroke=\"#999\"/>\
         <text x=\"{left}\" y=\"{2}\">0</text><text x=\"{1}\" y=\"{2}\" text-anchor=\"end\">{3}</text></svg>",
        h - bottom,
        w - right,
        h - bottom + 16.0,
        duration(t_max)
    );
    svg
}

/// A duration for people: `42 s`, `12.5 min`, `3.2 h`, `2.1 days`.
pub fn duration(s: f64) -> String {
    if !s.is_finite() {
        "–".to_string()
    } else if s < 120.0 {
        format!("{s:.0} s")
    } else if s < 7200.0 {
        format!("{:.1} min", s / 60.0)
    } else if s < 172_800.0 {
        format!("{:.1} h", s / 3600.0)
    } else {
        format!("{:.1} days", s / 86_400.0)
    }
}

/// Three significant digits.
fn sig(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = (2 - v.abs().log10().floor() as i32).clamp(0, 12) as usize;
    if v.abs() >= 1e-3 && v.abs() < 1e5 {
        format!("{v:.digits$}")
    } else {
        format!("{v:.2e}")
    }
}
