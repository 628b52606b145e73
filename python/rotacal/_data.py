"""From the user's data to the engine: DataFrames, numpy arrays and files."""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping
from typing import Any, Optional, Union

import numpy as np

from . import _rotacal
from ._calibration import Calibration

#: Columns read as text: a condition letter, a pose's name, the gaps between conversions.
_TEXT = {"condition", "pose", "conv_gaps"}

Data = Union[str, "os.PathLike[str]", Mapping[str, Any], Any]


def read_recording(path: Union[str, "os.PathLike[str]"]):
    """Read a recording CSV (docs/formats.md), checked as ``rotacal calibrate`` checks it.

    Parameters
    ----------
    path
        The recording.

    Returns
    -------
    pandas.DataFrame
        Its rows, grouped by condition in order of first appearance, with its columns
        (``condition``, ``t_s``, ``u``, ``v``, ``w``, ...). ``df.attrs["rotacal"]`` holds
        the file's metadata (``method``, ``rate_hz``, ``g_loc``, ``units``, ...) as text,
        which :func:`calibrate` takes back.

    Raises
    ------
    RecordingError
        The file cannot be read: ``line`` and ``column`` say where.
    """
    columns, meta, _method = _rotacal.read_recording(os.fspath(path))
    return _frame(columns, meta)


def _letters(values: Any) -> Optional[np.ndarray]:
    """A column of one-letter texts (a condition) as their ASCII bytes (uint8), read in
    chunks so that no Python object per row and no copy of the whole column is made;
    ``None`` when it holds anything else (which is then handed over as text, for the engine
    to name the row)."""
    try:
        import pandas as pd
    except ImportError:
        return None
    if isinstance(getattr(values, "dtype", None), pd.CategoricalDtype):
        # A pandas Categorical (read_recording's condition): a letter per category, looked
        # up by the codes it holds, without a Python object per row.
        cats = list(values.cat.categories)
        if not all(isinstance(c, str) and len(c) == 1 and c.isascii() for c in cats):
            return None
        codes = values.cat.codes.to_numpy()
        if (codes < 0).any():
            return None  # a missing value: handed over as text, for the engine to name
        return np.array([ord(c) for c in cats], dtype=np.uint8)[codes]
    n = len(values)
    out = np.empty(n, dtype=np.uint8)
    chunk = 1 << 16
    table = {}
    for start in range(0, n, chunk):
        # By position: a pandas Series' own index may be anything.
        rows = getattr(values, "iloc", values)
        part = rows[start:start + chunk]
        part = part.to_numpy() if hasattr(part, "to_numpy") else part
        try:
            codes, uniques = pd.factorize(np.asarray(part, dtype=object))
        except TypeError:
            return None
        if (codes < 0).any():
            return None
        for u in uniques:
            if not (isinstance(u, str) and len(u) == 1 and u.isascii()):
                return None
            table.setdefault(u, ord(u))
        lut = np.array([table[u] for u in uniques], dtype=np.uint8)
        out[start:start + len(codes)] = lut[codes]
    return out


def _objects(values: Any) -> Optional[np.ndarray]:
    """A column of texts that numpy already holds as Python objects (pandas' ``str``
    kept in Python, ``object`` columns, numpy object arrays), as that array, without a
    copy; ``None`` for anything else. The extension reads each distinct object's letter
    once (a condition column holds a few objects over and over), or the texts."""
    if isinstance(values, np.ndarray):
        return values if values.dtype == object and values.ndim == 1 else None
    try:
        import pandas as pd
    except ImportError:
        return None
    if not isinstance(values, pd.Series):
        return None
    if isinstance(values.array, pd.arrays.StringArray) or values.dtype == object:
        return values.to_numpy(dtype=object)
    return None


