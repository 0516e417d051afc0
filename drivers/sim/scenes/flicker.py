"""The ``flicker`` preset: a room with a lamp flickering at twice the mains frequency and a switched light."""

from __future__ import annotations

import math

import numpy as np

from necviz.drivers.sim.scene import LightingChange, db_to_log
from necviz.drivers.sim.scenes import mains
from necviz.drivers.sim.scenes.preset import (
    COMMON_PARAMS,
    US,
    Param,
    PresetScene,
    _smoothstep_scalar,
    _structured_texture,
)

__all__ = ["Flicker"]

#: Fiducial markers (``markers``): patch centres as fractions of the image (the third one in the
#: lamp's pool of light), cells of ``MARKER_CELL`` px.
MARKERS = ((0.10, 0.15), (0.72, 0.18), (0.33, 0.47), (0.86, 0.72), (0.52, 0.82))
MARKER_CELL = 5


class Flicker(PresetScene):
    """A static room lit by ambient light and a mains-powered lamp, plus a light switched on and off.

    Linear irradiance ``L(x,t) = R(x) [E_a S(t) + E_l w(x) (1 + depth s(t))]``:
    ``R`` a structured reflectance texture, ``w`` the lamp's soft pool of light (a bright lamp
    blob at its top), ``E_l / E_a`` = ``lamp_db``, ``S(t)`` the switched light, 1 when off and
    ``switch_db`` brighter when on, toggled at ``switch_times_s`` (starting off), each switch a
    smoothstep ramp in ln S over ``switch_ms``.

    ``mains_hz`` is the lamp's flicker frequency, twice the mains frequency (100 Hz on 50 Hz mains);
    ``s(t)`` is ``cos(2 pi mains_hz t)``, or with ``duty > 0`` a PWM-like pulse train (an LED driver:
    full output for ``duty`` of each period; :mod:`.mains`).
    ``lamp_mask`` (bool image) marks where the lamp dominates. ``changes``: one per switch time
    (moved by ``change_jitter_ms``; ``times`` holds the switch times in s as applied).

    Markers (``markers``): five ArUco markers (30 px, ids 0-4) on the walls, one in the lamp's pool
    (it flickers with the lamp), static.
    """

    name = "flicker"
    DEFAULT_DURATION_US = 1_000_000
    PARAMS = {
        "base_log": Param(5.0, -5.0, 15.0, "mean ln L of the ambient-lit scene (switched light off, lamp excluded)"),
        "mains_hz": Param(100.0, 1.0, 1000.0, "lamp modulation frequency, Hz"),
        "depth": Param(0.3, 0.0, 0.95, "modulation depth of the lamp"),
        "duty": Param(
            0.0, 0.0, 0.9, "lamp waveform: 0 sinusoidal, else a PWM pulse train on for this fraction of a period"
        ),
        "lamp_db": Param(12.0, -20.0, 60.0, "lamp over ambient irradiance in its pool, dB"),
        "switch_db": Param(20.0, 0.0, 80.0, "switched light: on/off ratio, dB"),
        "switch_times_s": Param(
            None,
            kind="times",
            doc="times the light toggles, s (starts off)",
            default_text="[30 %, 60 %] of the duration",
            range_text="increasing, in [0, duration]",
        ),
        "switch_ms": Param(2.0, 0.0, 1000.0, "duration of a switch ramp, ms"),
        **COMMON_PARAMS,
    }

    def _build(self) -> None:
        p, rng, sensor = self.params, self._rng, self.sensor
        H, W = sensor.shape
        times = self._times_list("switch_times_s", (0.3, 0.6))
        self.t_us = self._jittered_us("switch_times_s", [ts * US for ts in times])  # applied times, µs
        self.times = times if self._jitter_bound_us() == 0 else [t / US for t in self.t_us]
        R = _structured_texture(rng, H, W, amp=0.7, density=0.8, size=(5, 50))
        self._paint_markers(R, self._marker_places(MARKERS, MARKER_CELL, W, H), MARKER_CELL)
        lx, ly = W * rng.uniform(0.25, 0.4), H * rng.uniform(0.3, 0.45)
        rr = ((self._xx - lx) / (0.22 * W)) ** 2 + ((self._yy - ly) / (0.3 * H)) ** 2
        w = np.exp(-(rr**2)).astype(np.float32)  # soft pool
        blob = np.exp(-(((self._xx - lx) ** 2 + (self._yy - ly + 0.22 * H) ** 2) / (0.03 * W) ** 2))
        w = w + 6.0 * blob.astype(np.float32)
        self.lamp_mask = w > 0.6
        el = 10 ** (p["lamp_db"] / 20)
        ys, xs = np.nonzero(w > 1e-4)
        self.roi = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
        self.A = np.exp(np.float32(p["base_log"]) + R).astype(np.float32)
        self.B = (self.A * el * w)[self.roi].copy()
        self.s_log = db_to_log(p["switch_db"])
        self.sw_us = p["switch_ms"] * 1e3
        self.omega = 2 * math.pi * p["mains_hz"] / US
        self.changes = []
        state = 0.0
        for _i, t_us in enumerate(self.t_us):
            new = 0.0 if state else 1.0
            m0 = np.log(self.A * math.exp(state * self.s_log) + 1e-30)
            m1 = np.log(self.A * math.exp(new * self.s_log) + 1e-30)
            m0[self.roi] = np.log(self.A[self.roi] * math.exp(state * self.s_log) + self.B)
            m1[self.roi] = np.log(self.A[self.roi] * math.exp(new * self.s_log) + self.B)
            self.changes.append(
                LightingChange(int(round(t_us)), "light on" if new else "light off", float(m1.mean() - m0.mean()))
            )
            state = new

    def _switch(self, t: float) -> float:
        s = 0.0
        for k, ts_us in enumerate(self.t_us):
            target = 1.0 if k % 2 == 0 else 0.0
            x = (t - ts_us) / self.sw_us if self.sw_us > 0 else (1.0 if t >= ts_us else 0.0)
            if x <= 0:
                break
            s = s + (target - s) * _smoothstep_scalar(x)
        return s

    def log_irradiance(self, t_us: float) -> np.ndarray:
        t = self._check_t(t_us)
        S = math.exp(self._switch(t) * self.s_log)
        out = self.A * np.float32(S)
        p = self.params
        if p["duty"] > 0.0:
            mod = np.float32(1.0 + p["depth"] * mains.modulation(t, p["mains_hz"], p["duty"]))
        else:
            mod = np.float32(1.0 + p["depth"] * math.cos(self.omega * t))
        out[self.roi] += self.B * mod
        return np.log(out)

    def max_log_rate(self, t0_us: float, t1_us: float) -> float | None:
        p = self.params
        rate = mains.max_log_rate(p["mains_hz"], p["depth"], p["duty"])
        for ts_us in self.t_us:
            if t1_us >= ts_us and t0_us <= ts_us + self.sw_us:
                rate += self.s_log * 1.5 / max(self.sw_us, 1.0)
        return rate
