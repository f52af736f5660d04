"""Datasets: loading real data, frames as NumPy views, arrays in, and bad input."""

import gc
import shutil

import numpy as np
import pytest

import fpm
from conftest import USAF


def test_real_usaf_set_loads_with_its_parameters(usaf):
    assert len(usaf) == 121
    assert usaf.system["wavelength_um"] == pytest.approx(0.626)
    assert usaf.geometry["rows"] == 11 and usaf.geometry["cols"] == 11
    assert len(usaf.leds) == len(usaf.exposure_ms) == len(usaf.defocus_um) == 121
    assert (5, 5) in usaf.leds


def test_a_full_frame_behind_a_ring_array_loads():
    ring = fpm.Dataset.load(USAF.parent / "thuhololab-ring93")
    assert ring.geometry["rings"] == [1, 8, 12, 16, 24, 32]
    assert len(ring) == 93 and ring.leds[1] == (1, 0) and ring.leds[-1] == (5, 31)
    assert ring.frame(0).shape == (1024, 1024) and ring.frame(0).dtype == np.uint8


def test_frames_are_read_only_views_not_copies(usaf):
    a, b = usaf.frame(0), usaf.frames[0]
    assert a.dtype == np.uint8 and a.shape == (128, 128)
    assert np.shares_memory(a, b), "two views of one frame must share its memory"
    assert not a.flags.writeable
    with pytest.raises(ValueError):
        a[0, 0] = 1
    assert np.array_equal(usaf.frame(-1), usaf.frames[120])
    with pytest.raises(IndexError, match="121 frames"):
        usaf.frame(121)


def test_a_view_keeps_its_dataset_alive():
    reference = fpm.Dataset.load(USAF).frame(3).astype(np.int64).sum()
    view = fpm.Dataset.load(USAF).frame(3)  # the dataset itself is dropped at once
    gc.collect()
    assert view.astype(np.int64).sum() == reference
    assert reference > 0


def test_arrays_in_save_and_load_back(usaf, tmp_path):
    frames = np.stack(usaf.frames).astype(np.uint16) * 3
    ds = fpm.Dataset.from_arrays(
        frames,
        usaf.leds,
        usaf.system,
        usaf.geometry,
        exposure_ms=usaf.exposure_ms,
        dark_level=2.0,
    )
    assert len(ds) == 121 and ds.frame(5).dtype == np.uint16
    ds.save(tmp_path / "copy")
    back = fpm.Dataset.load(tmp_path / "copy")
    assert back.leds == usaf.leds
    assert back.dark_level == 2.0
    for k in (0, 60, 120):
        assert np.array_equal(back.frame(k), frames[k])


def test_a_display_gamma_is_stated_kept_and_checked(usaf, tmp_path):
    # The vendored frames were saved for viewing: the dataset says how to decode them.
    assert usaf.gamma == pytest.approx(2.2)
    frames = list(usaf.frames[:3])
    ds = fpm.Dataset.from_arrays(
        frames, usaf.leds[:3], usaf.system, usaf.geometry, bit_depth=8, gamma=2.2
    )
    ds.save(tmp_path / "copy")
    assert fpm.Dataset.load(tmp_path / "copy").gamma == pytest.approx(2.2)
    linear = fpm.Dataset.from_arrays(frames, usaf.leds[:3], usaf.system, usaf.geometry)
    assert linear.gamma is None
    with pytest.raises(fpm.DatasetError, match=r"camera\.gamma.*bit_depth"):
        fpm.Dataset.from_arrays(frames, usaf.leds[:3], usaf.system, usaf.geometry, gamma=2.2)


def test_arrays_never_borrow_a_truth_from_the_working_directory(acquisition, monkeypatch):
    # A simulated set's truth sits in its directory; a dataset made from its arrays
    # has no directory, so it must not be scored against that truth.
    ds, _ = acquisition
    monkeypatch.chdir(ds.dir)
    copy = fpm.Dataset.from_arrays(
        ds.frames, ds.leds, ds.system, ds.geometry, exposure_ms=ds.exposure_ms, dark_level=ds.dark_level
    )
    assert str(copy.dir) == "<in memory>"
    assert fpm.reconstruct(ds, passes=1).report.get("versus_truth") is not None
    assert fpm.reconstruct(copy, passes=1).report.get("versus_truth") is None


def test_float_frames_stay_float(usaf):
    frames = [f.astype(np.float64) / 255.0 for f in usaf.frames[:3]]
    ds = fpm.Dataset.from_arrays(frames, usaf.leds[:3], usaf.system, usaf.geometry)
    assert ds.frame(0).dtype == np.float32
    assert np.allclose(ds.frame(2), frames[2], atol=1e-6)


def test_missing_dataset_names_the_manifest(tmp_path):
    with pytest.raises(fpm.DatasetError, match="dataset.toml"):
        fpm.Dataset.load(tmp_path / "nowhere")


def test_bad_key_is_named_with_its_value(tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(USAF, bad)
    toml = (bad / "dataset.toml").read_text()
    (bad / "dataset.toml").write_text(toml.replace("na = 0.1", "na = 1.5", 1))
    with pytest.raises(fpm.DatasetError, match=r"system\.na.*1\.5"):
        fpm.Dataset.load(bad)


def test_missing_frame_file_is_named(tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(USAF, bad)
    victim = bad / "frames" / "img_008.tif"
    victim.unlink()
    with pytest.raises(fpm.DatasetError, match=r"frame 7 \(frames/img_008\.tif\)"):
        fpm.Dataset.load(bad)


def test_bad_arrays_are_named(usaf):
    frames = list(usaf.frames[:3])
    with pytest.raises(ValueError, match="leds: 2 LEDs for 3 frames"):
        fpm.Dataset.from_arrays(frames, usaf.leds[:2], usaf.system, usaf.geometry)
    with pytest.raises(fpm.DatasetError, match="frame 1"):
        fpm.Dataset.from_arrays(
            [frames[0], frames[1][:64]], usaf.leds[:2], usaf.system, usaf.geometry
        )
    with pytest.raises(ValueError, match=r"frames\[0\].*2-D"):
        fpm.Dataset.from_arrays(
            [np.zeros((2, 8, 8))], usaf.leds[:1], usaf.system, usaf.geometry
        )
    nan = np.full((16, 16), np.nan, dtype=np.float32)
    with pytest.raises(fpm.DatasetError, match="non-finite"):
        fpm.Dataset.from_arrays([nan], usaf.leds[:1], usaf.system, usaf.geometry)
    with pytest.raises(ValueError, match="system.*wavelength_um"):
        fpm.Dataset.from_arrays(frames, usaf.leds[:3], {"na": 0.1}, usaf.geometry)
    with pytest.raises(ValueError, match="entrance_pupil_mm"):
        fpm.Dataset.from_arrays(
            frames, usaf.leds[:3], dict(usaf.system, entrance_pupil_mm=0.0), usaf.geometry
        )
    with pytest.raises(ValueError, match="exposure_ms: 2 values for 3 frames"):
        fpm.Dataset.from_arrays(
            frames, usaf.leds[:3], usaf.system, usaf.geometry, exposure_ms=[1, 2]
        )
