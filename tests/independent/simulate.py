"""An FPM data set from a forward model we did not write: NumPy, from the physics of
docs/dataset.md (§1.1 axes, §1.2 the array, §1.3 illumination and Fourier convention,
§2 image formation), not from fpm's Rust code, so that a bias shared by fpm's simulator
and fpm's solver cannot hide (issue 63).

The sample: complex, sampled at half the camera's sample-plane pixel, and larger than
the field (a quarter field beyond each edge: light from outside the field reaches its
edges, as on a slide). Each LED of a 21×21 grid lights it with its exact spherical wave
exp(i2πR/λ), R the distance from the LED (or, with --plane, a plane wave at its angle
from the field's centre). The exit field's spectrum is cut by a circular pupil of
radius NA/λ (a telecentric objective) at the camera's sampling, its intensity taken on
the camera's field, Poisson noise at 20 000 photo-electrons for the clear sample, a
dark level of 100 counts with 3 counts of read noise, 16-bit linear counts.

Writes OUT/dataset.toml, OUT/frames/, and the truth (truth.json, truth_amplitude.tif,
truth_phase.tif over exactly the camera's field at the sample's pixel, docs/dataset.md
§5.8), so that `fpm reconstruct` scores itself against the hidden sample.

    python simulate.py OUT --size 256 [--sample smooth|cells] [--pitch-mm 2.5]
        [--height-mm 90] [--plane] [--seed 1]
"""
import argparse
import json
from pathlib import Path

import numpy as np
import tifffile

WAVELENGTH_UM, NA, MAGNIFICATION, CAMERA_PIXEL_UM = 0.53, 0.1, 4.0, 2.4
ROWS = COLS = 21
CENTER = (10, 10)
DARK, CLEAR_ELECTRONS, READ_NOISE = 100.0, 20000.0, 3.0
# The sample's pixel is the camera's (at the sample) over this: fine enough for the
# widest synthetic aperture here (NA + the corner LED's sine < 0.5 at λ 0.53 µm).
SAMPLE_UPSAMPLE = 2


def sample(n, pixel_um, kind, rng):
    """Amplitude and phase of an n×n sample: smooth random texture at a few scales
    (`smooth`), or overlapping discs with sharp edges, each absorbing and delaying
    (`cells`)."""
    if kind == "cells":
        amplitude, phase = np.ones((n, n)), np.zeros((n, n))
        x = np.arange(n) * pixel_um
        xx, yy = np.meshgrid(x, x)
        for _ in range(int(60 * (n * pixel_um / 200) ** 2)):
            cx, cy, radius = rng.uniform(0, n * pixel_um, 2).tolist() + [rng.uniform(2, 12)]
            inside = np.hypot(xx - cx, yy - cy) < radius
            amplitude[inside] *= rng.uniform(0.3, 0.95)
            phase[inside] += rng.uniform(0.3, 1.5)
        return amplitude, phase
    f = np.fft.fftfreq(n, pixel_um)
    radial = np.hypot(f[None, :], f[:, None])

    def texture(scale_um):
        g = np.fft.ifft2(np.fft.fft2(rng.standard_normal((n, n))) * np.exp(-(radial * scale_um) ** 2)).real
        return (g - g.mean()) / g.std()

    amplitude = np.clip(0.8 + 0.12 * texture(1.2) + 0.05 * texture(4.0), 0.2, 1.2)
    return amplitude, 0.8 * texture(1.0) + 0.4 * texture(5.0)


def centred_fft(a):
    return np.fft.fftshift(np.fft.fft2(np.fft.ifftshift(a)))


