//! The JSON a benchmark writes to `benches/results/<bench>-<mode>.json`: what it ran on, its
//! raw figures and the BENCHMARKS.md rows it owns, "met" decided from its figure and target.
//! BENCHMARKS.md is generated from these files: `cargo run --example benchmarks_md`.
//! Shared by the benches, tests and examples that produce rows (`#[path]` includes).
#![allow(dead_code)]

use serde_json::{json, Value};
use std::path::{Path, PathBuf};

/// A section of BENCHMARKS.md: its title, its place, and the peer column's heading.
#[derive(Clone, Copy)]
pub struct Section {
    pub title: &'static str,
    pub order: u32,
    pub peer: &'static str,
}

pub const ACQUISITION: Section = Section {
    title: "Acquisition and storage",
    order: 1,
    peer: "peer",
};
pub const SIM_CALIB_THERMAL: Section = Section {
    title: "Simulator, calibration, thermal",
    order: 2,
    peer: "peer",
};
pub const ALLAN: Section = Section {
    title: "Allan analysis (3.24 M samples, one axis)",
    order: 3,
    peer: "allantools",
};
pub const FUSION: Section = Section {
    title: "Fusion and study",
    order: 4,
    peer: "peer",
};

/// One row of BENCHMARKS.md.
pub struct Row {
    id: &'static str,
    section: Section,
    order: u32,
    measured: String,
    doc: String,
    data: String,
    ours: String,
    peer: String,
    ratio: String,
    target: String,
    met: String,
    command: String,
    not_met: Option<(String, String)>,
    timed: bool,
}

impl Row {
    /// Row `id` at `order` in `section`, `measured` linked to `doc` (a path from the
    /// workspace root); peer, ratio, target and met are "—" until set.
    pub fn new(id: &'static str, section: Section, order: u32, measured: &str, doc: &str) -> Self {
        let dash = || "—".to_string();
        Self {
            id,
            section,
            order,
            measured: measured.into(),
            doc: doc.into(),
            data: dash(),
            ours: dash(),
            peer: dash(),
            ratio: dash(),
            target: dash(),
            met: dash(),
            command: dash(),
            not_met: None,
            timed: false,
        }
    }
    pub fn data(mut self, v: impl Into<String>) -> Self {
        self.data = v.into();
        self
    }
    pub fn ours(mut self, v: impl Into<String>) -> Self {
        self.ours = v.into();
        self
    }
    pub fn peer(mut self, v: impl Into<String>) -> Self {
        self.peer = v.into();
        self
    }
    pub fn ratio(mut self, v: impl Into<String>) -> Self {
        self.ratio = v.into();
        self
    }
    pub fn target(mut self, v: impl Into<String>) -> Self {
        self.target = v.into();
        self
    }
    /// "yes" or "no".
    pub fn met(mut self, ok: bool) -> Self {
        self.met = if ok { "yes" } else { "no" }.into();
        self
    }
    /// A qualified verdict (e.g. "no (VM floor)").
    pub fn met_text(mut self, v: impl Into<String>) -> Self {
        self.met = v.into();
        self
    }
    /// The command that produces this row's JSON (`…` abbreviates the one of the row above).
    pub fn command(mut self, v: impl Into<String>) -> Self {
        self.command = v.into();
        self
    }
    /// A timing: when missed at a load of 1 or more, the reason given is the load.
    pub fn timed(mut self) -> Self {
        self.timed = true;
        self
    }
    /// An entry of "Targets not met, and why": the target in a few words and the reason.
    pub fn not_met(mut self, what: impl Into<String>, why: impl Into<String>) -> Self {
        self.not_met = Some((what.into(), why.into()));
        self
    }
    pub fn to_json(&self) -> Value {
        let mut v = json!({
            "id": self.id,
            "section": self.section.title,
            "section_order": self.section.order,
            "peer_column": self.section.peer,
            "order": self.order,
            "measured": self.measured,
            "doc": self.doc,
            "data": self.data,
            "ours": self.ours,
            "peer": self.peer,
            "ratio": self.ratio,
            "target": self.target,
            "met": self.met,
            "command": self.command,
        });
        if let Some((what, why)) = &self.not_met {
            v["not_met"] = json!({ "what": what, "why": why });
        }
        v
    }
}

/// The workspace root (where Cargo.lock is), from this crate's manifest directory.
pub fn workspace_root() -> PathBuf {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    manifest
        .ancestors()
        .find(|d| d.join("Cargo.lock").exists())
        .unwrap_or(manifest)
        .to_path_buf()
}

/// Where results go: `IMULAB_BENCH_RESULTS` when set, else `benches/results`.
pub fn results_dir() -> PathBuf {
    std::env::var_os("IMULAB_BENCH_RESULTS")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace_root().join("benches/results"))
}

/// Whether `IMULAB_BENCH_RESULTS` names a results directory: tests write their figures only
/// then (e.g. `IMULAB_BENCH_RESULTS=benches/results cargo test --test allan stable32`).
pub fn requested() -> bool {
    std::env::var_os("IMULAB_BENCH_RESULTS").is_some()
}

/// The 1-minute load average (a figure measured at load ≥ 1 on 2 cores was disturbed).
pub fn load_average() -> f64 {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or(f64::NAN)
}

/// Writes `<results_dir>/<bench>-<mode>.json` and says so on stdout.
pub fn write(bench: &str, mode: &str, args: Value, figures: Value, rows: &[Row]) {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let load = load_average();
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let rows: Vec<Value> = rows
        .iter()
        .map(|r| {
            let mut v = r.to_json();
            // A timing missed while other jobs shared the cores says so.
            if r.timed && r.met == "no" && r.not_met.is_none() && load >= 1.0 {
                v["not_met"] = json!({
                    "what": format!("{} {}", r.measured, r.target),
                    "why": format!("measured at load {load:.1} on {cores} cores; `benches/record_all` reruns it on an idle machine"),
                });
            }
            v
        })
        .collect();
    let doc = json!({
        "bench": bench,
        "mode": mode,
        "args": args,
        "recorded_unix_s": now,
        "load_1min_at_end": load,
        "cores": cores,
        "figures": figures,
        "rows": rows,
    });
    let dir = results_dir();
    std::fs::create_dir_all(&dir).expect("create the results directory");
    let path = dir.join(format!("{bench}-{mode}.json"));
    let text = serde_json::to_string_pretty(&doc).expect("results as JSON") + "\n";
    std::fs::write(&path, text).unwrap_or_else(|e| panic!("writing {}: {e}", path.display()));
    println!("wrote {}", path.display());
}

/// `a-b` with `digits` decimals, or `a` when both round alike.
pub fn range(lo: f64, hi: f64, digits: usize) -> String {
    let (a, b) = (format!("{lo:.digits$}"), format!("{hi:.digits$}"));
    if a == b {
        a
    } else {
        format!("{a}-{b}")
    }
}

/// Minimum and maximum of `values`.
pub fn min_max(values: &[f64]) -> (f64, f64) {
    values
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        })
}
