//! Thermal analysis benchmark: recovery of known thermal coefficients from simulated
//! chamber runs over seeds and two grades, and the run time of the whole analysis of a
//! 24 h, 150 Hz, 6-axis run (one axis in memory at a time). Method and tables:
//! docs/bench/thermal.md. Run: `cargo bench --bench thermal` (`-- recovery`, `-- scale` or `-- timing` for one part;
//! `-- recovery --seeds N` for seeds 1..=N, 10 by default; `-- cli` replays
//! `thermal_drive.toml` through the release CLI with and without a model fitted by
//! `imulab thermal --model`). Figures and BENCHMARKS.md rows go to
//! `benches/results/thermal-<part>.json`.

#[path = "support/results.rs"]
mod results;

#[path = "support/cli.rs"]
mod cli;
use cli::{imulab, profile_flag, replay_drifts};

use imulab::allan::input::AxisSeries;
use imulab::allan::units::{RateUnit, SensorKind};
use imulab::sim::imu_model::{Channels, ImuSimulator, ImuSpec, G0};
use imulab::sim::presets::imu_preset;
use imulab::sim::temperature::{ProgramSegment, TemperatureProfile};
use imulab::thermal::analysis::{analyse_axis_thermal, AxisThermal, DeviceMotion, ThermalOptions};
use nalgebra::Vector3;
use serde_json::json;
use std::time::Instant;

fn chamber(cycles: u32) -> TemperatureProfile {
    TemperatureProfile::program(
        25.0,
        vec![
            ProgramSegment::Soak { duration_s: 1200.0 },
            ProgramSegment::Ramp {
                to_c: 60.0,
                c_per_min: 1.0,
            },
            ProgramSegment::Soak { duration_s: 1200.0 },
            ProgramSegment::Ramp {
                to_c: -10.0,
                c_per_min: 1.0,
            },
            ProgramSegment::Soak { duration_s: 1200.0 },
            ProgramSegment::Ramp {
                to_c: 25.0,
                c_per_min: 1.0,
            },
        ],
        cycles,
    )
}

/// One axis (x of `sensor`) of `spec` through `profile`, level: the series with its temperature.
fn simulate(
    spec: &ImuSpec,
    sensor: SensorKind,
    seed: u64,
    rate_hz: f64,
    duration_s: f64,
    profile: &TemperatureProfile,
) -> AxisSeries {
    simulate_posed(spec, sensor, seed, rate_hz, duration_s, profile, &|_| {
        Vector3::new(0.0, 0.0, -G0)
    })
}

/// As [`simulate`] with the specific force `force(t)` in the sensor frame.
fn simulate_posed(
    spec: &ImuSpec,
    sensor: SensorKind,
    seed: u64,
    rate_hz: f64,
    duration_s: f64,
    profile: &TemperatureProfile,
    force: &dyn Fn(f64) -> Vector3<f64>,
) -> AxisSeries {
    let channels = match sensor {
        SensorKind::Gyro => Channels {
            gyro: [true, false, false],
            accel: [false; 3],
        },
        SensorKind::Accel => Channels {
            gyro: [false; 3],
            accel: [true, false, false],
        },
    };
    let mut sim = ImuSimulator::new(spec, "bench", seed, rate_hz, channels).unwrap();
    let n = (duration_s * rate_hz) as usize;
    let w = Vector3::zeros();
    let mut rate = Vec::with_capacity(n);
    let mut temp = Vec::with_capacity(n);
    for k in 0..n {
        let t = k as f64 / rate_hz;
        let r = sim.step(&w, &force(t), profile.at(t), 0, 0).record.unwrap();
        rate.push(match sensor {
            SensorKind::Gyro => r.gyro[0],
            SensorKind::Accel => r.accel[0],
        });
        temp.push(r.temp as f32);
    }
    let name = match sensor {
        SensorKind::Gyro => "gyro_x",
        SensorKind::Accel => "accel_x",
    };
    let mut s = AxisSeries::one_segment(name, 1.0 / rate_hz, rate);
    s.temperature = Some(temp);
    s
}

