//! Term recovery: simulate one axis of an IMU preset (no wire, no daemon), compute its
//! overlapping Allan deviation on the octave grid the reports use, fit the noise model, and
//! compare the fitted terms, their 95 % intervals and the slope-line readings with what the
//! preset says, and the measured curve with the analytic curve the simulator implies.
//!
//! ```text
//! cargo run --release --example term_recovery -- --preset bench-cheap --sensor gyro --axis 0 \
//!     --hours 0.5,2,6 --seeds 8 [--rrw X] [--lsb X] [--tempco X --ramp-c X] [--curve]
//! ```
//!
//! `--rrw` adds a rate random walk (°/h/√h or mg/√h), `--lsb` rounds the output to an LSB
//! (°/s or mg), `--tempco` a bias temperature coefficient (°/h/°C or mg/°C) with the chamber
//! drifting linearly by `--ramp-c` °C over the run (0: held at the reference temperature).
//! Figures in docs/bench/allan.md ("term recovery") come from this program. A run without
//! `--rrw`, `--lsb` and `--tempco` writes its summary and BENCHMARKS.md row to
//! `benches/results/term_recovery-seeds.json`.

#[path = "../benches/support/results.rs"]
mod results;

use clap::Parser;
use imulab::allan::fit::{fit_noise_terms, slope_readings, Term, BIAS_INSTABILITY_FACTOR};
use imulab::allan::{compute_curve, DeviationKind, Phase, TauGrid};
use imulab::sim::flicker::FlickerDesign;
use imulab::sim::imu_model::{Channels, ImuSimulator, ImuSpec, TriadErrors};
use imulab::sim::presets::imu_preset;
use imulab::sim::temperature::TemperatureProfile;
use nalgebra::Vector3;

#[derive(Parser, Debug)]
struct Args {
    /// IMU preset name.
    #[arg(long, default_value = "bench-cheap")]
    preset: String,
    /// gyro or accel.
    #[arg(long, default_value = "gyro")]
    sensor: String,
    /// Axis 0, 1 or 2.
    #[arg(long, default_value_t = 0)]
    axis: usize,
    /// Run lengths, hours.
    #[arg(long, value_delimiter = ',', default_value = "0.5,2,6")]
    hours: Vec<f64>,
    /// Seeds 1..=N.
    #[arg(long, default_value_t = 8)]
    seeds: u64,
    /// Sample rate, Hz.
    #[arg(long, default_value_t = 150.0)]
    rate: f64,
    /// Add a rate random walk (°/h/√h or mg/√h).
    #[arg(long)]
    rrw: Option<f64>,
    /// Round the output to this LSB (°/s or mg).
    #[arg(long)]
    lsb: Option<f64>,
    /// Add a bias temperature coefficient (°/h/°C or mg/°C).
    #[arg(long)]
    tempco: Option<f64>,
    /// Temperature change over the run, °C (linear), with --tempco.
    #[arg(long, default_value_t = 0.0)]
    ramp_c: f64,
    /// Print the measured/analytic ratio per τ for the first seed.
    #[arg(long)]
    curve: bool,
}

