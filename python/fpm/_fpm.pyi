"""Type stubs of fpm's native module (python/src/*.rs)."""

from os import PathLike
from pathlib import Path
from typing import Any, Callable, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str
RECONSTRUCT_DEFAULTS: dict[str, int | float]
"""The reconstruction's defaults (upsample, passes, floor_sigma, noise_band_sigma)."""
RECONSTRUCT_LIMITS: dict[str, tuple[int, int]]
"""Inclusive ranges of upsample, passes and tile (camera pixels)."""

Led = Tuple[int, int]
Progress = Callable[[int, int], Any]
Json = Any

class FpmError(RuntimeError):
    """A calibration or reconstruction failed; the message says what and where."""

class DatasetError(ValueError):
    """A dataset is wrong: the message names the file, key or frame."""

class Dataset:
    """An FPM dataset: frames, the LED lit for each, the optics and the LED array."""

    @staticmethod
    def load(path: Union[str, PathLike[str]]) -> Dataset:
        """Load and check the dataset in `path` (a directory with dataset.toml)."""
    @staticmethod
    def from_arrays(
        frames: Union[npt.ArrayLike, Sequence[npt.ArrayLike]],
        leds: Sequence[Led],
        system: dict[str, float],
        geometry: dict[str, Any],
        exposure_ms: Union[float, Sequence[float], None] = None,
        defocus_um: Union[float, Sequence[float], None] = None,
        dark_level: float = 0.0,
        bit_depth: Optional[int] = None,
        dir: Union[str, PathLike[str], None] = None,
        gamma: Optional[float] = None,
    ) -> Dataset:
        """A dataset from frames in memory (uint8, uint16 or float; sample-plane
        orientation), the (row, col) LED of each, and the optics and LED array as
        dicts of the dataset's keys. `gamma`: the frames were saved with a display
        gamma (a stored v is the light F·(v/F)^gamma, F = 2^bit_depth − 1; needs
        `bit_depth`)."""
    @staticmethod
    def from_zheng_mat(src: Union[str, PathLike[str]], out: Union[str, PathLike[str]], **stated: Any) -> Dataset:
        """Zheng lab MATLAB data (`fpm import zheng-mat`), written as a dataset in
        `out` and loaded. Keywords state what the file does not give:
        wavelength_um, na, magnification, pixel_size_um, height_mm, pitch_mm,
        bit_depth, dark_level (docs/import.md)."""
    @staticmethod
    def from_caltech_mat(src: Union[str, PathLike[str]], out: Union[str, PathLike[str]], **stated: Any) -> Dataset:
        """Caltech FPM_software MATLAB data (`fpm import caltech-mat`)."""
    @staticmethod
    def from_ptylab_h5(src: Union[str, PathLike[str]], out: Union[str, PathLike[str]], **stated: Any) -> Dataset:
        """PtyLab FPM HDF5 data (`fpm import ptylab-h5`)."""
    @staticmethod
    def from_tiff_csv(src: Union[str, PathLike[str]], out: Union[str, PathLike[str]], **stated: Any) -> Dataset:
        """TIFFs and a CSV of LED positions or NAs (`fpm import tiff-csv`; `csv` names
        the CSV)."""
    @property
    def source(self) -> Optional[dict[str, Any]]:
        """Where an imported dataset came from: format, path, assumed (None for
        fpm's own)."""
    def save(self, dir: Union[str, PathLike[str]]) -> None:
        """Write frames/ (TIFF) and dataset.toml into `dir`."""
    @property
    def dir(self) -> Path:
        """Where the dataset came from (`<in memory>` for arrays given no dir)."""
    @property
    def system(self) -> dict[str, float]:
        """wavelength_um, na, magnification, pixel_size_um."""
    @property
    def geometry(self) -> dict[str, Any]:
        """The LED array as the dataset states it: rows, cols, pitch_mm, height_mm,
        center, dx_mm, dy_mm, theta_deg, tilt_x_deg, tilt_y_deg."""
    @property
    def leds(self) -> list[Led]:
        """Each frame's LED (a multiplexed frame's first)."""
    @property
    def frame_leds(self) -> list[list[Led]]:
        """Every LED lit for each frame (several for a multiplexed dataset)."""
    @property
    def led_positions_mm(self) -> list[tuple[float, float, float]]:
        """Each frame's LED as the dataset places it: (x, y, z) mm, z its distance
        below the sample."""
    @property
    def exposure_ms(self) -> list[float]: ...
    @property
    def defocus_um(self) -> list[float]: ...
    @property
    def dark_level(self) -> float: ...
    @property
    def gamma(self) -> Optional[float]:
        """The display gamma the frames were saved with (None: linear counts)."""
    @property
    def frames(self) -> list[np.ndarray]:
        """Read-only NumPy views of the frames (no copy; uint8, uint16 or float32)."""
    def frame(self, index: int) -> np.ndarray:
        """Frame `index` (negative counts from the end), a read-only view."""
    def __len__(self) -> int: ...

