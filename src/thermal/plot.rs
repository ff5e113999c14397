//! SVG plots of the thermal section (plotters' SVG backend, as the Allan report uses):
//! bias against temperature with the fit, its 95 % band and both branches, and the
//! temperature and bias against time.

use super::analysis::AxisThermal;
use super::polyfit::PolyFit;
use plotters::prelude::*;

const GREY: RGBColor = RGBColor(160, 160, 160);
const RISING: RGBColor = RGBColor(200, 40, 40);
const FALLING: RGBColor = RGBColor(40, 80, 200);

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-9);
    (lo - pad, hi + pad)
}

fn curve(fit: &PolyFit, scale: f64, offset: f64) -> Vec<(f64, f64)> {
    let [lo, hi] = fit.range_c;
    (0..=100)
        .map(|k| {
            let t = lo + (hi - lo) * k as f64 / 100.0;
            (t, fit.eval(t) * scale + offset)
        })
        .collect()
}

/// Bias against temperature: block means (grey, red rising, blue falling), the fit (black)
/// with its band, and the branch fits.
pub fn bias_against_temperature(a: &AxisThermal) -> String {
    let mut svg = String::new();
    draw_bias(&mut svg, a);
    svg
}

fn draw_bias(svg: &mut String, a: &AxisThermal) {
    let scale = super::analysis::datasheet_unit(a.sensor, a.unit).1;
    {
        let root = SVGBackend::with_string(svg, (640, 400)).into_drawing_area();
        let _ = root.fill(&WHITE);
        let (x0, x1) = range(a.trace.temp_c.iter().copied());
        let (y0, y1) = range(a.trace.bias.iter().copied());
        let Ok(mut chart) = ChartBuilder::on(&root)
            .caption(
                format!("{} {}: bias against sensor temperature", a.device, a.axis),
                ("sans-serif", 16),
            )
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, y0..y1)
        else {
            return;
        };
        let _ = chart
            .configure_mesh()
            .x_desc("sensor temperature, °C")
            .y_desc(format!("bias, {}", a.datasheet_unit))
            .draw();
        let points = a
            .trace
            .temp_c
            .iter()
            .zip(&a.trace.bias)
            .zip(&a.trace.branch)
            .map(|((&t, &b), &br)| {
                let color = match br {
                    1 => RISING,
                    -1 => FALLING,
                    _ => GREY,
                };
                Circle::new((t, b), 2, color.filled())
            });
        let _ = chart.draw_series(points);
        let band: Vec<(f64, f64)> = {
            let [lo, hi] = a.fit.range_c;
            let ts: Vec<f64> = (0..=100)
                .map(|k| lo + (hi - lo) * k as f64 / 100.0)
                .collect();
            ts.iter()
                .map(|&t| (t, (a.fit.eval(t) + a.fit.band(t)) * scale))
                .chain(
                    ts.iter()
                        .rev()
                        .map(|&t| (t, (a.fit.eval(t) - a.fit.band(t)) * scale)),
                )
                .collect()
        };
        let _ = chart.draw_series(std::iter::once(Polygon::new(band, BLACK.mix(0.15))));
        if let Some(h) = &a.hysteresis {
            let _ = chart
                .draw_series(LineSeries::new(
                    curve(&h.rising, scale, 0.0),
                    RISING.stroke_width(2),
                ))
                .map(|s| {
                    s.label("rising")
                        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], RISING))
                });
            let _ = chart
                .draw_series(LineSeries::new(
                    curve(&h.falling, scale, 0.0),
                    FALLING.stroke_width(2),
                ))
                .map(|s| {
                    s.label("falling")
                        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], FALLING))
                });
        }
        let _ = chart
            .draw_series(LineSeries::new(
                curve(&a.fit, scale, 0.0),
                BLACK.stroke_width(2),
            ))
            .map(|s| {
                s.label(format!("order-{} fit, 95 % band", a.fit.order))
                    .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK))
            });
        let _ = chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw();
        let _ = root.present();
    }
}

/// Sensor temperature (top) and bias (bottom) against time.
pub fn against_time(a: &AxisThermal) -> String {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (640, 400)).into_drawing_area();
        let _ = root.fill(&WHITE);
        let (top, bottom) = root.split_vertically(190);
        let hours: Vec<f64> = a.trace.t_s.iter().map(|t| t / 3600.0).collect();
        let (x0, x1) = range(hours.iter().copied());
        let panels = [
            (&top, &a.trace.temp_c, "temperature, °C".to_string(), RISING),
            (
                &bottom,
                &a.trace.bias,
                format!("bias, {}", a.datasheet_unit),
                FALLING,
            ),
        ];
        for (i, (area, values, label, color)) in panels.into_iter().enumerate() {
            let (y0, y1) = range(values.iter().copied());
            let mut builder = ChartBuilder::on(area);
            builder
                .margin(8)
                .x_label_area_size(30)
                .y_label_area_size(70);
            if i == 0 {
                builder.caption(
                    format!("{} {}: temperature and bias against time", a.device, a.axis),
                    ("sans-serif", 16),
                );
            }
            let Ok(mut chart) = builder.build_cartesian_2d(x0..x1, y0..y1) else {
                continue;
            };
            let _ = chart
                .configure_mesh()
                .x_desc("time, h")
                .y_desc(label)
                .draw();
            let _ = chart.draw_series(LineSeries::new(
                hours.iter().copied().zip(values.iter().copied()),
                color.stroke_width(1),
            ));
        }
        let _ = root.present();
    }
    svg
}