fn main() -> Result<(), String> {
    let args = Args::parse();
    let mut spec = imu_preset(&args.preset).ok_or(format!("no preset {}", args.preset))?;
    let gyro = match args.sensor.as_str() {
        "gyro" => true,
        "accel" => false,
        other => return Err(format!("--sensor gyro|accel, got {other}")),
    };
    if args.axis > 2 {
        return Err(format!("--axis 0..=2, got {}", args.axis));
    }
    let i = args.axis;
    // The spec value in datasheet units, and the factor from SI to those units.
    let (preset_b, si_to_unit) = if gyro {
        (spec.gyro.bias_instability_dph[i], 3600.0f64.to_degrees())
    } else {
        (spec.accel.bias_instability_mg[i], 1e3 / 9.806_65)
    };
    if let Some(k) = args.rrw {
        if gyro {
            spec.gyro.rrw_dph_rth[i] = k;
        } else {
            spec.accel.rrw_mg_rth[i] = k;
        }
    }
    if let Some(l) = args.lsb {
        if gyro {
            spec.gyro.lsb_dps = Some(l);
        } else {
            spec.accel.lsb_mg = Some(l);
        }
    }
    if let Some(c) = args.tempco {
        if gyro {
            spec.gyro.bias_tempco_dph_per_c[i] = c;
        } else {
            spec.accel.bias_tempco_mg_per_c[i] = c;
        }
    }
    let si: TriadErrors = if gyro {
        spec.gyro.to_si()?
    } else {
        spec.accel.to_si()?
    };
    let design = FlickerDesign::new(si.instability_floor[i], si.bias_instability_band_s);
    let tau0 = 1.0 / args.rate;
    // Rounding to the LSB adds white noise of variance LSB²/12 per sample.
    let white2 = si.white_density[i].powi(2) + si.lsb.powi(2) / 12.0 * tau0;
    let analytic = |tau: f64| {
        (white2 / tau + design.adev(tau).powi(2) + si.random_walk[i].powi(2) * tau / 3.0).sqrt()
    };
    println!(
        "preset {} {} axis {i}: spec bias instability {preset_b} ({}), simulated floor {:.4} \
         = {:.3}×spec, band {:?} s; white {:.4e}, rrw {:.4e} (SI)",
        args.preset,
        args.sensor,
        if gyro { "°/h" } else { "mg" },
        si.instability_floor[i] * si_to_unit,
        si.instability_floor[i] * si_to_unit / preset_b,
        si.bias_instability_band_s,
        si.white_density[i],
        si.random_walk[i],
    );
    println!("hours seed | fit B [95 %] id | B/spec | spec in? | slope B (τmin) /spec | fit N/spec | K [95 %] | χ²r");
    let mut summaries = Vec::new();
    for &hours in &args.hours {
        let n = (hours * 3600.0 * args.rate).round() as usize;
        let mut ratios = Vec::new();
        let mut slope_ratios = Vec::new();
        let mut covered = 0;
        let mut identified = 0;
        let mut widths = Vec::new();
        for seed in 1..=args.seeds {
            let y = simulate(&spec, gyro, i, args.rate, n, seed, args.ramp_c)?;
            let curve = compute_curve(
                &Phase::from_rate(y),
                tau0,
                DeviationKind::Oadev,
                &TauGrid::Octave,
            );
            if args.curve && seed == 1 {
                for p in &curve.points {
                    let a = analytic(p.tau);
                    println!(
                        "   τ {:>9.2} s  meas {:.4e}  analytic {:.4e}  ratio {:.3} [{:.3}, {:.3}] α {}",
                        p.tau,
                        p.deviation,
                        a,
                        p.deviation / a,
                        p.low.unwrap_or(f64::NAN) / a,
                        p.high.unwrap_or(f64::NAN) / a,
                        p.alpha
                    );
                }
            }
            let fit = fit_noise_terms(&curve).map_err(|e| e.to_string())?;
            let slopes = slope_readings(&curve);
            let b = fit.get(Term::BiasInstability).ok_or("no B")?;
            let nn = fit.get(Term::RandomWalk).ok_or("no N")?;
            let k = fit.get(Term::RateRandomWalk).ok_or("no K")?;
            let u = |v: f64| v * si_to_unit;
            let inside = b.low * si_to_unit <= preset_b && preset_b <= b.high * si_to_unit;
            if b.value.is_some() {
                identified += 1;
                widths.push(b.high / b.low);
            }
            if inside && b.value.is_some() {
                covered += 1;
            }
            let value = b.value.map_or(f64::NAN, u);
            ratios.push(value / preset_b);
            let slope_b = slopes.bias_instability.map_or(f64::NAN, u);
            slope_ratios.push(slope_b / preset_b);
            println!(
                "{hours:>5} {seed:>4} | {value:.4} [{:.4}, {:.4}] {} | {:.3} | {} | {slope_b:.4} ({:.0} s) {:.3} | {:.3} | {} [{:.3e}, {:.3e}] | {:.2}",
                u(b.low),
                u(b.high),
                if b.value.is_some() { "id" } else { "n.i." },
                value / preset_b,
                if inside { "yes" } else { "NO" },
                slopes.bias_instability_tau.unwrap_or(f64::NAN),
                slope_b / preset_b,
                nn.value.unwrap_or(f64::NAN) / si.white_density[i].max(f64::MIN_POSITIVE),
                if k.value.is_some() { "K id" } else { "K n.i." },
                k.low,
                k.high,
                fit.reduced_chi_squared,
            );
        }
        let mean = |v: &[f64]| {
            v.iter().filter(|x| x.is_finite()).sum::<f64>()
                / v.iter().filter(|x| x.is_finite()).count().max(1) as f64
        };
        println!(
            "{hours:>5} h summary: fit B/spec mean {:.3} (identified {identified}/{}), spec inside 95 % {covered}/{}, \
             interval high/low median {:.2}, slope-line B/spec mean {:.3}; 1/0.664 = {:.3}",
            mean(&ratios),
            args.seeds,
            args.seeds,
            median(&mut widths),
            mean(&slope_ratios),
            1.0 / BIAS_INSTABILITY_FACTOR
        );
        summaries.push(serde_json::json!({
            "hours": hours, "fit_b_over_spec_mean": mean(&ratios), "identified": identified,
            "spec_inside_95": covered, "seeds": args.seeds, "interval_high_over_low_median": median(&mut widths),
            "slope_b_over_spec_mean": mean(&slope_ratios),
        }));
    }
    if args.rrw.is_none() && args.lsb.is_none() && args.tempco.is_none() {
        write_results(&args, &summaries);
    }
    Ok(())
}

