"""The sealed test set (issue 30): frozen before it is run, disjoint from everything a choice saw."""

from __future__ import annotations

import hashlib
import tomllib
from pathlib import Path

from necviz.drivers.sim.scenes import make_scenario

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
SEALED = BENCH / "sealed"


def test_the_sealed_scenes_and_sweep_file_are_unchanged_since_sealing():
    lines = (SEALED / "SHA256SUMS").read_text(encoding="utf-8").splitlines()
    assert len(lines) == 26  # 25 scenes and the sweep file
    for line in lines:
        digest, rel = line.split("  ", 1)
        assert hashlib.sha256((BENCH / rel).read_bytes()).hexdigest() == digest, f"{rel} changed after sealing"


def test_the_sweep_runs_every_sealed_scene_on_unused_seeds_with_independent_phases():
    spec = tomllib.loads((BENCH / "sweeps" / "sealed.toml").read_text(encoding="utf-8"))
    scenes = sorted(Path(s).name for s in spec["scenarios"])
    assert scenes == sorted(p.name for p in SEALED.glob("*.toml"))
    assert spec["seeds"] == "300..309"
    keys = []
    for p in SEALED.glob("*.toml"):
        params = tomllib.loads(p.read_text(encoding="utf-8"))["params"]
        assert params["change_jitter_ms"] == 10.0  # uniform over the 20 ms frame interval
        keys.append(params["phase_key"])
    assert len(set(keys)) == len(keys) and 0 not in keys
    # no other sweep file, and no training or validation scene, uses the sealed scenes or seeds
    for other in (BENCH / "sweeps").glob("*.toml"):
        if other.name == "sealed.toml":
            continue
        text = other.read_text(encoding="utf-8")
        assert "sealed/" not in text, other.name
        seeds = tomllib.loads(text).get("seeds", "")
        lo, _, hi = str(seeds).partition("..")
        if lo.isdigit():
            assert int(hi or lo) < 300 or int(lo) > 309, other.name


def test_a_phase_key_gives_a_scene_its_own_change_phases_for_the_same_seed():
    base = {"change_jitter_ms": 10.0, "markers": False}
    a = make_scenario("flicker", seed=300, **base).t_us
    assert make_scenario("flicker", seed=300, phase_key=0, **base).t_us == a  # 0: the seed alone, as before
    b = make_scenario("flicker", seed=300, phase_key=5200, **base).t_us
    c = make_scenario("flicker", seed=300, phase_key=5201, **base).t_us
    assert len({tuple(a), tuple(b), tuple(c)}) == 3
    assert make_scenario("flicker", seed=300, phase_key=5200, **base).t_us == b  # reproducible
