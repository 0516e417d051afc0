"""The ``static_lab`` preset: a static lab scene whose lights step between levels (the paper's indoor test)."""

from __future__ import annotations

import math
from itertools import pairwise

import cv2
import numpy as np

from necviz.core.checks import check_number
from necviz.core.errors import ParameterError
from necviz.drivers.sim.aps import ApsParams
from necviz.drivers.sim.scene import LightingChange, db_to_log
from necviz.drivers.sim.scenes.preset import (
    COMMON_PARAMS,
    US,
    Param,
    PresetScene,
    _smoothstep_scalar,
    _structured_texture,
)

__all__ = ["StaticLab", "DEFAULT_STEPS", "between_exposures_us"]

#: Default light steps: (fraction of the duration, level in dB relative to ``base_log``).
DEFAULT_STEPS = ((0.2, 20.0), (0.4, -20.0), (0.6, 40.0), (0.8, 0.0))
#: The simulator's default frame clock: exposures start at ``FIRST_START_US + k FRAME_INTERVAL_US``
#: (``RigOptions.first_start_us``, 1000 and ``ApsParams.frame_interval_us``).
FIRST_START_US = 1_000
FRAME_INTERVAL_US = ApsParams.frame_interval_us
#: Fiducial markers (``markers``): patch centres as fractions of the image, cells of ``MARKER_CELL`` px.
MARKERS = ((0.12, 0.17), (0.38, 0.52), (0.14, 0.80), (0.86, 0.62))
MARKER_CELL = 5


def between_exposures_us(t_us: float) -> float:
    """The first mid-point between two exposure starts of the default frame clock at or after ``t_us``.

    Mid-points lie at ``FIRST_START_US + (k + 1/2) FRAME_INTERVAL_US``, ``k >= 0`` (11 ms, 31 ms, ...).
    """
    k = max(math.ceil((t_us - FIRST_START_US) / FRAME_INTERVAL_US - 0.5), 0)
    return FIRST_START_US + (k + 0.5) * FRAME_INTERVAL_US


