"""``necviz demo``: the embedded default — simulated ``tunnel_exit``, NEC against the baselines.

Every controller drives its own simulated camera; all cameras share one scene and one event
stream (:class:`~necviz.drivers.sim.camera.SimRig`), as in ``necviz compare``, shown side by side
in the ``compare`` layout. No hardware and no files needed.
"""

from __future__ import annotations

import sys

from .compare import parse_controllers
from .core.control import CameraLimits, make_controller
from .core.errors import ParameterError
from .dashboard import check_run_args, run_dashboard
from .drivers.sim.aps import ApsParams
from .drivers.sim.camera import SimRig
from .drivers.sim.scenes import SCENARIOS, make_scenario
from .pipeline import Lane

DEFAULT_CONTROLLERS = "nec,navid,shim,begin,builtin,fixed"


def build(scenario: str = "tunnel_exit", controllers: str = DEFAULT_CONTROLLERS, seed: int = 0,
          duration_s: float | None = None):
    """The rig, its lanes and the run properties."""
    if scenario not in SCENARIOS:
        raise ParameterError(f"unknown scenario {scenario!r}; available: {', '.join(sorted(SCENARIOS))}")
    if duration_s is not None and not (0 < duration_s <= 600):
        raise ParameterError(f"--duration must lie in (0, 600] s, got {duration_s}")
    names = parse_controllers(controllers)
    scene = make_scenario(scenario, seed=seed, duration_us=None if duration_s is None else int(duration_s * 1e6))
    aps = ApsParams()
    rig = SimRig(scene, names, aps=aps, seed=seed)
    limits = CameraLimits(aps.exposure_min_us, aps.exposure_max_us, aps.gain_max)
    lanes = []
    for n in names:
        ctrl = make_controller(n, sensor=scene.sensor, limits=limits, exposure_us=rig.cams[n].exposure_us)
        lanes.append(Lane.build(n, ctrl, scene.sensor))
    props = {"command": "demo", "scenario": scenario, "seed": seed, "duration_s": scene.duration_us / 1e6,
             "controllers": ",".join(names), "camera_limits": limits, "camera_profile": "default DAVIS346 response"}
    return rig, lanes, props


def run(args, out=...) -> dict:
    out = sys.stdout if out is ... else out
    check_run_args(args)  # before anything is opened or truncated
    rig, lanes, props = build(args.scenario, args.controllers, args.seed, args.duration)
    recorder = None
    if getattr(args, "record", None):
        from .drivers.replay.native import Recorder

        recorder = Recorder(args.record, sensor=rig.sensor, properties={**props, "recorded_lane": lanes[0].name})
    print(f"  demo: {args.scenario}, {', '.join(lane.name for lane in lanes)} "
          f"({props['duration_s']:g} s simulated)", file=out)
    return run_dashboard(args, "demo", rig, lanes, "compare", props, f"necviz demo: {args.scenario}", rig.sensor,
                         recorder=recorder, record_lane=lanes[0].name, expected_duration_s=props["duration_s"],
                         sink_options={"lossless_when_unpaced": True}, out=out)  # simulated time can wait
