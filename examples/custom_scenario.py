#!/usr/bin/env python
"""A custom simulated scene in closed loop with NEC: a lamp switched off, then on again.

The scene is a ``FunctionScene``: a Python function returning ln L for every pixel at time t µs
(here a textured room that dims by ``--dim-ln`` natural-log units at 30 % of the run and comes
back at 65 %). ``--toml`` builds the same light steps from TOML text instead (the ``static_lab``
preset via ``scenario_from_toml``). A one-camera ``SimRig`` renders events and frames; NEC (built
by ``make_controller("nec", ...)``) sees every packet through the ``Pipeline`` every necviz command
runs, and its commands go back to the camera.
Printed: the exposure/gain NEC applied in each phase, the saturated frames (> 50 % of pixels
over- or under-exposed) and the exposure trace.

usage: python examples/custom_scenario.py [--duration-s 1.0] [--dim-ln 3.0] [--toml]
"""

import argparse
import math

import numpy as np

from necviz.core import SensorGeometry, default_davis346
from necviz.core.control import CameraLimits, make_controller
from necviz.drivers.sim.aps import ApsParams
from necviz.drivers.sim.rig import SimRig
from necviz.drivers.sim.scene import FunctionScene, LightingChange
from necviz.drivers.sim.scenes import scenario_from_toml
from necviz.pipeline import Lane, Pipeline

RAMP_US = 5_000  # a lamp takes 5 ms to switch


def lamp_scene(sensor: SensorGeometry, duration_us: int, off_us: int, on_us: int, dim_ln: float) -> FunctionScene:
    yy, xx = np.mgrid[0 : sensor.height, 0 : sensor.width]
    room = (
        5.0
        + 0.4 * np.sin(xx / 9.0) * np.cos(yy / 7.0)
        + 0.3 * np.where((xx // 16 + yy // 16) % 2, 1, -1)
        + 0.05 * np.random.default_rng(1).standard_normal(sensor.shape)
    ).astype(np.float32)

    def lamp_off_then_on(t_us, sensor):
        dark = np.clip((t_us - off_us) / RAMP_US, 0, 1) - np.clip((t_us - on_us) / RAMP_US, 0, 1)
        return room - np.float32(dim_ln * dark)

    changes = [LightingChange(off_us, "lamp off", -dim_ln), LightingChange(on_us, "lamp on", dim_ln)]
    return FunctionScene(lamp_off_then_on, sensor, duration_us, changes=changes, name="lamp")


def toml_scene(sensor: SensorGeometry, duration_us: int, off_us: int, on_us: int, dim_ln: float):
    dim_db = dim_ln * 20 / math.log(10)  # the presets take light levels in dB (20 log10)
    return scenario_from_toml(f"""
name = "static_lab"
duration_us = {duration_us}
sensor = {{width = {sensor.width}, height = {sensor.height}}}
[params]
steps = [[{off_us / 1e6}, {-dim_db:.3f}], [{on_us / 1e6}, 0.0]]
ramp_ms = {RAMP_US / 1e3}
""")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=1.0, help="simulated time in s (0.2..10)")
    ap.add_argument("--dim-ln", type=float, default=3.0, help="how much darker with the lamp off, ln units (0..5)")
    ap.add_argument("--size", default="128x96", help="sensor WIDTHxHEIGHT in pixels (small = fast)")
    ap.add_argument("--toml", action="store_true", help="build the scene from TOML text (static_lab preset)")
    args = ap.parse_args()
    if not (0.2 <= args.duration_s <= 10 and 0 < args.dim_ln <= 5):
        ap.error("need 0.2 <= --duration-s <= 10 and 0 < --dim-ln <= 5")
    try:
        sensor = SensorGeometry(*(int(v) for v in args.size.lower().split("x")))
    except (TypeError, ValueError):
        ap.error(f"--size must look like 128x96, got {args.size!r}")
    duration_us = int(args.duration_s * 1e6)
    off_us, on_us = int(0.3 * duration_us), int(0.65 * duration_us)
    scene = (toml_scene if args.toml else lamp_scene)(sensor, duration_us, off_us, on_us, args.dim_ln)

    aps, crf = ApsParams(), default_davis346()
    limits = CameraLimits(aps.exposure_min_us, aps.exposure_max_us, aps.gain_max)
    # start at the exposure that is right for the first instant: g(I_opt) = ln T + ln L (T in s)
    start_us = math.exp(crf.goal_log_exposure - float(np.mean(scene.log_irradiance(0)))) * 1e6
    cam = SimRig(scene, {"camera": (start_us, 1.0)}, aps=aps, crf=crf, seed=0)
    rate = cam.camera_info.event_rate_max  # the source's event bus ceiling, which NEC's escape rule reads
    nec = make_controller("nec", sensor=sensor, limits=limits, exposure_us=start_us, crf=crf, event_rate_max=rate)
    pipe = Pipeline(cam, [Lane("camera", nec)])  # the closed loop every necviz command runs
    pipe.run().finish()
    table = pipe.telemetry["camera"].table  # (start µs, exposure µs, gain, over-exposed rate, under-exposed rate)
    frames = np.stack(
        [
            table.column(k)
            for k in ("exposure_start_us", "exposure_us", "gain", "over_exposed_rate", "under_exposed_rate")
        ],
        axis=1,
    )
    f = np.array(frames)
    sat = (f[:, 3] > 0.5) | (f[:, 4] > 0.5)

    print(
        f"scene {scene.name!r} ({'TOML' if args.toml else 'FunctionScene'}), {sensor.width}x{sensor.height} px, "
        f"{args.duration_s:g} s; lamp off at {off_us / 1e3:g} ms (-{args.dim_ln:g} ln), on at {on_us / 1e3:g} ms"
    )
    print(
        f"{'phase':10s} {'frames':>6s} {'exposure µs':>15s} {'gain':>11s} {'saturated':>9s} {'settled ln(TK/TK0)':>18s}"
    )
    for label, lo, hi in (("lamp on", 0, off_us), ("lamp off", off_us, on_us), ("on again", on_us, duration_us)):
        sel = (f[:, 0] >= lo) & (f[:, 0] < hi)
        if sel.any():  # settled: the exposure-gain product of the phase's last frame, relative to the first frame
            settled_ln = math.log(f[sel, 1][-1] * f[sel, 2][-1] / (f[0, 1] * f[0, 2]))
            print(
                f"{label:10s} {int(sel.sum()):6d} {f[sel, 1].min():7.0f}..{f[sel, 1].max():<7.0f} "
                f"{f[sel, 2].min():5.2f}..{f[sel, 2].max():<5.2f} {int(sat[sel].sum()):9d} {settled_ln:+18.2f}"
            )
    print(
        f"saturated frames: {int(sat.sum())} of {len(f)}"
        + (f" (starting at {', '.join(f'{t / 1e3:.0f}' for t in f[sat, 0])} ms)" if sat.any() else "")
    )
    print(
        f"exposure trace: initial {f[0, 1]:.0f} µs, min {f[:, 1].min():.0f} µs, max {f[:, 1].max():.0f} µs "
        f"(gain up to {f[:, 2].max():.2f}), final {f[-1, 1]:.0f} µs"
    )


if __name__ == "__main__":
    main()
