"""imucal interoperability (issue 35, proof point 3), checked against imucal 2.6 itself:
a rotacal calibration written as imucal's JSON loads in imucal and corrects imucal's
example session to the m/s² values of `rotacal apply`; imucal's own calibration of that
session, read from its JSON, agrees with rotacal's within U."""

import numpy as np
import pandas as pd
import pytest
from imucal import CalibrationInfo, FerrarisCalibration, ferraris_regions_from_section_list
from imucal.ferraris_calibration_info import FerrarisCalibrationInfo

import rotacal
from conftest import DATA

SESSION = DATA / "imucal-ferraris"


def test_a_rotacal_calibration_corrects_in_imucal_as_rotacal_apply(sessions, cli, tmp_path):
    cal = rotacal.calibrate(str(sessions["imucal"]))
    info = CalibrationInfo.from_json(cal.to_imucal())
    assert isinstance(info, FerrarisCalibrationInfo)
    # rotacal apply, in the frame the imucal file carries (the poses').
    (tmp_path / "cal.json").write_text(cal.to_json())
    cli("apply", tmp_path / "cal.json", sessions["imucal"], "--frame", "platter",
        "--out", tmp_path / "ms2.csv")
    ours = rotacal.read_recording(tmp_path / "ms2.csv")[["u", "v", "w"]].to_numpy()
    # imucal on the same readings (the session's pose rows, as imported).
    raw = rotacal.read_recording(sessions["imucal"])[["u", "v", "w"]].to_numpy()
    gyr = np.random.default_rng(0).normal(size=raw.shape)
    acc, gyr_out = info.calibrate(raw, gyr, acc_unit="m/s^2", gyr_unit="deg/s")
    err = np.abs(acc - ours).max(axis=1) / np.linalg.norm(ours, axis=1)
    assert err.max() <= 1e-9, err.max()
    assert len(raw) == 3428
    # The gyroscope's readings pass through unchanged.
    assert np.array_equal(gyr_out, gyr)
    assert "Not carried: the uncertainties" in info.comment


def test_imucal_s_own_calibration_agrees_within_u(sessions, tmp_path):
    # imucal's Ferraris calibration of its example session, as its examples compute it.
    data = pd.read_csv(SESSION / "example_ferraris_session.csv", header=0, index_col=0)
    sections = pd.read_json(SESSION / "example_ferraris_session_list.json").T
    regions = ferraris_regions_from_section_list(data, sections)
    theirs = FerrarisCalibration(grav=9.81).compute(
        regions, sampling_rate_hz=102.4, from_acc_unit="m/s^2", from_gyr_unit="deg/s"
    )
    (tmp_path / "imucal.json").write_text(theirs.to_json())
    read = rotacal.read_imucal(tmp_path / "imucal.json")
    assert np.array_equal(read.K_a, theirs.K_a) and np.array_equal(read.b_a, theirs.b_a)
    cal = rotacal.calibrate(str(sessions["imucal"]))
    table = cal.compare_imucal(read)
    print(table)
    assert list(table.index) == ["s_u", "s_v", "s_w", "φ_uv", "φ_vw", "φ_wu", "O_u", "O_v", "O_w"]
    assert table["within_U"].all(), table
    # With imucal's estimator (equal weights, offsets from each axis's pair) the two are one
    # computation: equal to rounding.
    same = rotacal.calibrate(str(sessions["imucal"]), pose_weights="equal", offsets="axis-pairs")
    t = same.compare_imucal(read)
    assert (t["difference"].abs() <= 1e-12 * t["rotacal"].abs().clip(lower=1)).all(), t


def test_what_is_not_imucal_is_refused(tmp_path):
    with pytest.raises(ValueError, match="format version"):
        rotacal.read_imucal('{"cal_type": "Ferraris", "K_a": []}')
    with pytest.raises(ValueError, match="cal_type"):
        rotacal.read_imucal('{"_format_version": "2.0.0", "cal_type": "Magic"}')
    with pytest.raises(ValueError, match="K_a has shape"):
        rotacal.read_imucal('{"_format_version": "2.0.0", "cal_type": "Ferraris", '
                            '"K_a": [1, 2], "R_a": [[1,0,0],[0,1,0],[0,0,1]], "b_a": [0,0,0]}')


def test_the_migration_in_docs_python_md_runs_as_written(sessions, monkeypatch):
    doc = (DATA.parents[2] / "docs" / "python.md").read_text()
    after = doc.split("An imucal user's migration", 1)[1].split("\n\n", 2)[1]
    code = "\n".join(line[4:] for line in after.splitlines())
    monkeypatch.chdir(SESSION)
    scope = {}
    exec(compile(code, "docs/python.md", "exec"), scope)
    cal, info = scope["cal"], scope["info"]
    assert isinstance(info, FerrarisCalibrationInfo)
    # The same poses as the worked example's import: the same values, bit for bit.
    imported = rotacal.calibrate(str(sessions["imucal"])).properties()
    assert cal.properties()["value"].equals(imported["value"])
    assert cal.properties()["U"].equals(imported["U"])
