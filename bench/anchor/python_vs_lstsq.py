#!/usr/bin/env python3
"""Issue 35's speed and memory measurement (scripts/bench-python): rotacal.calibrate on a
DataFrame already in memory against numpy's lstsq of the same three-parameter fits on the
same arrays (the anchor's fit alone: sin, cos and 1 at the nominal rate per condition, for
u, v, w together), paired run by run, each first in every other pair; and the peak memory
calibrate's first call adds over the DataFrame (VmHWM after resetting it through
/proc/self/clear_refs); then calibrate on the same file as pandas.read_csv gives it.
Usage: python_vs_lstsq.py RECORDING.csv RUNS OUT.json"""
import gc
import json
import statistics
import sys
import time

import numpy as np
import pandas as pd

import rotacal

path, runs, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
df = rotacal.read_recording(path)
rate = float(df.attrs["rotacal"]["rate_hz"])
groups = [(d["t_s"].to_numpy(), d[["u", "v", "w"]].to_numpy()) for _, d in df.groupby("condition")]


def anchor():
    for t, y in groups:
        wt = 2 * np.pi * rate * t
        X = np.column_stack([np.sin(wt), np.cos(wt), np.ones_like(wt)])
        np.linalg.lstsq(X, y, rcond=None)


def status(key):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key):
                return int(line.split()[1]) * 1024


# Memory first, on the first call: later calls reuse what the allocator kept, and would
# show less.
gc.collect()
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")
before = status("VmRSS:")
cal = rotacal.calibrate(df)
added = status("VmHWM:") - before
pairs = []
for i in range(runs):
    # Each goes first in every other pair: what one leaves behind (numpy's BLAS threads
    # spinning, caches) falls on both alike.
    t0 = time.perf_counter()
    if i % 2 == 0:
        anchor()
    else:
        rotacal.calibrate(df)
    t1 = time.perf_counter()
    if i % 2 == 0:
        rotacal.calibrate(df)
    else:
        anchor()
    t2 = time.perf_counter()
    pairs.append((t1 - t0, t2 - t1) if i % 2 == 0 else (t2 - t1, t1 - t0))
a = [p[0] for p in pairs]
r = [p[1] for p in pairs]
# The same session as pandas' own reader gives it (the condition as pandas' str, seq as
# integers): a user's DataFrame rather than read_recording's, timed alone.
csv = pd.read_csv(path, comment="#")
meta = df.attrs["rotacal"]
rotacal.calibrate(csv, metadata=meta)
csv_times = []
for _ in range(runs):
    t0 = time.perf_counter()
    rotacal.calibrate(csv, metadata=meta)
    csv_times.append(time.perf_counter() - t0)
result = {
    "what": "rotacal.calibrate(DataFrame) against numpy lstsq of the same fits, paired",
    "rows": len(df),
    "columns": list(df.columns),
    "dataframe_bytes": int(df.memory_usage(deep=True).sum()),
    "runs": runs,
    "lstsq_s_median": statistics.median(a),
    "lstsq_s_all": a,
    "rotacal_s_median": statistics.median(r),
    "rotacal_s_all": r,
    "ratio_lstsq_over_rotacal": statistics.median(a) / statistics.median(r),
    "read_csv_rotacal_s_median": statistics.median(csv_times),
    "read_csv_rotacal_s_all": csv_times,
    "read_csv_ratio_lstsq_over_rotacal": statistics.median(a) / statistics.median(csv_times),
    "peak_added_bytes": added,
    "goals": {"ratio_at_least": 1.0, "peak_added_bytes_at_most": 20 * 2**20},
    "goals_met": {
        "faster_than_lstsq": statistics.median(a) / statistics.median(r) >= 1.0,
        "memory": added <= 20 * 2**20,
    },
    "numpy": np.__version__,
    "rotacal": rotacal.__version__,
    "commit": rotacal.__commit__,
    "s_u": cal.quantity("s_u").value,
}
with open(out, "w") as f:
    json.dump(result, f, indent=2)
    f.write("\n")
print(json.dumps({k: v for k, v in result.items() if not k.endswith("_all")}, indent=2))
