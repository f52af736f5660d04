"""fpm.Client against a real `fpm serve --virtual` on 127.0.0.1: an acquisition queued,
followed through the event stream and written; live snapshots and camera frames as
NumPy arrays; a second acquisition cancelled mid-sequence; a bad request refused
naming its field."""

import subprocess
import time

import numpy as np
import pytest

import fpm


@pytest.fixture()
def service(fpm_cli, tmp_path):
    state = tmp_path / "state"
    process = subprocess.Popen(
        [fpm_cli, "serve", "--virtual", "--virtual-size", "64", "--listen", "127.0.0.1:0",
         "--state-dir", str(state)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        first = process.stdout.readline()
        assert first.startswith("fpm serve: listening on http://"), first
        address = first.strip().removeprefix("fpm serve: listening on http://")
        yield fpm.Client(address, state_dir=state)
    finally:
        process.terminate()
        process.wait(timeout=30)


def test_an_acquisition_is_queued_followed_and_written(service, tmp_path):
    out = tmp_path / "field"
    events = service.events()
    job = service.acquire(out, step_ms=15.0)
    states, frames = [], []
    for event in events:
        if event.get("job") != job:
            continue
        if event["event"] == "progress":
            frames.append(event["progress"]["frames"])
        elif event["event"] == "state":
            states.append(event["state"])
            if event["state"] in fpm.client.FINAL_STATES:
                break
    assert states == ["queued", "running", "done"]
    assert frames[-1] == 441 and frames == sorted(frames)
    record = service.job(job)
    assert record["summary"]["frames_in_dataset"] == 441
    assert len(fpm.Dataset.load(out)) == 441


def test_live_snapshots_and_camera_frames_come_as_numpy_arrays(service):
    tifffile = pytest.importorskip("tifffile")
    events = service.events()
    job = service.acquire(step_ms=15.0, reconstruct=True, snapshot_every=150)
    seen, frames = [], []
    for event in events:
        if event.get("job") != job:
            continue
        if event["event"] == "snapshot":
            # Fetched as it is announced: what a live viewer does.
            seen.append(service.snapshot(job))
        elif event["event"] == "camera_frame" and not frames:
            frames.append(service.camera_frame())
        elif event["event"] == "state" and event["state"] in fpm.client.FINAL_STATES:
            assert event["state"] == "done", event
            break
    assert [s.frames for s in seen] == [150, 300, 441]
    assert [s.finished for s in seen] == [False, False, True]
    last = seen[-1]
    # 64² frames, upsampled 4×: 256² pixels of 2.4 µm / 4× / 4.
    assert last.amplitude.shape == last.phase.shape == (256, 256)
    assert last.pixel_um == pytest.approx(2.4 / 4 / 4)
    out = service.job(job)["out"]
    written = tifffile.imread(f"{out}/reconstruction/amplitude.tif")
    assert np.allclose(last.amplitude, written, rtol=1e-6)
    # The stream's snapshots converge on it.
    errors = [np.linalg.norm(s.amplitude - written) / np.linalg.norm(written) for s in seen]
    assert errors[0] > errors[1] > errors[2] and errors[2] < 1e-6, errors
    frame = frames[0]
    assert frame.job == job and frame.pixels.shape == (64, 64)
    assert frame.pixels.dtype == np.uint16 and frame.pixels.max() > 0
    assert b"<html" in service.file(job, "acquisition.html")
    with pytest.raises(fpm.ServiceError, match="404"):
        service.snapshot(job + 100)


def test_a_cancelled_acquisition_keeps_what_it_captured(service, tmp_path):
    out = tmp_path / "cancelled"
    job = service.acquire(out, step_ms=15.0)
    while service.status()["running"] != job:
        time.sleep(0.05)
    time.sleep(1.0)  # into its capture sequence
    service.cancel(job)
    record = service.wait(job, timeout=60)
    assert record["state"] == "cancelled", record
    kept = record["summary"]["frames_in_dataset"]
    assert 0 < kept < 441
    with pytest.raises(fpm.ServiceError, match="already ended"):
        service.cancel(job)


def test_a_bad_request_is_refused_naming_its_field(service, tmp_path):
    with pytest.raises(fpm.ServiceError, match=r"400: passes: invalid type"):
        service.acquire(tmp_path / "x", passes="five")
    with pytest.raises(fpm.ServiceError, match=r"401: .*token"):
        fpm.Client(service.address, token="wrong").acquire(tmp_path / "y")
    assert service.jobs() == []
