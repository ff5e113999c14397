//! Stable32 agreement of the noise identification and the confidence intervals: every
//! row of every Stable32 table in `../shared/external/allan-reference` goes through
//! [`compute_curve`] on the table's τ list, and the identified α and the 68 % bounds are
//! compared with the printed ones. The match counts per table are printed and asserted
//! to be every row, except the TOTDEV all-τ table: it prints α = 0 on every row, also
//! where Stable32's own ADEV of the same data at the same τ identifies 1 … −2, so its α
//! are counted and printed but not taken as identifications.
//! Skips with a message when the reference data are absent.

use super::reference::{read_numbers, read_table, reference_dir, Row};
use imulab::allan::{compute_curve, Curve, DeviationKind, Phase, TauGrid};

/// Relative tolerance on a printed bound (Stable32 prints 5 significant digits, ~1e-4).
const BOUND_TOLERANCE: f64 = 1e-3;

#[derive(Default, Debug)]
struct Counts {
    rows: usize,
    alpha_matched: usize,
    bounds: usize,
    bounds_matched: usize,
    worst_bound: f64,
    misses: Vec<String>,
}

/// Compares `curve` with `rows`; bounds are checked as printed (`relative_bounds` false) or
/// relative to sigma (for tables computed on a differently normalised copy of the data).
fn compare(curve: &Curve, rows: &[Row], relative_bounds: bool) -> Counts {
    let mut counts = Counts::default();
    for row in rows {
        counts.rows += 1;
        let Some(p) = curve.points.iter().find(|p| p.m == row.m) else {
            counts.misses.push(format!("m={}: no point", row.m));
            continue;
        };
        if p.alpha == row.alpha {
            counts.alpha_matched += 1;
        } else {
            counts
                .misses
                .push(format!("m={}: alpha {} vs {}", row.m, p.alpha, row.alpha));
        }
        if row.low > 0.0 {
            counts.bounds += 1;
            let scale = if relative_bounds {
                row.sigma / p.deviation
            } else {
                1.0
            };
            let (Some(low), Some(high)) = (p.low, p.high) else {
                counts.misses.push(format!("m={}: no interval", row.m));
                continue;
            };
            let error = ((low * scale - row.low) / row.low)
                .abs()
                .max(((high * scale - row.high) / row.high).abs());
            counts.worst_bound = counts.worst_bound.max(error);
            if error <= BOUND_TOLERANCE {
                counts.bounds_matched += 1;
            } else {
                counts.misses.push(format!(
                    "m={} alpha {}: bounds [{:.5e}, {:.5e}] vs [{:.4e}, {:.4e}] (edf {:?}, error {error:.2e})",
                    row.m,
                    p.alpha,
                    low * scale,
                    high * scale,
                    row.low,
                    row.high,
                    p.edf
                ));
            }
        }
    }
    counts
}

fn kind_of(name: &str) -> DeviationKind {
    <DeviationKind as clap::ValueEnum>::from_str(name, true)
        .unwrap_or_else(|e| panic!("unknown kind {name}: {e}"))
}

#[test]
fn stable32_alphas_and_bounds_match_every_row() {
    let Some(dir) = reference_dir() else { return };
    let phase_dat = Phase::from_phase(&read_numbers(&dir.join("phasedat/PHASE.DAT")), 1.0);
    let ocxo = Phase::from_rate(
        read_numbers(&dir.join("ocxo/ocxo_frequency.txt"))
            .iter()
            .map(|f| (f - 1e7) / 1e7)
            .collect(),
    );
    // (file, phase, kind, bounds relative to sigma, α matched at least, bounds matched at least)
    let mut tables: Vec<(String, &Phase, String, bool)> = Vec::new();
    for name in ["adev", "oadev", "mdev", "hdev", "ohdev", "tdev", "totdev"] {
        tables.push((
            format!("phasedat/phase_dat_{name}_octave.txt"),
            &phase_dat,
            name.into(),
            false,
        ));
    }
    for name in ["adev", "oadev"] {
        tables.push((
            format!("phasedat/phase_dat_{name}.txt"),
            &phase_dat,
            name.into(),
            false,
        ));
    }
    for name in ["adev", "oadev", "mdev", "hdev", "totdev"] {
        tables.push((
            format!("ocxo/stable32_{name}_alltau.txt"),
            &ocxo,
            name.into(),
            false,
        ));
    }
    for name in ["adev", "oadev"] {
        tables.push((format!("ocxo/{name}_octave.txt"), &ocxo, name.into(), true));
    }
    // The TOTDEV all-τ table's α are not identifications (see the module doc).
    let not_identified = "ocxo/stable32_totdev_alltau.txt";
    let mut failed = Vec::new();
    let (mut alpha_total, mut alpha_rows, mut bound_total, mut bound_rows) = (0, 0, 0, 0);
    // α of the tables whose α are identifications.
    let mut identified = (0, 0);
    for (file, phase, name, relative) in &tables {
        let rows = read_table(&dir.join(file));
        let grid = TauGrid::List(rows.iter().map(|r| r.tau).collect());
        let curve = compute_curve(phase, 1.0, kind_of(name), &grid);
        let counts = compare(&curve, &rows, *relative);
        eprintln!(
            "{file}: alpha {}/{}, bounds {}/{} within {BOUND_TOLERANCE:e} (worst {:.2e})",
            counts.alpha_matched,
            counts.rows,
            counts.bounds_matched,
            counts.bounds,
            counts.worst_bound
        );
        for miss in counts.misses.iter().take(12) {
            eprintln!("    {miss}");
        }
        alpha_total += counts.alpha_matched;
        alpha_rows += counts.rows;
        if file != not_identified {
            identified.0 += counts.alpha_matched;
            identified.1 += counts.rows;
        }
        bound_total += counts.bounds_matched;
        bound_rows += counts.bounds;
        let alphas_ok = counts.alpha_matched == counts.rows || file == not_identified;
        if !alphas_ok || counts.bounds_matched < counts.bounds {
            failed.push(file.clone());
        }
    }
    eprintln!("all tables: alpha {alpha_total}/{alpha_rows}, bounds {bound_total}/{bound_rows}");
    if super::results::requested() {
        let row = super::results::Row::new(
            "allan-stable32",
            super::results::ALLAN,
            9,
            "Stable32 noise ID and bounds",
            "docs/bench/allan.md",
        )
        .data(format!("{} Stable32 tables", tables.len()))
        .ours(format!(
            "α {}/{}, bounds {bound_total}/{bound_rows} within {BOUND_TOLERANCE:.0e}",
            identified.0, identified.1
        ))
        .target("100 %")
        .met(failed.is_empty())
        .command(format!(
            "IMULAB_BENCH_RESULTS=benches/results cargo test{} --test allan stable32",
            if cfg!(debug_assertions) {
                ""
            } else {
                " --release"
            }
        ));
        super::results::write(
            "stable32",
            "test",
            serde_json::json!({ "tables": tables.iter().map(|t| t.0.clone()).collect::<Vec<_>>(), "bound_tolerance": BOUND_TOLERANCE }),
            serde_json::json!({
                "alpha_matched": alpha_total, "alpha_rows": alpha_rows,
                "alpha_matched_identified": identified.0, "alpha_rows_identified": identified.1,
                "bounds_matched": bound_total, "bounds": bound_rows, "failed": failed,
            }),
            &[row],
        );
    }
    assert!(
        failed.is_empty(),
        "tables with rows that differ from Stable32: {failed:?}"
    );
}
