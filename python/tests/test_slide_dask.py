"""examples/slide_dask.py on a local Dask cluster (2 workers, everything on
127.0.0.1): every field's output equals a direct run, and a second run skips them."""

import json
import subprocess
import sys

import numpy as np
import pytest
import tifffile

import fpm
from conftest import REPO

EXAMPLE = REPO / "examples" / "slide_dask.py"


@pytest.fixture(scope="module")
def slide(tmp_path_factory):
    root = tmp_path_factory.mktemp("slide")
    for seed in (1, 2, 3):
        fpm.simulate_acquisition(root / f"field_{seed}", size=64, seed=seed)
    return root


def run_example(slide, out):
    run = subprocess.run(
        [sys.executable, str(EXAMPLE), str(slide), str(out), "--workers", "2", "--passes", "3", "--json"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


def test_fields_on_a_local_cluster_match_direct_runs(slide, tmp_path):
    out = tmp_path / "results"
    summary = run_example(slide, out)
    assert summary["workers"] == 2
    # The scheduler, both workers and the dashboard: loopback only.
    assert len(summary["addresses"]) == 4
    for address in summary["addresses"]:
        assert address.split("://")[1].startswith("127.0.0.1:"), address
    assert (summary["done"], summary["skipped"], summary["failed"]) == (3, 0, 0)
    for seed in (1, 2, 3):
        direct = fpm.reconstruct(fpm.Dataset.load(slide / f"field_{seed}"), passes=3)
        field = out / f"field_{seed}"
        assert np.array_equal(tifffile.imread(field / "amplitude.tif"), direct.amplitude)
        assert np.array_equal(tifffile.imread(field / "phase.tif"), direct.phase)
        assert (field / "report.json").is_file()
    again = run_example(slide, out)
    assert (again["done"], again["skipped"]) == (0, 3)


def test_a_scans_fields_on_workers_are_what_fpm_stitch_joins(fpm_cli, tmp_path):
    # A simulated 1 × 2 scan: its fields reconstructed on the cluster into their own
    # reconstruction/, then joined by `fpm stitch`, which reads them back.
    scan = tmp_path / "scan"
    subprocess.run(
        [fpm_cli, "simulate", "scan", "--out", str(scan), "--fields", "1x2", "--size", "64",
         "--magnification", "2", "--leds", "5", "--overlap", "0.4", "--stage-error-um", "5"],
        check=True,
        capture_output=True,
    )
    run = subprocess.run(
        [sys.executable, str(EXAMPLE), str(scan), "--workers", "2", "--passes", "3",
         "--upsample", "2", "--json"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout)["done"] == 2
    written = {
        f: (scan / "fields" / f / "reconstruction" / "amplitude.tif").stat().st_mtime_ns
        for f in ("r0c0", "r0c1")
    }
    stitched = subprocess.run(
        [fpm_cli, "stitch", str(scan), "--json"], capture_output=True, text=True, check=True
    )
    report = json.loads(stitched.stdout)
    assert [f["dataset"] for f in report["fields"]] == ["fields/r0c0", "fields/r0c1"]
    assert (scan / "mosaic" / "mosaic.zarr" / ".zattrs").is_file()
    # Read back, not reconstructed again.
    for f, mtime in written.items():
        assert (scan / "fields" / f / "reconstruction" / "amplitude.tif").stat().st_mtime_ns == mtime
    # Not a scan and no OUT_ROOT: said, not guessed.
    bare = subprocess.run(
        [sys.executable, str(EXAMPLE), str(tmp_path)], capture_output=True, text=True, timeout=600
    )
    assert bare.returncode != 0 and "OUT_ROOT" in bare.stderr, bare.stderr
