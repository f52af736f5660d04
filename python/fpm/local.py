"""The acquisition service's snapshots read from shared memory, for viewers on the same
machine: the service publishes each snapshot once on the iceoryx2 service named in
``Client.status()["snapshot_service"]`` (``fpm/serve/<port>/snapshots``), and a reader
here takes it from there with one copy into NumPy, with no HTTP, no PNG and no
encoding, however large. Needs the ``iceoryx2`` package (``pip install iceoryx2``).

    from fpm.local import SnapshotReader
    reader = SnapshotReader(client.status()["snapshot_service"])
    snapshot = reader.newest(timeout=1.0)    # fpm.client.Snapshot, or None

The layout is the one the Rust side documents (``fpm_frames::SnapshotHeader``).
"""

from __future__ import annotations

import ctypes
import time
from typing import Optional

import numpy as np

from .client import Snapshot

try:  # an optional extra: without it, viewers fetch snapshots over HTTP
    import iceoryx2 as iox2
except ImportError:  # pragma: no cover - depends on the environment
    iox2 = None

#: Viewers a snapshot service admits (the service's own setting; must match).
MAX_VIEWERS = 8


class SnapshotHeader(ctypes.Structure):
    """``fpm::SnapshotHeader/1``: 56 bytes, little-endian; the payload is
    ``2 · width · height`` float32, the amplitude's rows then the phase's."""

    _fields_ = [
        ("job", ctypes.c_int64),
        ("seq", ctypes.c_uint64),
        ("frames", ctypes.c_uint64),
        ("of", ctypes.c_uint64),
        ("pixel_um", ctypes.c_double),
        ("width", ctypes.c_uint32),
        ("height", ctypes.c_uint32),
        ("finished", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
    ]

    @staticmethod
    def type_name() -> str:
        return "fpm::SnapshotHeader/1"


assert ctypes.sizeof(SnapshotHeader) == 56


def available() -> bool:
    """Whether snapshots can be read from shared memory here (iceoryx2 installed)."""
    return iox2 is not None


class SnapshotReader:
    """Reads the snapshots of the service whose snapshot service is ``name``."""

    def __init__(self, name: str):
        if iox2 is None:
            raise ImportError("reading snapshots from shared memory needs `pip install iceoryx2`")
        iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
        self._node = (
            iox2.NodeBuilder.new()
            .name(iox2.NodeName.new("fpm-python-snapshots"))
            .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
            .create(iox2.ServiceType.Ipc)
        )
        self._service = (
            self._node.service_builder(iox2.ServiceName.new(name))
            .publish_subscribe(iox2.Slice[ctypes.c_float])
            .user_header(SnapshotHeader)
            .max_publishers(1)
            .max_subscribers(MAX_VIEWERS)
            .history_size(1)
            .subscriber_max_buffer_size(2)
            .enable_safe_overflow(True)
            .open_or_create()
        )
        self._subscriber = self._service.subscriber_builder().create()

    def newest(self, timeout: float = 0.0, after_seq: int = -1) -> Optional[Snapshot]:
        """The newest snapshot published (all older ones waiting are skipped), waiting
        up to ``timeout`` s for one whose ``seq`` is above ``after_seq``; None if none
        came."""
        deadline = time.monotonic() + timeout
        newest = None
        while True:
            while True:
                sample = self._subscriber.receive()
                if sample is None:
                    break
                snapshot = _copied(sample)
                del sample  # released at once: the service's buffer is small
                if snapshot.seq > after_seq:
                    newest = snapshot
            if newest is not None or time.monotonic() >= deadline:
                return newest
            time.sleep(0.005)

    def close(self) -> None:
        """Release the ports (also on garbage collection)."""
        self._subscriber = None
        self._service = None
        self._node = None


def _copied(sample) -> Snapshot:
    """A received sample as a ``Snapshot``, copied out of shared memory (the sample is
    released right after)."""
    h = sample.user_header().contents
    area = h.width * h.height
    values = np.frombuffer(
        (ctypes.c_float * (2 * area)).from_address(sample.payload().data_ptr), dtype=np.float32
    )
    shape = (h.height, h.width)
    return Snapshot(
        job=h.job,
        seq=h.seq,
        frames=h.frames,
        of=h.of,
        finished=bool(h.finished),
        pixel_um=h.pixel_um,
        amplitude=values[:area].reshape(shape).copy(),
        phase=values[area:].reshape(shape).copy(),
    )
