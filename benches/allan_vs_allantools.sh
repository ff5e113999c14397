#!/usr/bin/env bash
# Times Python allantools on the same data as `cargo bench --bench allan`
# (target/allan-bench/data.npy: 6 h x 150 Hz x 6 axes) for the deviation types the
# issue names, one axis and six axes, and checks that both tools agree on OADEV.
# The venv is cached under target/allantools-venv.
# Usage: benches/allan_vs_allantools.sh   (run `cargo bench --bench allan` first)
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
venv="$root/target/allantools-venv"
data="$root/target/allan-bench/data.npy"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet allantools
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
