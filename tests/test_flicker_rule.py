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
#: training: a 7 dB switch ramping over 49 ms under a 120 Hz PWM lamp (depth 0.43), exposures ~0.4-0.8 ms
PWM_RAMP = str(ROOT / "benchmarks" / "training" / "pwm_bright_06.toml")


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


def test_edges_short_bursts_of_one_direction_are_a_lamps_edges():
    """A lamp that reaches the bus ceiling on its falling edge only (120 Hz: every 8.3 ms, one window each):
    the windows never reverse, so without edges every one is a one-way loss; with edges the second and later
    ones are a flicker's swings, and the light counts as flickering."""
    times = [0, 8_333, 16_667, 25_000]
    assert not any(FlickerWatch(edges=False).observe(t, -1) for t in times)
    w = FlickerWatch(edges=True)
    assert [w.observe(t, -1) for t in times] == [False, True, True, True]
    assert w.active(30_000)


def test_edges_reach_across_periods_the_lamp_missed():
    """A lamp near the ceiling's threshold reaches it on some periods only: short bursts 22 ms apart are
    still edges (within memory_us of the last), 60 ms apart are not."""
    w = FlickerWatch(edges=True, memory_us=40_000)
    assert [w.observe(t, d) for t, d in ((0, -1), (22_000, 1), (44_000, -1))] == [False, True, True]
    w = FlickerWatch(edges=True, memory_us=40_000)
    assert [w.observe(t, -1) for t in (0, 60_000, 120_000)] == [False, False, False]


def test_edges_leave_one_way_losses_alone():
    """A light switched in 1 ms (one short burst), a change that keeps the bus at its ceiling (a burst longer
    than max_edge_us) and the short burst right after a long one stay one-way losses."""
    w = FlickerWatch(edges=True, max_edge_us=1_500)
    assert not any(w.observe(t, 1) for t in (0, 1_000))  # one short burst alone
    w = FlickerWatch(edges=True, max_edge_us=1_500)
    burst = [w.observe(t, -1) for t in range(0, 10_000, 1_000)]  # contiguous for 9 ms
    assert not any(burst)
    assert not w.observe(15_000, -1)  # after a long burst: not an edge
    w = FlickerWatch(edges=True, max_edge_us=1_500)
    assert not any(w.observe(t, -1) for t in (0, 1_000, 2_000))  # a light switched in 2 ms ...
    assert not w.observe(5_000, -1)  # ... and the lamp's swing after it: the switch's loss is not withdrawn
    w = FlickerWatch(edges=True, max_edge_us=1_500)
    w.observe(0, 1)  # a short burst, then a one-way change 10 ms later: its first 1.5 ms pass as an edge
    run = [w.observe(t, 1) for t in range(10_000, 20_000, 1_000)]
    assert run[:2] == [True] * 2 and not any(run[2:])


def test_an_edge_withdraws_the_loss_its_first_burst_started():
    """The first short burst at the ceiling starts the escape rule's case (a); the lamp's next edge shows it
    was a flicker's swing and withdraws it (nec_bus.BusWatch); without edges it stays."""
    from necviz.core.control.nec_bus import BusWatch

    rate = 1e6  # events/s: a 1 ms window of 1,000 OFF events is at the ceiling

    def feed(edges: bool) -> list[int]:
        bus, w, off, seen = BusWatch(), FlickerWatch(edges=edges), 0, []
        bus.watch(0, 0, (0, 0), rate, w)
        t = 0
        for _ in range(3):  # three periods of 8 ms: a 1 ms window at the ceiling, then 7 ms of 100 events
            off += 1_000
            t += 1_000
            bus.watch(1_000, t, (0, off), rate, w)
            seen.append(bus.saturated_dir)
            for _ in range(7):
                off += 100
                t += 1_000
                bus.watch(100, t, (0, off), rate, w)
        return seen

    assert feed(edges=False) == [-1, -1, -1]
    assert feed(edges=True) == [-1, 0, 0]


def test_nec_watches_edges_by_default_and_the_papers_controller_does_not():
    from necviz.core.control import CameraLimits, make_controller
    from necviz.core.sensor import DAVIS346

    assert make_controller("nec", sensor=DAVIS346, limits=CameraLimits()).flicker.edges
    assert not make_controller("nec", sensor=DAVIS346, limits=CameraLimits(), flicker_edges=False).flicker.edges
    assert not make_controller("nec-paper", sensor=DAVIS346, limits=CameraLimits()).flicker.edges


def test_bad_settings_are_refused():
    with pytest.raises(ParameterError):
        FlickerWatch(horizon_us=0)
    with pytest.raises(ParameterError):
        FlickerWatch(max_edge_us=0)


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


@pytest.mark.slow
def test_a_switch_under_a_pwm_lamp_clips_no_more_than_without_events():
    """A 7 dB switch ramping over 49 ms under a 120 Hz PWM lamp (training): the lamp's falling edges ride the
    ramp to the bus ceiling once a period; without edges the escape rule takes them for a loss and the next
    frame is exposed 2-4 times too long (3-4 frames over 10 % per run where nec-frames clips none); with edges
    NEC clips no more than nec-frames."""
    r = _run(
        PWM_RAMP,
        controllers=["nec", "nec@noedges", "nec-frames"],
        controller_params={"nec@noedges": {"flicker_edges": False}},
    )
    nec, noedges, frames = (r[k]["saturated_frames_10"] for k in ("nec", "nec@noedges", "nec-frames"))
    assert noedges >= frames + 2  # the failure edges remove is there
    assert nec <= frames
