"""Write an fpm dataset (a simulated one: a 21 x 21 grid, centred, in focus) in another
lab's format, as that lab's reference code reads it, for tests/tests/import.rs.

    python export.py FORMAT DATASET OUT [--mutate sign|axes|units] [--v73]

Each writer follows the source's public code, not fpm's conventions (docs/import.md
cites them); --mutate writes the same file with one convention broken on purpose, so
the test shows it would catch an importer that got that convention wrong.
"""

import argparse
import csv
import math
import pathlib
import tomllib

import numpy as np
import tifffile


def load(dataset):
    """The dataset's intensities (dark-subtracted, per ms) and each frame's LED
    position relative to the axis, mm (x along columns, y along rows), and height."""
    m = tomllib.loads((dataset / "dataset.toml").read_text())
    led = m["led"]
    r0, c0 = led["center"]
    pitch, height = led["pitch_mm"], led["height_mm"]
    dark = m.get("camera", {}).get("dark_level", 0.0)
    frames = []
    for f in m["frame"]:
        if f.get("defocus_um", 0.0) != 0.0:
            continue
        counts = tifffile.imread(dataset / f["file"]).astype(np.float64)
        intensity = (counts - dark) / f.get("exposure_ms", 1.0)
        r, c = f["led"]
        frames.append(((r, c), ((c - c0) * pitch, (r - r0) * pitch), intensity))
    return m, frames, height


def sines(x, y, h):
    """The LED's sines seen from the field's centre, (x, y)/R."""
    big_r = math.sqrt(x * x + y * y + h * h)
    return x / big_r, y / big_r


def save_mat(path, variables, v73):
    """MATLAB v5 (scipy, compressed as MATLAB's own `save` is) or v7.3 (HDF5 behind
    MATLAB's 512-byte user block, each array transposed as MATLAB stores it)."""
    if not v73:
        import scipy.io

        scipy.io.savemat(path, variables, do_compression=True)
        return
    import h5py

    with h5py.File(path, "w", userblock_size=512) as f:
        for name, value in variables.items():
            a = np.atleast_2d(np.asarray(value))
            d = f.create_dataset(name, data=a.T, compression="gzip")
            cls = {np.float64: "double", np.float32: "single", np.uint16: "uint16", np.uint8: "uint8"}
            d.attrs["MATLAB_class"] = np.bytes_(cls[a.dtype.type])
    with open(path, "r+b") as f:
        f.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created by: fpm tests".ljust(116, b" "))


def caltech(m, frames, height, out, mutate, v73):
    """FPM_software (hwzhou2020/FPM_software): imlow H x W x N, NA_list N x 2 with
    column 1 along the columns; its Gerchberg-Saxton code reads frame n at
    -(2 pi / lambda) NA_list(n, :), so NA_list holds the light's direction sines, the
    negative of the LED's own."""
    stack = np.stack([f[2] for f in frames], axis=-1)
    na_list = np.array([[-s for s in sines(x, y, height)] for _, (x, y), _ in frames])
    s = m["system"]
    lam, dpix = s["wavelength_um"], s["pixel_size_um"]
    if mutate == "sign":
        na_list = -na_list
    elif mutate == "axes":
        na_list = na_list[:, ::-1].copy()
    elif mutate == "units":
        lam, dpix = lam * 1e-6, dpix * 1e-6
    save_mat(
        out,
        {"imlow": stack, "NA_list": na_list, "NA": s["na"], "lambda": lam, "dpix_c": dpix, "mag": s["magnification"]},
        v73,
    )


