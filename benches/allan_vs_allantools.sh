#!/usr/bin/env bash
# Times Python allantools on the same data as `cargo bench --bench allan`
# (target/allan-bench/data.npy: 6 h x 150 Hz x 6 axes) for the deviation types the
# issue names, one axis and six axes, and checks that both tools agree on OADEV.
# The venv is cached under target/allantools-venv.
# Usage: benches/allan_vs_allantools.sh [process]   (run `cargo bench --bench allan` first)
#
# `process` times whole processes instead, with hyperfine: `imulab allan x.npy --rate 150
# --kind KIND --taus octave --json o.json` (release build) against a Python process that
# loads the same one-column x.npy, runs allantools on the same taus and writes its results
# as JSON, and against benches/allan_process_floor.c, alternating them in one run.
# Each mode writes its figures and BENCHMARKS.md rows to benches/results/
# allan_vs_allantools-{kernel,process}.json, with ours read from benches/results/allan-speed.json.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
results="${IMULAB_BENCH_RESULTS:-$root/benches/results}"
ours="$results/allan-speed.json"
venv="$root/target/allantools-venv"
data="$root/target/allan-bench/data.npy"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet numpy allantools
fi
if [ ! -f "$ours" ]; then
    echo "missing $ours: run 'cargo bench --bench allan' first" >&2
    exit 1
fi
if [ "${1:-}" = process ]; then
    bin="${CARGO_TARGET_DIR:-$root/target}/release/imulab"
    if [ ! -x "$bin" ]; then
        echo "missing $bin: run 'cargo build --release --bin imulab' first" >&2
        exit 1
    fi
    command -v hyperfine >/dev/null || { echo "hyperfine is needed (apt-get install hyperfine)" >&2; exit 1; }
    work="$(mktemp -d)"
    trap 'rm -rf "$work"' EXIT
    # Axis 0 of the bench's data when it exists, else the same model (white N = 2e-3 plus
    # random walk K = 5e-5, 6 h at 150 Hz) simulated here.
    "$venv/bin/python" - "$data" "$work/x.npy" <<'PY'
import os, sys
import numpy as np
if os.path.exists(sys.argv[1]):
    y = np.ascontiguousarray(np.load(sys.argv[1])[:, 0])
else:
    rate, n = 150.0, 3_240_000
    g = np.random.default_rng(1)
    y = 2e-3 * np.sqrt(rate) * g.standard_normal(n) + np.cumsum(5e-5 / np.sqrt(rate) * g.standard_normal(n))
np.save(sys.argv[2], y)
PY
    cat >"$work/peer.py" <<'PY'
import json, sys
import numpy as np
import allantools
kind, path, out = sys.argv[1], sys.argv[2], sys.argv[3]
y = np.load(path)
rate, n = 150.0, y.shape[0]
stop = {"oadev": 4, "mdev": 4, "hdev": 5, "totdev": 2}[kind]
m, taus = 1, []
while m <= (n + 1) // stop:
    taus.append(m / rate)
    m *= 2
t, dev, err, ns = getattr(allantools, kind)(y, rate=rate, data_type="freq", taus=np.array(taus))
json.dump({"tau": list(t), "deviation": list(dev), "error": list(err), "count": [int(c) for c in ns]}, open(out, "w"))
PY
    echo "# $(date -u +%H:%M:%S) load $(cut -d' ' -f1-3 /proc/loadavg); $("$bin" --version); allantools $("$venv/bin/python" -c 'import allantools; print(allantools.__version__)')"
    gcc -O2 -o "$work/floor" "$root/benches/allan_process_floor.c"
    echo "| deviation | ours mean [ms] | ours min [ms] | allantools mean [ms] | allantools min [ms] | ratio of means | floor mean [ms] | floor min [ms] |"
    echo "|---|---|---|---|---|---|---|---|"
    for kind in oadev mdev hdev totdev; do
        hyperfine --style none --warmup 3 --runs "${RUNS:-20}" -N --export-json "$work/$kind.json" \
            "$bin allan $work/x.npy --rate 150 --kind $kind --taus octave --json $work/o.json" \
            "$venv/bin/python $work/peer.py $kind $work/x.npy $work/p.json" \
            "$work/floor $work/x.npy $work/floor.txt" >/dev/null
        "$venv/bin/python" - "$work/$kind.json" "$kind" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))["results"]
ours, peer, floor = r[0], r[1], r[2]
ms = lambda v: f"{1e3 * v:.1f}"
print(f"| {sys.argv[2]} | {ms(ours['mean'])} | {ms(ours['min'])} | {ms(peer['mean'])} | {ms(peer['min'])} | {peer['mean'] / ours['mean']:.0f}× | {ms(floor['mean'])} | {ms(floor['min'])} |")
PY
    done
    "$venv/bin/python" - "$work" "$ours" "$results" "${RUNS:-20}" "$("$bin" --version)" <<'PY'
