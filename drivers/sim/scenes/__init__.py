"""Named scenario presets for the closed-loop simulator: HDR scenes with motion and lighting steps.

Every preset is a :class:`~necviz.drivers.sim.scene.Scene`; it is deterministic for its seed (textures
and hand shake come from ``numpy.random.default_rng(seed)``), renders float32 ``ln L`` at the sensor's
resolution with vectorised NumPy/OpenCV (one or a few ``cv2.remap``/``cv2.warpAffine`` calls per image),
and lists its lighting steps in ``scene.changes`` (:class:`~necviz.drivers.sim.scene.LightingChange`).

Units: ``ln L`` as in :mod:`necviz.drivers.sim.scene` (``ln L = 5`` is well exposed at about 4 ms);
lighting steps are given in dB (20 log10 of the irradiance ratio; ``db_to_log`` converts), times in
seconds or milliseconds as the parameter name says, image speeds in pixels per second.

Presets (``SCENARIOS``), one module each:

``tunnel_exit``
    driving out of a tunnel (forward motion, growing bright portal, step of ``step_db`` over
    ``transition_ms``, a pedestrian walking in after the exit).
``indoor_outdoor``
    walking out of a building through a door with hand shake (60-80 dB).
``flicker``
    a room with a mains-powered lamp flickering at 100 Hz plus a light switched on and off.
``static_lab``
    a static lab scene whose lights step between configured dB levels (the paper's indoor test);
    its default steps fall mid-way between the simulator's default exposure starts.
``handheld_scan``
    handheld scan over a facade with soft sun/shadow boundaries sweeping across (40-60 dB).

Each preset's parameters (default, range, meaning) are listed in its class docstring, generated
from its ``PARAMS`` (:mod:`.preset`); :func:`scenario_params_markdown` renders all of them for
``docs/simulator.md``. Every preset takes ``change_jitter_ms`` (default half the APS frame interval,
10 ms): each lighting change moves by a seeded uniform offset of at most that much, so each seed
meets the frame clock at its own phase (0: the nominal times, the same for every seed); and
``markers`` (default true): ArUco fiducial markers drawn into the scene (:mod:`.fiducials`), whose
ground truth ``scene.marker_truth(t_us)`` gives (:class:`necviz.core.markers.MarkerTruth`).

Build one with :func:`make_scenario` (``make_scenario("tunnel_exit", seed=3, step_db=90)``) or from a
TOML description with :func:`scenario_from_toml` (keys in :mod:`.toml`)::

    name = "tunnel_exit"
    seed = 3
    duration_s = 2.0          # or duration_us = 2000000; default: the preset's own duration
    sensor = "DAVIS346"       # optional: "DAVIS346", "DAVIS240" or {width = .., height = ..}
    [params]
    step_db = 90
"""

from necviz.drivers.sim.scenes.flicker import Flicker
from necviz.drivers.sim.scenes.handheld_scan import HandheldScan
from necviz.drivers.sim.scenes.indoor_outdoor import IndoorOutdoor
from necviz.drivers.sim.scenes.preset import COMMON_PARAMS, Param, PresetScene
from necviz.drivers.sim.scenes.registry import SCENARIOS, make_scenario, scenario_params, scenario_params_markdown
from necviz.drivers.sim.scenes.static_lab import StaticLab
from necviz.drivers.sim.scenes.toml import load_scenario_spec, scenario_from_toml
from necviz.drivers.sim.scenes.tunnel_exit import TunnelExit

__all__ = [
    "SCENARIOS",
    "make_scenario",
    "load_scenario_spec",
    "scenario_from_toml",
    "scenario_params",
    "scenario_params_markdown",
    "TunnelExit",
    "IndoorOutdoor",
    "Flicker",
    "StaticLab",
    "HandheldScan",
    "PresetScene",
    "Param",
    "COMMON_PARAMS",
]
