//! Rate-table calibration (after IEEE Std 1293's scale-factor tests): the gyro's mean output
//! over segments of known constant table rate, fitted against the rate. The table rates come
//! from a CSV (`rate_dps`, and optionally `start_s`,`end_s`; without times the constant-rate
//! segments are found in the data, in order). The spindle axis is the one whose output
//! follows the rate; its scale factor and non-linearity (a quadratic term and the largest
//! deviation from the straight line) come from least squares, the other axes' sensitivity to
//! it is its column of M.

use super::file::RateTableResult;
use super::recording::Recording;
use super::statics::DetectorOptions;
use super::TriadModel;
use anyhow::{bail, Context, Result};
use nalgebra::{DMatrix, DVector};
use serde::Deserialize;
use std::path::Path;

/// One row of the table CSV.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TableRow {
    pub rate_dps: f64,
    pub start_s: Option<f64>,
    pub end_s: Option<f64>,
}

/// One constant-rate segment found or given.
#[derive(Debug, Clone, PartialEq)]
pub struct Segment {
    pub rate_dps: f64,
    pub t_start: f64,
    pub t_end: f64,
    pub mean: [f64; 3],
    pub samples: usize,
}

/// Reads the table CSV.
pub fn read_table(path: &Path) -> Result<Vec<TableRow>> {
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_path(path)
        .with_context(|| format!("cannot read rate table {}", path.display()))?;
    let mut rows = Vec::new();
    for (i, row) in reader.deserialize::<TableRow>().enumerate() {
        let row = row.map_err(|e| {
            anyhow::anyhow!(
                "{} row {}: {e} (columns: rate_dps, and optionally start_s, end_s)",
                path.display(),
                i + 2
            )
        })?;
        if !row.rate_dps.is_finite() || row.start_s.is_some() != row.end_s.is_some() {
            bail!(
                "{} row {}: give a finite rate_dps and either both start_s and end_s or neither",
                path.display(),
                i + 2
            );
        }
        rows.push(row);
    }
    if rows.len() < 3 {
        bail!(
            "{}: {} table rates; the scale-factor and non-linearity fit needs at least 3 different rates (both signs recommended)",
            path.display(),
            rows.len()
        );
    }
    Ok(rows)
}

fn mean_of(rec: &Recording, lo: usize, hi: usize) -> [f64; 3] {
    let n = (hi - lo) as f64;
    let mut m = [0.0; 3];
    for r in &rec.gyro[lo..hi] {
        for k in 0..3 {
            m[k] += r[k] / n;
        }
    }
    m
}

/// The segments of `rows` in `rec`: by their times, or detected (steady rate away from the
/// initial rest) and matched to the rows in order. Also returns the rest mean (the bias).
pub fn segments(
    rec: &Recording,
    rows: &[TableRow],
    opts: &DetectorOptions,
) -> Result<(Vec<Segment>, [f64; 3])> {
    let dt = rec.dt();
    let init_end = rec.t.partition_point(|&t| t < opts.init_s);
    if init_end < 10 {
        bail!(
            "{}: the rate-table run must start with the table at rest for --init-static {} s",
            rec.source,
            opts.init_s
        );
    }
    let rest = mean_of(rec, 0, init_end);
    if rows.iter().all(|r| r.start_s.is_some()) {
        let mut out = Vec::new();
        for r in rows {
            let (a, b) = (r.start_s.unwrap_or(0.0), r.end_s.unwrap_or(0.0));
            let lo = rec.t.partition_point(|&t| t < a);
            let hi = rec.t.partition_point(|&t| t < b);
            if hi <= lo + 1 {
                bail!(
                    "rate table: the segment {a}-{b} s at {} °/s holds no samples (the recording spans 0-{:.1} s)",
                    r.rate_dps,
                    rec.t[rec.len() - 1]
                );
            }
            out.push(Segment {
                rate_dps: r.rate_dps,
                t_start: a,
                t_end: b,
                mean: mean_of(rec, lo, hi),
                samples: hi - lo,
            });
        }
        return Ok((out, rest));
    }
    // Steady windows: gyro variance near the rest's, and a rate well away from rest.
    let window = ((opts.window_s / dt).round() as usize).max(3) | 1;
    let var_of = |lo: usize, hi: usize| {
        let m = mean_of(rec, lo, hi);
        let n = (hi - lo) as f64;
        rec.gyro[lo..hi]
            .iter()
            .map(|r| (0..3).map(|k| (r[k] - m[k]).powi(2)).sum::<f64>())
            .sum::<f64>()
            / n
    };
    let rest_var = var_of(0, init_end).max(1e-14);
    let min_len = (opts.min_static_s / dt).round() as usize;
    let mut found = Vec::new();
    let mut i = init_end;
    while i + window <= rec.len() {
        let steady = |i: usize| {
            let m = mean_of(rec, i, i + window);
            let away = (0..3).map(|k| (m[k] - rest[k]).powi(2)).sum::<f64>().sqrt();
            var_of(i, i + window) < opts.threshold * rest_var && away > 1f64.to_radians()
        };
        if !steady(i) {
            i += window / 2 + 1;
            continue;
        }
        let start = i;
        while i + window <= rec.len() && steady(i) {
            i += window;
        }
        let end = i.min(rec.len());
        if end - start >= min_len {
            found.push((start, end));
        }
    }
    if found.len() != rows.len() {
        let list: Vec<String> = found
            .iter()
            .map(|&(a, b)| {
                let m = mean_of(rec, a, b);
                let big = m.iter().map(|v| v.abs()).fold(0.0, f64::max);
                format!(
                    "{:.1}-{:.1} s (~{:.1} °/s)",
                    rec.t[a],
                    rec.t[b - 1],
                    big.to_degrees()
                )
            })
            .collect();
        bail!(
            "rate table: the CSV lists {} rates but {} constant-rate segments were found: {}; give start_s and end_s for each rate in the CSV",
            rows.len(),
            found.len(),
            if list.is_empty() { "none".into() } else { list.join(", ") }
        );
    }
    Ok((
        found
            .iter()
            .zip(rows)
            .map(|(&(a, b), r)| Segment {
                rate_dps: r.rate_dps,
                t_start: rec.t[a],
                t_end: rec.t[b - 1],
                mean: mean_of(rec, a, b),
                samples: b - a,
            })
            .collect(),
        rest,
    ))
}

