"""``necviz sweep plan``: what a sweep file expands to and how long it should take.

The estimate comes from one calibration run in this process, made as a sweep worker makes it
(single-threaded simulator, after a warm-up that loads the Numba kernels): the grid's first run,
at most ``cap_s`` simulated seconds of it. Its time per simulated second, times the grid's
simulated seconds, is the summed run time, spread over the workers. Other scenarios and
controllers cost differently (NEC processes every event, the image-only baselines do not; SIFT
adds about 40 ms a frame; a scene costs more once it is bright and full of events), so the figure
is a guide, not a promise.
"""

from __future__ import annotations

import json
import time

from necviz.sweeps.spec import Plan


def run_duration_s(spec: dict) -> float:
    """The simulated seconds of a run: its ``duration_s``, else its scenario file's, else the preset's."""
    if spec.get("duration_s") is not None:
        return float(spec["duration_s"])
    from necviz.drivers.sim.scenes import SCENARIOS
    from necviz.options import SceneOptions

    sc = SceneOptions(
        spec["scenario"], seed=spec.get("seed"), duration_s=None, params=dict(spec.get("scenario_params") or {})
    )
    s = sc.spec()
    if s.get("duration_us"):
        return s["duration_us"] / 1e6
    return SCENARIOS[s["name"]].DEFAULT_DURATION_US / 1e6


def describe(plan: Plan) -> dict:
    """Counts and the swept values of ``plan`` (plain data)."""
    from necviz.sweeps.report import is_spec_column

    counts = plan.counts()
    scen_cfg = {
        json.dumps([r.spec["scenario"], r.spec["scenario_params"], r.spec["sim"], r.spec["duration_s"]], sort_keys=True)
        for r in plan.runs
    }
    values: dict = {}
    for r in plan.runs:
        for k, v in r.columns.items():
            if is_spec_column(k) and k not in ("controller",):
                values.setdefault(k, [])
                if v not in values[k]:
                    values[k].append(v)
    swept = {k: v for k, v in values.items() if len(v) > 1}
    durations: dict = {}
    for r in plan.runs:
        key = (r.spec["scenario"], r.spec["duration_s"], json.dumps(r.spec["scenario_params"], sort_keys=True))
        if key not in durations:
            durations[key] = run_duration_s(r.spec)
    sim_s = sum(
        durations[(r.spec["scenario"], r.spec["duration_s"], json.dumps(r.spec["scenario_params"], sort_keys=True))]
        for r in plan.runs
    )
    ctrl = []
    for r in plan.runs:
        (c,) = r.spec["controllers"]
        label = c + (
            f" {json.dumps(r.spec['controller_params'][c], sort_keys=True)}"
            if r.spec["controller_params"].get(c)
            else ""
        )
        if label not in ctrl:
            ctrl.append(label)
    return {
        "name": plan.name,
        **counts,
        "scenario_configurations": len(scen_cfg),
        "profiles": len(values.get("profile", [None])),
        "seeds_list": plan.seeds,
        "sift": plan.sift,
        "markers": plan.markers,
        "swept": swept,
        "controllers": ctrl,
        "simulated_s": sim_s,
        "metrics": plan.metrics,
    }


def calibrate(plan: Plan, cap_s: float = 2.0) -> dict | None:
    """Time one run of the grid's first spec (see the module docstring) as a sweep worker runs it."""
    from necviz.runs import run_spec
    from necviz.sweeps.worker import flatten_result

    if not plan.runs:
        return None
    first = dict(plan.runs[0].spec)
    try:
        d = min(run_duration_s(first), cap_s)
    except Exception as e:  # noqa: BLE001 - no estimate rather than no plan
        return {"error": f"{type(e).__name__}: {' '.join(str(e).split())[:200]}"}
    try:
        from necviz.sweeps.engine import _warmup_spec

        # warm-up: load the kernels, as a sweep worker does (a preset: a scenario file's own parameters,
        # its change jitter say, may not fit a few-ms run); single-threaded, as on a sweep worker
        run_spec(_warmup_spec(plan), threads=False)
        t0 = time.perf_counter()
        result = run_spec(dict(first, duration_s=d), threads=False)
        took = time.perf_counter() - t0
    except Exception as e:  # noqa: BLE001 - no estimate rather than no plan
        return {"error": f"{type(e).__name__}: {' '.join(str(e).split())[:200]}"}
    metrics = flatten_result(result["results"][first["controllers"][0]])[1]
    return {
        "scenario": first["scenario"],
        "controller": first["controllers"][0],
        "sift": bool(first.get("sift")),
        "metrics": metrics,
        "duration_s": d,
        "run_s": took,
        "per_sim_s": took / d,
    }


def estimate(plan: Plan, workers: int, cal: dict | None, desc: dict | None = None) -> dict | None:
    if not cal or "error" in cal:
        return cal
    desc = desc or describe(plan)
    total = desc["simulated_s"] * cal["per_sim_s"]
    return {
        **cal,
        "workers": workers,
        "run_s_total": total,
        "run_s_mean": total / max(1, len(plan.runs)),
        "wall_s": total / max(1, workers),
    }


__all__ = ["calibrate", "describe", "estimate", "run_duration_s"]
