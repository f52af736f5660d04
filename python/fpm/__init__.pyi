from ._fpm import (
    Calibration as Calibration,
    ColorResult as ColorResult,
    Dataset as Dataset,
    DatasetError as DatasetError,
    FpmError as FpmError,
    Result as Result,
    Streaming as Streaming,
    __version__ as __version__,
    calibrate as calibrate,
    dpc as dpc,
    reconstruct as reconstruct,
    simulate_acquisition as simulate_acquisition,
    simulate_calibration as simulate_calibration,
    simulate_color_acquisition as simulate_color_acquisition,
)
from .client import Client as Client, ServiceError as ServiceError
