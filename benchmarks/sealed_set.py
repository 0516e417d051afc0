#!/usr/bin/env python
"""Draw a sealed test set (issue 30): new scenes, independent change phases, ten test seeds — written once, never run here.

The validation set (``benchmarks/heldout/*.toml``, seeds 100..109) had been run and ranked for every NEC
variant while the method was designed, so it validates; it cannot seal. This script draws a new set the
same way (``benchmarks/metering.py``'s :func:`heldout_params`: every parameter uniform in the preset's
documented range, narrowed to what the simulated DAVIS346 can expose) with a generator seed nobody has
used (:class:`SealedSet`; the validation set's is 20240601), and adds what the validation set lacked:

* **mains flicker as indoors**: every ``flicker`` scene's lamp at 100 or 120 Hz (50 / 60 Hz mains), depth
  uniform in [0, 0.95], half of them a PWM pulse train (``duty`` uniform in [0.1, 0.9]); half of the
  ``tunnel_exit`` scenes lit by flickering lamps (depth in [0.3, 0.95], 100 or 120 Hz, sine or PWM);
* **independent phases**: ``change_jitter_ms = 10`` (half the 20 ms frame interval: each lighting change
  uniform over the frame interval) and a ``phase_key`` per scene (its scene seed), so the scenes of a
  family draw their phases independently for the same run seed (with the validation set's key 0 every
  scene of a family met the frame clock at the same phase for a seed).

A set, once run and read, is spent: what is designed after it is tested on a new one. :data:`SETS` holds
every set drawn (``sealed``: generator 20261202, seeds 300..309, run 2026-12-03; ``sealed2``: generator
20261203, seeds 400..409). For the chosen set it writes ``benchmarks/NAME/*.toml`` (:data:`PER_PRESET` per
preset; an existing file is never replaced), the sweep file ``benchmarks/sweeps/NAME.toml`` and
``benchmarks/NAME/SHA256SUMS`` (the scenes and the sweep file; ``tests/test_sealed_set.py`` checks every
set, so an edit after sealing fails the suite). How a set is run once and committed: docs/evaluation.md,
"The sealed test sets".

usage: python benchmarks/sealed_set.py [--set NAME] [--check]
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from metering import PRESETS, heldout_params, toml_value  # noqa: E402

#: the validation set's generator seed and scene seeds (1000..1403), training's (2001..2004, pwm_bright 01..12),
#: and the training (0..4) and validation (100..109) run seeds: no sealed set may reuse any of them
JITTER_MS = 10.0  # uniform over the frame interval: ± half the simulated camera's 20 ms frame interval
PER_PRESET = 5


@dataclass(frozen=True)
class SealedSet:
    """One sealed test set: where its files live and what was drawn for it (fixed before its run)."""

    name: str  #: its directory under benchmarks/ and its sweep file benchmarks/sweeps/NAME.toml
    generator: int  #: the generator seed of its draws, never used for anything else
    scene_seed0: int  #: scene seeds: scene_seed0 + 100 * preset index + k
    seeds: str  #: the test seeds, never run by anyone before
    controllers: tuple[str, ...]
    why: str  #: what the set is for, written into its sweep file's header

    @property
    def directory(self) -> Path:
        return HERE / self.name

    @property
    def sweep(self) -> Path:
        return HERE / "sweeps" / f"{self.name}.toml"

    @property
    def sums(self) -> Path:
        return self.directory / "SHA256SUMS"


SETS = {
    s.name: s
    for s in (
        SealedSet(
            "sealed",
            20261202,
            5000,
            "300..309",
            ("nec", "nec-frames", "nec-paper", "navid-tuned", "shim-tuned", "begin-tuned"),
            "the evaluation of issue 30",
        ),
        SealedSet(
            "sealed2",
            20261203,
            6000,
            "400..409",
            ("nec", "nec-frames", "navid-tuned", "shim-tuned", "begin-tuned"),
            "the second sealed set of issue 30: the first (benchmarks/sealed, seeds 300..309) was run and read, and the "
            "flicker-edges rule and the re-tuned baselines came after it, designed on training scenes; this set tests "
            "the code that ships now. nec-paper was measured on the first set and is no criterion: left out for time",
        ),
    )
}
#: the set drawn last: the one the results page and the README judge
CURRENT = "sealed2"


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


def scene_paths(ss: SealedSet) -> list[Path]:
    return [
        ss.directory / f"{name}_{ss.scene_seed0 + 100 * i + k}.toml"
        for i, name in enumerate(PRESETS)
        for k in range(PER_PRESET)
    ]


def write_scenes(ss: SealedSet) -> list[Path]:
    ss.directory.mkdir(exist_ok=True)
    paths = scene_paths(ss)
    for path in paths:
        if path.exists():
            continue
        name = path.stem.rsplit("_", 1)[0]
        seed = int(path.stem.rsplit("_", 1)[1])
        params = sealed_params(name, np.random.default_rng([seed, ss.generator]), seed)
        lines = [
            f"# SEALED test scene (issue 30; benchmarks/sealed_set.py, generator {ss.generator}): {name}, parameters drawn",
            f"# by heldout_params with the sealed set's additions. Run once, by benchmarks/sweeps/{ss.name}.toml; never tuned on.",
            f'name = "{name}"',
            f"seed = {seed}",
            "",
            "[params]",
        ]
        lines += [f"{k} = {toml_value(v)}" for k, v in params.items()]
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return paths


def write_sweep(ss: SealedSet, paths: list[Path]) -> None:
    if ss.sweep.exists():
        return
    order = [p for k in range(PER_PRESET) for p in paths[k::PER_PRESET]]  # one scene of each family in turn
    runs = len(paths) * 10 * len(ss.controllers)
    why = textwrap.fill(ss.why, 110, initial_indent="# ", subsequent_indent="# ")
    text = f'''# SEALED TEST, run ONCE on the code that ships (docs/evaluation.md, "The sealed test sets"). What it is for:
{why}
# Scenes: benchmarks/{ss.name}/*.toml ({len(paths)} scenes, {PER_PRESET} per preset, drawn by benchmarks/sealed_set.py --set {ss.name}
# with generator {ss.generator}; every change uniform over the frame interval, each scene its own phase stream).
# Seeds {ss.seeds}: never run. Nothing here took part in any choice. Do not run it for development: use the training
# scenes or the validation set. SHA256SUMS in benchmarks/{ss.name}/ seals this file and the scenes.
#   necviz sweep run benchmarks/sweeps/{ss.name}.toml --out out/{ss.name} --workers 2 --dashboard off
#   python benchmarks/events_table.py out/{ss.name} --metric saturated_frames_50 --metric saturated_frames_10 \\
#       --metric true_valid_fraction_mean --metric marker_detection_rate \\
#       --rows benchmarks/results/{ss.name}_rows.csv --json benchmarks/results/{ss.name}.json
# {runs} runs: about {runs * 4.5 / 3600:.1f} h on 2 free workers (the first sealed set's 1,500 took 1 h 52 min).
name = "sealed test set {ss.name} (issue 30): NEC, NEC without events, the tuned baselines"
seeds = "{ss.seeds}"
sift = false
markers = true
metrics = ["saturated_frames_50", "saturated_frames_10", "recovery_ms", "true_valid_fraction_mean",
           "mean_over_exposed_rate", "mean_under_exposed_rate", "marker_detection_rate", "marker_latency_ms",
           "marker_missed", "marker_corner_error_px"]
controllers = [{", ".join(f'"{c}"' for c in ss.controllers)}]
scenarios = [  # one scene of each family in turn: an interrupted run still covers every family
{chr(10).join(f'    "../{ss.name}/{p.name}",' for p in order)}
]
'''
    ss.sweep.write_text(text, encoding="utf-8")


def sums(ss: SealedSet, paths: list[Path]) -> str:
    files = [*paths, ss.sweep]
    return "".join(f"{hashlib.sha256(f.read_bytes()).hexdigest()}  {f.relative_to(HERE).as_posix()}\n" for f in files)


def intact(ss: SealedSet) -> bool:
    """True when the set's scenes and sweep file are byte for byte what its SHA256SUMS sealed."""
    paths = scene_paths(ss)
    if not ss.sums.is_file() or not ss.sweep.is_file() or not all(p.is_file() for p in paths):
        return False
    return ss.sums.read_text(encoding="utf-8") == sums(ss, paths)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", default=CURRENT, choices=sorted(SETS), help="which sealed set (default: %(default)s)")
    ap.add_argument("--check", action="store_true", help="only check every set's files against its SHA256SUMS")
    args = ap.parse_args()
    if args.check:
        bad = [name for name, ss in SETS.items() if not intact(ss)]
        for name in SETS:
            print(f"{name}: " + ("CHANGED since it was sealed (or never sealed)" if name in bad else "intact"))
        return 1 if bad else 0
    ss = SETS[args.set]
    paths = write_scenes(ss)
    write_sweep(ss, paths)
    if ss.sums.exists():
        print(f"{ss.sums} exists: kept (the set is sealed); --check compares", file=sys.stderr)
    else:
        ss.sums.write_text(sums(ss, paths), encoding="utf-8")
    print(f"{len(paths)} scenes in {ss.directory}, {ss.sweep}, {ss.sums}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
