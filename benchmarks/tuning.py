#!/usr/bin/env python
"""Every controller tuned with the same budget: the same number of variants, the same training runs, the same rule.

``benchmarks/metering.py`` chose NEC's defaults from 20 variants of its metering, goal and escape rule on
the presets. A baseline tuned by nobody is not a fair opponent, so this script gives every controller
with parameters the same treatment (docs/evaluation.md):

* **Budget**: :data:`VARIANTS` variants per controller (20), a grid over the parameters that set how
  far and how fast it moves — NEC's 20 metering candidates (the same as ``metering.py``'s), Navid's
  step-size mapping ``ev_per_unit`` × its target MSV, Shim's ``kp`` × ``d`` (2018 rule), Bégin's
  ``feedback_gain`` × ``ev_range`` (its step-size mapping). The published setting is among each
  controller's variants, so tuning can only keep it or beat it on the training runs. The DAVIS
  built-in rule and the fixed exposure have no parameters to tune (the built-in rule is the camera's
  own fixed algorithm; a fixed exposure's only parameter is the exposure): they are not tuned.
* **Training runs**: the five presets and the deep-flicker training scenes (``benchmarks/training/*.toml``)
  × seeds ``0..N-1`` (default 5), every change moved by a seeded
  random phase against the 20 ms frame clock (``change_jitter_ms = 10``), so the seeds are
  independent replicates. Every variant of every controller runs as a lane of the same rig (same
  scene, same events), so they are compared on identical input.
* **Rule** (``metering.py``'s): per controller, a variant's *regret* in a preset is its mean saturated
  frames (> 50 %) minus the best of that controller's variants there; the choice is the least total
  regret over the presets, ties broken by the total > 10 % count, then by the mean ground-truth valid
  fraction.
* **Test** scenes and seeds (``benchmarks/heldout/*.toml``, seeds >= 100) play no part here; the
  evaluation sweeps report on them (``benchmarks/sweeps/heldout.toml``).

Outputs: the table and the choice per controller (stdout), every measurement in
``benchmarks/results/tuning.json``, and the chosen parameters in ``necviz/tuned.json`` (shipped with
the package; :mod:`necviz.tuned` registers them as ``navid-tuned``, ``shim-tuned``, ...).

usage: python benchmarks/tuning.py [--seeds 5] [--controllers nec,navid,shim,begin] [--jobs 2]
                                   [--scenarios a,b] [--duration S] [--json ...] [--tuned necviz/tuned.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
PRESETS = ["tunnel_exit", "indoor_outdoor", "flicker", "static_lab", "handheld_scan"]
#: the deep mains-flicker training scenes (issue 30): 100 and 120 Hz, depths to 0.95, PWM, a switched light,
#: a tunnel exit under flickering lamps; training only, like the presets
TRAINING_FILES = sorted(str(p.relative_to(ROOT)) for p in (HERE / "training").glob("*.toml"))
#: variants per controller: the budget every controller gets
VARIANTS = 20
#: training seeds move each lighting change by a seeded uniform offset in [-10, +10] ms: a uniform phase
#: over the simulated camera's 20 ms frame clock (the presets' ``change_jitter_ms``)
CHANGE_JITTER_MS = 10.0
METRICS = ("saturated_frames_50", "saturated_frames_10", "true_valid_fraction_mean")
#: controllers without parameters to tune, and why
NOT_TUNED = {
    "builtin": "the DAVIS built-in auto-exposure is the camera's own fixed rule (libcaer's constants); it has no "
    "parameters a user sets",
    "fixed": "a fixed exposure has no parameter but the exposure itself",
}


def _label(params: dict) -> str:
    return ",".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in params.items())


def nec_variants() -> dict[str, dict]:
    """NEC's 20 candidates, as ``benchmarks/metering.py`` ran them (metering x goal, escape off/on)."""
    out = {}
    for metering in ("paper", "median", "percentile", "zones"):
        for goal in (None, 100, 128):
            p = {"metering": metering, "goal_mode": "paper", "escape": False}
            if goal is not None:
                p["goal"] = goal
            out[f"{metering}_{'mid' if goal is None else goal}"] = p
    out["paper_mid_esc04"] = {"metering": "paper", "goal_mode": "paper", "escape": True, "edge_margin": 0.4}
    out["zones_mid_esc04"] = {"metering": "zones", "goal_mode": "paper", "escape": True, "edge_margin": 0.4}
    for goal in (None, 100):
        for margin in (0.2, 0.4, 0.7):
            p = {"metering": "median", "goal_mode": "paper", "escape": True, "edge_margin": margin}
            if goal is not None:
                p["goal"] = goal
            out[f"median_{'mid' if goal is None else goal}_esc{int(round(margin * 10)):02d}"] = p
    return out


