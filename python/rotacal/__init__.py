"""rotacal: calibrate triaxial accelerometers by rotation in Earth's gravity.

The intrinsic properties of a device (three sensitivities, the three angles between its
sensitive axes, three offsets), each with its uncertainty budget, from a recording held
as a pandas or polars DataFrame, as numpy arrays, or in a file. The numbers are the
command line's: the same engine, in Rust (docs/python.md).

>>> import rotacal
>>> cal = rotacal.calibrate("session.csv")            # doctest: +SKIP
>>> cal.properties                                    # doctest: +SKIP
"""

from ._calibration import Calibration, Quantity
from ._data import (
    Allan,
    Discrepancy,
    allan,
    calibrate,
    discrepancy,
    read_recording,
    simulate,
    write_recording,
)
from ._imucal import ImucalCalibration, read_imucal
from ._rotacal import (
    CalibrationError,
    DiscrepancyError,
    RecordingError,
    __commit__,
    __version__,
)

__all__ = [
    "Allan",
    "Calibration",
    "CalibrationError",
    "Discrepancy",
    "DiscrepancyError",
    "ImucalCalibration",
    "Quantity",
    "RecordingError",
    "__commit__",
    "__version__",
    "allan",
    "calibrate",
    "discrepancy",
    "read_imucal",
    "read_recording",
    "simulate",
    "write_recording",
]
