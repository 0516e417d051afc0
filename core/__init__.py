"""Pure computation: event/frame types, camera response, estimators, controllers. No I/O."""

if __name__ != "necviz.core":  # the folder imported as a top-level package (e.g. from the repository root)
    raise ImportError(
        f"this folder is the package necviz.core, not {__name__!r}: import necviz.core "
        "(installed by `pip install -e .` from the repository root)"
    )


from necviz.core.lazy import lazy_exports

# name -> module, imported on first use: importing a light submodule (necviz.core.errors, say) must not
# load NumPy, SciPy and Numba through this package's __init__ (the command line answers --help at once)
_API = {
    "CameraResponse": "necviz.core.crf",
    "debevec_malik": "necviz.core.crf",
    "default_davis346": "necviz.core.crf",
    "edi_reconstruct": "necviz.core.edi",
    "fast_edi_reconstruct": "necviz.core.edi",
    "medi_reconstruct": "necviz.core.edi",
    "valid_mask": "necviz.core.edi",
    "NecvizError": "necviz.core.errors",
    "TediParams": "necviz.core.event_model",
    "EVENT_DTYPE": "necviz.core.events",
    "EventBatch": "necviz.core.events",
    "make_events": "necviz.core.events",
    "validate_events": "necviz.core.events",
    "ExposureMarker": "necviz.core.frames",
    "Frame": "necviz.core.frames",
    "PeripheralEstimator": "necviz.core.ptedi",
    "PeripheralOptions": "necviz.core.ptedi",
    "DAVIS240": "necviz.core.sensor",
    "DAVIS346": "necviz.core.sensor",
    "SensorGeometry": "necviz.core.sensor",
    "TediCalibration": "necviz.core.tedi",
    "TediFitOptions": "necviz.core.tedi",
    "PairSelection": "necviz.core.tedi",
    "calibrate_tedi": "necviz.core.tedi",
    "tedi_reconstruct": "necviz.core.tedi",
}

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
    "PeripheralOptions",
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


__getattr__, __dir__ = lazy_exports(__name__, _API)