fn analyse(series: AxisSeries, sensor: SensorKind, profile: &TemperatureProfile) -> AxisThermal {
    let unit = match sensor {
        SensorKind::Gyro => RateUnit::RadPerSecond,
        SensorKind::Accel => RateUnit::MetrePerSecondSquared,
    };
    let chamber = |t: f64| profile.at(t);
    analyse_axis_thermal(
        "bench",
        series,
        sensor,
        unit,
        Some(&chamber),
        &ThermalOptions::default(),
        &mut DeviceMotion::default(),
    )
    .unwrap()
    .0
}

/// Within 5 % of the truth, or the truth inside the stated 95 % interval.
fn recovered(a: &AxisThermal, order: usize, truth: f64) -> (bool, f64) {
    let Some(c) = a.coefficients.get(order) else {
        return (false, f64::NAN);
    };
    let error = (c.value - truth) / truth;
    (
        error.abs() <= 0.05 || (c.low..=c.high).contains(&truth),
        error,
    )
}

/// A term's name, its true value, and per seed (recovered, relative error).
type TermResults<'a> = (&'a str, f64, Vec<(bool, f64)>);

fn quiet_grade() -> ImuSpec {
    let mut s = imu_preset("icm20948-thermal").unwrap();
    s.gyro.noise_density_dps_rthz = Some([0.005; 3]);
    s.gyro.bias_instability_dph = [2.0; 3];
    s.accel.noise_density_ug_rthz = Some([100.0; 3]);
    s.accel.bias_instability_mg = [0.01; 3];
    s
}

fn main() {
    // `-- recovery`, `-- scale` or `-- timing` runs one part; all by default.
    // `--seeds N`: seeds 1..=N of `recovery` (10 by default).
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut seeds = 10u64;
    let mut parts = Vec::new();
    let mut i = 0;
    while i < args.len() {
        if args[i] == "--seeds" {
            let value = args.get(i + 1).map(String::as_str).unwrap_or("");
            seeds = match value.parse() {
                Ok(n) if n > 0 => n,
                _ => {
                    eprintln!("--seeds needs a positive whole number, got {value:?}");
                    std::process::exit(2);
                }
            };
            i += 2;
            continue;
        }
        if !args[i].starts_with('-') {
            parts.push(args[i].clone());
        }
        i += 1;
    }
    let wants = |part: &str| parts.is_empty() || parts.iter().any(|p| p == part);
    if wants("recovery") {
        recovery(seeds);
    }
    if wants("scale") {
        scale_recovery();
    }
    if wants("timing") {
        timing();
    }
    // Not part of the default run: it drives the release CLI.
    if parts.iter().any(|p| p == "cli") {
        cli_replay();
    }
}

