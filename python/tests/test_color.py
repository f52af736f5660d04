"""Colour from Python: `fpm.reconstruct` of a colour dataset gives every channel and
the registered colour image, as `fpm reconstruct` does."""

import json
import subprocess

import numpy as np
import tifffile

import fpm


def test_a_colour_dataset_reconstructs_to_its_channels_as_the_command_does(fpm_cli, tmp_path):
    path, truths = fpm.simulate_color_acquisition(
        tmp_path / "rgb", size=48, spectral_samples=1, sample="stained"
    )
    assert sorted(truths) == ["blue", "green", "red"]
    # The simulator's dies: red's 0.7 mm toward −x of green's, blue's toward +x.
    assert truths["red"]["dx_mm"] < truths["green"]["dx_mm"] < truths["blue"]["dx_mm"]
    res = fpm.reconstruct(path, passes=5)
    assert isinstance(res, fpm.ColorResult)
    assert res.names == ["red", "green", "blue"]
    assert res.wavelengths_um == sorted(res.wavelengths_um, reverse=True)
    c, h, w = res.amplitude.shape
    assert (c, h, w) == (3, 192, 192) and res.phase.shape == (3, 192, 192)
    assert res.rgb.shape == (192, 192, 3) and res.rgb.dtype == np.uint8
    # A stained sample: the dye absorbs green most, red least.
    mean = res.rgb.reshape(-1, 3).mean(axis=0)
    assert mean[0] > mean[1], mean
    channels = res.channels
    assert set(channels) == {"red", "green", "blue"}
    for name, r in channels.items():
        score = r.report["versus_truth"]["complex_nrmse"]
        assert score < 0.6, (name, score)
    report = res.report
    assert [ch["name"] for ch in report["channels"]] == res.names
    # The same numbers as the command.
    out = tmp_path / "out"
    subprocess.run(
        [fpm_cli, "reconstruct", str(path), "--out", str(out), "--passes", "5"],
        check=True,
        capture_output=True,
    )
    cli = json.loads((out / "report.json").read_text())
    for mine, theirs in zip(report["channels"], cli["channels"]):
        assert mine["versus_truth"]["complex_nrmse"] == theirs["versus_truth"]["complex_nrmse"]
    with tifffile.TiffFile(out / "amplitude.tif") as tif:
        assert tif.is_ome
        stack = tif.asarray()
    assert stack.shape == (3, 192, 192)
    np.testing.assert_allclose(stack, res.amplitude, atol=1e-6)
    res.save(tmp_path / "saved")
    assert (tmp_path / "saved" / "color.png").is_file()
    assert (tmp_path / "saved" / "red" / "amplitude.tif").is_file()
    # OME-Zarr: the amplitudes, then the phases, each channel named.
    import zarr

    res.save(tmp_path / "zarr", format="ome-zarr")
    group = zarr.open_group(tmp_path / "zarr" / "image.ome.zarr", mode="r")
    labels = [c["label"] for c in group.attrs["omero"]["channels"]]
    assert labels == [f"{what} {c}" for what in ("amplitude", "phase") for c in res.names]
    full = group["0"][:]
    assert full.shape == (6, 192, 192)
    np.testing.assert_array_equal(full[:3], res.amplitude)
    np.testing.assert_array_equal(full[3:], res.phase)
