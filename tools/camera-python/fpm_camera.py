"""Publish camera frames into fpm from Python: the reference driver side of the frame
contract (README "Camera frames over iceoryx2"), for cameras whose SDK only speaks
Python (pypylon, picamera2, PySpin, pycromanager, ...).

    from fpm_camera import FramePublisher
    with FramePublisher("0", max_pixels=2048 * 2048) as camera:
        for image, stamp_ns in my_sdk_frames():          # uint16 or uint8 2-D arrays
            camera.publish(image, timestamp_ns=stamp_ns, exposure_us=20000, bit_depth=12)

Each frame is copied once, from the SDK's array into the loaned shared-memory sample;
`fpm acquire --frames 0` reads it in place. The stamp must be the camera's own
timestamp of the exposure start (ns, any epoch): fpm fits the camera clock to the LED
controller's. `SettingsPublisher` says what the camera applied (pixel format, exposure,
its gamma), which `fpm acquire` records and states in the dataset. `RigTriggers` gives the trigger pulses of a virtual rig (`fpm emulator
--rig NAME`), for testing without a camera.
"""

from __future__ import annotations

import ctypes
import json
from typing import Optional

import iceoryx2 as iox2
import numpy as np

# The frame contract (host/frames in the Rust crates): names, type names, settings.
FRAME_READY = 1
MAX_SUBSCRIBERS = 2
SUBSCRIBER_BUFFER = 2
SUBSCRIBER_BORROWED = 1
PUBLISHER_LOANED = 1
MAX_SETTINGS_BYTES = 16 * 1024


