"""The names and default lanes the command line shows, in a module that imports nothing.

The parser (``necviz --help``, a mistyped flag) reads them without importing the registries;
``tests/test_cli.py`` keeps :data:`CONTROLLER_NAMES` and :data:`SCENARIO_NAMES` equal to the
registries (:data:`necviz.core.control.CONTROLLERS`, :data:`necviz.drivers.sim.scenes.SCENARIOS`).
"""

from __future__ import annotations

#: the registered controllers (necviz.core.control.CONTROLLERS) and scenario presets
#: (necviz.drivers.sim.scenes.SCENARIOS), for the help and for checking flags without importing them
CONTROLLER_NAMES = (
    "begin",
    "begin-tuned",
    "builtin",
    "fixed",
    "navid",
    "navid-tuned",
    "nec",
    "nec-frames",
    "nec-paper",
    "nec-raw",
    "nec-tuned",
    "shim",
    "shim-tuned",
)
SCENARIO_NAMES = ("flicker", "handheld_scan", "indoor_outdoor", "static_lab", "tunnel_exit")
FORMATS = ("necviz", "aedat4", "aedat3", "aedat2", "rosbag1", "rosbag2", "hdf5", "rpg-text")

#: The ports ``--serve`` listens on (gRPC data, web viewer) and where ``--connect`` streams by default.
DEFAULT_GRPC_PORT = 9876
DEFAULT_WEB_PORT = 9090
DEFAULT_CONNECT = f"rerun+http://127.0.0.1:{DEFAULT_GRPC_PORT}/proxy"
#: The layouts a command can be shown with (layouts/: live, inspect, compare).
LAYOUT_NAMES = ("live", "inspect", "compare")
#: The five published auto-exposure baselines (image only), in the order every table lists them.
BASELINES = ("navid", "shim", "begin", "builtin", "fixed")
#: The baselines as tuned with NEC's budget on the training scenes (necviz/tuned.json, docs/evaluation.md),
#: in the same order; the built-in rule and the fixed exposure have nothing to tune.
TUNED_BASELINES = ("navid-tuned", "shim-tuned", "begin-tuned", "builtin", "fixed")
#: What the demo shows side by side: NEC, NEC without events (``nec-frames``: what the events add)
#: and the five baselines as tuned (the fair comparison the results page makes; the published
#: constants are one ``--controllers navid,shim,begin`` away).
DEFAULT_CONTROLLERS = ("nec", "nec-frames", *TUNED_BASELINES)
#: What a comparison runs by default: the demo's lanes, the paper's controller exactly
#: (``nec-paper``) and NEC without its compensation (``nec-raw``).
COMPARE_CONTROLLERS = ("nec", "nec-frames", "nec-paper", "nec-raw", *BASELINES)

__all__ = [
    "BASELINES",
    "COMPARE_CONTROLLERS",
    "CONTROLLER_NAMES",
    "DEFAULT_CONNECT",
    "DEFAULT_GRPC_PORT",
    "DEFAULT_WEB_PORT",
    "DEFAULT_CONTROLLERS",
    "FORMATS",
    "LAYOUT_NAMES",
    "SCENARIO_NAMES",
    "TUNED_BASELINES",
]
