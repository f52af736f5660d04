"""A napari dock widget for the acquisition service (``fpm serve``): start, pause,
resume and cancel acquisitions, follow their progress, and watch the streaming
reconstruction grow as two layers, amplitude and phase (a cyclic colormap), with their
physical scale in µm.

In napari: *Plugins → fpm: acquisition service*, or from Python::

    import napari
    from fpm.napari import ServiceWidget

    viewer = napari.Viewer()
    viewer.window.add_dock_widget(ServiceWidget(viewer), name="fpm")

It talks to the service over its HTTP API (``fpm.Client``; the token is found in the
service's state directory as the client finds it) and, when the service runs on this
machine and ``iceoryx2`` is installed, reads the snapshots from shared memory
(``fpm.local``) rather than over HTTP. The events are read on a thread of their own and
handed to the widget through Qt signals, so napari never waits on the network.
"""

from __future__ import annotations

import math
import threading
from typing import Any, Optional

from qtpy.QtCore import Signal
from qtpy.QtWidgets import (
    QCheckBox,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QProgressBar,
    QPushButton,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from . import local as local_snapshots
from .client import FINAL_STATES, Client, ServiceError, Snapshot
from .napari_data import AMPLITUDE_LAYER, PHASE_LAYER, show_amplitude_and_phase


class ServiceWidget(QWidget):
    """Drive the acquisition service from napari; see the module's documentation.

    ``viewer`` is a ``napari.Viewer`` (or its model, ``napari.components.ViewerModel``);
    ``client`` the service's ``fpm.Client`` (default: the service at its default
    address); ``local`` whether to read snapshots from shared memory (default: when the
    service is on this machine and iceoryx2 is installed)."""

    #: An event of the service (on the GUI thread).
    event_received = Signal(dict)
    #: A snapshot fetched for the job the widget follows (on the GUI thread).
    snapshot_received = Signal(object)

    def __init__(
        self,
        viewer: Any,
        client: Optional[Client] = None,
        local: Optional[bool] = None,
        parent=None,
    ):
        super().__init__(parent)
        self.viewer = viewer
        self.client = client if client is not None else Client()
        host = self.client.address.rsplit(":", 1)[0]
        if local is None:
            local = local_snapshots.available() and host in ("127.0.0.1", "localhost", "[::1]")
        self._local = local
        #: Where snapshots come from: "shared memory" or "HTTP".
        self.snapshots_from = "HTTP"
        #: The job the widget follows (the last it started, or the one running).
        self.job: Optional[int] = None
        #: Its newest snapshot.
        self.last_snapshot: Optional[Snapshot] = None
        self._paused = False

        self.reconstruct = QCheckBox("reconstruct while acquiring")
        self.reconstruct.setChecked(True)
        self.step_ms = QSpinBox()
        self.step_ms.setRange(1, 60_000)
        self.step_ms.setValue(40)
        self.step_ms.setSuffix(" ms")
        self.snapshot_every = QSpinBox()
        self.snapshot_every.setRange(0, 100_000)
        self.snapshot_every.setValue(25)
        self.snapshot_every.setSuffix(" frames")
        self.start = QPushButton("Start acquisition")
        self.pause = QPushButton("Pause")
        self.cancel = QPushButton("Cancel")
        self.progress = QProgressBar()
        self.status = QLabel("connecting…")
        self.status.setWordWrap(True)

        form = QFormLayout()
        form.addRow(self.reconstruct)
        form.addRow("LED on", self.step_ms)
        form.addRow("snapshot every", self.snapshot_every)
        buttons = QHBoxLayout()
        for b in (self.start, self.pause, self.cancel):
            buttons.addWidget(b)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addLayout(buttons)
        layout.addWidget(self.progress)
        layout.addWidget(self.status)
        layout.addStretch()

        self.start.clicked.connect(self._start)
        self.pause.clicked.connect(self._pause_or_resume)
        self.cancel.clicked.connect(self._cancel)
        self.event_received.connect(self._on_event)
        self.snapshot_received.connect(self.show_snapshot)
        self._set_running(False)

        self._stop = threading.Event()
        self._events = self.client.events()
        self._reader = threading.Thread(target=self._read_events, name="fpm-events", daemon=True)
        self._reader.start()
        self._show_status()

    # The service's side, on the reader thread.

    def _local_reader(self):
        """The shared-memory reader, made on the thread that uses it (None: HTTP)."""
        if not self._local:
            return None
        try:
            reader = local_snapshots.SnapshotReader(self.client.status()["snapshot_service"])
        except Exception as e:  # an optional extra never stops the widget
            self.event_received.emit(
                {"event": "widget_error", "error": f"snapshots over HTTP ({e})"})
            return None
        self.snapshots_from = "shared memory"
        return reader

    def _snapshot(self, reader, event: dict) -> Snapshot:
        """The snapshot ``event`` announces: from shared memory if it is there (the
        service publishes it there before announcing it), else over HTTP."""
        if reader is not None:
            snapshot = reader.newest(timeout=0.5, after_seq=event["seq"] - 1)
            if snapshot is not None and snapshot.job == event["job"]:
                return snapshot
        return self.client.snapshot(event["job"])

    def _read_events(self) -> None:
        reader = self._local_reader()
        try:
            for event in self._events:
                if self._stop.is_set():
                    return
                if event.get("event") == "snapshot" and event.get("job") == self.job:
                    # Fetched here, not on the GUI thread.
                    try:
                        self.snapshot_received.emit(self._snapshot(reader, event))
                    except (ServiceError, OSError) as e:
                        event = {"event": "widget_error", "error": f"snapshot: {e}"}
                self.event_received.emit(event)
        except Exception as e:  # the service went away: said, not raised in napari
            if not self._stop.is_set():
                self.event_received.emit({"event": "widget_error", "error": f"events: {e}"})

    # The GUI's side.

    def _show_status(self) -> None:
        try:
            status = self.client.status()
        except (ServiceError, OSError) as e:
            self.status.setText(f"no service at {self.client.address}: {e} (start `fpm serve`)")
            return
        running = status.get("running")
        if running is not None:
            self.job = running
            self._set_running(True)
        self.status.setText(f"fpm {status['version']} · {status['rig']}")

    def _set_running(self, running: bool) -> None:
        self.start.setEnabled(not running)
        self.pause.setEnabled(running)
        self.cancel.setEnabled(running)
        if not running:
            self._paused = False
            self.pause.setText("Pause")

    def _act(self, what, *args):
        try:
            return what(*args)
        except (ServiceError, OSError) as e:
            self.status.setText(str(e))
            return None

    def _start(self) -> None:
        job = self._act(
            lambda: self.client.acquire(
                reconstruct=self.reconstruct.isChecked(),
                flatten_background=True,
                step_ms=float(self.step_ms.value()),
                snapshot_every=int(self.snapshot_every.value()),
            )
        )
        if job is not None:
            self.job = job
            self.last_snapshot = None
            self.progress.setValue(0)
            self.status.setText(f"job {job} queued")
            self._set_running(True)

    def _pause_or_resume(self) -> None:
        if self.job is None:
            return
        if self._paused:
            self._act(self.client.resume, self.job)
        else:
            self._act(self.client.pause, self.job)

    def _cancel(self) -> None:
        if self.job is not None:
            self._act(self.client.cancel, self.job)

    def _on_event(self, event: dict) -> None:
        kind = event.get("event")
        if kind == "widget_error":
            self.status.setText(event["error"])
            return
        if event.get("job") != self.job:
            if kind == "state" and event.get("state") == "running" and self.job is None:
                self.job = event["job"]
                self._set_running(True)
            return
        if kind == "progress":
            p = event["progress"]
            self.progress.setMaximum(max(p["of"], 1))
            self.progress.setValue(p["frames"])
            self._paused = bool(p.get("paused"))
            self.pause.setText("Resume" if self._paused else "Pause")
            eta = event.get("eta_s")
            text = f"job {self.job}: {p['phase']} · {p['frames']} / {p['of'] or '?'} frames"
            if eta is not None:
                text += f" · about {math.ceil(eta)} s left"
            self.status.setText(text)
        elif kind == "state":
            state = event["state"]
            self.status.setText(
                f"job {self.job} {state}" + (f": {event['error']}" if event.get("error") else "")
            )
            self._set_running(state not in FINAL_STATES)

    def show_snapshot(self, snapshot: Snapshot) -> None:
        """Show ``snapshot`` as the amplitude and phase layers (made on first use, then
        updated in place), scaled to its pixel in µm."""
        self.last_snapshot = snapshot
        show_amplitude_and_phase(self.viewer, snapshot.amplitude, snapshot.phase,
                                 snapshot.pixel_um)
        layers = self.viewer.layers
        what = "finished reconstruction" if snapshot.finished else (
            f"after {snapshot.frames} of {snapshot.of} frames")
        layers[AMPLITUDE_LAYER].metadata["fpm"] = {
            "job": snapshot.job, "frames": snapshot.frames, "finished": snapshot.finished}
        self.progress.setToolTip(f"snapshot: {what}")

    def closeEvent(self, event) -> None:  # noqa: N802 (Qt's name)
        """Stop reading events (the stream is closed; the service and its jobs go on)."""
        self._stop.set()
        close = getattr(self._events, "close", None)
        if close is not None:
            try:
                close()
            except (RuntimeError, ValueError):
                pass  # a generator running on the reader thread: it ends at its next event
        super().closeEvent(event)


def make_widget(napari_viewer) -> ServiceWidget:
    """The dock widget for napari's plugin menu (``napari.yaml``): napari passes its
    viewer by this parameter's name."""
    return ServiceWidget(napari_viewer)