def _column_values(name: str, values: Any) -> Any:
    """A column as the extension takes it: float64 or (a condition's letters) uint8,
    contiguous; a condition's Python texts as numpy holds them; or a list of str."""
    if name == "condition":
        objects = _objects(values)
        if objects is not None:
            return objects
        letters = _letters(values)
        if letters is not None:
            return letters
    if name in _TEXT:
        return ["" if v is None else str(v) for v in np.asarray(values, dtype=object).tolist()]
    arr = np.asarray(values)
    if arr.ndim != 1:
        raise _recording_error(name, None, f"column {name}: {arr.ndim}-D, a column is 1-D")
    if arr.dtype.kind in "fiub":
        return np.ascontiguousarray(arr, dtype=np.float64)
    # Text or objects: numbers written as text are read as a file's fields are, and a
    # field that is not one is named with its row.
    return ["" if v is None else str(v) for v in arr.tolist()]


def _recording_error(column: str, row: Optional[int], message: str) -> Exception:
    e = _rotacal.RecordingError(message)
    e.source, e.line, e.row, e.column = "the data", None, row, column
    return e


def _table(data: Any, columns: Optional[Mapping[str, str]], metadata: Optional[Mapping[str, Any]]):
    """The (name, values) pairs and metadata of a DataFrame, a mapping or numpy arrays:
    ``df.attrs["rotacal"]``, then ``metadata`` over it."""
    rename = {theirs: ours for ours, theirs in (columns or {}).items()}
    meta: dict = {}
    attrs = getattr(data, "attrs", None)
    if isinstance(attrs, Mapping) and isinstance(attrs.get("rotacal"), Mapping):
        meta = dict(attrs["rotacal"])
    meta.update({k: v for k, v in (metadata or {}).items() if v is not None})
    meta = {str(k): v if isinstance(v, str) else repr(v) for k, v in meta.items()}
    if isinstance(data, Mapping):
        names = list(data.keys())
        get = data.__getitem__
        source = "the mapping"
    elif hasattr(data, "columns") and hasattr(data, "__getitem__"):
        names = [str(c) for c in data.columns]
        get = data.__getitem__
        source = f"the {type(data).__name__}"
    else:
        raise TypeError(
            "data: a path, a pandas or polars DataFrame, or a mapping of column names to "
            f"arrays is needed, not {type(data).__name__}"
        )
    missing = [theirs for theirs in rename if theirs not in names]
    if missing:
        raise _recording_error(
            missing[0], None, f"{source}: columns= names {missing[0]!r}, which it has not"
        )
    pairs = []
    for name in names:
        ours = rename.get(name, name)
        col = get(name)
        # A condition column is read in chunks, where it is (_letters): not as one copy.
        pairs.append((ours, _column_values(ours, col if ours == "condition" else _series(col))))
    return pairs, meta, source


def _series(col: Any) -> Any:
    """A column's values as numpy sees them (pandas and polars Series have to_numpy)."""
    to_numpy = getattr(col, "to_numpy", None)
    return to_numpy() if callable(to_numpy) else col


def _command(func: str, data: Any, options: Mapping[str, Any]) -> list:
    what = os.fspath(data) if isinstance(data, (str, os.PathLike)) else type(data).__name__
    args = ", ".join([repr(what)] + [f"{k}={v!r}" for k, v in options.items() if v is not None])
    return [sys.executable, f"rotacal.{func}({args})"]


