"""``necviz calibrate``: fit a camera profile (TEDI's six parameters, and the response where brackets exist).

The TEDI parameters ``p = {c+, c-, a+, b+, a-, b-}`` are fitted by frame-to-frame consistency
(Eq. 7 of Lin et al., "Neuromorphic exposure control", with squared residuals): for consecutive
frames ``i-1, i`` and a common reference ``g`` (the exposure start of frame ``i-1``), minimise
``Σ_i Σ_x (ln L_i(g,x) - ln L_{i-1}(g,x))²`` where each ``ln L`` is Eq. 5 applied to one frame
and the events between it and ``g`` (:mod:`necviz.core.tedi`, SciPy least squares). Where the
data hold exposure brackets of a static scene, the camera response ``g(Z)`` is fitted first by
Debevec & Malik (1997) and the TEDI fit uses it.

Data: recordings in any format :func:`necviz.drivers.recordings.open_recording` reads, or simulator
runs (:func:`simulate_calibration_stream`: the calibration scene of
:mod:`necviz.drivers.sim.calibration_scene`, or a preset, driven by an exposure oracle).
Both are consumed as one stream of packets by :class:`PairCollector`.

Modules: :mod:`.pairs` (choosing the frame pairs and the exposure brackets from a stream,
:class:`CollectorOptions`), :mod:`.fit` (the least-squares fit, :class:`CalibrationOptions` shared by
the three ``calibrate_*`` functions, and :class:`CalibrationResult`), :mod:`.from_recordings` and
:mod:`.from_simulation` (the two data sources). The shipped simulated-DAVIS346 profile is
:func:`necviz.profiles.default_sim_profile`; the command is :mod:`necviz.commands.calibrate`.
"""

from __future__ import annotations

from necviz.core.lazy import lazy_exports

# name -> module, imported on first use (the command line reads the defaults without loading the fit)
_API = {
    **dict.fromkeys(
        ("DEFAULT_F_SCALE", "DEFAULT_LOSS", "DEFAULT_SLOW_RATE", "DEFAULTS"), "necviz.calibration.settings"
    ),
    **dict.fromkeys(
        ("FIT_CHOICES", "CalibrationOptions", "CalibrationResult", "calibrate_collected"), "necviz.calibration.fit"
    ),
    "calibrate_from_recordings": "necviz.calibration.from_recordings",
    **dict.fromkeys(
        (
            "BRACKET_OFFSETS",
            "CalibrationSimulation",
            "ExposureOracle",
            "calibrate_from_simulation",
            "make_sim_scene",
            "simulate_calibration_stream",
        ),
        "necviz.calibration.from_simulation",
    ),
    **dict.fromkeys(("DEFAULT_SELECTION", "CollectorOptions", "PairCollector"), "necviz.calibration.pairs"),
}

__all__ = [
    "BRACKET_OFFSETS",
    "DEFAULTS",
    "DEFAULT_F_SCALE",
    "DEFAULT_LOSS",
    "DEFAULT_SELECTION",
    "DEFAULT_SLOW_RATE",
    "FIT_CHOICES",
    "CalibrationOptions",
    "CalibrationResult",
    "CalibrationSimulation",
    "CollectorOptions",
    "ExposureOracle",
    "PairCollector",
    "calibrate_collected",
    "calibrate_from_recordings",
    "calibrate_from_simulation",
    "make_sim_scene",
    "simulate_calibration_stream",
]


__getattr__, __dir__ = lazy_exports(__name__, _API)
