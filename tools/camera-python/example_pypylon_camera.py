"""A Basler camera through pypylon into fpm: grab on each trigger, publish with
fpm_camera. Runs without hardware on pylon's camera emulation (`--emulated`), where a
software trigger fired on each trigger-out pulse of a virtual rig stands in for the
cable from the LED controller to the camera's Line0.

    python example_pypylon_camera.py --camera CAM [--serial SN]             # a real camera
    python example_pypylon_camera.py --camera CAM --emulated --rig RIG      # no hardware

With a real camera, wire the controller's trigger-out to Line0: the camera is set to
TriggerMode On, TriggerSource Line0, and frames are stamped by the camera's own clock
(`GrabResult.TimeStamp`). Only the transport layer needed is opened: pylon's
`TlFactory.EnumerateDevices()` would also send GigE Vision discovery broadcasts.
"""

import argparse
import os
import signal
import sys
import time

from fpm_camera import FramePublisher, RigTriggers, SettingsPublisher


def open_camera(pylon, emulated: bool, serial: str | None):
    factory = pylon.TlFactory.GetInstance()
    if emulated:
        layer = factory.CreateTl("BaslerCamEmu")
        devices = layer.EnumerateDevices()
        if not devices:
            raise SystemExit("pylon's camera emulation found no device (PYLON_CAMEMU unset?)")
        return pylon.InstantCamera(layer.CreateDevice(devices[0]))
    info = pylon.DeviceInfo()
    if serial:
        info.SetSerialNumber(serial)
    return pylon.InstantCamera(factory.CreateFirstDevice(info))


def feature(camera, name: str):
    """A feature's value, or None where the camera does not have it (or not now)."""
    from pypylon import genicam

    node = camera.GetNodeMap().GetNode(name)
    if node is None or not genicam.IsReadable(node):
        return None
    return getattr(camera, name).GetValue()


def encoding_gamma(camera) -> float | None:
    """The gamma that decodes the frames (`encoding_gamma`: the dataset's `[camera]
    gamma`), by the rule `fpm camera run` applies to GenICam cameras: a lookup table
    on says nothing; GammaEnable off or no Gamma feature is raw counts (1); the sRGB
    curve is 2.2; otherwise the inverse of Gamma (the camera outputs
    full·(v/full)^Gamma)."""
    if feature(camera, "LUTEnable"):
        return None
    if feature(camera, "GammaEnable") is False:
        return 1.0
    if str(feature(camera, "GammaSelector") or "").lower() == "srgb":
        return 2.2
    gamma = feature(camera, "Gamma")
    if gamma is None:
        return 1.0
    return 1.0 / gamma if gamma >= 0.2 else None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--camera", required=True, help="fpm camera id (fpm/camera/<ID>/frames)")
    ap.add_argument("--serial", help="the Basler camera's serial number")
    ap.add_argument("--emulated", action="store_true", help="pylon's camera emulation")
    ap.add_argument("--rig", help="with --emulated: trigger on this virtual rig's pulses")
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--height", type=int, default=64)
    ap.add_argument("--pixel-format", default="Mono12")
    ap.add_argument("--exposure-us", type=float, default=5000.0)
    ap.add_argument("--ready-file", help="written once listening")
    args = ap.parse_args()
    if args.emulated:
        os.environ.setdefault("PYLON_CAMEMU", "1")
    from pypylon import pylon  # after PYLON_CAMEMU is set

    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    camera = open_camera(pylon, args.emulated, args.serial)
    camera.Open()
    camera.PixelFormat.SetValue(args.pixel_format)
    camera.Width.SetValue(args.width)
    camera.Height.SetValue(args.height)
    if hasattr(camera, "ExposureTimeAbs"):
        camera.ExposureTimeAbs.SetValue(args.exposure_us)
    elif hasattr(camera, "ExposureTime"):
        camera.ExposureTime.SetValue(args.exposure_us)
    bits = {"Mono8": 8, "Mono10": 10, "Mono12": 12, "Mono16": 16}.get(args.pixel_format, 16)
    camera.TriggerSelector.SetValue("FrameStart")
    camera.TriggerMode.SetValue("On")
    software = args.emulated
    camera.TriggerSource.SetValue("Software" if software else "Line0")
    triggers = RigTriggers(args.rig) if software and args.rig else None
    info = camera.GetDeviceInfo()
    applied = {
        "vendor": info.GetVendorName(),
        "model": info.GetModelName(),
        "serial": info.GetSerialNumber(),
        "pixel_format": camera.PixelFormat.GetValue(),
        "bit_depth": bits,
        "roi": [camera.OffsetX.GetValue(), camera.OffsetY.GetValue(),
                camera.Width.GetValue(), camera.Height.GetValue()],
        # Read back from the feature set above.
        "exposure_us": feature(camera, "ExposureTimeAbs") or feature(camera, "ExposureTime"),
        "trigger_mode": camera.TriggerMode.GetValue(),
        "trigger_source": camera.TriggerSource.GetValue(),
    }
    gamma = encoding_gamma(camera)
    if gamma is not None:
        applied["encoding_gamma"] = gamma
    pitch = feature(camera, "SensorPixelWidth")
    if pitch is not None:
        applied["pixel_size_um"] = pitch
    settings = SettingsPublisher(args.camera, applied)
    camera.StartGrabbing(pylon.GrabStrategy_OneByOne)
    published = 0
    with FramePublisher(args.camera, max_pixels=args.width * args.height) as fpm:
        if args.ready_file:
            open(args.ready_file, "w").close()
        while not stop:
            settings.serve()
            if triggers is not None:
                if triggers.next(0.1) is None:
                    continue
                camera.WaitForFrameTriggerReady(1000, pylon.TimeoutHandling_ThrowException)
                triggered_ns = time.monotonic_ns()
                camera.ExecuteSoftwareTrigger()
            # Waiting on a hardware trigger, come back often enough to serve the settings
            # to an acquisition that starts meanwhile (it waits 300 ms for them).
            result = camera.RetrieveResult(1000 if triggers else 100, pylon.TimeoutHandling_Return)
            if not result or not result.IsValid():
                continue
            try:
                if not result.GrabSucceeded():
                    print(f"grab failed: {result.GetErrorDescription()}", file=sys.stderr)
                    continue
                # The camera's clock; the emulation stamps 0, so there the host's clock
                # at the software trigger stands in (fpm fits either to the controller's).
                stamp = result.TimeStamp or (triggered_ns if triggers else time.monotonic_ns())
                fpm.publish(result.Array, timestamp_ns=stamp, exposure_us=int(args.exposure_us),
                            bit_depth=bits)
                published += 1
            finally:
                result.Release()
    camera.StopGrabbing()
    camera.Close()
    print(f"published {published} frames", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
