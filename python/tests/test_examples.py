"""The examples run top to bottom, as a user would run them."""

import subprocess
import sys

import tifffile

from conftest import REPO


def test_python_session_runs(tmp_path):
    run = subprocess.run(
        [sys.executable, str(REPO / "examples" / "python_session.py"), str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr
    assert "calibrated" in run.stdout and "Δx =" in run.stdout
    assert tifffile.imread(tmp_path / "usaf" / "amplitude.tif").shape == (512, 512)
