"""The sealed test sets (issue 30): frozen before they are run, disjoint from everything a choice saw and from each other."""

from __future__ import annotations

import hashlib
import sys
import tomllib
from pathlib import Path

import pytest

from necviz.drivers.sim.scenes import make_scenario

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(BENCH))
from sealed_set import SETS  # noqa: E402


def _seed_range(text: str) -> range:
    lo, _, hi = str(text).partition("..")
    return range(int(lo), int(hi or lo) + 1)


@pytest.mark.parametrize("name", sorted(SETS))
def test_the_sealed_scenes_and_sweep_file_are_unchanged_since_sealing(name):
    ss = SETS[name]
    lines = ss.sums.read_text(encoding="utf-8").splitlines()
    assert len(lines) == 26  # 25 scenes and the sweep file
    for line in lines:
        digest, rel = line.split("  ", 1)
        assert hashlib.sha256((BENCH / rel).read_bytes()).hexdigest() == digest, f"{rel} changed after sealing"


@pytest.mark.parametrize("name", sorted(SETS))
def test_the_sweep_runs_every_sealed_scene_on_unused_seeds_with_independent_phases(name):
    ss = SETS[name]
    spec = tomllib.loads(ss.sweep.read_text(encoding="utf-8"))
    scenes = sorted(Path(s).name for s in spec["scenarios"])
    assert scenes == sorted(p.name for p in ss.directory.glob("*.toml"))
    assert spec["seeds"] == ss.seeds and len(_seed_range(ss.seeds)) == 10
    assert spec["controllers"] == list(ss.controllers)
    keys = []
    for p in ss.directory.glob("*.toml"):
        params = tomllib.loads(p.read_text(encoding="utf-8"))["params"]
        assert params["change_jitter_ms"] == 10.0  # uniform over the 20 ms frame interval
        keys.append(params["phase_key"])
    assert len(set(keys)) == len(keys) and 0 not in keys
    # no other sweep file (another sealed set's included) names this set's scenes or any of its seeds
    mine = set(_seed_range(ss.seeds))
    for other in (BENCH / "sweeps").glob("*.toml"):
        if other == ss.sweep:
            continue
        text = other.read_text(encoding="utf-8")
        assert f"../{ss.name}/" not in text, other.name
        seeds = tomllib.loads(text).get("seeds", "")
        if str(seeds).partition("..")[0].isdigit():
            assert not mine & set(_seed_range(seeds)), other.name


def test_no_two_sealed_sets_share_a_generator_a_scene_seed_or_a_phase_stream():
    generators = [ss.generator for ss in SETS.values()]
    assert len(set(generators)) == len(generators) and 20240601 not in generators  # the validation set's
    keys = [
        tomllib.loads(p.read_text(encoding="utf-8"))["params"]["phase_key"]
        for ss in SETS.values()
        for p in ss.directory.glob("*.toml")
    ]
    assert len(keys) == 25 * len(SETS) and len(set(keys)) == len(keys)


def test_a_phase_key_gives_a_scene_its_own_change_phases_for_the_same_seed():
    base = {"change_jitter_ms": 10.0, "markers": False}
    a = make_scenario("flicker", seed=300, **base).t_us
    assert make_scenario("flicker", seed=300, phase_key=0, **base).t_us == a  # 0: the seed alone, as before
    b = make_scenario("flicker", seed=300, phase_key=5200, **base).t_us
    c = make_scenario("flicker", seed=300, phase_key=5201, **base).t_us
    assert len({tuple(a), tuple(b), tuple(c)}) == 3
    assert make_scenario("flicker", seed=300, phase_key=5200, **base).t_us == b  # reproducible
