//! The `imulab thermal` document: per device the temperature source and thermal lag, per
//! axis the results of [`super::analysis`]; as JSON (`--json`, schema in docs/thermal.md),
//! as a text summary, as the HTML report section with its SVG plots, and as the
//! compensation model it exports.

use super::analysis::{AxisThermal, Warmup};
use super::model::{AxisModel, DeviceModel, ThermalModel, MODEL_FORMAT, MODEL_VERSION};
use super::plot;
use imulab_allan::units::RateUnit;
use serde::{Deserialize, Serialize};
use std::fmt::Write;

/// Version of the JSON document layout.
pub const SCHEMA_VERSION: u32 = 1;

/// The first-order lag of the sensor temperature behind the chamber.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ThermalLag {
    pub time_constant_s: f64,
    /// Sensor minus lagged chamber temperature (self-heating), °C.
    pub offset_c: f64,
    /// RMS misfit of the first-order model, °C.
    pub rms_c: f64,
}

/// One device.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DeviceThermal {
    pub device: String,
    /// Sensor temperature range, °C.
    pub temperature_range_c: [f64; 2],
    /// Where the chamber temperature came from (`None`: not logged).
    pub chamber: Option<String>,
    pub lag: Option<ThermalLag>,
    pub axes: Vec<AxisThermal>,
}

/// The `--json` document.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ThermalReport {
    pub schema_version: u32,
    pub generator: String,
    pub input: String,
    pub devices: Vec<DeviceThermal>,
}

impl ThermalReport {
    pub fn new(input: String, devices: Vec<DeviceThermal>) -> Self {
        ThermalReport {
            schema_version: SCHEMA_VERSION,
            generator: format!("imulab {}", env!("CARGO_PKG_VERSION")),
            input,
            devices,
        }
    }

    /// The compensation model of every fitted axis (units SI: the fits of session data are).
    pub fn model(&self) -> ThermalModel {
        ThermalModel {
            format: MODEL_FORMAT.into(),
            version: MODEL_VERSION,
            generator: self.generator.clone(),
            source: self.input.clone(),
            temperature: "sensor".into(),
            devices: self
                .devices
                .iter()
                .map(|d| DeviceModel {
                    device: d.device.clone(),
                    axes: d
                        .axes
                        .iter()
                        .map(|a| {
                            let si = a.unit.to_si();
                            AxisModel {
                                axis: a.axis.clone(),
                                unit: match a.unit {
                                    RateUnit::RadPerSecond
                                    | RateUnit::DegPerSecond
                                    | RateUnit::DegPerHour => "rad/s".into(),
                                    _ => "m/s^2".into(),
                                },
                                reference_c: a.fit.reference_c,
                                valid_range_c: a.fit.range_c,
                                coefficients: a.fit.coefficients.iter().map(|c| c * si).collect(),
                                ci95: a.fit.ci95.iter().map(|c| c * si).collect(),
                            }
                        })
                        .collect(),
                })
                .collect(),
        }
    }
}

fn coefficient_text(a: &AxisThermal, order: usize) -> String {
    match a.coefficients.get(order) {
        None => "—".into(),
        Some(c) => format!("{:.4} [{:.4}, {:.4}] {}", c.value, c.low, c.high, c.unit),
    }
}

fn scale_text(sf: &super::analysis::ScaleFactor) -> String {
    sf.coefficients
        .iter()
        .map(|c| format!("{:.2} [{:.2}, {:.2}] {}", c.value, c.low, c.high, c.unit))
        .collect::<Vec<_>>()
        .join(", ")
}

fn noise_text(p: &super::analysis::PlateauNoise) -> String {
    let mut parts = Vec::new();
    for t in &p.terms {
        if let Some(v) = t.values.first() {
            if let Some(x) = v.value {
                parts.push(format!("{} {:.4} {}", t.name, x, v.unit));
            }
        }
    }
    if parts.is_empty() {
        p.fit_error
            .clone()
            .unwrap_or_else(|| "no term identified".into())
    } else {
        parts.join(", ")
    }
}

