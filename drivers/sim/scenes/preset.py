"""Shared parts of the scenario presets: documented parameters, the preset base class, textures and warps.

:class:`Param` documents one parameter (default, accepted range, meaning with its unit);
:class:`PresetScene` checks a preset's ``PARAMS`` (with :func:`necviz.core.checks.check_number`),
seeds its random generator and builds its textures once; :func:`params_table` and
:func:`params_markdown` render a ``PARAMS`` dict as a reStructuredText table (appended to every
preset's class docstring when the class is defined) or as Markdown (``docs/simulator.md``).

Every preset also takes the parameters of :data:`COMMON_PARAMS`: ``change_jitter_ms`` moves each
lighting change by a seeded random offset (see :meth:`PresetScene._jitter_us`); by default by up to
half the APS model's frame interval either way, so every seed meets the frame clock at its own,
uniformly drawn phase (independent replicates); ``markers`` draws the preset's fiducial markers
(:mod:`.fiducials`), whose ground truth :meth:`PresetScene.marker_truth` gives.
"""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass
from itertools import pairwise
from typing import Any

import cv2
import numpy as np

from necviz.core.checks import check_number, format_number
from necviz.core.errors import ParameterError
from necviz.core.markers import MarkerTruth, visibility
from necviz.core.sensor import DAVIS346, SensorGeometry
from necviz.drivers.sim.aps import ApsParams
from necviz.drivers.sim.scene import Scene
from necviz.drivers.sim.scenes.fiducials import PlacedMarker, paint, patch_size

US = 1e6  # µs per second
JITTER_STREAM = 0x6A17  # spawn key of the change-time jitter stream (independent of the textures' stream)
#: Default ``change_jitter_ms``: half the APS model's default frame interval (10 ms at 50 fps), so the
#: offsets, uniform in [-j, +j], put each change at a uniform phase of the frame clock.
DEFAULT_JITTER_MS = ApsParams.frame_interval_us / 2 / 1000


# ---------------------------------------------------------------------------------------------
# parameters
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Param:
    """One documented preset parameter: default, accepted closed range and unit/meaning.

    ``kind``: ``"float"`` (a number in ``[lo, hi]``), ``"opt_float"`` (``None`` = a default derived
    from the duration), ``"flag"`` (true or false), ``"times"`` (a list of times in s) or ``"steps"``
    (a list of (time s, level dB)).
    ``default_text`` and ``range_text`` replace the generated table cells where the numbers alone
    do not say it (derived defaults, lists).
    """

    default: Any
    lo: float | None = None
    hi: float | None = None
    doc: str = ""
    kind: str = "float"
    default_text: str = ""
    range_text: str = ""

    def default_cell(self) -> str:
        if self.default_text:
            return self.default_text
        if self.kind == "flag":
            return "true" if self.default else "false"
        return "derived" if self.default is None else format_number(self.default)

    def range_cell(self) -> str:
        if self.range_text:
            return self.range_text
        if self.kind == "flag":
            return "true, false"
        lo, hi = self.lo, self.hi
        if lo is not None and hi is not None:
            return f"[{format_number(lo)}, {format_number(hi)}]"
        if lo is not None:
            return f">= {format_number(lo)}"
        if hi is not None:
            return f"<= {format_number(hi)}"
        return "any number"