def grid(**axes) -> dict[str, dict]:
    """Every combination of the axes (``name=[values]``), labelled ``k=v,...``."""
    keys = list(axes)
    combos = [{}]
    for k in keys:
        combos = [{**c, k: v} for c in combos for v in axes[k]]
    return {_label(c): c for c in combos}


def variants() -> dict[str, dict[str, dict]]:
    """Controller -> label -> parameters (each controller :data:`VARIANTS` variants, the published one included)."""
    return {
        "nec": nec_variants(),
        # Navid: its step-size mapping (EV per published PI unit; published mapping ours, 0.01) x the target MSV
        "navid": grid(ev_per_unit=[0.005, 0.01, 0.02, 0.03, 0.05], target_msv=[2.0, 2.25, 2.5, 2.75]),
        # Shim 2018: proportional gain x the nonlinearity d (published 1.6 and 0.1)
        "shim": grid(kp=[0.8, 1.6, 3.2, 6.4], d=[0.05, 0.1, 0.2, 0.4, 0.8]),
        # Bégin: saturation feedback x the largest ΔEV per frame (published 1.5 and 2)
        "begin": grid(feedback_gain=[1.0, 1.5, 2.0, 3.0], ev_range=[2.0, 3.0, 4.0, 6.0, 8.0]),
    }


PUBLISHED = {
    "nec": "median_100_esc04",  # necviz's current default (chosen by metering.py on these presets)
    "navid": "ev_per_unit=0.01,target_msv=2.5",
    "shim": "kp=1.6,d=0.1",
    "begin": "feedback_gain=1.5,ev_range=2",
}


def t_ci(values) -> tuple[float, float]:
    """Mean and 95 % CI half-width (Student's t) of the finite values."""
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=np.float64)
    if v.size == 0:
        return math.nan, math.nan
    if v.size < 2:
        return float(v.mean()), 0.0
    from scipy.stats import t

    return float(v.mean()), float(t.ppf(0.975, v.size - 1) * v.std(ddof=1) / math.sqrt(v.size))


# -- runs -------------------------------------------------------------------------------------------
def _job(spec: dict) -> dict:
    from necviz.runs import run_spec

    t0 = time.perf_counter()
    try:
        r = run_spec(spec)
    except Exception as e:  # noqa: BLE001 - one failed run must not lose the others; reported
        return {"scenario": spec["scenario"], "seed": spec["seed"], "error": f"{type(e).__name__}: {e}"}
    keep = {lane: {k: m.get(k) for k in METRICS} for lane, m in r["results"].items()}
    return {"scenario": spec["scenario"], "seed": spec["seed"], "results": keep, "seconds": time.perf_counter() - t0}


def run_all(specs: list[dict], jobs: int) -> list[dict]:
    out = []
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for i, res in enumerate(pool.map(_job, specs)):
            out.append(res)
            print(
                f"  [{i + 1}/{len(specs)}] {res['scenario']} seed {res['seed']}: {res.get('seconds', 0):.0f} s"
                f"{'  ' + res['error'] if 'error' in res else ''} (elapsed {time.perf_counter() - t0:.0f} s)",
                file=sys.stderr,
                flush=True,
            )
    return out


