"""Analytic scenes for tests: a fixed texture times a global irradiance with closed forms.

``ln L(t, x) = ln tex(x) + ln l_k(t)`` where ``k`` is the pixel's group (one group unless the
test wants different lighting in different parts of the sensor). Each ``l_k`` is a closed-form
monotone trajectory with an exact time integral and an exact inverse, so ideal events are
placed at the exact threshold-crossing times and frames are exact exposure averages: an
independent truth for the estimators (nothing here calls the code under test except the
camera response used to quantise frames).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from necviz.core.crf import US_PER_S, CameraResponse
from necviz.core.events import EVENT_DTYPE
from necviz.core.frames import Frame


@dataclass(frozen=True)
class Trajectory:
    """``ln l(t)``: 0 before ``t0``, then a step, a log-linear ramp or an exponential approach to ``delta``."""

    kind: str  # "step" | "ramp" | "exp" | "flat"
    t0: float = 0.0
    delta: float = 0.0  # total change of ln l (natural log units; 120 dB = 13.8)
    duration: float = 1.0  # ramp length, or exp time constant (µs)

    def log(self, t):
        t = np.asarray(t, dtype=np.float64)
        d, t0, D = self.delta, self.t0, self.duration
        if self.kind == "flat":
            return np.zeros_like(t)
        if self.kind == "step":
            return np.where(t > t0, d, 0.0)  # an event at t0 has happened for t > t0
        if self.kind == "ramp":
            return d * np.clip((t - t0) / D, 0.0, 1.0)
        a = math.exp(d)
        return np.where(t >= t0, np.log(a - (a - 1.0) * np.exp(-np.maximum(t - t0, 0.0) / D)), 0.0)

    def integral(self, s: float, e: float) -> float:
        """``∫_s^e l(t) dt`` in closed form."""
        d, t0, D = self.delta, self.t0, self.duration
        if self.kind == "flat":
            return e - s
        before = max(0.0, min(e, t0) - s)
        a0, b0 = max(s, t0), e
        if b0 <= a0:
            return before
        if self.kind == "step":
            return before + (b0 - a0) * math.exp(d)
        if self.kind == "ramp":
            t1 = t0 + D
            total = before
            lo, hi = a0, min(b0, t1)
            if hi > lo:
                if abs(d) < 1e-12:
                    total += hi - lo
                else:
                    total += D / d * (math.exp(d * (hi - t0) / D) - math.exp(d * (lo - t0) / D))
            if b0 > t1:
                total += (b0 - max(a0, t1)) * math.exp(d)
            return total
        a = math.exp(d)
        return before + a * (b0 - a0) - (a - 1.0) * D * (math.exp(-(a0 - t0) / D) - math.exp(-(b0 - t0) / D))

    def crossing_time(self, level):
        """Time at which ``ln l`` first reaches ``level`` (between 0 and delta)."""
        level = np.asarray(level, dtype=np.float64)
        d, t0, D = self.delta, self.t0, self.duration
        if self.kind == "step":
            return np.full_like(level, t0)
        if self.kind == "ramp":
            return t0 + D * level / d
        a = math.exp(d)
        return t0 - D * np.log((a - np.exp(level)) / (a - 1.0))


def texture(width: int, height: int) -> np.ndarray:
    """A smooth pattern with edges: ln tex in about [-0.8, 0.8]."""
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    smooth = 0.5 * np.sin(2 * np.pi * xx / 16.0) * np.cos(2 * np.pi * yy / 12.0)
    edges = 0.3 * np.where(((xx // 8) + (yy // 8)) % 2 == 0, 1.0, -1.0)
    return smooth + edges


class AnalyticScene:
    """Texture x per-group trajectory, ideal events, exact frames."""

    def __init__(
        self, width=64, height=48, trajectories=(Trajectory("flat"),), groups=None, log_level=0.0, log_texture=None
    ):
        self.width, self.height = width, height
        self.log_tex = texture(width, height) if log_texture is None else np.asarray(log_texture, np.float64)
        self.log_level = log_level
        self.trajectories = list(trajectories)
        self.groups = np.zeros((height, width), np.int64) if groups is None else np.asarray(groups, np.int64)

    # -- truth ---------------------------------------------------------------------------------
    def log_irradiance(self, t: float) -> np.ndarray:
        """``ln L(t, x)`` for every pixel."""
        out = self.log_level + self.log_tex.copy()
        for k, tr in enumerate(self.trajectories):
            out[self.groups == k] += float(tr.log(t))
        return out

    def mean_log_irradiance(self, t: float, mask=None) -> float:
        v = self.log_irradiance(t)
        return float(v.mean() if mask is None else v[mask].mean())

    def log_mean_irradiance(self, t: float, mask=None) -> float:
        v = np.exp(self.log_irradiance(t))
        return float(np.log(v.mean() if mask is None else v[mask].mean()))

    def exposure_average(self, s: float, e: float) -> np.ndarray:
        """``Lbar(x) = (1/T) ∫_s^e L(t, x) dt`` exactly."""
        out = np.exp(self.log_level + self.log_tex)
        for k, tr in enumerate(self.trajectories):
            out[self.groups == k] *= tr.integral(s, e) / (e - s)
        return out

    # -- sensor data -----------------------------------------------------------------------------
    def frame(self, crf: CameraResponse, s: int, e: int, gain: float = 1.0, seq: int = 0) -> Frame:
        """The exact exposure average through the camera response, rounded to 8 bits."""
        h = np.log(self.exposure_average(s, e)) + math.log((e - s) / US_PER_S) + math.log(gain)
        z = np.clip(np.rint(np.asarray(crf.intensity(h))), 0, 255)
        return Frame(z.astype(np.uint8), int(s), int(e), float(gain), seq)

    def events(self, c_on: float, c_off: float, seed: int = 0) -> np.ndarray:
        """Ideal DVS events at the exact crossing times, one random threshold phase per pixel.

        Each pixel remembers a reference level; an ON event fires when ``ln L`` rises ``c_on``
        above it, an OFF event when it falls ``c_off`` below, and the reference moves by the
        threshold. Trajectories are monotone, so every crossing is one closed-form inverse.
        """
        rng = np.random.default_rng(seed)
        ts, xs, ys, ps = [], [], [], []
        yy, xx = np.mgrid[0 : self.height, 0 : self.width]
        for k, tr in enumerate(self.trajectories):
            sel = self.groups == k
            if tr.kind == "flat" or tr.delta == 0:
                continue
            n_pix = int(sel.sum())
            c = c_on if tr.delta > 0 else c_off
            phase = rng.uniform(0.0, c, size=n_pix)  # how far the reference sits below/above the start level
            n_ev = np.floor((abs(tr.delta) + phase) / c).astype(np.int64)
            rep = np.repeat(np.arange(n_pix), n_ev)
            kk = np.arange(rep.size) - np.repeat(np.cumsum(n_ev) - n_ev, n_ev) + 1
            level = (kk * c - phase[rep]) * np.sign(tr.delta)
            ts.append(tr.crossing_time(level))
            xs.append(xx[sel][rep])
            ys.append(yy[sel][rep])
            ps.append(np.full(rep.size, 1 if tr.delta > 0 else -1))
        if not ts:
            return np.zeros(0, EVENT_DTYPE)
        t = np.concatenate(ts)
        order = np.argsort(t, kind="stable")
        ev = np.empty(t.size, EVENT_DTYPE)
        # a crossing at t belongs to the first whole µs at which it has happened
        ev["t"] = np.ceil(t[order] - 1e-9).astype(np.int64)
        ev["x"] = np.concatenate(xs)[order]
        ev["y"] = np.concatenate(ys)[order]
        ev["p"] = np.concatenate(ps)[order]
        return ev
