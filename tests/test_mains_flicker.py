"""Mains-powered lamps in the simulator (drivers/sim/scenes/mains.py): PWM and sine flicker, tunnel lamps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from necviz.drivers.sim.scenes import mains, make_scenario


@pytest.mark.parametrize("duty", [0.3, 0.5])
def test_a_pwm_lamp_is_on_for_its_duty_cycle_at_full_depth(duty):
    hz = 120.0
    t = np.linspace(0.0, 1e6 / hz, 2000, endpoint=False)
    s = np.array([mains.modulation(x, hz, duty) for x in t])
    assert s.max() == 1.0 and s.min() == -1.0
    assert np.mean(s == 1.0) == pytest.approx(duty - mains.PWM_EDGE, abs=0.01)  # flat top, edges excluded
    assert np.mean(s > 0) == pytest.approx(duty, abs=0.01)
    # the log-rate bound holds on the edges (sampled finely)
    depth = 0.95
    ln = np.log1p(depth * s)
    assert np.abs(np.diff(ln) / np.diff(t)).max() <= mains.max_log_rate(hz, depth, duty)


def test_the_flicker_preset_with_a_pwm_lamp_swings_its_pool_by_the_depth():
    s = make_scenario("flicker", seed=1, mains_hz=100.0, depth=0.9, duty=0.5, lamp_db=40.0, markers=False)
    m = s.lamp_mask
    # lamp 40 dB over the ambient: the pool follows the lamp, (1 + 0.9) / (1 - 0.9) = 19 -> ln 2.94
    on = float(s.log_irradiance(2_500.0)[m].mean())  # mid-pulse
    off = float(s.log_irradiance(7_500.0)[m].mean())  # mid-gap
    assert on - off == pytest.approx(math.log(19.0), abs=0.15)
    assert s.max_log_rate(0, 10_000) >= mains.max_log_rate(100.0, 0.9, 0.5)


def test_tunnel_lamps_flicker_inside_and_leave_a_steady_tunnel_unchanged():
    base = dict(seed=2, markers=False, change_jitter_ms=0.0)
    steady = make_scenario("tunnel_exit", **base)
    lit = make_scenario("tunnel_exit", lamp_depth=0.9, lamp_hz=100.0, **base)
    zero = make_scenario("tunnel_exit", lamp_depth=0.0, **base)
    t0 = 0.0
    assert np.array_equal(steady.log_irradiance(t0), zero.log_irradiance(t0))
    # inside the tunnel: the whole image swings by ln((1 + d cos) ...); at t = 0 the cosine is 1, at 5 ms -1
    d = lit.log_irradiance(t0) - steady.log_irradiance(t0)
    assert float(np.median(d)) == pytest.approx(math.log1p(0.9), abs=0.01)
    d5 = lit.log_irradiance(5_000.0) - steady.log_irradiance(5_000.0)
    assert float(np.median(d5)) == pytest.approx(math.log1p(-0.9), abs=0.01)
    # the exit's size is the lamps' mean: the same recorded change as the steady tunnel's
    assert lit.changes[0].delta_log == pytest.approx(steady.changes[0].delta_log)
