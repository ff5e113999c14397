//! Rate-table calibration (after IEEE Std 1293's scale-factor tests): the gyro's mean output
//! over segments of known constant table rate, fitted against the rate. The table rates come
//! from a CSV (`rate_dps`, optionally `start_s`,`end_s`, `axis`, the body axis on the
//! spindle, and `input`, the recording the row belongs to; without times the constant-rate
//! segments are found in the data, in order, each recording on its own clock). The
//! recordings hold one mounting or three (x, then y, then z on the spindle, in one recording
//! or one each); each segment's mounting is the CSV's `axis` or the body axis along gravity
//! (a vertical spindle). Per mounting, each gyro axis's segment means against the rate give that
//! spindle axis's column of M, and the spindle axis's own output its non-linearity (a
//! quadratic term and the largest deviation from the straight line); three mountings give
//! the whole M and the biases.

use super::file::RateTableAxis;
use super::recording::Recording;
use super::statics::DetectorOptions;
use super::TriadModel;
use anyhow::{bail, Context, Result};
use nalgebra::{DMatrix, DVector};
use serde::Deserialize;
use statrs::distribution::{ContinuousCDF, StudentsT};
use std::collections::BTreeMap;
use std::path::Path;

/// One row of the table CSV.
#[derive(Debug, Clone, PartialEq)]
pub struct TableRow {
    pub rate_dps: f64,
    pub start_s: Option<f64>,
    pub end_s: Option<f64>,
    /// Body axis on the spindle (`x`, `y` or `z`); absent: the axis along gravity.
    pub axis: Option<char>,
    /// The input the row belongs to, as written: a 1-based index or the input's path (or
    /// its last component); absent: rows go to the inputs in order.
    pub input: Option<String>,
}

/// The CSV row as written, before the axis is checked.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CsvRow {
    rate_dps: f64,
    start_s: Option<f64>,
    end_s: Option<f64>,
    axis: Option<String>,
    input: Option<String>,
}

/// Fewest different rates per mounting: the quadratic fit (3 parameters) needs one more to
/// leave a residual.
pub const MIN_RATES: usize = 4;

const AXES: [&str; 3] = ["x", "y", "z"];

/// One constant-rate segment found or given.
#[derive(Debug, Clone, PartialEq)]
pub struct Segment {
    pub rate_dps: f64,
    pub t_start: f64,
    pub t_end: f64,
    /// Mean gyro and accel output over the segment.
    pub mean: [f64; 3],
    pub accel_mean: [f64; 3],
    pub samples: usize,
    /// Body axis on the spindle (0, 1, 2 for x, y, z).
    pub spindle: usize,
    /// The input (0-based) it was found in; its times are on that input's clock.
    pub input: usize,
}