def calibrate(
    data: Data,
    method: Optional[str] = None,
    rate_hz: Optional[float] = None,
    g_loc: Optional[float] = None,
    columns: Optional[Mapping[str, str]] = None,
    metadata: Optional[Mapping[str, Any]] = None,
    **options: Any,
) -> Calibration:
    """Calibrate a recording: the intrinsic properties with their uncertainty budget.

    The command line's ``rotacal calibrate``, with the same engine and the same numbers.

    Parameters
    ----------
    data
        A path to a recording CSV; a pandas or polars DataFrame; or a mapping of column
        names to arrays. Columns are named as in docs/formats.md (``condition``, ``t_s``,
        ``u``, ``v``, ``w``; ``angle_deg``; ``gx``, ``gy``, ``gz``; ...), or mapped with
        ``columns``. A DataFrame from :func:`read_recording` carries its metadata in
        ``df.attrs["rotacal"]``.
    method
        ``"rotation"``, ``"static"`` or ``"free"`` (default: the metadata's, else
        rotation when there is ``t_s``).
    rate_hz
        Nominal rotation rate, Hz (overrides the metadata's).
    g_loc
        Local gravity, m/s² (overrides the metadata's).
    columns
        ``{rotacal's name: your column's name}``, e.g. ``{"u": "acc_x"}``.
    metadata
        For a DataFrame or arrays: the recording's ``# key=value`` metadata
        (docs/formats.md: ``units``, ``device``, ``sample_rate_hz``, ``tick_hz``,
        ``u_g_loc``, ...), over ``df.attrs["rotacal"]``. Numbers are written with
        ``repr``, which Python makes exact.
    **options
        The command line's other flags with ``_`` for ``-``: ``u_g_loc``, ``u_time_s``,
        ``u_angle_deg``, ``monte_carlo``, ``pose_weights`` (``"random-effects"``,
        ``"equal"``), ``offsets`` (``"joint"``, ``"axis-pairs"``), ``still_window_s``,
        ``still_threshold``, ``min_still_s``, ``slow_noise``, ``noise_from`` (a path).

    Returns
    -------
    Calibration

    Raises
    ------
    RecordingError
        The data cannot be read: ``column`` and ``row`` (a DataFrame's, 0-based) or
        ``line`` (a file's) say where.
    CalibrationError
        The data were read but cannot be calibrated.
    """
    opts = dict(options, method=method, rate_hz=rate_hz, g_loc=g_loc)
    command = _command("calibrate", data, opts)
    if isinstance(data, (str, os.PathLike)):
        if columns is not None or metadata is not None:
            raise TypeError("columns= and metadata= are for DataFrames and arrays, not files")
        text = _rotacal.calibrate_path(os.fspath(data), opts, command)
    else:
        pairs, meta, source = _table(data, columns, metadata)
        try:
            text = _rotacal.calibrate_columns(pairs, list(meta.items()), source, opts, command)
        except (_rotacal.RecordingError, _rotacal.CalibrationError) as e:
            _label_row(e, data)
            raise
    return Calibration.from_json(text)


def _label_row(e: Exception, data: Any) -> None:
    """`e.index`: the DataFrame's index label of the row `e.row` (a position), if it has
    an index (pandas)."""
    row = getattr(e, "row", None)
    index = getattr(data, "index", None)
    e.index = None
    if row is not None and index is not None and not callable(index):
        try:
            e.index = index[row]
        except (IndexError, TypeError):
            pass


def _categorical(letters: Any) -> Any:
    """A condition column handed back as its letters' bytes (uint8) as a pandas
    Categorical: three letters a million times over, a byte a row and no Python object per
    row (and :func:`calibrate` hands it back over as its codes)."""
    import pandas as pd

    if not (isinstance(letters, np.ndarray) and letters.dtype == np.uint8):
        return letters
    present = np.flatnonzero(np.bincount(letters, minlength=256))
    lut = np.zeros(256, dtype=np.int8)
    lut[present] = np.arange(len(present))
    return pd.Categorical.from_codes(lut[letters], categories=[chr(c) for c in present])


def _frame(pairs, meta, extra=None):
    """A DataFrame of (name, values) pairs, with the metadata in ``attrs["rotacal"]``."""
    import pandas as pd

    df = pd.DataFrame({name: _categorical(v) if name == "condition" else v for name, v in pairs})
    df.attrs["rotacal"] = dict(meta)
    return df


