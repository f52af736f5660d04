"""The napari plugin's reader and reconstruct widget (fpm.napari_data) in real Qt,
offscreen: napari's own plugin manager reads the manifest and picks fpm's reader for a
dataset folder and a result folder; the layers carry the frames per LED, the LEDs'
places and the physical scale; the widget reconstructs with its progress bar, shows the
result and saves it as the command writes it. The viewer is napari's model (no OpenGL
canvas: there is no display here)."""

import math
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
pytest.importorskip("pytestqt")
pytest.importorskip("napari")

import npe2  # noqa: E402
import tifffile  # noqa: E402
from napari.components import ViewerModel  # noqa: E402
from qtpy.QtCore import Qt  # noqa: E402

import fpm  # noqa: E402
from fpm.napari_data import (  # noqa: E402
    AMPLITUDE_LAYER,
    PHASE_LAYER,
    PUPIL_PHASE_LAYER,
    ReconstructWidget,
    get_reader,
)

MANIFEST = Path(fpm.__file__).parent / "napari.yaml"


def test_the_manifest_is_valid_and_napari_picks_fpm_for_its_folders(usaf):
    manifest = npe2.PluginManifest.from_file(MANIFEST)
    manifest.validate_imports()
    names = {c.id for c in manifest.contributions.commands}
    assert {"ptychoscope.get_reader", "ptychoscope.reconstruct_widget"} <= names
    pm = npe2.PluginManager.instance()
    if manifest.name not in pm._manifests:
        pm.register(manifest)
    readers = [r.command for r in pm.iter_compatible_readers([str(usaf.dir)])]
    assert "ptychoscope.get_reader" in readers, readers
    # Anything else is left to napari's other readers.
    assert get_reader(str(usaf.dir / "frames")) is None


def test_a_dataset_opens_as_frames_per_led_and_the_leds_as_points(acquisition):
    acquisition, _ = acquisition
    reader = get_reader(str(acquisition.dir))
    assert reader is not None
    (frames, fmeta, fkind), (points, pmeta, pkind) = reader(str(acquisition.dir))
    assert (fkind, pkind) == ("image", "points")
    n = len(acquisition)
    assert frames.shape == (n, *acquisition.frame(0).shape)
    k = n // 3
    assert np.array_equal(frames[k], acquisition.frame(k))
    assert fmeta["metadata"]["leds"][k] == tuple(acquisition.leds[k])
    system = acquisition.system
    pixel_um = system["pixel_size_um"] / system["magnification"]
    assert fmeta["scale"][1:] == pytest.approx((pixel_um, pixel_um))
    assert fmeta["axis_labels"][0] == "frame (LED)"
    # The LEDs where the dataset places them, (y, x) mm, labelled row,col.
    x, y, _ = acquisition.led_positions_mm[k]
    assert points[k] == pytest.approx((y, x))
    assert pmeta["features"]["row"][k] == acquisition.leds[k][0]
    viewer = ViewerModel()
    for data, meta, kind in reader(str(acquisition.dir)):
        getattr(viewer, f"add_{kind}")(data, **meta)
    assert len(viewer.layers) == 2
    assert tuple(str(u) for u in viewer.layers[0].units[1:]) == ("micrometer", "micrometer")


def test_the_widget_reconstructs_shows_and_saves_and_the_result_opens_again(
    acquisition, qtbot, tmp_path
):
    acquisition, _ = acquisition
    viewer = ViewerModel()
    widget = ReconstructWidget(viewer, dataset=acquisition.dir)
    qtbot.addWidget(widget)
    widget.passes.setValue(3)
    widget.upsample.setValue(2)
    qtbot.mouseClick(widget.run, Qt.MouseButton.LeftButton)
    assert not widget.run.isEnabled()
    qtbot.waitUntil(lambda: widget.result is not None, timeout=120_000)
    assert widget.progress.value() == widget.progress.maximum() > 0
    result = widget.result
    amplitude, phase = viewer.layers[AMPLITUDE_LAYER], viewer.layers[PHASE_LAYER]
    assert np.array_equal(amplitude.data, result.amplitude)
    assert tuple(amplitude.scale) == pytest.approx((result.pixel_um, result.pixel_um))
    assert phase.colormap.name == "twilight"
    assert tuple(phase.contrast_limits) == pytest.approx((-math.pi, math.pi))
    assert PUPIL_PHASE_LAYER in viewer.layers
    assert "done: 3 passes" in widget.status.text()

    out = tmp_path / "result"
    widget.out.setText(str(out))
    qtbot.mouseClick(widget.save, Qt.MouseButton.LeftButton)
    assert np.array_equal(tifffile.imread(out / "amplitude.tif"), result.amplitude)
    # The saved folder opens again through the reader, at the same scale.
    layers = get_reader(str(out))(str(out))
    (amp, ameta, _), (ph, phmeta, _) = layers[:2]
    assert np.array_equal(amp, result.amplitude)
    assert ameta["scale"] == pytest.approx((result.pixel_um, result.pixel_um))
    assert phmeta["colormap"] == "twilight"
    assert len(layers) == 4  # and the pupil's amplitude and phase


def test_the_widget_offers_the_librarys_ranges_and_defaults(qtbot, tmp_path):
    """The widget's passes and upsample start at the library's defaults and reach its
    limits (it once allowed upsample 1-8 where `fpm reconstruct` takes 1-64)."""
    widget = ReconstructWidget(ViewerModel(), dataset=tmp_path)
    qtbot.addWidget(widget)
    for name in ("passes", "upsample"):
        box = getattr(widget, name)
        assert (box.minimum(), box.maximum()) == fpm.RECONSTRUCT_LIMITS[name], name
        assert box.value() == fpm.RECONSTRUCT_DEFAULTS[name], name


def test_a_folder_that_is_not_a_dataset_is_said_in_the_widget(qtbot, tmp_path):
    widget = ReconstructWidget(ViewerModel(), dataset=tmp_path)
    qtbot.addWidget(widget)
    qtbot.mouseClick(widget.run, Qt.MouseButton.LeftButton)
    assert "cannot open" in widget.status.text() and "dataset.toml" in widget.status.text()
    assert widget.run.isEnabled()