import json, os, sys, time
import allantools
work, ours_path, results, runs, version = sys.argv[1:6]
ours = json.load(open(ours_path))["figures"]
kinds = ["oadev", "mdev", "hdev", "totdev"]
stats = {}
for k in kinds:
    r = json.load(open(f"{work}/{k}.json"))["results"]
    pick = lambda x: {"mean_s": x["mean"], "min_s": x["min"], "max_s": x["max"], "times_s": x["times"]}
    stats[k] = {"imulab": pick(r[0]), "allantools": pick(r[1]), "floor": pick(r[2])}
load = float(open("/proc/loadavg").read().split()[0])
ratios = [stats[k]["allantools"]["mean_s"] / stats[k]["imulab"]["mean_s"] for k in kinds]
o = stats["oadev"]
ratio_ok, ms_ok = min(ratios) >= 30, o["imulab"]["min_s"] <= 0.020
kernel = next(c for c in ours["kinds"] if c["kind"] == "oadev" and c["grid"] == "octave")
ms = lambda v: f"{1e3 * v:.0f}"
row = {
    "id": "allan-process", "section": "Allan analysis (3.24 M samples, one axis)",
    "section_order": 3, "peer_column": "allantools", "order": 3,
    "measured": "whole process", "doc": "docs/bench/allan.md",
    "data": f"`imulab allan x.npy … --json`, load {load:.1f}",
    "ours": f"OADEV {ms(o['imulab']['mean_s'])} ms, min {ms(o['imulab']['min_s'])}",
    "peer": f"Python + allantools: {o['allantools']['mean_s']:.2f} s",
    "ratio": f"{min(ratios):.0f}-{max(ratios):.0f}× (4 kinds)",
    "target": "≥ 30×; ≤ 20 ms",
    "met": "yes" if ratio_ok and ms_ok else f"ratio {'yes' if ratio_ok else 'no'}, 20 ms {'yes' if ms_ok else 'no'}",
    "command": f"RUNS={runs} bash benches/allan_vs_allantools.sh process",
}
reasons = []
if not ratio_ok and load >= 1.0:
    reasons.append(("≥ 30× allantools", f"the ratio was measured at load {load:.1f} on {os.cpu_count()} cores "
                    "(`benches/record_all` reruns it on an idle machine)"))
if not ms_ok:
    reasons.append(("≤ 20 ms", f"min {ms(o['imulab']['min_s'])} ms; a process that only maps, integrates and exits "
                    f"(`benches/allan_process_floor.c`) takes {ms(o['floor']['min_s'])}-{ms(o['floor']['mean_s'])} ms "
                    f"(min-mean, same run) and the deviation kernel {ms(kernel['one_axis_s'])} ms: "
                    f"{ms(o['floor']['min_s'] + kernel['one_axis_s'])} ms together on this machine"))
if reasons:
    row["not_met"] = {"what": "`imulab allan` process " + " and ".join(r[0] for r in reasons),
                      "why": "; ".join(r[1] for r in reasons)}
doc = {
    "bench": "allan_vs_allantools", "mode": "process",
    "args": {"runs": int(runs), "warmup": 3, "kinds": kinds, "imulab": version,
             "allantools": allantools.__version__},
    "recorded_unix_s": int(time.time()), "load_1min_at_end": load, "cores": os.cpu_count(),
    "figures": {"kinds": stats}, "rows": [row],
}
os.makedirs(results, exist_ok=True)
path = os.path.join(results, "allan_vs_allantools-process.json")
with open(path, "w") as f:
    f.write(json.dumps(doc, indent=2, ensure_ascii=False) + "\n")
print(f"wrote {path}")
PY
    exit 0
fi
if [ ! -f "$data" ]; then
    echo "missing $data: run 'cargo bench --bench allan' first" >&2
    exit 1
fi
"$venv/bin/python" - "$data" "$ours" "$results" <<'PY'
import json, os, sys, time
import numpy as np
import allantools

data = np.load(sys.argv[1])
ours = json.load(open(sys.argv[2]))["figures"]
rate = 150.0
n = data.shape[0]
print(f"# allantools {allantools.__version__}, numpy {np.__version__}: {n} samples per axis, {data.shape[1]} axes\n")

def octave_taus(kind_stop):
    m, out = 1, []
    while m <= (n + 1) // kind_stop:
        out.append(m / rate)
        m *= 2
    return np.array(out)

def dense_taus(per_decade, stop):
    ms, k = [], 0
    while True:
        m = int(round(10 ** (k / per_decade)))
        if m > (n + 1) // stop:
            break
        if not ms or ms[-1] != m:
            ms.append(m)
        k += 1
    return np.array(ms) / rate

