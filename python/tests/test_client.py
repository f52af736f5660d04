"""fpm.Client against a real `fpm serve --virtual` on 127.0.0.1: an acquisition queued,
followed through the event stream and written; live snapshots and camera frames as
NumPy arrays; a second acquisition cancelled mid-sequence; a bad request refused
naming its field."""

import json
import subprocess
import threading
import time

import numpy as np
import pytest

import fpm


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


def test_a_reconstruct_job_makes_what_fpm_reconstruct_makes(service, fpm_cli, tmp_path):
    tifffile = pytest.importorskip("tifffile")
    dataset = tmp_path / "field"
    service.wait(service.acquire(dataset, step_ms=15.0), timeout=120)
    events = service.events()
    job = service.reconstruct(dataset, tmp_path / "rec", passes=3, flatten_background=True)
    work = []
    for event in events:
        if event.get("job") != job:
            continue
        # The frame updates' count (frames of more than 8 bits stating no gamma are
        # first screened for one: "camera gamma candidates", counted on their own).
        if event["event"] == "work" and event["what"] == "frame updates":
            work.append((event["done"], event["total"]))
        elif event["event"] == "state" and event["state"] in fpm.client.FINAL_STATES:
            assert event["state"] == "done", service.job(job)
            break
    assert work and work[-1][0] == work[-1][1] and work == sorted(work), work
    record = service.job(job)
    assert record["kind"] == "reconstruct" and record["summary"]["passes"] == 3
    assert record["reports"] == ["report.html"]
    subprocess.run(
        [fpm_cli, "reconstruct", str(dataset), "--out", str(tmp_path / "cli"), "--passes", "3",
         "--flatten-background"],
        check=True, capture_output=True,
    )
    ours = tifffile.imread(tmp_path / "rec" / "amplitude.tif")
    theirs = tifffile.imread(tmp_path / "cli" / "amplitude.tif")
    assert np.array_equal(ours, theirs)
    # The finished image is the job's snapshot.
    assert np.array_equal(service.snapshot(job).amplitude, ours)
    with pytest.raises(fpm.ServiceError, match=r"400: dataset .*no dataset.toml"):
        service.reconstruct(tmp_path / "nothing-here")


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


def test_a_raw_sequence_takes_the_leds_given_in_their_order(service, tmp_path):
    leds = [(10, 10), (0, 0), (10, 11), (20, 20)]
    job = service.sequence(leds, tmp_path / "seq", step_ms=15.0)
    record = service.wait(job, timeout=60)
    assert record["state"] == "done", record
    assert record["kind"] == "sequence"
    ds = fpm.Dataset.load(tmp_path / "seq")
    assert sorted(tuple(led) for led in ds.leds) == sorted(leds)
    summary = record["summary"]
    assert summary["capture"]["requested"] == 4 and summary["frames_in_dataset"] == 4
    assert [tuple(l) for l in summary["still_missing"]] == []
    # The centre LED lights the field (bright field); a corner LED leaves it dark.
    at = {tuple(led): k for k, led in enumerate(ds.leds)}
    centre, corner = ds.frame(at[(10, 10)]), ds.frame(at[(0, 0)])
    assert centre.mean() > 5 * corner.mean(), (centre.mean(), corner.mean())
    # An LED the board does not have: the job fails naming it.
    bad = service.wait(service.sequence([(30, 30)], tmp_path / "bad"), timeout=60)
    assert bad["state"] == "failed" and "[30, 30] is not on the board" in bad["error"], bad


