"""From a dataset to an image, in Python: a notebook-style walk through the `fpm`
package (each `# %%` is a cell). It runs top to bottom as a script, and CI runs it:

    pip install ./python
    python examples/python_session.py [OUT_DIR]
"""

# %% Setup
import sys
import tempfile
from pathlib import Path

import numpy as np

import fpm

repo = Path(__file__).resolve().parents[1]
out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="fpm-"))
print(f"fpm {fpm.__version__}, writing into {out}")

# %% 1. Calibrate the LED array (pdcFPM) from a defocus set
# The simulator hides a misplaced array (1.2 mm, -0.8 mm, 4°, 91 mm); the dataset
# states only the nominal one, as a home-built rig's would.
rig = dict(dx_mm=1.2, dy_mm=-0.8, theta_deg=4.0, height_mm=91.0)
calibration_set, truth = fpm.simulate_calibration(out / "calibration", seed=5, **rig)
cal = fpm.calibrate(calibration_set)
sigma = cal.uncertainty
print(f"Δx = {cal.dx_mm:+.4f} ± {sigma['dx_mm']:.4f} mm (truth {truth['dx_mm']:+.4f})")
print(f"Δy = {cal.dy_mm:+.4f} ± {sigma['dy_mm']:.4f} mm (truth {truth['dy_mm']:+.4f})")
print(f"θ  = {cal.theta_deg:+.4f} ± {sigma['theta_deg']:.4f} ° (truth {truth['theta_deg']:+.4f})")
print(f"h  = {cal.height_mm:.3f} ± {sigma['height_mm']:.3f} mm (truth {truth['height_mm']:.3f})")
for warning in cal.warnings:
    print("warning:", warning)

# %% 2. Reconstruct an acquisition of the same rig with the calibrated array
acquisition, _ = fpm.simulate_acquisition(out / "acquisition", size=128, seed=5, **rig)


shown = {"quarters": 0}


def progress(done, total):
    """Called from the reconstruction as frame updates complete (tqdm works too)."""
    quarters = 4 * done // total
    if quarters > shown["quarters"]:
        shown["quarters"] = quarters
        print(f"  {done}/{total} frame updates")


nominal = fpm.reconstruct(acquisition, passes=5)
calibrated = fpm.reconstruct(acquisition, geometry=cal, passes=5, progress=progress)
print(
    "complex NRMSE against the hidden sample:"
    f" nominal array {nominal.report['versus_truth']['complex_nrmse']:.3f},"
    f" calibrated {calibrated.report['versus_truth']['complex_nrmse']:.3f}"
)

# %% 3. Real data: the repository's USAF target (Zuo lab, 11×11 LEDs)
usaf = fpm.Dataset.load(repo / "data" / "zuo-usaf-11x11")
frame = usaf.frame(0)  # a read-only NumPy view, no copy
print(f"{usaf}: frame 0 is {frame.dtype}, mean {frame.mean():.1f} counts")
result = fpm.reconstruct(usaf, passes=5)
amplitude, phase = result.amplitude, result.phase
print(
    f"{amplitude.shape[1]}x{amplitude.shape[0]} pixels of {result.pixel_um:.3f} µm;"
    f" phase spans {np.ptp(phase):.2f} rad"
)
result.save(out / "usaf")
print(f"wrote {out / 'usaf'} (amplitude.tif, phase.tif, PNG previews, report.json)")