/// Reads the table CSV.
pub fn read_table(path: &Path) -> Result<Vec<TableRow>> {
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_path(path)
        .with_context(|| format!("cannot read rate table {}", path.display()))?;
    let mut rows = Vec::new();
    for (i, row) in reader.deserialize::<CsvRow>().enumerate() {
        let row = row.map_err(|e| {
            anyhow::anyhow!(
                "{} row {}: {e} (columns: rate_dps, and optionally start_s, end_s, axis, input)",
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
        let axis = match row.axis.as_deref().map(str::to_ascii_lowercase).as_deref() {
            None | Some("") => None,
            Some("x") => Some('x'),
            Some("y") => Some('y'),
            Some("z") => Some('z'),
            Some(other) => bail!(
                "{} row {}: axis {other:?} is not x, y or z (the body axis on the spindle)",
                path.display(),
                i + 2
            ),
        };
        rows.push(TableRow {
            rate_dps: row.rate_dps,
            start_s: row.start_s,
            end_s: row.end_s,
            axis,
            input: row.input.filter(|s| !s.is_empty()),
        });
    }
    if rows.is_empty() {
        bail!(
            "{}: no table rates; list at least {MIN_RATES} different rates per mounting (both signs recommended)",
            path.display()
        );
    }
    Ok(rows)
}

fn accel_mean_of(rec: &Recording, lo: usize, hi: usize) -> [f64; 3] {
    let n = (hi - lo) as f64;
    let mut m = [0.0; 3];
    for r in &rec.accel[lo..hi] {
        for k in 0..3 {
            m[k] += r[k] / n;
        }
    }
    m
}

/// The body axis on the spindle for a segment: the row's, or the axis along gravity.
fn spindle_of(row: &TableRow, accel_mean: &[f64; 3], t: (f64, f64)) -> Result<usize> {
    if let Some(c) = row.axis {
        return Ok(AXES.iter().position(|a| a.starts_with(c)).unwrap_or(2));
    }
    let norm = accel_mean.iter().map(|v| v * v).sum::<f64>().sqrt();
    let k = (0..3)
        .max_by(|&a, &b| accel_mean[a].abs().total_cmp(&accel_mean[b].abs()))
        .unwrap_or(2);
    let off = (accel_mean[k].abs() / norm)
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees();
    if !(norm > 0.0 && off < 20.0) {
        bail!(
            "rate table: in the {} °/s segment ({:.1}-{:.1} s) gravity is {off:.0}° from the nearest body axis, so the axis on the spindle cannot be told from it; add an `axis` column (x, y or z) to the CSV",
            row.rate_dps,
            t.0,
            t.1
        );
    }
    Ok(k)
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

/// How an input is named in messages: its source, with its number when there are several.
fn label(recs: &[Recording], i: usize) -> String {
    if recs.len() > 1 {
        format!("input {} ({})", i + 1, recs[i].source)
    } else {
        recs[i].source.clone()
    }
}

/// The input a row's `input` names: a 1-based number, or an input's path as given or its
/// last component.
fn resolve(recs: &[Recording], row: usize, name: &str) -> Result<usize> {
    if let Ok(k) = name.parse::<usize>() {
        if (1..=recs.len()).contains(&k) {
            return Ok(k - 1);
        }
        bail!(
            "rate table: row {} names input {k}, but there are {} inputs (numbered from 1)",
            row + 2,
            recs.len()
        );
    }
    let matches: Vec<usize> = (0..recs.len())
        .filter(|&k| {
            let path = Path::new(&recs[k].name);
            recs[k].name == name
                || path.file_name().is_some_and(|f| f == name)
                || path.to_string_lossy().trim_end_matches('/') == name.trim_end_matches('/')
        })
        .collect();
    match matches.as_slice() {
        [k] => Ok(*k),
        [] => bail!(
            "rate table: row {} names input {name:?}, which is none of the inputs ({}); give its number (from 1) or its path",
            row + 2,
            recs.iter().map(|r| r.name.as_str()).collect::<Vec<_>>().join(", ")
        ),
        _ => bail!(
            "rate table: row {} names input {name:?}, which fits several inputs; give its number (from 1) or its whole path",
            row + 2
        ),
    }
}

/// The segments of `rows` in the inputs `recs`, each input on its own clock (a segment never
/// spans two inputs). With an `input` column each input takes its rows; without, the rows
/// go to the inputs in order: the segments found in the first input, then in the second…
/// A group of rows that all have times is cut by them (seconds from its input's first
/// sample); otherwise the segments are detected (steady rate away from the initial rest)
/// and matched to the rows in order.
pub fn segments(
    recs: &[Recording],
    rows: &[TableRow],
    opts: &DetectorOptions,
) -> Result<Vec<Segment>> {
    let named = rows.iter().filter(|r| r.input.is_some()).count();
    if named == 0 {
        if recs.len() == 1 && rows.iter().all(|r| r.start_s.is_some()) {
            return timed_segments(recs, 0, &rows.iter().collect::<Vec<_>>(), opts);
        }
        if recs.len() > 1 && rows.iter().any(|r| r.start_s.is_some()) {
            bail!(
                "rate table: with {} inputs, rows with start_s and end_s need an `input` column (the input's number from 1, or its path) saying whose clock their times are on",
                recs.len()
            );
        }
        let found: Vec<Vec<(usize, usize)>> = (0..recs.len())
            .map(|i| steady_segments(recs, i, opts))
            .collect::<Result<_>>()?;
        let total: usize = found.iter().map(Vec::len).sum();
        if total != rows.len() {
            let list: Vec<String> = found
                .iter()
                .enumerate()
                .map(|(i, f)| {
                    if recs.len() > 1 {
                        format!("{}: {}", label(recs, i), describe(&recs[i], f))
                    } else {
                        describe(&recs[i], f)
                    }
                })
                .collect();
            bail!(
                    "rate table: the CSV lists {} rates but {total} constant-rate segments were found: {}; give start_s and end_s for each rate in the CSV{}",
                    rows.len(),
                    list.join("; "),
                    if recs.len() > 1 { " (and its input)" } else { "" }
                );
        }
        let mut rows = rows.iter();
        let mut out = Vec::with_capacity(total);
        for (i, f) in found.iter().enumerate() {
            let rec = &recs[i];
            for (&(a, b), r) in f.iter().zip(rows.by_ref()) {
                out.push(segment(rec, r, a, b, (rec.t[a], rec.t[b - 1]), i)?);
            }
        }
        return Ok(out);
    }
    if named != rows.len() {
        let k = rows.iter().position(|r| r.input.is_none()).unwrap_or(0);
        bail!(
            "rate table: row {} has no `input`; give it for every row or for none",
            k + 2
        );
    }
    let owner: Vec<usize> = rows
        .iter()
        .enumerate()
        .map(|(k, r)| resolve(recs, k, r.input.as_deref().unwrap_or("")))
        .collect::<Result<_>>()?;
    let mut out = Vec::new();
    for i in 0..recs.len() {
        let mine: Vec<&TableRow> = rows
            .iter()
            .zip(&owner)
            .filter(|(_, &o)| o == i)
            .map(|(r, _)| r)
            .collect();
        if mine.is_empty() {
            bail!(
                "rate table: no CSV row names {} in its `input` column; list its rates, or leave the input out",
                label(recs, i)
            );
        }
        if mine.iter().all(|r| r.start_s.is_some()) {
            out.extend(timed_segments(recs, i, &mine, opts)?);
            continue;
        }
        let found = steady_segments(recs, i, opts)?;
        if found.len() != mine.len() {
            bail!(
                "rate table: the CSV lists {} rates for {} but {} constant-rate segments were found there: {}; give start_s and end_s for each rate in the CSV",
                mine.len(),
                label(recs, i),
                found.len(),
                describe(&recs[i], &found)
            );
        }
        let rec = &recs[i];
        for (&(a, b), r) in found.iter().zip(mine) {
            out.push(segment(rec, r, a, b, (rec.t[a], rec.t[b - 1]), i)?);
        }
    }
    Ok(out)
}

/// The end of input `i`'s initial rest, checked to be there.
fn rest_end(recs: &[Recording], i: usize, opts: &DetectorOptions) -> Result<usize> {
    let init_end = recs[i].t.partition_point(|&t| t < opts.init_s);
    if init_end < 10 {
        bail!(
            "{}: the rate-table run must start with the table at rest for --init-static {} s",
            label(recs, i),
            opts.init_s
        );
    }
    Ok(init_end)
}

/// The segments of input `i` cut by the rows' times.
fn timed_segments(
    recs: &[Recording],
    i: usize,
    rows: &[&TableRow],
    opts: &DetectorOptions,
) -> Result<Vec<Segment>> {
    rest_end(recs, i, opts)?;
    let rec = &recs[i];
    let mut out = Vec::new();
    for r in rows {
        let (a, b) = (r.start_s.unwrap_or(0.0), r.end_s.unwrap_or(0.0));
        let lo = rec.t.partition_point(|&t| t < a);
        let hi = rec.t.partition_point(|&t| t < b);
        if hi <= lo + 1 {
            bail!(
                "rate table: the segment {a}-{b} s at {} °/s holds no samples ({} spans 0-{:.1} s)",
                r.rate_dps,
                label(recs, i),
                rec.t[rec.len() - 1]
            );
        }
        out.push(segment(rec, r, lo, hi, (a, b), i)?);
    }
    Ok(out)
}

/// The found segments' times and approximate rates, for messages.
fn describe(rec: &Recording, found: &[(usize, usize)]) -> String {
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
    if list.is_empty() {
        "none".into()
    } else {
        list.join(", ")
    }
}

/// The steady-rate stretches of input `i` (sample ranges): gyro variance near the initial
/// rest's and a rate well away from rest, one window less at each end.
fn steady_segments(
    recs: &[Recording],
    i: usize,
    opts: &DetectorOptions,
) -> Result<Vec<(usize, usize)>> {
    let init_end = rest_end(recs, i, opts)?;
    let rec = &recs[i];
    let dt = rec.dt();
    let rest = mean_of(rec, 0, init_end);
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
        // One window less at each end: the tail of a change of rate can pass the variance
        // test while still short of the new rate.
        let (start, end) = (start + window, i.min(rec.len()).saturating_sub(window));
        if end >= start + min_len {
            found.push((start, end));
        }
    }
    Ok(found)
}

/// The segment of `row` over samples `lo..hi`, spanning times `t`.
fn segment(
    rec: &Recording,
    row: &TableRow,
    lo: usize,
    hi: usize,
    t: (f64, f64),
    input: usize,
) -> Result<Segment> {
    let accel_mean = accel_mean_of(rec, lo, hi);
    Ok(Segment {
        rate_dps: row.rate_dps,
        t_start: t.0,
        t_end: t.1,
        mean: mean_of(rec, lo, hi),
        accel_mean,
        samples: hi - lo,
        spindle: spindle_of(row, &accel_mean, t)?,
        input,
    })
}

/// Linear least squares y ≈ X·β: β, its standard errors (widened by t/1.96 for the
/// degrees of freedom left, so that 1.96 of them is the 95 % interval) and the residuals.
fn lstsq(x: &DMatrix<f64>, y: &DVector<f64>) -> Result<(DVector<f64>, Vec<f64>, DVector<f64>)> {
    let inv = (x.transpose() * x)
        .try_inverse()
        .context("rate table: the rates cannot separate bias, scale and non-linearity; use at least 4 different rates per mounting")?;
    let beta = &inv * x.transpose() * y;
    let r = y - x * &beta;
    let dof = x.nrows().saturating_sub(x.ncols()).max(1) as f64;
    let widen = StudentsT::new(0.0, 1.0, dof)
        .map(|d| d.inverse_cdf(0.975) / 1.96)
        .unwrap_or(1.0);
    let s2 = r.norm_squared() / dof;
    let se = (0..x.ncols())
        .map(|k| (inv[(k, k)] * s2).sqrt() * widen)
        .collect();
    Ok((beta, se, r))
}

/// One mounting's fit: the spindle axis's column of M (signed so that the diagonal entry is
/// positive), its standard errors, the intercepts and their standard errors, and the
/// spindle axis's non-linearity.
struct MountingFit {
    column: [f64; 3],
    column_sigma: [f64; 3],
    intercept: [f64; 3],
    intercept_sigma: [f64; 3],
    axis: RateTableAxis,
}

fn fit_mounting(k: usize, segs: &[&Segment]) -> Result<MountingFit> {
    let name = AXES[k];
    let mut distinct: Vec<f64> = segs.iter().map(|s| s.rate_dps).collect();
    distinct.sort_by(f64::total_cmp);
    distinct.dedup();
    if distinct.len() < MIN_RATES {
        bail!(
            "rate table: the mounting with {name} on the spindle has {} different rates ({}); each mounting needs at least {MIN_RATES} (both signs recommended) for the scale factor and non-linearity",
            distinct.len(),
            distinct
                .iter()
                .map(|r| format!("{r} °/s"))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    let rates: Vec<f64> = segs.iter().map(|s| s.rate_dps.to_radians()).collect();
    let n = rates.len();
    let lin = DMatrix::from_fn(n, 2, |i, j| if j == 0 { 1.0 } else { rates[i] });
    let mut slope = [0.0; 3];
    let mut fit = MountingFit {
        column: [0.0; 3],
        column_sigma: [0.0; 3],
        intercept: [0.0; 3],
        intercept_sigma: [0.0; 3],
        axis: RateTableAxis::default(),
    };
    for (i, slope) in slope.iter_mut().enumerate() {
        let y = DVector::from_iterator(n, segs.iter().map(|s| s.mean[i]));
        let (beta, se, _) = lstsq(&lin, &y)?;
        *slope = beta[1];
        fit.column_sigma[i] = se[1];
        fit.intercept[i] = beta[0];
        fit.intercept_sigma[i] = se[0];
    }
    let follows = (0..3)
        .max_by(|&a, &b| slope[a].abs().total_cmp(&slope[b].abs()))
        .unwrap_or(k);
    if follows != k {
        bail!(
            "rate table: the segments at {:.1}-{:.1} s were taken as {name} on the spindle, but the gyro's {} axis follows the table rate; state the axis in an `axis` column of the CSV",
            segs[0].t_start,
            segs[n - 1].t_end,
            AXES[follows]
        );
    }
    // The body axis along the spindle's positive direction is +k or −k: the sign of the
    // spindle axis's own response.
    let sign = slope[k].signum();
    fit.column = slope.map(|v| v * sign);
    let x: Vec<f64> = rates.iter().map(|r| r * sign).collect();
    let y = DVector::from_iterator(n, segs.iter().map(|s| s.mean[k]));
    let lin_x = DMatrix::from_fn(n, 2, |i, j| if j == 0 { 1.0 } else { x[i] });
    let (_, _, straight) = lstsq(&lin_x, &y)?;
    let quad = DMatrix::from_fn(n, 3, |i, j| x[i].powi(j as i32));
    let (q, q_se, _) = lstsq(&quad, &y)?;
    // The spindle axis's slope and its error from the fit with the quadratic term: the
    // straight line's residuals would hold the non-linearity.
    fit.column[k] = q[1];
    fit.column_sigma[k] = q_se[1];
    let full_scale = x.iter().map(|r| r.abs()).fold(0.0, f64::max);
    let scale = fit.column[k];
    let per_dps = 1e6 * 1f64.to_radians() / q[1];
    fit.axis = RateTableAxis {
        axis: if sign < 0.0 {
            format!("-{name}")
        } else {
            name.into()
        },
        rates_dps: segs.iter().map(|s| s.rate_dps).collect(),
        scale_factor_ppm: (scale - 1.0) * 1e6,
        scale_factor_sigma_ppm: fit.column_sigma[k] * 1e6,
        quadratic_ppm_per_dps: q[2] * per_dps,
        quadratic_sigma_ppm_per_dps: q_se[2] * per_dps.abs(),
        nonlinearity_ppm_of_full_scale: straight.amax() / (scale * full_scale) * 1e6,
    };
    Ok(fit)
}

/// Fits the gyro from the segments. One mounting: the bias (the intercepts) and the spindle
/// axis's column of M, the other columns those of the identity. Three mountings (x, y and z
/// each on the spindle once): the whole M and the bias of each axis from the two mountings
/// in which it is off the spindle (on it, the intercept also holds the earth rate's vertical
/// component).
pub fn fit_rate_table(segs: &[Segment]) -> Result<(TriadModel, Vec<RateTableAxis>)> {
    let mut by_axis: BTreeMap<usize, Vec<&Segment>> = BTreeMap::new();
    for s in segs {
        by_axis.entry(s.spindle).or_default().push(s);
    }
    if by_axis.len() == 2 {
        let missing: Vec<&str> = (0..3)
            .filter(|k| !by_axis.contains_key(k))
            .map(|k| AXES[k])
            .collect();
        let found: Vec<&str> = by_axis.keys().map(|&k| AXES[k]).collect();
        bail!(
            "rate table: mountings with {} on the spindle found, {} missing; the full gyro matrix needs x, y and z each on the spindle (or run one mounting alone for its axis only)",
            found.join(" and "),
            missing.join(", ")
        );
    }
    let fits: Vec<(usize, MountingFit)> = by_axis
        .iter()
        .map(|(&k, s)| Ok((k, fit_mounting(k, s)?)))
        .collect::<Result<_>>()?;
    let mut model = TriadModel {
        bias: [0.0; 3],
        bias_sigma: [0.0; 3],
        matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        matrix_sigma: [[0.0; 3]; 3],
    };
    for (k, f) in &fits {
        for i in 0..3 {
            model.matrix[i][*k] = f.column[i];
            model.matrix_sigma[i][*k] = f.column_sigma[i];
        }
    }
    if let [(_, only)] = fits.as_slice() {
        model.bias = only.intercept;
        model.bias_sigma = only.intercept_sigma;
    } else {
        for i in 0..3 {
            let off: Vec<&MountingFit> = fits
                .iter()
                .filter(|(k, _)| *k != i)
                .map(|(_, f)| f)
                .collect();
            let m = off.len() as f64;
            model.bias[i] = off.iter().map(|f| f.intercept[i]).sum::<f64>() / m;
            model.bias_sigma[i] = off
                .iter()
                .map(|f| f.intercept_sigma[i].powi(2))
                .sum::<f64>()
                .sqrt()
                / m;
        }
    }
    Ok((model, fits.into_iter().map(|(_, f)| f.axis).collect()))
}