def test_a_scan_job_takes_its_fields_as_datasets(service, tmp_path):
    # Two fields, the centre LED only: the request the client builds runs as a job,
    # each field an ordinary dataset where scan.json says the stage put it.
    job = service.scan((1, 2), tmp_path / "scan", overlap=0.3, leds=[[10, 10]], step_ms=15.0)
    record = service.wait(job, timeout=120)
    assert record["state"] == "done", record
    assert record["kind"] == "scan" and record["summary"]["acquired"] == 2
    manifest = json.loads((tmp_path / "scan" / "scan.json").read_text())
    fields = {f["dataset"]: f for f in manifest["fields"]}
    assert set(fields) == {"fields/r0c0", "fields/r0c1"}
    step = fields["fields/r0c1"]["stage_um"][0] - fields["fields/r0c0"]["stage_um"][0]
    width = record["summary"]["field_um"][0]
    assert abs(step - 0.7 * width) < 1e-6 * width, (step, width)
    for name in fields:
        assert len(fpm.Dataset.load(tmp_path / "scan" / name).leds) == 1
    with pytest.raises(fpm.ServiceError, match=r"400: fields"):
        service.scan((0, 2), tmp_path / "none")


def test_a_bad_request_is_refused_naming_its_field(service, tmp_path):
    with pytest.raises(fpm.ServiceError, match=r"400: passes: invalid type"):
        service.acquire(tmp_path / "x", passes="five")
    with pytest.raises(fpm.ServiceError, match=r"401: .*token"):
        fpm.Client(service.address, token="wrong").acquire(tmp_path / "y")
    assert service.jobs() == []


