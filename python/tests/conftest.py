"""Shared fixtures: the repository's real data and simulated datasets (made once per
test session with the package's own simulator, the full wave-optics model)."""

import os
import subprocess
from pathlib import Path

import pytest

import fpm

REPO = Path(__file__).resolve().parents[2]
USAF = REPO / "data" / "zuo-usaf-11x11"


@pytest.fixture(scope="session")
def usaf() -> fpm.Dataset:
    """The repository's real USAF acquisition (121 LEDs, 128² 8-bit frames)."""
    return fpm.Dataset.load(USAF)


@pytest.fixture(scope="session")
def fpm_cli():
    """The `fpm` command built from the same crates (set by the Rust test that runs
    this suite), for comparisons; tests that need it skip without it."""
    path = os.environ.get("FPM_BIN")
    if not path:
        pytest.skip("FPM_BIN not set: no fpm command to compare with")
    return path


@pytest.fixture(scope="session")
def acquisition(tmp_path_factory):
    """A simulated 64² acquisition of 441 LEDs with the array 1 mm, 1 mm off and
    turned 5° (the dataset states the nominal array): (dataset, truth)."""
    out = tmp_path_factory.mktemp("acquisition")
    return fpm.simulate_acquisition(out, size=64, seed=7)


@pytest.fixture(scope="session")
def placement(acquisition):
    """Where the simulated array really is, as a placement dict."""
    _, truth = acquisition
    return {k: truth[k] for k in ("dx_mm", "dy_mm", "theta_deg", "height_mm")}


# The acquisition service (`fpm serve --virtual`) for the client and napari tests.

def _serve(fpm_cli, state, size=None, rig=()):
    """`fpm serve --virtual` with a size² camera (or on the rig `rig` names), its
    client; stopped after."""
    on = ["--virtual", "--virtual-size", str(size)] if size else list(rig)
    process = subprocess.Popen(
        [fpm_cli, "serve", *on, "--listen", "127.0.0.1:0", "--state-dir", str(state)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        first = process.stdout.readline()
        assert first.startswith("fpm serve: listening on http://"), first
        address = first.strip().removeprefix("fpm serve: listening on http://")
        yield fpm.Client(address, state_dir=state)
    finally:
        process.terminate()
        process.wait(timeout=30)


@pytest.fixture()
def service(fpm_cli, tmp_path):
    yield from _serve(fpm_cli, tmp_path / "state", 64)


@pytest.fixture()
def calibratable(fpm_cli, tmp_path):
    """A rig whose camera is large enough for the calibration's defocused feature."""
    yield from _serve(fpm_cli, tmp_path / "state", 192)