def simulate(config: str, seed: Optional[int] = None):
    """Simulate the experiment (``rotacal simulate``; docs/simulator.md).

    Parameters
    ----------
    config
        A preset's name (``"paper-10mhz"``, ``"paper-multirate"``,
        ``"metrologia-static"``), a TOML configuration file's path, or TOML text.
    seed
        Replaces the configuration's seed.

    Returns
    -------
    pandas.DataFrame
        The recording the command line writes, read back: the same rows, bit for bit, with
        its metadata (and the simulator's truth keys) in ``attrs["rotacal"]``.
    """
    pairs, meta = _rotacal.simulate(str(config), seed)
    return _frame(pairs, meta)


def apply(calibration: Calibration, data: Any, frame: Optional[str] = None,
          rate_hz: Optional[float] = None, columns: Optional[Mapping[str, str]] = None,
          metadata: Optional[Mapping[str, Any]] = None):
    """:meth:`Calibration.apply`."""
    if frame is None:
        entry = calibration._entry(rate_hz)
        frame = "platter" if (entry.get("correction") or {}).get("platter_frame") else "device"
    if isinstance(data, (str, os.PathLike)):
        data = read_recording(data)
    pairs, meta, source = _table(data, columns, metadata)
    command = _command("Calibration.apply", data, {"frame": frame, "rate_hz": rate_hz})
    try:
        out, out_meta = _rotacal.apply_columns(
            calibration.to_json(), "the calibration", pairs, list(meta.items()), source,
            frame, rate_hz, command,
        )
    except _rotacal.RecordingError as e:
        _label_row(e, data)
        raise
    return _frame(out, out_meta)


class Discrepancy:
    """The discrepancy workflow's analysis: what ``rotacal discrepancy --json`` writes
    (docs/discrepancy.md, docs/formats.md), with its verdict at hand.

    Attributes
    ----------
    explained : bool
        Whether the model with the effects it named explains the data (the command line
        exits with status 4 where it does not).
    summary : str
        The verdict in a sentence.
    """

    def __init__(self, text: str):
        import json

        self._text = text
        self._data = json.loads(text)
        verdict = self._data.get("verdict", {})
        self.explained: bool = bool(verdict.get("explained"))
        self.summary: str = verdict.get("summary", "")
        self.traceability: dict = self._data.get("traceability", {})

    def to_json(self) -> str:
        """The analysis JSON, as the command line writes it."""
        return self._text

    def as_dict(self) -> dict:
        """The analysis as Python objects."""
        import json

        return json.loads(self._text)

    def __repr__(self) -> str:
        return f"<rotacal.Discrepancy explained={self.explained}: {self.summary}>"


def discrepancy(
    data: Data,
    g_loc: Optional[float] = None,
    rate_hz: Optional[float] = None,
    alpha: Optional[float] = None,
    slow_noise: bool = False,
    columns: Optional[Mapping[str, str]] = None,
    metadata: Optional[Mapping[str, Any]] = None,
) -> Discrepancy:
    """Where model and measurement disagree, and which effect explains it (``rotacal
    discrepancy``; docs/discrepancy.md): a rotation recording as a path, a DataFrame or
    arrays, as for :func:`calibrate`.

    Parameters
    ----------
    g_loc, rate_hz
        Override the metadata's.
    alpha
        Significance of each effect's F-test (default: the command line's, 0.001).
    slow_noise
        Count flicker and a bias random walk, estimated from the data, in every test.

    Returns
    -------
    Discrepancy
        Whether it is explained is ``.explained``; nothing is raised when it is not.

    Raises
    ------
    RecordingError, DiscrepancyError
    """
    opts = {"g_loc": g_loc, "rate_hz": rate_hz, "alpha": alpha, "slow_noise": slow_noise}
    command = _command("discrepancy", data, opts)
    if isinstance(data, (str, os.PathLike)):
        if columns is not None or metadata is not None:
            raise TypeError("columns= and metadata= are for DataFrames and arrays, not files")
        return Discrepancy(_rotacal.discrepancy_path(os.fspath(data), opts, command))
    pairs, meta, source = _table(data, columns, metadata)
    try:
        text = _rotacal.discrepancy_columns(pairs, list(meta.items()), source, opts, command)
    except _rotacal.RecordingError as e:
        _label_row(e, data)
        raise
    return Discrepancy(text)


