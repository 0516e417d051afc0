"""NEC's flicker rule (necviz.core.control.flicker_watch): a flickering bus is not a one-way loss.

The closed-loop checks run on a TRAINING scene (benchmarks/training/flicker_pwm_120.toml: 120 Hz PWM,
depth 0.95), never on a held-out one."""

from __future__ import annotations

from pathlib import Path

import pytest

from necviz.core.control.flicker_watch import FlickerWatch
from necviz.core.errors import ParameterError
from necviz.runs import run_spec

ROOT = Path(__file__).resolve().parents[1]
PWM_120 = str(ROOT / "benchmarks" / "training" / "flicker_pwm_120.toml")


def test_alternating_windows_are_flicker_after_two_reversals():
    w = FlickerWatch(horizon_us=20_000, min_reversals=2, max_run_us=10_000)
    # 100 Hz: ON windows for 2 ms, OFF 5 ms later, ...
    seen = [w.observe(t, d) for t, d in ((0, 1), (1000, 1), (5000, -1), (6000, -1), (10_000, 1), (15_000, -1))]
    assert seen == [False, False, False, False, True, True]
    assert w.active(16_000) and not w.active(15_000 + 20_001)
    assert w.flicker_windows == 2


def test_one_way_run_is_never_flicker():
    w = FlickerWatch()
    assert not any(w.observe(t, 1) for t in range(0, 100_000, 500))
    assert w.flicker_windows == 0 and not w.active(100_000)


def test_a_long_run_amid_flicker_is_a_one_way_change():
    w = FlickerWatch(horizon_us=20_000, min_reversals=2, max_run_us=10_000)
    for t, d in ((0, 1), (5000, -1), (10_000, 1), (15_000, -1)):
        w.observe(t, d)
    assert w.observe(20_000, 1)  # the next swing
    # the light goes up and stays up: the bus stays at its ceiling ON for longer than max_run
    run = [w.observe(t, 1) for t in range(20_500, 40_000, 500)]
    assert run[0] and not run[-1]
    assert not w.active(40_000)


def test_stale_windows_start_afresh():
    w = FlickerWatch(horizon_us=20_000, min_reversals=2)
    w.observe(0, 1)
    w.observe(5000, -1)
    assert not w.observe(100_000, 1)  # 95 ms later: not a reversal within the horizon
    assert not w.observe(105_000, -1)


def test_bad_settings_are_refused():
    with pytest.raises(ParameterError):
        FlickerWatch(horizon_us=0)


def _run(scenario, **extra):
    spec = {
        "scenario": scenario,
        "seed": 0,
        "scenario_params": {"change_jitter_ms": 10.0},
        "controllers": ["nec", "nec@norule", "nec-frames"],
        "controller_params": {"nec@norule": {"flicker_rule": False}},
        **extra,
    }
    return run_spec(spec)["results"]


@pytest.mark.slow
def test_deep_flicker_nec_clips_no_more_than_without_events():
    """120 Hz PWM at depth 0.95 (training): without the rule NEC clips far more frames over 10 % than
    nec-frames (the escape rule fires every half-period); with it, no more than nec-frames."""
    r = _run(PWM_120, duration_s=0.6)
    nec, norule, frames = (r[k]["saturated_frames_10"] for k in ("nec", "nec@norule", "nec-frames"))
    assert norule > frames + 5  # the failure the rule removes is there
    assert nec <= frames


@pytest.mark.slow
def test_one_way_change_reacts_as_before():
    """A tunnel exit without flickering lamps (the bus at its ceiling one way): NEC with the rule is
    frame for frame NEC without it (same lane name: the simulated camera's noise is drawn per lane)."""
    traces = []
    for rule in (True, False):
        spec = {
            "scenario": "tunnel_exit",
            "seed": 0,
            "duration_s": 1.0,
            "scenario_params": {"change_jitter_ms": 10.0},
            "controllers": ["nec"],
            "controller_params": {"nec": {"flicker_rule": rule}},
        }
        traces.append(run_spec(spec)["results"]["nec"]["exposure_trace_us"])
    assert traces[0] == traces[1]