def centred_ifft(a):
    return np.fft.fftshift(np.fft.ifft2(np.fft.ifftshift(a)))


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", type=Path)
    p.add_argument("--size", type=int, default=256, help="camera frame side, pixels")
    p.add_argument("--sample", choices=["smooth", "cells"], default="smooth")
    p.add_argument("--pitch-mm", type=float, default=2.5)
    p.add_argument("--height-mm", type=float, default=90.0)
    p.add_argument("--plane", action="store_true", help="plane waves from the field's centre")
    p.add_argument("--seed", type=int, default=1)
    a = p.parse_args()
    rng = np.random.default_rng(a.seed)
    n = a.size
    camera_um = CAMERA_PIXEL_UM / MAGNIFICATION
    pad = n // 4
    n_low = n + 2 * pad
    n_high = n_low * SAMPLE_UPSAMPLE
    pixel_um = camera_um / SAMPLE_UPSAMPLE
    amplitude, phase = sample(n_high, pixel_um, a.sample, rng)
    transmission = amplitude * np.exp(1j * phase)
    # The optical axis at index n/2 (docs/dataset.md §1.1); LED positions in µm (§1.2,
    # θ = 0, no offset), h below the sample.
    x = (np.arange(n_high) - n_high // 2) * pixel_um
    xx, yy = np.meshgrid(x, x)
    f = (np.arange(n_low) - n_low // 2) / (n_low * camera_um)
    pupil = np.hypot(f[None, :], f[:, None]) <= NA / WAVELENGTH_UM
    h_um = a.height_mm * 1e3
    lo = (n_high - n_low) // 2
    (a.out / "frames").mkdir(parents=True, exist_ok=True)
    names = []
    for row in range(ROWS):
        for col in range(COLS):
            led_x = (col - CENTER[1]) * a.pitch_mm * 1e3
            led_y = (row - CENTER[0]) * a.pitch_mm * 1e3
            if a.plane:
                # exp(+i2π f_i·x), f_i = (s_x, s_y)/λ with s from the LED to the centre (§1.3).
                r0 = np.sqrt(led_x**2 + led_y**2 + h_um**2)
                path = -(xx * led_x + yy * led_y) / r0
            else:
                path = np.sqrt((xx - led_x) ** 2 + (yy - led_y) ** 2 + h_um**2) - h_um
            exit_wave = transmission * np.exp(2j * np.pi * path / WAVELENGTH_UM)
            spectrum = centred_fft(exit_wave)[lo:lo + n_low, lo:lo + n_low] * pupil
            field = centred_ifft(spectrum) / SAMPLE_UPSAMPLE**2
            intensity = np.abs(field[pad:pad + n, pad:pad + n]) ** 2
            counts = rng.poisson(intensity * CLEAR_ELECTRONS) + DARK + rng.normal(0, READ_NOISE, intensity.shape)
            name = f"frames/r{row:02d}_c{col:02d}.tif"
            tifffile.imwrite(a.out / name, np.clip(np.round(counts), 0, 65535).astype(np.uint16))
            names.append((name, row, col))
    with open(a.out / "dataset.toml", "w") as toml:
        toml.write(
            f"[system]\nwavelength_um = {WAVELENGTH_UM}\nna = {NA}\nmagnification = {MAGNIFICATION}\n"
            f"pixel_size_um = {CAMERA_PIXEL_UM}\n\n[led]\nrows = {ROWS}\ncols = {COLS}\n"
            f"pitch_mm = {a.pitch_mm}\nheight_mm = {a.height_mm}\ncenter = [{CENTER[0]}, {CENTER[1]}]\n\n"
            f"[camera]\ndark_level = {DARK}\nbit_depth = 16\ngamma = 1.0\n\n"
        )
        for name, row, col in names:
            toml.write(f'[[frame]]\nfile = "{name}"\nled = [{row}, {col}]\n\n')
    field_lo = pad * SAMPLE_UPSAMPLE
    crop = (slice(field_lo, field_lo + n * SAMPLE_UPSAMPLE),) * 2
    tifffile.imwrite(a.out / "truth_amplitude.tif", amplitude[crop].astype(np.float32))
    tifffile.imwrite(a.out / "truth_phase.tif", phase[crop].astype(np.float32))
    truth = {"dx_mm": 0.0, "dy_mm": 0.0, "theta_deg": 0.0, "height_mm": a.height_mm,
             "seed": a.seed, "object_pixel_um": pixel_um}
    (a.out / "truth.json").write_text(json.dumps(truth))


if __name__ == "__main__":
    main()
