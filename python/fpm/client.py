"""A client of the acquisition service (``fpm serve``), standard library only.

>>> import fpm
>>> c = fpm.Client()                      # 127.0.0.1:8737, the token found by itself
>>> job = c.acquire("/data/field-1", reconstruct=True)
>>> for event in c.events():             # state changes and progress, as they happen
...     print(event)
...     if event.get("job") == job and event.get("state") in ("done", "failed", "cancelled"):
...         break
>>> c.job(job)["summary"]["frames_in_dataset"]
441
>>> live = c.snapshot(job)                # the reconstruction as NumPy arrays
>>> live.amplitude.shape, live.pixel_um
((256, 256), 0.15)

Requests that change the rig carry the token the service wrote (0600) into its state
directory; a refused request raises ``ServiceError`` with the service's message, which
names the field, header or job at fault.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any, Iterator, Optional

DEFAULT_ADDRESS = "127.0.0.1:8737"
FINAL_STATES = ("done", "failed", "cancelled", "interrupted")


class ServiceError(RuntimeError):
    """The service refused a request: ``status`` is the HTTP status, the message the
    service's own."""

    def __init__(self, status: int, message: str):
        super().__init__(f"{status}: {message}")
        self.status = status


@dataclasses.dataclass
class Snapshot:
    """A job's reconstruction as it stood: ``amplitude`` and ``phase`` (radians)
    float32 arrays whose pixel is ``pixel_um`` µm in the sample plane, after
    ``frames`` of ``of`` frames; ``finished`` for the final reconstruction."""

    job: int
    seq: int
    frames: int
    of: int
    finished: bool
    pixel_um: float
    amplitude: Any
    phase: Any


@dataclasses.dataclass
class CameraFrame:
    """A raw camera frame as the service kept it while a job captured: ``pixels``
    (uint16 counts), lit by LED ``led`` (row, col) for ``exposure_us``."""

    job: int
    seq: int
    led: tuple
    exposure_us: int
    pixels: Any


def default_state_dir() -> Path:
    """Where ``fpm serve`` keeps its state unless told otherwise."""
    state = os.environ.get("XDG_STATE_HOME")
    return (Path(state) if state else Path.home() / ".local" / "state") / "fpm"