def spiral(n):
    """LED_location.m's order: legs of 1, 1, 2, 2, ... along +x, +y, -x, -y."""
    steps, at, out, leg = [(1, 0), (0, 1), (-1, 0), (0, -1)], (0, 0), [(0, 0)], 0
    while len(out) < n:
        for _ in range(leg // 2 + 1):
            if len(out) < n:
                at = (at[0] + steps[leg % 4][0], at[1] + steps[leg % 4][1])
                out.append(at)
        leg += 1
    return out


def zheng(m, frames, height, out, mutate, v73):
    """The Zheng lab's files (SmartImagingLabUConn/Fourier-Ptychography): imlow_HDR
    H x W x 225 single amplitudes in LED_location.m's spiral around the centre LED of
    a 15 x 15 array, xint/yint (mm), theta (deg), wlength and z (m)."""
    led = m["led"]
    r0, c0 = led["center"]
    by_led = {f[0]: f[2] for f in frames}
    order = spiral(225)
    if mutate == "axes":
        order = [(y, x) for x, y in order]
    amplitudes = [np.sqrt(np.clip(by_led[(r0 + yi, c0 + xi)], 0, None)) for xi, yi in order]
    if mutate == "sign":
        amplitudes = [np.sqrt(np.clip(by_led[(r0 + yi, c0 - xi)], 0, None)) for xi, yi in order]
    wlength = m["system"]["wavelength_um"] * 1e-6
    if mutate == "units":
        wlength *= 1e6
    variables = {
        "imlow_HDR": np.stack(amplitudes, axis=-1).astype(np.float32),
        "xint": 0.0,
        "yint": 0.0,
        "theta": 0.0,
        "wlength": wlength,
        "z": 0.0,
        "aberration": 0.0,
    }
    save_mat(out, variables, v73)


def tiff_csv(m, frames, height, out, mutate, v73):
    """A multi-page TIFF (float32 intensities) and a CSV of each LED's position."""
    tifffile.imwrite(out, np.stack([f[2] for f in frames]).astype(np.float32))
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["row", "col", "x_mm", "y_mm"])
        for (r, c), (x, y), _ in frames:
            if mutate == "sign":
                x = -x
            elif mutate == "axes":
                x, y = y, x
            elif mutate == "units":
                x, y = x / 10, y / 10
            w.writerow([r, c, x, y])


def ptylab(m, frames, height, out, mutate, v73):
    """PtyLab's FPM HDF5 (PtyLab.py's loader): datasets at the root, ptychogram
    frames x rows x columns, encoder frames x 2 holding each LED's position in metres
    with column 0 along the rows, wavelength, dxd (the camera's pixel), zled in
    metres; PtyLab reads frame n's band at +encoder(n)/(lambda R)."""
    import h5py

    s = m["system"]
    encoder = np.array([[y * 1e-3, x * 1e-3] for _, (x, y), _ in frames])
    scale = 1e-6
    if mutate == "sign":
        encoder[:, 1] = -encoder[:, 1]
    elif mutate == "axes":
        encoder = encoder[:, ::-1].copy()
    elif mutate == "units":
        scale = 1.0
    with h5py.File(out, "w") as f:
        f["ptychogram"] = np.stack([fr[2] for fr in frames]).astype(np.float32)
        f["encoder"] = encoder
        f["wavelength"] = s["wavelength_um"] * scale
        f["dxd"] = s["pixel_size_um"] * scale
        f["zled"] = height * 1e-3
        f["magnification"] = s["magnification"]
        f["NA"] = s["na"]


def main():
    p = argparse.ArgumentParser()
    p.add_argument("format", choices=["caltech-mat", "zheng-mat", "ptylab-h5", "tiff-csv"])
    p.add_argument("dataset", type=pathlib.Path)
    p.add_argument("out", type=pathlib.Path)
    p.add_argument("--mutate", choices=["sign", "axes", "units"])
    p.add_argument("--v73", action="store_true")
    a = p.parse_args()
    m, frames, height = load(a.dataset)
    write = {"caltech-mat": caltech, "zheng-mat": zheng, "ptylab-h5": ptylab, "tiff-csv": tiff_csv}[a.format]
    write(m, frames, height, a.out, a.mutate, a.v73)


if __name__ == "__main__":
    main()
