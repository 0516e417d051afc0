"""``necviz bench sim``: how fast the closed-loop simulator runs on this machine.

Simulates a scenario (a preset or a TOML file; default ``tunnel_exit``, 5 s at 346x260) with several cameras sharing one scene and one
event stream, each at its own fixed exposure, consuming every packet. Reports the real-time factor
(simulated seconds per wall second; >= 1 is faster than real time), events generated, scene
samples rendered and frames per camera. Prints a live progress line while it runs.
"""

from __future__ import annotations

import time

import numpy as np

from necviz.bench.timing import machine, write_result
from necviz.core.errors import ParameterError
from necviz.core.frames import Frame
from necviz.progress import output


def run(duration_s=5.0, cameras=6, scene=None, json_path=None, out=...) -> dict:
    """Run the simulator benchmark on ``scene`` (:class:`~necviz.options.SceneOptions`; its duration
    defaults to ``duration_s``), print progress and a summary, optionally write JSON."""
    out = output(out)
    from dataclasses import replace

    from necviz.drivers.sim.rig import SimRig
    from necviz.options import SceneOptions

    if not (0 < duration_s <= 600) or not (1 <= cameras <= 32):
        raise ParameterError("bench sim needs 0 < duration <= 600 s and 1..32 cameras")
    scene_options = scene or SceneOptions()
    if scene_options.duration_s is None:
        scene_options = replace(scene_options, duration_s=duration_s)
    duration_s = scene_options.duration_s
    scenario, seed = scene_options.name, scene_options.resolved_seed
    scene = scene_options.build()
    exposures = np.geomspace(20, 15_000, cameras)
    rig = SimRig(scene, {f"cam{i}": (float(e), 1.0) for i, e in enumerate(exposures)}, seed=seed)
    frames = 0
    events = 0
    t_start = time.perf_counter()
    next_report = 0.0
    for name, p in rig.packets():
        if name is None:
            events += len(p)
        elif isinstance(p, Frame):
            frames += 1
        now = time.perf_counter()
        if now >= next_report:
            sim_s = rig.now_us / 1e6
            print(
                f"\r  simulated {sim_s:5.2f}/{duration_s:g} s  {events:,} events  {frames} frames  "
                f"({sim_s / max(now - t_start, 1e-9):.2f}x real time)",
                end="",
                file=out,
                flush=True,
            )
            next_report = now + 0.5
    wall = time.perf_counter() - t_start
    print(file=out)
    result = {
        "scenario": scenario,
        "seed": seed,
        "duration_s": duration_s,
        "cameras": cameras,
        "wall_s": wall,
        "realtime_factor": duration_s / wall,
        "events": int(events),
        "mev_per_s_generated": events / wall / 1e6,
        "samples_rendered": rig.samples_rendered,
        "frames": frames,
        "sensor": f"{scene.sensor.width}x{scene.sensor.height}",
        "machine": machine(),
    }
    print(
        f"{scenario}: {duration_s:g} s with {cameras} cameras in {wall:.2f} s -> real-time factor "
        f"{result['realtime_factor']:.2f}; {events:,} events, {rig.samples_rendered} scene samples, "
        f"{frames} frames",
        file=out,
    )
    write_result(result, json_path, out)
    return result
