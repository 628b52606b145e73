#!/usr/bin/env python3
"""The anchor of scripts/bench-calibrate (issue 18): what a metrologist with Python at hand
would write instead of running rotacal. One least-squares fit of sin, cos and 1 at the
nominal rate per condition and channel, then the Gram form G = S·Sᵀ (docs/method.md): each
condition's sine and cosine amplitudes are two columns of g·S, and each column of S is seen
by two conditions. Prints s_u, s_v, s_w (counts per m/s²) and φ_uv, φ_vw, φ_wu (degrees).
Usage: pandas_calibrate.py RECORDING.csv"""
import sys
import numpy as np
import pandas as pd

path = sys.argv[1]
meta = dict(l[2:].strip().split("=", 1) for l in open(path) if l.startswith("# ") and "=" in l)
rate, g = float(meta["rate_hz"]), float(meta["g_loc"])
df = pd.read_csv(path, comment="#", usecols=["condition", "t_s", "u", "v", "w"])
G = np.zeros((3, 3))
for _, d in df.groupby("condition"):
    wt = 2 * np.pi * rate * d["t_s"].to_numpy()
    X = np.column_stack([np.sin(wt), np.cos(wt), np.ones_like(wt)])
    coef, *_ = np.linalg.lstsq(X, d[["u", "v", "w"]].to_numpy(), rcond=None)
    G += (np.outer(coef[0], coef[0]) + np.outer(coef[1], coef[1])) / (2 * g * g)
s = np.sqrt(np.diag(G))
phi = [np.degrees(np.arccos(G[i, j] / (s[i] * s[j]))) for i, j in ((0, 1), (1, 2), (2, 0))]
print(" ".join(f"{x:.6f}" for x in [*s, *phi]))
