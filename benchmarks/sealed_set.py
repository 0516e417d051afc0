#!/usr/bin/env python
"""Draw the sealed test set (issue 30): new scenes, independent change phases, ten test seeds — written once, never run here.

The validation set (``benchmarks/heldout/*.toml``, seeds 100..109) had been run and ranked for every NEC
variant while the method was designed, so it validates; it cannot seal. This script draws a new set the
same way (``benchmarks/metering.py``'s :func:`heldout_params`: every parameter uniform in the preset's
documented range, narrowed to what the simulated DAVIS346 can expose) with a generator seed nobody has
used (:data:`GENERATOR`; the validation set's is 20240601), and adds what the validation set lacked:

* **mains flicker as indoors**: every ``flicker`` scene's lamp at 100 or 120 Hz (50 / 60 Hz mains), depth
  uniform in [0, 0.95], half of them a PWM pulse train (``duty`` uniform in [0.1, 0.9]); half of the
  ``tunnel_exit`` scenes lit by flickering lamps (depth in [0.3, 0.95], 100 or 120 Hz, sine or PWM);
* **independent phases**: ``change_jitter_ms = 10`` (half the 20 ms frame interval: each lighting change
  uniform over the frame interval) and a ``phase_key`` per scene (its scene seed), so the scenes of a
  family draw their phases independently for the same run seed (with the validation set's key 0 every
  scene of a family met the frame clock at the same phase for a seed).

It writes ``benchmarks/sealed/*.toml`` (:data:`PER_PRESET` per preset; an existing file is never
replaced), the sweep file ``benchmarks/sweeps/sealed.toml`` (test seeds :data:`SEEDS`) and
``benchmarks/sealed/SHA256SUMS`` (the scenes and the sweep file; ``tests/test_sealed_set.py`` checks them,
so an edit after sealing fails the suite). How it is run once and committed: docs/evaluation.md,
"The sealed test set".

usage: python benchmarks/sealed_set.py [--check]
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from metering import PRESETS, heldout_params, toml_value  # noqa: E402

#: the generator seed of the draws: never used before (the validation set's is 20240601)
GENERATOR = 20261202
#: scene seeds: 5000 + 100 * preset index + k (the validation set's are 1000..1403, training's 2001..2004)
SCENE_SEED0 = 5000
PER_PRESET = 5
#: the test seeds: never run by anyone (training 0..4, validation 100..109)
SEEDS = "300..309"
#: uniform over the frame interval: ± half the simulated camera's 20 ms frame interval
JITTER_MS = 10.0
DIRECTORY = HERE / "sealed"
SWEEP = HERE / "sweeps" / "sealed.toml"
SUMS = DIRECTORY / "SHA256SUMS"
CONTROLLERS = ["nec", "nec-frames", "nec-paper", "navid-tuned", "shim-tuned", "begin-tuned"]


def sealed_params(name: str, rng: np.random.Generator, scene_seed: int) -> dict:
    """:func:`heldout_params` with the sealed set's additions (module docstring)."""
    p = heldout_params(name, rng)
    p["change_jitter_ms"] = JITTER_MS
    p["phase_key"] = scene_seed
    u = lambda lo, hi: round(float(rng.uniform(lo, hi)), 3)  # noqa: E731
    if name == "flicker":
        p["mains_hz"] = float(rng.choice([100.0, 120.0]))
        p["depth"] = u(0.0, 0.95)
        p["duty"] = u(0.1, 0.9) if rng.random() < 0.5 else 0.0
    elif name == "tunnel_exit" and rng.random() < 0.5:
        p["lamp_hz"] = float(rng.choice([100.0, 120.0]))
        p["lamp_depth"] = u(0.3, 0.95)
        p["lamp_duty"] = u(0.1, 0.9) if rng.random() < 0.5 else 0.0
    return p


def scene_paths() -> list[Path]:
    return [
        DIRECTORY / f"{name}_{SCENE_SEED0 + 100 * i + k}.toml"
        for i, name in enumerate(PRESETS)
        for k in range(PER_PRESET)
    ]


