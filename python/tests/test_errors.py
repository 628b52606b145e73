"""Bad data (issue 35, proof point 4): each malformed DataFrame raises a Python exception
that names the column and the row; none crashes the interpreter."""

import numpy as np
import pytest

import rotacal


@pytest.fixture()
def df(sessions):
    return rotacal.read_recording(sessions["demo"])


def test_a_missing_column(df):
    with pytest.raises(rotacal.RecordingError) as e:
        rotacal.calibrate(df.drop(columns=["u"]))
    assert (e.value.column, e.value.row) == ("u", None)
    assert "missing column 'u'" in str(e.value)


def test_nan(df):
    df.loc[17, "v"] = np.nan
    with pytest.raises(rotacal.RecordingError) as e:
        rotacal.calibrate(df)
    assert (e.value.column, e.value.row, e.value.line) == ("v", 17, None)
    assert str(e.value) == "the DataFrame: row 17: column v: value is not finite (NaN or infinity)"


def test_wrong_dtype(df):
    df["w"] = df["w"].astype(str)
    df.loc[5, "w"] = "abc"
    with pytest.raises(rotacal.RecordingError) as e:
        rotacal.calibrate(df)
    assert (e.value.column, e.value.row) == ("w", 5)
    assert "'abc' is not a number" in str(e.value)


def test_unsorted_time(df):
    df.loc[9, "t_s"] = 0.0
    with pytest.raises(rotacal.RecordingError) as e:
        rotacal.calibrate(df)
    assert (e.value.column, e.value.row) == ("t_s", 9)
    assert "time went backwards in condition x" in str(e.value)


def test_the_row_is_a_position_and_index_its_label(df):
    df.index = df.index + 1000
    df.loc[1017, "u"] = np.inf
    with pytest.raises(rotacal.RecordingError) as e:
        rotacal.calibrate(df)
    assert (e.value.row, e.value.index) == (17, 1017)


def test_an_unknown_condition_and_unequal_columns(df):
    # read_recording's condition is a Categorical: a new letter is a new category. As
    # text, the same letter is named at the same row.
    as_category = df.copy()
    as_category["condition"] = as_category["condition"].cat.add_categories("q")
    as_category.loc[3, "condition"] = "q"
    as_text = df.copy()
    as_text["condition"] = as_text["condition"].astype(str)
    as_text.loc[3, "condition"] = "q"
    for bad in (as_category, as_text):
        with pytest.raises(rotacal.RecordingError) as e:
            rotacal.calibrate(bad)
        assert (e.value.column, e.value.row) == ("condition", 3)
        assert "unknown condition 'q'" in str(e.value)
    # Python objects: a missing one (pandas' NaN, numpy's None) and a text of two letters,
    # each named at its row.
    columns = {c: df[c].to_numpy() for c in ("t_s", "u", "v", "w")}
    for row, value, shown in ((5, None, "'nan'"), (7, "xx", "'xx'")):
        as_objects = df.assign(condition=df["condition"].to_numpy(dtype=object))
        as_objects.loc[row, "condition"] = value
        objects = df["condition"].to_numpy(dtype=object)
        objects[row] = value
        arrays = dict(columns, condition=objects)
        for bad, named in ((as_objects, shown), (arrays, "''" if value is None else shown)):
            with pytest.raises(rotacal.RecordingError) as e:
                rotacal.calibrate(bad, metadata=df.attrs["rotacal"])
            assert (e.value.column, e.value.row) == ("condition", row)
            assert f"unknown condition {named}" in str(e.value)
    with pytest.raises(rotacal.RecordingError) as e:
        rotacal.calibrate({"condition": ["x"] * 3, "t_s": np.arange(3.0), "u": np.zeros(3),
                           "v": np.zeros(3), "w": np.zeros(2)}, g_loc=9.81, rate_hz=0.1)
    assert e.value.column == "w" and "2 values, but the first column has 3" in str(e.value)


def test_a_file_names_its_line(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("# g_loc=9.8\n# rate_hz=0.01\ncondition,t_s,u,v,w\nx,0,1,2,3\nx,1,1,nope,3\n")
    with pytest.raises(rotacal.RecordingError) as e:
        rotacal.calibrate(str(bad))
    assert (e.value.line, e.value.row, e.value.column) == (5, None, "v")
    with pytest.raises(rotacal.RecordingError) as e:
        rotacal.read_recording(tmp_path / "absent.csv")
    assert "absent.csv: cannot read" in str(e.value)


def test_a_calibration_that_fails_and_bad_options(df):
    df.attrs["rotacal"].pop("g_loc")
    with pytest.raises(rotacal.CalibrationError) as e:
        rotacal.calibrate(df)
    assert "local gravity" in str(e.value) or "g_loc" in str(e.value)
    with pytest.raises(TypeError, match="unexpected keyword argument 'rate'"):
        rotacal.calibrate(df, rate=0.01)
    with pytest.raises(ValueError, match="pose_weights"):
        rotacal.calibrate(df, g_loc=9.81, pose_weights="heavy")
    with pytest.raises(TypeError, match="data: a path"):
        rotacal.calibrate(42)
