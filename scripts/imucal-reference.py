#!/usr/bin/env python3
"""The imucal numbers written into host/tests/suite/imucal.rs, and how they were obtained.

Not part of CI (it needs PyPI). To reproduce:

    python3 -m venv /tmp/imucal-venv
    /tmp/imucal-venv/bin/pip install imucal==2.6.0
    /tmp/imucal-venv/bin/python scripts/imucal-reference.py

Seen on 2026-11-22 with imucal 2.6.0, numpy 2.4.6, pandas 3.1.1, Python 3.11.7. The data are
loaded as imucal's examples/basic_ferraris.py loads them; imucal cuts each section with
data.iloc[start:end] (rows by position, end exclusive). The accelerometer part of
FerrarisCalibration.compute: U_p, U_a = pose means as columns; b_a = diag(U_p + U_a)/2;
K_a = diag(|row_i(U_p - U_a)|)/(2g); R_a = K_a^-1 (U_p - U_a)/(2g).
"""
from pathlib import Path

import numpy as np
import pandas as pd
from imucal import FerrarisCalibration, ferraris_regions_from_section_list

DATA = Path(__file__).resolve().parent.parent / "host/tests/data/imucal-ferraris"
data = pd.read_csv(DATA / "example_ferraris_session.csv", header=0, index_col=0)
sections = pd.read_json(DATA / "example_ferraris_session_list.json").T
regions = ferraris_regions_from_section_list(data, sections)
info = FerrarisCalibration(grav=9.81).compute(
    regions, sampling_rate_hz=102.4, from_acc_unit="m/s^2", from_gyr_unit="deg/s"
)


def show(name, m):
    rows = np.atleast_2d(np.asarray(m, dtype=float))
    print(f"{name} = [")
    for r in rows:
        print("    [" + ", ".join("%.17g" % x for x in r) + "],")
    print("]")


for pose in ["x_p", "x_a", "y_p", "y_a", "z_p", "z_a"]:
    s = sections.loc[pose]
    acc = data.iloc[s.start : s.end][["acc_x", "acc_y", "acc_z"]].to_numpy()
    show(f"mean {pose} (n = {len(acc)})", acc.mean(axis=0))
show("K_a", info.K_a)
show("R_a", info.R_a)
show("K_a @ R_a", info.K_a @ info.R_a)
show("b_a", info.b_a)
