"""``necviz bench sim``: how fast the closed-loop simulator runs on this machine.

Simulates a scenario (a preset or a TOML file; default ``tunnel_exit``, 5 s at 346x260) with several cameras sharing one scene and one
event stream, each at its own fixed exposure, consuming every packet. Reports the real-time factor
(simulated seconds per wall second; >= 1 is faster than real time), events generated, scene
samples rendered and frames per camera. Prints a live progress line while it runs.

Each figure is the median of ``repeats`` runs, with the slowest and fastest. Start-up is not timed: the
rig's kernels are loaded first (:meth:`~necviz.drivers.sim.rig.SimRig.warm_up`). The same run also
measures a *replay*: the rig reading the rendered scene and its events from a scene cache
(:mod:`necviz.drivers.sim.scene_cache`, a temporary one written by the first run), as a replayed demo
does: frames are still formed per camera, the packets are the same.
"""

from __future__ import annotations

import tempfile
import time

import numpy as np

from necviz.bench.timing import machine, spread, write_result
from necviz.core.errors import ParameterError
from necviz.core.frames import Frame
from necviz.progress import output


def _one(rig, duration_s: float, out, label: str) -> tuple[float, int, int]:
    """Consume every packet of ``rig``; ``(wall seconds, events, frames)``."""
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
                f"\r  {label}: simulated {sim_s:5.2f}/{duration_s:g} s  {events:,} events  {frames} frames  "
                f"({sim_s / max(now - t_start, 1e-9):.2f}x real time)",
                end="",
                file=out,
                flush=True,
            )
            next_report = now + 0.5
    wall = time.perf_counter() - t_start
    if out is not None:
        print(file=out)
    return wall, events, frames


def run(duration_s=5.0, cameras=6, scene=None, json_path=None, out=..., repeats: int = 3, replay: bool = True) -> dict:
    """Run the simulator benchmark on ``scene`` (:class:`~necviz.options.SceneOptions`; its duration
    defaults to ``duration_s``) ``repeats`` times (and as many replays from a scene cache), print progress
    and a summary, optionally write JSON."""
    out = output(out)
    from dataclasses import replace

    from necviz.drivers.sim.rig import SimRig
    from necviz.drivers.sim.scene_cache import SceneCache
    from necviz.options import SceneOptions

    if not (0 < duration_s <= 600) or not (1 <= cameras <= 32) or repeats < 1:
        raise ParameterError("bench sim needs 0 < duration <= 600 s, 1..32 cameras and repeats >= 1")
    scene_options = scene or SceneOptions()
    if scene_options.duration_s is None:
        scene_options = replace(scene_options, duration_s=duration_s)
    duration_s = scene_options.duration_s
    scenario, seed = scene_options.name, scene_options.resolved_seed
    scene = scene_options.build()
    exposures = np.geomspace(20, 15_000, cameras)

    def rig_with(cache=None):
        return SimRig(scene, {f"cam{i}": (float(e), 1.0) for i, e in enumerate(exposures)}, seed=seed, cache=cache)

    rig_with().warm_up()  # kernels loaded before anything is timed
    walls, cached_walls = [], []
    events = frames = 0
    rig = None
    with tempfile.TemporaryDirectory(prefix="necviz-bench-cache-") as tmp:
        cache = SceneCache(tmp, 1 << 40) if replay else None
        for k in range(repeats):
            rig = rig_with(cache if k == 0 else None)  # the first run also writes the cache the replays read
            wall, events, frames = _one(rig, duration_s, out, f"run {k + 1}/{repeats}")
            walls.append(wall)
        samples = rig.samples_rendered
        if replay:
            for k in range(repeats):
                r = rig_with(cache)
                wall, ev, fr = _one(r, duration_s, out, f"replay {k + 1}/{repeats}")
                if r.samples_cached == 0 or ev != events or fr != frames:
                    raise RuntimeError("the replay did not read the cache, or differed from the simulation")
                cached_walls.append(wall)
    wall = float(np.median(walls))
    result = {
        "scenario": scenario,
        "seed": seed,
        "duration_s": duration_s,
        "cameras": cameras,
        "wall_s": wall,
        "realtime_factor": duration_s / wall,
        "realtime_factor_runs": spread(duration_s / np.array(walls)),
        "events": int(events),
        "mev_per_s_generated": events / wall / 1e6,
        "samples_rendered": samples,
        "frames": frames,
        "sensor": f"{scene.sensor.width}x{scene.sensor.height}",
        "machine": machine(),
    }
    if cached_walls:
        result["replay_from_scene_cache"] = {
            "wall_s": float(np.median(cached_walls)),
            "realtime_factor": duration_s / float(np.median(cached_walls)),
            "realtime_factor_runs": spread(duration_s / np.array(cached_walls)),
        }
    print(
        f"{scenario}: {duration_s:g} s with {cameras} cameras in {wall:.2f} s (median of {repeats}) -> real-time "
        f"factor {result['realtime_factor']:.2f} ({result['realtime_factor_runs']['min']:.2f}.."
        f"{result['realtime_factor_runs']['max']:.2f}); {events:,} events, {samples} scene samples, {frames} frames",
        file=out,
    )
    if cached_walls:
        rc = result["replay_from_scene_cache"]
        print(
            f"  replayed from the scene cache: real-time factor {rc['realtime_factor']:.2f} "
            f"({rc['realtime_factor_runs']['min']:.2f}..{rc['realtime_factor_runs']['max']:.2f})",
            file=out,
        )
    print(f"  load average {result['machine']['load_average']}", file=out)
    write_result(result, json_path, out)
    return result
