"""A camera for testing without hardware: answers every trigger pulse of a virtual rig
with a NumPy frame that shows which LED was lit (value 1000 + 32·row + col everywhere,
so a mislabelled frame is visible), stamped on a camera clock 2.5 s ahead of the
controller's, the way a pypylon, picamera2 or PySpin loop would publish its frames.

    python example_numpy_camera.py --rig RIG --camera CAM [--size 64] [--frames N]
"""

import argparse
import signal
import sys

import numpy as np

from fpm_camera import FramePublisher, RigTriggers, SettingsPublisher


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rig", required=True)
    ap.add_argument("--camera", required=True)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--frames", type=int, default=None, help="stop after this many")
    ap.add_argument("--ready-file", default=None, help="written once listening")
    args = ap.parse_args()
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    triggers = RigTriggers(args.rig)
    # What this camera applies: raw 12-bit counts (no gamma), one fixed exposure.
    settings = SettingsPublisher(
        args.camera,
        {
            "vendor": "fpm",
            "model": "example NumPy camera",
            "pixel_format": "Mono12",
            "bit_depth": 12,
            "roi": [0, 0, args.size, args.size],
            "exposure_us": 5000,
            "encoding_gamma": 1.0,
        },
    )
    with FramePublisher(args.camera, max_pixels=args.size * args.size) as camera:
        if args.ready_file:
            open(args.ready_file, "w").close()
        published = 0
        while not stop and (args.frames is None or published < args.frames):
            settings.serve()
            pulse = triggers.next(0.1)
            if pulse is None:
                continue
            lit = pulse.lit_leds()
            value = 1000 + 32 * lit[0][0] + lit[0][1] if lit else 100
            image = np.full((args.size, args.size), value, dtype=np.uint16)
            camera.publish(
                image,
                timestamp_ns=2_500_000_000 + pulse.time_us * 1000,
                exposure_us=5000,
                bit_depth=12,
            )
            published += 1
    print(f"published {published} frames", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
