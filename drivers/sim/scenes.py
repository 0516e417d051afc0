"""Named scenario presets for the closed-loop simulator: HDR scenes with motion and lighting steps.

Every preset is a :class:`~necviz.drivers.sim.scene.Scene`; it is deterministic for its seed (textures
and hand shake come from ``numpy.random.default_rng(seed)``), renders float32 ``ln L`` at the sensor's
resolution with vectorised NumPy/OpenCV (one or a few ``cv2.remap``/``cv2.warpAffine`` calls per image),
and lists its lighting steps in ``scene.changes`` (:class:`LightingChange`).

Units: ``ln L`` as in :mod:`necviz.drivers.sim.scene` (``ln L = 5`` is well exposed at about 4 ms);
lighting steps are given in dB (20 log10 of the irradiance ratio; ``db_to_log`` converts), times in
seconds or milliseconds as the parameter name says, image speeds in pixels per second.

Presets (``SCENARIOS``):

``tunnel_exit``
    driving out of a tunnel (forward motion, growing bright portal, step of ``step_db`` over
    ``transition_ms``, a pedestrian walking in after the exit).
``indoor_outdoor``
    walking out of a building through a door with hand shake (60-80 dB).
``flicker``
    a room with a mains-powered lamp flickering at 100 Hz plus a light switched on and off.
``static_lab``
    a static lab scene whose lights step between configured dB levels (the paper's indoor test).
``handheld_scan``
    handheld scan over a facade with soft sun/shadow boundaries sweeping across (40-60 dB).

Build one with :func:`make_scenario` (``make_scenario("tunnel_exit", seed=3, step_db=90)``) or from a
TOML description with :func:`scenario_from_toml`::

    name = "tunnel_exit"
    seed = 3
    duration_s = 2.0          # or duration_us = 2000000; default: the preset's own duration
    sensor = "DAVIS346"       # optional: "DAVIS346", "DAVIS240" or {width = .., height = ..}
    [params]
    step_db = 90
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from ...core.errors import ParameterError, ProfileError
from ...core.sensor import DAVIS240, DAVIS346, SensorGeometry
from .scene import LightingChange, Scene, db_to_log

US = 1e6  # µs per second

__all__ = ["SCENARIOS", "make_scenario", "scenario_from_toml", "scenario_params", "TunnelExit",
           "IndoorOutdoor", "Flicker", "StaticLab", "HandheldScan", "PresetScene"]


# ---------------------------------------------------------------------------------------------
# parameters
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Param:
    """One documented preset parameter: default, accepted closed range and unit/meaning."""

    default: Any
    lo: float | None = None
    hi: float | None = None
    doc: str = ""
    kind: str = "float"  # "float", "opt_float" (None = derived default), "times" (list of s), "steps"


def _check_number(scenario: str, key: str, v, lo, hi) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise ParameterError(f"{scenario}: parameter {key} must be a number, got {v!r}")
    v = float(v)
    if not math.isfinite(v):
        raise ParameterError(f"{scenario}: parameter {key} must be finite, got {v!r}")
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise ParameterError(f"{scenario}: parameter {key} = {v:g} is out of range [{lo:g}, {hi:g}]")
    return v


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _smoothstep_scalar(x: float) -> float:
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


# ---------------------------------------------------------------------------------------------
# textures
# ---------------------------------------------------------------------------------------------
def _noise(rng: np.random.Generator, h: int, w: int, std: float = 1.0, k0: float = 1 / 96,
           kmax: float = 0.3) -> np.ndarray:
    """Periodic multi-octave (1/f amplitude) noise by spectral synthesis, zero mean, given std."""
    white = rng.standard_normal((h, w))
    spec = np.fft.rfft2(white)
    k = np.sqrt(np.fft.fftfreq(h)[:, None] ** 2 + np.fft.rfftfreq(w)[None, :] ** 2)
    amp = 1.0 / (k + k0)
    amp[k > kmax] = 0.0
    amp[0, 0] = 0.0
    out = np.fft.irfft2(spec * amp, s=(h, w))
    out *= std / max(out.std(), 1e-12)
    return out.astype(np.float32)


def _draw_shapes(img: np.ndarray, rng: np.random.Generator, n: int, size: tuple[float, float],
                 amp: float, wrap: bool = False) -> None:
    """Draw ``n`` random rectangles, outlines, lines, ellipses, triangles and checker patches in place.

    Values are offsets in ln units of magnitude ~``amp``; ``size`` = (min, max) shape size in texels.
    With ``wrap`` the shapes are also drawn shifted by the image size so the texture stays periodic.
    """
    h, w = img.shape
    shifts = [(0, 0)]
    if wrap:
        shifts = [(sx, sy) for sx in (-w, 0, w) for sy in (-h, 0, h)]
    smin, smax = size
    for _ in range(n):
        kind = rng.integers(0, 6)
        x, y = rng.uniform(0, w), rng.uniform(0, h)
        a, b = rng.uniform(smin, smax, size=2)
        val = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.35, 1.0) * amp)
        thick = int(rng.integers(1, 4))
        ang = float(rng.uniform(0, 180))
        if kind == 5:  # checker patch (corners for feature matchers)
            cell = max(2, int(rng.uniform(smin / 4, smax / 4)))
            nc = int(rng.integers(3, 7))
            patch = ((np.indices((nc * cell, nc * cell)) // cell).sum(0) % 2).astype(np.float32)
            patch = (patch - 0.5) * 2 * abs(val)
            for sx, sy in shifts:
                x0, y0 = int(x) + sx, int(y) + sy
                xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x0 + nc * cell, w), min(y0 + nc * cell, h)
                if xa < xb and ya < yb:
                    img[ya:yb, xa:xb] = patch[ya - y0:yb - y0, xa - x0:xb - x0]
            continue
        for sx, sy in shifts:
            cx, cy = x + sx, y + sy
            if kind == 0:
                cv2.rectangle(img, (int(cx), int(cy)), (int(cx + a), int(cy + b)), val, -1)
            elif kind == 1:
                cv2.rectangle(img, (int(cx), int(cy)), (int(cx + a), int(cy + b)), val, thick)
            elif kind == 2:
                dx, dy = a * math.cos(math.radians(ang)) * 1.5, a * math.sin(math.radians(ang)) * 1.5
                cv2.line(img, (int(cx), int(cy)), (int(cx + dx), int(cy + dy)), val, thick)
            elif kind == 3:
                cv2.ellipse(img, (int(cx), int(cy)), (int(a / 2) + 1, int(b / 2) + 1), ang, 0, 360, val, -1)
            else:
                pts = np.array([[cx, cy], [cx + a, cy + rng.uniform(-b, b) * 0 + b * 0.3],
                                [cx + a * 0.4, cy + b]], dtype=np.int32)
                cv2.fillPoly(img, [pts], val)


def _blur(img: np.ndarray, sigma: float, wrap: bool) -> np.ndarray:
    """Gaussian blur; with ``wrap`` the image is treated as periodic."""
    if not wrap:
        return cv2.GaussianBlur(img, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    m = int(math.ceil(4 * sigma)) + 1
    big = np.pad(img, m, mode="wrap")
    return cv2.GaussianBlur(big, (0, 0), sigma)[m:-m, m:-m].copy()


def _structured_texture(rng: np.random.Generator, h: int, w: int, *, amp: float = 0.6, density: float = 1.0,
                        size: tuple[float, float] = (6, 40), wrap: bool = False) -> np.ndarray:
    """Value noise plus drawn shapes (edges, corners, checkers), zero mean, float32 ln-unit offsets."""
    img = _noise(rng, h, w, std=0.25 * amp / 0.6)
    n = int(density * h * w / 900) + 4
    _draw_shapes(img, rng, n, size, amp, wrap=wrap)
    img += _noise(rng, h, w, std=0.05, k0=1 / 8, kmax=0.45)  # fine grain
    img = _blur(img, 0.7, wrap)
    img -= img.mean()
    return img.astype(np.float32)


class _Shake:
    """Smooth random-walk-like hand shake: sums of sinusoids (0.3-12 Hz, 1/f amplitudes), seeded.

    ``__call__(t_s)`` -> (dx px, dy px, rot rad) with RMS ``px`` per axis and ``deg`` in rotation.
    """

    def __init__(self, rng: np.random.Generator, px: float, deg: float, n: int = 14):
        f = np.exp(rng.uniform(math.log(0.3), math.log(12.0), size=(3, n)))
        a = 1.0 / f
        a *= np.sqrt(2.0) / np.sqrt((a ** 2).sum(axis=1, keepdims=True))  # RMS 1 per component
        self.f, self.phase = f, rng.uniform(0, 2 * math.pi, size=(3, n))
        self.amp = a * np.array([[px], [px], [math.radians(deg)]])

    def __call__(self, t_s: float):
        v = (self.amp * np.sin(2 * math.pi * self.f * t_s + self.phase)).sum(axis=1)
        return float(v[0]), float(v[1]), float(v[2])

    def max_speed(self) -> float:
        """Upper bound of the translation speed in px/s (rotation excluded)."""
        return float((self.amp[:2] * 2 * math.pi * self.f[:2]).sum(axis=1).max())


def _affine(scale: float, rot: float, src_c: tuple[float, float], dst_c: tuple[float, float]) -> np.ndarray:
    """Matrix mapping texture coords to image coords: rotate+scale about src_c, put it at dst_c."""
    c, s = math.cos(rot) * scale, math.sin(rot) * scale
    return np.array([[c, -s, dst_c[0] - c * src_c[0] + s * src_c[1]],
                     [s, c, dst_c[1] - s * src_c[0] - c * src_c[1]]], dtype=np.float64)


def _warp(tex: np.ndarray, m: np.ndarray, sensor: SensorGeometry, border=cv2.BORDER_REFLECT) -> np.ndarray:
    return cv2.warpAffine(tex, m, (sensor.width, sensor.height), flags=cv2.INTER_LINEAR, borderMode=border)


# ---------------------------------------------------------------------------------------------
# base class
# ---------------------------------------------------------------------------------------------
class PresetScene(Scene):
    """A named preset: validates its documented ``PARAMS`` and builds its textures once."""

    name = "preset"
    PARAMS: dict[str, Param] = {}
    DEFAULT_DURATION_US = 2_000_000

    def __init__(self, sensor: SensorGeometry = DAVIS346, duration_us: int | None = None, seed: int = 0,
                 **params):
        if duration_us is None:
            duration_us = self.DEFAULT_DURATION_US
        if not isinstance(sensor, SensorGeometry):
            raise ParameterError(f"{self.name}: sensor must be a SensorGeometry, got {sensor!r}")
        super().__init__(sensor, duration_us, seed)
        unknown = sorted(set(params) - set(self.PARAMS))
        if unknown:
            raise ParameterError(f"{self.name}: unknown parameter(s) {', '.join(unknown)}; accepted: "
                                 f"{', '.join(self.PARAMS)}")
        self.params = {}
        for key, spec in self.PARAMS.items():
            v = params.get(key, spec.default)
            if spec.kind == "float":
                v = _check_number(self.name, key, v, spec.lo, spec.hi)
            elif spec.kind == "opt_float" and v is not None:
                v = _check_number(self.name, key, v, spec.lo, spec.hi)
            self.params[key] = v
        self.duration_s = self.duration_us / US
        self.annotations: dict[str, Any] = {}
        self._rng = np.random.default_rng(self.seed)
        H, W = sensor.shape
        self._yy, self._xx = np.mgrid[0:H, 0:W].astype(np.float32)
        self._build()

    # subclasses
    def _build(self) -> None:
        raise NotImplementedError

    def _check_t(self, t_us) -> float:
        t = float(t_us)
        if not math.isfinite(t):
            raise ParameterError(f"{self.name}: time must be finite, got {t_us!r}")
        return t

    def _time_s(self, key: str, frac: float) -> float:
        """An optional time parameter in seconds; None means ``frac`` of the duration."""
        v = self.params[key]
        if v is None:
            v = frac * self.duration_s
            self.params[key] = v
        if not 0.0 < v < self.duration_s:
            raise ParameterError(f"{self.name}: {key} = {v:g} s must lie inside the duration "
                                 f"(0, {self.duration_s:g}) s")
        return v

    def _times_list(self, key: str, default_fracs) -> list[float]:
        v = self.params[key]
        if v is None:
            v = [f * self.duration_s for f in default_fracs]
        if not isinstance(v, (list, tuple)):
            raise ParameterError(f"{self.name}: {key} must be a list of times in seconds, got {v!r}")
        out = [_check_number(self.name, f"{key}[{i}]", x, 0.0, self.duration_s) for i, x in enumerate(v)]
        if any(b <= a for a, b in zip(out, out[1:])):
            raise ParameterError(f"{self.name}: {key} must be strictly increasing, got {out}")
        self.params[key] = out
        return out

    def _mean_now(self, t_us: float) -> float:
        return float(self.log_irradiance(t_us).astype(np.float64).mean())


# ---------------------------------------------------------------------------------------------
# forward motion geometry (tunnel / road)
# ---------------------------------------------------------------------------------------------
class _Corridor:
    """Box corridor (or open road with roadside facades and sky) seen from a camera moving along it.

    Every pixel's ray hits the floor, a wall or the ceiling at depth ``z`` (m); the surfaces are
    unrolled into one texture atlas (u = position around the cross-section, v = depth), so forward
    motion by ``s`` metres is a shift of the static v map: one ``cv2.remap`` per image, with the
    exact expanding flow from the focus of expansion. Distant texture is attenuated (haze/mip
    substitute) so it does not alias.
    """

    def __init__(self, sensor: SensorGeometry, f: float, foe: tuple[float, float], half_w: float, floor_h: float,
                 top_h: float, closed: bool, res: float, period_m: float, z_max: float = 300.0):
        H, W = sensor.shape
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
        dx, dy = xx + 0.5 - foe[0], yy + 0.5 - foe[1]
        big = 1e9
        zf = np.where(dy > 1e-9, f * floor_h / np.maximum(dy, 1e-9), big)
        zw = np.where(np.abs(dx) > 1e-9, f * half_w / np.maximum(np.abs(dx), 1e-9), big)
        zc = np.where(dy < -1e-9, f * top_h / np.maximum(-dy, 1e-9), big) if closed else np.full_like(dx, big)
        z = np.minimum(np.minimum(zf, zw), zc)
        floor, wall = z == zf, (z == zw) & (z != zf)
        ceil = ~(floor | wall)
        z = np.minimum(z, z_max)
        X, Y = dx * z / f, -dy * z / f
        if closed:
            total = 4 * half_w + 2 * (floor_h + top_h)
            u = np.where(floor, X + half_w, 0.0)
            u = np.where(wall & (dx > 0), 2 * half_w + Y + floor_h, u)
            u = np.where(ceil, 2 * half_w + floor_h + top_h + half_w - X, u)
            u = np.where(wall & (dx <= 0), 4 * half_w + floor_h + top_h + top_h - Y, u)
            sky = np.zeros_like(floor)
        else:
            total = 2 * half_w + 2 * (floor_h + top_h)
            sky = ceil | (wall & (Y > top_h)) | (z >= z_max)
            u = np.where(floor, X + half_w, 0.0)
            u = np.where(wall & (dx > 0), 2 * half_w + Y + floor_h, u)
            u = np.where(wall & (dx <= 0), total - (Y + floor_h), u)
            u = np.where(sky, 0.0, u)
        self.total_u, self.period_m, self.res = total, period_m, res
        self.shape_tex = (int(round(period_m * res)), int(round(total * res)))
        self.mapx = (np.mod(u, total) * res).astype(np.float32)
        self.mapy0 = (z * res).astype(np.float32)
        self.z, self.floor, self.wall, self.ceil, self.sky = z, floor, wall & ~sky, ceil & ~sky, sky
        self.X, self.Y = X, Y
        footprint = z * res / f  # texels per pixel
        self.haze = (1.0 / (1.0 + (footprint / 2.5) ** 2)).astype(np.float32)
        # image flow (px/s per m/s of speed): radial, |p - foe| / z
        self.flow_per_mps = np.hypot(dx, dy) / np.maximum(z, 1e-6)

    def render(self, tex: np.ndarray, s_m: float) -> np.ndarray:
        shift = np.float32((s_m * self.res) % self.shape_tex[0])
        return cv2.remap(tex, self.mapx, self.mapy0 + shift, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)


def _paste(img: np.ndarray, patch: np.ndarray, alpha: np.ndarray, x: float, y: float, level: float) -> None:
    """Alpha-blend ``level + patch`` into ``img`` with its top-left corner at sub-pixel (x, y)."""
    H, W = img.shape
    ph, pw = patch.shape
    x0, y0 = int(math.floor(x)) - 1, int(math.floor(y)) - 1
    xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x0 + pw + 3, W), min(y0 + ph + 3, H)
    if xa >= xb or ya >= yb:
        return
    m = np.array([[1.0, 0.0, x - xa], [0.0, 1.0, y - ya]])
    size = (xb - xa, yb - ya)
    p = cv2.warpAffine(patch, m, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    a = cv2.warpAffine(alpha, m, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    roi = img[ya:yb, xa:xb]
    roi += a * (level + p - roi)


# ---------------------------------------------------------------------------------------------
# tunnel_exit
# ---------------------------------------------------------------------------------------------
class TunnelExit(PresetScene):
    """Driving out of a tunnel into sunlight.

    Geometry: a box tunnel (10 m wide, camera 1.5 m above the road, ceiling 4.5 m above the camera,
    tiled walls, ceiling lamps every 12 m) then an open road with lane marks, roadside facades and sky;
    the camera (focal length 0.75 x width, focus of expansion at (W/2, 0.42 H)) moves forward at
    ``speed_kmh``, so texture flows radially out of the focus of expansion. The tunnel portal is the
    tunnel's cross-section at depth ``z_p(t)``: pixels whose tunnel surface lies beyond it see the
    bright outside, so the portal grows as ``1/z_p`` while approaching. It reaches ``portal_frac`` of
    the image when the transition starts (``exit_s - transition_ms/2``); then the whole view ramps
    (smoothstep in ln L) to the outside over ``transition_ms`` (the last metres through the portal
    compressed into a documented interval). A textured pedestrian walks into view from the right
    edge ``pedestrian_delay_ms`` after the exit and crosses laterally.

    Parameters (defaults): ``inside_log`` = 5.0 (mean ln L of the tunnel surfaces,
    portal excluded), ``step_db`` = 60 dB (outside
    brighter by this; 40..140), ``transition_ms`` = 40 ms, ``exit_s`` = 40 % of the duration (time the
    camera passes the portal, middle of the transition), ``speed_kmh`` = 60, ``portal_frac`` = 0.08,
    ``texture_contrast`` = 1.0 (multiplier of the texture's ln contrast), ``pedestrian_delay_ms`` = 150,
    ``pedestrian_speed_px_s`` = 60, ``pedestrian_px`` = 48 (height in pixels). Default duration 2 s.

    ``changes``: one "tunnel exit" at ``exit_s`` with the mean ln L change across the transition
    (less than ``db_to_log(step_db)`` by the portal's share before it). ``annotations``:
    ``transition_us`` (start, end), ``pedestrian_enters_us``, ``foe`` (x, y).
    """

    name = "tunnel_exit"
    DEFAULT_DURATION_US = 2_000_000
    PARAMS = {
        "inside_log": Param(5.0, -5.0, 15.0, "mean ln L of the tunnel surfaces (portal excluded)"),
        "step_db": Param(60.0, 40.0, 140.0, "outside/inside irradiance ratio, dB"),
        "transition_ms": Param(40.0, 1.0, 1000.0, "duration of the portal passage, ms"),
        "exit_s": Param(None, 0.0, None, "time the portal is passed, s (default 40 % of the duration)",
                        "opt_float"),
        "speed_kmh": Param(60.0, 0.0, 300.0, "forward speed, km/h"),
        "portal_frac": Param(0.08, 0.0, 0.5, "image fraction covered by the portal when the transition starts"),
        "texture_contrast": Param(1.0, 0.0, 3.0, "multiplier of the texture contrast"),
        "pedestrian_delay_ms": Param(150.0, 0.0, 1e6, "pedestrian enters the view this long after the exit, ms"),
        "pedestrian_speed_px_s": Param(60.0, 0.0, 2000.0, "lateral pedestrian speed, px/s"),
        "pedestrian_px": Param(48.0, 8.0, 250.0, "pedestrian height, px"),
    }

    def _build(self) -> None:
        p, rng, sensor = self.params, self._rng, self.sensor
        H, W = sensor.shape
        self.t_exit = self._time_s("exit_s", 0.4) * US
        self.tr_us = p["transition_ms"] * 1e3
        self.t0_tr, self.t1_tr = self.t_exit - self.tr_us / 2, self.t_exit + self.tr_us / 2
        self.v = p["speed_kmh"] / 3.6 / US  # m/µs
        self.step = db_to_log(p["step_db"])
        f = 0.75 * W
        self.foe = (W / 2.0, 0.42 * H)
        res = 16.0
        self.inside = _Corridor(sensor, f, self.foe, 5.0, 1.5, 4.5, True, res, 48.0)
        self.outside = _Corridor(sensor, f, self.foe, 9.0, 1.5, 14.0, False, res, 60.0)
        tc = p["texture_contrast"]
        # --- tunnel atlas: tiles, wall stripes, ceiling lamps ---
        ti = self.inside
        th, tw = ti.shape_tex
        tex = _structured_texture(rng, th, tw, amp=0.5, density=0.6, size=(4, 28), wrap=True)
        tile = ((np.indices((th, tw)) % 16 == 0).any(0)).astype(np.float32)  # 1 m tile joints
        tex -= 0.35 * tile
        u_ceil0, u_ceil1 = (10 + 6) * res, (10 + 6 + 10) * res  # ceiling u range (texels)
        for k in range(int(48 / 12)):
            y0 = int((k * 12 + 2) * res)
            cv2.rectangle(tex, (int((u_ceil0 + u_ceil1) / 2 - 10), y0), (int((u_ceil0 + u_ceil1) / 2 + 10), y0 + 24),
                          2.2, -1)
        tex = _blur(tex, 0.6, True)
        self.tex_in = tex * tc
        shade = np.where(ti.floor, -0.4, np.where(ti.ceil, -0.2, 0.2)).astype(np.float32)
        self.in_gain = ti.haze
        self.in_off = shade
        # --- outside atlas: road with lane marks, facades with windows ---
        to = self.outside
        oh, ow = to.shape_tex
        tex = _structured_texture(rng, oh, ow, amp=0.6, density=0.7, size=(4, 40), wrap=True)
        lane_u = [(9.0 - 1.75) * res, (9.0 + 1.75) * res]
        for k in range(int(60 / 10)):
            for u in lane_u:
                cv2.rectangle(tex, (int(u - 2), int(k * 10 * res)), (int(u + 2), int((k * 10 + 3) * res)), 1.4, -1)
        for side_u0 in (18.0 * res, (to.total_u - 15.5) * res):  # windows on both facades
            for yy in range(0, oh, 40):
                for uu in range(int(side_u0 + 24), int(side_u0 + 15.5 * res - 24), 56):
                    cv2.rectangle(tex, (uu, yy + 6), (uu + 24, yy + 28), float(rng.uniform(-1.2, -0.5)), -1)
                    cv2.rectangle(tex, (uu, yy + 6), (uu + 24, yy + 28), 0.6, 2)
        tex = _blur(tex, 0.6, True)
        self.tex_out = tex * tc
        sky = 0.8 + 0.25 * tc * cv2.GaussianBlur(_noise(rng, H, W, 1.0, k0=1 / 40, kmax=0.05), (0, 0), 2)
        self.out_gain = np.where(to.sky, 0.0, to.haze).astype(np.float32)
        self.out_off = np.where(to.sky, sky, np.where(to.floor, -0.3, 0.1)).astype(np.float32)
        # normalise the levels so the mean inside (t = 0) / outside (at the exit) are exact
        self.t_ped = math.inf  # (pedestrian set up below, excluded from the normalisation)
        self.in_off += np.float32(p["inside_log"] - self._inside(0.0).mean())
        self.out_off += np.float32(p["inside_log"] + self.step - self._outside(self.t_exit).mean())
        # --- portal: tunnel depth at which the opening covers portal_frac of the image ---
        self.ln_zin = np.log(ti.z).astype(np.float32)
        frac = p["portal_frac"]
        self.z_min = float(np.quantile(ti.z, 1.0 - frac)) if frac > 0 else float(ti.z.max()) * 1.01
        self.portal_soft = 0.02  # ln depth units: ~2 % of the portal radius
        # --- pedestrian ---
        ph = int(round(p["pedestrian_px"]))
        pw = max(4, int(round(ph * 0.4)))
        self.ped_patch = _structured_texture(rng, ph, pw, amp=0.5, density=3.0, size=(2, max(3, ph / 5)))
        self.ped_patch[: ph // 2] += 0.6
        self.ped_patch[ph // 2:] -= 0.6
        alpha = np.zeros((ph, pw), np.float32)
        cv2.ellipse(alpha, (pw // 2, ph // 8), (max(1, pw // 4), max(1, ph // 9)), 0, 0, 360, 1.0, -1)  # head
        cv2.rectangle(alpha, (1, ph // 4), (pw - 2, ph - 1), 1.0, -1)
        self.ped_alpha = cv2.GaussianBlur(alpha, (0, 0), 0.7)
        self.ped_level_off = 0.4
        self.ped_y = self.foe[1] + 0.28 * H - ph  # feet on the road's right side
        self.t_ped = self.t_exit + p["pedestrian_delay_ms"] * 1e3
        self.ped_x0 = W - 1.0  # enters from the right edge
        self.annotations = {"transition_us": (self.t0_tr, self.t1_tr), "pedestrian_enters_us": self.t_ped,
                            "foe": self.foe}
        # motion bound for max_log_rate: gradient of a rendered frame x max flow
        g = max(np.abs(np.diff(self._inside(0.0), axis=1)).max(), np.abs(np.diff(self._outside(self.t_exit), axis=1)).max())
        flow_in = float((self.inside.flow_per_mps * (self.inside.z < 80)).max())
        flow_out = float((self.outside.flow_per_mps * ~self.outside.sky).max())
        self._motion_rate = 1.5 * float(g) * max(flow_in, flow_out) * self.v  # ln/µs
        i0, o0 = self._inside(0.0), self._outside(self.t_exit)
        self._span = float(max(o0.max() - i0.min(), i0.max() - o0.min())) + 0.5  # max |out - in| per pixel
        before = self._mean_now(self.t0_tr - 1.0)
        after = self._mean_now(self.t1_tr + 1.0)
        self.changes = [LightingChange(int(round(self.t_exit)), "tunnel exit", after - before)]

    def _inside(self, t: float) -> np.ndarray:
        img = self.inside.render(self.tex_in, self.v * t)
        return img * self.in_gain + self.in_off

    def _outside(self, t: float) -> np.ndarray:
        img = self.outside.render(self.tex_out, self.v * t)
        img = img * self.out_gain + self.out_off
        if t >= self.t_ped - 5e6:  # pedestrian (off screen before t_ped)
            x = self.ped_x0 - self.params["pedestrian_speed_px_s"] * (t - self.t_ped) / US
            lvl = self.params["inside_log"] + self.step + self.ped_level_off
            _paste(img, self.ped_patch, self.ped_alpha, x, self.ped_y, lvl)
        return img

    def _portal_depth(self, t: float) -> float:
        return self.z_min + self.v * max(self.t0_tr - t, 0.0)

    def log_irradiance(self, t_us: float) -> np.ndarray:
        t = self._check_t(t_us)
        ramp = _smoothstep_scalar((t - self.t0_tr) / self.tr_us)
        if ramp >= 1.0:
            return self._outside(t).astype(np.float32, copy=False)
        inside = self._inside(t)
        if self.params["portal_frac"] <= 0 and ramp <= 0.0:
            return inside
        w = (self.ln_zin - np.float32(math.log(self._portal_depth(t)))) * np.float32(1.0 / self.portal_soft)
        w = np.clip(w + 0.5, 0.0, 1.0)
        if ramp > 0.0:
            w = np.maximum(w, np.float32(ramp))
        if not w.any():
            return inside
        out = self._outside(t)
        inside += w * (out - inside)
        return inside

    def max_log_rate(self, t0_us: float, t1_us: float) -> float | None:
        rate = self._motion_rate
        if t1_us >= self.t0_tr and t0_us <= self.t1_tr:
            rate += self._span * 1.5 / self.tr_us
        tt = min(max(t1_us, t0_us), self.t0_tr)
        zp = self._portal_depth(tt)
        rate += self.step / self.portal_soft * self.v / zp
        return rate


# ---------------------------------------------------------------------------------------------
# indoor_outdoor
# ---------------------------------------------------------------------------------------------
class IndoorOutdoor(PresetScene):
    """Walking out of a building through a door, camera in hand (shake).

    The indoor wall with the door (a soft-edged opening showing the bright outdoor scene) is a
    textured plane the walker approaches at ``walk_speed_mps``; its image zooms about the door
    (1/distance) until the door covers ``door_frac`` of the view, when the transition starts
    (``exit_s - transition_ms/2``); the view then ramps (smoothstep in ln L) to the outdoor scene
    over ``transition_ms``. The outdoor scene (a textured plane 25 m behind the door) zooms slowly as
    the walk continues. Hand shake: smooth random-walk translation (``shake_px`` RMS per axis) and
    rotation (``shake_deg`` RMS) from the seed, applied to both layers.

    Parameters (defaults): ``inside_log`` = 5.0, ``step_db`` = 70 dB (60..80), ``exit_s`` = 50 % of the
    duration, ``transition_ms`` = 300, ``walk_speed_mps`` = 1.4, ``door_frac`` = 0.1, ``shake_px`` = 3.0,
    ``shake_deg`` = 0.5. Default duration 3 s. ``changes``: one "door exit" at ``exit_s``.
    """

    name = "indoor_outdoor"
    DEFAULT_DURATION_US = 3_000_000
    PARAMS = {
        "inside_log": Param(5.0, -5.0, 15.0, "mean ln L indoors"),
        "step_db": Param(70.0, 60.0, 80.0, "outdoor/indoor irradiance ratio, dB"),
        "exit_s": Param(None, 0.0, None, "time of passing the door, s (default 50 % of the duration)",
                        "opt_float"),
        "transition_ms": Param(300.0, 1.0, 3000.0, "duration of the door passage, ms"),
        "walk_speed_mps": Param(1.4, 0.0, 5.0, "walking speed, m/s"),
        "door_frac": Param(0.1, 0.005, 0.6, "image fraction of the door when the transition starts"),
        "shake_px": Param(3.0, 0.0, 30.0, "hand shake RMS translation, px"),
        "shake_deg": Param(0.5, 0.0, 10.0, "hand shake RMS rotation, degrees"),
    }

    def _build(self) -> None:
        p, rng, sensor = self.params, self._rng, self.sensor
        H, W = sensor.shape
        self.t_exit = self._time_s("exit_s", 0.5) * US
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
        self.shake = _Shake(rng, p["shake_px"], p["shake_deg"])
        self.off_in = np.float32(0.0)
        self.off_out = np.float32(0.0)
        self.off_in = np.float32(p["inside_log"] - self._inside(0.0)[0].mean())
        self.off_out = np.float32(p["inside_log"] + self.step - self._outside(self.t1_tr).mean())
        self._s_max = s_max
        self._motion_rate = 1.5 * float(np.abs(np.diff(tex, axis=1)).max()) * (
            self.shake.max_speed() + 0.5 * math.hypot(W, H) * v / self.z_min + math.radians(p["shake_deg"]) * 4 * 2 * math.pi * 12 * W) / US
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

    def _inside(self, t: float):
        m = self._view(t, (self.z0 / self._dist(t)) / self.os, self.door_c)
        return _warp(self.tex_in, m, self.sensor) + self.off_in, m

    def _outside(self, t: float) -> np.ndarray:
        D0 = self.z0 + self.dd
        D = max(D0 - self.v * t, D0 / 3.0)
        oh, ow = self.tex_out.shape
        m = self._view(t, (self.z0 + self.dd) / D / self.os * 1.0, (ow / 2, oh / 2))
        return _warp(self.tex_out, m, self.sensor) + self.off_out

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


# ---------------------------------------------------------------------------------------------
# flicker
# ---------------------------------------------------------------------------------------------
class Flicker(PresetScene):
    """A static room lit by ambient light and a mains-powered lamp, plus a light switched on and off.

    Linear irradiance ``L(x,t) = R(x) [E_a S(t) + E_l w(x) (1 + depth cos(2 pi mains_hz t))]``:
    ``R`` a structured reflectance texture, ``w`` the lamp's soft pool of light (a bright lamp
    blob at its top), ``E_l / E_a`` = ``lamp_db``, ``S(t)`` the switched light, 1 when off and
    ``switch_db`` brighter when on, toggled at ``switch_times_s`` (starting off), each switch a
    smoothstep ramp in ln S over ``switch_ms``.

    Parameters (defaults): ``base_log`` = 5.0 (mean ln L of the ambient-lit scene, switch off, without the
    lamp), ``mains_hz`` = 100 (lamp flicker frequency, twice the mains frequency), ``depth`` = 0.3
    (modulation depth, 0..0.95), ``lamp_db`` = 12 dB, ``switch_db`` = 20 dB, ``switch_times_s`` =
    [30 %, 60 %] of the duration, ``switch_ms`` = 2.0. Default duration 1 s.
    ``lamp_mask`` (bool image) marks where the lamp dominates. ``changes``: one per switch time.
    """

    name = "flicker"
    DEFAULT_DURATION_US = 1_000_000
    PARAMS = {
        "base_log": Param(5.0, -5.0, 15.0, "mean ln L of the ambient-lit scene"),
        "mains_hz": Param(100.0, 1.0, 1000.0, "lamp modulation frequency, Hz"),
        "depth": Param(0.3, 0.0, 0.95, "modulation depth of the lamp"),
        "lamp_db": Param(12.0, -20.0, 60.0, "lamp over ambient irradiance in its pool, dB"),
        "switch_db": Param(20.0, 0.0, 80.0, "switched light: on/off ratio, dB"),
        "switch_times_s": Param(None, kind="times", doc="times the light toggles, s (starts off)"),
        "switch_ms": Param(2.0, 0.0, 1000.0, "duration of a switch ramp, ms"),
    }

    def _build(self) -> None:
        p, rng, sensor = self.params, self._rng, self.sensor
        H, W = sensor.shape
        self.times = self._times_list("switch_times_s", (0.3, 0.6))
        R = _structured_texture(rng, H, W, amp=0.7, density=0.8, size=(5, 50))
        lx, ly = W * rng.uniform(0.25, 0.4), H * rng.uniform(0.3, 0.45)
        rr = ((self._xx - lx) / (0.22 * W)) ** 2 + ((self._yy - ly) / (0.3 * H)) ** 2
        w = np.exp(-rr ** 2).astype(np.float32)  # soft pool
        blob = np.exp(-(((self._xx - lx) ** 2 + (self._yy - ly + 0.22 * H) ** 2) / (0.03 * W) ** 2))
        w = w + 6.0 * blob.astype(np.float32)
        self.lamp_mask = w > 0.6
        el = 10 ** (p["lamp_db"] / 20)
        ys, xs = np.nonzero(w > 1e-4)
        self.roi = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
        expR = np.exp(R).astype(np.float32)
        self.A = np.exp(np.float32(p["base_log"]) + R).astype(np.float32)
        self.B = (self.A * el * w)[self.roi].copy()
        self.s_log = db_to_log(p["switch_db"])
        self.sw_us = p["switch_ms"] * 1e3
        self.omega = 2 * math.pi * p["mains_hz"] / US
        self.changes = []
        state = 0.0
        for i, ts in enumerate(self.times):
            new = 0.0 if state else 1.0
            m0 = np.log(self.A * math.exp(state * self.s_log) + 1e-30)
            m1 = np.log(self.A * math.exp(new * self.s_log) + 1e-30)
            m0[self.roi] = np.log(self.A[self.roi] * math.exp(state * self.s_log) + self.B)
            m1[self.roi] = np.log(self.A[self.roi] * math.exp(new * self.s_log) + self.B)
            self.changes.append(LightingChange(int(round(ts * US)), "light on" if new else "light off",
                                               float(m1.mean() - m0.mean())))
            state = new
        del expR

    def _switch(self, t: float) -> float:
        s = 0.0
        for k, ts in enumerate(self.times):
            target = 1.0 if k % 2 == 0 else 0.0
            x = (t - ts * US) / self.sw_us if self.sw_us > 0 else (1.0 if t >= ts * US else 0.0)
            if x <= 0:
                break
            s = s + (target - s) * _smoothstep_scalar(x)
        return s

    def log_irradiance(self, t_us: float) -> np.ndarray:
        t = self._check_t(t_us)
        S = math.exp(self._switch(t) * self.s_log)
        out = self.A * np.float32(S)
        mod = np.float32(1.0 + self.params["depth"] * math.cos(self.omega * t))
        out[self.roi] += self.B * mod
        return np.log(out)

    def max_log_rate(self, t0_us: float, t1_us: float) -> float | None:
        m = self.params["depth"]
        rate = m * self.omega / (1.0 - m)
        for ts in self.times:
            if t1_us >= ts * US and t0_us <= ts * US + self.sw_us:
                rate += self.s_log * 1.5 / max(self.sw_us, 1.0)
        return rate


# ---------------------------------------------------------------------------------------------
# static_lab
# ---------------------------------------------------------------------------------------------
class StaticLab(PresetScene):
    """A static lab scene (desk clutter, a checkerboard target, shelves) whose lights step between levels.

    ``ln L(x,t) = base(x) + db_to_log(level_db(t))`` with ``mean(base) = base_log``; ``level_db``
    starts at ``initial_db`` and changes at each ``(time_s, level_db)`` of ``steps`` with a smoothstep
    (in ln) of ``ramp_ms`` (0 = instantaneous). No motion: between steps the image is constant.

    Parameters (defaults): ``base_log`` = 5.0, ``initial_db`` = 0.0, ``steps`` = [(20 %, +20), (40 %,
    -20), (60 %, +40), (80 %, 0)] (times as fractions of the duration, levels in dB relative to
    ``base_log``), ``ramp_ms`` = 1.0. Default duration 5 s. ``changes``: one per step.
    """

    name = "static_lab"
    DEFAULT_DURATION_US = 5_000_000
    PARAMS = {
        "base_log": Param(5.0, -5.0, 15.0, "mean ln L at 0 dB"),
        "initial_db": Param(0.0, -100.0, 100.0, "light level at t = 0, dB relative to base_log"),
        "steps": Param(None, kind="steps", doc="list of (time s, level dB) light steps"),
        "ramp_ms": Param(1.0, 0.0, 10000.0, "duration of each light change, ms"),
    }

    def _build(self) -> None:
        p, rng, sensor = self.params, self._rng, self.sensor
        H, W = sensor.shape
        steps = p["steps"]
        if steps is None:
            d = self.duration_s
            steps = [(0.2 * d, 20.0), (0.4 * d, -20.0), (0.6 * d, 40.0), (0.8 * d, 0.0)]
        if not isinstance(steps, (list, tuple)):
            raise ParameterError(f"static_lab: steps must be a list of (time_s, level_db) pairs, got {steps!r}")
        clean = []
        for i, st in enumerate(steps):
            if not isinstance(st, (list, tuple)) or len(st) != 2:
                raise ParameterError(f"static_lab: steps[{i}] must be a (time_s, level_db) pair, got {st!r}")
            ts = _check_number(self.name, f"steps[{i}] time", st[0], 0.0, self.duration_s)
            lv = _check_number(self.name, f"steps[{i}] level", st[1], -100.0, 100.0)
            clean.append((ts, lv))
        if any(b[0] <= a[0] for a, b in zip(clean, clean[1:])):
            raise ParameterError(f"static_lab: step times must be strictly increasing, got {[s[0] for s in clean]}")
        p["steps"] = clean
        tex = _structured_texture(rng, H, W, amp=0.7, density=0.7, size=(5, 60))
        # checkerboard target and shelf lines
        cell = max(4, W // 40)
        cx0, cy0 = int(W * rng.uniform(0.5, 0.65)), int(H * rng.uniform(0.15, 0.3))
        for i in range(7):
            for j in range(5):
                cv2.rectangle(tex, (cx0 + i * cell, cy0 + j * cell), (cx0 + (i + 1) * cell - 1, cy0 + (j + 1) * cell - 1),
                              0.9 if (i + j) % 2 else -0.9, -1)
        for k in range(3):
            y = int(H * (0.55 + 0.12 * k))
            cv2.line(tex, (0, y), (W - 1, y), -0.8, 2)
        vign = -0.3 * (((self._xx - W / 2) / W) ** 2 + ((self._yy - H / 2) / H) ** 2) * 4
        base = tex + vign
        self.base = (base - base.mean() + p["base_log"]).astype(np.float32)
        self.ramp_us = p["ramp_ms"] * 1e3
        self.changes = []
        prev = p["initial_db"]
        for ts, lv in clean:
            self.changes.append(LightingChange(int(round(ts * US)), f"lights {prev:+g} -> {lv:+g} dB",
                                               db_to_log(lv - prev)))
            prev = lv

    def level_db(self, t_us: float) -> float:
        """The light level (dB relative to ``base_log``) at ``t_us``."""
        lv = self.params["initial_db"]
        for ts, new in self.params["steps"]:
            t0 = ts * US
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
        for ts, lv in self.params["steps"]:
            if t1_us >= ts * US and t0_us <= ts * US + self.ramp_us:
                rate = max(rate, abs(db_to_log(lv - prev)) * 1.5 / max(self.ramp_us, 1.0))
            prev = lv
        return rate


# ---------------------------------------------------------------------------------------------
# handheld_scan
# ---------------------------------------------------------------------------------------------
class HandheldScan(PresetScene):
    """Handheld scan over a sunlit facade crossed by moving soft shadow boundaries.

    The facade (3 x sensor width, 1.6 x height: windows, brick courses, signs, noise) is panned
    back and forth at ``scan_speed_px_s`` with a slow vertical drift and hand shake (``shake_px``,
    ``shake_deg``). Shadow bands (period ``shadow_period_px`` on the facade, half in sun) move across
    it at ``shadow_speed_px_s`` perpendicular to edges tilted by ``shadow_angle_deg``; edges are
    linear ramps ``shadow_soft_px`` wide; sun is brighter than shadow by ``shadow_db``.

    Parameters (defaults): ``base_log`` = 5.0 (mean ln L in shadow), ``shadow_db`` = 50 dB (10..100),
    ``shadow_speed_px_s`` = 120, ``shadow_period_px`` = 700, ``shadow_soft_px`` = 12,
    ``shadow_angle_deg`` = 70, ``scan_speed_px_s`` = 80, ``shake_px`` = 2.5, ``shake_deg`` = 0.4.
    Default duration 3 s. ``changes``: every time a shadow edge crosses the image centre (a local
    change: ``delta_log`` = +-db_to_log(shadow_db) at the centre, not of the mean).
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
        self.tex = (tex - tex.mean() + p["base_log"]).astype(np.float32)
        self.fshape = (fh, fw)
        self.shake = _Shake(rng, p["shake_px"], p["shake_deg"])
        self.step = db_to_log(p["shadow_db"])
        a = math.radians(p["shadow_angle_deg"])
        self.n = (math.sin(a), -math.cos(a))  # normal of the edges (facade coords)
        self.phase0 = rng.uniform(0, p["shadow_period_px"])
        self.x_lo, self.x_hi = W / 2 + 10, fw - W / 2 - 10
        self.ycen = fh / 2
        self._motion_rate = (1.5 * float(np.abs(np.diff(tex, axis=1)).max())
                             * (p["scan_speed_px_s"] + self.shake.max_speed() + 20) / US
                             + self.step / p["shadow_soft_px"] * (p["shadow_speed_px_s"] + p["scan_speed_px_s"]
                                                                  + self.shake.max_speed() + 20) / US)
        # changes: shadow edges crossing the image centre (sampled every 0.5 ms)
        ts = np.arange(0, self.duration_us + 1, 500.0)
        wc = np.array([self._weight_at_centre(t) for t in ts])
        idx = np.nonzero(np.diff(np.sign(wc - 0.5)) != 0)[0]
        self.changes = [LightingChange(int(ts[i + 1]), "sun edge at centre" if wc[i + 1] > wc[i] else
                                       "shadow edge at centre", self.step if wc[i + 1] > wc[i] else -self.step)
                        for i in idx]

    def _pose(self, t: float):
        """Facade point at the image centre (x, y) and shake (dx, dy, rot) at time t (µs)."""
        span = self.x_hi - self.x_lo
        d = self.params["scan_speed_px_s"] * t / US
        tri = d % (2 * span) if span > 0 else 0.0
        xc = self.x_lo + (tri if tri <= span else 2 * span - tri)
        yc = self.ycen + 0.08 * self.fshape[0] * math.sin(2 * math.pi * 0.23 * t / US)
        return (xc, yc), self.shake(t / US)

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
        c = nx * inv[0, 2] + ny * inv[1, 2] + self.params["shadow_speed_px_s"] * t / US + self.phase0
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


# ---------------------------------------------------------------------------------------------
# registry
# ---------------------------------------------------------------------------------------------
SCENARIOS: dict[str, Callable[..., Scene]] = {
    "tunnel_exit": TunnelExit,
    "indoor_outdoor": IndoorOutdoor,
    "flicker": Flicker,
    "static_lab": StaticLab,
    "handheld_scan": HandheldScan,
}


def scenario_params(name: str) -> dict[str, Param]:
    """The documented parameters (default, range, meaning) of a preset."""
    if name not in SCENARIOS:
        raise ParameterError(f"unknown scenario {name!r}; known: {', '.join(sorted(SCENARIOS))}")
    return dict(SCENARIOS[name].PARAMS)


def make_scenario(name: str, sensor: SensorGeometry = DAVIS346, duration_us: int | None = None, seed: int = 0,
                  **params) -> Scene:
    """Build the named preset; ``duration_us`` None uses the preset's default duration."""
    if not isinstance(name, str) or name not in SCENARIOS:
        raise ParameterError(f"unknown scenario {name!r}; known: {', '.join(sorted(SCENARIOS))}")
    return SCENARIOS[name](sensor=sensor, duration_us=duration_us, seed=seed, **params)


_SENSORS = {"DAVIS346": DAVIS346, "DAVIS240": DAVIS240}
_TOML_KEYS = {"name", "seed", "duration_s", "duration_us", "sensor", "params"}


def scenario_from_toml(path_or_text: str | os.PathLike) -> Scene:
    """Build a scenario from a TOML file path or TOML text (see the module docstring for the keys)."""
    if isinstance(path_or_text, os.PathLike) or (isinstance(path_or_text, str) and "=" not in path_or_text):
        path = Path(path_or_text)
        source = str(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as e:
            raise ProfileError(f"{source}: cannot read scenario file ({e.strerror or e})") from None
    elif isinstance(path_or_text, str):
        source, text = "scenario TOML", path_or_text
    else:
        raise ProfileError(f"scenario_from_toml needs a path or TOML text, got {type(path_or_text).__name__}")
    try:
        d = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ProfileError(f"{source}: invalid TOML: {e}") from None
    unknown = sorted(set(d) - _TOML_KEYS)
    if unknown:
        raise ProfileError(f"{source}: unknown key(s) {', '.join(unknown)}; accepted: {', '.join(sorted(_TOML_KEYS))}")
    if "name" not in d:
        raise ProfileError(f"{source}: missing key \"name\" (one of {', '.join(sorted(SCENARIOS))})")
    seed = d.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ProfileError(f"{source}: \"seed\" must be an integer, got {seed!r}")
    if "duration_s" in d and "duration_us" in d:
        raise ProfileError(f"{source}: give either duration_s or duration_us, not both")
    duration_us = None
    if "duration_s" in d:
        v = d["duration_s"]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise ProfileError(f"{source}: \"duration_s\" must be a positive number, got {v!r}")
        duration_us = int(round(v * US))
    elif "duration_us" in d:
        v = d["duration_us"]
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise ProfileError(f"{source}: \"duration_us\" must be a positive integer, got {v!r}")
        duration_us = v
    sensor = d.get("sensor", DAVIS346)
    if isinstance(sensor, str):
        if sensor not in _SENSORS:
            raise ProfileError(f"{source}: unknown sensor {sensor!r}; known: {', '.join(_SENSORS)} "
                               "or a table {width = .., height = ..}")
        sensor = _SENSORS[sensor]
    elif isinstance(sensor, dict):
        try:
            sensor = SensorGeometry(sensor["width"], sensor["height"])
        except KeyError as e:
            raise ProfileError(f"{source}: sensor table is missing {e}") from None
        except ParameterError as e:
            raise ProfileError(f"{source}: {e}") from None
    elif not isinstance(sensor, SensorGeometry):
        raise ProfileError(f"{source}: \"sensor\" must be a name or a table, got {sensor!r}")
    params = d.get("params", {})
    if not isinstance(params, dict):
        raise ProfileError(f"{source}: [params] must be a table, got {params!r}")
    try:
        return make_scenario(d["name"], sensor=sensor, duration_us=duration_us, seed=seed, **params)
    except ParameterError as e:
        raise ParameterError(f"{source}: {e}") from None
