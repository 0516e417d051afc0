"""The calibration scene: a textured static scene under lighting ramps of many speeds and sizes.

This scene exists to calibrate the six TEDI parameters (Eq. 7 of Lin et al.'s NEC paper) on data
that no evaluation uses: the evaluation presets (``tunnel_exit``, ``indoor_outdoor``, ``flicker``,
``static_lab``, ``handheld_scan``) never appear in it, and it is not registered as a preset.

What Eq. 7 needs, and how the scene provides it:

* **several events per pixel between consecutive frames while the pixel stays valid** — every
  pixel sees the same texture all the time (ln contrast ``contrast``, clipped to about
  ±3 ``contrast``), and the lighting changes by 0.3 to 6 ln units per change (up to 52 dB), so a
  frame pair across a change carries ~1 to ~25 threshold crossings per pixel;
* **fast changes, where the compensation ``a±, b±`` acts** — each ramp lasts a log-uniform
  ``ramp_ms`` (3 to 300 ms by default), i.e. from ~1 to ~1000 ln units per second; at the sensor's
  12 Mev/s ceiling a whole-sensor ramp is under-counted above ~30 ln/s, and the refractory period
  and the photoreceptor bandwidth under-count the fastest ones in every pixel;
* **global and partial changes** — a fraction ``spot_prob`` of the changes light only a soft-edged
  "lamp" region (15-35 % of the image), so the per-pixel rate and the sensor-wide rate vary
  independently (as in a tunnel portal or a door);
* **up and down, in staircases** — each region's level climbs or falls in 1-3 consecutive
  changes before turning (within ``level_range``/``spot_range``), so ON and OFF thresholds are
  both exercised and most changes continue the previous direction (a DVS pixel loses about half
  an event at every reversal, which the calibration's continuation rule avoids);
* **no motion by default** — a tripod-mounted camera: every event comes from the lighting, so
  each pixel's change is monotonic within a ramp. ``motion_px`` adds a smooth hand-held-like
  jitter; its back-and-forth edge crossings cost about half an event per reversal (the DVS
  hysteresis), which Eq. 7 reads as larger thresholds (measured: +3-5 % at 1.5 px RMS);
* **exposure brackets for the camera response** — the first ``bracket_s`` seconds are static (no
  motion, constant light): a driver that steps the exposure there gives Debevec-Malik its input.

``ln L(x, t) = base_log + T(x - m(t)) + level(t) + spot(x) spot_level(t)`` with ``T`` the
zero-mean texture, ``m(t)`` the jitter, ``level``/``spot_level`` piecewise smoothstep ramps in ln L.
The schedule, the texture, the lamp region and the jitter all come from ``seed``; the names in double
backquotes above are fields of :class:`CalibrationSceneOptions`.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import asdict, dataclass

import cv2
import numpy as np

from necviz.core.checks import check_number
from necviz.core.errors import ParameterError
from necviz.core.sensor import DAVIS346, SensorGeometry
from necviz.drivers.sim.scene import LightingChange, Scene

__all__ = ["CalibrationScene", "CalibrationSceneOptions", "CALIBRATION_SCENE"]

#: The name ``necviz calibrate --sim`` accepts for this scene.
CALIBRATION_SCENE = "calibration"


def _smoothstep(x: float) -> float:
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


class _Ramps:
    """A piecewise-constant level joined by smoothstep ramps: ``(t0_us, t1_us, from, to)`` segments."""

    def __init__(self, segments: list[tuple[float, float, float, float]]):
        self.segments = segments
        self.starts = [s[0] for s in segments]

    def __call__(self, t_us: float) -> float:
        j = bisect.bisect_right(self.starts, t_us) - 1
        if j < 0:
            return self.segments[0][2] if self.segments else 0.0
        t0, t1, a, b = self.segments[j]
        if t_us >= t1:
            return b
        return a + (b - a) * _smoothstep((t_us - t0) / (t1 - t0))


@dataclass(frozen=True)
class CalibrationSceneOptions:
    """The calibration scene's texture, lighting schedule and motion (validated here, once).

    Parameters
    ----------
    base_log : float
        Mean ``ln L`` at level 0 (well exposed at ~4 ms), -5..15.
    contrast : float
        ln standard deviation of the texture, 0..1.5.
    motion_px : float
        RMS jitter per axis (px), 0..20; 0 (default) is a static, tripod-mounted camera.
    bracket_s : float
        The static opening for exposure brackets (s, >= 0; at most the scene's duration).
    level_range, spot_range : tuple of float
        ``(low, high)`` of the global level and of the lamp region's extra level (ln units,
        -10..10 each), each at least twice ``min_step`` wide.
    ramp_ms : tuple of float
        ``(low, high)`` of the log-uniform ramp durations (ms, 0.1..10,000).
    hold_ms : tuple of float
        ``(low, high)`` of the uniform hold after each ramp (ms, 1..10,000).
    min_step : float
        The smallest change (ln units), 0..5.
    spot_prob : float
        The fraction of changes that light only the lamp region, 0..1.

    Raises
    ------
    ParameterError
        A value out of its range, a pair that is not ``(low, high)`` with ``low <= high``, or a
        level range narrower than twice ``min_step``.
    """

    base_log: float = 5.0
    contrast: float = 0.35
    motion_px: float = 0.0
    bracket_s: float = 0.4
    level_range: tuple[float, float] = (-2.0, 4.0)
    spot_range: tuple[float, float] = (-1.0, 2.0)
    ramp_ms: tuple[float, float] = (3.0, 300.0)
    hold_ms: tuple[float, float] = (40.0, 120.0)
    min_step: float = 0.3
    spot_prob: float = 0.35

    def __post_init__(self) -> None:
        name = CALIBRATION_SCENE
        checked: dict = {
            "base_log": check_number("base_log", self.base_log, -5.0, 15.0, where=name),
            "contrast": check_number("contrast", self.contrast, 0.0, 1.5, where=name),
            "motion_px": check_number("motion_px", self.motion_px, 0.0, 20.0, where=name),
            "bracket_s": check_number("bracket_s", self.bracket_s, 0.0, where=name),
        }
        for key, lo, hi in (
            ("level_range", -10.0, 10.0),
            ("spot_range", -10.0, 10.0),
            ("ramp_ms", 0.1, 10_000.0),
            ("hold_ms", 1.0, 10_000.0),
        ):
            v = getattr(self, key)
            if not isinstance(v, (tuple, list)) or len(v) != 2:
                raise ParameterError(f"{name}: {key} must be a (low, high) pair, got {v!r}")
            a = check_number(f"{key}[0]", v[0], lo, hi, where=name)
            b = check_number(f"{key}[1]", v[1], lo, hi, where=name)
            if b < a:
                raise ParameterError(f"{name}: {key} = {v!r} must be (low, high) with low <= high")
            checked[key] = (a, b)
        min_step = checked["min_step"] = check_number("min_step", self.min_step, 0.0, 5.0, where=name)
        checked["spot_prob"] = check_number("spot_prob", self.spot_prob, 0.0, 1.0, where=name)
        for key in ("level_range", "spot_range"):
            lo, hi = checked[key]
            if hi - lo < 2 * min_step:
                raise ParameterError(f"{name}: {key} {checked[key]} is narrower than twice min_step ({min_step:g})")
        for key, value in checked.items():
            object.__setattr__(self, key, value)


class CalibrationScene(Scene):
    """Textured static scene with lighting ramps of varied speed and size (module docstring).

    Default duration 6 s. ``changes``: one :class:`LightingChange` per ramp (mean ln L change);
    ``params``: the options as a dict (as every scene reports its parameters).

    Parameters
    ----------
    sensor : SensorGeometry
        The sensor the scene is rendered for.
    duration_us : int, optional
        Length of the scene (µs; default :attr:`DEFAULT_DURATION_US`).
    seed : int
        Seeds the schedule, the texture, the lamp region and the jitter.
    options : CalibrationSceneOptions, optional
        Texture, lighting schedule and motion (default: ``CalibrationSceneOptions()``).

    Raises
    ------
    ParameterError
        A sensor that is not a :class:`SensorGeometry`, ``options`` that is not a
        :class:`CalibrationSceneOptions`, or a bracket opening longer than the scene.
    """

    name = CALIBRATION_SCENE
    DEFAULT_DURATION_US = 6_000_000

    def __init__(
        self,
        sensor: SensorGeometry = DAVIS346,
        duration_us: int | None = None,
        seed: int = 0,
        options: CalibrationSceneOptions | None = None,
    ):
        if not isinstance(sensor, SensorGeometry):
            raise ParameterError(f"{self.name}: sensor must be a SensorGeometry, got {sensor!r}")
        options = CalibrationSceneOptions() if options is None else options
        if not isinstance(options, CalibrationSceneOptions):
            raise ParameterError(f"{self.name}: options must be CalibrationSceneOptions, got {type(options).__name__}")
        duration_us = self.DEFAULT_DURATION_US if duration_us is None else duration_us
        super().__init__(sensor, duration_us, seed)
        dur_s = self.duration_us / 1e6
        if options.bracket_s > dur_s:
            raise ParameterError(
                f"{self.name}: bracket_s = {options.bracket_s:g} is longer than the scene ({dur_s:g} s)"
            )
        self.options = options
        self.params = asdict(options)
        motion_px = options.motion_px
        self.bracket_us = int(round(options.bracket_s * 1e6))
        rng = np.random.default_rng([self.seed, 0xCA1])
        H, W = sensor.shape
        self._margin = int(math.ceil(4 * motion_px)) + 2
        self._texture = self._make_texture(rng, H + 2 * self._margin, W + 2 * self._margin, options.contrast)
        self._spot = self._make_spot(rng, H, W)
        self._jitter = self._make_jitter(rng, motion_px)
        self._global, self._lamp, self.changes = self._make_schedule(rng)

    # -- construction ------------------------------------------------------------------------------
    @staticmethod
    def _make_texture(rng: np.random.Generator, h: int, w: int, contrast: float) -> np.ndarray:
        """Zero-mean ln-contrast texture: smooth noise at three scales plus sharp-edged shapes."""
        tex = np.zeros((h, w), np.float32)
        for cell, amp in ((48, 0.6), (16, 0.4), (5, 0.25)):
            gh, gw = h // cell + 2, w // cell + 2
            coarse = rng.standard_normal((gh, gw)).astype(np.float32)
            tex += amp * cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC)
        n = max(4, h * w // 700)
        for _ in range(n):
            v = float(rng.normal(0.0, 1.2))
            cx, cy = int(rng.integers(0, w)), int(rng.integers(0, h))
            sz = int(rng.integers(3, max(4, min(h, w) // 6)))
            if rng.random() < 0.5:
                cv2.rectangle(tex, (cx - sz, cy - sz // 2), (cx + sz, cy + sz // 2), v, -1)
            else:
                cv2.ellipse(tex, (cx, cy), (sz, max(2, sz // 2)), float(rng.uniform(0, 180)), 0, 360, v, -1)
        tex = cv2.GaussianBlur(tex, (0, 0), 0.7)
        tex -= tex.mean()
        tex *= contrast / max(float(tex.std()), 1e-6)
        lim = 3.0 * contrast
        if lim > 0:
            tex = lim * np.tanh(tex / lim)  # soft clip: keeps every pixel within the valid range
        tex -= tex.mean()
        return tex.astype(np.float32)

    @staticmethod
    def _make_spot(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
        """A soft-edged elliptical lamp region covering 15-35 % of the image (weights 0..1)."""
        frac = rng.uniform(0.15, 0.35)
        aspect = rng.uniform(0.6, 1.6)
        ry = math.sqrt(frac * h * w / (math.pi * aspect))
        rx = aspect * ry
        cx, cy = rng.uniform(0.3, 0.7) * w, rng.uniform(0.3, 0.7) * h
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        r = np.sqrt(((xx - cx) / rx) ** 2 + ((yy - cy) / ry) ** 2)
        edge = 6.0 / max(min(rx, ry), 1.0)
        return np.clip((1.0 + edge - r) / (2 * edge), 0.0, 1.0).astype(np.float32)

    @staticmethod
    def _make_jitter(rng: np.random.Generator, px: float):
        f = np.exp(rng.uniform(math.log(0.3), math.log(4.0), size=(2, 6)))
        a = 1.0 / f
        a *= px * math.sqrt(2.0) / np.sqrt((a**2).sum(axis=1, keepdims=True))
        ph = rng.uniform(0.0, 2 * math.pi, size=(2, 6))
        return f, a, ph

    def _make_schedule(self, rng: np.random.Generator):
        """Staircases: 1-3 changes in one direction, then the other way, per region (module docstring)."""
        p = self.params
        glob, lamp, changes = [], [], []
        state = {"global": [0.0, 1, 0], "lamp": [0.0, 1, 0]}  # level, direction, changes left in this run
        lo_r, hi_r = p["ramp_ms"]
        t = self.bracket_us + 100_000.0
        end = self.duration_us - 60_000.0
        spot_share = float(self._spot.mean())
        while True:
            region = "lamp" if rng.random() < p["spot_prob"] else "global"
            lo, hi = p["spot_range"] if region == "lamp" else p["level_range"]
            st = state[region]
            cur, direction, left = st
            room = hi - cur if direction > 0 else cur - lo
            if left <= 0 or room < p["min_step"]:
                direction = -direction
                left = int(rng.integers(1, 4))
                room = hi - cur if direction > 0 else cur - lo
            size = float(rng.uniform(p["min_step"], max(p["min_step"], min(room, 1.5 * room / left))))
            new = cur + direction * size
            ramp = 1e3 * math.exp(rng.uniform(math.log(lo_r), math.log(hi_r)))
            hold = 1e3 * rng.uniform(*p["hold_ms"])
            if t + ramp + hold > end:
                break
            (lamp if region == "lamp" else glob).append((t, t + ramp, cur, new))
            share = spot_share if region == "lamp" else 1.0
            changes.append(
                LightingChange(
                    int(round(t + ramp / 2)),
                    f"{region} {cur:+.2f} -> {new:+.2f} ln in {ramp / 1e3:.3g} ms",
                    (new - cur) * share,
                )
            )
            state[region] = [new, direction, left - 1]
            t += ramp + hold
        return _Ramps(glob), _Ramps(lamp), changes

    # -- evaluation --------------------------------------------------------------------------------
    def offset(self, t_us: float) -> tuple[float, float]:
        """The jitter ``m(t)`` in pixels (zero during the static bracket opening, eased in after it)."""
        if self.params["motion_px"] <= 0 or t_us <= self.bracket_us:
            return 0.0, 0.0
        f, a, ph = self._jitter
        ts = t_us / 1e6
        ease = _smoothstep((t_us - self.bracket_us) / 100_000.0)
        base = np.sin(2 * math.pi * f * (self.bracket_us / 1e6) + ph)
        v = (a * (np.sin(2 * math.pi * f * ts + ph) - base)).sum(axis=1) * ease
        return float(v[0]), float(v[1])

    def levels(self, t_us: float) -> tuple[float, float]:
        """``(level, spot_level)`` at ``t_us`` (ln units)."""
        return self._global(t_us), self._lamp(t_us)

    def log_irradiance(self, t_us: float) -> np.ndarray:
        t = float(t_us)
        if not math.isfinite(t):
            raise ParameterError(f"{self.name}: time must be finite, got {t_us!r}")
        H, W = self.sensor.shape
        dx, dy = self.offset(t)
        m = self._margin
        if dx == 0.0 and dy == 0.0:
            img = self._texture[m : m + H, m : m + W].copy()
        else:
            mat = np.array([[1.0, 0.0, dx - m], [0.0, 1.0, dy - m]], np.float64)
            img = cv2.warpAffine(self._texture, mat, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        lv, sp = self.levels(t)
        img += np.float32(self.params["base_log"] + lv)
        if sp != 0.0:
            img += np.float32(sp) * self._spot
        return img

    def mean_log(self, t_us: float) -> float:
        """Mean ``ln L`` over the sensor at ``t_us`` (the texture is zero-mean)."""
        lv, sp = self.levels(t_us)
        return self.params["base_log"] + lv + sp * float(self._spot.mean())
