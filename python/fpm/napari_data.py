"""fpm datasets and results in napari: open a dataset folder (its frames as a stack
along an LED axis, the lit LEDs as points in the LED plane), open a result folder
(amplitude, phase with a cyclic colormap, and the recovered pupil, at their physical
scale in µm), and reconstruct a dataset from a dock widget with a progress bar, then
save the result as ``fpm reconstruct`` writes it.

In napari: *File → Open Folder…* on a dataset (``dataset.toml``) or a result
(``report.json`` with ``amplitude.tif``), and *Plugins → fpm: reconstruct*; from
Python::

    import napari
    from fpm.napari_data import ReconstructWidget

    viewer = napari.Viewer()
    viewer.open("data/zuo-usaf-11x11", plugin="ptychoscope")
    viewer.window.add_dock_widget(ReconstructWidget(viewer), name="fpm reconstruct")
"""

from __future__ import annotations

import json
import math
import threading
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np
from qtpy.QtCore import Signal
from qtpy.QtWidgets import (
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QProgressBar,
    QPushButton,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

#: Layer names the reconstruct widget and the service widget (fpm.napari) keep up to date.
AMPLITUDE_LAYER = "fpm amplitude"
PHASE_LAYER = "fpm phase"
PUPIL_AMPLITUDE_LAYER = "fpm pupil amplitude"
PUPIL_PHASE_LAYER = "fpm pupil phase"

LayerData = tuple[Any, dict[str, Any], str]


def get_reader(path: Any) -> Optional[Callable[[Any], list[LayerData]]]:
    """napari's reader hook: a reader for an fpm dataset or result folder, else None
    (napari then asks its other readers)."""
    if isinstance(path, list):
        if len(path) != 1:
            return None
        path = path[0]
    folder = Path(path)
    if (folder / "dataset.toml").is_file():
        return read_dataset
    if (folder / "report.json").is_file() and (folder / "amplitude.tif").is_file():
        return read_result
    return None


def _micrometres(pixel_um: float, axes: int = 2) -> dict[str, Any]:
    return {"scale": (pixel_um,) * axes, "units": ("micrometer",) * axes}


def read_dataset(path: Any) -> list[LayerData]:
    """A dataset folder as two layers: its frames (one image per LED, in the dataset's
    order; the LED of each in the layer's metadata and on its slider axis) at the
    sample-plane pixel, and the lit LEDs as points (mm in the sample's frame, labelled
    row,col)."""
    from . import Dataset

    folder = Path(path[0] if isinstance(path, list) else path)
    import dask.array as da  # napari's own dependency

    ds = Dataset.load(folder)
    system = ds.system
    pixel_um = system["pixel_size_um"] / system["magnification"]
    # A lazy stack of the frames' views: napari reads the frame shown, and a dataset
    # of hundreds of large frames is not copied once more into memory.
    frames = da.stack([da.from_array(f, chunks=f.shape) for f in ds.frames])
    leds = [tuple(int(v) for v in led) for led in ds.leds]
    positions = np.array([(y, x) for x, y, _ in ds.led_positions_mm], dtype=float)
    frames_meta = {
        "name": f"{folder.name} frames",
        "scale": (1.0, pixel_um, pixel_um),
        "units": ("pixel", "micrometer", "micrometer"),
        "axis_labels": ("frame (LED)", "y", "x"),
        "metadata": {
            "leds": leds,
            "exposure_ms": list(ds.exposure_ms),
            "system": dict(system),
            "geometry": dict(ds.geometry),
        },
        "colormap": "gray",
    }
    points_meta = {
        "name": f"{folder.name} LEDs",
        "units": ("mm", "mm"),
        "features": {
            "frame": np.arange(len(leds)),
            "row": np.array([r for r, _ in leds]),
            "col": np.array([c for _, c in leds]),
        },
        "text": {"string": "{row},{col}", "size": 8},
        "size": 1.0,
        "metadata": {"leds": leds},
    }
    return [(frames, frames_meta, "image"), (positions, points_meta, "points")]


def _image(path: Path) -> np.ndarray:
    import tifffile

    return np.asarray(tifffile.imread(path))


def read_result(path: Any) -> list[LayerData]:
    """A result folder (as ``fpm reconstruct`` and ``Reconstruction.save`` write it) as
    amplitude, phase (cyclic colormap, −π…π) and, where written, the pupil's amplitude
    and phase, at the pixels of report.json (µm)."""
    folder = Path(path[0] if isinstance(path, list) else path)
    report = json.loads((folder / "report.json").read_text())
    pixel_um = float(report["pixel_um"])
    layers: list[LayerData] = [
        (_image(folder / "amplitude.tif"),
         {"name": f"{folder.name} amplitude", "colormap": "gray",
          **_micrometres(pixel_um)}, "image"),
        (_image(folder / "phase.tif"),
         {"name": f"{folder.name} phase", "colormap": "twilight",
          "contrast_limits": (-math.pi, math.pi), **_micrometres(pixel_um)}, "image"),
    ]
    for part, colormap in (("amplitude", "magma"), ("phase", "twilight")):
        file = folder / f"pupil_{part}.tif"
        if file.is_file():
            meta = {"name": f"{folder.name} pupil {part}", "colormap": colormap,
                    "visible": False}
            if part == "phase":
                meta["contrast_limits"] = (-math.pi, math.pi)
            layers.append((_image(file), meta, "image"))
    return layers


def _show(viewer, name: str, data: np.ndarray, **meta) -> None:
    """Put `data` into layer `name`, adding it the first time."""
    if name in viewer.layers:
        layer = viewer.layers[name]
        layer.data = data
        for key in ("scale", "units"):
            if key in meta:
                setattr(layer, key, meta[key])
    else:
        viewer.add_image(data, name=name, **meta)


def show_amplitude_and_phase(viewer, amplitude: np.ndarray, phase: np.ndarray,
                             pixel_um: float) -> None:
    """The layers ``AMPLITUDE_LAYER`` and ``PHASE_LAYER`` (cyclic colormap, −π…π) at
    `pixel_um` µm: made on first use, then updated in place (the reconstruct widget's
    result, the acquisition service's snapshots)."""
    scale = _micrometres(pixel_um)
    _show(viewer, AMPLITUDE_LAYER, amplitude, colormap="gray", **scale)
    _show(viewer, PHASE_LAYER, phase, colormap="twilight",
          contrast_limits=(-math.pi, math.pi), **scale)


class ReconstructWidget(QWidget):
    """Reconstruct a dataset folder from napari (``fpm.reconstruct`` with the command's
    defaults, on a thread of its own, the progress bar following the frame updates),
    show the result as layers at its physical scale, and save it."""

    #: (done, total) frame updates, on the GUI thread.
    progressed = Signal(int, int)
    #: The finished reconstruction, or the exception that ended it.
    done = Signal(object)

    def __init__(self, viewer, dataset: Any = None) -> None:
        super().__init__()
        self.viewer = viewer
        self.result = None
        self.dataset = QLineEdit(str(dataset) if dataset is not None else "")
        browse = QPushButton("…")
        browse.clicked.connect(self._browse)
        row = QHBoxLayout()
        row.addWidget(self.dataset)
        row.addWidget(browse)
        # The library's ranges and defaults (what `fpm reconstruct` takes).
        from . import RECONSTRUCT_DEFAULTS, RECONSTRUCT_LIMITS

        self.passes = QSpinBox()
        self.passes.setRange(*RECONSTRUCT_LIMITS["passes"])
        self.passes.setValue(RECONSTRUCT_DEFAULTS["passes"])
        self.upsample = QSpinBox()
        self.upsample.setRange(*RECONSTRUCT_LIMITS["upsample"])
        self.upsample.setValue(RECONSTRUCT_DEFAULTS["upsample"])
        self.run = QPushButton("Reconstruct")
        self.run.clicked.connect(self.start)
        self.progress = QProgressBar()
        self.status = QLabel("choose a dataset folder (dataset.toml)")
        self.status.setWordWrap(True)
        self.out = QLineEdit()
        self.out.setPlaceholderText("output folder")
        self.save = QPushButton("Save")
        self.save.setEnabled(False)
        self.save.clicked.connect(self.save_result)
        form = QFormLayout()
        form.addRow("dataset", row)
        form.addRow("passes", self.passes)
        form.addRow("upsample", self.upsample)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addWidget(self.run)
        layout.addWidget(self.progress)
        layout.addWidget(self.status)
        layout.addWidget(self.out)
        layout.addWidget(self.save)
        self.progressed.connect(self._on_progress)
        self.done.connect(self._on_finished)

    def _browse(self) -> None:
        folder = QFileDialog.getExistingDirectory(self, "dataset folder")
        if folder:
            self.dataset.setText(folder)

    def start(self) -> None:
        """Reconstruct the dataset in the folder field (returns at once)."""
        from . import Dataset, FpmError

        try:
            ds = Dataset.load(self.dataset.text())
        except (ValueError, FpmError) as e:
            self.status.setText(f"cannot open: {e}")
            return
        self.run.setEnabled(False)
        self.save.setEnabled(False)
        self.progress.setValue(0)
        self.status.setText(f"reconstructing {ds}")
        passes, upsample = self.passes.value(), self.upsample.value()

        def work() -> None:
            from . import reconstruct

            try:
                result = reconstruct(ds, passes=passes, upsample=upsample,
                                     progress=lambda d, t: self.progressed.emit(d, t))
            except Exception as e:  # shown in the widget, not lost on a thread
                result = e
            self.done.emit(result)

        threading.Thread(target=work, daemon=True, name="fpm reconstruct").start()

    def _on_progress(self, done: int, total: int) -> None:
        self.progress.setMaximum(total)
        self.progress.setValue(done)

    def _on_finished(self, result: Any) -> None:
        self.run.setEnabled(True)
        if isinstance(result, Exception):
            self.status.setText(f"failed: {result}")
            return
        self.result = result
        show_amplitude_and_phase(self.viewer, result.amplitude, result.phase,
                                 result.pixel_um)
        pupil = result.pupil
        _show(self.viewer, PUPIL_AMPLITUDE_LAYER, np.abs(pupil), colormap="magma",
              visible=False)
        _show(self.viewer, PUPIL_PHASE_LAYER, np.angle(pupil).astype(np.float32),
              colormap="twilight", contrast_limits=(-math.pi, math.pi), visible=False)
        errors = result.report["error_per_pass"]
        lines = [f"done: {len(errors)} passes, error {errors[-1]:.4f}"]
        lines += [f"warning: {w}" for w in result.warnings]
        self.status.setText("\n".join(lines))
        self.save.setEnabled(True)

    def save_result(self) -> None:
        """Write the result into the output folder as ``fpm reconstruct`` does."""
        if self.result is None:
            return
        out = self.out.text()
        if not out:
            out = QFileDialog.getExistingDirectory(self, "output folder")
            if not out:
                return
            self.out.setText(out)
        self.result.save(out)
        self.status.setText(f"{self.status.text()}\nwrote {out}")


def make_reconstruct_widget(napari_viewer) -> ReconstructWidget:
    """napari's widget hook."""
    return ReconstructWidget(napari_viewer)
