#!/usr/bin/env python
"""NEC over DVS contrast thresholds and refractory periods on the training scenes (issue 29, item 5).

Each run is one closed loop of the simulated DAVIS346 with ``nec`` and ``nec-frames`` (NEC without events, the
ablation) as lanes of the same rig, the DVS biases set at scene start as ``--dvs KEY=VALUE`` does
(:mod:`necviz.dvs_controls`: the bias words written to the simulated camera, every lane's P-TEDI following the
thresholds they give). Settings: contrast thresholds ``c_on = c_off`` in {0.15, the default biases (≈ 0.26/0.24),
0.40} × refractory period {the default biases' 100 us, 4× it}. Scenes: the five presets and the deep-flicker
scenes ``benchmarks/training/*.toml``, seeds 0 and 1, every change at a random phase (``change_jitter_ms = 10``):
TRAINING scenes and seeds only, never the held-out or sealed ones.

Per run: the lanes' saturated frames (> 50 % and > 10 % of the pixels), true-valid fraction, P-TEDI's prediction
error (RMSE, ln) and thresholds, and the stream's events (delivered, threshold crossings, lost to the refractory
period and to the 12 Mev/s bus ceiling). Per setting: means over scenes and seeds, and NEC's paired differences
to the default biases (per scene and seed) with their 95 % interval (Student's t over the 18 pairs; scenes differ,
so read the interval as a spread, not a test). ``nec-frames`` does not read events: its column is the floor the
events add to, the same at every setting (the frames do not depend on the DVS biases).

    nice -n 19 python benchmarks/dvs_sweep.py --json benchmarks/results/dvs_sweep.json   # ≈ 108 runs, one worker
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from tuning import CHANGE_JITTER_MS, PRESETS, TRAINING_FILES, t_ci  # noqa: E402

LANES = ("nec", "nec-frames")
METRICS = ("saturated_frames_50", "saturated_frames_10", "true_valid_fraction_mean")
THRESHOLDS = (("0.15", "0.15"), None, ("0.40", "0.40"))  # c_on, c_off (None: the default biases)
REFRACTORY = (None, "400")  # us (None: the default biases' 100 us; 400: 4x)


def settings() -> dict[str, tuple[tuple[str, str], ...]]:
    """Setting label -> its ``--dvs`` controls."""
    out = {}
    for c in THRESHOLDS:
        for r in REFRACTORY:
            dvs: list[tuple[str, str]] = []
            if c is not None:
                dvs += [("c_on", c[0]), ("c_off", c[1])]
            if r is not None:
                dvs.append(("refractory_us", r))
            label = f"c={'default' if c is None else c[0]}, refr={'default' if r is None else r + ' us'}"
            out[label] = tuple(dvs)
    return out


def run(scenario: str, seed: int, dvs, duration_s: float | None) -> dict:
    """One closed loop; the lanes' metrics, P-TEDI's error and thresholds, and the stream's event counts."""
    from necviz.options import SceneOptions
    from necviz.pipeline import Observer
    from necviz.runs import RunOptions, run_once

    seen: dict = {"events": 0, "sim": None}

    class Count(Observer):
        def __init__(self, rig):
            self.rig = rig

        def events(self, batch):
            seen["events"] += len(batch)
            if seen["sim"] is None:
                seen["sim"] = self.rig._dvs_sim  # the running event model (the rig lets go of it at the end)

    stats: dict = {}

    def drive(pipe, label, expected_s):
        stats.update(pipe.run().finish())

    scene = SceneOptions(scenario, seed=seed, duration_s=duration_s, params={"change_jitter_ms": CHANGE_JITTER_MS})
    opts = RunOptions(scene, LANES, sift=False, threads=False, dvs=tuple(dvs))
    t0 = time.perf_counter()
    res = run_once(opts, (lambda rig, lanes: Count(rig),), progress=drive)["results"]
    sim = seen["sim"]
    lanes = {}
    for ln in LANES:
        s = stats["lanes"][ln]
        lanes[ln] = {
            **{k: res[ln][k] for k in METRICS},
            "prediction_error_rmse": s.get("prediction_error_rmse"),
            "ptedi": s.get("ptedi"),
        }
    return {
        "scenario": scenario,
        "seed": seed,
        "lanes": lanes,
        "events": seen["events"],
        "crossings": getattr(sim, "crossings", None),
        "lost_refractory": getattr(sim, "dropped_by_refractory", None),
        "lost_bus_ceiling": getattr(sim, "dropped_by_ceiling", None),
        "seconds": time.perf_counter() - t0,
    }


