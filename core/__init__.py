"""Pure computation: event/frame types, camera response, estimators, controllers. No I/O."""

if __name__ != "necviz.core":  # the folder imported as a top-level package (e.g. from the repository root)
    raise ImportError(
        f"this folder is the package necviz.core, not {__name__!r}: import necviz.core "
        "(installed by `pip install -e .` from the repository root)"
    )


from necviz.core.crf import CameraResponse, debevec_malik, default_davis346
from necviz.core.edi import edi_reconstruct, fast_edi_reconstruct, medi_reconstruct, valid_mask
from necviz.core.errors import NecvizError
from necviz.core.event_model import TediParams
from necviz.core.events import EVENT_DTYPE, EventBatch, make_events, validate_events
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.ptedi import PeripheralEstimator
from necviz.core.sensor import DAVIS240, DAVIS346, SensorGeometry
from necviz.core.tedi import PairSelection, TediCalibration, TediFitOptions, calibrate_tedi, tedi_reconstruct

__all__ = [
    "CameraResponse",
    "DAVIS240",
    "DAVIS346",
    "EVENT_DTYPE",
    "EventBatch",
    "ExposureMarker",
    "Frame",
    "NecvizError",
    "PeripheralEstimator",
    "SensorGeometry",
    "TediParams",
    "debevec_malik",
    "default_davis346",
    "make_events",
    "validate_events",
    "edi_reconstruct",
    "fast_edi_reconstruct",
    "medi_reconstruct",
    "tedi_reconstruct",
    "calibrate_tedi",
    "TediCalibration",
    "TediFitOptions",
    "PairSelection",
    "valid_mask",
]
