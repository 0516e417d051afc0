"""The ``indoor_outdoor`` preset: walking out of a building through a door with hand shake (60-80 dB)."""

from __future__ import annotations

import math

import cv2
import numpy as np

from necviz.core.markers import apply_affine
from necviz.drivers.sim.scene import LightingChange, db_to_log
from necviz.drivers.sim.scenes.fiducials import patch_size, quiet_corners
from necviz.drivers.sim.scenes.preset import (
    COMMON_PARAMS,
    US,
    Param,
    PresetScene,
    _affine,
    _bilinear,
    _Shake,
    _smoothstep_scalar,
    _structured_texture,
    _warp,
)

__all__ = ["IndoorOutdoor"]

#: Texels per cell of the fiducial markers (the textures are sampled at 2 texels per pixel at the start).
MARKER_CELL = 10
#: Outdoor markers: offsets of their centres from the outdoor plane's centre, in image widths/heights at
#: the start of the walk.
OUTDOOR_MARKERS = ((-0.28, -0.3), (0.26, -0.24), (0.04, 0.16))


class IndoorOutdoor(PresetScene):
    """Walking out of a building through a door, camera in hand (shake).

    The indoor wall with the door (a soft-edged opening showing the bright outdoor scene) is a
    textured plane the walker approaches at ``walk_speed_mps``; its image zooms about the door
    (1/distance) until the door covers ``door_frac`` of the view, when the transition starts
    (``exit_s - transition_ms/2``); the view then ramps (smoothstep in ln L) to the outdoor scene
    over ``transition_ms``. The outdoor scene (a textured plane 25 m behind the door) zooms slowly as
    the walk continues. Hand shake: smooth random-walk translation (``shake_px`` RMS per axis) and
    rotation (``shake_deg`` RMS) from the seed, applied to both layers.

    ``changes``: one "door exit" at ``exit_s`` (moved by ``change_jitter_ms``, with the whole
    transition).

    Markers (``markers``): ArUco markers (ids 0-1) on the wall either side of the door and three
    (ids 2-4) on the outdoor plane, 10 texels a cell (5 px at the start); they zoom and shake with
    their plane. A marker counts as visible only where its plane has at least 90 % of the view
    (the door's opening, the transition's blend).
    """

    name = "indoor_outdoor"
    DEFAULT_DURATION_US = 3_000_000
    PARAMS = {
        "inside_log": Param(5.0, -5.0, 15.0, "mean ln L indoors"),
        "step_db": Param(70.0, 60.0, 80.0, "outdoor/indoor irradiance ratio, dB"),
        "exit_s": Param(
            None,
            0.0,
            None,
            "time of passing the door (middle of the transition), s",
            "opt_float",
            default_text="50 % of the duration",
            range_text="inside the duration",
        ),
        "transition_ms": Param(300.0, 1.0, 3000.0, "duration of the door passage, ms"),
        "walk_speed_mps": Param(1.4, 0.0, 5.0, "walking speed, m/s"),
        "door_frac": Param(0.1, 0.005, 0.6, "image fraction of the door when the transition starts"),
        "shake_px": Param(3.0, 0.0, 30.0, "hand shake RMS translation, px"),
        "shake_deg": Param(0.5, 0.0, 10.0, "hand shake RMS rotation, degrees"),
        **COMMON_PARAMS,
    }

    def _build(self) -> None:
        p, rng, sensor = self.params, self._rng, self.sensor
        H, W = sensor.shape
        self.t_exit = self._jittered_us("exit_s", [self._time_s("exit_s", 0.5) * US])[0]
        self.tr_us = p["transition_ms"] * 1e3
        self.t0_tr, self.t1_tr = self.t_exit - self.tr_us / 2, self.t_exit + self.tr_us / 2
        self.step = db_to_log(p["step_db"])
        v = p["walk_speed_mps"] / US
        f = 0.75 * W
        # door 1 m x 2.1 m; distance at which it covers door_frac of the image
        self.z_min = f * math.sqrt(2.1 / (p["door_frac"] * W * H))
        self.v = v
        self.z0 = min(self.z_min + v * max(self.t0_tr, 0.0), 4.0 * self.z_min)
        os_ = 2.0  # texture oversampling (zoom up to 4x stays sharp enough)
        s_max = self.z0 / self.z_min
        self.os = os_
        # indoor texture in texels; scale at t = 0 is 1/os px per texel
        th, tw = int(H * 1.4 * os_), int(W * 1.4 * os_)
        tex = _structured_texture(rng, th, tw, amp=0.7, density=0.5, size=(6, 60))
        self.door_c = (tw / 2 + rng.uniform(-0.05, 0.05) * tw, th / 2 + 0.1 * th)
        # door size in texels at t = 0: image size at z0 times os
        dw, dh = f * 1.0 / self.z0 * os_, f * 2.1 / self.z0 * os_
        x0, y0 = self.door_c[0] - dw / 2, self.door_c[1] - dh / 2
        frame = 0.06 * dw
        cv2.rectangle(tex, (int(x0 - frame), int(y0 - frame)), (int(x0 + dw + frame), int(y0 + dh)), 0.9, -1)
        mask = np.zeros((th, tw), np.float32)
        cv2.rectangle(mask, (int(round(x0)), int(round(y0))), (int(round(x0 + dw)), int(round(y0 + dh))), 1.0, -1)
        self.door_mask = cv2.GaussianBlur(mask, (0, 0), 1.2)
        self.tex_in = tex
        self.dd = 25.0  # outdoor plane behind the door, m
        oh, ow = int(H * 1.6 * os_), int(W * 1.6 * os_)
        self.tex_out = _structured_texture(rng, oh, ow, amp=0.8, density=0.6, size=(6, 70))
        # fiducial markers: two on the wall beside the door, three on the outdoor plane
        n = patch_size(MARKER_CELL)
        side = dw / 2 + frame + 12 + n / 2
        beside = [(self.door_c[0] + sgn * side - n / 2, self.door_c[1] - n / 2) for sgn in (-1, 1)]
        nxt = self._paint_markers(tex, beside, MARKER_CELL, "inside")
        outdoor = [(ow / 2 + fx * W * os_ - n / 2, oh / 2 + fy * H * os_ - n / 2) for fx, fy in OUTDOOR_MARKERS]
        self._paint_markers(self.tex_out, outdoor, MARKER_CELL, "outside", nxt)
        self.shake = _Shake(rng, p["shake_px"], p["shake_deg"])
        self.off_in = np.float32(0.0)
        self.off_out = np.float32(0.0)
        self.off_in = np.float32(p["inside_log"] - self._inside(0.0)[0].mean())
        self.off_out = np.float32(p["inside_log"] + self.step - self._outside(self.t1_tr).mean())
        self._s_max = s_max
        self._motion_rate = (
            1.5
            * float(np.abs(np.diff(tex, axis=1)).max())
            * (
                self.shake.max_speed()
                + 0.5 * math.hypot(W, H) * v / self.z_min
                + math.radians(p["shake_deg"]) * 4 * 2 * math.pi * 12 * W
            )
            / US
        )
        i0, o0 = self._inside(0.0)[0], self._outside(self.t1_tr)
        self._span = float(max(o0.max() - i0.min(), i0.max() - o0.min())) + 0.5  # max |out - in| per pixel
        before = self._mean_now(self.t0_tr - 1.0)
        after = self._mean_now(self.t1_tr + 1.0)
        self.changes = [LightingChange(int(round(self.t_exit)), "door exit", after - before)]
        self.annotations = {"transition_us": (self.t0_tr, self.t1_tr)}

    def _dist(self, t: float) -> float:
        return max(self.z0 - self.v * t, self.z_min) if t < self.t0_tr else self.z_min

    def _view(self, t: float, scale: float, src_c) -> np.ndarray:
        H, W = self.sensor.shape
        dx, dy, rot = self.shake(t / US)
        return _affine(scale, rot, src_c, (W / 2 + dx, H / 2 + 0.1 * H + dy))

    def _m_in(self, t: float) -> np.ndarray:
        return self._view(t, (self.z0 / self._dist(t)) / self.os, self.door_c)

    def _m_out(self, t: float) -> np.ndarray:
        D0 = self.z0 + self.dd
        D = max(D0 - self.v * t, D0 / 3.0)
        oh, ow = self.tex_out.shape
        return self._view(t, (self.z0 + self.dd) / D / self.os * 1.0, (ow / 2, oh / 2))

    def _inside(self, t: float):
        m = self._m_in(t)
        return _warp(self.tex_in, m, self.sensor) + self.off_in, m

    def _outside(self, t: float) -> np.ndarray:
        return _warp(self.tex_out, self._m_out(t), self.sensor) + self.off_out

    def _outdoor_weight(self, t: float, points) -> np.ndarray:
        """The outdoor view's share ``w`` (0..1) at image ``points`` (..., 2), as :meth:`log_irradiance` blends."""
        ramp = _smoothstep_scalar((t - self.t0_tr) / self.tr_us)
        if ramp >= 1.0:
            return np.ones(np.shape(points)[:-1])
        tex = apply_affine(cv2.invertAffineTransform(self._m_in(t)), points)
        return np.maximum(_bilinear(self.door_mask, tex), ramp)

    def _marker_geometry(self, t_us: float):
        ids = np.array([m.marker_id for m in self.markers], np.int64)
        corners, weight = np.zeros((ids.size, 4, 2)), np.zeros(ids.size)
        m_in, m_out = self._m_in(t_us), self._m_out(t_us)
        for i, mk in enumerate(self.markers):
            corners[i] = apply_affine(m_in if mk.layer == "inside" else m_out, mk.corners)
            w = self._outdoor_weight(t_us, quiet_corners(corners[i]))
            weight[i] = (1.0 - w if mk.layer == "inside" else w).min()
        return ids, corners, weight

    def log_irradiance(self, t_us: float) -> np.ndarray:
        t = self._check_t(t_us)
        ramp = _smoothstep_scalar((t - self.t0_tr) / self.tr_us)
        if ramp >= 1.0:
            return self._outside(t)
        inside, m = self._inside(t)
        w = _warp(self.door_mask, m, self.sensor, cv2.BORDER_CONSTANT)
        if ramp > 0:
            w = np.maximum(w, np.float32(ramp))
        inside += w * (self._outside(t) - inside)
        return inside

    def max_log_rate(self, t0_us: float, t1_us: float) -> float | None:
        rate = self._motion_rate
        if t1_us >= self.t0_tr and t0_us <= self.t1_tr:
            rate += self._span * 1.5 / self.tr_us
        return rate
