#!/usr/bin/env python3
"""Read a whole imulab session with h5py and numpy.

Usage:  python3 read_session.py SESSION_DIR [--dump-json FILE]

--dump-json writes every table as JSON (floats as exact repr() strings), for tests.

`read_session(dir)` returns a dict:
  "manifest": the parsed session.toml,
  "tables":   {group path: {column name: numpy array}}, e.g.
              tables["imu/imu0"]["gyro"] is an N x 3 float64 array in rad/s,
              tables["events"]["kind"] an array of str,
              tables["raw/imu0"] has "t_mono_ns", "offset", "len" and "bytes" (offsets are
              into the concatenated "bytes" of the whole session).
Every table's rows are concatenated across the chunk files in order. A file still being
written (*.partial) is opened in SWMR mode; rows whose t_mono_ns is the fill value
(-2**63, never written) are dropped. See docs/session-format.md for the layout.
"""
import json
import pathlib
import re
import sys
import tomllib

import h5py
import numpy as np

SCHEMA_VERSION = 1  # of the chunk files
SESSION_SCHEMA_VERSIONS = (1, 2)  # of session.toml (2 added the write-ahead journal)
CHUNK_NAME = re.compile(r"^chunk-(\d+)\.h5(\.partial)?$")
FILL_T = np.iinfo(np.int64).min
STRING_COLUMNS = ("device", "kind", "detail")


def chunk_files(session):
    """(path, is_partial) of every chunk file, in chunk order."""
    found = []
    for p in pathlib.Path(session).iterdir():
        m = CHUNK_NAME.match(p.name)
        if m:
            found.append((int(m.group(1)), m.group(2) is not None, p))
    return [(p, partial) for _, partial, p in sorted(found)]


def tables_in(f):
    """Paths of every group holding a t_mono_ns dataset (one table each)."""
    paths = []
    f.visititems(lambda name, obj: paths.append(name.rsplit("/", 1)[0])
                 if isinstance(obj, h5py.Dataset) and name.endswith("/t_mono_ns") else None)
    return sorted(paths)


def read_session(session):
    session = pathlib.Path(session)
    manifest = tomllib.loads((session / "session.toml").read_text())
    if manifest["schema_version"] not in SESSION_SCHEMA_VERSIONS:
        raise ValueError(f"{session}/session.toml: unknown schema version {manifest['schema_version']}")
    parts = {}  # group -> column -> list of arrays
    raw_base = {}  # raw group -> bytes already read from earlier files
    for path, partial in chunk_files(session):
        with h5py.File(path, "r", libver="v110", swmr=partial) as f:
            if f.attrs["schema_version"] != SCHEMA_VERSION:
                raise ValueError(f"{path}: unknown schema version {f.attrs['schema_version']}")
            for group in tables_in(f):
                g = f[group]
                row_columns = [c for c in g if c != "bytes"]
                n = min(g[c].shape[0] for c in row_columns)
                t = g["t_mono_ns"][:n]
                n = int(np.count_nonzero(t != FILL_T))  # unwritten rows only sit at the end
                cols = parts.setdefault(group, {})
                for c in row_columns:
                    cols.setdefault(c, []).append(g[c][:n])
                if "bytes" in g:  # raw journal: shift offsets to the concatenated bytes
                    base = raw_base.get(group, 0)
                    cols["offset"][-1] = cols["offset"][-1] + base
                    if n:
                        end = int(g["offset"][n - 1]) + int(g["len"][n - 1])
                    else:
                        end = 0
                    cols.setdefault("bytes", []).append(g["bytes"][:end])
                    raw_base[group] = base + end
    tables = {}
    for group, cols in parts.items():
        tables[group] = {}
        for c, arrays in cols.items():
            a = np.concatenate(arrays)
            if c in STRING_COLUMNS:
                a = np.array([s.decode("utf-8") for s in a], dtype=object)
            tables[group][c] = a
    return {"manifest": manifest, "tables": tables}


def main(argv):
    if len(argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    s = read_session(argv[1])
    for group, cols in sorted(s["tables"].items()):
        t = cols["t_mono_ns"]
        span = (t[-1] - t[0]) * 1e-9 if len(t) > 1 else 0.0
        print(f"/{group}: {len(t)} rows over {span:.3f} s; columns {', '.join(cols)}")
    if len(argv) >= 4 and argv[2] == "--dump-json":
        # Floats as repr() strings: exact, and JSON has no NaN.
        def plain(x):
            if isinstance(x, list):
                return [plain(y) for y in x]
            return repr(x) if isinstance(x, float) else x
        dump = {g: {c: (plain(a.tolist()) if c != "bytes" else a.tobytes().hex()) for c, a in cols.items()}
                for g, cols in s["tables"].items()}
        pathlib.Path(argv[3]).write_text(json.dumps(dump))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
