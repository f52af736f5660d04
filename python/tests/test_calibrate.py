"""Calibration from Python: the truth within the reported uncertainty, and the same
numbers as the fpm command."""

import json
import subprocess

import pytest

import fpm

TRUTH = dict(dx_mm=1.3, dy_mm=-0.7, theta_deg=3.0, height_mm=90.0)


@pytest.fixture(scope="module")
def calibration_set(tmp_path_factory):
    out = tmp_path_factory.mktemp("calibration")
    ds, truth = fpm.simulate_calibration(out, seed=11, **TRUTH)
    return out, ds, truth


def test_simulated_calibration_finds_the_hidden_array(calibration_set):
    _, ds, truth = calibration_set
    assert truth["dx_mm"] == TRUTH["dx_mm"]
    assert ds.geometry["dx_mm"] == 0.0, "the dataset states only the nominal array"
    cal = fpm.calibrate(ds)
    sigma = cal.uncertainty
    for key in ("dx_mm", "dy_mm", "theta_deg", "height_mm"):
        value = getattr(cal, key)
        assert sigma[key] > 0
        assert abs(value - truth[key]) <= 3 * sigma[key], (key, value, sigma[key])
    assert abs(cal.dx_mm - truth["dx_mm"]) < 0.01
    assert not [w for w in cal.warnings if "uncertain" in w], cal.warnings
    assert len(cal.leds) >= 6 and "status" in cal.leds[0]
    assert cal.geometry["dx_mm"] == cal.dx_mm and cal.geometry["rows"] == 21
    assert "Calibration(dx_mm=" in repr(cal)


def test_a_hard_case_says_it_cannot_be_trusted(tmp_path):
    # A 20 µm feature off the axis at a small defocus: the lateral accuracy target is
    # out of reach, and the calibration must say so rather than look confident.
    ds, truth = fpm.simulate_calibration(
        tmp_path, seed=3, feature_um=20.0, feature_at_um=(30.0, 20.0), defocus_um=100.0, **TRUTH
    )
    cal = fpm.calibrate(ds)
    assert any(w.startswith("Δx, Δy are uncertain") for w in cal.warnings), cal.warnings
    assert abs(cal.dx_mm - truth["dx_mm"]) <= 3 * cal.uncertainty["dx_mm"]


def test_same_numbers_as_the_command(calibration_set, fpm_cli, tmp_path):
    out, ds, _ = calibration_set
    cal = fpm.calibrate(ds)
    cal.save(tmp_path / "python.json")
    saved = json.loads((tmp_path / "python.json").read_text())
    subprocess.run(
        [fpm_cli, "calibrate", str(out), "--out", str(tmp_path / "cli.json")],
        check=True,
        capture_output=True,
    )
    cli = json.loads((tmp_path / "cli.json").read_text())
    for key in ("dx_mm", "dy_mm", "theta_deg", "height_mm", "uncertainty"):
        assert saved[key] == cli[key], key


def test_a_frame_without_the_feature_warns_or_fails(usaf):
    # The USAF set is an in-focus acquisition, not a defocus calibration set.
    with pytest.raises(fpm.FpmError):
        fpm.calibrate(usaf)


def test_bad_options_are_refused(calibration_set):
    _, ds, _ = calibration_set
    with pytest.raises(ValueError, match="roi"):
        fpm.calibrate(ds, roi=(0, 0, 0, 10))
    with pytest.raises(ValueError, match="defocus_sigma_um"):
        fpm.calibrate(ds, defocus_sigma_um=-1.0)


def test_a_hand_built_boards_own_scatter_is_measured_and_named(calibration_set, tmp_path):
    # Each LED off its grid by σ 0.25 mm per axis: the calibration measures every LED's
    # own place (offset_mm) and names the scatter; the rigid board of the module's set
    # reads a few µm.
    ds, truth = fpm.simulate_calibration(tmp_path, seed=11, led_jitter_mm=0.25, **TRUTH)
    assert len(truth["leds"]) == 25, "the truth lists where the calibration's LEDs were"
    scattered = fpm.calibrate(ds)
    rigid = fpm.calibrate(calibration_set[1])

    def offsets_rms(cal):
        offsets = [l["offset_mm"] for l in cal.leds if l.get("offset_mm") is not None]
        assert len(offsets) >= 20, cal.leds
        return (sum(x * x + y * y for x, y in offsets) / (2 * len(offsets))) ** 0.5

    assert offsets_rms(scattered) > 0.15, offsets_rms(scattered)
    assert offsets_rms(rigid) < 0.02, offsets_rms(rigid)
    assert any("sit off a rigid board" in w for w in scattered.warnings), scattered.warnings
    assert not any("sit off a rigid board" in w for w in rigid.warnings), rigid.warnings
    with pytest.raises(fpm.FpmError, match="led_jitter_mm"):
        fpm.simulate_calibration(tmp_path / "bad", led_jitter_mm=-1.0)
