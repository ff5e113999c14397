#!/usr/bin/env python3
"""Writes one producer's JSON to benches/results/<bench>-<mode>.json for the shell producers
(benches/fuzz_all, .ci/vcan), in the shape benches/support/results.rs writes.

    write_result.py DIR BENCH MODE ARGS_JSON FIGURES_JSON ROW_JSON

ROW_JSON holds the row's cells (id, section, section_order, order, measured, doc, data, ours,
target, met, command; peer and ratio default to "—")."""
import json
import os
import sys
import time

directory, bench, mode, args, figures, row = sys.argv[1:7]
row = json.loads(row)
row.setdefault("peer", "—")
row.setdefault("ratio", "—")
row.setdefault("peer_column", "peer")
load = float(open("/proc/loadavg").read().split()[0])
doc = {
    "args": json.loads(args),
    "bench": bench,
    "cores": os.cpu_count(),
    "figures": json.loads(figures),
    "load_1min_at_end": load,
    "mode": mode,
    "recorded_unix_s": int(time.time()),
    "rows": [row],
}
os.makedirs(directory, exist_ok=True)
path = os.path.join(directory, f"{bench}-{mode}.json")
with open(path, "w") as f:
    json.dump(doc, f, indent=2, sort_keys=True, ensure_ascii=False)
    f.write("\n")
print(f"wrote {path}")
