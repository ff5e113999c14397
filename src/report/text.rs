//! Numbers, units and text as the report prints them: datasheet units, durations,
//! significant figures, HTML escaping.

use crate::allan::analysis::AxisResult;
use crate::allan::thermal::ThermalSummary;
use crate::allan::units::thermal_coefficient_in_units;

/// `text` with the characters HTML and SVG give meaning to (`&`, `<`, `>`, `"`) escaped.
pub fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A duration for people: seconds, minutes or hours.
pub(super) fn duration(seconds: f64) -> String {
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
pub(super) fn sig3(v: f64) -> String {
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

pub(super) fn seconds(v: Option<f64>) -> String {
    match v {
        None => "–".into(),
        Some(t) if t >= 1e6 => "&gt; 10⁶ s".into(),
        Some(t) if t >= 120.0 => format!("{} s ({:.1} min)", sig3(t), t / 60.0),
        Some(t) => format!("{} s", sig3(t)),
    }
}
