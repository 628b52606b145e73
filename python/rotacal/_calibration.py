"""A calibration: the command line's JSON (docs/formats.md), read into Python objects."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from ._imucal import ImucalCalibration, imucal_json

#: The intrinsic properties, in the budget's order: (name, JSON group, JSON key).
_PROPERTIES = [
    ("s_u", "sensitivity", "u"),
    ("s_v", "sensitivity", "v"),
    ("s_w", "sensitivity", "w"),
    ("φ_uv", "angle_deg", "uv"),
    ("φ_vw", "angle_deg", "vw"),
    ("φ_wu", "angle_deg", "wu"),
    ("O_u", "offset", "u"),
    ("O_v", "offset", "v"),
    ("O_w", "offset", "w"),
]


@dataclass(frozen=True)
class Quantity:
    """A result with its uncertainty (GUM): value, standard uncertainty u, expanded
    uncertainty U = k·u (95 %), coverage factor k, effective degrees of freedom ν_eff
    (``inf``: infinite) and unit."""

    value: float
    u: float
    U: float
    k: float
    nu_eff: float
    unit: str

    def __str__(self) -> str:
        return f"{self.value} ± {self.U} {self.unit} (k = {self.k:.2f})"


@dataclass(frozen=True)
class Correction:
    """The correction a = M·(y − O) to m/s² (docs/formats.md, ``correction``): M (3×3),
    O (3,), their standard uncertainties, and the covariance of (M row-major, O) (12×12)."""

    frame: str
    M: np.ndarray
    O: np.ndarray
    M_u: np.ndarray
    O_u: np.ndarray
    covariance: np.ndarray
    units_in: str


class Calibration:
    """A calibration: what ``rotacal calibrate --json`` writes, with its parts as Python
    objects. :meth:`to_json` gives back the JSON it was made from, byte for byte.

    Attributes
    ----------
    method : str
    g_loc : float
        Local gravity used, m/s².
    units : str
        The readings' units.
    rates : list of float or None
        Each entry's nominal rotation rate, Hz (``None``: static or free poses).
    traceability : dict
        Which rotacal made it, when, from what (docs/formats.md, "Traceability").
    """

    def __init__(self, text: str, data: dict):
        self._text = text
        self._data = data
        self.method: str = data["method"]
        self.g_loc: float = data["g_loc"]
        self.units: str = data["units"]
        self.rates: list = [e.get("rate_hz") for e in data["by_rate"]]
        self.traceability: dict = data.get("traceability", {})

    @classmethod
    def from_json(cls, text: str) -> "Calibration":
        """A calibration from the JSON ``rotacal calibrate --json`` wrote (or
        :meth:`to_json`)."""
        data = json.loads(text)
        for key in ("method", "g_loc", "units", "by_rate"):
            if key not in data:
                raise ValueError(f"not a rotacal calibration: no '{key}' key")
        if not data["by_rate"]:
            raise ValueError("not a rotacal calibration: 'by_rate' is empty")
        return cls(text, data)

    def to_json(self) -> str:
        """The calibration JSON, as the command line writes it (docs/formats.md)."""
        return self._text

    def _entry(self, rate_hz: Optional[float]) -> dict:
        entries = self._data["by_rate"]
        if rate_hz is None:
            if len(entries) > 1:
                raise ValueError(f"several rates ({self.rates}): say which with rate_hz=")
            return entries[0]
        for e in entries:
            if e.get("rate_hz") == rate_hz:
                return e
        raise ValueError(f"no entry at {rate_hz} Hz: the rates are {self.rates}")

    def _combined(self, entry: dict) -> dict:
        b = entry.get("uncertainty_budget") or {}
        return {c["quantity"]: c for c in b.get("combined", [])}

    def quantity(self, name: str, rate_hz: Optional[float] = None) -> Quantity:
        """One intrinsic property (``"s_u"``, ``"φ_uv"`` or ``"phi_uv"``, ``"O_w"``, ...)."""
        name = name.replace("phi_", "φ_")
        entry = self._entry(rate_hz)
        for n, group, key in _PROPERTIES:
            if n == name:
                g = entry["intrinsic"].get(group)
                if not g:
                    raise ValueError(f"{name}: not estimated by this calibration")
                q = g[key]
                c = self._combined(entry).get(n, {})
                units = dict(zip(entry["uncertainty_budget"]["quantities"],
                                 entry["uncertainty_budget"]["units"]))
                nu = c.get("nu_eff")
                return Quantity(
                    value=q["value"],
                    u=q["std_unc"],
                    U=q["expanded_unc"],
                    k=q["k"],
                    nu_eff=float("inf") if nu is None else nu,
                    unit=units.get(n, ""),
                )
        raise ValueError(f"{name}: the properties are {[p[0] for p in _PROPERTIES]}")

    def properties(self, rate_hz: Optional[float] = None):
        """The intrinsic properties as a pandas DataFrame: index the property, columns
        value, u, U, k, nu_eff, unit."""
        import pandas as pd

        entry = self._entry(rate_hz)
        rows = {}
        for n, group, _ in _PROPERTIES:
            if entry["intrinsic"].get(group):
                q = self.quantity(n, entry.get("rate_hz"))
                rows[n] = [q.value, q.u, q.U, q.k, q.nu_eff, q.unit]
        return pd.DataFrame.from_dict(
            rows, orient="index", columns=["value", "u", "U", "k", "nu_eff", "unit"]
        )

    def budget(self, rate_hz: Optional[float] = None):
        """The uncertainty budget as a pandas DataFrame: a row per source (with its type,
        A or B, and its standard uncertainty where it is one number), a column per
        property holding that source's contribution |c|·u, then the combined u."""
        import pandas as pd

        b = self._entry(rate_hz)["uncertainty_budget"]
        quantities = b["quantities"]
        rows = {}
        for s in b["sources"]:
            rows[s["source"]] = [s["type"], s.get("std_unc"), s.get("unit")] + [
                np.nan if x is None else x for x in s["contribution"]
            ]
        combined = {c["quantity"]: c["std_unc"] for c in b["combined"]}
        rows["combined u"] = ["", None, None] + [combined.get(q, np.nan) for q in quantities]
        return pd.DataFrame.from_dict(
            rows, orient="index", columns=["type", "u(input)", "unit"] + quantities
        )

    def correction(self, frame: str = "device", rate_hz: Optional[float] = None) -> Correction:
        """The correction to m/s² in the ``"device"`` frame (x′ along u, y′ in the u-v
        plane) or the ``"platter"`` frame (static calibrations)."""
        c = self._entry(rate_hz).get("correction")
        if not c:
            raise ValueError("this calibration has no correction")
        f = c.get(f"{frame}_frame")
        if not f:
            raise ValueError(f"this calibration has no correction in the {frame} frame")
        return Correction(
            frame=frame,
            M=np.array(f["matrix"], dtype=float),
            O=np.array(f["offset"], dtype=float),
            M_u=np.array(f["matrix_std_unc"], dtype=float),
            O_u=np.array(f["offset_std_unc"], dtype=float),
            covariance=np.array(f["covariance"], dtype=float),
            units_in=c["units_in"],
        )

    def to_imucal(
        self,
        frame: Optional[str] = None,
        rate_hz: Optional[float] = None,
        cal_type: Optional[str] = None,
    ) -> str:
        """This calibration as imucal's calibration JSON (imucal 2.x), for
        ``imucal.CalibrationInfo.from_json``: K_a, R_a, b_a from the correction in
        ``frame`` (default: ``"platter"`` where there is one, the frame of the poses, as
        imucal's own; else ``"device"``). The gyroscope's terms are identity and zero, so
        imucal passes gyroscope readings through unchanged: rotacal calibrates
        accelerometers. The uncertainties, the budget and the traceability cannot be
        carried (imucal's format has no place for them); the comment names this
        calibration, and its JSON keeps them.

        ``cal_type``: ``"Turntable"`` (default for rotation) or ``"Ferraris"`` (default
        for static and free poses); imucal treats both alike."""
        entry = self._entry(rate_hz)
        c = entry.get("correction") or {}
        if frame is None:
            frame = "platter" if c.get("platter_frame") else "device"
        corr = self.correction(frame, rate_hz)
        if cal_type is None:
            cal_type = "Turntable" if self.method == "rotation" else "Ferraris"
        t = self.traceability
        inputs = ", ".join(
            f"{i.get('path')} (SHA-256 {i.get('sha256')})" for i in t.get("inputs", [])
        )
        comment = (
            f"rotacal {t.get('rotacal', '?')} ({t.get('commit', '?')}), {self.method} "
            f"calibration of {inputs or 'unnamed data'} on {t.get('date_utc', '?')}, "
            f"{frame} frame. Not carried: the uncertainties (see rotacal's JSON). "
            "The gyroscope terms are identity: rotacal calibrates accelerometers only."
        )
        return imucal_json(corr.M, corr.O, corr.units_in, comment, cal_type)

    def compare_imucal(self, other: "ImucalCalibration", rate_hz: Optional[float] = None):
        """Each intrinsic property here and in an imucal calibration (:func:`read_imucal`),
        as a pandas DataFrame: rotacal's value and U, imucal's value, their difference
        (imucal − rotacal), |difference|/U, and whether it is within U. imucal gives no
        uncertainty: U is this calibration's alone."""
        import pandas as pd

        theirs = other.intrinsic()
        props = self.properties(rate_hz)
        rows = {}
        for name in props.index:
            v, U = props.loc[name, "value"], props.loc[name, "U"]
            d = theirs[name] - v
            rows[name] = [v, U, theirs[name], d, abs(d) / U, abs(d) <= U, props.loc[name, "unit"]]
        return pd.DataFrame.from_dict(
            rows,
            orient="index",
            columns=["rotacal", "U", "imucal", "difference", "|difference|/U", "within_U", "unit"],
        )

    def apply(self, data, frame: Optional[str] = None, rate_hz: Optional[float] = None,
              columns=None, metadata=None):
        """Correct readings: a = M·(y − O) in m/s², as ``rotacal apply`` does.

        Parameters
        ----------
        data
            A recording: a path, a DataFrame or a mapping of arrays, as for
            :func:`rotacal.calibrate` (``columns=`` and ``metadata=`` likewise), in the
            calibration's units.
        frame
            ``"device"`` (x′ along u, y′ in the u-v plane) or ``"platter"`` (the poses'
            frame; static calibrations). Default: platter where there is one.
        rate_hz
            Which entry, for a calibration with several rates.

        Returns
        -------
        pandas.DataFrame
            The corrected recording: u, v, w in m/s² and ``u_unc``, ``v_unc``, ``w_unc``,
            each value's standard uncertainty from the calibration (k in
            ``attrs["rotacal"]["coverage_factor"]``), the other columns as they were; the
            values are ``rotacal apply``'s, bit for bit.
        """
        from ._data import apply

        return apply(self, data, frame, rate_hz, columns, metadata)

    def noise(self, rate_hz: Optional[float] = None):
        """The noise model of each record (condition and channel) the calibration fitted,
        as a pandas DataFrame: its model, sd, the AR coefficients, lag-1 autocorrelation,
        variance factor, n, effective n and degrees of freedom (docs/uncertainty.md,
        "The noise model"; the JSON's ``noise``)."""
        import pandas as pd

        return pd.DataFrame(self._entry(rate_hz).get("noise") or [])

    def as_dict(self) -> dict:
        """The whole calibration JSON as Python objects."""
        return json.loads(self._text)

    def __repr__(self) -> str:
        rates = "" if self.rates == [None] else f", rates {self.rates} Hz"
        return f"<rotacal.Calibration {self.method}{rates}, units {self.units}>"
