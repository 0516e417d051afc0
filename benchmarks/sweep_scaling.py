#!/usr/bin/env python
"""``necviz sweep`` speed: scaling from 1 to 2 workers, and what scheduling plus writing costs.

The grid: ``tunnel_exit`` (0.5 s simulated) with ``transition_ms`` 15, 40, 150 and 400, NEC,
seeds 0..9 — 40 runs of about one second each on this machine. Each worker count runs the whole
grid into a fresh folder on an embedded local cluster (``--repeats`` times, alternating), and the
script reports:

* ``sweep wall``: from the first task submitted to the last row written (the cluster's start is
  listed apart; each worker's one-off warm-up is inside);
* ``scaling``: sweep wall with 2 workers / with 1 worker (the target is at most 0.55);
* ``overhead``: scheduling and writing as a fraction of the summed run time. With one worker the
  sweep is serial, so everything that is not a run or the warm-up is overhead:
  ``(sweep wall - warm-up - sum of runs) / sum of runs``. With two workers the same accounting
  also counts the idle tail (one worker finishing the last run alone), so the figure given is the
  gaps between consecutive runs on each worker plus the last row's write, over the summed runs.

The load average before and after is recorded: other processes on the machine inflate every
figure, so a run with a 1-minute load above ~0.5 before it started is flagged as disturbed.

usage: python benchmarks/sweep_scaling.py [--repeats 2] [--seeds 10] [--duration 2.0] [--json PATH]
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import sys
import tempfile
import time
from itertools import pairwise
from pathlib import Path

from necviz.sweeps import SweepOptions, load_plan, run_sweep

GRID = """
name = "sweep-scaling benchmark"
seeds = "0..{last}"
duration_s = {duration}
controllers = ["nec"]
[[scenarios]]
name = "tunnel_exit"
params = {{ transition_ms = [15, 40, 150, 400] }}
"""


def one(plan, workers: int, folder: Path) -> dict:
    out = folder / f"w{workers}-{time.time_ns()}"
    t0 = time.perf_counter()
    res = run_sweep(plan, out, SweepOptions(workers=workers, dashboard=None), stream=None)
    total = time.perf_counter() - t0
    assert res.ok == len(plan.runs), f"{res.failed} runs failed"
    # gaps between consecutive runs on each worker (scheduling, result transfer, row building)
    by_worker: dict = {}
    for w, start, end in res.timeline:
        by_worker.setdefault(w, []).append((start, end))
    gaps = 0.0
    for spans in by_worker.values():
        spans.sort()
        gaps += sum(max(0.0, b[0] - a[1]) for a, b in pairwise(spans))
    shutil.rmtree(out, ignore_errors=True)
    serial = (res.wall_s - res.warmup_s - res.run_s) / res.run_s
    return {
        "workers": workers,
        "runs": res.ok,
        "sweep_wall_s": res.wall_s,
        "startup_s": res.startup_s,
        "total_s": total,
        "run_s_sum": res.run_s,
        "run_s_mean": res.run_s / res.ok,
        "warmup_s_sum": res.warmup_s,
        "write_s_sum": res.write_s,
        "gaps_s_sum": gaps,
        "overhead_serial": serial if workers == 1 else None,
        "overhead_gaps": gaps / res.run_s,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=2, help="sweeps per worker count (alternating; default 2)")
    ap.add_argument("--seeds", type=int, default=10, help="seeds per cell (default 10: 40 runs)")
    ap.add_argument(
        "--duration",
        type=float,
        default=0.5,
        help="simulated seconds per run (default 0.5: about one second of run time)",
    )
    ap.add_argument("--json", default=str(Path(__file__).parent / "results" / "sweep_scaling.json"))
    args = ap.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="necviz-sweep-bench-"))
    grid = folder / "grid.toml"
    grid.write_text(GRID.format(last=args.seeds - 1, duration=args.duration))
    plan = load_plan(grid)
    load_before = os.getloadavg()
    results = []
    try:
        for rep in range(args.repeats):
            for w in (1, 2) if rep % 2 == 0 else (2, 1):
                r = one(plan, w, folder)
                r["repeat"] = rep
                results.append(r)
                print(
                    f"  {w} worker{'s' if w > 1 else ' '}: sweep {r['sweep_wall_s']:6.1f} s, runs "
                    f"{r['run_s_mean']:.2f} s each, startup {r['startup_s']:.1f} s",
                    file=sys.stderr,
                    flush=True,
                )
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    load_after = os.getloadavg()

    def best(w):
        return min((r for r in results if r["workers"] == w), key=lambda r: r["sweep_wall_s"])

    b1, b2 = best(1), best(2)
    ratios = [
        r2["sweep_wall_s"] / r1["sweep_wall_s"]
        for r1, r2 in zip(
            [r for r in results if r["workers"] == 1], [r for r in results if r["workers"] == 2], strict=True
        )
    ]
    summary = {
        "runs": len(plan.runs),
        "scaling_best": b2["sweep_wall_s"] / b1["sweep_wall_s"],
        "scaling_per_repeat": ratios,
        "scaling_total_best": b2["total_s"] / b1["total_s"],
        "overhead_serial_best": b1["overhead_serial"],
        "overhead_gaps_2_workers": b2["overhead_gaps"],
        "run_s_mean_1_worker": b1["run_s_mean"],
        "run_s_mean_2_workers": b2["run_s_mean"],
        "load_before": load_before,
        "load_after": load_after,
        "disturbed": load_before[0] > 0.5,
    }
    print(
        f"\nsweep scaling: {len(plan.runs)} runs (tunnel_exit {args.duration:g} s, 4 transitions × {args.seeds} "
        f"seeds, NEC); best of {args.repeats}\n"
    )
    print("| workers | sweep wall s | cluster start s | mean run s | summed runs s | warm-up s | overhead |")
    print("|---|---|---|---|---|---|---|")
    for b in (b1, b2):
        ov = b["overhead_serial"] if b["workers"] == 1 else b["overhead_gaps"]
        print(
            f"| {b['workers']} | {b['sweep_wall_s']:.1f} | {b['startup_s']:.1f} | {b['run_s_mean']:.2f} | "
            f"{b['run_s_sum']:.1f} | {b['warmup_s_sum']:.1f} | {100 * ov:.2f} % |"
        )
    print(
        f"\n2 workers / 1 worker: {summary['scaling_best']:.3f} of the sweep time (per repeat: "
        f"{', '.join(f'{x:.3f}' for x in ratios)}; with the cluster start {summary['scaling_total_best']:.3f})"
    )
    print(
        f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f}"
        + (" — DISTURBED: other processes were running" if summary["disturbed"] else "")
    )
    doc = {
        "benchmark": "sweep_scaling",
        "command": "python benchmarks/sweep_scaling.py " + " ".join(sys.argv[1:]),
        "grid": GRID.format(last=args.seeds - 1, duration=args.duration),
        "summary": summary,
        "sweeps": results,
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
        "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    from necviz.outputs import write_json

    write_json(args.json, doc, indent=1)
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
