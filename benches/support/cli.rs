//! The release CLI as the benchmarks that time or check whole commands run it (`#[path]`
//! include, like `results.rs`).
#![allow(dead_code)]

use std::path::Path;
use std::time::Instant;

/// `--profile dev` when this is a dev build (the command that reproduces the figures).
pub fn profile_flag() -> &'static str {
    if cfg!(debug_assertions) {
        " --profile dev"
    } else {
        ""
    }
}

/// Runs the `imulab` binary of this build from the workspace root; wall time and stdout.
pub fn imulab(args: &[&str]) -> (f64, String) {
    let start = Instant::now();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_imulab"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(args)
        .output()
        .expect("run imulab");
    let wall = start.elapsed().as_secs_f64();
    assert!(
        out.status.success(),
        "imulab {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    (wall, String::from_utf8_lossy(&out.stdout).into())
}

/// Per-outage maximum horizontal drift of a replay's `errors.json` (filtered solution).
pub fn outage_drifts(out_dir: &Path) -> Vec<f64> {
    let text = std::fs::read_to_string(out_dir.join("errors.json")).expect("errors.json");
    let v: serde_json::Value = serde_json::from_str(&text).expect("errors.json");
    v["filtered"]["outages"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|o| o["max_horizontal_m"].as_f64())
        .collect()
}

/// Replays session `session` with GNSS withheld by `outages` into `out`, with `extra`
/// arguments (a calibration, a compensation model), and returns its per-outage drifts.
pub fn replay_drifts(session: &str, outages: &str, out: &Path, extra: &[&str]) -> Vec<f64> {
    let out_arg = out.display().to_string();
    let mut args = vec!["replay", session, "--outages", outages, "--out", &out_arg];
    args.extend_from_slice(extra);
    imulab(&args);
    outage_drifts(out)
}
