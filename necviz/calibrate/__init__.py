"""``necviz calibrate``: fit a camera profile (TEDI's six parameters, and the response where brackets exist).

The TEDI parameters ``p = {c+, c-, a+, b+, a-, b-}`` are fitted by frame-to-frame consistency
(Eq. 7 of Lin et al., "Neuromorphic exposure control", with squared residuals): for consecutive
frames ``i-1, i`` and a common reference ``g`` (the exposure start of frame ``i-1``), minimise
``Σ_i Σ_x (ln L_i(g,x) - ln L_{i-1}(g,x))²`` where each ``ln L`` is Eq. 5 applied to one frame
and the events between it and ``g`` (:mod:`necviz.core.tedi`, SciPy least squares). Where the
data hold exposure brackets of a static scene, the camera response ``g(Z)`` is fitted first by
Debevec & Malik (1997) and the TEDI fit uses it.

Data: recordings in any format :func:`necviz.drivers.replay.open_recording` reads, or simulator
runs (:func:`simulate_calibration_stream`: the calibration scene of
:mod:`necviz.drivers.sim.calibration_scene`, or a preset, driven by an exposure oracle).
Both are consumed as one stream of packets by :class:`PairCollector`.

Modules: :mod:`.pairs` (choosing the frame pairs and the exposure brackets from a stream),
:mod:`.fit` (the least-squares fit and :class:`CalibrationResult`), :mod:`.recordings` and
:mod:`.simulate` (the two data sources), :mod:`.profile` (the shipped simulated-DAVIS346 profile),
:mod:`.cli` (the ``necviz calibrate`` command). Every name is importable from ``necviz.calibrate``.
"""

from __future__ import annotations

# The names below and outside __all__ (DEFAULTS, FIT_CHOICES, DEFAULT_*, KNOWN_EVENT_RATES, BRACKET_OFFSETS,
# ExposureOracle, make_sim_scene, calibrate_collected) stay importable from here, as from the single module
# this package replaced.
from .cli import add_parser, parse_seeds, run
from .fit import (DEFAULT_F_SCALE, DEFAULT_LOSS, DEFAULT_SLOW_RATE, FIT_CHOICES, CalibrationResult,  # noqa: F401
                  calibrate_collected)
from .pairs import DEFAULTS, PairCollector  # noqa: F401
from .profile import SIM_CALIBRATION, SIM_PROFILE, default_sim_profile
from .recordings import KNOWN_EVENT_RATES, calibrate_from_recordings  # noqa: F401
from .simulate import (BRACKET_OFFSETS, ExposureOracle, calibrate_from_simulation, make_sim_scene,  # noqa: F401
                       simulate_calibration_stream)

__all__ = ["CalibrationResult", "PairCollector", "add_parser", "calibrate_from_recordings",
           "calibrate_from_simulation", "default_sim_profile", "parse_seeds", "run", "simulate_calibration_stream",
           "SIM_PROFILE", "SIM_CALIBRATION"]

