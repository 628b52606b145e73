"""imucal's calibration files (imucal 2.x, ``FerrarisCalibrationInfo`` and
``TurntableCalibrationInfo`` JSON): read one and compare it with a rotacal calibration, or
write a rotacal calibration as one (docs/python.md, "imucal")."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

#: The calibration format version imucal 2.x writes and reads.
FORMAT_VERSION = "2.0.0"


@dataclass(frozen=True)
class ImucalCalibration:
    """An imucal calibration: raw = K_a·R_a·a + b_a for the accelerometer (K_a diagonal,
    R_a with rows of unit length), and the gyroscope's terms, which rotacal does not use.

    Its intrinsic properties in rotacal's terms: s_j = K_a[j, j] (as S = K_a·R_a has rows
    of those lengths), φ_jk the angle between rows j and k of R_a, O = b_a."""

    cal_type: str
    K_a: np.ndarray
    R_a: np.ndarray
    b_a: np.ndarray
    acc_unit: Optional[str] = None
    from_acc_unit: Optional[str] = None
    comment: Optional[str] = None
    other: dict = field(default_factory=dict)

    def intrinsic(self) -> dict:
        """s_u, s_v, s_w (from_acc_unit per acc_unit), φ_uv, φ_vw, φ_wu (degrees), O_u,
        O_v, O_w (from_acc_unit)."""
        s = self.K_a @ self.R_a
        rows = [s[j] / np.linalg.norm(s[j]) for j in range(3)]

        def angle(j, k):
            return math.degrees(math.acos(max(-1.0, min(1.0, float(rows[j] @ rows[k])))))

        return {
            "s_u": float(np.linalg.norm(s[0])),
            "s_v": float(np.linalg.norm(s[1])),
            "s_w": float(np.linalg.norm(s[2])),
            "φ_uv": angle(0, 1),
            "φ_vw": angle(1, 2),
            "φ_wu": angle(2, 0),
            "O_u": float(self.b_a[0]),
            "O_v": float(self.b_a[1]),
            "O_w": float(self.b_a[2]),
        }


def read_imucal(source) -> ImucalCalibration:
    """Read an imucal calibration JSON (a path, or the JSON text).

    Raises
    ------
    ValueError
        Not an imucal 2.x accelerometer calibration: which key or value is wrong.
    """
    text = str(source)
    if not text.lstrip().startswith("{"):
        with open(source, encoding="utf8") as f:
            text = f.read()
    d = json.loads(text)
    version = d.pop("_format_version", None)
    if version is None or int(str(version).split(".")[0]) != 2:
        raise ValueError(f"imucal calibration: format version {version!r}, not 2.x")
    cal_type = d.pop("cal_type", None)
    if cal_type not in ("Ferraris", "Turntable"):
        raise ValueError(f"imucal calibration: cal_type {cal_type!r}, not Ferraris or Turntable")
    arrays = {}
    for key, shape in (("K_a", (3, 3)), ("R_a", (3, 3)), ("b_a", (3,))):
        if d.get(key) is None:
            raise ValueError(f"imucal calibration: no {key}")
        arrays[key] = np.asarray(d.pop(key), dtype=float)
        if arrays[key].shape != shape:
            raise ValueError(f"imucal calibration: {key} has shape {arrays[key].shape}, not {shape}")
    return ImucalCalibration(
        cal_type=cal_type,
        acc_unit=d.pop("acc_unit", None),
        from_acc_unit=d.pop("from_acc_unit", None),
        comment=d.pop("comment", None),
        other=d,
        **arrays,
    )


def imucal_json(M: np.ndarray, O: np.ndarray, units_in: str, comment: str, cal_type: str) -> str:
    """imucal's calibration JSON for the correction a = M·(y − O): S = M⁻¹ = K_a·R_a with
    K_a the lengths of S's rows, R_a its rows normalised, b_a = O; the gyroscope's terms
    identity and zero, which pass its readings through unchanged."""
    if cal_type not in ("Ferraris", "Turntable"):
        raise ValueError(f"cal_type {cal_type!r}: Ferraris or Turntable")
    S = np.linalg.inv(np.asarray(M, dtype=float))
    k = np.linalg.norm(S, axis=1)
    d = {
        "acc_unit": "m/s^2",
        "gyr_unit": "deg/s",
        "from_acc_unit": units_in,
        "from_gyr_unit": "deg/s",
        "comment": comment,
        "K_a": np.diag(k).tolist(),
        "R_a": (S / k[:, None]).tolist(),
        "b_a": np.asarray(O, dtype=float).tolist(),
        "K_g": np.eye(3).tolist(),
        "R_g": np.eye(3).tolist(),
        "K_ga": np.zeros((3, 3)).tolist(),
        "b_g": [0.0, 0.0, 0.0],
        "cal_type": cal_type,
        "_format_version": FORMAT_VERSION,
    }
    return json.dumps(d, indent=4)
