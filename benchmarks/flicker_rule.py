#!/usr/bin/env python
"""NEC's flicker rule and its ablation on the training scenes (issue 30; core/control/flicker_watch.py).

Runs ``nec`` (the rule on), ``nec`` with ``flicker_rule = false`` and ``nec-frames`` as lanes of the same
rig (same scene, same events) on the training scenes — the five presets and the deep-flicker scenes
``benchmarks/training/*.toml`` — over seeds ``0..N-1`` with every change at a random phase
(``change_jitter_ms = 10``), and prints per scene the mean saturated frames (> 50 %, > 10 %) and the
paired differences (per seed) with their 95 % interval (Student's t over seeds). Training scenes only:
the rule was designed on them, so this shows the design, not how it does on unseen scenes.

On the validation set's flicker scenes (seen during the design of NEC, never in the rule's), with its seeds:
``--scenarios benchmarks/heldout/flicker_1200.toml,... --first-seed 100 --seeds 5
--json benchmarks/results/flicker_rule_validation.json``.

usage: python benchmarks/flicker_rule.py [--seeds 3] [--first-seed 0] [--jobs 2] [--scenarios a,b]
                                         [--json benchmarks/results/flicker_rule.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from tuning import CHANGE_JITTER_MS, METRICS, PRESETS, run_all, t_ci  # noqa: E402

TRAINING_FILES = sorted(str(p.relative_to(HERE.parent)) for p in (HERE / "training").glob("*.toml"))
LANES = ["nec", "nec@no_flicker_rule", "nec-frames"]
PARAMS = {"nec@no_flicker_rule": {"flicker_rule": False}}


def any_failed(runs: list[dict]) -> bool:
    """Say in one line (stderr) that runs failed, if any did: a table over the rest would be silently partial."""
    failed = [r for r in runs if "error" in r]
    if failed:
        print(
            f"{len(failed)} of {len(runs)} runs failed (first: {failed[0]['error']}); no table written", file=sys.stderr
        )
    return bool(failed)


def paired_row(rs: list[dict], lanes: list[str], ablated: str, key: str) -> dict:
    """One scene's row over its runs ``rs``: each metric's mean ± 95 % CI per lane, and NEC's paired differences
    with ``nec-frames`` and with the ablated lane (under ``key``), then the per-seed results."""
    row: dict = {}
    for m in METRICS:
        row[m] = {ln: t_ci([r["results"][ln][m] for r in rs]) for ln in lanes}
        row[m]["nec - nec-frames"] = t_ci([r["results"]["nec"][m] - r["results"]["nec-frames"][m] for r in rs])
        row[m][key] = t_ci([r["results"]["nec"][m] - r["results"][ablated][m] for r in rs])
    row["per_seed"] = {r["seed"]: r["results"] for r in rs}
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=0, help="seeds FIRST..FIRST+N-1 (training: 0)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--scenarios", default=",".join(TRAINING_FILES + PRESETS))
    ap.add_argument("--json", default=str(HERE / "results" / "flicker_rule.json"))
    args = ap.parse_args()
    scenarios = [s for s in args.scenarios.split(",") if s]
    specs = [
        {
            "scenario": s,
            "seed": k,
            "scenario_params": {"change_jitter_ms": CHANGE_JITTER_MS},
            "controllers": LANES,
            "controller_params": PARAMS,
            "sift": False,
        }
        for s in scenarios
        for k in range(args.first_seed, args.first_seed + args.seeds)
    ]
    t0 = time.perf_counter()
    runs = run_all(specs, args.jobs)
    if any_failed(runs):
        return 1
    table = {}
    print(
        f"{'scene':24s} {'>50%: nec / no rule / frames':>30s} {'>10%: nec / no rule / frames':>30s}"
        f"  {'>10% nec-frames':>16s} {'>10% nec-no rule':>17s}"
    )
    for s in scenarios:
        rs = [r for r in runs if r["scenario"] == s]
        row = paired_row(rs, LANES, "nec@no_flicker_rule", "nec - no rule")
        table[Path(s).stem] = row
        f = lambda m, row=row: " / ".join(f"{row[m][ln][0]:.1f}" for ln in LANES)  # noqa: E731
        d = lambda key, row=row: f"{row['saturated_frames_10'][key][0]:+.1f} ± {row['saturated_frames_10'][key][1]:.1f}"  # noqa: E731
        print(
            f"{Path(s).stem:24s} {f('saturated_frames_50'):>30s} {f('saturated_frames_10'):>30s}"
            f"  {d('nec - nec-frames'):>16s} {d('nec - no rule'):>17s}"
        )
    out = {
        "command": "python benchmarks/flicker_rule.py " + " ".join(sys.argv[1:]),
        "seeds": list(range(args.first_seed, args.first_seed + args.seeds)),
        "scenario_params": {"change_jitter_ms": CHANGE_JITTER_MS},
        "lanes": LANES,
        "controller_params": PARAMS,
        "table": table,
        "seconds": time.perf_counter() - t0,
    }
    Path(args.json).write_text(json.dumps(out, indent=1, default=float) + "\n", encoding="utf-8")
    print(f"wrote {args.json} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