class Calibration:
    """A calibrated LED array, each value with its 1σ in `uncertainty`."""

    @property
    def dx_mm(self) -> float: ...
    @property
    def dy_mm(self) -> float: ...
    @property
    def theta_deg(self) -> float: ...
    @property
    def height_mm(self) -> float: ...
    @property
    def tilt_deg(self) -> Tuple[float, float]: ...
    @property
    def tilt_observable(self) -> bool: ...
    @property
    def uncertainty(self) -> dict[str, float]:
        """1σ of dx_mm, dy_mm, theta_deg, height_mm, tilt_x_deg, tilt_y_deg."""
    @property
    def leds(self) -> list[dict[str, Json]]:
        """Per LED: status, measured and fitted shifts, residual."""
    @property
    def warnings(self) -> list[str]:
        """What to know before trusting the numbers (empty when all is well)."""
    @property
    def geometry(self) -> dict[str, Any]:
        """The calibrated geometry (for reconstruct, Streaming, from_arrays)."""
    @property
    def report(self) -> dict[str, Json]:
        """Everything, as in calibration.json."""
    @property
    def time_ms(self) -> float: ...
    def save(self, path: Union[str, PathLike[str]]) -> None:
        """Write calibration.json (readable by `fpm reconstruct --calibration`)."""

class Result:
    """A reconstruction: object, pupil and report."""

    @property
    def amplitude(self) -> npt.NDArray[np.float32]: ...
    @property
    def phase(self) -> npt.NDArray[np.float32]:
        """Radians."""
    @property
    def object(self) -> npt.NDArray[np.complex64]: ...
    @property
    def pupil(self) -> npt.NDArray[np.complex64]: ...
    @property
    def pixel_um(self) -> float:
        """The reconstructed grid's pixel at the sample, µm."""
    @property
    def report(self) -> dict[str, Json]:
        """As report.json (with `versus_truth` for simulated datasets, and `warnings`:
        each one's `check` and `message`)."""
    @property
    def warnings(self) -> list[str]:
        """What to know before trusting the images, each with the action that applies
        (empty when all is well)."""
    def save(
        self, dir: Union[str, PathLike[str]], *, format: str = "tiff", compress: bool = False
    ) -> None:
        """Write amplitude/phase as OME-TIFFs (float32, pixel size in µm) or, with
        format="ome-zarr", as one OME-Zarr pyramid (image.ome.zarr); pupil TIFFs, PNG
        previews and report.json into `dir`."""

class ColorResult:
    """A colour reconstruction: every channel with its own wavelength, LEDs and pupil,
    registered to the reference channel."""

    @property
    def names(self) -> list[str]: ...
    @property
    def wavelengths_um(self) -> list[float]: ...
    @property
    def channels(self) -> dict[str, Result]:
        """Each channel's own reconstruction (before registration)."""
    @property
    def amplitude(self) -> npt.NDArray[np.float32]:
        """(channel, y, x), registered."""
    @property
    def phase(self) -> npt.NDArray[np.float32]:
        """(channel, y, x), radians, registered."""
    @property
    def rgb(self) -> npt.NDArray[np.uint8]:
        """(y, x, 3) sRGB preview, white-balanced on the clear background."""
    @property
    def pixel_um(self) -> float: ...
    @property
    def report(self) -> dict[str, Json]:
        """As the colour report.json: per channel its wavelength, geometry, shift,
        clear level and `versus_truth`."""
    @property
    def warnings(self) -> list[str]: ...
    def save(
        self, dir: Union[str, PathLike[str]], *, format: str = "tiff", compress: bool = False
    ) -> None:
        """amplitude/phase with one channel per wavelength, color.png, report.json, and
        each channel's own outputs in `dir/<name>/`."""

class Streaming:
    """A reconstruction fed frame by frame while the acquisition runs."""

    def __init__(
        self,
        system: dict[str, float],
        geometry: dict[str, Any],
        width: int,
        height: int,
        *,
        tile: Optional[int] = None,
        upsample: int = 4,
        dark_level: float = 0.0,
        fixed_pupil: bool = False,
        background: str = "per-frame",
        floor: str = "soft",
        floor_sigma: float = 3.0,
        noise_band_sigma: float = 7.5,
        flatten_background: bool = False,
        background_block_um: Optional[float] = None,
    ) -> None: ...
    def push(self, led: Led, frame: npt.ArrayLike, exposure_ms: float = 1.0) -> None:
        """A frame taken under `led`; the estimate is updated at once."""
    @property
    def received(self) -> int: ...
    def snapshot(self) -> Optional[npt.NDArray[np.complex64]]:
        """The sample as it stands (None until every tile has a bright-field frame)."""
    def finish(self, passes: int = 10, progress: Optional[Progress] = None) -> Result:
        """The remaining passes over every frame received, as `reconstruct` runs them."""

def calibrate(
    dataset: Dataset,
    *,
    roi: Optional[Tuple[int, int, int, int]] = None,
    defocus_sigma_um: float = 1.0,
    bias_correction: bool = True,
    fit_tilt: bool = True,
) -> Calibration:
    """pdcFPM calibration of the LED array from a defocus dataset."""