class FrameHeader(ctypes.Structure):
    """`fpm::FrameHeader/1`: 48 bytes, little-endian, sent with every frame."""

    _fields_ = [
        ("frame_number", ctypes.c_uint64),
        ("timestamp_ns", ctypes.c_uint64),
        ("exposure_us", ctypes.c_uint32),
        ("width", ctypes.c_uint32),
        ("height", ctypes.c_uint32),
        ("bit_depth", ctypes.c_uint32),
        ("pixel_count", ctypes.c_uint64),
        ("camera_id", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
    ]

    @staticmethod
    def type_name() -> str:
        return "fpm::FrameHeader/1"


assert ctypes.sizeof(FrameHeader) == 48


class LitLed(ctypes.Structure):
    """`fpm::rig::LitLed/1`."""

    _fields_ = [
        ("row", ctypes.c_uint8),
        ("col", ctypes.c_uint8),
        ("rgb", ctypes.c_uint8 * 3),
        ("reserved", ctypes.c_uint8 * 3),
    ]

    @staticmethod
    def type_name() -> str:
        return "fpm::rig::LitLed/1"


class TriggerPulse(ctypes.Structure):
    """`fpm::rig::TriggerPulse/1`: the controller fired the camera trigger."""

    _fields_ = [
        ("pulse_number", ctypes.c_uint64),
        ("time_us", ctypes.c_uint64),
        ("lit_count", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32),
        ("lit", LitLed * 64),
    ]

    @staticmethod
    def type_name() -> str:
        return "fpm::rig::TriggerPulse/1"

    def lit_leds(self) -> list[tuple[int, int, tuple[int, int, int]]]:
        """(row, col, (r, g, b)) of the LEDs shining at the trigger."""
        return [
            (led.row, led.col, tuple(led.rgb))
            for led in self.lit[: min(self.lit_count, 64)]
        ]


def _node(name: str):
    # iceoryx2 says on every start that it runs without a config file, by design here.
    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    return (
        iox2.NodeBuilder.new()
        .name(iox2.NodeName.new(name))
        .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
        .create(iox2.ServiceType.Ipc)
    )


class FramePublisher:
    """Publishes one camera's frames on `fpm/camera/<camera>/frames` and signals each
    on `fpm/camera/<camera>/frame-ready`."""

    def __init__(self, camera: str, max_pixels: int, camera_id: int = 0):
        self.max_pixels = max_pixels
        self.camera_id = camera_id
        self.frame_number = 0
        self._node = _node("fpm-camera-python")
        frames = (
            self._node.service_builder(iox2.ServiceName.new(f"fpm/camera/{camera}/frames"))
            .publish_subscribe(iox2.Slice[ctypes.c_uint16])
            .user_header(FrameHeader)
            .max_publishers(1)
            .max_subscribers(MAX_SUBSCRIBERS)
            .subscriber_max_buffer_size(SUBSCRIBER_BUFFER)
            .subscriber_max_borrowed_samples(SUBSCRIBER_BORROWED)
            .history_size(0)
            .enable_safe_overflow(True)
            .open_or_create()
        )
        ready = (
            self._node.service_builder(iox2.ServiceName.new(f"fpm/camera/{camera}/frame-ready"))
            .event()
            .open_or_create()
        )
        self._publisher = (
            frames.publisher_builder()
            .initial_max_slice_len(max_pixels)
            .allocation_strategy(iox2.AllocationStrategy.Static)
            .max_loaned_samples(PUBLISHER_LOANED)
            .create()
        )
        self._notifier = ready.notifier_builder().create()
        self._services = (frames, ready)

    def publish(
        self,
        image: np.ndarray,
        timestamp_ns: int,
        exposure_us: int,
        bit_depth: int = 16,
        frame_number: Optional[int] = None,
    ) -> int:
        """Publish a 2-D image (uint8 or uint16, rows × columns) stamped with the
        camera's exposure start. Returns the frame number sent; a skipped number tells
        the host a frame was lost."""
        if image.ndim != 2:
            raise ValueError(f"a frame is a 2-D array, got shape {image.shape}")
        if image.dtype not in (np.uint8, np.uint16):
            raise ValueError(f"pixels must be uint8 or uint16, got {image.dtype}")
        if not 1 <= bit_depth <= 16:
            raise ValueError(f"bit_depth {bit_depth} is not in 1..16")
        height, width = image.shape
        n = width * height
        if n > self.max_pixels:
            raise ValueError(f"a {width}x{height} frame exceeds max_pixels {self.max_pixels}")
        if frame_number is not None:
            self.frame_number = frame_number
        sample = self._publisher.loan_slice_uninit(n)
        header = sample.user_header().contents
        header.frame_number = self.frame_number
        header.timestamp_ns = timestamp_ns
        header.exposure_us = exposure_us
        header.width = width
        header.height = height
        header.bit_depth = bit_depth
        header.pixel_count = n
        header.camera_id = self.camera_id
        header.flags = 0
        # The one copy: the SDK's pixels into shared memory (widened if 8-bit).
        target = np.frombuffer(
            (ctypes.c_uint16 * n).from_address(sample.payload().data_ptr), dtype=np.uint16
        ).reshape(height, width)
        np.copyto(target, image, casting="safe")
        sample.assume_init().send()
        self._notifier.notify_with_custom_event_id(iox2.EventId.new(FRAME_READY))
        sent = self.frame_number
        self.frame_number += 1
        return sent

    def close(self) -> None:
        """Release the ports (also on garbage collection)."""
        self._notifier = None
        self._publisher = None
        self._services = None
        self._node = None

    def __enter__(self) -> "FramePublisher":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class SettingsPublisher:
    """Publishes what the camera applied, a JSON document, on
    `fpm/camera/<camera>/settings` with a history of one, as `fpm camera run` does for
    a GenICam camera: `fpm acquire` records it in acquisition.json (`camera_settings`)
    and states its `encoding_gamma` as the dataset's `[camera] gamma` (1.0 for raw
    counts; 1/Gamma when the camera's Gamma feature is on; leave it out when a lookup
    table is on). Other keys it reads: `pixel_size_um`, `binning`,
    `published_pixel_factor` (a pitch that disagrees with `--pixel-um` is warned
    about). Call `serve()` in the frame loop: readers that connected since get the
    document then."""

    def __init__(self, camera: str, settings: dict):
        text = json.dumps(settings).encode()
        if len(text) > MAX_SETTINGS_BYTES:
            raise ValueError(f"settings of {len(text)} bytes exceed {MAX_SETTINGS_BYTES}")
        self._node = _node("fpm-camera-python-settings")
        service = (
            self._node.service_builder(iox2.ServiceName.new(f"fpm/camera/{camera}/settings"))
            .publish_subscribe(iox2.Slice[ctypes.c_uint8])
            .max_publishers(1)
            .history_size(1)
            .subscriber_max_buffer_size(1)
            .open_or_create()
        )
        self._publisher = (
            service.publisher_builder().initial_max_slice_len(MAX_SETTINGS_BYTES).create()
        )
        sample = self._publisher.loan_slice_uninit(len(text))
        ctypes.memmove(sample.payload().data_ptr, text, len(text))
        sample.assume_init().send()
        self._service = service

    def serve(self) -> None:
        """Hand the document to readers that connected since."""
        self._publisher.update_connections()

    def close(self) -> None:
        self._publisher = None
        self._service = None
        self._node = None


class RigTriggers:
    """The trigger pulses of a virtual rig (`fpm emulator --rig NAME`): what a camera on
    the controller's trigger-out would see, with the LEDs lit at that moment."""

    def __init__(self, rig: str):
        self._node = _node("fpm-camera-python-rig")
        service = (
            self._node.service_builder(iox2.ServiceName.new(f"fpm/rig/{rig}/trigger"))
            .publish_subscribe(TriggerPulse)
            .subscriber_max_buffer_size(1024)
            .history_size(0)
            .open_or_create()
        )
        self._subscriber = service.subscriber_builder().buffer_size(1024).create()
        self._service = service

    def next(self, timeout_s: float) -> Optional[TriggerPulse]:
        """The next pulse, or None after `timeout_s`."""
        import time

        deadline = time.monotonic() + timeout_s
        while True:
            sample = self._subscriber.receive()
            if sample is not None:
                pulse = TriggerPulse()
                ctypes.memmove(ctypes.addressof(pulse), sample.payload(), ctypes.sizeof(pulse))
                return pulse
            if time.monotonic() >= deadline:
                return None
            time.sleep(0.0005)
