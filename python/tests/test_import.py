"""`fpm.Dataset.from_*`: other labs' data imported as `fpm import` does (the four
formats' own conventions are tested end to end in tests/tests/import.rs; here the
Python entry points, on the format the package's test environment can write)."""

import numpy as np
import pytest
import tifffile

import fpm


def test_a_tiff_folder_and_csv_import_as_the_arrays_and_positions_given(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    rng = np.random.default_rng(3)
    frames = [rng.integers(0, 4000, (24, 32), dtype=np.uint16) for _ in range(3)]
    for k, f in enumerate(frames):
        tifffile.imwrite(src / f"f{k}.tif", f)
    (src / "leds.csv").write_text(
        "row,col,x_mm,y_mm,exposure_ms\n0,0,0.0,0.0,10\n0,1,4.0,0.0,20\n1,0,0.0,-4.0,20\n"
    )
    ds = fpm.Dataset.from_tiff_csv(
        src, tmp_path / "out", height_mm=60, wavelength_um=0.52, na=0.1,
        magnification=4, pixel_size_um=2.4, bit_depth=12,
    )
    assert ds.leds == [(0, 0), (0, 1), (1, 0)]
    assert ds.exposure_ms == [10.0, 20.0, 20.0]
    for k, f in enumerate(frames):
        np.testing.assert_array_equal(ds.frame(k), f)
    assert ds.led_positions_mm == [(0.0, 0.0, 60.0), (4.0, 0.0, 60.0), (0.0, -4.0, 60.0)]
    assert ds.source["format"] == "tiff-csv"
    assert any("dark" in a for a in ds.source["assumed"])
    # The same dataset loads from disk as written.
    again = fpm.Dataset.load(tmp_path / "out")
    assert again.leds == ds.leds and again.source == ds.source


def test_an_import_missing_what_the_source_cannot_say_names_it(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    tifffile.imwrite(src / "f0.tif", np.zeros((8, 8), np.uint16))
    (src / "leds.csv").write_text("na_x,na_y\n0.0,0.0\n")
    with pytest.raises(fpm.DatasetError, match="--wavelength-um"):
        fpm.Dataset.from_tiff_csv(src, tmp_path / "out", height_mm=60)
    with pytest.raises(ValueError, match="heigth_mm: not a keyword"):
        fpm.Dataset.from_tiff_csv(src, tmp_path / "out", heigth_mm=60)
