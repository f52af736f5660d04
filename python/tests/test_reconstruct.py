"""Reconstruction from Python: real data, simulated data scored against its truth,
progress, the GIL released, outputs that other tools read."""

import threading
import time

import numpy as np
import pytest
import tifffile

import fpm


def test_real_usaf_reconstructs(usaf):
    res = fpm.reconstruct(usaf, passes=2)
    assert res.amplitude.shape == (512, 512) and res.amplitude.dtype == np.float32
    assert res.object.dtype == np.complex64 and res.pupil.shape == (128, 128)
    assert np.isfinite(res.amplitude).all() and np.isfinite(res.phase).all()
    assert res.pixel_um == pytest.approx(6.5 / 4 / 4)
    report = res.report
    assert report["frames"] == 121 and report["passes"] == 2
    assert report["error_per_pass"][-1] < report["error_per_pass"][0]
    # Its frames are decoded from their display gamma, and the result explains them.
    assert report["camera_gamma"] == pytest.approx(2.2)
    assert abs(report["bright_field_fit"]["offset_share"]) < 0.15
    # Warnings as report.json lists them, and as text; the geometry is the nominal one.
    checks = [w["check"] for w in report["warnings"]]
    assert "nominal-geometry" in checks, checks
    assert len(res.warnings) == len(checks) and "fpm calibrate" in res.warnings[0]


def test_frames_stored_for_display_are_simulated_and_stated(tmp_path):
    ds, _ = fpm.simulate_acquisition(
        tmp_path / "encoded", size=64, noise="eight-bit", display_gamma=2.2
    )
    assert ds.gamma == pytest.approx(2.2)
    # The offset is stored encoded, as the pixels are: 2 counts of light read ~28.
    assert ds.dark_level == pytest.approx(255 * (2 / 255) ** (1 / 2.2))
    with pytest.raises(ValueError, match="display_gamma: 0 is not"):
        fpm.simulate_acquisition(tmp_path / "bad", size=64, display_gamma=0.0)
    with pytest.raises(ValueError, match="sample = 'beads'"):
        fpm.simulate_acquisition(tmp_path / "bad", size=64, sample="beads")
    weak, truth = fpm.simulate_acquisition(tmp_path / "weak", size=64, sample="weak-phase")
    assert truth["sample"] == "weak-phase"


def test_the_true_placement_beats_the_nominal_one(acquisition, placement):
    ds, _ = acquisition
    nominal = fpm.reconstruct(ds, passes=4).report["versus_truth"]["complex_nrmse"]
    placed = fpm.reconstruct(ds, geometry=placement, passes=4)
    score = placed.report["versus_truth"]["complex_nrmse"]
    assert score < 0.5 * nominal, (score, nominal)
    assert placed.report["geometry"]["dx_mm"] == placement["dx_mm"]


def test_flattening_the_clear_background_is_asked_for_and_reported(tmp_path):
    # Cells and bars on clear glass, a field of several blocks (the shared 64² set is
    # about one cell wide: no glass to fit), 10 passes (after 4 the glass's amplitude
    # has not settled into one level, and nothing is fitted).
    ds, truth = fpm.simulate_acquisition(tmp_path, size=160, seed=1)
    placement = {k: truth[k] for k in ("dx_mm", "dy_mm", "theta_deg", "height_mm")}
    kept = fpm.reconstruct(ds, geometry=placement, upsample=2)
    flat = fpm.reconstruct(ds, geometry=placement, upsample=2, flatten_background=True)
    assert kept.report["background_phase"]["treatment"] == "kept"
    done = flat.report["background_phase"]
    assert done["treatment"] == "flattened" and done["fitted"] > 0, done
    score = lambda r: r.report["versus_truth"]["complex_nrmse"]
    assert score(flat) < 0.7 * score(kept), (score(flat), score(kept))
    with pytest.raises(ValueError, match="flatten_background"):
        fpm.reconstruct(ds, passes=1, background_block_um=40.0)


