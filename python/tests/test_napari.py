"""The napari dock widget (fpm.napari) in real Qt, offscreen, against a real `fpm serve
--virtual`: an acquisition started from the widget grows two layers with the
reconstruction at its physical scale, ending as the image the job wrote; a second,
paused and cancelled from the widget, holds and then ends cancelled. The viewer is
napari's model (its layers, no OpenGL canvas: there is no display here)."""

import math
import os

import numpy as np
import pytest

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
pytest.importorskip("pytestqt")
pytest.importorskip("napari")

from napari.components import ViewerModel  # noqa: E402
from qtpy.QtCore import Qt  # noqa: E402

from fpm.napari import AMPLITUDE_LAYER, PHASE_LAYER, ServiceWidget  # noqa: E402


def test_the_dock_widget_acquires_shows_pauses_and_cancels(service, qtbot):
    tifffile = pytest.importorskip("tifffile")
    viewer = ViewerModel()
    widget = ServiceWidget(viewer, client=service)
    qtbot.addWidget(widget)
    assert "virtual rig" in widget.status.text()
    widget.step_ms.setValue(15)
    widget.snapshot_every.setValue(150)
    qtbot.mouseClick(widget.start, Qt.MouseButton.LeftButton)
    first = widget.job
    assert first is not None and not widget.start.isEnabled()
    # Snapshots grow into the layers; the last is the finished reconstruction.
    seen = []
    qtbot.waitUntil(
        lambda: (widget.last_snapshot is not None
                 and (not seen or seen[-1] != widget.last_snapshot.frames)
                 and seen.append(widget.last_snapshot.frames) is None
                 and widget.last_snapshot.finished),
        timeout=120_000,
    )
    qtbot.waitUntil(lambda: widget.start.isEnabled(), timeout=30_000)
    assert seen[-1] == 441 and seen == sorted(seen), seen
    # On this machine the snapshots came through shared memory, not HTTP.
    assert widget.snapshots_from == "shared memory"
    amplitude, phase = viewer.layers[AMPLITUDE_LAYER], viewer.layers[PHASE_LAYER]
    pixel_um = 2.4 / 4 / 4  # the virtual camera's pixel, 4× objective, 4× upsampling
    assert tuple(amplitude.scale) == pytest.approx((pixel_um, pixel_um))
    assert tuple(str(u) for u in amplitude.units) == ("micrometer", "micrometer")
    assert phase.colormap.name == "twilight"
    assert tuple(phase.contrast_limits) == pytest.approx((-math.pi, math.pi))
    out = service.job(first)["out"]
    written = tifffile.imread(f"{out}/reconstruction/amplitude.tif")
    assert np.allclose(amplitude.data, written, rtol=1e-6)
    assert "done" in widget.status.text()

    # A second: paused from the widget (it holds: no frame comes), then cancelled.
    qtbot.mouseClick(widget.start, Qt.MouseButton.LeftButton)
    second = widget.job
    assert second != first
    qtbot.waitUntil(lambda: widget.progress.value() >= 20, timeout=60_000)
    qtbot.mouseClick(widget.pause, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: "paused" in widget.status.text(), timeout=10_000)
    assert widget.pause.text() == "Resume"
    held = widget.progress.value()
    qtbot.wait(600)
    assert widget.progress.value() == held
    assert service.status()["progress"]["phase"] == "paused"
    qtbot.mouseClick(widget.cancel, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: widget.start.isEnabled(), timeout=30_000)
    record = service.job(second)
    assert record["state"] == "cancelled", record
    assert "cancelled" in widget.status.text()
    assert held <= record["summary"]["frames_in_dataset"] < 441
    widget.close()
