//! Term selection over many seeds: simulates one axis of every IMU preset (gyro and
//! accelerometer, no wire, no daemon), fits the noise model to its overlapping Allan
//! deviation on the octave grid the reports use, and counts per term how often a term
//! the preset does not have is reported (false positive) and how often one it has is
//! not (miss). The presets have white noise (N) and bias instability (B); quantization
//! (Q), rate random walk (K) and rate ramp (R) are absent. Presets with a thermal model
//! (warm-up transient, temperature coefficients) are left out: a bias settling over 300 s
//! after power-on is a real drift the fit rightly reads as K or R, not a noise term, and
//! `imulab thermal` is what measures it.
//!
//! ```text
//! cargo run --release --example term_selection -- [--hours 6] [--seeds 20] [--rate 150]
//! ```
//!
//! The table in docs/bench/allan.md ("term selection") comes from this program; it writes
//! its counts and BENCHMARKS.md row to `benches/results/term_selection-seeds.json`.

#[path = "../benches/support/results.rs"]
mod results;

use clap::Parser;
use imulab::allan::fit::{fit_noise_terms, Term};
use imulab::allan::{compute_curve, DeviationKind, Phase, TauGrid};
use imulab::sim::imu_model::{Channels, ImuSimulator};
use imulab::sim::presets::{imu_preset, imu_preset_names};
use nalgebra::Vector3;
use rayon::prelude::*;

#[derive(Parser, Debug)]
struct Args {
    /// Run length, hours.
    #[arg(long, default_value_t = 6.0)]
    hours: f64,
    /// Seeds 1..=N per preset and sensor.
    #[arg(long, default_value_t = 20)]
    seeds: u64,
    /// Sample rate, Hz.
    #[arg(long, default_value_t = 150.0)]
    rate: f64,
    /// Axis 0, 1 or 2.
    #[arg(long, default_value_t = 0)]
    axis: usize,
}

fn main() -> Result<(), String> {
    let args = Args::parse();
    let n = (args.hours * 3600.0 * args.rate).round() as usize;
    let tau0 = 1.0 / args.rate;
    let present = [Term::RandomWalk, Term::BiasInstability];
    // [term] -> (reported, runs)
    let mut totals = [(0usize, 0usize); 5];
    let mut cases = Vec::new();
    println!(
        "{} h at {} Hz, {} seeds, axis {}: reported / runs per term (N, B present; Q, K, R absent)",
        args.hours, args.rate, args.seeds, args.axis
    );
    println!("preset       sensor |   Q   N   B   K   R");
    for name in imu_preset_names() {
        let spec = imu_preset(name).ok_or(format!("no preset {name}"))?;
        if has_thermal_model(&spec) {
            continue;
        }
        for gyro in [true, false] {
            // Seeds in parallel (rayon), counted in seed order.
            let runs: Vec<[bool; 5]> = (1..=args.seeds)
                .into_par_iter()
                .map(|seed| -> Result<[bool; 5], String> {
                    let mut on = [false; 3];
                    on[args.axis] = true;
                    let channels = if gyro {
                        Channels {
                            gyro: on,
                            accel: [false; 3],
                        }
                    } else {
                        Channels {
                            gyro: [false; 3],
                            accel: on,
                        }
                    };
                    let mut sim = ImuSimulator::new(&spec, "dut", seed, args.rate, channels)?;
                    let zero = Vector3::zeros();
                    let mut y = Vec::with_capacity(n + 1);
                    for _ in 0..n {
                        let r = sim
                            .step(&zero, &zero, spec.reference_temp_c, 0, 0)
                            .record
                            .ok_or("dropped sample")?;
                        y.push(if gyro {
                            r.gyro[args.axis]
                        } else {
                            r.accel[args.axis]
                        });
                    }
                    let curve = compute_curve(
                        &Phase::from_rate(y),
                        tau0,
                        DeviationKind::Oadev,
                        &TauGrid::Octave,
                    );
                    let fit = fit_noise_terms(&curve).map_err(|e| e.to_string())?;
                    Ok(Term::ALL.map(|term| fit.get(term).is_some_and(|t| t.value.is_some())))
                })
                .collect::<Result<_, _>>()?;
            let mut reported = [0usize; 5];
            for run in &runs {
                for (j, &r) in run.iter().enumerate() {
                    reported[j] += usize::from(r);
                }
            }
            let cells: Vec<String> = reported.iter().map(|r| format!("{r:>3}")).collect();
            println!(
                "{name:<12} {:<6} | {}",
                if gyro { "gyro" } else { "accel" },
                cells.join(" ")
            );
            cases.push(serde_json::json!({
                "preset": name, "sensor": if gyro { "gyro" } else { "accel" },
                "reported": reported.iter().zip(Term::ALL).map(|(r, t)| (t.symbol().to_string(), *r)).collect::<std::collections::BTreeMap<_, _>>(),
            }));
            for (j, r) in reported.iter().enumerate() {
                totals[j].0 += r;
                totals[j].1 += args.seeds as usize;
            }
        }
    }
    println!("per term over all presets and sensors:");
    for (j, term) in Term::ALL.iter().enumerate() {
        let (r, runs) = totals[j];
        let rate = 100.0 * r as f64 / runs.max(1) as f64;
        if present.contains(term) {
            println!(
                "  {} present: missed {}/{runs} ({:.1} %)",
                term.symbol(),
                runs - r,
                100.0 - rate
            );
        } else {
            println!(
                "  {} absent: reported {r}/{runs} ({rate:.1} %)",
                term.symbol()
            );
        }
    }
    write_results(&args, &totals, &present, cases);
    Ok(())
}