/// Linear least squares y ≈ X·β; returns β, its standard errors and the residuals.
fn lstsq(x: &DMatrix<f64>, y: &DVector<f64>) -> Result<(DVector<f64>, Vec<f64>, DVector<f64>)> {
    let xtx = x.transpose() * x;
    let inv = xtx
        .try_inverse()
        .context("rate table: the rates cannot separate bias, scale and non-linearity; use at least 3 different rates")?;
    let beta = &inv * x.transpose() * y;
    let r = y - x * &beta;
    let dof = (x.nrows() as f64 - x.ncols() as f64).max(1.0);
    let s2 = r.norm_squared() / dof;
    let se = (0..x.ncols()).map(|k| (inv[(k, k)] * s2).sqrt()).collect();
    Ok((beta, se, r))
}

/// Fits the gyro from the segments: bias and the spindle axis's column of M (the other
/// columns stay those of the identity: a one-axis table does not see them).
pub fn fit_rate_table(segs: &[Segment], rest: [f64; 3]) -> Result<(TriadModel, RateTableResult)> {
    let rates: Vec<f64> = segs.iter().map(|s| s.rate_dps.to_radians()).collect();
    let n = rates.len();
    let mut distinct = rates.clone();
    distinct.sort_by(f64::total_cmp);
    distinct.dedup();
    if distinct.len() < 3 {
        bail!(
            "rate table: {} different rates; the fit needs at least 3",
            distinct.len()
        );
    }
    let lin = DMatrix::from_fn(n, 2, |i, j| if j == 0 { 1.0 } else { rates[i] });
    let mut column = [0.0; 3];
    let mut column_sigma = [0.0; 3];
    let mut bias = rest;
    for k in 0..3 {
        let y = DVector::from_iterator(n, segs.iter().map(|s| s.mean[k]));
        let (beta, se, _) = lstsq(&lin, &y)?;
        column[k] = beta[1];
        column_sigma[k] = se[1];
        bias[k] = beta[0];
    }
    let axis = (0..3)
        .max_by(|&a, &b| column[a].abs().total_cmp(&column[b].abs()))
        .unwrap_or(2);
    let sign = column[axis].signum();
    let y = DVector::from_iterator(n, segs.iter().map(|s| s.mean[axis] * sign));
    let (_, _, straight) = lstsq(&lin, &y)?;
    let quad = DMatrix::from_fn(n, 3, |i, j| rates[i].powi(j as i32));
    let (q, _, _) = lstsq(&quad, &y)?;
    let full_scale = rates.iter().map(|r| r.abs()).fold(0.0, f64::max);
    let scale = column[axis].abs();
    let mut matrix = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let mut matrix_sigma = [[0.0; 3]; 3];
    for k in 0..3 {
        matrix[k][axis] = column[k] * sign;
        matrix_sigma[k][axis] = column_sigma[k];
    }
    let name = ["x", "y", "z"][axis];
    let mut rates_dps: Vec<f64> = segs.iter().map(|s| s.rate_dps).collect();
    rates_dps.dedup();
    Ok((
        TriadModel {
            bias,
            bias_sigma: [0.0; 3],
            matrix,
            matrix_sigma,
        },
        RateTableResult {
            axis: if sign < 0.0 {
                format!("-{name}")
            } else {
                name.into()
            },
            rates_dps,
            scale_factor_ppm: (scale - 1.0) * 1e6,
            scale_factor_sigma_ppm: column_sigma[axis] * 1e6,
            quadratic_ppm_per_dps: q[2] / q[1] * 1e6 * 1f64.to_radians(),
            nonlinearity_ppm_of_full_scale: straight.amax() / (scale * full_scale) * 1e6,
        },
    ))
}