def dpc(
    dataset: Dataset,
    reg_phase: Optional[float] = None,
    reg_absorption: Optional[float] = None,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """A weak object's phase (radians) and absorption from the four half-circle
    patterns of the dataset's in-focus bright-field frames (`fpm dpc`), with the
    report (its `warnings` say when the sample is not weak). Tikhonov weights default
    to 1e-3."""

def reconstruct(
    dataset: Union[Dataset, str, PathLike[str]],
    *,
    geometry: Union[Calibration, dict[str, Any], str, PathLike[str], None] = None,
    upsample: int = 4,
    passes: int = 10,
    tile: Optional[int] = None,
    refine_leds: bool = False,
    fixed_pupil: bool = False,
    background: str = "per-frame",
    floor: str = "soft",
    floor_sigma: float = 3.0,
    noise_band_sigma: float = 7.5,
    flatten_background: bool = False,
    background_block_um: Optional[float] = None,
    entrance_pupil_mm: Optional[float] = None,
    refocus_um: Union[float, str, None] = None,
    progress: Optional[Progress] = None,
) -> Union[Result, ColorResult]:
    """EPRY reconstruction of the dataset's in-focus frames (GIL released).

    `dataset` may be a directory; a colour dataset's gives a ColorResult (`geometry`:
    the path of its colour calibration.json).

    `geometry` None: the placement the dataset was acquired with where its
    acquisition.json records one (a calibration made then, or the one stored on the
    board), else its nominal placement (the report's `geometry_source` says which).

    `entrance_pupil_mm`: the objective's entrance pupil distance above the sample, for
    objectives that are not telecentric (default: telecentric). `refocus_um`: how far
    the sample sat from focus when the frames were taken, µm (toward the LEDs
    positive); the image comes out refocused onto the sample."""

def simulate_acquisition(
    out: Union[str, PathLike[str]],
    *,
    size: int = 256,
    seed: int = 1,
    dx_mm: float = 1.0,
    dy_mm: float = 1.0,
    theta_deg: float = 5.0,
    height_mm: float = 92.0,
    tilt_deg: Tuple[float, float] = (0.0, 0.0),
    noise: str = "realistic",
    stray_light: float = 0.0,
    upsample: int = 2,
    dark_field_peak_dn: Optional[float] = None,
    led_jitter_mm: float = 0.0,
    entrance_pupil_mm: Optional[float] = None,
    display_gamma: Optional[float] = None,
    sample: str = "cells",
    multiplex: int = 1,
    multiplex_bright: int = 1,
) -> Tuple[Dataset, dict[str, Json]]:
    """A full simulated acquisition written into `out`: (dataset, truth).

    `multiplex`, `multiplex_bright`: dark-field and bright-field LEDs lit together in
    each frame (`fpm simulate acquisition --multiplex --multiplex-bright`).

    `sample`: "cells" (absorbing and phase cells with bar groups), "weak-phase"
    (unstained cells) or "stained" (dense, strongly absorbing cells).

    `noise`: "realistic" (a 12-bit machine-vision sensor), "eight-bit" (a home-built
    rig's 8-bit camera, as noisy as the vendored USAF set's; with
    `dark_field_peak_dn=25`, dark-field frames as dim as that set's) or "none".

    `entrance_pupil_mm`: through an objective that is not telecentric (the dataset
    cannot state it; the truth does).

    `display_gamma`: frames stored for viewing with this gamma (e.g. 2.2), as camera
    software exporting 8-bit images does; the dataset states it (`Dataset.gamma`)."""

def simulate_calibration(
    out: Union[str, PathLike[str]],
    *,
    size: int = 256,
    seed: int = 1,
    dx_mm: float = 1.0,
    dy_mm: float = 1.0,
    theta_deg: float = 5.0,
    height_mm: float = 92.0,
    tilt_deg: Tuple[float, float] = (0.0, 0.0),
    noise: str = "realistic",
    stray_light: float = 0.0,
    defocus_um: float = 200.0,
    feature_um: float = 50.0,
    feature_at_um: Tuple[float, float] = (0.0, 0.0),
    led_jitter_mm: float = 0.0,
) -> Tuple[Dataset, dict[str, Json]]:
    """A simulated pdcFPM calibration set written into `out`: (dataset, truth).

    `led_jitter_mm`: each LED off its grid by its own draw of this σ per axis, as on a
    hand-built board (truth["leds"] lists where the calibration's LEDs were; the
    calibration's `leds[i]["offset_mm"]` measures each)."""

def simulate_color_acquisition(
    out: Union[str, PathLike[str]],
    *,
    colors: Sequence[str] = ("red", "green", "blue"),
    die_offset_mm: Optional[dict[str, Tuple[float, float]]] = None,
    focal_shift_um: Optional[dict[str, float]] = None,
    spectral_samples: int = 5,
    size: int = 128,
    seed: int = 1,
    dx_mm: float = 0.0,
    dy_mm: float = 0.0,
    theta_deg: float = 0.0,
    height_mm: float = 92.0,
    noise: str = "realistic",
    sample: str = "cells",
) -> Tuple[Path, dict[str, Json]]:
    """A colour acquisition (a scan per colour, each its own dataset) in `out`; its
    directory and each colour's truth."""
