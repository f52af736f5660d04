"""fpm: Fourier ptychographic microscopy from Python.

The same code as the ``fpm`` command (its Rust crates, compiled into this package):

>>> import fpm
>>> ds = fpm.Dataset.load("data/usaf-ledmatrix")          # or Dataset.from_arrays(...)
>>> cal = fpm.calibrate(fpm.Dataset.load("calibration-set"))  # Δx, Δy, θ, h with 1σ
>>> res = fpm.reconstruct(ds, geometry=cal, upsample=4, passes=10)
>>> res.amplitude, res.phase, res.pupil, res.report

Long calls release the GIL. Bad input raises ``DatasetError`` (a ``ValueError``)
naming the file, key or frame; a calibration or reconstruction that cannot run raises
``FpmError`` (a ``RuntimeError``).
"""

from ._fpm import (
    Calibration,
    ColorResult,
    Dataset,
    DatasetError,
    FpmError,
    RECONSTRUCT_DEFAULTS,
    RECONSTRUCT_LIMITS,
    Result,
    Streaming,
    __version__,
    calibrate,
    dpc,
    reconstruct,
    simulate_acquisition,
    simulate_calibration,
    simulate_color_acquisition,
)
from .client import Client, ServiceError

__all__ = [
    "Calibration",
    "Client",
    "ColorResult",
    "Dataset",
    "DatasetError",
    "FpmError",
    "RECONSTRUCT_DEFAULTS",
    "RECONSTRUCT_LIMITS",
    "Result",
    "ServiceError",
    "Streaming",
    "__version__",
    "calibrate",
    "dpc",
    "reconstruct",
    "simulate_acquisition",
    "simulate_calibration",
    "simulate_color_acquisition",
]
