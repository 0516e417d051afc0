#!/usr/bin/env python
"""The flicker rule's edges (``NECOptions.flicker_edges``) and their ablation on the training scenes (issue 30).

Runs ``nec`` (edges on, the default), ``nec`` with ``flicker_edges = false`` (the flicker rule as it was)
and ``nec-frames`` as lanes of one rig (same scene, same events) over seeds ``FIRST..FIRST+N-1`` with every
change at a random phase (``change_jitter_ms = 10``), and prints per scene the mean frames per run over
50 % and over 10 % clipped, then per family (the flicker scenes: the ``flicker`` preset and every
``benchmarks/training/*.toml`` flicker scene; every scene) NEC − ``nec-frames`` and NEC − the rule without
edges, clustered by scene (Student's t over the scenes' mean paired differences). Training scenes by
default: the rule was designed on them. ``--validation`` runs the validation set's scenes
(``benchmarks/heldout/*.toml``) on seeds 100..104 instead, after the design was fixed.

usage: python benchmarks/flicker_edges.py [--seeds 5] [--first-seed 0] [--jobs 2] [--scenarios a,b]
                                          [--validation] [--json benchmarks/results/flicker_edges.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from flicker_rule import any_failed, paired_row  # noqa: E402
from tuning import CHANGE_JITTER_MS, PRESETS, run_all, t_ci  # noqa: E402

TRAINING_FILES = sorted(str(p.relative_to(HERE.parent)) for p in (HERE / "training").glob("*.toml"))
HELDOUT_FILES = sorted(str(p.relative_to(HERE.parent)) for p in (HERE / "heldout").glob("*.toml"))
LANES = ["nec", "nec@no_flicker_edges", "nec-frames"]
PARAMS = {"nec@no_flicker_edges": {"flicker_edges": False}}


def _family(scenario: str) -> str:
    """``flicker`` for the flicker preset and every flicker scene file, else the scene's preset name."""
    if scenario.endswith(".toml"):
        import tomllib

        return tomllib.loads((HERE.parent / scenario).read_text(encoding="utf-8"))["name"]
    return scenario


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=None, help="seeds FIRST..FIRST+N-1 (training 0, validation 100)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--scenarios", default=None, help="comma-separated (default: the training scenes)")
    ap.add_argument("--validation", action="store_true", help="the validation scenes, seeds from 100")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    first = args.first_seed if args.first_seed is not None else (100 if args.validation else 0)
    default = HELDOUT_FILES if args.validation else TRAINING_FILES + PRESETS
    scenarios = [s for s in (args.scenarios or ",".join(default)).split(",") if s]
    out_json = args.json or str(
        HERE / "results" / ("flicker_edges_validation.json" if args.validation else "flicker_edges.json")
    )
    # the validation files carry their own change_jitter_ms; the training runs set 10 ms (docs/evaluation.md)
    jitter = {} if args.validation else {"change_jitter_ms": CHANGE_JITTER_MS}
    specs = [
        {
            "scenario": s,
            "seed": k,
            "scenario_params": jitter,
            "controllers": LANES,
            "controller_params": PARAMS,
            "sift": False,
        }
        for s in scenarios
        for k in range(first, first + args.seeds)
    ]
    t0 = time.perf_counter()
    runs = run_all(specs, args.jobs)
    if any_failed(runs):
        return 1
    table: dict[str, dict] = {}
    print(f"{'scene':24s} {'>50%: nec / no edges / frames':>32s} {'>10%: nec / no edges / frames':>32s}")
    for s in scenarios:
        rs = [r for r in runs if r["scenario"] == s]
        row = {"family": _family(s), **paired_row(rs, LANES, "nec@no_flicker_edges", "nec - no edges")}
        table[Path(s).stem] = row
        f = lambda m, row=row: " / ".join(f"{row[m][ln][0]:.1f}" for ln in LANES)  # noqa: E731
        print(f"{Path(s).stem:24s} {f('saturated_frames_50'):>32s} {f('saturated_frames_10'):>32s}")
    families: dict[str, dict] = {}
    groups = {"flicker": [k for k, v in table.items() if v["family"] == "flicker"], "every scene": list(table)}
    for fam in sorted({v["family"] for v in table.values()}):
        if fam != "flicker":
            groups[fam] = [k for k, v in table.items() if v["family"] == fam]
    print(
        f"\n{'family (scenes)':24s} {'metric':>20s} {'nec - nec-frames':>18s} {'nec - no edges':>18s} {'no edges - frames':>18s}"
    )
    for fam, keys in groups.items():
        if not keys:
            continue
        fam_row = {}
        for m in ("saturated_frames_50", "saturated_frames_10"):
            d = {key: t_ci([table[k][m][key][0] for k in keys]) for key in ("nec - nec-frames", "nec - no edges")}
            d["no edges - nec-frames"] = t_ci(
                [table[k][m]["nec@no_flicker_edges"][0] - table[k][m]["nec-frames"][0] for k in keys]
            )
            fam_row[m] = d
            pm = lambda c: f"{c[0]:+.2f} ± {c[1]:.2f}"  # noqa: E731
            print(
                f"{fam + f' ({len(keys)})':24s} {m:>20s} {pm(d['nec - nec-frames']):>18s} {pm(d['nec - no edges']):>18s}"
                f" {pm(d['no edges - nec-frames']):>18s}"
            )
        families[fam] = {"scenes": keys, **fam_row}
    out = {
        "command": "python benchmarks/flicker_edges.py " + " ".join(sys.argv[1:]),
        "seeds": list(range(first, first + args.seeds)),
        "scenario_params": jitter,
        "lanes": LANES,
        "controller_params": PARAMS,
        "table": table,
        "families": families,
        "seconds": time.perf_counter() - t0,
    }
    Path(out_json).write_text(json.dumps(out, indent=1, default=float) + "\n", encoding="utf-8")
    print(f"wrote {out_json} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
