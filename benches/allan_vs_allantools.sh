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
# as JSON, alternating the two in one run.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
venv="$root/target/allantools-venv"
data="$root/target/allan-bench/data.npy"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet allantools
fi
if [ "${1:-}" = process ]; then
    bin="$root/target/release/imulab"
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
    echo "| deviation | ours mean [ms] | ours min [ms] | allantools mean [ms] | allantools min [ms] | ratio of means |"
    echo "|---|---|---|---|---|---|"
    for kind in oadev mdev hdev totdev; do
        hyperfine --style none --warmup 3 --runs "${RUNS:-20}" -N --export-json "$work/$kind.json" \
            "$bin allan $work/x.npy --rate 150 --kind $kind --taus octave --json $work/o.json" \
            "$venv/bin/python $work/peer.py $kind $work/x.npy $work/p.json" >/dev/null
        "$venv/bin/python" - "$work/$kind.json" "$kind" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))["results"]
ours, peer = r[0], r[1]
ms = lambda v: f"{1e3 * v:.1f}"
print(f"| {sys.argv[2]} | {ms(ours['mean'])} | {ms(ours['min'])} | {ms(peer['mean'])} | {ms(peer['min'])} | {peer['mean'] / ours['mean']:.0f}× |")
PY
    done
    exit 0
fi
if [ ! -f "$data" ]; then
    echo "missing $data: run 'cargo bench --bench allan' first" >&2
    exit 1
fi
"$venv/bin/python" - "$data" <<'PY'
import sys, time
import numpy as np
import allantools

data = np.load(sys.argv[1])
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
print("| deviation | grid | taus | 1 axis [s] | 1 axis CPU [s] | 6 axes [s] | 6 axes CPU [s] |")
print("|---|---|---|---|---|---|---|")
for name, grid, fn, taus in cases:
    t0, c0 = time.perf_counter(), time.process_time()
    fn(data[:, 0], rate=rate, data_type="freq", taus=taus)
    one, one_cpu = time.perf_counter() - t0, time.process_time() - c0
    t0, c0 = time.perf_counter(), time.process_time()
    for a in range(data.shape[1]):
        fn(data[:, a], rate=rate, data_type="freq", taus=taus)
    six, six_cpu = time.perf_counter() - t0, time.process_time() - c0
    print(f"| {name} | {grid} | {len(taus)} | {one:.3f} | {one_cpu:.3f} | {six:.3f} | {six_cpu:.3f} |", flush=True)

# Agreement check on axis 0, OADEV octave (printed for the record).
t, dev, err, ns = allantools.oadev(data[:, 0], rate=rate, data_type="freq", taus=octave_taus(4))
print("\nallantools OADEV axis 0 (tau, dev):")
for a, b in zip(t, dev):
    print(f"{a:.6e} {b:.10e}")
PY
