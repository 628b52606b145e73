"""Shared fixtures: the command line to compare with, the repository's test data, and a
check that the package under test is the installed wheel, not the source folder."""

import json
import os
import subprocess
from pathlib import Path

import pytest

import rotacal

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "host" / "tests" / "data"


def pytest_configure(config):
    where = Path(rotacal.__file__).resolve()
    assert "site-packages" in where.parts, f"rotacal imported from {where}, not the wheel"


@pytest.fixture(scope="session")
def cli():
    """Run the rotacal command line; returns its stdout (it must succeed)."""
    exe = os.environ.get("ROTACAL_BIN", str(ROOT / "target" / "release" / "rotacal"))

    def run(*args):
        done = subprocess.run([exe, *map(str, args)], capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
        return done.stdout

    return run


@pytest.fixture(scope="session")
def sessions(cli, tmp_path_factory):
    """The parity inputs, as recordings: the demo's session (through the firmware's logic
    and its packets), imucal's six-position session (imported as docs/calibration.md
    shows) and imu_tk's free session (as it ships)."""
    d = tmp_path_factory.mktemp("sessions")
    cli("demo", "--out", d / "demo")
    cli(
        "import", DATA / "imucal-ferraris" / "example_ferraris_session.csv",
        "--columns", "t=0,u=4,v=5,w=6", "--skip", "1", "--time-scale", "0.009765625",
        "--sample-rate-hz", "102.4", "--g-loc", "9.81", "--units", "m/s^2",
        "--sections", DATA / "imucal-ferraris" / "example_ferraris_session_list.json",
        "--poses", "x_p=+x,x_a=-x,y_p=+y,y_a=-y,z_p=+z,z_a=-z",
        "--out", d / "imucal.csv",
    )
    return {
        "demo": d / "demo" / "recording.csv",
        "imucal": d / "imucal.csv",
        "imutk": DATA / "imutk-xsens" / "xsens_acc_free.csv",
    }


def calibrate_cli(cli, path, out):
    """`rotacal calibrate PATH --json OUT`: the JSON's text."""
    cli("calibrate", path, "--json", out)
    return Path(out).read_text()


def without(d, keys):
    """`d` (parsed JSON) without `keys` anywhere in it."""
    if isinstance(d, dict):
        return {k: without(v, keys) for k, v in d.items() if k not in keys}
    if isinstance(d, list):
        return [without(v, keys) for v in d]
    return d


def same(a, b):
    """Parsed JSONs equal bit for bit: every float compared by its bits, via repr."""
    return json.dumps(a, sort_keys=False) == json.dumps(b, sort_keys=False)
