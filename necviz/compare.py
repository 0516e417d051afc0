"""``necviz compare``: every controller in closed loop on the same simulated scene.

All cameras share one scene and one event stream (:class:`~necviz.drivers.sim.camera.SimRig`);
each controller drives its own camera. NEC sees events and frames, the image-only baselines see
their frames (they receive the event batches too, and ignore them). Every controller starts from
the same exposure (right for the scene's first instant) under the same camera limits.
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from .core.control import CONTROLLERS, CameraLimits, make_controller
from .core.errors import ParameterError
from .core.frames import Frame
from .core.metrics import SiftMatcher, over_exposed_rate, summarise, under_exposed_rate
from .drivers.sim.aps import ApsParams
from .drivers.sim.camera import SimRig
from .drivers.sim.scenes import SCENARIOS, make_scenario

METRICS = ("frames", "saturated_frames_50", "saturated_frames_10", "mean_over_exposed_rate",
           "mean_under_exposed_rate", "recovery_ms", "sift_inliers_mean")


def parse_controllers(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in CONTROLLERS]
    if not names or unknown:
        raise ParameterError(f"unknown controller(s) {', '.join(unknown) or '(none given)'}; "
                             f"available: {', '.join(sorted(CONTROLLERS))}")
    if len(set(names)) != len(names):
        raise ParameterError("each controller may appear once in --controllers")
    return names


def run_once(scenario: str, controllers: list[str], seed: int, duration_s: float | None, sift: bool,
             recording=None, scenario_params: dict | None = None, out=...) -> dict:
    """One closed-loop run; returns ``{name: metrics dict}`` plus traces."""
    out = sys.stdout if out is ... else out
    scene = make_scenario(scenario, seed=seed, duration_us=None if duration_s is None else int(duration_s * 1e6),
                          **(scenario_params or {}))
    aps = ApsParams()
    rig = SimRig(scene, controllers, aps=aps, seed=seed)
    limits = CameraLimits(aps.exposure_min_us, aps.exposure_max_us, aps.gain_max)
    ctrls = {n: make_controller(n, sensor=scene.sensor, limits=limits, exposure_us=rig.cams[n].exposure_us)
             for n in controllers}
    per = {n: {"starts": [], "over": [], "under": [], "sift": [], "exposure": [], "gain": []} for n in controllers}
    sifts = {n: SiftMatcher() for n in controllers} if sift else {}
    t_wall = time.perf_counter()
    next_report = 0.0
    for cam, packet in rig.packets():
        for n in (controllers if cam is None else (cam,)):
            cmd = ctrls[n].feed(packet)
            if cmd is not None:
                rig.set_exposure(n, cmd.exposure_us, cmd.gain)
                if recording is not None:
                    recording.scalar(f"{n}/exposure/commanded", cmd.issue_time_us, cmd.exposure_us)
                    recording.scalar(f"{n}/gain/commanded", cmd.issue_time_us, cmd.gain)
                    lp = getattr(ctrls[n], "last_log_irradiance", math.nan)
                    if math.isfinite(lp):
                        recording.scalar(f"{n}/irradiance/predicted", cmd.issue_time_us, lp)
        if isinstance(packet, Frame):
            p = per[cam]
            over, under = over_exposed_rate(packet.image), under_exposed_rate(packet.image)
            p["starts"].append(packet.exposure_start_us)
            p["over"].append(over)
            p["under"].append(under)
            p["exposure"].append(packet.exposure_us)
            p["gain"].append(packet.gain)
            if sift:
                p["sift"].append(sifts[cam].next(packet.image))
            if recording is not None:
                recording.frame(cam, packet.exposure_start_us, packet.sequence, packet.image, over, under)
                recording.scalar(f"{cam}/exposure/applied", packet.exposure_start_us, packet.exposure_us)
                recording.scalar(f"{cam}/gain/applied", packet.exposure_start_us, packet.gain)
                recording.scalar(f"{cam}/over_exposed_rate", packet.exposure_start_us, over)
                recording.scalar(f"{cam}/under_exposed_rate", packet.exposure_start_us, under)
        now = time.perf_counter()
        if out is not None and now >= next_report:
            print(f"\r  {scenario} seed {seed}: {rig.now_us / 1e6:5.2f}/{scene.duration_us / 1e6:g} s simulated "
                  f"({now - t_wall:4.1f} s)", end="", file=out, flush=True)
            next_report = now + 0.5
    if out is not None:
        print(file=out)
    steps = [c.t_us for c in scene.changes]
    res = {}
    for n in controllers:
        p = per[n]
        m = summarise(p["starts"], p["over"], p["under"], steps, p["sift"] if sift else None, end_us=scene.duration_us)
        res[n] = {**m.as_dict(), "exposure_trace_us": p["exposure"], "gain_trace": p["gain"],
                  "frame_starts_us": p["starts"]}
    return {"results": res, "duration_s": scene.duration_us / 1e6, "steps_us": steps}


def _fmt(v, std=None, digits=1):
    if v is None:
        return "—"
    s = f"{v:.{digits}f}" if isinstance(v, float) else str(v)
    if std is not None and std > 0:
        s += f" ± {std:.{digits}f}"
    return s


def run(scenario="tunnel_exit", controllers="nec,navid,shim,begin,builtin,fixed", seed=0, seeds=1,
        duration_s=None, sift=True, json_path=None, save=None, scenario_params=None, out=...) -> dict:
    """Run the comparison (``seeds`` runs from ``seed``), print a table, write JSON and an .rrd."""
    out = sys.stdout if out is ... else out
    if scenario not in SCENARIOS:
        raise ParameterError(f"unknown scenario {scenario!r}; available: {', '.join(sorted(SCENARIOS))}")
    names = parse_controllers(controllers) if isinstance(controllers, str) else list(controllers)
    if not isinstance(seeds, int) or seeds < 1:
        raise ParameterError(f"--seeds must be a positive integer, got {seeds!r}")
    if duration_s is not None and not (0 < duration_s <= 600):
        raise ParameterError(f"--duration must lie in (0, 600] s, got {duration_s}")
    recording = None
    if save:
        from .recording import CompareRecording

        recording = CompareRecording(save, {"scenario": scenario, "seed": seed, "seeds": seeds,
                                            "controllers": ",".join(names), **(scenario_params or {})})
    runs = []
    try:
        for k in range(seeds):
            runs.append(run_once(scenario, names, seed + k, duration_s, sift,
                                 recording if k == 0 else None, scenario_params, out))
    finally:
        if recording is not None:
            recording.close()
    table = {}
    for n in names:
        row = {}
        for key in METRICS:
            vals = [r["results"][n][key] for r in runs]
            if any(v is None for v in vals):
                row[key] = None
                row[key + "_std"] = None
            else:
                row[key] = vals[0] if seeds == 1 else float(np.mean(vals))
                row[key + "_std"] = float(np.std(vals, ddof=1)) if seeds > 1 else 0.0
        if seeds == 1:
            row["recovery_ms_per_step"] = runs[0]["results"][n]["recovery_ms_per_step"]
            row["exposure_trace_us"] = runs[0]["results"][n]["exposure_trace_us"]
            row["gain_trace"] = runs[0]["results"][n]["gain_trace"]
            row["frame_starts_us"] = runs[0]["results"][n]["frame_starts_us"]
        table[n] = row
    result = {"scenario": scenario, "seed": seed, "seeds": seeds, "duration_s": runs[0]["duration_s"],
              "lighting_steps_us": runs[0]["steps_us"], "controllers": table}
    if out is not None:
        print(f"\n{scenario}, {result['duration_s']:g} s, seed {seed}" + (f" (+{seeds - 1} more)" if seeds > 1 else ""),
              file=out)
        w = max(10, *(len(n) for n in table))  # controller names registered by users may be longer
        hdr = f"{'controller':{w}s} {'frames':>6s} {'sat>50%':>10s} {'sat>10%':>10s} {'mean over':>10s} " \
              f"{'mean under':>10s} {'recovery ms':>12s} {'SIFT inliers':>13s}"
        print(hdr, file=out)
        for n, r in table.items():
            print(f"{n:{w}s} {_fmt(r['frames'], digits=0):>6s} {_fmt(r['saturated_frames_50'], r['saturated_frames_50_std']):>10s} "
                  f"{_fmt(r['saturated_frames_10'], r['saturated_frames_10_std']):>10s} "
                  f"{_fmt(r['mean_over_exposed_rate'], r['mean_over_exposed_rate_std'], 3):>10s} "
                  f"{_fmt(r['mean_under_exposed_rate'], r['mean_under_exposed_rate_std'], 3):>10s} "
                  f"{_fmt(r['recovery_ms'], r['recovery_ms_std']):>12s} "
                  f"{_fmt(r['sift_inliers_mean'], r['sift_inliers_mean_std']):>13s}", file=out)
    if json_path:
        Path(json_path).parent.mkdir(parents=True, exist_ok=True)
        Path(json_path).write_text(json.dumps(result, indent=1) + "\n")
        if out is not None:
            print(f"wrote {json_path}", file=out)
    if save and out is not None:
        print(f"wrote {save} (open it with: rerun {save})", file=out)
    return result