fn recovery(seed_count: u64) {
    let seeds: Vec<u64> = (1..=seed_count).collect();
    let profile = chamber(1);
    let rate = 50.0;
    let duration = 12_000.0;
    println!(
        "| grade | sensor | term | truth | median error | median stated σ / truth | seeds ok | worst |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    let mut not_found = Vec::new();
    let mut cells = Vec::new();
    let mut limits: Vec<(String, f64)> = Vec::new();
    for (grade, spec) in [
        ("icm20948-thermal", imu_preset("icm20948-thermal").unwrap()),
        ("quiet", quiet_grade()),
    ] {
        for sensor in [SensorKind::Accel, SensorKind::Gyro] {
            let (c1, c2, hyst, tau_w) = match sensor {
                SensorKind::Accel => (
                    spec.accel.bias_tempco_mg_per_c[0],
                    spec.accel.bias_tempco2_mg_per_c2[0],
                    spec.accel.bias_hysteresis_mg[0],
                    spec.thermal.warmup_time_constant_s,
                ),
                SensorKind::Gyro => (
                    spec.gyro.bias_tempco_dph_per_c[0],
                    spec.gyro.bias_tempco2_dph_per_c2[0],
                    spec.gyro.bias_hysteresis_dph[0],
                    spec.thermal.warmup_time_constant_s,
                ),
            };
            let mut rows: Vec<TermResults> = vec![
                ("c1", c1, vec![]),
                ("c2", c2, vec![]),
                ("hysteresis gap", hyst, vec![]),
                ("warm-up τ", tau_w, vec![]),
                ("thermal lag τ", spec.thermal.time_constant_s, vec![]),
            ];
            let (mut tau_sigma, mut gap_sigma) = (Vec::new(), Vec::new());
            for &seed in &seeds {
                let a = analyse(
                    simulate(&spec, sensor, seed, rate, duration, &profile),
                    sensor,
                    &profile,
                );
                rows[0].2.push(recovered(&a, 1, c1));
                rows[1].2.push(recovered(&a, 2, c2));
                rows[2]
                    .2
                    .push(a.hysteresis.as_ref().map_or((false, f64::NAN), |h| {
                        let error = (h.largest_gap - hyst) / hyst;
                        let inside = (h.largest_gap - hyst).abs() <= h.largest_gap_ci95;
                        (error.abs() <= 0.10 || inside, error)
                    }));
                rows[3]
                    .2
                    .push(a.warmup.as_ref().map_or((false, f64::NAN), |w| {
                        let error = (w.time_constant_s - tau_w) / tau_w;
                        let [lo, hi] = w.time_constant_ci95_s;
                        (error.abs() <= 0.10 || (lo..=hi).contains(&tau_w), error)
                    }));
                if let Some(w) = &a.warmup {
                    tau_sigma.push(w.time_constant_relative_sigma);
                }
                // A miss without a transient: what the soak could have detected near τ.
                if let Some(l) = &a.warmup_detection_limit {
                    if let Some(d) = l.limits.iter().min_by(|x, y| {
                        (x.time_constant_s - tau_w)
                            .abs()
                            .total_cmp(&(y.time_constant_s - tau_w).abs())
                    }) {
                        not_found.push(format!(
                            "{grade} {sensor:?} seed {seed}: {:.2} {} at τ {:.0} s",
                            d.amplitude, l.unit, d.time_constant_s
                        ));
                        limits.push((format!("{grade} {sensor:?}"), d.amplitude));
                    }
                }
                if let Some(h) = &a.hysteresis {
                    gap_sigma.push(h.largest_gap_ci95 / 1.96 / hyst);
                }
                let chamber_c: Vec<f64> = a.trace.t_s.iter().map(|&t| profile.at(t)).collect();
                let lag =
                    imulab::thermal::analysis::fit_lag(&a.trace.t_s, &chamber_c, &a.trace.temp_c)
                        .map_or(f64::NAN, |l| {
                            (l.0 - spec.thermal.time_constant_s) / spec.thermal.time_constant_s
                        });
                rows[4].2.push((lag.abs() <= 0.10, lag));
            }
            let median = |v: &mut Vec<f64>| {
                v.sort_by(f64::total_cmp);
                v.get(v.len() / 2).copied().unwrap_or(f64::NAN) * 100.0
            };
            let sigma = [
                String::new(),
                String::new(),
                format!("{:.1} %", median(&mut gap_sigma)),
                format!("{:.1} %", median(&mut tau_sigma)),
                String::new(),
            ];
            let both = (0..seeds.len())
                .filter(|&i| rows[0].2[i].0 && rows[1].2[i].0)
                .count();
            cells.push(json!({
                "grade": grade, "sensor": format!("{sensor:?}"), "seeds": seeds.len(),
                "c1_and_c2_ok": both,
                "terms": rows.iter().map(|(term, truth, r)| json!({
                    "term": term, "truth": truth, "ok": r.iter().filter(|x| x.0).count(),
                    "found": r.iter().filter(|x| x.1.is_finite()).count(),
                    "errors": r.iter().map(|x| x.1).collect::<Vec<_>>(),
                })).collect::<Vec<_>>(),
                "warmup_truth": tau_w,
                "warmup_bias": match sensor {
                    SensorKind::Accel => spec.accel.warmup_bias_mg[0],
                    SensorKind::Gyro => spec.gyro.warmup_bias_dph[0],
                },
            }));
            for (k, (term, truth, results)) in rows.into_iter().enumerate() {
                let mut errors: Vec<f64> = results
                    .iter()
                    .map(|r| r.1)
                    .filter(|e| e.is_finite())
                    .collect();
                errors.sort_by(f64::total_cmp);
                let found = errors.len();
                let ok = results.iter().filter(|r| r.0).count();
                let worst = errors
                    .iter()
                    .copied()
                    .max_by(|a, b| a.abs().total_cmp(&b.abs()))
                    .unwrap_or(f64::NAN);
                println!(
                    "| {grade} | {sensor:?} | {term} | {truth} | {:+.1} % | {} | {ok}/{} | {:+.1} %{} |",
                    errors.get(errors.len() / 2).copied().unwrap_or(f64::NAN) * 100.0,
                    sigma[k],
                    results.len(),
                    worst * 100.0,
                    if found < results.len() {
                        format!(" (found in {found})")
                    } else {
                        String::new()
                    }
                );
            }
        }
    }
    if !not_found.is_empty() {
        println!(
            "\nwarm-up not found (a miss above); the smallest amplitude the soak could have detected near the true τ:"
        );
        for line in &not_found {
            println!("- {line}");
        }
    }
    let false_reported = false_warmups(&seeds, &profile, rate, duration);
    recovery_results(seed_count, &cells, &limits, &false_reported);
}

/// The three rows of the recovery table: bias tempco, hysteresis gap, warm-up τ.
fn recovery_results(
    seeds: u64,
    cells: &[serde_json::Value],
    limits: &[(String, f64)],
    false_reported: &[(String, usize)],
) {
    let n = seeds as usize;
    let term = |c: &serde_json::Value, t: &str| {
        c["terms"]
            .as_array()
            .and_then(|v| v.iter().find(|x| x["term"] == t))
            .and_then(|x| x["ok"].as_u64())
            .unwrap_or(0) as usize
    };
    let both: usize = cells
        .iter()
        .map(|c| c["c1_and_c2_ok"].as_u64().unwrap_or(0) as usize)
        .sum();
    let total = n * cells.len();
    let data = format!("{seeds} seeds × 2 grades × accel/gyro");
    let command = format!(
        "cargo bench --bench thermal{} -- recovery --seeds {seeds}",
        profile_flag()
    );
    let tempco = results::Row::new(
        "thermal-tempco",
        results::SIM_CALIB_THERMAL,
        9,
        "bias tempco",
        "docs/bench/thermal.md",
    )
    .data(data)
    .ours(format!("c1, c2 within 5 % in {both}/{total}"))
    .target("≥ 90 %")
    .met(both as f64 >= 0.9 * total as f64)
    .command(command);
    // At least 27 of 30: 90 % of the seeds of each grade and sensor.
    let need = (0.9 * n as f64).ceil() as usize;
    let gaps: Vec<usize> = cells.iter().map(|c| term(c, "hysteresis gap")).collect();
    let (lo, hi) = (
        gaps.iter().min().copied().unwrap_or(0),
        gaps.iter().max().copied().unwrap_or(0),
    );
    let gap = results::Row::new(
        "thermal-hysteresis",
        results::SIM_CALIB_THERMAL,
        10,
        "hysteresis gap",
        "docs/bench/thermal.md",
    )
    .data("same")
    .ours(format!(
        "{} of {n} per grade and sensor",
        if lo == hi {
            lo.to_string()
        } else {
            format!("{lo}-{hi}")
        }
    ))
    .target(format!("≥ {need}/{n}"))
    .met(lo >= need)
    .command("same");
    let warm = |sensor: &str| -> Vec<(String, usize)> {
        cells
            .iter()
            .filter(|c| c["sensor"] == sensor)
            .map(|c| {
                (
                    c["grade"].as_str().unwrap_or("").to_string(),
                    term(c, "warm-up τ"),
                )
            })
            .collect()
    };
    let (accel, gyro) = (warm("Accel"), warm("Gyro"));
    let list = |v: &[(String, usize)]| {
        v.iter()
            .map(|(_, k)| format!("{k}/{n}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let worst_false = false_reported.iter().map(|f| f.1).max().unwrap_or(0);
    let mut warmup = results::Row::new(
        "thermal-warmup",
        results::SIM_CALIB_THERMAL,
        11,
        "warm-up τ",
        "docs/bench/thermal.md",
    )
    .data("same")
    .ours(format!(
        "accel {}; gyro {}; reported where none: ≤ {worst_false}/{n}",
        list(&accel),
        list(&gyro)
    ))
    .target(format!("≥ {need}/{n}"))
    .command("same");
    // The first grade is the preset (icm20948-thermal), the second the quiet one.
    let short = |i: usize| if i == 0 { "preset" } else { "quiet" };
    let missed: Vec<(usize, &str, usize)> = [("accel", &accel), ("gyro", &gyro)]
        .into_iter()
        .flat_map(|(s, v)| {
            v.iter()
                .enumerate()
                .filter(|(_, x)| x.1 < need)
                .map(move |(i, x)| (i, s, x.1))
        })
        .collect();
    if missed.is_empty() {
        warmup = warmup.met(true);
    } else {
        warmup = warmup.met_text(format!(
            "{} no (data floor)",
            missed
                .iter()
                .map(|(i, s, _)| format!("{} {s}", short(*i)))
                .collect::<Vec<_>>()
                .join(", ")
        ));
        let (i, sensor, found) = missed[0];
        let key = format!(
            "{} {}",
            cells[i * 2]["grade"].as_str().unwrap_or(""),
            if sensor == "gyro" { "Gyro" } else { "Accel" }
        );
        let cell = cells.iter().find(|c| {
            format!(
                "{} {}",
                c["grade"].as_str().unwrap_or(""),
                c["sensor"].as_str().unwrap_or("")
            ) == key
        });
        let amps: Vec<f64> = limits.iter().filter(|l| l.0 == key).map(|l| l.1).collect();
        let (a_lo, a_hi) = results::min_max(&amps);
        let unit = if sensor == "gyro" { "°/h" } else { "mg" };
        warmup = warmup.not_met(
            format!("Warm-up τ of the {} {sensor} ({found}/{n})", short(i)),
            format!(
                "its {} {unit}, τ {} s transient sits at the 20 min soak's 3σ detection limit ({a_lo:.0}-{a_hi:.0} {unit} where it was missed, drift included), so it is found in {found} of {n} runs",
                cell.map_or(f64::NAN, |c| c["warmup_bias"].as_f64().unwrap_or(f64::NAN)),
                cell.map_or(f64::NAN, |c| c["warmup_truth"].as_f64().unwrap_or(f64::NAN)),
            ),
        );
    }
    results::write(
        "thermal",
        "recovery",
        json!({ "seeds": seeds, "rate_hz": 50.0, "duration_s": 12_000.0 }),
        json!({ "cells": cells, "warmup_not_found_limits": limits.iter().map(|l| json!({"case": l.0, "amplitude": l.1})).collect::<Vec<_>>(),
                "false_warmups": false_reported.iter().map(|f| json!({"case": f.0, "reported": f.1})).collect::<Vec<_>>() }),
        &[tempco, gap, warmup],
    );
}

/// The same runs with the warm-up switched off: how often a transient is reported where none
/// exists (the price of reporting one whose τ the soak bounds only from below).
fn false_warmups(
    seeds: &[u64],
    profile: &TemperatureProfile,
    rate: f64,
    duration: f64,
) -> Vec<(String, usize)> {
    let mut out = Vec::new();
    println!("\n| grade | sensor | runs without a warm-up | reported one |");
    println!("|---|---|---|---|");
    for (grade, mut spec) in [
        ("icm20948-thermal", imu_preset("icm20948-thermal").unwrap()),
        ("quiet", quiet_grade()),
    ] {
        spec.gyro.warmup_bias_dph = [0.0; 3];
        spec.accel.warmup_bias_mg = [0.0; 3];
        for sensor in [SensorKind::Accel, SensorKind::Gyro] {
            let reported = seeds
                .iter()
                .filter(|&&seed| {
                    analyse(
                        simulate(&spec, sensor, seed, rate, duration, profile),
                        sensor,
                        profile,
                    )
                    .warmup
                    .is_some()
                })
                .count();
            println!("| {grade} | {sensor:?} | {} | {reported} |", seeds.len());
            out.push((format!("{grade} {sensor:?}"), reported));
        }
    }
    out
}

/// Accelerometer scale factor against temperature: the chamber program of [`recovery`] with
/// the x axis held up (+1 g) then down (−1 g) for 150 s each at the end of every soak, and a
/// last 25 °C soak; the scale tempco fitted from the poses against the scene's.
fn scale_recovery() {
    // Ends of the soaks of `chamber(1)` (25, 60, −10 °C) and of the soak at 25 °C after it.
    let soak_ends = [1200.0, 4500.0, 9900.0, 13_200.0];
    let force = |t: f64| {
        for end in soak_ends {
            if (end - 300.0..end - 150.0).contains(&t) {
                return Vector3::new(G0, 0.0, 0.0);
            }
            if (end - 150.0..end).contains(&t) {
                return Vector3::new(-G0, 0.0, 0.0);
            }
        }
        Vector3::new(0.0, 0.0, -G0)
    };
    let profile = chamber(1);
    println!("\n| grade | term | truth | median error | median 95 % half-width / truth | seeds ok (5 % or in 95 % CI) | worst |");
    println!("|---|---|---|---|---|---|---|");
    let (mut all_ok, mut all_n, mut grades) = (0, 0, Vec::new());
    for (grade, spec) in [
        ("icm20948-thermal", imu_preset("icm20948-thermal").unwrap()),
        ("quiet", quiet_grade()),
    ] {
        let truth = spec.accel.scale_tempco_ppm_per_c[0];
        let (mut errors, mut sigmas, mut ok) = (Vec::new(), Vec::new(), 0);
        for seed in 1..=10u64 {
            let series = simulate_posed(
                &spec,
                SensorKind::Accel,
                seed,
                50.0,
                13_200.0,
                &profile,
                &force,
            );
            let a = analyse(series, SensorKind::Accel, &profile);
            let Some(c) = a.scale_factor.as_ref().and_then(|s| s.coefficients.get(1)) else {
                errors.push(f64::NAN);
                continue;
            };
            let error = (c.value - truth) / truth;
            if error.abs() <= 0.05 || (c.low..=c.high).contains(&truth) {
                ok += 1;
            }
            errors.push(error);
            sigmas.push((c.high - c.low) / 2.0 / truth);
        }
        let worst = errors
            .iter()
            .copied()
            .max_by(|a, b| a.abs().total_cmp(&b.abs()))
            .unwrap_or(f64::NAN);
        errors.sort_by(f64::total_cmp);
        sigmas.sort_by(f64::total_cmp);
        println!(
            "| {grade} | scale tempco c1 (ppm/°C) | {truth} | {:+.2} % | {:.2} % | {ok}/10 | {:+.2} % |",
            errors[errors.len() / 2] * 100.0,
            sigmas.get(sigmas.len() / 2).copied().unwrap_or(f64::NAN) * 100.0,
            worst * 100.0
        );
        all_ok += ok;
        all_n += 10;
        grades
            .push(json!({ "grade": grade, "truth_ppm_per_c": truth, "ok": ok, "errors": errors }));
    }
    // The chamber-with-poses fixture through the CLI's library path is in the docs; here the
    // simulated seeds.
    let row = results::Row::new(
        "thermal-scale",
        results::SIM_CALIB_THERMAL,
        12,
        "accel scale tempco",
        "docs/bench/thermal.md",
    )
    .data("10 seeds × 2 grades, ±1 g poses")
    .ours(format!("{all_ok}/{all_n} within 5 %"))
    .target("within 5 %")
    .met(all_ok == all_n)
    .command("cargo bench --bench thermal -- scale");
    results::write(
        "thermal",
        "scale",
        json!({ "seeds": 10 }),
        json!({ "grades": grades }),
        &[row],
    );
}

fn timing() {
    // Run time: 24 h at 150 Hz, 6 axes, one axis simulated and analysed at a time.
    let profile = chamber(3);
    let spec = imu_preset("icm20948-thermal").unwrap();
    let mut total = 0.0;
    let mut axes = Vec::new();
    for (i, sensor) in [
        SensorKind::Gyro,
        SensorKind::Gyro,
        SensorKind::Gyro,
        SensorKind::Accel,
        SensorKind::Accel,
        SensorKind::Accel,
    ]
    .into_iter()
    .enumerate()
    {
        let series = simulate(&spec, sensor, 100 + i as u64, 150.0, 86_400.0, &profile);
        let start = Instant::now();
        let a = analyse(series, sensor, &profile);
        let secs = start.elapsed().as_secs_f64();
        total += secs;
        axes.push(secs);
        assert!(a.fit.order >= 1);
    }
    println!("\nwhole thermal analysis of 24 h x 150 Hz x 6 axes (12.96 M samples per axis, in memory; session reading not included): {total:.2} s (target < 2 s)");
    let load = results::load_average();
    let row = results::Row::new(
        "thermal-time",
        results::SIM_CALIB_THERMAL,
        13,
        "thermal run time",
        "docs/bench/thermal.md",
    )
    .data("24 h × 150 Hz × 6 axes, release")
    .ours(format!("{total:.2} s (load {load:.1})"))
    .target("< 2 s, one axis")
    .met(total < 2.0)
    .timed()
    .command("cargo bench --bench thermal -- timing");
    results::write(
        "thermal",
        "timing",
        json!({ "hours": 24, "rate_hz": 150, "axes": 6 }),
        json!({ "axes_s": axes, "total_s": total }),
        &[row],
    );
}

/// `thermal_drive.toml` replayed with 30 s outages every 120 s, without and with the model
/// `imulab thermal --model` fits on the static chamber run of the same IMU.
fn cli_replay() {
    let tmp = std::env::temp_dir().join(format!("imulab-thermal-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).expect("temporary directory");
    let p = |name: &str| tmp.join(name).display().to_string();
    imulab(&["sim", "fixtures/scenes/thermal_drive.toml", "-o", &p("S")]);
    let raw = replay_drifts(&p("S"), "every:120:30", &tmp.join("R0"), &[]);
    imulab(&[
        "sim",
        "fixtures/scenes/thermal_drive_chamber.toml",
        "-o",
        &p("C"),
    ]);
    imulab(&["thermal", &p("C"), "--model", &p("fitted.json")]);
    let model = p("fitted.json");
    let comp = replay_drifts(
        &p("S"),
        "every:120:30",
        &tmp.join("R1"),
        &["--compensate", &model],
    );
    let _ = std::fs::remove_dir_all(&tmp);
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    println!("replay drift mean {:.2} → {:.2} m", mean(&raw), mean(&comp));
    let row = results::Row::new(
        "thermal-replay",
        results::SIM_CALIB_THERMAL,
        14,
        "replay drift, `--compensate`",
        "docs/bench/thermal.md",
    )
    .data(format!(
        "`thermal_drive.toml`, {} × 30 s outages",
        raw.len()
    ))
    .ours(format!("mean {:.2} → {:.2} m", mean(&raw), mean(&comp)))
    .ratio(format!("{:.1}× smaller", mean(&raw) / mean(&comp)))
    .target("smaller")
    .met(mean(&comp) < mean(&raw))
    .command("cargo bench --bench thermal -- cli");
    results::write(
        "thermal",
        "cli",
        json!({ "drive": "fixtures/scenes/thermal_drive.toml", "chamber": "fixtures/scenes/thermal_drive_chamber.toml", "outages": "every:120:30", "model": "fitted by imulab thermal --model" }),
        json!({ "drift_uncompensated_m": raw, "drift_compensated_m": comp }),
        &[row],
    );
}