/// The row: fitted/true B over the run lengths, and the truth inside the fit's 95 % interval
/// in at least 90 % of the seeds of every length.
fn write_results(args: &Args, summaries: &[serde_json::Value]) {
    let f = |s: &serde_json::Value, k: &str| s[k].as_f64().unwrap_or(f64::NAN);
    let ratios: Vec<f64> = summaries
        .iter()
        .map(|s| f(s, "fit_b_over_spec_mean"))
        .collect();
    let (lo, hi) = results::min_max(&ratios);
    let covered = summaries
        .iter()
        .all(|s| f(s, "spec_inside_95") >= 0.9 * args.seeds as f64);
    let hours: Vec<String> = args.hours.iter().map(|h| h.to_string()).collect();
    let (h_lo, h_hi) = results::min_max(&args.hours);
    let row = results::Row::new(
        "allan-term-recovery",
        results::ALLAN,
        7,
        "bias instability read back",
        "docs/bench/allan.md",
    )
    .data(format!(
        "{} {}, {} seeds, {}-{} h",
        args.preset, args.sensor, args.seeds, h_lo, h_hi
    ))
    .ours(format!("fitted/true {}", results::range(lo, hi, 2)))
    .target("in 95 % CI")
    .met(covered)
    .command(format!(
        "cargo run{} --example term_recovery -- --preset {} --sensor {} --axis {} --hours {} --seeds {}",
        if cfg!(debug_assertions) { "" } else { " --release" },
        args.preset,
        args.sensor,
        args.axis,
        hours.join(","),
        args.seeds
    ));
    results::write(
        "term_recovery",
        "seeds",
        serde_json::json!({
            "preset": args.preset, "sensor": args.sensor, "axis": args.axis, "hours": args.hours,
            "seeds": args.seeds, "rate_hz": args.rate,
        }),
        serde_json::json!({ "per_length": summaries }),
        &[row],
    );
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn simulate(
    spec: &ImuSpec,
    gyro: bool,
    axis: usize,
    rate: f64,
    n: usize,
    seed: u64,
    ramp_c: f64,
) -> Result<Vec<f64>, String> {
    let mut on = [false; 3];
    on[axis] = true;
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
    let mut sim = ImuSimulator::new(spec, "dut", seed, rate, channels)?;
    let t_end = n as f64 / rate;
    let profile = TemperatureProfile::Ramp {
        start_c: spec.reference_temp_c,
        end_c: spec.reference_temp_c + ramp_c,
        start_s: 0.0,
        end_s: t_end.max(1.0),
    };
    let zero = Vector3::zeros();
    let mut out = Vec::with_capacity(n + 1);
    for k in 0..n {
        let temp = profile.at(k as f64 / rate);
        let r = sim
            .step(&zero, &zero, temp, 0, 0)
            .record
            .ok_or("dropped sample")?;
        out.push(if gyro { r.gyro[axis] } else { r.accel[axis] });
    }
    Ok(out)
}
