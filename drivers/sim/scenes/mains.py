"""Mains-powered lamps: the light's modulation at twice the mains frequency, sinusoidal or PWM-like.

A lamp on alternating current flickers at twice the mains frequency (100 Hz on 50 Hz mains, 120 Hz on
60 Hz): an incandescent or fluorescent lamp roughly sinusoidally, a cheap LED driver often as a
pulse train at full depth (the light is on for a fraction ``duty`` of each period). Both are written
as a factor on the lamp's mean-free output ``1 + depth s(t)`` with ``s`` in ``[-1, 1]``: ``depth`` is
the modulation depth ``(max - min) / (max + min)``, so ``depth = 0.95`` is a 39:1 swing (3.7 ln).

* ``duty = 0``: ``s = cos(2 pi f t)``.
* ``0 < duty < 1``: a pulse train, ``s = +1`` for a fraction ``duty`` of each period and ``-1`` for the
  rest, with smoothstep edges of :data:`PWM_EDGE` of a period (at most half the shorter phase) so the
  log rate stays bounded (the simulator's adaptive sampling needs a bound).
"""

from __future__ import annotations

import math

#: rise and fall of a PWM lamp's pulse, as a fraction of the period (0.5 ms at 100 Hz)
PWM_EDGE = 0.05


def _smooth(x: float) -> float:
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


def pwm_edge(duty: float) -> float:
    """The edge width (fraction of a period) of a pulse train of this duty cycle."""
    return min(PWM_EDGE, 0.5 * duty, 0.5 * (1.0 - duty))


def modulation(t_us: float, hz: float, duty: float) -> float:
    """``s(t)`` in ``[-1, 1]`` (module docstring) at ``t_us``; O(1)."""
    phase = (t_us * 1e-6 * hz) % 1.0
    if duty <= 0.0:
        return math.cos(2.0 * math.pi * phase)
    e = pwm_edge(duty)
    if phase < e:  # rising into the pulse
        return -1.0 + 2.0 * _smooth(phase / e)
    if phase < duty:
        return 1.0
    if phase < duty + e:  # falling
        return 1.0 - 2.0 * _smooth((phase - duty) / e)
    return -1.0


def max_log_rate(hz: float, depth: float, duty: float) -> float:
    """An upper bound of ``|d ln(1 + depth s) / dt|`` per µs (for :meth:`Scene.max_log_rate`)."""
    if depth <= 0.0:
        return 0.0
    if duty <= 0.0:
        return depth * 2.0 * math.pi * hz * 1e-6 / (1.0 - depth)
    # on an edge s = -1 + 2 S(x), S the smoothstep over x in [0, 1] in e = pwm_edge / hz seconds:
    # |d ln(1 + depth s)/dt| = depth 2 S'(x) / (e (1 + depth s)), maximised over x on a fine grid (+5 %)
    edge_us = pwm_edge(duty) / hz * 1e6
    peak = max(
        depth * 12.0 * x * (1.0 - x) / (1.0 + depth * (-1.0 + 2.0 * x * x * (3.0 - 2.0 * x)))
        for x in (i / 1000.0 for i in range(1001))
    )
    return 1.05 * peak / edge_us