/// The text summary printed on stdout.
pub fn summary_text(report: &ThermalReport) -> String {
    let mut s = String::new();
    for d in &report.devices {
        let _ = writeln!(
            s,
            "device {}: sensor temperature {:.2} to {:.2} °C; chamber: {}",
            d.device,
            d.temperature_range_c[0],
            d.temperature_range_c[1],
            d.chamber.as_deref().unwrap_or("not logged")
        );
        match &d.lag {
            Some(l) => {
                let _ = writeln!(
                    s,
                    "  thermal lag chamber → sensor: τ = {:.1} s, offset {:+.3} °C, rms {:.3} °C",
                    l.time_constant_s, l.offset_c, l.rms_c
                );
            }
            None => {
                let _ = writeln!(s, "  thermal lag: needs the chamber temperature");
            }
        }
        for a in &d.axes {
            let _ = writeln!(
                s,
                "  {}: order {} (BIC), c1 {}, c2 {}; residual rms {:.4} {}",
                a.axis,
                a.fit.order,
                coefficient_text(a, 1),
                coefficient_text(a, 2),
                a.fit.residual_rms * super::analysis::datasheet_unit(a.sensor, a.unit).1,
                a.datasheet_unit
            );
            if let Some(h) = &a.hysteresis {
                let _ = writeln!(
                    s,
                    "    hysteresis (joint fit, gap order {}): largest gap (rising − falling) {:+.4} ± {:.4} {} at {:.1} °C, mean {:+.4}",
                    h.gap.order, h.largest_gap, h.largest_gap_ci95, h.unit, h.largest_gap_at_c, h.mean_gap
                );
            }
            if let Some(w) = &a.warmup {
                let _ = writeln!(
                    s,
                    "    warm-up: τ = {}, amplitude {}, within {:.4} {} of the settled value after {:.0} s",
                    time_constant_text(w),
                    amplitude_text(w),
                    w.tolerance,
                    w.unit,
                    w.time_to_tolerance_s
                );
            }
            if let Some(sf) = &a.scale_factor {
                let _ = writeln!(
                    s,
                    "    scale factor from ±1 g poses at {} temperatures: {}",
                    sf.points.len(),
                    scale_text(sf)
                );
            }
            for p in &a.plateaus {
                let _ = writeln!(
                    s,
                    "    plateau {:.1} °C ({:.0} s): {}",
                    p.temperature_c,
                    p.duration_s,
                    noise_text(p)
                );
            }
            for n in &a.notes {
                let _ = writeln!(s, "    note: {n}");
            }
        }
    }
    s
}

/// An interval end: ∞ where the data do not bound it.
fn bound(x: f64, decimals: usize) -> String {
    if x.is_infinite() {
        if x > 0.0 { "∞" } else { "−∞" }.to_string()
    } else {
        format!("{x:.decimals$}")
    }
}

/// A warm-up's time constant with its 95 % interval: `312.4 s [250.1, ∞]`.
fn time_constant_text(w: &Warmup) -> String {
    let [lo, hi] = w.time_constant_ci95_s;
    format!(
        "{:.1} s [{}, {}]",
        w.time_constant_s,
        bound(lo, 1),
        bound(hi, 1)
    )
}

/// A warm-up's amplitude with its unit and 95 % interval: `+0.0123 rad/s [0.0101, 0.0150]`.
fn amplitude_text(w: &Warmup) -> String {
    let [lo, hi] = w.amplitude_ci95;
    format!(
        "{:+.4} {} [{}, {}]",
        w.amplitude,
        w.unit,
        bound(lo, 4),
        bound(hi, 4)
    )
}