def test_progress_counts_up_to_the_total(acquisition, placement):
    ds, _ = acquisition
    seen = []
    fpm.reconstruct(ds, geometry=placement, passes=2, progress=lambda d, t: seen.append((d, t)))
    assert len(seen) >= 10
    done = [d for d, _ in seen]
    assert done == sorted(done) and seen[-1][0] == seen[-1][1] == 2 * len(ds)


def test_a_raising_callback_is_raised_after_the_run(acquisition):
    ds, _ = acquisition

    def stop(done, total):
        raise KeyError("from the callback")

    with pytest.raises(KeyError, match="from the callback"):
        fpm.reconstruct(ds, passes=1, progress=stop)


def test_the_gil_is_released_while_it_runs(acquisition, placement):
    ds, _ = acquisition
    running = threading.Event()
    finished = threading.Event()

    def work():
        running.set()
        fpm.reconstruct(ds, geometry=placement, passes=6, upsample=4)
        finished.set()

    thread = threading.Thread(target=work)
    thread.start()
    running.wait()
    ticks = 0
    while not finished.is_set():
        ticks += 1
        time.sleep(0.001)
    thread.join()
    # With the GIL held for the whole run, this thread could not tick at all.
    assert ticks >= 20, ticks


def test_outputs_carry_what_was_computed(usaf, tmp_path):
    res = fpm.reconstruct(usaf, passes=1)
    res.save(tmp_path)
    assert np.array_equal(tifffile.imread(tmp_path / "amplitude.tif"), res.amplitude)
    assert np.array_equal(tifffile.imread(tmp_path / "phase.tif"), res.phase)
    assert (tmp_path / "report.json").is_file() and (tmp_path / "amplitude.png").is_file()


@pytest.mark.parametrize("compress", [False, True])
def test_images_are_ome_tiffs_with_their_pixel_size(usaf, tmp_path, compress):
    res = fpm.reconstruct(usaf, passes=1)
    res.save(tmp_path, compress=compress)
    for name, values in (("amplitude", res.amplitude), ("phase", res.phase)):
        with tifffile.TiffFile(tmp_path / f"{name}.tif") as tif:
            assert tif.is_ome, name
            ome = tifffile.xml2dict(tif.ome_metadata)["OME"]
            pixels = ome["Image"]["Pixels"]
            assert pixels["PhysicalSizeX"] == pytest.approx(res.pixel_um)
            assert pixels["PhysicalSizeY"] == pytest.approx(res.pixel_um)
            assert pixels["SizeX"] == values.shape[1] and pixels["Type"] == "float"
            assert pixels["Channel"]["Name"] == name
            assert pixels["Channel"]["ExcitationWavelength"] == pytest.approx(626)
            assert ome["Instrument"]["Objective"]["LensNA"] == pytest.approx(0.1)
            page = tif.pages[0]
            assert (page.compression == 8) == compress  # deflate
            numerator, denominator = page.tags["XResolution"].value
            assert 1e4 * denominator / numerator == pytest.approx(res.pixel_um, rel=1e-6)
            assert np.array_equal(tif.asarray(), values)


def test_geometry_from_a_calibration_file(usaf, tmp_path):
    path = tmp_path / "placement.json"
    path.write_text('{"dx_mm": 0.5, "dy_mm": 0, "theta_deg": 0, "height_mm": 87.5}')
    res = fpm.reconstruct(usaf, geometry=path, passes=1)
    assert res.report["geometry"]["dx_mm"] == 0.5
    assert res.report["geometry_source"] == str(path)


def test_an_objective_that_is_not_telecentric_is_reconstructed_when_stated(tmp_path):
    # A pupil 15 mm above a 154 µm field: the outer LEDs' angles to it change by a
    # fifth of their spacing across the field, which a telecentric reading smears.
    ds, truth = fpm.simulate_acquisition(
        tmp_path, size=256, seed=2, dx_mm=0.0, dy_mm=0.0, theta_deg=0.0, entrance_pupil_mm=15.0
    )
    assert truth["entrance_pupil_mm"] == 15.0
    placement = {k: truth[k] for k in ("dx_mm", "dy_mm", "theta_deg", "height_mm")}
    score = lambda res: res.report["versus_truth"]["complex_nrmse"]
    telecentric = fpm.reconstruct(ds, geometry=placement, passes=6)
    stated = fpm.reconstruct(ds, geometry=placement, passes=6, entrance_pupil_mm=15.0)
    assert stated.report["system"]["entrance_pupil_mm"] == 15.0
    assert "entrance_pupil_mm" not in telecentric.report["system"]
    # Measured: 0.107 against 0.370.
    assert score(stated) < 0.6 * score(telecentric), (score(stated), score(telecentric))