def summarise(runs: list[dict], labels: list[str], default: str) -> dict:
    """Per setting: means (95 % CI) over scenes and seeds, and NEC's paired difference to the default biases."""
    base = {(r["scenario"], r["seed"]): r for r in runs if r["setting"] == default}
    table = {}
    for lab in labels:
        rs = [r for r in runs if r["setting"] == lab]
        row: dict = {"runs": len(rs)}
        for m in (*METRICS, "prediction_error_rmse"):
            row[m] = {ln: t_ci([r["lanes"][ln][m] for r in rs]) for ln in LANES}
            row[m]["nec - nec-frames"] = (
                t_ci([r["lanes"]["nec"][m] - r["lanes"]["nec-frames"][m] for r in rs]) if m in METRICS else None
            )
            row[m]["nec - nec at default"] = t_ci(
                [r["lanes"]["nec"][m] - base[(r["scenario"], r["seed"])]["lanes"]["nec"][m] for r in rs]
            )
        for k in ("events", "crossings", "lost_refractory", "lost_bus_ceiling"):
            row[k] = t_ci([r[k] for r in rs if r[k] is not None])
        row["events_vs_default"] = t_ci([r["events"] / base[(r["scenario"], r["seed"])]["events"] for r in rs])
        row["ptedi"] = rs[0]["lanes"]["nec"]["ptedi"] if rs else None
        row["per_scene_saturated_frames_10_nec"] = {
            Path(s).stem: sum(r["lanes"]["nec"]["saturated_frames_10"] for r in rs if r["scenario"] == s)
            / max(1, sum(1 for r in rs if r["scenario"] == s))
            for s in dict.fromkeys(r["scenario"] for r in rs)
        }
        row["per_scene_lost_bus_ceiling"] = {
            Path(s).stem: sum(r["lost_bus_ceiling"] or 0 for r in rs if r["scenario"] == s)
            / max(1, sum(1 for r in rs if r["scenario"] == s))
            for s in dict.fromkeys(r["scenario"] for r in rs)
        }
        table[lab] = row
    return table


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=2, help="training seeds 0..N-1 (default 2)")
    ap.add_argument(
        "--scenarios", default=",".join(PRESETS + TRAINING_FILES), help="comma-separated (default: training)"
    )
    ap.add_argument("--duration", type=float, default=None, help="seconds of each scene (default: the scene's own)")
    ap.add_argument("--json", default=None, help="write the results here")
    args = ap.parse_args(argv)
    scenarios = [s for s in args.scenarios.split(",") if s]
    for s in scenarios:
        if "sealed" in s or "heldout" in s:
            raise SystemExit(
                f"dvs_sweep.py: {s} is not a training scene (training presets and benchmarks/training only)"
            )
    sets = settings()
    labels = list(sets)
    default = "c=default, refr=default"
    jobs = [(lab, s, k) for s in scenarios for k in range(args.seeds) for lab in labels]
    runs = []
    t0 = time.perf_counter()
    for i, (lab, s, k) in enumerate(jobs):
        r = {"setting": lab, "dvs": [list(kv) for kv in sets[lab]], **run(s, k, sets[lab], args.duration)}
        runs.append(r)
        print(
            f"  [{i + 1}/{len(jobs)}] {Path(s).stem} seed {k}, {lab}: {r['events']:,} events, "
            f"sat>10% nec {r['lanes']['nec']['saturated_frames_10']} / nec-frames "
            f"{r['lanes']['nec-frames']['saturated_frames_10']}, {r['seconds']:.0f} s "
            f"(elapsed {time.perf_counter() - t0:.0f} s)",
            file=sys.stderr,
            flush=True,
        )
    table = summarise(runs, labels, default)
    print(
        f"\n{'setting':30s} {'P-TEDI c_on/c_off':>18s} {'sat>50% nec / frames':>21s} {'sat>10% nec / frames':>21s}"
        f" {'Δ>10% vs default':>17s} {'true-valid nec / frames':>24s} {'events (M)':>11s} {'bus-lost (M)':>13s}"
    )
    for lab, row in table.items():
        th = row["ptedi"] or {}
        pt = f"{th.get('c_on', float('nan')):.3f}/{th.get('c_off', float('nan')):.3f}"
        f = lambda m, row=row: " / ".join(f"{row[m][ln][0]:.2f}" for ln in LANES)  # noqa: E731
        d = row["saturated_frames_10"]["nec - nec at default"]
        print(
            f"{lab:30s} {pt:>18s} {f('saturated_frames_50'):>21s} {f('saturated_frames_10'):>21s}"
            f" {d[0]:+7.2f} ± {d[1]:<6.2f} {f('true_valid_fraction_mean'):>24s} {row['events'][0] / 1e6:11.2f}"
            f" {row['lost_bus_ceiling'][0] / 1e6:13.3f}"
        )
    if args.json:
        out = {
            "command": "python benchmarks/dvs_sweep.py " + " ".join(argv if argv is not None else sys.argv[1:]),
            "seeds": list(range(args.seeds)),
            "scenarios": scenarios,
            "scenario_params": {"change_jitter_ms": CHANGE_JITTER_MS},
            "lanes": list(LANES),
            "settings": {lab: [list(kv) for kv in v] for lab, v in sets.items()},
            "default": default,
            "table": table,
            "runs": runs,
            "seconds": time.perf_counter() - t0,
            "machine": {"load_average": list(os.getloadavg()), "cpus": os.cpu_count()},
        }
        Path(args.json).write_text(json.dumps(out, indent=1, default=float) + "\n", encoding="utf-8")
        print(f"wrote {args.json} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