def write_recording(data: Any, path: Union[str, "os.PathLike[str]"],
                    columns: Optional[Mapping[str, str]] = None, **metadata: Any) -> None:
    """Write a DataFrame or arrays as a recording CSV (docs/formats.md) that ``rotacal``
    reads back exactly, checked as the reader checks a file, whole or not at all (a
    temporary file renamed into place).

    Parameters
    ----------
    data
        A pandas or polars DataFrame or a mapping of arrays, columns named as in
        docs/formats.md or mapped with ``columns``.
    path
        The file to write.
    **metadata
        The ``# key=value`` lines (``method``, ``rate_hz``, ``g_loc``, ``units``,
        ``device``, ...), over ``df.attrs["rotacal"]``.

    Raises
    ------
    RecordingError
        The data are not a recording: ``column`` and ``row`` say where.
    """
    pairs, meta, source = _table(data, columns, metadata)
    try:
        _rotacal.write_columns(pairs, list(meta.items()), source, os.fspath(path))
    except _rotacal.RecordingError as e:
        _label_row(e, data)
        raise


class Allan:
    """The overlapping Allan deviation of each still record and channel of a recording,
    with 1σ intervals and the fitted IEEE noise terms N, B, K: what ``rotacal allan
    --json`` writes (docs/allan.md, docs/formats.md "Allan JSON")."""

    def __init__(self, text: str):
        import json

        self._text = text
        self._data = json.loads(text)
        self.units: str = self._data.get("units", "")
        self.traceability: dict = self._data.get("traceability", {})

    def to_json(self) -> str:
        """The Allan JSON, as the command line writes it."""
        return self._text

    def as_dict(self) -> dict:
        """The analysis as Python objects."""
        import json

        return json.loads(self._text)

    def points(self):
        """Every point as a pandas DataFrame: record, channel, tau_s, m, n, adev and the 1σ
        interval's bounds (``lo``, ``hi``; NaN where there is none), in ``units``."""
        import pandas as pd

        rows = []
        for g in self._data["groups"]:
            for c in g["channels"]:
                for p in c["points"]:
                    iv = p.get("interval") or {}
                    rows.append({
                        "record": g["name"], "channel": c["channel"], "tau_s": p["tau_s"],
                        "m": p["m"], "n": p["n"], "adev": p["adev"],
                        "lo": iv.get("lo", np.nan), "hi": iv.get("hi", np.nan),
                    })
        return pd.DataFrame(rows)

    def __repr__(self) -> str:
        return f"<rotacal.Allan {len(self._data['groups'])} records, units {self.units}>"


def allan(data: Data, from_s: Optional[float] = None, to_s: Optional[float] = None,
          columns: Optional[Mapping[str, str]] = None,
          metadata: Optional[Mapping[str, Any]] = None) -> Allan:
    """The Allan deviation of each still record of a recording (``rotacal allan``;
    docs/allan.md): a path, a DataFrame or arrays, as for :func:`calibrate`.

    Parameters
    ----------
    from_s, to_s
        Use only samples at ``from_s ≤ t_s ≤ to_s`` (device time).

    Raises
    ------
    RecordingError
        The data cannot be read.
    ValueError
        A record cannot be analysed (a gap, too few samples): the message says which.
    """
    command = _command("allan", data, {"from_s": from_s, "to_s": to_s})
    if isinstance(data, (str, os.PathLike)):
        if columns is not None or metadata is not None:
            raise TypeError("columns= and metadata= are for DataFrames and arrays, not files")
        return Allan(_rotacal.allan(os.fspath(data), [], [], "", from_s, to_s, command))
    pairs, meta, source = _table(data, columns, metadata)
    try:
        text = _rotacal.allan(None, pairs, list(meta.items()), source, from_s, to_s, command)
    except _rotacal.RecordingError as e:
        _label_row(e, data)
        raise
    return Allan(text)