class StaticLab(PresetScene):
    """A static lab scene (desk clutter, a checkerboard target, shelves) whose lights step between levels.

    ``ln L(x,t) = base(x) + db_to_log(level_db(t))`` with ``mean(base) = base_log``; ``level_db``
    starts at ``initial_db`` and changes at each ``(time_s, level_db)`` of ``steps`` with a smoothstep
    (in ln) of ``ramp_ms`` (0 = instantaneous). No motion: between steps the image is constant.
    ``changes``: one per step.

    Default steps: +20, -20, +40 and 0 dB at 20, 40, 60 and 80 % of the duration, each delayed to
    the first mid-point between two exposure starts of the simulator's default frame clock
    (:func:`between_exposures_us`: exposures start at 1 ms + k 20 ms), i.e. at 1.011, 2.011, 3.011 and
    4.011 s in the default 5 s. Why: a step at a round time (1.000 s, ramp to 1.001 s) lies within
    the 1 ms command latency (``ApsParams.latency_us``) of the exposure starting at 1.001 s, so no
    command prompted by it can reach that exposure: every controller loses that frame to the
    coincidence of two clocks, not to its own reaction. Half-way between starts a step leaves
    10 ms, less the latency, to command the next exposure, which is the case event-based exposure
    control is meant to win, while a frame-based controller first sees the step in the next frame;
    a step can still fall inside a long exposure, as it would with a real camera. The placement is
    the same for every seed without jitter; ``change_jitter_ms`` moves each to a random phase
    (the default, 10 ms, spreads the phase uniformly over a 20 ms frame; 0 keeps the mid-points).
    Runs too short for the four mid-points to be distinct (under about 0.1 s) keep the plain
    fractions. Steps given in ``steps`` are used at the times given (plus the jitter).

    Markers (``markers``): four ArUco markers (30 px, ids 0-3) on the desk and shelves, static.
    """

    name = "static_lab"
    DEFAULT_DURATION_US = 5_000_000
    PARAMS = {
        "base_log": Param(5.0, -5.0, 15.0, "mean ln L at 0 dB"),
        "initial_db": Param(0.0, -100.0, 100.0, "light level at t = 0, dB relative to base_log"),
        "steps": Param(
            None,
            kind="steps",
            doc="list of (time s, level dB) light steps",
            default_text="+20, -20, +40, 0 dB at 1.011, 2.011, 3.011, 4.011 s (in 5 s: 20/40/60/80 % "
            "of the duration, moved mid-way between exposure starts)",
            range_text="times in [0, duration], levels in [-100, 100]",
        ),
        "ramp_ms": Param(1.0, 0.0, 10000.0, "duration of each light change, ms"),
        **COMMON_PARAMS,
    }

    def _default_steps(self) -> tuple[list, list[float]]:
        """The default steps in s and their times in µs (see the class docstring)."""
        D = self.duration_us
        t_us = [between_exposures_us(f * D) for f, _ in DEFAULT_STEPS]
        if any(b <= a for a, b in pairwise(t_us)) or t_us[-1] > D:
            t_us = [f * D for f, _ in DEFAULT_STEPS]
        return [(t / US, lv) for t, (_, lv) in zip(t_us, DEFAULT_STEPS, strict=True)], t_us

    def _build(self) -> None:
        p, rng, sensor = self.params, self._rng, self.sensor
        H, W = sensor.shape
        steps, default_us = p["steps"], None
        if steps is None:
            steps, default_us = self._default_steps()
        if not isinstance(steps, (list, tuple)):
            raise ParameterError(f"static_lab: steps must be a list of (time_s, level_db) pairs, got {steps!r}")
        clean = []
        for i, st in enumerate(steps):
            if not isinstance(st, (list, tuple)) or len(st) != 2:
                raise ParameterError(f"static_lab: steps[{i}] must be a (time_s, level_db) pair, got {st!r}")
            ts = check_number(f"steps[{i}] time (s, in [0, duration])", st[0], 0.0, self.duration_s, where=self.name)
            lv = check_number(f"steps[{i}] level", st[1], -100.0, 100.0, where=self.name)
            clean.append((ts, lv))
        if any(b[0] <= a[0] for a, b in pairwise(clean)):
            raise ParameterError(f"static_lab: step times must be strictly increasing, got {[s[0] for s in clean]}")
        p["steps"] = clean
        nominal_us = default_us if default_us is not None else [ts * US for ts, _ in clean]
        self.t_us = self._jittered_us("steps", nominal_us)  # applied step times, µs
        tex = _structured_texture(rng, H, W, amp=0.7, density=0.7, size=(5, 60))
        # checkerboard target and shelf lines
        cell = max(4, W // 40)
        cx0, cy0 = int(W * rng.uniform(0.5, 0.65)), int(H * rng.uniform(0.15, 0.3))
        for i in range(7):
            for j in range(5):
                cv2.rectangle(
                    tex,
                    (cx0 + i * cell, cy0 + j * cell),
                    (cx0 + (i + 1) * cell - 1, cy0 + (j + 1) * cell - 1),
                    0.9 if (i + j) % 2 else -0.9,
                    -1,
                )
        for k in range(3):
            y = int(H * (0.55 + 0.12 * k))
            cv2.line(tex, (0, y), (W - 1, y), -0.8, 2)
        self._paint_markers(tex, self._marker_places(MARKERS, MARKER_CELL, W, H), MARKER_CELL)
        vign = -0.3 * (((self._xx - W / 2) / W) ** 2 + ((self._yy - H / 2) / H) ** 2) * 4
        base = tex + vign
        self.base = (base - base.mean() + p["base_log"]).astype(np.float32)
        self.ramp_us = p["ramp_ms"] * 1e3
        self.changes = []
        prev = p["initial_db"]
        for t_us, (_, lv) in zip(self.t_us, clean, strict=True):
            self.changes.append(
                LightingChange(int(round(t_us)), f"lights {prev:+g} -> {lv:+g} dB", db_to_log(lv - prev))
            )
            prev = lv

    def level_db(self, t_us: float) -> float:
        """The light level (dB relative to ``base_log``) at ``t_us``."""
        lv = self.params["initial_db"]
        for t0, (_, new) in zip(self.t_us, self.params["steps"], strict=True):
            if t_us <= t0:
                break
            x = 1.0 if self.ramp_us <= 0 else _smoothstep_scalar((t_us - t0) / self.ramp_us)
            lv = lv + (new - lv) * x
        return lv

    def log_irradiance(self, t_us: float) -> np.ndarray:
        t = self._check_t(t_us)
        return self.base + np.float32(db_to_log(self.level_db(t)))

    def max_log_rate(self, t0_us: float, t1_us: float) -> float | None:
        rate, prev = 0.0, self.params["initial_db"]
        for ts_us, (_, lv) in zip(self.t_us, self.params["steps"], strict=True):
            if t1_us >= ts_us and t0_us <= ts_us + self.ramp_us:
                rate = max(rate, abs(db_to_log(lv - prev)) * 1.5 / max(self.ramp_us, 1.0))
            prev = lv
        return rate
