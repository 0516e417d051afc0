#!/usr/bin/env python
"""How long the evaluation sweeps will take: every controller timed on its own, then summed over each file's runs.

``necviz sweep plan FILE`` times one calibration run (the grid's first) and scales it to the whole grid;
the evaluation's files mix controllers whose costs differ several-fold (Shim and Bégin process every
frame at full resolution with several synthetic exposures; NEC's events are cheap), so one run is a
poor guide. This script times each controller of the files once, as a sweep worker runs it (one
thread, after a warm-up), on a preset of ``--duration`` simulated seconds, and adds up
``simulated seconds x seconds per simulated second`` over every run of every file, then divides by
the workers. The figure is for this machine at the time it runs (the load of other jobs included).

usage: python benchmarks/sweep_budget.py FILE.toml [FILE.toml ...] [--workers 2] [--duration 2]
                                         [--scenario tunnel_exit] [--json benchmarks/results/sweep_budget.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def time_controller(name: str, params: dict, scenario: str, duration_s: float) -> float:
    """Seconds of wall time per simulated second of one single-threaded run of ``name``."""
    from necviz.runs import run_spec

    spec = {"scenario": scenario, "seed": 0, "controllers": [name], "sift": False}
    if params:
        spec["controller_params"] = {name: params}
    # single-threaded, as on a sweep worker; first a warm-up: the Numba kernels
    run_spec(dict(spec, duration_s=0.05), threads=False)
    t0 = time.perf_counter()
    run_spec(dict(spec, duration_s=duration_s), threads=False)
    return (time.perf_counter() - t0) / duration_s


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--duration", type=float, default=2.0, help="simulated seconds of each timing run")
    ap.add_argument("--scenario", default="tunnel_exit", help="the preset the controllers are timed on")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    from necviz.sweeps.planning import run_duration_s
    from necviz.sweeps.spec import load_plan

    plans = [(f, load_plan(f)) for f in args.files]
    configs = {}
    for _, plan in plans:
        for r in plan.runs:
            (c,) = r.spec["controllers"]
            key = json.dumps([c, r.spec["controller_params"].get(c) or {}], sort_keys=True)
            configs[key] = (c, r.spec["controller_params"].get(c) or {})
    cost = {}
    for key, (c, params) in configs.items():
        cost[key] = time_controller(c, params, args.scenario, args.duration)
        print(f"  {c:20s} {json.dumps(params)[:60]:60s} {cost[key]:6.2f} s per simulated s", file=sys.stderr)
    total_s, rows = 0.0, []
    durations: dict = {}
    for f, plan in plans:
        run_s, sim_s = 0.0, 0.0
        for r in plan.runs:
            (c,) = r.spec["controllers"]
            dkey = (r.spec["scenario"], r.spec["duration_s"], json.dumps(r.spec["scenario_params"], sort_keys=True))
            if dkey not in durations:
                durations[dkey] = run_duration_s(r.spec)
            d = durations[dkey]
            sim_s += d
            run_s += d * cost[json.dumps([c, r.spec["controller_params"].get(c) or {}], sort_keys=True)]
        total_s += run_s
        rows.append(
            {"file": f, "runs": len(plan.runs), "simulated_s": sim_s, "run_s": run_s, "wall_s": run_s / args.workers}
        )
    print(
        f"\n{'file':44s} {'runs':>6s} {'simulated s':>12s} {'CPU h':>7s} {'wall h (' + str(args.workers) + ' workers)':>20s}"
    )
    for r in rows:
        print(
            f"{r['file']:44s} {r['runs']:6d} {r['simulated_s']:12.0f} {r['run_s'] / 3600:7.2f} {r['wall_s'] / 3600:20.2f}"
        )
    print(
        f"{'total':44s} {sum(r['runs'] for r in rows):6d} {sum(r['simulated_s'] for r in rows):12.0f} "
        f"{total_s / 3600:7.2f} {total_s / args.workers / 3600:20.2f}"
    )
    if args.json:
        out = {
            "command": "python benchmarks/sweep_budget.py " + " ".join(argv if argv is not None else sys.argv[1:]),
            "workers": args.workers,
            "timing_scenario": args.scenario,
            "timing_duration_s": args.duration,
            "seconds_per_simulated_second": {k: v for k, v in cost.items()},
            "files": rows,
            "total_wall_s": total_s / args.workers,
        }
        Path(args.json).write_text(json.dumps(out, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
