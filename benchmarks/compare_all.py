#!/usr/bin/env python
"""NEC versus the baselines on every simulator scenario: the README's comparison tables.

Runs `necviz compare` for each scenario (default duration, every controller of the comparison, SIFT on),
writes benchmarks/results/compare_<scenario>.json and prints one Markdown table per scenario.
About 5 minutes on 2 cores (SIFT on every frame is most of it).

usage: python benchmarks/compare_all.py [--seeds N] [--scenarios a,b]
"""

import argparse
import sys
from pathlib import Path

from necviz.compare import run
from necviz.drivers.sim.scenes import SCENARIOS
from necviz.options import CompareOptions, SceneOptions

ORDER = ["tunnel_exit", "indoor_outdoor", "flicker", "static_lab", "handheld_scan"]


def cell(row, key, digits):
    v, s = row[key], row.get(key + "_ci95")
    if v is None:
        return "never"
    txt = f"{v:.{digits}f}" if isinstance(v, float) else str(v)
    return txt + (f" ± {s:.{digits}f}" if s else "")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--scenarios", default=",".join(ORDER))
    args = ap.parse_args()
    out_dir = Path(__file__).parent / "results"
    for name in args.scenarios.split(","):
        if name not in SCENARIOS:
            print(f"unknown scenario {name}", file=sys.stderr)
            return 2
        res = run(CompareOptions(SceneOptions(name), seeds=args.seeds, json=out_dir / f"compare_{name}.json",
                                 force=True), out=sys.stderr)
        print(f"\n**{name}** ({res['duration_s']:g} s, seed {res['seed']}"
              + (f", {res['seeds']} seeds" if res["seeds"] > 1 else "") + ")\n")
        print("| controller | frames | saturated >50 % | >10 % | mean over-exposed | mean under-exposed | recovery ms | SIFT inliers |")
        print("|---|---|---|---|---|---|---|---|")
        for c, row in res["controllers"].items():
            print(f"| {c} | {cell(row, 'frames', 0)} | {cell(row, 'saturated_frames_50', 1 if args.seeds > 1 else 0)} "
                  f"| {cell(row, 'saturated_frames_10', 1 if args.seeds > 1 else 0)} | {cell(row, 'mean_over_exposed_rate', 3)} "
                  f"| {cell(row, 'mean_under_exposed_rate', 3)} | {cell(row, 'recovery_ms', 0)} "
                  f"| {cell(row, 'sift_inliers_mean', 0)} |")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