def test_the_floor_is_chosen_as_fpm_reconstruct_chooses_it(usaf):
    """`floor` is `fpm reconstruct --floor`: soft by default, hard when asked, and the
    report says which (the dark-field frames' light near the floor then differs)."""
    soft = fpm.reconstruct(usaf, passes=1)
    hard = fpm.reconstruct(usaf, passes=1, floor="hard", floor_sigma=5.0, noise_band_sigma=0.0)
    assert soft.report["background"]["floor"] == "soft"
    assert soft.report["background"]["noise_band_sigma"] == 7.5
    background = hard.report["background"]
    assert (background["floor"], background["floor_sigma"], background["noise_band_sigma"]) == ("hard", 5.0, 0.0)
    assert not np.array_equal(soft.amplitude, hard.amplitude)


def test_bad_arguments_are_refused(usaf):
    with pytest.raises(ValueError, match="background"):
        fpm.reconstruct(usaf, background="sometimes")
    with pytest.raises(ValueError, match="floor = 'medium'"):
        fpm.reconstruct(usaf, floor="medium")
    with pytest.raises(ValueError, match="passes"):
        fpm.reconstruct(usaf, passes=0)
    with pytest.raises(ValueError, match="geometry"):
        fpm.reconstruct(usaf, geometry={"dx_mm": 1.0})
    with pytest.raises(fpm.FpmError, match="nowhere.json"):
        fpm.reconstruct(usaf, geometry="/nowhere.json")
    with pytest.raises(ValueError, match="entrance_pupil_mm"):
        fpm.reconstruct(usaf, entrance_pupil_mm=-5.0)
    with pytest.raises(ValueError, match="refocus_um"):
        fpm.reconstruct(usaf, refocus_um=float("nan"))


def test_the_defaults_are_the_librarys_and_its_limits_are_enforced(usaf):
    """`reconstruct` and `Streaming` default as the library (and `fpm reconstruct`)
    does, and the limits it exports are the ones its checks refuse beyond."""
    import inspect

    defaults = fpm.RECONSTRUCT_DEFAULTS
    checked = 0
    for function in (fpm.reconstruct, fpm.Streaming):
        parameters = inspect.signature(function).parameters
        for name, value in defaults.items():
            if name in parameters:
                assert parameters[name].default == value, (function, name)
                checked += 1
    # reconstruct's four and Streaming's three (it has no passes).
    assert checked == 7, checked
    low, high = fpm.RECONSTRUCT_LIMITS["upsample"]
    for bad in (low - 1, high + 1):
        with pytest.raises(ValueError, match=f"upsample {bad}: must be {low}-{high}"):
            fpm.reconstruct(usaf, upsample=bad)
    low, high = fpm.RECONSTRUCT_LIMITS["passes"]
    with pytest.raises(ValueError, match=f"passes {high + 1}: must be {low}-{high}"):
        fpm.reconstruct(usaf, passes=high + 1)