def write_scenes() -> list[Path]:
    DIRECTORY.mkdir(exist_ok=True)
    paths = scene_paths()
    for path in paths:
        if path.exists():
            continue
        name = path.stem.rsplit("_", 1)[0]
        seed = int(path.stem.rsplit("_", 1)[1])
        params = sealed_params(name, np.random.default_rng([seed, GENERATOR]), seed)
        lines = [
            f"# SEALED test scene (issue 30; benchmarks/sealed_set.py, generator {GENERATOR}): {name}, parameters drawn",
            "# by heldout_params with the sealed set's additions. Run once, by benchmarks/sweeps/sealed.toml; never tuned on.",
            f'name = "{name}"',
            f"seed = {seed}",
            "",
            "[params]",
        ]
        lines += [f"{k} = {toml_value(v)}" for k, v in params.items()]
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return paths


def write_sweep(paths: list[Path]) -> None:
    if SWEEP.exists():
        return
    order = [p for k in range(PER_PRESET) for p in paths[k::PER_PRESET]]  # one scene of each family in turn
    runs = len(paths) * 10 * len(CONTROLLERS)
    text = f'''# SEALED TEST: the evaluation of issue 30, run ONCE on the code that ships (docs/evaluation.md, "The sealed test set").
# Scenes: benchmarks/sealed/*.toml ({len(paths)} scenes, {PER_PRESET} per preset, drawn by benchmarks/sealed_set.py with generator
# {GENERATOR}; every change uniform over the frame interval, each scene its own phase stream). Seeds {SEEDS}: never run.
# Nothing here took part in any choice. Do not run it for development: use the training scenes (benchmarks/training,
# the presets) or the validation set (heldout.toml). SHA256SUMS in benchmarks/sealed/ seals this file and the scenes.
#   necviz sweep plan benchmarks/sweeps/sealed.toml
#   necviz sweep run benchmarks/sweeps/sealed.toml --out out/sealed --workers 2
#   python benchmarks/events_table.py out/sealed --metric saturated_frames_50 --metric saturated_frames_10 \\
#       --metric true_valid_fraction_mean --metric marker_detection_rate --rows benchmarks/results/sealed_rows.csv
# {runs} runs: about 1.5-2.5 h on 2 free workers (the validation set's 900 runs took about 1 h 15 min at 5 seeds).
name = "sealed test set (issue 30): NEC, NEC without events, the paper's controller, the tuned baselines"
seeds = "{SEEDS}"
sift = false
markers = true
metrics = ["saturated_frames_50", "saturated_frames_10", "recovery_ms", "true_valid_fraction_mean",
           "mean_over_exposed_rate", "mean_under_exposed_rate", "marker_detection_rate", "marker_latency_ms",
           "marker_missed", "marker_corner_error_px"]
controllers = [{", ".join(f'"{c}"' for c in CONTROLLERS)}]
scenarios = [  # one scene of each family in turn: an interrupted run still covers every family
{chr(10).join(f'    "../sealed/{p.name}",' for p in order)}
]
'''
    SWEEP.write_text(text, encoding="utf-8")


def sums(paths: list[Path]) -> str:
    files = [*paths, SWEEP]
    return "".join(f"{hashlib.sha256(f.read_bytes()).hexdigest()}  {f.relative_to(HERE).as_posix()}\n" for f in files)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only check the files against SHA256SUMS")
    args = ap.parse_args()
    if args.check:
        ok = SUMS.is_file() and SUMS.read_text(encoding="utf-8") == sums(scene_paths())
        print("sealed set intact" if ok else "sealed set CHANGED since it was sealed (or never sealed)")
        return 0 if ok else 1
    paths = write_scenes()
    write_sweep(paths)
    if SUMS.exists():
        print(f"{SUMS} exists: kept (the set is sealed); --check compares", file=sys.stderr)
    else:
        SUMS.write_text(sums(paths), encoding="utf-8")
    print(f"{len(paths)} scenes in {DIRECTORY}, {SWEEP}, {SUMS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