#: Parameters every preset takes (appended to each preset's own ``PARAMS``).
COMMON_PARAMS = {
    "change_jitter_ms": Param(
        DEFAULT_JITTER_MS,
        0.0,
        1000.0,
        "moves each lighting change by a seeded uniform offset in [-j, +j] ms (whole µs), so each seed meets "
        "the frame clock at its own phase; default half the APS frame interval (uniform phase over the 20 ms "
        "frame; less if changes are closer than 2j); 0: the nominal times, the same for every seed",
    ),
    "phase_key": Param(
        0.0,
        0.0,
        2.0**31 - 1,
        "a whole number keying the change-time offsets' random stream together with the seed: scenes with "
        "different keys draw independent phases for the same seed (a sealed set gives each scene its own); 0: "
        "the seed alone (every scene of a family at the same offsets for a seed)",
    ),
    "markers": Param(
        True,
        kind="flag",
        doc="draw the preset's ArUco fiducial markers (DICT_4X4_50, ±1 ln around the local level) for the "
        "marker-detection metrics; false: the scene without them",
    ),
}


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def params_table(params: dict[str, Param]) -> str:
    """``params`` as a reStructuredText simple table: parameter, default, range, meaning (unit)."""
    rows = [("parameter", "default", "range", "meaning")]
    rows += [(f"``{k}``", p.default_cell(), p.range_cell(), p.doc) for k, p in params.items()]
    w = [max(len(r[i]) for r in rows) for i in range(3)]
    rule = "  ".join("=" * n for n in (*w, max(len(r[3]) for r in rows)))
    line = lambda r: "  ".join(c.ljust(n) for c, n in zip(r[:3], w, strict=True)) + "  " + r[3]
    return "\n".join([rule, line(rows[0]), rule, *(line(r) for r in rows[1:]), rule])


def params_markdown(params: dict[str, Param]) -> str:
    """``params`` as a Markdown table: parameter, default, range, meaning (unit)."""
    out = ["| parameter | default | range | meaning |", "|---|---|---|---|"]
    out += [
        f"| `{k}` | {_cell(p.default_cell())} | {_cell(p.range_cell())} | {_cell(p.doc)} |" for k, p in params.items()
    ]
    return "\n".join(out)


def summary(cls) -> str:
    """The first line of a preset's docstring (its one-line description)."""
    return inspect.cleandoc(cls.__doc__ or "").split("\n", 1)[0]


def _document(cls) -> None:
    """Append the generated parameter table to a preset's docstring (once, when the class is defined)."""
    doc = inspect.cleandoc(cls.__doc__ or "")
    cls.__doc__ = (
        f"{doc}\n\nParameters (generated from ``PARAMS``; default duration "
        f"{format_number(cls.DEFAULT_DURATION_US / US)} s):\n\n{params_table(cls.PARAMS)}\n"
    )


def _smoothstep_scalar(x: float) -> float:
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


# ---------------------------------------------------------------------------------------------
# textures
# ---------------------------------------------------------------------------------------------
def _noise(
    rng: np.random.Generator, h: int, w: int, std: float = 1.0, k0: float = 1 / 96, kmax: float = 0.3
) -> np.ndarray:
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


def _draw_shapes(
    img: np.ndarray, rng: np.random.Generator, n: int, size: tuple[float, float], amp: float, wrap: bool = False
) -> None:
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
                    img[ya:yb, xa:xb] = patch[ya - y0 : yb - y0, xa - x0 : xb - x0]
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
                pts = np.array(
                    [[cx, cy], [cx + a, cy + rng.uniform(-b, b) * 0 + b * 0.3], [cx + a * 0.4, cy + b]], dtype=np.int32
                )
                cv2.fillPoly(img, [pts], val)