/// The smallest detectable warm-up amplitudes, one per time constant.
fn detection_text(l: &super::analysis::WarmupLimit) -> String {
    l.limits
        .iter()
        .map(|d| {
            format!(
                "{:.4} {} at τ {:.0} s",
                d.amplitude, l.unit, d.time_constant_s
            )
        })
        .collect::<Vec<_>>()
        .join(", ")
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// The thermal section of a report: tables and plots (HTML fragment).
pub fn html_section(report: &ThermalReport) -> String {
    let mut h = String::from("<section id=\"thermal\"><h2>Thermal characterisation</h2>\n");
    for d in &report.devices {
        let _ = writeln!(
            h,
            "<h3>{}</h3><p>Sensor temperature {:.2} to {:.2} °C; chamber temperature: {}. {}</p>",
            esc(&d.device),
            d.temperature_range_c[0],
            d.temperature_range_c[1],
            esc(d.chamber.as_deref().unwrap_or("not logged")),
            match &d.lag {
                Some(l) => format!(
                    "Thermal lag chamber → sensor: τ = {:.1} s (offset {:+.3} °C, rms {:.3} °C).",
                    l.time_constant_s, l.offset_c, l.rms_c
                ),
                None => "Thermal lag: not available without the chamber temperature.".into(),
            }
        );
        h.push_str("<table><tr><th>axis</th><th>order</th><th>c1 [95 %]</th><th>c2 [95 %]</th><th>hysteresis: largest gap</th><th>warm-up τ [95 %], amplitude, time to tolerance</th><th>scale factor from ±1 g poses</th></tr>\n");
        for a in &d.axes {
            let hyst = a.hysteresis.as_ref().map_or("—".to_string(), |x| {
                format!(
                    "{:+.4} ± {:.4} {} at {:.1} °C",
                    x.largest_gap, x.largest_gap_ci95, x.unit, x.largest_gap_at_c
                )
            });
            let warm = match (&a.warmup, &a.warmup_detection_limit) {
                (Some(w), _) => format!(
                    "{}, {}, {:.0} s (±{:.4})",
                    time_constant_text(w),
                    amplitude_text(w),
                    w.time_to_tolerance_s,
                    w.tolerance
                ),
                (None, Some(l)) => format!("not found; detectable: {}", detection_text(l)),
                (None, None) => "—".to_string(),
            };
            let scale = a.scale_factor.as_ref().map_or("—".to_string(), scale_text);
            let _ = writeln!(
                h,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                esc(&a.axis),
                a.fit.order,
                esc(&coefficient_text(a, 1)),
                esc(&coefficient_text(a, 2)),
                esc(&hyst),
                esc(&warm),
                esc(&scale)
            );
        }
        h.push_str("</table>\n");
        if let Some(first) = d.axes.first() {
            if !first.plateaus.is_empty() {
                h.push_str("<h4>Noise terms per plateau</h4><table><tr><th>axis</th><th>plateau °C</th><th>duration s</th><th>terms</th></tr>\n");
                for a in &d.axes {
                    for p in &a.plateaus {
                        let _ = writeln!(
                            h,
                            "<tr><td>{}</td><td>{:.1}</td><td>{:.0}</td><td>{}</td></tr>",
                            esc(&a.axis),
                            p.temperature_c,
                            p.duration_s,
                            esc(&noise_text(p))
                        );
                    }
                }
                h.push_str("</table>\n");
            }
        }
        for a in &d.axes {
            let _ = writeln!(
                h,
                "<div class=\"plots\">{}{}</div>",
                plot::bias_against_temperature(a),
                plot::against_time(a)
            );
            for n in &a.notes {
                let _ = writeln!(
                    h,
                    "<p class=\"note\">{} {}: {}</p>",
                    esc(&a.device),
                    esc(&a.axis),
                    esc(n)
                );
            }
        }
    }
    h.push_str("</section>\n");
    h
}

/// A self-contained page holding the thermal section.
pub fn html_page(report: &ThermalReport, title: &str) -> String {
    format!(
        "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>{t}</title><style>\
         body{{font-family:sans-serif;margin:1.5em;max-width:1340px}}\
         table{{border-collapse:collapse;margin:0.5em 0}}td,th{{border:1px solid #bbb;padding:3px 6px;font-size:13px}}\
         .plots svg{{margin:4px}} .note{{color:#555;font-size:13px}}</style></head>\
         <body><h1>{t}</h1><p>Input: {input}; {gen}</p>{section}</body></html>\n",
        t = esc(title),
        input = esc(&report.input),
        gen = esc(&report.generator),
        section = html_section(report)
    )
}