def test_ome_zarr_pyramid_opens_with_zarr(usaf, tmp_path):
    import zarr

    res = fpm.reconstruct(usaf, passes=1)
    res.save(tmp_path, format="ome-zarr")
    assert not (tmp_path / "amplitude.tif").exists()
    group = zarr.open_group(tmp_path / "image.ome.zarr", mode="r")
    multiscales = group.attrs["multiscales"][0]
    assert multiscales["version"] == "0.4"
    assert [a["name"] for a in multiscales["axes"]] == ["c", "y", "x"]
    assert multiscales["axes"][2]["unit"] == "micrometer"
    paths = [d["path"] for d in multiscales["datasets"]]
    assert paths == ["0", "1"]  # 512² then 256² (one chunk)
    for level, d in enumerate(multiscales["datasets"]):
        scale = d["coordinateTransformations"][0]["scale"]
        assert scale[1] == scale[2] == pytest.approx(res.pixel_um * 2**level)
    full = group["0"]
    assert full.shape == (2, 512, 512) and full.chunks == (1, 256, 256)
    assert np.array_equal(full[0], res.amplitude)
    assert np.array_equal(full[1], res.phase)
    half = group["1"][:]
    assert half.shape == (2, 256, 256)
    assert np.allclose(half[0], res.amplitude.reshape(256, 2, 256, 2).mean(axis=(1, 3)), rtol=1e-5)
    mean_field = res.object.reshape(256, 2, 256, 2).mean(axis=(1, 3))
    assert np.allclose(np.exp(1j * half[1]), np.exp(1j * np.angle(mean_field)), atol=1e-4)
    assert [c["label"] for c in group.attrs["omero"]["channels"]] == ["amplitude", "phase"]


def test_ome_zarr_edge_chunks_hold_exactly_the_image(acquisition, placement, tmp_path):
    import zarr

    ds, _ = acquisition
    res = fpm.reconstruct(ds, geometry=placement, passes=1, upsample=5)  # 320², not a chunk multiple
    res.save(tmp_path, format="ome-zarr")
    group = zarr.open_group(tmp_path / "image.ome.zarr", mode="r")
    assert group["0"].shape == (2, 320, 320) and group["1"].shape == (2, 160, 160)
    assert np.array_equal(group["0"][0], res.amplitude)
    assert np.array_equal(group["0"][1], res.phase)


def test_napari_s_reader_sees_channels_levels_and_scale(usaf, tmp_path):
    # ome-zarr-py's Reader is what the napari-ome-zarr plugin builds layers from.
    from ome_zarr.io import parse_url
    from ome_zarr.reader import Reader

    res = fpm.reconstruct(usaf, passes=1)
    res.save(tmp_path, format="ome-zarr")
    nodes = list(Reader(parse_url(str(tmp_path / "image.ome.zarr")))())
    image = nodes[0]
    assert [level.shape for level in image.data] == [(2, 512, 512), (2, 256, 256)]
    assert image.metadata["channel_names"] == ["amplitude", "phase"]
    scales = [t[0]["scale"] for t in image.metadata["coordinateTransformations"]]
    assert scales[0][1:] == pytest.approx([res.pixel_um] * 2)
    assert scales[1][1:] == pytest.approx([2 * res.pixel_um] * 2)
    assert np.array_equal(np.asarray(image.data[0][0]), res.amplitude)


def test_a_multiplexed_acquisition_lists_each_frames_leds_and_reconstructs(tmp_path):
    one, _ = fpm.simulate_acquisition(
        tmp_path / "one", size=64, dx_mm=0.0, dy_mm=0.0, theta_deg=0.0
    )
    mux, _ = fpm.simulate_acquisition(
        tmp_path / "mux", size=64, dx_mm=0.0, dy_mm=0.0, theta_deg=0.0, multiplex=4
    )
    lit = [led for frame in mux.frame_leds for led in frame]
    assert len(lit) == len(set(lit)) == 441
    assert max(len(frame) for frame in mux.frame_leds) == 4
    assert len(mux.leds) == len(mux.frame_leds) < 441 / 3
    assert [frame[0] for frame in mux.frame_leds] == mux.leds
    scores = [
        fpm.reconstruct(ds, passes=6).report["versus_truth"]["complex_nrmse"]
        for ds in (one, mux)
    ]
    # The simulator's 64² sets: 0.127 and 0.171 at 10 passes (docs/results.md).
    assert scores[1] < 1.6 * scores[0], scores
    with pytest.raises(fpm.FpmError, match="--refine-leds needs frames lit by one LED"):
        fpm.reconstruct(mux, refine_leds=True, passes=1)
