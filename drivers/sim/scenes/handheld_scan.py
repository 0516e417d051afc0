"""The ``handheld_scan`` preset: a handheld scan over a facade crossed by moving soft sun/shadow edges."""

from __future__ import annotations

import math

import cv2
import numpy as np

from necviz.core.markers import apply_affine
from necviz.drivers.sim.scene import LightingChange, db_to_log
from necviz.drivers.sim.scenes.fiducials import patch_size
from necviz.drivers.sim.scenes.preset import (
    COMMON_PARAMS,
    US,
    Param,
    PresetScene,
    _affine,
    _Shake,
    _structured_texture,
    _warp,
)

__all__ = ["HandheldScan"]

#: Texels (= px: the facade is not scaled) per cell of the fiducial markers.
MARKER_CELL = 5


class HandheldScan(PresetScene):
    """Handheld scan over a sunlit facade crossed by moving soft shadow boundaries.

    The facade (3 x sensor width, 1.6 x height: windows, brick courses, signs, noise) is panned
    back and forth at ``scan_speed_px_s`` with a slow vertical drift and hand shake (``shake_px``,
    ``shake_deg``). Shadow bands (period ``shadow_period_px`` on the facade, half in sun) move across
    it at ``shadow_speed_px_s`` perpendicular to edges tilted by ``shadow_angle_deg``; edges are
    linear ramps ``shadow_soft_px`` wide; sun is brighter than shadow by ``shadow_db``.

    ``changes``: every time a shadow edge crosses the image centre (a local change: ``delta_log`` =
    +-db_to_log(shadow_db) at the centre, not of the mean), found on a 0.5 ms grid. The crossing
    times follow from the motion (the band phase is drawn from the seed); ``change_jitter_ms``
    delays the shadow bands (not the camera) by one seeded offset of at most that much, which moves
    the crossings against the frame clock (not by exactly that offset, since the camera moves too).

    Markers (``markers``): five ArUco markers (30 px, ids 0-4) on the facade, every half image width
    along the scan path, alternately above and below its centre line; they pan, shake and cross
    the shadow edges with the facade.
    """

    name = "handheld_scan"
    DEFAULT_DURATION_US = 3_000_000
    PARAMS = {
        "base_log": Param(5.0, -5.0, 15.0, "mean ln L of the facade in shadow"),
        "shadow_db": Param(50.0, 10.0, 100.0, "sun/shadow irradiance ratio, dB"),
        "shadow_speed_px_s": Param(120.0, 0.0, 5000.0, "speed of the shadow edges on the facade, px/s"),
        "shadow_period_px": Param(700.0, 50.0, 1e5, "spacing of the shadow bands on the facade, px"),
        "shadow_soft_px": Param(12.0, 0.5, 500.0, "width of a shadow edge, px"),
        "shadow_angle_deg": Param(70.0, -180.0, 180.0, "tilt of the shadow edges from horizontal, degrees"),
        "scan_speed_px_s": Param(80.0, 0.0, 2000.0, "horizontal scan speed, px/s"),
        "shake_px": Param(2.5, 0.0, 30.0, "hand shake RMS translation, px"),
        "shake_deg": Param(0.4, 0.0, 10.0, "hand shake RMS rotation, degrees"),
        **COMMON_PARAMS,
    }

    def _build(self) -> None:
        p, rng, sensor = self.params, self._rng, self.sensor
        H, W = sensor.shape
        fh, fw = int(H * 1.6), int(W * 3)
        tex = _structured_texture(rng, fh, fw, amp=0.5, density=0.4, size=(5, 40))
        for y in range(0, fh, 9):  # brick courses
            cv2.line(tex, (0, y), (fw - 1, y), -0.35, 1)
        win_w, win_h = max(6, W // 14), max(8, H // 8)
        for y in range(int(0.1 * fh), fh - win_h, int(win_h * 2.2)):
            for x in range(int(0.03 * fw), fw - win_w, int(win_w * 2.4)):
                cv2.rectangle(tex, (x, y), (x + win_w, y + win_h), float(rng.uniform(-1.3, -0.6)), -1)
                cv2.rectangle(tex, (x - 2, y - 2), (x + win_w + 2, y + win_h + 2), 0.7, 2)
                cv2.line(tex, (x + win_w // 2, y), (x + win_w // 2, y + win_h), 0.5, 1)
        tex = cv2.GaussianBlur(tex, (0, 0), 0.6)
        n = patch_size(MARKER_CELL)  # markers along the scan path, alternately above and below its centre line
        places = [(W * (0.5 + 0.5 * k) - n / 2, fh / 2 + (0.2 if k % 2 else -0.22) * H - n / 2) for k in range(5)]
        self._paint_markers(tex, places, MARKER_CELL)
        self.tex = (tex - tex.mean() + p["base_log"]).astype(np.float32)
        self.fshape = (fh, fw)
        self.shake = _Shake(rng, p["shake_px"], p["shake_deg"])
        self.step = db_to_log(p["shadow_db"])
        a = math.radians(p["shadow_angle_deg"])
        self.n = (math.sin(a), -math.cos(a))  # normal of the edges (facade coords)
        self.phase0 = rng.uniform(0, p["shadow_period_px"])
        self.shadow_delay_us = float(self._jitter_us(1)[0])  # change_jitter_ms: the bands run late by this
        self.x_lo, self.x_hi = W / 2 + 10, fw - W / 2 - 10
        self.ycen = fh / 2
        self._motion_rate = (
            1.5 * float(np.abs(np.diff(tex, axis=1)).max()) * (p["scan_speed_px_s"] + self.shake.max_speed() + 20) / US
            + self.step
            / p["shadow_soft_px"]
            * (p["shadow_speed_px_s"] + p["scan_speed_px_s"] + self.shake.max_speed() + 20)
            / US
        )
        # changes: shadow edges crossing the image centre (sampled every 0.5 ms)
        ts = np.arange(0, self.duration_us + 1, 500.0)
        wc = np.array([self._weight_at_centre(t) for t in ts])
        idx = np.nonzero(np.diff(np.sign(wc - 0.5)) != 0)[0]
        self.changes = [
            LightingChange(
                int(ts[i + 1]),
                "sun edge at centre" if wc[i + 1] > wc[i] else "shadow edge at centre",
                self.step if wc[i + 1] > wc[i] else -self.step,
            )
            for i in idx
        ]

    def _pose(self, t: float):
        """Facade point at the image centre (x, y) and shake (dx, dy, rot) at time t (µs)."""
        span = self.x_hi - self.x_lo
        d = self.params["scan_speed_px_s"] * t / US
        tri = d % (2 * span) if span > 0 else 0.0
        xc = self.x_lo + (tri if tri <= span else 2 * span - tri)
        yc = self.ycen + 0.08 * self.fshape[0] * math.sin(2 * math.pi * 0.23 * t / US)
        return (xc, yc), self.shake(t / US)

    def _marker_geometry(self, t_us: float):
        ids, corners, _ = super()._marker_geometry(t_us)
        return ids, apply_affine(self._matrix(t_us), corners), None

    def _matrix(self, t: float) -> np.ndarray:
        H, W = self.sensor.shape
        (xc, yc), (dx, dy, rot) = self._pose(t)
        return _affine(1.0, rot, (xc, yc), (W / 2 + dx, H / 2 + dy))

    def _shadow_coeffs(self, t: float, m: np.ndarray):
        """s(x, y) = a x + b y + c: facade coordinate along the edge normal, minus the band motion."""
        inv = cv2.invertAffineTransform(m)
        nx, ny = self.n
        a = nx * inv[0, 0] + ny * inv[1, 0]
        b = nx * inv[0, 1] + ny * inv[1, 1]
        c = (
            nx * inv[0, 2]
            + ny * inv[1, 2]
            + self.params["shadow_speed_px_s"] * (t - self.shadow_delay_us) / US
            + self.phase0
        )
        return a, b, c % self.params["shadow_period_px"]

    def _weight_at_centre(self, t: float) -> float:
        H, W = self.sensor.shape
        a, b, c = self._shadow_coeffs(t, self._matrix(t))
        s = a * (W / 2) + b * (H / 2) + c
        P, soft = self.params["shadow_period_px"], self.params["shadow_soft_px"]
        g = P / (2 * math.pi * soft)
        return min(max(0.5 + g * math.cos(2 * math.pi * s / P), 0.0), 1.0)

    def log_irradiance(self, t_us: float) -> np.ndarray:
        t = self._check_t(t_us)
        m = self._matrix(t)
        img = _warp(self.tex, m, self.sensor)
        a, b, c = self._shadow_coeffs(t, m)
        P, soft = self.params["shadow_period_px"], self.params["shadow_soft_px"]
        k = np.float32(2 * math.pi / P)
        s = self._xx * np.float32(a * k) + self._yy * np.float32(b * k) + np.float32(c * k)
        w = np.cos(s)
        w *= np.float32(self.step * P / (2 * math.pi * soft))
        w += np.float32(0.5 * self.step)
        np.clip(w, 0.0, np.float32(self.step), out=w)
        img += w
        return img

    def max_log_rate(self, t0_us: float, t1_us: float) -> float | None:
        return self._motion_rate