def test_a_board_of_another_protocol_is_refused_with_the_way_out(fpm_cli, tmp_path):
    """A board flashed with older firmware (the emulated controller reporting protocol
    0.9): the service refuses every job that would drive it, and the client raises
    that refusal with the way out, before anything is queued."""
    from conftest import _serve

    link = tmp_path / "ctl.tty"
    board = subprocess.Popen(
        [fpm_cli, "emulator", "--link", str(link), "--no-camera", "--report-protocol", "0.9"],
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 20
        while not link.exists():
            assert board.poll() is None and time.monotonic() < deadline, "no emulator"
            time.sleep(0.02)
        served = _serve(fpm_cli, tmp_path / "state", rig=["--port", str(link)])
        client = next(served)
        try:
            with pytest.raises(fpm.ServiceError, match=r"(?s)409: .*0\.9.*fpm device flash"):
                client.acquire(tmp_path / "x")
            assert client.jobs() == []
            assert client.status()["controller"]["state"] == "mismatch"
        finally:
            served.close()
    finally:
        board.terminate()
        board.wait(timeout=30)


def _rig_of(client):
    """The virtual rig's name, as `fpm serve --virtual` describes it."""
    rig = client.status()["rig"]
    assert rig.startswith("virtual rig "), rig
    return rig.removeprefix("virtual rig ").split(":")[0]


def test_calibrate_acquire_and_cancel_a_second_as_a_notebook_would(
    calibratable, fpm_cli, tmp_path
):
    """The service's whole round from Python: a calibration stored on the board, an
    acquisition reconstructing from it with live snapshots, a second one cancelled as
    its frames come; the first's image is the one `fpm acquire` makes on the same rig."""
    tifffile = pytest.importorskip("tifffile")
    service = calibratable
    events = service.events()
    cal = service.calibrate(tmp_path / "calibration", defocus_sigma_um=0.0)
    first = service.acquire(
        tmp_path / "first", step_ms=15.0, reconstruct=True, flatten_background=True,
        snapshot_every=150, passes=2,
    )
    second = service.acquire(tmp_path / "second", step_ms=40.0)
    # The cancel is sent from a thread of its own a second after the service says the
    # second runs, as a notebook's button would: this loop's events lag behind the rig
    # while it fetches the first job's snapshots, and on a loaded machine the service's
    # frame count does too (the virtual camera falls behind the LEDs, and frames are
    # labelled online only while their arrival keeps pace with the controller's steps).
    at_cancel = {}

    def cancel_second_once_it_runs():
        while True:
            if service.status()["running"] == second:
                time.sleep(1.0)
                at_cancel["frames"] = service.status()["progress"]["frames"]
                at_cancel["asked"] = time.time()
                service.cancel(second)
                return
            if service.job(second)["state"] in fpm.client.FINAL_STATES:
                return
            time.sleep(0.02)

    canceller = threading.Thread(target=cancel_second_once_it_runs, daemon=True)
    canceller.start()
    ended, snapshots, running_at = {}, [], {}
    for event in events:
        job, kind = event.get("job"), event["event"]
        if kind == "snapshot" and job == first:
            snapshots.append(service.snapshot(first))
        elif kind == "state" and event["state"] == "running":
            running_at[job] = event["at_s"]
        elif kind == "state" and event["state"] in fpm.client.FINAL_STATES:
            ended[job] = event
            if job == second:
                break
    canceller.join(timeout=30)
    seen_at_cancel, asked = at_cancel["frames"], at_cancel["asked"]
    assert [ended[j]["state"] for j in (cal, first, second)] == ["done", "done", "cancelled"]
    calibration = service.job(cal)
    assert (tmp_path / "calibration" / "calibration.json").is_file()
    assert "calibration.html" in calibration["reports"]
    # The acquisition after it started from the calibration stored on the board.
    record = service.job(first)
    assert record["summary"]["geometry_source"] == "board", record["summary"]
    assert [s.frames for s in snapshots] == [150, 300, 441]
    assert snapshots[-1].finished
    # The second stopped at the cancel, its frames kept: at 40 ms an LED, no more frames
    # than the LEDs lit between its start and its cancelled event (18 s for all 441).
    kept = service.job(second)["summary"]["frames_in_dataset"]
    lit_by_then = (ended[second]["at_s"] - running_at[second]) / 0.040
    assert seen_at_cancel <= kept <= lit_by_then + 2 and kept < 441, (
        seen_at_cancel, kept, lit_by_then)
    print(f"cancel → cancelled event: {1e3 * (ended[second]['at_s'] - asked):.0f} ms; "
          f"{kept - seen_at_cancel} frames after the {seen_at_cancel} seen")
    # The same acquisition by the command line on the same rig (the service is idle).
    rig = _rig_of(service)
    out = tmp_path / "by-the-cli"
    subprocess.run(
        [fpm_cli, "acquire", "--port", str(tmp_path / "state" / "virtual-rig" / "controller.tty"),
         "--frames", rig, "--stage", "virtual", "--rig", rig, "--out", str(out),
         "--step-ms", "15", "--reconstruct", "--flatten-background", "--passes", "2"],
        check=True, capture_output=True, text=True,
    )
    cli = json.loads((out / "acquisition.json").read_text())
    assert cli["geometry_source"] == "board"
    ours = tifffile.imread(tmp_path / "first" / "reconstruction" / "amplitude.tif")
    theirs = tifffile.imread(out / "reconstruction" / "amplitude.tif")
    assert ours.shape == theirs.shape
    assert np.allclose(snapshots[-1].amplitude, ours, rtol=1e-6)
    difference = np.linalg.norm(ours - theirs) / np.linalg.norm(theirs)
    print(f"service vs fpm acquire: amplitude differs by {difference:.4f} (relative L2)")
    assert difference < 0.02, difference


def test_snapshots_read_from_shared_memory_equal_the_http_ones(service):
    from fpm.local import SnapshotReader

    reader = SnapshotReader(service.status()["snapshot_service"])
    events = service.events()
    job = service.acquire(step_ms=15.0, reconstruct=True, snapshot_every=200)
    seen = []
    for event in events:
        if event.get("job") != job:
            continue
        if event["event"] == "snapshot":
            local = reader.newest(timeout=2.0, after_seq=event["seq"] - 1)
            assert local is not None and local.seq == event["seq"], (local, event)
            seen.append(local)
        elif event["event"] == "state" and event["state"] in fpm.client.FINAL_STATES:
            break
    assert [s.frames for s in seen] == [200, 400, 441] and seen[-1].finished
    over_http = service.snapshot(job)
    assert np.array_equal(seen[-1].amplitude, over_http.amplitude)
    assert np.array_equal(seen[-1].phase, over_http.phase)
    assert seen[-1].pixel_um == over_http.pixel_um
    reader.close()