def aggregate(runs: list[dict]) -> dict:
    """``{scenario: {lane: {metric: {"mean", "ci95", "per_seed"}}}}``."""
    per: dict = {}
    for r in runs:
        for lane, m in r.get("results", {}).items():
            per.setdefault(r["scenario"], {}).setdefault(lane, []).append(m)
    out: dict = {}
    for scen, lanes in per.items():
        out[scen] = {}
        for lane, ms in lanes.items():
            row = {}
            for k in METRICS:
                mean, ci = t_ci([m.get(k) for m in ms])
                row[k] = {"mean": mean, "ci95": ci, "per_seed": [m.get(k) for m in ms]}
            out[scen][lane] = row
    return out


def choose(table: dict, lanes: list[str]) -> list[tuple]:
    """``(regret, total > 10 %, -mean true valid, lane)`` sorted: the rule (module docstring)."""
    best = {g: min(table[g][lane]["saturated_frames_50"]["mean"] for lane in lanes) for g in table}
    rows = []
    for lane in lanes:
        regret = sum(table[g][lane]["saturated_frames_50"]["mean"] - best[g] for g in table)
        s10 = sum(table[g][lane]["saturated_frames_10"]["mean"] for g in table)
        tv = float(np.nanmean([table[g][lane]["true_valid_fraction_mean"]["mean"] for g in table]))
        rows.append((round(regret, 9), round(s10, 9), -tv, lane))
    return sorted(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="training seeds per preset (0..N-1)")
    ap.add_argument("--controllers", default="nec,navid,shim,begin", help="controllers to tune")
    ap.add_argument("--scenarios", default=",".join(PRESETS + TRAINING_FILES))
    ap.add_argument("--duration", type=float, default=None, help="simulated seconds per run (default: the preset's)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", default=str(HERE / "results" / "tuning.json"))
    ap.add_argument("--tuned", default=str(ROOT / "necviz" / "tuned.json"), help="where the choice goes")
    args = ap.parse_args()

    allv = variants()
    ctrls = [c for c in args.controllers.split(",") if c]
    bad = [c for c in ctrls if c not in allv]
    if bad:
        print(f"necviz: error: no variants for {', '.join(bad)}; tunable: {', '.join(allv)}", file=sys.stderr)
        return 2
    for c in ctrls:
        assert len(allv[c]) == VARIANTS and PUBLISHED[c] in allv[c], c
    scenarios = [s for s in args.scenarios.split(",") if s]
    lanes, params, index = [], {}, {}
    for c in ctrls:
        for i, (label, p) in enumerate(allv[c].items()):
            lane = f"{c}@v{i:02d}"
            lanes.append(lane)
            params[lane] = p
            index[lane] = (c, label)
    specs = [
        {
            "scenario": s,
            "seed": k,
            "duration_s": args.duration,
            "scenario_params": {"change_jitter_ms": CHANGE_JITTER_MS},
            "controllers": lanes,
            "controller_params": params,
            "sift": False,
        }
        for s in scenarios
        for k in range(args.seeds)
    ]
    print(
        f"{len(specs)} training runs ({len(scenarios)} scenes x {args.seeds} seeds), {len(lanes)} lanes each "
        f"({VARIANTS} variants x {len(ctrls)} controllers), {args.jobs} processes",
        file=sys.stderr,
    )
    t0 = time.perf_counter()
    runs = run_all(specs, args.jobs)
    errors = [r for r in runs if "error" in r]
    for r in errors:
        print(f"FAILED {r['scenario']} seed {r['seed']}: {r['error']}", file=sys.stderr)
    table = aggregate([r for r in runs if "results" in r])

    chosen, report = {}, {}
    for c in ctrls:  # lanes are KIND@vNN: a label may hold characters a lane name may not
        mine = [ln for ln in lanes if index[ln][0] == c]
        ranking = choose(table, mine)
        best = ranking[0][3]
        pub = next(ln for ln in mine if index[ln][1] == PUBLISHED[c])
        print(f"\n## {c}: {VARIANTS} variants, chosen by least regret at > 50 % (then > 10 %, then true valid)")
        print(
            f"{'variant':40s} " + " ".join(f"{Path(s).stem[:13]:>13s}" for s in scenarios) + "  regret  >10% sum  valid"
        )
        for regret, s10, ntv, ln in ranking:
            cells = " ".join(f"{table[s][ln]['saturated_frames_50']['mean']:13.1f}" for s in scenarios)
            mark = " *" if ln == best else (" (published)" if ln == pub else "")
            print(f"{index[ln][1]:40s} {cells}  {regret:6.2f}  {s10:8.1f}  {-ntv:.3f}{mark}")
        chosen[c] = {
            "label": index[best][1],
            "params": params[best],
            "published_label": PUBLISHED[c],
            "published_params": params[pub],
            "regret": ranking[0][0],
            "published_regret": next(r[0] for r in ranking if r[3] == pub),
        }
        report[c] = {
            "ranking": [[r[0], r[1], -r[2], index[r[3]][1]] for r in ranking],
            "variants": {index[ln][1]: params[ln] for ln in mine},
        }
    command = "python benchmarks/tuning.py " + " ".join(sys.argv[1:])
    training = {
        "scenarios": scenarios,
        "seeds": list(range(args.seeds)),
        "duration_s": args.duration,
        "scenario_params": {"change_jitter_ms": CHANGE_JITTER_MS},
    }
    rule = (
        "least total regret at > 50 % saturated frames over the training presets (regret: a variant's mean minus "
        "the best of the same controller's variants), ties by total > 10 %, then by mean true valid fraction"
    )
    # one run may tune some controllers: the results of the others (an earlier run) are kept beside them
    json_path = Path(args.json)
    prev = json.loads(json_path.read_text(encoding="utf-8")) if json_path.is_file() else {}
    runs_by_ctrl = {c: {"command": command, "training": training, "seconds": time.perf_counter() - t0} for c in ctrls}
    table_out = {f"{c}:{label}": {} for c in ctrls for label in allv[c]}
    for s, lanes_ in table.items():
        for ln, row in lanes_.items():
            table_out[f"{index[ln][0]}:{index[ln][1]}"][s] = row
    keep = lambda d: {k: v for k, v in (d or {}).items() if k.split(":", 1)[0] not in ctrls}  # noqa: E731
    result = {
        "rule": rule,
        "variants_per_controller": VARIANTS,
        "runs": {**(prev.get("runs") or {}), **runs_by_ctrl},
        "controllers": {**(prev.get("controllers") or {}), **report},
        "chosen": {**(prev.get("chosen") or {}), **chosen},
        "not_tuned": NOT_TUNED,
        "table": {**keep(prev.get("table")), **table_out},
        "errors": [f"{r['scenario']} seed {r['seed']}: {r['error']}" for r in errors],
    }
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(result, indent=1, default=float), encoding="utf-8")
    if errors:
        print(f"\n{len(errors)} runs failed: {args.tuned} left unchanged", file=sys.stderr)
        return 1
    tuned_path = Path(args.tuned)
    old = json.loads(tuned_path.read_text(encoding="utf-8")) if tuned_path.is_file() else {}
    tuned = {
        "command": command,
        "training": training,
        "rule": rule,
        "variants_per_controller": VARIANTS,
        "results": "benchmarks/results/tuning.json",
        "controllers": {
            **old.get("controllers", {}),
            **{
                c: {**{k: v for k, v in chosen[c].items() if k != "published_params"}, "command": command}
                for c in ctrls
            },
        },
        "not_tuned": NOT_TUNED,
    }
    tuned_path.write_text(json.dumps(tuned, indent=1) + "\n", encoding="utf-8")
    print(f"\nwrote {args.json} and {tuned_path} ({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
