#!/usr/bin/env python3
"""Golden values for rotacal's `allan` module, from allantools 2024.06 (LGPL-3.0).

Run: /tmp/av/bin/python host/engine/tests/data/allan/generate.py (from the repository root).
Writes <name>.txt (the series, one value a line, 10 significant digits) and golden.json
(allantools' outputs for the values as read back from those files, so the text rounding
does not enter the comparison). Only the output numbers are committed, not allantools' code.
"""
import json
import math
import os

import numpy as np
import scipy.special
import scipy.stats
import allantools
from allantools import ci as atci

HERE = os.path.dirname(os.path.abspath(__file__))
ONE_SIGMA = scipy.special.erf(1 / math.sqrt(2))


def series():
    rng = np.random.default_rng(20240601)
    white = rng.normal(0.0, 50.0, 2000) + 3.0            # white FM, offset 3
    rw = np.cumsum(rng.normal(0.0, 0.2, 4000))           # random-walk FM
    # Kasdin & Walter flicker (allantools noise_kasdin, b = -1 on freq data), plus white
    # noise so that the noise id changes along tau.
    np.random.seed(7)
    fl = allantools.noise_kasdin.Noise(8192, qd=1.0, b=-1)
    fl.generateNoise()
    flick = np.asarray(fl.time_series[:8192]) * 10.0 + rng.normal(0.0, 1.0, 8192)
    return [("white", white, 1.0), ("rw", rw, 104.0), ("flicker", flick, 16.0)]


def main():
    out = {"generator": "allantools " + allantools.__version__, "ci": ONE_SIGMA, "sets": []}
    for name, y, rate in series():
        path = os.path.join(HERE, name + ".txt")
        with open(path, "w") as f:
            for v in y:
                f.write("%.9e\n" % v)
        y = np.loadtxt(path)
        taus, adev, ade, ns = allantools.oadev(y, rate=rate, data_type="freq", taus="octave")
        rows = []
        for t, d, n in zip(taus, adev, ns):
            m = int(round(t * rate))
            row = {"tau_s": t, "m": m, "adev": d, "n": int(n)}
            try:
                alpha = atci.autocorr_noise_id(y, m, data_type="freq", dmin=0, dmax=2)[0]
                edf = atci.edf_greenhall(alpha=alpha, d=2, m=m, N=len(y),
                                         overlapping=True, modified=False)
                lo, hi = atci.confidence_interval_noiseID(y, d, af=m, dev_type="oadev",
                                                          data_type="freq", ci=ONE_SIGMA)
                row.update({"alpha": int(alpha), "edf": float(edf), "lo": lo, "hi": hi})
            except (NotImplementedError, AssertionError):
                row.update({"alpha": None, "edf": None, "lo": None, "hi": None})
            rows.append(row)
        # An explicit tau list (allantools rounds tau·rate to m, half to even).
        ms = [3, 5, 100, 999]
        t2, a2, _, n2 = allantools.oadev(y, rate=rate, data_type="freq",
                                         taus=np.array(ms) / rate)
        explicit = [{"m": int(round(t * rate)), "adev": d, "n": int(n)}
                    for t, d, n in zip(t2, a2, n2)]
        out["sets"].append({"name": name, "rate_hz": rate, "len": len(y), "rows": rows,
                            "explicit": explicit})
    # scipy's chi-square quantiles, against which statrs' inverse_cdf is checked
    q = []
    edfs = [1.3, 2.0, 7.5, 31.7, 150.2, 1234.5, 98765.4, 1.0e6]
    edfs += [r["edf"] for s in out["sets"] for r in s["rows"] if r["edf"] is not None]
    for edf in edfs:
        pl = (1 - ONE_SIGMA) / 2
        q.append({"edf": edf, "p": pl, "x": scipy.stats.chi2.ppf(pl, edf)})
        q.append({"edf": edf, "p": 1 - pl, "x": scipy.stats.chi2.ppf(1 - pl, edf)})
    out["chi2"] = q
    with open(os.path.join(HERE, "golden.json"), "w") as f:
        json.dump(out, f, indent=1)
        f.write("\n")


if __name__ == "__main__":
    main()
