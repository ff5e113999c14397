//! `imulab replay`: GNSS/INS replay of recorded or simulated data through the error-state
//! filter. This version reads the KF-GINS text formats (`--kf-gins CONFIG.yaml`); writes the
//! trajectory as CSV, GeoJSON and KF-GINS navresult, and, with a truth `.nav` file, the
//! errors (RMS / p95 / max, per-outage drift, NEES).

use crate::fusion::export;
use crate::fusion::kfgins::{self, KfGinsConfig};
use crate::fusion::mechanisation::NavState;
use crate::fusion::metrics::{errors, summarise};
use anyhow::{bail, Context};
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
#[command(
    after_help = "Example: imulab replay --kf-gins dataset/kf-gins.yaml --truth dataset/truth.nav --outages every:300:60 --out results/"
)]
pub struct ReplayArgs {
    /// KF-GINS configuration file (paths inside resolve against the current directory).
    #[arg(long, value_name = "CONFIG.yaml")]
    pub kf_gins: PathBuf,
    /// Output directory (default: the configuration's `outputpath`).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Truth trajectory in KF-GINS .nav format, for error statistics.
    #[arg(long, value_name = "FILE.nav")]
    pub truth: Option<PathBuf>,
    /// Withhold GNSS from START for DUR seconds (relative to the start time); repeatable.
    #[arg(long = "outage", value_name = "START:DUR")]
    pub outage: Vec<String>,
    /// Withhold GNSS for DUR seconds every PERIOD seconds (first outage at PERIOD).
    #[arg(long, value_name = "every:PERIOD:DUR")]
    pub outages: Option<String>,
    /// Also run the RTS smoother and write the smoothed trajectory.
    #[arg(long)]
    pub smooth: bool,
}

fn parse_pair(text: &str, what: &str) -> anyhow::Result<(f64, f64)> {
    let (a, b) = text
        .split_once(':')
        .with_context(|| format!("{what} `{text}`: expected two numbers separated by `:`"))?;
    let num = |s: &str| {
        s.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v >= 0.0)
            .with_context(|| format!("{what} `{text}`: `{s}` is not a non-negative number"))
    };
    Ok((num(a)?, num(b)?))
}

/// Outage windows relative to the start, from `--outage` and `--outages`, up to `span_s`.
pub fn parse_outages(
    single: &[String],
    periodic: Option<&str>,
    span_s: f64,
) -> anyhow::Result<Vec<(f64, f64)>> {
    let mut out = Vec::new();
    for s in single {
        let (start, dur) = parse_pair(s, "--outage")?;
        out.push((start, start + dur));
    }
    if let Some(p) = periodic {
        let Some(rest) = p.strip_prefix("every:") else {
            bail!("--outages `{p}`: expected every:PERIOD:DUR");
        };
        let (period, dur) = parse_pair(rest, "--outages")?;
        if period <= 0.0 || dur >= period {
            bail!("--outages `{p}`: need 0 < DUR < PERIOD");
        }
        let mut start = period;
        while start < span_s {
            out.push((start, start + dur));
            start += period;
        }
    }
    Ok(out)
}

pub fn run(args: ReplayArgs) -> anyhow::Result<()> {
    let base = std::env::current_dir().context("current directory")?;
    let config = KfGinsConfig::from_file(&args.kf_gins, &base)?;
    if config.initial_bias_std.is_some() {
        tracing::warn!("initbgstd/initbastd/initsgstd/initsastd are not applied: initial sensor-error σ = imunoise σ");
    }
    let end = config.end_s.unwrap_or(f64::INFINITY);
    let span = if end.is_finite() {
        end - config.start_s
    } else {
        7.0 * 86400.0
    };
    let outages: Vec<(f64, f64)> = parse_outages(&args.outage, args.outages.as_deref(), span)?
        .into_iter()
        .map(|(a, b)| (a + config.start_s, b + config.start_s))
        .collect();
    let result = kfgins::replay_files(&config, &outages, args.smooth)?;
    // Periodic outages run to the end of the week when the end time is open; keep those
    // that start within the data for the report.
    let last_t = result
        .filtered
        .last()
        .map_or(f64::NEG_INFINITY, |s| s.nav.t_s);
    let outages: Vec<(f64, f64)> = outages.into_iter().filter(|o| o.0 <= last_t).collect();
    let out_dir = args
        .out
        .clone()
        .unwrap_or_else(|| config.output_path.clone());
    std::fs::create_dir_all(&out_dir).with_context(|| format!("{}", out_dir.display()))?;

    let truth = match &args.truth {
        Some(p) => Some(kfgins::read_nav(p)?),
        None => None,
    };
    let week = truth.as_ref().and_then(|t| t.first()).map_or(0, |r| r.week);
    let mut sets = vec![("filtered", &result.filtered)];
    if args.smooth {
        sets.push(("smoothed", &result.smoothed));
    }
    let mut report = serde_json::Map::new();
    for (name, sol) in sets {
        kfgins::write_navresult(&out_dir.join(format!("{name}_navresult.nav")), week, sol)?;
        export::write_csv(&out_dir.join(format!("{name}_trajectory.csv")), sol)?;
        export::write_geojson(&out_dir.join(format!("{name}_trajectory.geojson")), sol)?;
        if let Some(truth) = &truth {
            let lookup = |t: f64| -> Option<NavState> {
                let i = truth.partition_point(|r| r.nav.t_s < t - 1e-4);
                truth
                    .get(i)
                    .filter(|r| (r.nav.t_s - t).abs() < 1e-4)
                    .map(|r| r.nav)
            };
            let e = errors(sol, lookup);
            let s = summarise(&e, &outages);
            println!(
                "{name}: {} epochs vs truth: horizontal RMS {:.3} m, p95 {:.3} m, max {:.3} m; vertical RMS {:.3} m; NEES {:.2}; inside 3σ {:.1} %",
                s.epochs, s.horizontal.rms, s.horizontal.p95, s.horizontal.max, s.vertical.rms,
                s.nees_mean, 100.0 * s.inside_3sigma
            );
            for o in &s.outages {
                println!(
                    "  outage at +{:.0} s for {:.0} s: max horizontal drift {:.3} m",
                    o.start_s - config.start_s,
                    o.duration_s,
                    o.max_horizontal_m
                );
            }
            report.insert(name.to_string(), export::summary_json(&s));
        }
    }
    let st = &result.stats;
    println!(
        "IMU samples {} (rejected {}), GNSS used {} (withheld {}, rejected {}), filter PD events {}",
        st.imu_samples,
        st.imu_rejected_non_finite + st.imu_rejected_time,
        st.gnss_used,
        st.gnss_withheld_outage,
        st.gnss_rejected_invalid + st.gnss_rejected_duplicate + st.gnss_rejected_out_of_order,
        st.filter.pd_events
    );
    if !report.is_empty() {
        let p = out_dir.join("errors.json");
        std::fs::write(&p, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("{}", p.display()))?;
    }
    println!("wrote {}", out_dir.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outage_arguments_parse_and_reject_nonsense() {
        let o = parse_outages(&["10:5".into()], Some("every:100:30"), 350.0).expect("valid");
        assert_eq!(
            o,
            vec![(10.0, 15.0), (100.0, 130.0), (200.0, 230.0), (300.0, 330.0)]
        );
        assert!(parse_outages(&["10".into()], None, 1.0).is_err());
        assert!(parse_outages(&["a:5".into()], None, 1.0).is_err());
        assert!(parse_outages(&[], Some("every:10:20"), 100.0).is_err());
        assert!(parse_outages(&[], Some("often:10:2"), 100.0).is_err());
    }
}