def _blur(img: np.ndarray, sigma: float, wrap: bool) -> np.ndarray:
    """Gaussian blur; with ``wrap`` the image is treated as periodic."""
    if not wrap:
        return cv2.GaussianBlur(img, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    m = int(math.ceil(4 * sigma)) + 1
    big = np.pad(img, m, mode="wrap")
    return cv2.GaussianBlur(big, (0, 0), sigma)[m:-m, m:-m].copy()


def _structured_texture(
    rng: np.random.Generator,
    h: int,
    w: int,
    *,
    amp: float = 0.6,
    density: float = 1.0,
    size: tuple[float, float] = (6, 40),
    wrap: bool = False,
) -> np.ndarray:
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
        a *= np.sqrt(2.0) / np.sqrt((a**2).sum(axis=1, keepdims=True))  # RMS 1 per component
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
    return np.array(
        [[c, -s, dst_c[0] - c * src_c[0] + s * src_c[1]], [s, c, dst_c[1] - s * src_c[0] - c * src_c[1]]],
        dtype=np.float64,
    )


def _bilinear(img: np.ndarray, points) -> np.ndarray:
    """``img`` at fractional ``(x, y)`` points (pixel centres at integers; 0 outside), bilinear."""
    p = np.asarray(points, np.float64)
    x, y = p[..., 0], p[..., 1]
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    h, w = img.shape

    def at(yy, xx):
        ok = (xx >= 0) & (xx < w) & (yy >= 0) & (yy < h)
        return np.where(ok, img[np.clip(yy, 0, h - 1), np.clip(xx, 0, w - 1)], 0.0)

    top = at(y0, x0) * (1 - fx) + at(y0, x0 + 1) * fx
    bot = at(y0 + 1, x0) * (1 - fx) + at(y0 + 1, x0 + 1) * fx
    return top * (1 - fy) + bot * fy


def _warp(tex: np.ndarray, m: np.ndarray, sensor: SensorGeometry, border=cv2.BORDER_REFLECT) -> np.ndarray:
    return cv2.warpAffine(tex, m, (sensor.width, sensor.height), flags=cv2.INTER_LINEAR, borderMode=border)


# ---------------------------------------------------------------------------------------------
# base class
# ---------------------------------------------------------------------------------------------
class PresetScene(Scene):
    """A named preset: validates its documented ``PARAMS`` and builds its textures once.

    A subclass sets ``name``, ``DEFAULT_DURATION_US`` and ``PARAMS`` (its own parameters followed
    by ``**COMMON_PARAMS``) and implements ``_build`` (textures, ``changes``) and
    ``log_irradiance``; its parameter table is appended to its docstring when it is defined.
    """

    name = "preset"
    PARAMS: dict[str, Param] = {}
    DEFAULT_DURATION_US = 2_000_000

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if "PARAMS" in cls.__dict__:
            _document(cls)

    def __init__(self, sensor: SensorGeometry = DAVIS346, duration_us: int | None = None, seed: int = 0, **params):
        if duration_us is None:
            duration_us = self.DEFAULT_DURATION_US
        if not isinstance(sensor, SensorGeometry):
            raise ParameterError(f"{self.name}: sensor must be a SensorGeometry, got {sensor!r}")
        super().__init__(sensor, duration_us, seed)
        unknown = sorted(set(params) - set(self.PARAMS))
        if unknown:
            raise ParameterError(
                f"{self.name}: unknown parameter(s) {', '.join(unknown)}; accepted: {', '.join(self.PARAMS)}"
            )
        self.params = {}
        for key, spec in self.PARAMS.items():
            v = params.get(key, spec.default)
            if spec.kind == "float" or (spec.kind == "opt_float" and v is not None):
                v = check_number(key, v, spec.lo, spec.hi, where=self.name)
            elif spec.kind == "flag":
                if v not in (True, False, 0, 1) or isinstance(v, float):
                    raise ParameterError(f"{self.name}: {key} must be true or false, got {v!r}")
                v = bool(v)
            self.params[key] = v
        self._jitter_given = "change_jitter_ms" in params
        self.markers: list[PlacedMarker] = []
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
            raise ParameterError(
                f"{self.name}: {key} = {v:g} s must lie inside the duration (0, {self.duration_s:g}) s"
            )
        return v

    def _times_list(self, key: str, default_fracs) -> list[float]:
        v = self.params[key]
        if v is None:
            v = [f * self.duration_s for f in default_fracs]
        if not isinstance(v, (list, tuple)):
            raise ParameterError(f"{self.name}: {key} must be a list of times in seconds, got {v!r}")
        out = [check_number(f"{key}[{i}]", x, 0.0, self.duration_s, where=self.name) for i, x in enumerate(v)]
        if any(b <= a for a, b in pairwise(out)):
            raise ParameterError(f"{self.name}: {key} must be strictly increasing, got {out}")
        self.params[key] = out
        return out

    def _mean_now(self, t_us: float) -> float:
        return float(self.log_irradiance(t_us).astype(np.float64).mean())

    # change-time jitter (COMMON_PARAMS["change_jitter_ms"])
    def _jitter_bound_us(self) -> int:
        """The jitter bound ``J`` in whole µs (``floor(change_jitter_ms * 1000)``)."""
        return int(math.floor(self.params["change_jitter_ms"] * 1000.0 + 1e-9))

    def _jitter_us(self, n: int) -> np.ndarray:
        """``n`` offsets in whole µs, independent and uniform on ``{-J, ..., +J}``; zeros when ``J = 0``.

        Drawn from a stream spawned from the scene's seed (``SeedSequence(seed, spawn_key=(JITTER_STREAM,))``;
        with a non-zero ``phase_key`` ``(JITTER_STREAM, phase_key)``, so scenes with different keys draw
        independent offsets for the same seed), not from the texture generator: the same seed gives the
        same offsets, and jitter moves the timing of a scene without changing its textures.
        """
        J = self._jitter_bound_us()
        if J == 0:
            return np.zeros(n, np.int64)
        key = self.params.get("phase_key", 0.0)
        if key != int(key):
            raise ParameterError(f"{self.name}: phase_key must be a whole number, got {key:g}")
        spawn = (JITTER_STREAM,) if key == 0 else (JITTER_STREAM, int(key))
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=spawn))
        return rng.integers(-J, J, size=n, endpoint=True)

    def _jittered_us(self, key: str, nominal_us: list[float]) -> list[float]:
        """Change times (µs) moved by :meth:`_jitter_us`, kept inside ``[0, duration]`` and in order.

        With ``J = 0`` the nominal times are returned unchanged. Times closer than ``2 J`` could swap,
        so they are refused with a one-line error.
        """
        J = self._jitter_bound_us()
        if J == 0:
            return list(nominal_us)
        gaps = np.diff(np.asarray(nominal_us, np.float64))
        if gaps.size and gaps.min() <= 2 * J and not self._jitter_given:  # the default shrinks to fit
            J = max(int(math.ceil(gaps.min())) // 2 - 1, 0)
            self.params["change_jitter_ms"] = J / 1000.0
            if J == 0:
                return list(nominal_us)
        if gaps.size and gaps.min() <= 2 * J:
            raise ParameterError(
                f"{self.name}: change_jitter_ms = {self.params['change_jitter_ms']:g} could "
                f"reorder {key} ({gaps.min() / 1e3:g} ms apart); use less than "
                f"{gaps.min() / 2e3:g} ms"
            )
        d = self._jitter_us(len(nominal_us))
        return [min(max(t + float(x), 0.0), float(self.duration_us)) for t, x in zip(nominal_us, d, strict=True)]

    # fiducial markers (COMMON_PARAMS["markers"]; .fiducials)
    def _paint_markers(self, tex: np.ndarray, places, cell: int, layer: str = "scene", first_id: int = 0) -> int:
        """Paint markers into ``tex`` (in place) when ``markers`` is on: ``places`` are the patches'
        top-left texels ``(x0, y0)``, ids counted from ``first_id``; a patch that does not fit is
        skipped. Records them in ``self.markers``; returns the next free id."""
        mid = first_id
        if not self.params["markers"]:
            return mid
        for x0, y0 in places:
            corners = paint(tex, mid, int(round(x0)), int(round(y0)), cell)
            if corners is not None:
                self.markers.append(PlacedMarker(mid, corners, layer))
            mid += 1
        return mid

    def _marker_places(self, centres, cell: int, width: float, height: float) -> list[tuple[float, float]]:
        """Patch top-left texels for patches centred at ``centres`` (fractions of ``width`` x ``height``)."""
        n = patch_size(cell)
        return [(fx * width - n / 2, fy * height - n / 2) for fx, fy in centres]

    def _marker_geometry(self, t_us: float):
        """``(ids, image corners (n, 4, 2), layer weights (n,) or None)`` at ``t_us``; the default is a
        scene whose texture is the image (the corners as painted)."""
        ids = np.array([m.marker_id for m in self.markers], np.int64)
        corners = np.array([m.corners for m in self.markers], np.float64).reshape(-1, 4, 2)
        return ids, corners, None

    def marker_truth(self, t_us: float) -> MarkerTruth | None:
        """Where the scene's markers are at ``t_us`` (:class:`~necviz.core.markers.MarkerTruth`), ``None``
        without markers."""
        if not self.markers:
            return None
        ids, corners, weight = self._marker_geometry(self._check_t(t_us))
        H, W = self.sensor.shape
        return MarkerTruth(ids, corners, visibility(corners, W, H, weight))