cases = [
    ("oadev", "octave", allantools.oadev, octave_taus(4)),
    ("oadev", "dense:10", allantools.oadev, dense_taus(10, 4)),
    ("mdev", "octave", allantools.mdev, octave_taus(4)),
    ("hdev", "octave", allantools.hdev, octave_taus(5)),
    ("totdev", "octave", allantools.totdev, octave_taus(2)),
]
# Wall time and this process's CPU time (user + sys, all threads), since other jobs share
# the cores: the CPU time is the figure that the load inflates least.
print("| deviation | grid | taus | 1 axis [s] | 1 axis CPU [s] | 6 axes [s] | 6 axes CPU [s] | max rel. diff. to imulab |")
print("|---|---|---|---|---|---|---|---|")
measured = []
for name, grid, fn, taus in cases:
    t0, c0 = time.perf_counter(), time.process_time()
    _, dev, _, _ = fn(data[:, 0], rate=rate, data_type="freq", taus=taus)
    one, one_cpu = time.perf_counter() - t0, time.process_time() - c0
    # Agreement with our deviation of axis 0 on the same taus (allan-speed.json).
    mine = next(c for c in ours["kinds"] if c["kind"] == name and c["grid"] == grid)
    theirs = np.asarray(dev)
    same = len(mine["axis0_deviation"]) == len(theirs)
    diff = float(np.max(np.abs(theirs - np.asarray(mine["axis0_deviation"])) / theirs)) if same else None
    t0, c0 = time.perf_counter(), time.process_time()
    for a in range(data.shape[1]):
        fn(data[:, a], rate=rate, data_type="freq", taus=taus)
    six, six_cpu = time.perf_counter() - t0, time.process_time() - c0
    print(f"| {name} | {grid} | {len(taus)} | {one:.3f} | {one_cpu:.3f} | {six:.3f} | {six_cpu:.3f} | {diff if diff is None else f'{diff:.1e}'} |", flush=True)
    measured.append({"kind": name, "grid": grid, "taus": len(taus), "one_axis_s": one,
                     "one_axis_cpu_s": one_cpu, "six_axes_s": six, "six_axes_cpu_s": six_cpu,
                     "max_rel_diff_vs_imulab": diff})

# The rows against allantools: four kinds on the octave grid, one axis and six.
load = float(open("/proc/loadavg").read().split()[0])
four = ["oadev", "mdev", "hdev", "totdev"]
pair = lambda k: (next(c for c in ours["kinds"] if c["kind"] == k and c["grid"] == "octave"),
                  next(c for c in measured if c["kind"] == k and c["grid"] == "octave"))
pairs = [pair(k) for k in four]
one = [p["one_axis_s"] / o["one_axis_s"] for o, p in pairs]
six = [p["six_axes_s"] / o["six_axes_s"] for o, p in pairs]
threads = json.load(open(sys.argv[2]))["args"]["rayon_threads"]
common = {"section": "Allan analysis (3.24 M samples, one axis)", "section_order": 3,
          "peer_column": "allantools", "doc": "docs/bench/allan.md", "target": "≥ 30×"}
fmt_ms = lambda v: f"{1e3 * v:.1f}" if v < 0.01 else f"{1e3 * v:.0f}"
rows = [
    dict(common, id="allan-kinds", order=1, measured="OADEV / MDEV / HDEV / TOTDEV, octave",
         data=f"kernel, {threads} threads, load {load:.1f}",
         ours=" / ".join(fmt_ms(o["one_axis_s"]) for o, _ in pairs) + " ms",
         peer=" / ".join(f"{p['one_axis_s']:.2f}" for _, p in pairs) + " s",
         ratio=" / ".join(f"{r:.0f}" for r in one) + "×",
         met="yes" if min(one) >= 30 else "no",
         command="cargo bench --bench allan` + `bash benches/allan_vs_allantools.sh"),
    dict(common, id="allan-six-axes", order=2, measured="six axes",
         data="same, OADEV / MDEV / HDEV / TOTDEV",
         ours=" / ".join(fmt_ms(o["six_axes_s"]) for o, _ in pairs) + " ms",
         peer=" / ".join(f"{p['six_axes_s']:.2f}" for _, p in pairs) + " s",
         ratio=f"{min(six):.0f}-{max(six):.0f}×",
         met="yes" if min(six) >= 30 else "no", command="same"),
]
for r in rows:
    if r["met"] == "no" and load >= 1.0:
        r["not_met"] = {"what": f"{r['measured']} {r['target']}",
                        "why": f"measured at load {load:.1f} on {os.cpu_count()} cores; "
                        "`benches/record_all` reruns it on an idle machine"}
doc = {"bench": "allan_vs_allantools", "mode": "kernel",
       "args": {"data": "target/allan-bench/data.npy", "samples": n, "axes": data.shape[1],
                "allantools": allantools.__version__, "numpy": np.__version__},
       "recorded_unix_s": int(time.time()), "load_1min_at_end": load, "cores": os.cpu_count(),
       "figures": {"kinds": measured}, "rows": rows}
os.makedirs(sys.argv[3], exist_ok=True)
path = os.path.join(sys.argv[3], "allan_vs_allantools-kernel.json")
with open(path, "w") as f:
    f.write(json.dumps(doc, indent=2, ensure_ascii=False) + "\n")
print(f"wrote {path}")

# Agreement check on axis 0, OADEV octave (printed for the record).
t, dev, err, ns = allantools.oadev(data[:, 0], rate=rate, data_type="freq", taus=octave_taus(4))
print("\nallantools OADEV axis 0 (tau, dev):")
for a, b in zip(t, dev):
    print(f"{a:.6e} {b:.10e}")
PY
