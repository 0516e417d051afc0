"""The ``tunnel_exit`` preset: driving out of a tunnel into sunlight (forward motion, a growing portal)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from necviz.core.checks import check_number
from necviz.core.sensor import SensorGeometry
from necviz.drivers.sim.scene import LightingChange, db_to_log
from necviz.drivers.sim.scenes import mains
from necviz.drivers.sim.scenes.fiducials import PlacedMarker, paste_quad, quiet_corners
from necviz.drivers.sim.scenes.preset import (
    COMMON_PARAMS,
    US,
    Param,
    PresetScene,
    _bilinear,
    _blur,
    _noise,
    _smoothstep_scalar,
    _structured_texture,
)

__all__ = ["TunnelExit"]

#: Fiducial-marker signs beyond the exit, facing the camera: centre ``(X, Y)`` in m (right, up from the
#: camera), side of the marker's black border in m, distance ahead of the camera when it exits (m).
SIGNS = ((-2.0, 2.2, 1.6, 14.0), (2.6, 2.0, 1.6, 22.0), (0.0, 3.2, 2.0, 32.0))


@dataclass(frozen=True)
class _CrossSection:
    """A corridor's cross-section and texture atlas depth (m): half its width, the floor below and the
    ceiling (or, when open, the facades' top) above the camera, the atlas period along the corridor and
    the farthest depth rendered."""

    half_w: float
    floor_h: float
    top_h: float
    closed: bool
    period_m: float
    z_max: float = 300.0

    def __post_init__(self) -> None:
        for name in ("half_w", "floor_h", "top_h", "period_m", "z_max"):
            check_number(name, getattr(self, name), 0.0, lo_open=True, where="_CrossSection")


class _Corridor:
    """Box corridor (or open road with roadside facades and sky) seen from a camera moving along it.

    Every pixel's ray hits the floor, a wall or the ceiling at depth ``z`` (m); the surfaces are
    unrolled into one texture atlas (u = position around the cross-section, v = depth), so forward
    motion by ``s`` metres is a shift of the static v map: one ``cv2.remap`` per image, with the
    exact expanding flow from the focus of expansion. Distant texture is attenuated (haze/mip
    substitute) so it does not alias. ``f``: focal length (px); ``foe``: focus of expansion (px);
    ``res``: atlas texels per metre.
    """

    def __init__(self, sensor: SensorGeometry, f: float, foe: tuple[float, float], section: _CrossSection, res: float):
        half_w, floor_h, top_h, closed = section.half_w, section.floor_h, section.top_h, section.closed
        period_m, z_max = section.period_m, section.z_max
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

    ``changes``: one "tunnel exit" at ``exit_s`` (moved by ``change_jitter_ms``, with the whole
    transition, the pedestrian and the signs) with the mean ln L change across the transition (less
    than ``db_to_log(step_db)`` by the portal's share before it). ``annotations``: ``transition_us``
    (start, end), ``pedestrian_enters_us``, ``foe`` (x, y).

    Lamps (``lamp_depth > 0``): the tunnel's light flickers at ``lamp_hz``, a factor
    ``1 + lamp_depth s(t)`` on every inside surface (:mod:`.mains`; sinusoidal, or PWM with
    ``lamp_duty``), the outside's daylight steady; the levels and the exit's size are the lamps' mean.

    Markers (``markers``): three signs beyond the exit facing the camera (:data:`SIGNS`), each an
    ArUco marker (ids 0-2) 1.6-2 m wide, 14, 22 and 32 m ahead when the car exits, lit by the
    outside; they grow as the car approaches (visible, :mod:`necviz.core.markers`, once 18 px wide
    and seen through the portal or after the transition with at least 90 % weight).
    """

    name = "tunnel_exit"
    DEFAULT_DURATION_US = 2_000_000
    PARAMS = {
        "inside_log": Param(5.0, -5.0, 15.0, "mean ln L of the tunnel surfaces (portal excluded)"),
        "step_db": Param(60.0, 40.0, 140.0, "outside/inside irradiance ratio, dB"),
        "transition_ms": Param(40.0, 1.0, 1000.0, "duration of the portal passage, ms"),
        "exit_s": Param(
            None,
            0.0,
            None,
            "time the portal is passed (middle of the transition), s",
            "opt_float",
            default_text="40 % of the duration",
            range_text="inside the duration",
        ),
        "speed_kmh": Param(60.0, 0.0, 300.0, "forward speed, km/h"),
        "portal_frac": Param(0.08, 0.0, 0.5, "image fraction covered by the portal when the transition starts"),
        "texture_contrast": Param(1.0, 0.0, 3.0, "multiplier of the texture contrast"),
        "pedestrian_delay_ms": Param(150.0, 0.0, 1e6, "pedestrian enters the view this long after the exit, ms"),
        "pedestrian_speed_px_s": Param(60.0, 0.0, 2000.0, "lateral pedestrian speed, px/s"),
        "pedestrian_px": Param(48.0, 8.0, 250.0, "pedestrian height, px"),
        "lamp_depth": Param(
            0.0, 0.0, 0.95, "the tunnel's lamps (all its light) flicker with this modulation depth; 0: steady"
        ),
        "lamp_hz": Param(100.0, 1.0, 1000.0, "the tunnel lamps' flicker frequency (twice the mains), Hz"),
        "lamp_duty": Param(0.0, 0.0, 0.9, "the tunnel lamps' waveform: 0 sinusoidal, else PWM on for this fraction"),
        **COMMON_PARAMS,
    }

    def _build(self) -> None:
        p, rng, sensor = self.params, self._rng, self.sensor
        H, W = sensor.shape
        self._lamps_on = False  # levels, bounds and the change's size are the lamps' mean
        self.t_exit = self._jittered_us("exit_s", [self._time_s("exit_s", 0.4) * US])[0]
        self.tr_us = p["transition_ms"] * 1e3
        self.t0_tr, self.t1_tr = self.t_exit - self.tr_us / 2, self.t_exit + self.tr_us / 2
        self.v = p["speed_kmh"] / 3.6 / US  # m/µs
        self.step = db_to_log(p["step_db"])
        f = 0.75 * W
        self.foe = (W / 2.0, 0.42 * H)
        res = 16.0
        self.inside = _Corridor(sensor, f, self.foe, _CrossSection(5.0, 1.5, 4.5, True, 48.0), res)
        self.outside = _Corridor(sensor, f, self.foe, _CrossSection(9.0, 1.5, 14.0, False, 60.0), res)
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
            cv2.rectangle(
                tex, (int((u_ceil0 + u_ceil1) / 2 - 10), y0), (int((u_ceil0 + u_ceil1) / 2 + 10), y0 + 24), 2.2, -1
            )
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
        self._sign_ahead: list[float] = []  # (marker signs too)
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
        self.ped_patch[ph // 2 :] -= 0.6
        alpha = np.zeros((ph, pw), np.float32)
        cv2.ellipse(alpha, (pw // 2, ph // 8), (max(1, pw // 4), max(1, ph // 9)), 0, 0, 360, 1.0, -1)  # head
        cv2.rectangle(alpha, (1, ph // 4), (pw - 2, ph - 1), 1.0, -1)
        self.ped_alpha = cv2.GaussianBlur(alpha, (0, 0), 0.7)
        self.ped_level_off = 0.4
        self.ped_y = self.foe[1] + 0.28 * H - ph  # feet on the road's right side
        self.t_ped = self.t_exit + p["pedestrian_delay_ms"] * 1e3
        self.ped_x0 = W - 1.0  # enters from the right edge
        # --- fiducial-marker signs beyond the exit (world corners: X, Y, depth ahead at the exit) ---
        if p["markers"]:
            for k, (X, Y, side, ahead) in enumerate(SIGNS):
                h = side / 2
                world = np.array([[X - h, Y + h], [X + h, Y + h], [X + h, Y - h], [X - h, Y - h]])
                self.markers.append(PlacedMarker(k, world, f"sign at {ahead:g} m"))
                self._sign_ahead.append(ahead)
        self.annotations = {
            "transition_us": (self.t0_tr, self.t1_tr),
            "pedestrian_enters_us": self.t_ped,
            "foe": self.foe,
        }
        # motion bound for max_log_rate: gradient of a rendered frame x max flow
        g = max(
            np.abs(np.diff(self._inside(0.0), axis=1)).max(), np.abs(np.diff(self._outside(self.t_exit), axis=1)).max()
        )
        flow_in = float((self.inside.flow_per_mps * (self.inside.z < 80)).max())
        flow_out = float((self.outside.flow_per_mps * ~self.outside.sky).max())
        self._motion_rate = 1.5 * float(g) * max(flow_in, flow_out) * self.v  # ln/µs
        i0, o0 = self._inside(0.0), self._outside(self.t_exit)
        self._span = float(max(o0.max() - i0.min(), i0.max() - o0.min())) + 0.5  # max |out - in| per pixel
        before = self._mean_now(self.t0_tr - 1.0)
        after = self._mean_now(self.t1_tr + 1.0)
        self.changes = [LightingChange(int(round(self.t_exit)), "tunnel exit", after - before)]
        self._lamps_on = True

    def _inside(self, t: float) -> np.ndarray:
        img = self.inside.render(self.tex_in, self.v * t)
        return img * self.in_gain + self.in_off + np.float32(self._lamp_log(t))

    def _lamp_log(self, t: float) -> float:
        """ln of the tunnel lamps' flicker factor (0 while the scene is built: the levels are the mean's)."""
        p = self.params
        if p["lamp_depth"] <= 0.0 or not self._lamps_on:
            return 0.0
        return math.log1p(p["lamp_depth"] * mains.modulation(t, p["lamp_hz"], p["lamp_duty"]))

    def _outside(self, t: float) -> np.ndarray:
        img = self.outside.render(self.tex_out, self.v * t)
        img = img * self.out_gain + self.out_off
        if t >= self.t_ped - 5e6:  # pedestrian (off screen before t_ped)
            x = self.ped_x0 - self.params["pedestrian_speed_px_s"] * (t - self.t_ped) / US
            lvl = self.params["inside_log"] + self.step + self.ped_level_off
            _paste(img, self.ped_patch, self.ped_alpha, x, self.ped_y, lvl)
        for k, corners in self._sign_corners(t):
            paste_quad(img, k, corners)
        return img

    def _sign_corners(self, t: float) -> list[tuple[int, np.ndarray]]:
        """Image corners of every sign in front of the camera at ``t`` (pinhole projection, pixel centres
        at integers: ``x = foe_x - 0.5 + f X / z``, as the corridor's rays)."""
        f = 0.75 * self.sensor.width
        out = []
        for mk, ahead in zip(self.markers, self._sign_ahead, strict=True):
            z = ahead + self.v * (self.t_exit - t)
            if z > 1.0:
                xy = mk.corners
                pts = np.stack([self.foe[0] - 0.5 + f * xy[:, 0] / z, self.foe[1] - 0.5 - f * xy[:, 1] / z], axis=1)
                out.append((mk.marker_id, pts))
        return out

    def _outside_weight(self, t: float, points) -> np.ndarray:
        """The outside view's share (0..1) at image ``points`` (..., 2), as :meth:`log_irradiance` blends."""
        ramp = _smoothstep_scalar((t - self.t0_tr) / self.tr_us)
        if ramp >= 1.0:
            return np.ones(np.shape(points)[:-1])
        ln_z = _bilinear(self.ln_zin, np.asarray(points))
        w = np.clip((ln_z - math.log(self._portal_depth(t))) / self.portal_soft + 0.5, 0.0, 1.0)
        return np.maximum(w, ramp)

    def _marker_geometry(self, t_us: float):
        signs = self._sign_corners(float(t_us))
        ids = np.array([k for k, _ in signs], np.int64)
        corners = np.array([c for _, c in signs], np.float64).reshape(-1, 4, 2)
        weight = np.array([self._outside_weight(float(t_us), quiet_corners(c)).min() for c in corners])
        return ids, corners, weight

    def pedestrian_box(self, t_us: float, min_visible: float = 0.5) -> tuple[int, int, int, int] | None:
        """The pedestrian's bounding box ``(x0, y0, x1, y1)`` at ``t_us`` (pixels, end-exclusive, clipped
        to the sensor), or ``None`` while less than ``min_visible`` of its width is in view.

        Ground truth for the detection metric (is the pedestrian well exposed on the first frame it
        can be seen on?). The figure's top-left corner is at ``x = W - 1 - v (t - t_enter)``,
        ``y = ped_y`` (:meth:`_outside` pastes it there); its box is the patch's size. The default,
        half the figure in view, is lenient: the Caltech pedestrian benchmark (Dollár et al.,
        "Pedestrian detection: an evaluation of the state of the art", TPAMI 2012) already calls a
        figure more than 35 % occluded heavily occluded. The box ignores the transition's blend
        (the pedestrian enters ``pedestrian_delay_ms`` after the exit, once the view is outside).
        """
        if not self.t_ped <= float(t_us) or not math.isfinite(self.t_ped):
            return None
        H, W = self.sensor.shape
        ph, pw = self.ped_patch.shape
        x = self.ped_x0 - self.params["pedestrian_speed_px_s"] * (float(t_us) - self.t_ped) / US
        x0, x1 = max(int(math.floor(x)), 0), min(int(math.ceil(x + pw)), W)
        y0, y1 = max(int(math.floor(self.ped_y)), 0), min(int(math.ceil(self.ped_y + ph)), H)
        if x1 <= x0 or y1 <= y0 or (x1 - x0) < min_visible * pw:
            return None
        return x0, y0, x1, y1

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
        p = self.params
        rate = self._motion_rate + mains.max_log_rate(p["lamp_hz"], p["lamp_depth"], p["lamp_duty"])
        if t1_us >= self.t0_tr and t0_us <= self.t1_tr:
            rate += self._span * 1.5 / self.tr_us
        tt = min(max(t1_us, t0_us), self.t0_tr)
        zp = self._portal_depth(tt)
        rate += self.step / self.portal_soft * self.v / zp
        return rate
