"""`fpm.dpc`: DPC from Python gives what `fpm dpc` gives, as NumPy arrays."""

import json
import subprocess

import numpy as np

import fpm


def test_dpc_from_python_matches_the_command(usaf, fpm_cli, tmp_path):
    phase, absorption, report = fpm.dpc(usaf)
    assert phase.shape == absorption.shape == usaf.frame(0).shape
    assert phase.dtype == np.float32
    assert [h["half"] for h in report["halves"]] == ["top", "bottom", "left", "right"]
    # The USAF target is no weak object: the report says so.
    assert any("not weak" in w for w in report["warnings"])
    out = tmp_path / "dpc"
    subprocess.run([fpm_cli, "dpc", str(usaf.dir), "--out", str(out)], check=True, capture_output=True)
    cli = json.loads((out / "dpc.json").read_text())
    assert cli["halves"] == report["halves"]
    import tifffile

    np.testing.assert_allclose(tifffile.imread(out / "phase.tif"), phase, atol=1e-6)
    # A stronger weight holds the phase nearer zero.
    strong, _, _ = fpm.dpc(usaf, reg_phase=1.0)
    assert np.abs(strong).mean() < np.abs(phase).mean()
