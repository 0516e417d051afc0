"""Independent replicates: every seed meets the frame clock at its own phase (issue 20, item 4)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from necviz.drivers.sim.aps import ApsParams
from necviz.drivers.sim.scenes import SCENARIOS, make_scenario
from necviz.drivers.sim.scenes.preset import DEFAULT_JITTER_MS
from necviz.drivers.sim.scenes.static_lab import FIRST_START_US

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

PERIOD = ApsParams().frame_interval_us


def change_times(name, seed, **kw):
    return [c.t_us for c in make_scenario(name, seed=seed, **kw).changes]


def test_the_default_jitter_is_half_the_aps_frame_interval():
    assert DEFAULT_JITTER_MS * 1000 == PERIOD / 2 == 10_000
    for cls in SCENARIOS.values():
        assert cls.PARAMS["change_jitter_ms"].default == DEFAULT_JITTER_MS


@pytest.mark.parametrize("name", ["tunnel_exit", "indoor_outdoor", "flicker", "static_lab"])
def test_seeds_draw_different_change_times_and_the_same_seed_the_same(name):
    times = {seed: change_times(name, seed, duration_us=1_000_000) for seed in range(5)}
    assert len({tuple(t) for t in times.values()}) == 5, times
    assert times[3] == change_times(name, 3, duration_us=1_000_000)
    nominal = change_times(name, 0, duration_us=1_000_000, change_jitter_ms=0)
    assert all(change_times(name, s, duration_us=1_000_000, change_jitter_ms=0) == nominal for s in range(3))
    off = np.array([np.subtract(t, nominal) for t in times.values()])
    assert np.abs(off).max() <= PERIOD // 2


def test_handheld_scan_seeds_move_the_shadow_crossings():
    a = make_scenario("handheld_scan", seed=1, duration_us=1_500_000)
    b = make_scenario("handheld_scan", seed=1, duration_us=1_500_000, change_jitter_ms=0)
    assert a.shadow_delay_us != 0 and abs(a.shadow_delay_us) <= PERIOD / 2
    np.testing.assert_array_equal(a.tex, b.tex)  # the facade (and its markers) stay the seed's


@pytest.mark.parametrize("name", ["static_lab", "tunnel_exit"])
def test_the_phase_against_the_frame_clock_is_spread_over_the_frame(name):
    """Over 20 seeds each change's phase against the default frame clock covers the frame interval:
    no gap between neighbouring phases (on the circle) is wider than a quarter of the interval and
    at least 7 of 10 equal bins are hit. Without jitter every seed has the same phase."""
    per_change = np.array([change_times(name, s) for s in range(20)])
    for k in range(per_change.shape[1]):
        phase = np.sort((per_change[:, k] - FIRST_START_US) % PERIOD)
        gaps = np.diff(np.concatenate([phase, [phase[0] + PERIOD]]))
        assert gaps.max() < PERIOD / 4, (k, phase)
        assert np.unique(phase * 10 // PERIOD).size >= 7, (k, phase)
    fixed = np.array([change_times(name, s, change_jitter_ms=0) for s in range(4)])
    assert (fixed == fixed[0]).all()


def test_the_default_jitter_shrinks_where_changes_are_close_and_an_explicit_one_is_refused():
    from necviz.core.errors import ParameterError

    s = make_scenario("flicker", seed=2, switch_times_s=[0.5, 0.512])  # 12 ms apart: +-10 ms could swap them
    t = [c.t_us for c in s.changes]
    assert t[0] < t[1] and s.params["change_jitter_ms"] < 6
    with pytest.raises(ParameterError, match="could reorder"):
        make_scenario("flicker", seed=2, switch_times_s=[0.5, 0.512], change_jitter_ms=10)


def test_compare_json_lists_every_seeds_change_times(tmp_path):
    from necviz.commands.compare import run
    from necviz.options import CompareOptions, SceneOptions

    out = tmp_path / "c.json"
    run(
        CompareOptions(SceneOptions("static_lab", seed=4, duration_s=0.25), ("fixed",), seeds=3, sift=False, json=out),
        out=None,
    )
    data = json.loads(out.read_text())
    per_seed = data["lighting_steps_us_per_seed"]
    want = [change_times("static_lab", 4 + k, duration_us=250_000) for k in range(3)]
    assert per_seed == want and len({tuple(t) for t in per_seed}) == 3
    assert data["lighting_steps_us"] == want[0]
