"""Pure computation: event/frame types, camera response, estimators, controllers. No I/O."""

from .crf import CameraResponse, debevec_malik, default_davis346
from .edi import edi_reconstruct, fast_edi_reconstruct, medi_reconstruct, valid_mask
from .errors import NecvizError
from .event_model import TediParams
from .events import EVENT_DTYPE, make_events, validate_events
from .frames import ExposureMarker, Frame
from .ptedi import PeripheralEstimator
from .sensor import DAVIS240, DAVIS346, SensorGeometry
from .tedi import TediCalibration, calibrate_tedi, tedi_reconstruct

__all__ = [
    "CameraResponse", "DAVIS240", "DAVIS346", "EVENT_DTYPE", "ExposureMarker", "Frame", "NecvizError",
    "PeripheralEstimator", "SensorGeometry", "TediParams", "debevec_malik", "default_davis346",
    "make_events", "validate_events", "edi_reconstruct", "fast_edi_reconstruct", "medi_reconstruct",
    "tedi_reconstruct", "calibrate_tedi", "TediCalibration", "valid_mask",
]