/// The term-selection row: absent terms reported, present ones missed, each ≤ 5 %; a term
/// over 5 % names the preset and sensor most of its wrong calls come from.
fn write_results(
    args: &Args,
    totals: &[(usize, usize); 5],
    present: &[Term],
    cases: Vec<serde_json::Value>,
) {
    let runs = totals[0].1;
    let wrong_in = |c: &serde_json::Value, term: Term| {
        let r = c["reported"][term.symbol()].as_u64().unwrap_or(0);
        if present.contains(&term) {
            args.seeds - r
        } else {
            r
        }
    };
    let (mut reported, mut missed, mut over) = (Vec::new(), Vec::new(), None);
    for (j, term) in Term::ALL.iter().enumerate() {
        let (r, n) = totals[j];
        let wrong = if present.contains(term) { n - r } else { r };
        if present.contains(term) {
            missed.push(format!("{} {wrong}", term.symbol()));
        } else {
            reported.push(format!("{} {r}", term.symbol()));
        }
        if wrong as f64 > 0.05 * n as f64 && over.is_none() {
            over = Some((*term, wrong, n));
        }
    }
    let presets = cases.len() / 2;
    let mut row = results::Row::new(
        "allan-term-selection",
        results::ALLAN,
        8,
        "term selection",
        "docs/bench/allan.md",
    )
    .data(format!(
        "{presets} presets × 2 sensors × {} seeds, {} h",
        args.seeds, args.hours
    ))
    .ours(format!(
        "of {runs} each: absent reported {}; present missed {}",
        reported.join(", "),
        missed.join(", ")
    ))
    .target("≤ 5 %")
    .met(over.is_none())
    .command(format!(
        "cargo run{} --example term_selection -- --hours {} --seeds {}",
        if cfg!(debug_assertions) {
            ""
        } else {
            " --release"
        },
        args.hours,
        args.seeds
    ));
    if let Some((term, wrong, n)) = over {
        if let Some(worst) = cases.iter().max_by_key(|c| wrong_in(c, term)) {
            row = row.not_met(
                format!("Term selection ≤ 5 % ({} {wrong}/{n})", term.symbol()),
                format!(
                    "{} of them are the {} {} runs, in {} of its {} seeds",
                    wrong_in(worst, term),
                    worst["preset"].as_str().unwrap_or(""),
                    worst["sensor"].as_str().unwrap_or(""),
                    wrong_in(worst, term),
                    args.seeds
                ),
            );
        }
    }
    results::write(
        "term_selection",
        "seeds",
        serde_json::json!({ "hours": args.hours, "seeds": args.seeds, "rate_hz": args.rate, "axis": args.axis }),
        serde_json::json!({ "cases": cases, "per_term": Term::ALL.iter().zip(totals).map(|(t, (r, n))| serde_json::json!({"term": t.symbol(), "reported": r, "runs": n})).collect::<Vec<_>>() }),
        &[row],
    );
}

/// Whether a preset's bias moves with temperature or settles after power-on.
fn has_thermal_model(spec: &imulab::sim::imu_model::ImuSpec) -> bool {
    let any = |v: &[f64]| v.iter().any(|x| *x != 0.0);
    any(&spec.gyro.warmup_bias_dph)
        || any(&spec.accel.warmup_bias_mg)
        || any(&spec.gyro.bias_tempco_dph_per_c)
        || any(&spec.accel.bias_tempco_mg_per_c)
}