class Client:
    """The service at ``address`` (``host:port``); the token is read from
    ``state_dir`` (the service's ``--state-dir``) unless given."""

    def __init__(
        self,
        address: str = DEFAULT_ADDRESS,
        *,
        token: Optional[str] = None,
        state_dir: Optional[os.PathLike] = None,
        timeout: float = 30.0,
    ):
        self.address = address
        self.timeout = timeout
        if token is None:
            path = Path(state_dir) if state_dir is not None else default_state_dir()
            try:
                token = (path / "token").read_text().strip()
            except OSError:
                token = None  # reads still work; changes are refused, saying why
        self._token = token

    def _raw(self, method: str, path: str, body: Any = None):
        """The response's bytes and headers (a refusal raises ``ServiceError``)."""
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(
            f"http://{self.address}{path}", data=data, method=method
        )
        if data is not None:
            request.add_header("Content-Type", "application/json")
        if self._token:
            # Reads need it too when the service listens beyond loopback (--public).
            request.add_header("Authorization", f"Bearer {self._token}")
        try:
            with urllib.request.urlopen(request, timeout=self.timeout) as response:
                return response.read(), response.headers
        except urllib.error.HTTPError as e:
            text = e.read().decode(errors="replace")
            try:
                message = json.loads(text).get("error", text)
            except ValueError:
                message = text
            raise ServiceError(e.code, message) from None

    def _request(self, method: str, path: str, body: Any = None) -> Any:
        data, _ = self._raw(method, path, body)
        return json.loads(data) if data else None

    def status(self) -> dict:
        """The service's version, its rig, the running job and its progress."""
        return self._request("GET", "/api/status")

    def jobs(self) -> list:
        """Every job, newest first."""
        return self._request("GET", "/api/jobs")

    def job(self, job: int) -> dict:
        """One job: its state, request, times, error and summary."""
        return self._request("GET", f"/api/jobs/{int(job)}")

    def acquire(self, out: Optional[os.PathLike] = None, **fields: Any) -> int:
        """Queue an acquisition into ``out`` (made absolute here; None: a new directory
        under the service's runs, named in ``job(id)["out"]``); ``fields`` are ``fpm
        acquire``'s flags without the dashes (``calibrate=True``, ``reconstruct=True``,
        ``step_ms=30``, …) and ``snapshot_every`` (frames between live snapshots). Its
        job id."""
        body = {"kind": "acquire", **fields}
        if out is not None:
            body["out"] = str(Path(out).absolute())
        return self._request("POST", "/api/jobs", body)["id"]

    def calibrate(self, out: Optional[os.PathLike] = None, **fields: Any) -> int:
        """Queue a calibration of the LED array on the rig (pdcFPM) into ``out`` (as for
        :meth:`acquire`), stored on the controller unless ``store_geometry=False``, so
        that the acquisitions after it start from it; ``fields`` as ``fpm acquire
        --calibrate``'s flags (``defocus_um``, ``defocus_sigma_um``, the optics). Its job
        id."""
        body = {"kind": "calibrate", **fields}
        if out is not None:
            body["out"] = str(Path(out).absolute())
        return self._request("POST", "/api/jobs", body)["id"]

    def sequence(
        self, leds, out: Optional[os.PathLike] = None, **fields: Any
    ) -> int:
        """Queue a raw capture sequence: the LEDs ``leds`` (``[(row, col), …]``) lit in
        this order, one labelled frame each, written as a dataset into ``out`` (as for
        :meth:`acquire`; no calibration, no reconstruction); ``fields`` as ``step_ms``,
        ``color``, the optics. Its job id."""
        body = {"kind": "sequence", "leds": [[int(r), int(c)] for r, c in leds], **fields}
        if out is not None:
            body["out"] = str(Path(out).absolute())
        return self._request("POST", "/api/jobs", body)["id"]

    def scan(
        self,
        fields,
        out: Optional[os.PathLike] = None,
        overlap: float = 0.15,
        stage_sigma_um: float = 10.0,
        **acquire: Any,
    ) -> int:
        """Queue a scan of ``fields`` = ``(rows, cols)`` fields from where the stage is
        (+x, +y), neighbours overlapping by ``overlap``, into ``out`` (as for
        :meth:`acquire`); ``acquire`` is each field's acquisition as for
        :meth:`acquire` (``calibrate=True`` calibrates at the first field,
        ``reconstruct=True`` reconstructs each field while the next is acquired and
        stitches them into ``out/mosaic/mosaic.zarr``). Needs a motorised stage. Its
        job id; :meth:`resume` completes one that ended part-way."""
        rows, cols = fields
        body = {
            "kind": "scan",
            "fields": [int(rows), int(cols)],
            "overlap": float(overlap),
            "stage_sigma_um": float(stage_sigma_um),
            "acquire": acquire,
        }
        if out is not None:
            body["out"] = str(Path(out).absolute())
        return self._request("POST", "/api/jobs", body)["id"]

    def reconstruct(
        self, dataset: os.PathLike, out: Optional[os.PathLike] = None, **fields: Any
    ) -> int:
        """Queue a reconstruction of the dataset in ``dataset`` (an acquisition job's
        ``out``, say) into ``out`` (as for :meth:`acquire`); ``fields`` as ``fpm
        reconstruct``'s flags (``calibration``, ``passes``, ``upsample``,
        ``flatten_background``, ``refine_leds``, ``format="ome-zarr"``, …). The finished
        image is then the job's :meth:`snapshot`. Its job id."""
        body = {"kind": "reconstruct", "dataset": str(Path(dataset).absolute()), **fields}
        if out is not None:
            body["out"] = str(Path(out).absolute())
        if isinstance(body.get("calibration"), os.PathLike):
            body["calibration"] = str(Path(body["calibration"]).absolute())
        return self._request("POST", "/api/jobs", body)["id"]

    def snapshot(self, job: int) -> Snapshot:
        """``job``'s newest snapshot of its reconstruction (``ServiceError`` 404 when it
        has none yet, or it is no longer in the service's memory: the images are then
        in its output directory)."""
        import numpy as np

        parts = {}
        for part in ("amplitude", "phase"):
            data, headers = self._raw(
                "GET", f"/api/jobs/{int(job)}/snapshot/{part}?format=f32"
            )
            shape = tuple(int(n) for n in headers["X-Fpm-Shape"].split(","))
            parts[part] = (np.frombuffer(data, dtype="<f4").reshape(shape), headers)
        headers = parts["amplitude"][1]
        if parts["phase"][1]["X-Fpm-Seq"] != headers["X-Fpm-Seq"]:
            return self.snapshot(job)  # a newer one came between the two requests
        return Snapshot(
            job=int(job),
            seq=int(headers["X-Fpm-Seq"]),
            frames=int(headers["X-Fpm-Frames"]),
            of=int(headers["X-Fpm-Of"]),
            finished=headers["X-Fpm-Finished"] == "true",
            pixel_um=float(headers["X-Fpm-Pixel-Um"]),
            amplitude=parts["amplitude"][0],
            phase=parts["phase"][0],
        )

    def camera_frame(self) -> CameraFrame:
        """The newest raw camera frame the service kept (a few a second while a job
        captures)."""
        import numpy as np

        data, headers = self._raw("GET", "/api/camera/frame?format=u16")
        shape = tuple(int(n) for n in headers["X-Fpm-Shape"].split(","))
        row, col = (int(n) for n in headers["X-Fpm-Led"].split(","))
        return CameraFrame(
            job=int(headers["X-Fpm-Job"]),
            seq=int(headers["X-Fpm-Seq"]),
            led=(row, col),
            exposure_us=int(headers["X-Fpm-Exposure-Us"]),
            pixels=np.frombuffer(data, dtype="<u2").reshape(shape),
        )

    def file(self, job: int, path: str) -> bytes:
        """A file of ``job``'s output directory (``"acquisition.html"``,
        ``"reconstruction/amplitude.tif"``, …), as bytes."""
        data, _ = self._raw("GET", f"/api/jobs/{int(job)}/files/{path}")
        return data

    def cancel(self, job: int) -> None:
        """Cancel ``job``: a queued one never starts, a running one stops and keeps
        what it captured."""
        self._request("POST", f"/api/jobs/{int(job)}/cancel")

    def pause(self, job: int) -> None:
        """Pause the running ``job``: the rig holds before its next LED (the capture's
        sequence is cut at the LED it is on; the LEDs it did not reach wait)."""
        self._request("POST", f"/api/jobs/{int(job)}/pause")

    def resume(self, job: int) -> int:
        """Go on with ``job``: a paused one goes on (its id is returned); one that ended
        part-way (interrupted, cancelled, failed) is completed by a new job, which
        lights only the LEDs its frames lack, into its directory (the new id)."""
        return int(self._request("POST", f"/api/jobs/{int(job)}/resume")["id"])

    def wait(self, job: int, timeout: float = 600.0, poll: float = 0.1) -> dict:
        """``job`` once it has ended (``TimeoutError`` if not within ``timeout`` s)."""
        deadline = time.monotonic() + timeout
        while True:
            record = self.job(job)
            if record["state"] in FINAL_STATES:
                return record
            if time.monotonic() > deadline:
                raise TimeoutError(f"job {job} is still {record['state']} after {timeout} s")
            time.sleep(poll)

    def events(self) -> Iterator[dict]:
        """The service's events from now on, as they come: ``{"event": "state", "job",
        "state", "error"}``, ``{"event": "progress", "job", "progress", "eta_s"}``,
        ``{"event": "frame", "job", "led"}``, ``{"event": "snapshot", "job", "seq",
        "frames", "of", "finished", …}`` (fetch it with :meth:`snapshot`) and
        ``{"event": "camera_frame", …}`` (:meth:`camera_frame`). The stream is open
        when this returns, so a job queued next is seen from its start. Stop
        iterating (or close the iterator) to disconnect."""
        headers = {"Accept": "text/event-stream"}
        if self._token:
            headers["Authorization"] = f"Bearer {self._token}"
        request = urllib.request.Request(f"http://{self.address}/api/events", headers=headers)
        stream = urllib.request.urlopen(request, timeout=self.timeout)

        def read() -> Iterator[dict]:
            with stream:
                for raw in stream:
                    line = raw.decode().rstrip("\r\n")
                    if line.startswith("data:"):
                        yield json.loads(line[5:].strip())

        return read()
