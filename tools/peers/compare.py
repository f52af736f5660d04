#!/usr/bin/env python3
"""Compare `fpm reconstruct` with the published Python FPM packages fpm-rs and fpm-py.

Same machine, same frames (dark-subtracted, exposure-normalised, in-focus frames of a
dataset in the docs/dataset.md section 5 format), same illumination wave vectors, same
upsampling, same pass count, same frame order (increasing |f_i|, as `fpm reconstruct`
uses). Prints seconds per pass (reconstruction only, loading excluded), the ratio to
ours, and the complex NRMSE against the dataset's ground truth (docs/dataset.md section 6).

Run it through compare.sh, which sets up the venv with the pinned peers.

How each peer is fed (read from the installed sources, fpm-rs 0.2.0b3 / fpm-py 2.0.1;
fpm-rs 0.1.0, for Python >= 3.13, takes the same k vectors through its older API):
  fpm-rs  KVectorList of k = 2*pi*f_i (rad/m), the illumination vectors of docs/dataset.md
          section 1; checked against fpm-rs's own PlanarLEDArray built from [led].
          compile_model(reconstruction_shape = U x frame shape), Epry(iterations=N)
          with its default steps, schedule "sequential" = our frame order.
          fpm-rs crops sub-bin offsets by bilinear interpolation; the "bin-snapped"
          variant rounds each k to the nearest HR Fourier bin so that every crop is
          whole-bin (our own reconstruction reads the object at the nearest bin too).
  fpm-py  fpm_py.reconstruct(ImageSeries, output_scale_factor=U, max_iters=N,
          pupil_0=NA disc). k_vector = (f_y, f_x) in cycles/um (row, column order, as
          its crop code indexes) with du = 1/(N*pixel) cycles/um, so k/du is the
          crop offset in Fourier pixels; its own spatial_to_kvectors units do not
          match its crop code, so it is not used. Its default pupil is a disc of
          radius N/2 (the whole frame), not the objective NA, so the NA disc is
          passed as pupil_0. Its overlap_matrices adds each spectrum update H-1 rows
          above the patch it read, so the published reconstruction cannot converge;
          the "fpm-py-patched" variant swaps in an add at the read position (labelled
          in the table; not the published behaviour).
Both peers receive the physical illumination vector (+f_i) and, with their FFT and
crop conventions, return the complex conjugate of our object; the evaluation finds
such a conjugation/flip and prints it.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.metadata as md
import io
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PEERS = ("fpm-rs", "fpm-rs-snapped", "fpm-py", "fpm-py-patched")


def parse_args() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("dataset", type=Path, help="dataset directory (dataset.toml, frames, truth_*.tif)")
    p.add_argument("--passes", type=int, default=10, help="passes over all frames (default 10)")
    p.add_argument("--upsample", type=int, default=4, help="HR pixels per camera pixel (default 4)")
    p.add_argument("--json", type=Path, help="also write the table as JSON here")
    p.add_argument("--fpm", type=Path, default=REPO / "target/release/fpm",
                   help="our binary (default target/release/fpm; never built by this script)")
    p.add_argument("--threads", type=int, default=1,
                   help="threads for the peers (RAYON_NUM_THREADS, torch.set_num_threads); "
                        "default 1, what `fpm reconstruct` uses on a one-tile field")
    p.add_argument("--peers", default=",".join(PEERS),
                   help=f"comma list of peers to run (default: {','.join(PEERS)})")
    p.add_argument("--without-ours", action="store_true",
                   help="run the peers only (`fpm bench reconstruct` times ours itself)")
    p.add_argument("--truth-amplitude", type=Path, help="default DATASET/truth_amplitude.tif")
    p.add_argument("--truth-phase", type=Path, help="default DATASET/truth_phase.tif")
    p.add_argument("--keep", type=Path, help="keep our output and the peers' objects (.npy) here")
    return p.parse_args()


# --------------------------------------------------------------------------------------
# Dataset (docs/dataset.md section 5)
# --------------------------------------------------------------------------------------

class Dataset:
    def __init__(self, root: Path):
        import numpy as np
        import tifffile

        cfg = tomllib.loads((root / "dataset.toml").read_text())
        s, led, cam = cfg["system"], cfg["led"], cfg.get("camera", {})
        self.wavelength = float(s["wavelength_um"])
        self.na = float(s["na"])
        self.magnification = float(s["magnification"])
        self.camera_pixel = float(s["pixel_size_um"])
        self.pixel = self.camera_pixel / self.magnification  # sample plane, um
        self.led = led
        frames = [f for f in cfg["frame"] if float(f.get("defocus_um", 0.0)) == 0.0]
        if not frames:
            raise SystemExit("no in-focus frames in dataset")
        dark = float(cam.get("dark_level", 0.0))
        self.leds, self.f, images = [], [], []
        for fr in frames:
            counts = tifffile.imread(root / fr["file"]).astype(np.float64)
            if counts.ndim != 2:
                raise SystemExit(f"{fr['file']}: not a grayscale image")
            img = (counts - dark) / float(fr.get("exposure_ms", 1.0))
            if cam.get("transpose", False):
                img = img.T
            if cam.get("flip_x", False):
                img = img[:, ::-1]
            if cam.get("flip_y", False):
                img = img[::-1, :]
            r, c = int(fr["led"][0]), int(fr["led"][1])
            self.leds.append((r, c))
            self.f.append(self.illumination_f(r, c))
            images.append(img)
        self.f = np.array(self.f)  # (frames, 2): (f_x, f_y) cycles/um
        # nearest-first, the order `fpm reconstruct` uses (docs/dataset.md section 4)
        order = sorted(range(len(frames)), key=lambda i: (math.hypot(*self.f[i]), i))
        self.leds = [self.leds[i] for i in order]
        self.f = self.f[order]
        self.frames = np.ascontiguousarray(np.stack([images[i] for i in order]))
        self.negative_pixels = int((self.frames < 0).sum())
        np.maximum(self.frames, 0.0, out=self.frames)  # peers need non-negative intensity
        self.shape = self.frames.shape[1:]

    def led_position_mm(self, r: int, c: int) -> tuple[float, float, float]:
        """docs/dataset.md section 1: (x, y) in the LED plane, and the height h."""
        led = self.led
        d = float(led["pitch_mm"])
        r0, c0 = led.get("center", [led["rows"] // 2, led["cols"] // 2])
        dx, dy = led.get("offset_mm", [0.0, 0.0])
        th = math.radians(float(led.get("rotation_deg", 0.0)))
        p, q = c - c0, r - r0
        x = d * (p * math.cos(th) - q * math.sin(th)) + dx
        y = d * (p * math.sin(th) + q * math.cos(th)) + dy
        return x, y, float(led["height_mm"])

    def illumination_f(self, r: int, c: int) -> tuple[float, float]:
        """Illumination spatial frequency at the sample point (0, 0), cycles/um."""
        x, y, h = self.led_position_mm(r, c)
        n = math.sqrt(x * x + y * y + h * h)
        return (-x / n / self.wavelength, -y / n / self.wavelength)


# --------------------------------------------------------------------------------------
# Spectral helpers and the metric (docs/dataset.md section 6)
# --------------------------------------------------------------------------------------

def cfft(a):
    import numpy as np
    return np.fft.fftshift(np.fft.fft2(np.fft.ifftshift(a)))


def cifft(a):
    import numpy as np
    return np.fft.fftshift(np.fft.ifft2(np.fft.ifftshift(a)))


def resample(a, shape):
    """Spectral crop / zero-pad to `shape`; the optical axis stays at (H/2, W/2)."""
    import numpy as np
    if tuple(a.shape) == tuple(shape):
        return a.astype(np.complex128)
    spec = cfft(a.astype(np.complex128))
    out = np.zeros(shape, np.complex128)
    src, dst = [], []
    for n, m in zip(a.shape, shape):
        k = min(n, m)
        src.append(slice(n // 2 - k // 2, n // 2 - k // 2 + k))
        dst.append(slice(m // 2 - k // 2, m // 2 - k // 2 + k))
    out[tuple(dst)] = spec[tuple(src)]
    return cifft(out) * (shape[0] * shape[1]) / (a.shape[0] * a.shape[1])


def synthetic_aperture(ds: Dataset, shape):
    """Union of the pupil discs |f + f_i| <= NA/lambda on the HR grid's spectrum."""
    import numpy as np
    H, W = ds.shape
    fy = (np.arange(shape[0]) - shape[0] // 2) / (H * ds.pixel)
    fx = (np.arange(shape[1]) - shape[1] // 2) / (W * ds.pixel)
    rad2 = (ds.na / ds.wavelength) ** 2
    mask = np.zeros(shape, bool)
    for fxi, fyi in ds.f:
        # only the rows/columns the disc can touch
        r = math.sqrt(rad2)
        rows = np.nonzero(np.abs(fy + fyi) <= r)[0]
        cols = np.nonzero(np.abs(fx + fxi) <= r)[0]
        if rows.size == 0 or cols.size == 0:
            continue
        sl = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        mask[sl] |= ((fy[sl[0], None] + fyi) ** 2 + (fx[None, sl[1]] + fxi) ** 2) <= rad2
    return mask


def orientations(square: bool):
    """Conjugation x the flips/transposes that keep the optical-axis pixel fixed."""
    import numpy as np

    def fx(a):
        return np.roll(a[:, ::-1], 1, axis=1)

    def fy(a):
        return np.roll(a[::-1, :], 1, axis=0)

    geo = [("", lambda a: a), ("flip x", fx), ("flip y", fy), ("rotate 180", lambda a: fx(fy(a)))]
    if square:
        geo += [("transpose", lambda a: a.T), ("transpose+flip x", lambda a: fx(a.T)),
                ("transpose+flip y", lambda a: fy(a.T)), ("transpose+rotate 180", lambda a: fx(fy(a.T)))]
    out = []
    for conj in (False, True):
        for name, g in geo:
            label = ", ".join(x for x in (("conjugate" if conj else ""), name) if x)
            out.append((label, (lambda a, g=g, conj=conj: g(a.conj() if conj else a))))
    return out


class Metric:
    def __init__(self, ds: Dataset, truth, hr_shape):
        import numpy as np
        self.hr_shape = tuple(hr_shape)
        t = resample(truth, self.hr_shape)
        self.mask = synthetic_aperture(ds, self.hr_shape)
        self.truth = cifft(cfft(t) * self.mask)
        H, W = self.hr_shape
        self.region = (slice(round(H * 0.125), round(H * 0.875)), slice(round(W * 0.125), round(W * 0.875)))
        self.tnorm = np.linalg.norm(self.truth[self.region])

    def nrmse(self, rec) -> float:
        import numpy as np
        r, t = rec[self.region], self.truth[self.region]
        c = np.vdot(r, t) / max(np.vdot(r, r).real, 1e-300)
        return float(np.linalg.norm(c * r - t) / self.tnorm)

    def evaluate(self, obj):
        """NRMSE as returned, and the best over conjugation/flips/small whole-pixel shifts."""
        import numpy as np
        rec = resample(np.asarray(obj), self.hr_shape)
        raw = self.nrmse(rec)
        best = min(((self.nrmse(f(rec)), label, f) for label, f in
                    orientations(self.hr_shape[0] == self.hr_shape[1])), key=lambda x: x[0])
        val, label, f = best
        fixed = f(rec)
        # a different FFT centre shows up as a whole-pixel shift: look for one (<= 4 px)
        xc = cifft(cfft(self.truth) * np.conj(cfft(fixed)))
        H, W = self.hr_shape
        iy, ix = np.unravel_index(np.argmax(np.abs(xc)), xc.shape)
        dy, dx = int(iy - H // 2), int(ix - W // 2)
        if (dy, dx) != (0, 0) and max(abs(dy), abs(dx)) <= 4:
            shifted = np.roll(fixed, (dy, dx), axis=(0, 1))
            v = self.nrmse(shifted)
            if v < val:
                val = v
                label = ", ".join(x for x in (label, f"shift by ({dy}, {dx}) HR px (row, col)") if x)
        if val > 0.98 * raw:  # a fix must clearly help, not just win by noise
            return raw, raw, ""
        return raw, val, label


# --------------------------------------------------------------------------------------
# The runs
# --------------------------------------------------------------------------------------

def run_ours(args, workdir: Path):
    import numpy as np
    import tifffile
    out = workdir / "ours"
    cmd = [str(args.fpm), "reconstruct", str(args.dataset), "--out", str(out),
           "--passes", str(args.passes), "--upsample", str(args.upsample)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    rep = json.loads((out / "report.json").read_text())
    version = subprocess.run([str(args.fpm), "--version"], capture_output=True, text=True).stdout.strip()
    # report.json gives the reconstruction time alone (loading excluded); its fields
    # have changed across versions: total_ms (with passes), ms_per_pass, pass_ms
    passes = rep.get("passes") or args.passes
    if rep.get("total_ms") is not None:
        spp = rep["total_ms"] / passes / 1000.0
        note = "report.json total_ms / passes (loading excluded)"
    elif rep.get("ms_per_pass") is not None:
        spp = rep["ms_per_pass"] / 1000.0
        note = "report.json ms_per_pass (loading excluded)"
    elif rep.get("pass_ms"):
        spp = sum(rep["pass_ms"]) / len(rep["pass_ms"]) / 1000.0
        note = "report.json pass_ms (loading excluded)"
    else:
        spp = wall / args.passes
        note = "wall time of the whole command / passes (includes loading)"
    amp = tifffile.imread(out / "amplitude.tif").astype(np.float64)
    ph = tifffile.imread(out / "phase.tif").astype(np.float64)
    return dict(version=version.split()[-1] if version else "?", threads=rep.get("threads"),
                seconds_per_pass=spp, object=amp * np.exp(1j * ph),
                notes=f"{note}; whole command {wall:.2f} s")


def run_fpm_rs(ds: Dataset, args, snap: bool):
    import numpy as np
    import fpm_rs as fpm

    notes = []
    f = ds.f.copy()
    if hasattr(fpm, "PlanarLEDArray"):  # fpm-rs 0.2
        optics = fpm.Optics(wavelength_vacuum_m=ds.wavelength * 1e-6, objective_na=ds.na,
                            magnification=ds.magnification, camera_pixel_size=ds.camera_pixel * 1e-6)
        # cross-check: fpm-rs's own planar-array geometry must give the same vectors
        led = ds.led
        r0, c0 = led.get("center", [led["rows"] // 2, led["cols"] // 2])
        dx, dy = led.get("offset_mm", [0.0, 0.0])
        arr = fpm.PlanarLEDArray(
            shape=(int(led["rows"]), int(led["cols"])), pitch_m=float(led["pitch_mm"]) * 1e-3,
            reference_index=(float(c0), float(r0)),
            pose=fpm.ArrayPose.from_translation_and_extrinsic_xyz_degrees(
                (dx * 1e-3, dy * 1e-3, -float(led["height_mm"]) * 1e-3),
                (0.0, 0.0, float(led.get("rotation_deg", 0.0)))))
        kr = arr.resolve(optics).k_vectors[[arr.source_index(r, c) for r, c in ds.leds]]
        dev = float(np.max(np.abs(kr - 2 * np.pi * f * 1e6)) / np.max(np.abs(kr)))
        notes.append(f"k = 2*pi*f_i; fpm-rs PlanarLEDArray agrees to {dev:.1e} (relative)")
        illumination = lambda k: fpm.Illumination(fpm.KVectorList(k))  # noqa: E731
    else:  # fpm-rs 0.1: positional optics (SI units), a KVectorList is the illumination
        optics = fpm.Optics(ds.wavelength * 1e-6, ds.na, ds.magnification, ds.camera_pixel * 1e-6)
        notes.append("k = 2*pi*f_i (fpm-rs 0.1 API)")
        illumination = fpm.KVectorList
    if snap:
        H, W = ds.shape
        step = np.array([1.0 / (W * ds.pixel), 1.0 / (H * ds.pixel)])
        moved = np.round(f / step) * step
        notes.append(f"k snapped to the nearest HR Fourier bin (max move "
                     f"{np.max(np.abs(moved - f) / step):.2f} bin)")
        f = moved
    k = np.ascontiguousarray(2 * np.pi * f * 1e6)
    hr = (ds.shape[0] * args.upsample, ds.shape[1] * args.upsample)
    model = fpm.compile_model(optics, illumination(k), ds.shape, hr)
    assert model.frame_count == len(ds.leds) and tuple(model.reconstruction_shape) == hr
    problem = fpm.ReconstructionProblem(ds.frames, model)
    alg = fpm.Epry(iterations=args.passes)
    t0 = time.perf_counter()
    res = alg.run(problem, schedule="sequential")
    sec = time.perf_counter() - t0
    notes.append(f"Epry defaults (object_step 0.8, pupil_step 0.1); runtime.elapsed "
                 f"{res.runtime.elapsed_seconds:.2f} s for {res.runtime.completed_iterations} passes")
    return dict(version=md.version("fpm-rs"), threads=args.threads, seconds_per_pass=sec / args.passes,
                object=np.asarray(res.object), notes="; ".join(notes))


def run_fpm_py(ds: Dataset, args, patched: bool = False):
    import numpy as np
    import torch
    import fpm_py
    from fpm_py.core.structs import AcquisitionSettings, ImageCapture, ImageSeries

    torch.set_num_threads(args.threads)
    H, W = ds.shape
    if H != W:
        raise RuntimeError("fpm-py has one k-space step (du) for both axes: square frames only")
    du = 1.0 / (W * ds.pixel)  # cycles/um per Fourier pixel
    caps = [ImageCapture(image=torch.from_numpy(ds.frames[i].astype(np.float32)),
                         k_vector=torch.tensor([ds.f[i][1], ds.f[i][0]], dtype=torch.float32))
            for i in range(len(ds.leds))]
    series = ImageSeries(captures=caps, settings=AcquisitionSettings(
        du=du, pixel_size=ds.camera_pixel * 1e-6, wavelength=ds.wavelength * 1e-6),
        device=torch.device("cpu"))
    yy, xx = np.mgrid[0:H, 0:W]
    fr = np.hypot((yy - H // 2) / (H * ds.pixel), (xx - W // 2) / (W * ds.pixel))
    pupil = torch.from_numpy((fr <= ds.na / ds.wavelength).astype(np.complex64))
    import fpm_py.core.forward as fwd
    published_add = fwd.overlap_matrices
    if patched:
        # fpm-py 2.0.1 reads the spectrum patch at rows [x, x+H) but its overlap_matrices
        # adds the update at rows [x-H+1, x+1) (it takes x as the patch's bottom row).
        # This variant adds at the read position instead: NOT the published behaviour.
        def add_at_read_position(larger, smaller, row, col):
            h, w = smaller.shape[-2:]
            larger[row:row + h, col:col + w].add_(smaller)
            return larger
        fwd.overlap_matrices = add_at_read_position
    try:
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):  # it prints two lines per pass
            rec = fpm_py.reconstruct(series, output_scale_factor=args.upsample, pupil_0=pupil,
                                     max_iters=args.passes)
        sec = time.perf_counter() - t0
    finally:
        fwd.overlap_matrices = published_add
    return dict(version=md.version("fpm-py"), threads=torch.get_num_threads(),
                seconds_per_pass=sec / args.passes, object=rec.cpu().numpy(),
                notes=f"k_vector=(f_y, f_x) cycles/um, du={du:.6f} cycles/um; NA-disc pupil_0 "
                      f"(radius {ds.na / ds.wavelength / du:.1f} px); torch {md.version('torch')} CPU"
                      + ("" if patched else "; time not representative: most patches it reads stay "
                         "zero, so its early exit (delta_wave == 0) skips their updates"))


# --------------------------------------------------------------------------------------

def main() -> int:
    args = parse_args()
    # thread limits must be in place before the peers' libraries start their pools
    for var in ("RAYON_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = str(args.threads)
    import numpy as np
    import tifffile

    if not args.fpm.exists():
        print(f"error: {args.fpm} not found (build it first; this script never builds)", file=sys.stderr)
        return 2
    peers = [p.strip() for p in args.peers.split(",") if p.strip()]
    unknown = set(peers) - set(PEERS)
    if unknown:
        print(f"error: unknown peers {sorted(unknown)}", file=sys.stderr)
        return 2

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    t_all = time.perf_counter()
    log(f"loading {args.dataset}")
    ds = Dataset(args.dataset)
    hr = (ds.shape[0] * args.upsample, ds.shape[1] * args.upsample)
    ta = tifffile.imread(args.truth_amplitude or args.dataset / "truth_amplitude.tif").astype(np.float64)
    tp = tifffile.imread(args.truth_phase or args.dataset / "truth_phase.tif").astype(np.float64)
    metric = Metric(ds, ta * np.exp(1j * tp), hr)
    log(f"{len(ds.leds)} frames {ds.shape[0]}x{ds.shape[1]}, {args.passes} passes, x{args.upsample} "
        f"-> {hr[0]}x{hr[1]}; {ds.negative_pixels} negative dark-subtracted pixels clamped to 0 for peers")

    workdir = Path(tempfile.mkdtemp(prefix="fpm-peers-"))
    rows = []
    try:
        runs = [] if args.without_ours else [("fpm (ours)", "", lambda: run_ours(args, workdir))]
        for p in peers:
            if p == "fpm-rs":
                runs.append(("fpm-rs", "EPRY, exact k", lambda: run_fpm_rs(ds, args, snap=False)))
            elif p == "fpm-rs-snapped":
                runs.append(("fpm-rs", "EPRY, k bin-snapped", lambda: run_fpm_rs(ds, args, snap=True)))
            elif p == "fpm-py":
                runs.append(("fpm-py", "as published", lambda: run_fpm_py(ds, args)))
            elif p == "fpm-py-patched":
                runs.append(("fpm-py", "add-offset patched", lambda: run_fpm_py(ds, args, True)))
        for tool, variant, fn in runs:
            log(f"running {tool} {variant}".rstrip())
            row = dict(tool=tool, variant=variant)
            try:
                r = fn()
                obj = r.pop("object")
                if args.keep and tool != "fpm (ours)":
                    args.keep.mkdir(parents=True, exist_ok=True)
                    slug = "-".join((tool + " " + variant).replace(",", "").split())
                    np.save(args.keep / f"{slug}.npy", obj)
                raw, val, fix = metric.evaluate(obj)
                row.update(r, nrmse=val, nrmse_as_returned=raw, orientation_fix=fix)
                if fix:
                    log(f"  {tool}: applied '{fix}' to match the truth "
                        f"(NRMSE {raw:.4f} as returned -> {val:.4f})")
            except Exception as e:  # report and go on with the others
                row.update(error=f"{type(e).__name__}: {e}")
                log(f"  {tool} failed: {row['error']}")
            rows.append(row)
        if args.keep and not args.without_ours:
            args.keep.mkdir(parents=True, exist_ok=True)
            shutil.copytree(workdir / "ours", args.keep / "ours", dirs_exist_ok=True)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)

    ours = next((r.get("seconds_per_pass") for r in rows if r["tool"] == "fpm (ours)"), None)
    for r in rows:
        s = r.get("seconds_per_pass")
        r["ratio_to_ours"] = (s / ours) if (s and ours) else None

    def fmt(v, spec):
        return format(v, spec) if isinstance(v, (int, float)) else "-"

    print(f"\n{len(ds.leds)} frames {ds.shape[0]}x{ds.shape[1]}, {args.passes} passes, "
          f"upsample {args.upsample}, peer threads {args.threads}, {os.cpu_count()} CPUs, "
          f"{platform.processor() or platform.machine()}")
    print("ratio = tool s/pass / ours s/pass (above 1 = slower than ours); NRMSE per docs/dataset.md section 6")
    hdr = f"{'tool':<12} {'variant':<20} {'version':<10} {'thr':>3} {'s/pass':>8} {'ratio':>7} {'NRMSE':>7}  fix"
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        if "error" in r:
            print(f"{r['tool']:<12} {r['variant']:<20} failed: {r['error']}")
            continue
        print(f"{r['tool']:<12} {r['variant']:<20} {r['version']:<10} {fmt(r.get('threads'), 'd'):>3} "
              f"{fmt(r['seconds_per_pass'], '.3f'):>8} {fmt(r['ratio_to_ours'], '.2f'):>7} "
              f"{fmt(r['nrmse'], '.4f'):>7}  {r['orientation_fix'] or 'none'}")
    for r in rows:
        if r.get("notes"):
            print(f"  {' '.join(x for x in (r['tool'], r['variant']) if x)}: {r['notes']}")
    total = time.perf_counter() - t_all
    print(f"total {total:.1f} s")
    if args.json:
        doc = dict(dataset=str(args.dataset), passes=args.passes, upsample=args.upsample,
                   frames=len(ds.leds), frame_shape=list(ds.shape), hr_shape=list(hr),
                   peer_threads=args.threads, cpus=os.cpu_count(), python=platform.python_version(),
                   total_seconds=total, rows=rows)
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=2) + "\n")
    return 0 if all("error" not in r for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
