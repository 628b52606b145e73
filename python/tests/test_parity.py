"""One engine (issue 35, proof point 1): the package's calibration of a file, and of the
same file as a DataFrame, equal the command line's JSON bit for bit. What may differ is
named: the traceability block (when, by which command, from which input), and for a
DataFrame each pose's or group's `first_line`, which names its row, not a file line."""

import json

import pytest

import rotacal
from conftest import calibrate_cli, same, without


@pytest.mark.parametrize("name", ["demo", "imucal", "imutk"])
def test_a_file_calibrates_as_the_command_line_does(name, sessions, cli, tmp_path):
    path = sessions[name]
    text = calibrate_cli(cli, path, tmp_path / "cli.json")
    ours = rotacal.calibrate(str(path))
    cli_json, our_json = json.loads(text), json.loads(ours.to_json())
    assert same(without(our_json, {"traceability"}), without(cli_json, {"traceability"}))
    # The block says the same of the input, and names the Python call.
    assert our_json["traceability"]["inputs"] == cli_json["traceability"]["inputs"]
    assert our_json["traceability"]["g_loc"] == cli_json["traceability"]["g_loc"]
    assert "rotacal.calibrate(" in our_json["traceability"]["command_line"][1]
    # The command line's JSON goes through Calibration byte for byte.
    assert rotacal.Calibration.from_json(text).to_json() == text


@pytest.mark.parametrize("name", ["demo", "imucal", "imutk"])
def test_a_dataframe_calibrates_as_its_file(name, sessions, cli, tmp_path):
    path = sessions[name]
    cli_json = json.loads(calibrate_cli(cli, path, tmp_path / "cli.json"))
    df = rotacal.read_recording(path)
    ours = json.loads(rotacal.calibrate(df).to_json())
    places = {"traceability", "first_line"}
    assert same(without(ours, places), without(cli_json, places))
    t = ours["traceability"]
    assert t["inputs"][0]["path"] == "the DataFrame"
    assert len(t["inputs"][0]["sha256"]) == 64
    assert t["device"] == cli_json["traceability"]["device"]
    assert t["temperature_c"] == cli_json["traceability"]["temperature_c"]


def test_a_condition_as_category_as_text_or_as_polars_is_the_same(sessions):
    # read_recording gives the condition as a pandas Categorical; as text (pandas' str,
    # numpy's objects, pandas.read_csv's) or a polars column it calibrates the same, digest
    # and all.
    import pandas as pd
    import polars as pl

    df = rotacal.read_recording(sessions["demo"])
    assert str(df["condition"].dtype) == "category"
    want = without(rotacal.calibrate(df).as_dict(), {"date_utc", "command_line"})
    as_text = df.astype({"condition": str})
    as_objects = df.assign(condition=df["condition"].to_numpy(dtype=object))
    as_polars = pl.DataFrame(
        {c: as_text[c].tolist() if c == "condition" else df[c].to_numpy() for c in df.columns}
    )
    # pandas' own reader: one str object for every "x" (each distinct object read once).
    as_csv = pd.read_csv(sessions["demo"], comment="#")[list(df.columns)]
    for other in (as_text, as_objects, as_polars, as_csv):
        got = rotacal.calibrate(other, metadata=df.attrs["rotacal"])
        assert same(without(got.as_dict(), {"date_utc", "command_line"}), want)


def test_the_columns_digest_follows_the_data(sessions):
    df = rotacal.read_recording(sessions["imutk"])
    a = rotacal.calibrate(df).traceability["inputs"][0]["sha256"]
    assert rotacal.calibrate(df.copy()).traceability["inputs"][0]["sha256"] == a
    df.loc[10, "u"] += 1.0
    assert rotacal.calibrate(df).traceability["inputs"][0]["sha256"] != a


def test_numpy_arrays_and_renamed_columns(sessions):
    df = rotacal.read_recording(sessions["imutk"])
    meta = df.attrs["rotacal"]
    want = without(rotacal.calibrate(df).as_dict(), {"traceability"})
    arrays = {"time": df["t_s"].to_numpy(), "ax": df["u"].to_numpy(),
              "ay": df["v"].to_numpy(), "az": df["w"].to_numpy()}
    got = rotacal.calibrate(
        arrays, method=meta["method"], g_loc=float(meta["g_loc"]),
        columns={"t_s": "time", "u": "ax", "v": "ay", "w": "az"},
        metadata={"units": meta["units"], "sample_rate_hz": 100},
    )
    assert same(without(got.as_dict(), {"traceability"}), want)


def test_the_results_as_python_objects(sessions):
    cal = rotacal.calibrate(str(sessions["imucal"]))
    props = cal.properties()
    assert list(props.index) == ["s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu", "O_u", "O_v", "O_w"]
    q = cal.quantity("phi_vw")
    row = cal.as_dict()["by_rate"][0]["intrinsic"]["angle_deg"]["vw"]
    assert (q.value, q.u, q.U, q.k) == (row["value"], row["std_unc"], row["expanded_unc"], row["k"])
    assert q.unit == "deg" and q.U == pytest.approx(q.k * q.u, rel=1e-12)
    budget = cal.budget()
    assert budget.loc["combined u", "O_u"] == props.loc["O_u", "u"]
    c = cal.correction()
    assert c.M.shape == (3, 3) and c.covariance.shape == (12, 12)
    assert list(c.O_u) == list(props.loc[["O_u", "O_v", "O_w"], "u"])


def test_a_polars_dataframe_calibrates_as_pandas_does(sessions):
    import polars as pl

    pdf = rotacal.read_recording(sessions["imucal"])
    text = {"pose"}
    df = pl.DataFrame({c: pdf[c].tolist() if c in text else pdf[c].to_numpy() for c in pdf.columns})
    want = without(rotacal.calibrate(pdf).as_dict(), {"traceability"})
    got = rotacal.calibrate(df, metadata=pdf.attrs["rotacal"])
    assert same(without(got.as_dict(), {"traceability"}), want)
    # polars' null is a NaN in numpy: named with its row.
    bad = df.with_columns(
        pl.when(pl.int_range(pl.len()) == 5).then(None).otherwise(pl.col("u")).alias("u")
    )
    with pytest.raises(rotacal.RecordingError) as e:
        rotacal.calibrate(bad, metadata=pdf.attrs["rotacal"])
    assert (e.value.row, e.value.column) == (5, "u")


def test_the_columns_digest_is_the_documented_one(sessions):
    # docs/formats.md: each name's UTF-8 and a 0 byte; each number's 8 little-endian bytes;
    # each text's UTF-8 and a 0 byte; columns in order.
    import hashlib

    import numpy as np

    df = rotacal.read_recording(sessions["demo"])
    h, n = hashlib.sha256(), 0
    for name in df.columns:
        parts = [name.encode() + b"\0"]
        col = df[name]
        if col.dtype.kind == "f":
            parts.append(np.ascontiguousarray(col.to_numpy(), dtype="<f8").tobytes())
        else:
            parts.append(b"".join(str(v).encode() + b"\0" for v in col))
        for p in parts:
            h.update(p)
            n += len(p)
    t = rotacal.calibrate(df).traceability["inputs"][0]
    assert (t["sha256"], t["bytes"]) == (h.hexdigest(), n)
