"""Streaming from Python: frames pushed as a camera loop would, snapshots on the way,
and a finish that matches the offline run."""

import numpy as np
import pytest

import fpm


def aligned_difference(a, b):
    """‖a − b·e^{iφ}‖ / ‖a‖ for the best global phase φ."""
    phase = np.vdot(b, a)
    b = b * (phase / abs(phase))
    return np.linalg.norm(a - b) / np.linalg.norm(a)


def test_streamed_matches_offline(acquisition, placement):
    ds, _ = acquisition
    geometry = dict(ds.geometry, **placement)
    height, width = ds.frame(0).shape
    stream = fpm.Streaming(ds.system, geometry, width, height, dark_level=ds.dark_level)
    assert stream.snapshot() is None
    order = sorted(range(len(ds)), key=lambda k: abs(ds.leds[k][0] - 10) + abs(ds.leds[k][1] - 10))
    for k in order:
        stream.push(ds.leds[k], ds.frame(k), exposure_ms=ds.exposure_ms[k])
    assert stream.received == len(ds)
    early = stream.snapshot()
    assert early is not None and early.shape == (4 * height, 4 * width)
    streamed = stream.finish(passes=4)
    offline = fpm.reconstruct(ds, geometry=geometry, passes=5)
    assert streamed.object.shape == offline.object.shape
    difference = aligned_difference(offline.object, streamed.object)
    assert difference < 0.05, difference
    assert aligned_difference(offline.object, early) > difference
    with pytest.raises(fpm.FpmError, match="finished"):
        stream.push(ds.leds[0], ds.frame(0))


def test_bad_frames_are_refused_and_named(acquisition):
    ds, _ = acquisition
    stream = fpm.Streaming(ds.system, ds.geometry, 64, 64)
    with pytest.raises(ValueError, match=r"frame 0 \(LED \(10, 10\)\).*\(32, 64\)"):
        stream.push((10, 10), np.zeros((32, 64), np.uint16))
    with pytest.raises(ValueError, match="not on the 21x21 array"):
        stream.push((30, 1), np.zeros((64, 64), np.uint16))
    with pytest.raises(ValueError, match="exposure_ms"):
        stream.push((10, 10), np.zeros((64, 64), np.uint16), exposure_ms=0.0)
    assert stream.received == 0


def test_an_entrance_pupil_that_is_no_distance_is_refused(acquisition):
    ds, _ = acquisition
    for bad in (0.0, -20.0):
        with pytest.raises(ValueError, match="entrance_pupil_mm"):
            fpm.Streaming(dict(ds.system, entrance_pupil_mm=bad), ds.geometry, 64, 64)
    stream = fpm.Streaming(dict(ds.system, entrance_pupil_mm=40.0), ds.geometry, 64, 64)
    assert stream.received == 0


def test_settings_out_of_range_are_refused_as_a_reconstruction_refuses_them(acquisition):
    ds, _ = acquisition
    for kwargs, name in (
        (dict(upsample=0), r"upsample 0: must be 1-64"),
        (dict(upsample=65), r"upsample 65: must be 1-64"),
        (dict(floor_sigma=-1.0), r"floor_sigma -1: must be 0 or more"),
        (dict(noise_band_sigma=-1.0), r"noise_band_sigma -1: must be 0 or more"),
    ):
        with pytest.raises(ValueError, match=name):
            fpm.Streaming(ds.system, ds.geometry, 64, 64, **kwargs)
