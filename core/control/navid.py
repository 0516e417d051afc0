"""Nourani-Vatani & Roberts, "Automatic Camera Exposure Control" (ACRA 2007), image only.

Algorithm, per frame (summary in docs/baselines.md):

1. Histogram of the (optionally weighted) 8-bit image in **5 equal regions** (region of Z is
   ``(5·Z) // 256``: 0..51, 52..102, 103..153, 154..204, 205..255); ``x_i`` = (weighted) pixel
   count of region i. **Mean sample value** ``MSV = Σ(i+1)·x_i / Σx_i ∈ [1, 5]``.
2. Error ``e = target − MSV`` with the published **target 2.5**. Inside the dead band
   ``|e| ≤ dead_band`` (default 0.1, the MSV dead band libcaer uses) nothing changes.
3. Two PI controllers with the published, empirically determined proportional constants
   **K_exposure = 30·c + 20** and **K_gain = 10·c + 15**, ``c`` = fraction of the image used
   (1.0 without a mask, as in their test: K_exposure = 50, K_gain = 25). The integral
   constants are not published; we use ``K_i = 0.2·K_p`` and the anti-windup clamp
   ``|Σe| ≤ 3``, the ratio (k_i/k_p = 0.01/0.05) and clamp of the public reference
   implementation (alexzzhu/auto_exposure_control).
4. **Exposure first**: gain stays at 1 and its controller is off while the exposure is below
   its maximum. Once the frame was taken at ``T_max`` and still wants more light, the exposure
   controller stops (T stays at T_max) and the gain controller runs; when the gain comes back
   down to 1 and the image is still too bright, control hands back to the exposure loop.
   (A frame taken with gain > 1 below T_max — only possible from a foreign start setting — is
   corrected by the exposure loop on the product T·K, re-split exposure-first.)

**Mapping to physical units (our decision).** The paper adds ``u = K_p·e + K_i·Σe`` to the
Fire-i exposure register (1..511), so the same constants mean different relative steps at
different exposures. We apply the PI output in the log domain, scale-invariant across
exposures and cameras::

    T ← T · 2^{s·(K_exposure·e + K_i·Σe)},   K ← K · 2^{s·(K_gain·e + K_i,g·Σe_g)}

with ``s = ev_per_unit = 0.01`` EV per published unit, so K_exposure = 50 is **0.5 EV per
MSV unit**. Why 0.01: for a linear sensor near MSV 2.5 (mean ≈ 100 DN) one EV moves the MSV
by ≈ 0.7..1.4 (wide..narrow histogram), so the loop gain per frame is ≈ 0.35..0.7 and the
error shrinks by that fraction each frame — settled (inside the dead band) in ~3..6 frames,
matching the paper's "about 5 cycles". (Equivalently: the paper's additive step linearised
at a register value of 100/ln 2 ≈ 144 of the Fire-i's 1..511, where ΔT/T = 50·e/144 is
0.5·e EV.) The step is bounded: |e| ≤ 2.5 and |Σe| ≤ 3 give ≤ 1.55 EV per frame. Gain, with
the smaller published K_gain = 25, moves 0.25 EV per MSV unit.
Measured (tests/test_baselines_simple.py scene, DAVIS346-like CRF): MSV within ±0.3 of 2.5
after 5 frames from a start ~6.9 EV too bright and after 7 frames from ~6.6 EV too dark.

Anti-windup (ours, beyond the clamp): the integral is not accumulated while the actuator is
pinned at a limit in the direction of the error, and it is reset when the error changes sign
(otherwise a far-off start winds it up to the clamp and the overshoot decays only slowly),
inside the dead band, and when control passes between the exposure and gain loops.

Optional ``mask`` (weights image, same shape as the frames; 8-bit or float weights >= 0,
gradient masks allowed) weights the histogram counts. Every command is finite and clamped to
``self.limits``; images with no usable pixels (zero size, zero total weight) give ``None``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from necviz.core.checks import check_number as _num
from necviz.core.control.controller import CameraLimits, Controller, ControllerOptions, ExposureCommand, Tunable
from necviz.core.errors import ParameterError
from necviz.core.frames import Frame

N_REGIONS = 5
TARGET_MSV = 2.5
_REGION = (np.arange(256) * N_REGIONS) // 256  # region index of each 8-bit value


def mean_sample_value(image: np.ndarray, weights: np.ndarray | None = None) -> float:
    """``MSV = Σ(i+1)·x_i / Σx_i`` over 5 equal regions (NaN if no pixel carries weight)."""
    z = np.asarray(image, dtype=np.uint8).ravel()
    if z.size == 0:
        return math.nan
    w = None if weights is None else np.asarray(weights, dtype=np.float64).ravel()
    hist = np.bincount(z, weights=w, minlength=256)
    x = np.bincount(_REGION, weights=hist, minlength=N_REGIONS)
    total = float(x.sum())
    if not total > 0 or not math.isfinite(total):
        return math.nan
    return float((np.arange(1, N_REGIONS + 1) * x).sum()) / total


@dataclass(frozen=True, eq=False)
class NavidOptions(ControllerOptions):
    """Navid's settings.

    Parameters
    ----------
    target_msv : float
        Desired MSV in (1, 5), published 2.5.
    image_fraction : float, optional
        ``c`` in the published constants; ``None`` (default) = 1.0 without a mask, else the
        fraction of mask pixels with non-zero weight. In (0, 1].
    k_exposure, k_gain : float, optional
        Proportional constants; ``None`` (default) = the published ``30c + 20`` and ``10c + 15``.
    ki_ratio : float
        Integral constant as a fraction of the proportional one (default 0.2), >= 0.
    integral_limit : float
        Anti-windup clamp on ``|Σe|`` (default 3), >= 0.
    ev_per_unit : float
        log2 exposure (or gain) step per unit of PI output (default 0.01, see the module
        docstring), in (0, 0.1].
    dead_band : float
        No change while ``|target − MSV| <= dead_band`` (default 0.1), in [0, 1).
    mask : ndarray, optional
        Weights image (H x W, finite, >= 0, not all zero); frames must match its shape.
    """

    TUNABLE: ClassVar[tuple[Tunable, ...]] = (
        Tunable(
            "target_msv",
            "MSV",
            "mean sample value the histogram is driven to (1..5, mid-grey 2.5)",
            1.0,
            5.0,
            True,
            True,
        ),
        Tunable("dead_band", "MSV", "no correction while |MSV error| is below this", 0.0, 1.0, hi_open=True),
        Tunable("k_exposure", "1", "proportional gain of the exposure loop", 0.0, lo_open=True),
        Tunable("k_gain", "1", "proportional gain of the gain loop", 0.0, lo_open=True),
        Tunable("ev_per_unit", "EV", "exposure change per published PI output unit", 0.0, 0.1, lo_open=True),
    )

    target_msv: float = TARGET_MSV
    image_fraction: float | None = None
    k_exposure: float | None = None
    k_gain: float | None = None
    ki_ratio: float = 0.2
    integral_limit: float = 3.0
    ev_per_unit: float = 0.01
    dead_band: float = 0.1
    mask: np.ndarray | None = None

    def check(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        if self.mask is not None:
            m = np.asarray(self.mask)
            if m.ndim != 2 or not (np.issubdtype(m.dtype, np.number) or m.dtype == bool):
                raise ParameterError(f"mask must be a 2-D numeric weights image, got {m.dtype} {m.shape}")
            m = m.astype(np.float64)
            if not np.all(np.isfinite(m)) or np.any(m < 0):
                raise ParameterError("mask weights must be finite and >= 0")
            if not m.sum() > 0:
                raise ParameterError("mask has no pixel with non-zero weight")
            set_("mask", m)
        c = self.image_fraction
        if c is None:
            c = 1.0 if self.mask is None else float(np.count_nonzero(self.mask)) / self.mask.size
        c = _num("image_fraction", c, 0.0, 1.0, lo_open=True)
        set_("image_fraction", c)
        if self.k_exposure is None:
            set_("k_exposure", 30.0 * c + 20.0)
        if self.k_gain is None:
            set_("k_gain", 10.0 * c + 15.0)
        set_("ki_ratio", _num("ki_ratio", self.ki_ratio, 0.0))
        set_("integral_limit", _num("integral_limit", self.integral_limit, 0.0))


class NavidController(Controller):
    """Nourani-Vatani & Roberts 2007: 5-region MSV → PI exposure loop, then PI gain loop.

    Parameters
    ----------
    limits : CameraLimits
        Camera exposure/gain limits (every command is clamped to them).
    exposure_us, gain : float
        Initial setting (the paper starts with gain 1).
    options : NavidOptions, optional
        The settings (default: the published constants).
    """

    name = "navid"
    OPTIONS = NavidOptions
    options: NavidOptions  # set by Controller.__init__ (always an instance of OPTIONS)

    def __init__(
        self,
        limits: CameraLimits,
        exposure_us: float = 5_000.0,
        gain: float = 1.0,
        options: NavidOptions | None = None,
    ):
        super().__init__(limits, exposure_us, gain, options)
        self.integral_exposure = 0.0
        self.integral_gain = 0.0
        self.loop = "exposure"  # which PI loop ran last: "exposure" or "gain"
        self.last_msv = math.nan
        self.last_error = math.nan

    # -- the pieces ---------------------------------------------------------------------------
    def msv(self, image: np.ndarray) -> float:
        if self.options.mask is not None and image.shape != self.options.mask.shape:
            raise ParameterError(f"navid mask shape {self.options.mask.shape} does not match frame shape {image.shape}")
        return mean_sample_value(image, self.options.mask)

    def _integrate(self, integral: float, e: float, pinned: bool) -> float:
        if integral * e < 0:  # the error changed sign: drop the wound-up history (no overshoot tail)
            integral = 0.0
        if not pinned:
            integral += e
        return min(max(integral, -self.options.integral_limit), self.options.integral_limit)

    def _at_exposure_max(self) -> bool:
        # frame exposures are integer µs: allow the rounding of a non-integer T_max
        return self.exposure_us >= self.limits.exposure_max_us - 1.0

    # -- packets ------------------------------------------------------------------------------
    def on_frame(self, frame: Frame) -> ExposureCommand | None:
        super().on_frame(frame)
        lim = self.limits
        msv = self.msv(frame.image)
        self.last_msv = msv
        if not math.isfinite(msv):
            return None
        e = self.options.target_msv - msv
        self.last_error = e
        if abs(e) <= self.options.dead_band:
            self.integral_exposure = self.integral_gain = 0.0
            return None
        gain_loop = lim.has_gain and self._at_exposure_max() and (self.gain > 1.0 or e > 0)
        if gain_loop:
            if self.loop != "gain":
                self.loop, self.integral_gain = "gain", 0.0
            pinned = (e > 0 and self.gain >= lim.gain_max) or (e < 0 and self.gain <= 1.0)
            self.integral_gain = self._integrate(self.integral_gain, e, pinned)
            k_gain = self.options.k_gain
            assert k_gain is not None  # NavidOptions.check fills in the published default
            u = self.options.ev_per_unit * k_gain * (e + self.options.ki_ratio * self.integral_gain)
            exposure, gain = lim.exposure_max_us, self.gain * 2.0**u
        else:
            if self.loop != "exposure":
                self.loop, self.integral_exposure = "exposure", 0.0
            pinned = (e > 0 and self._at_exposure_max()) or (e < 0 and self.exposure_us <= lim.exposure_min_us)
            self.integral_exposure = self._integrate(self.integral_exposure, e, pinned)
            k_exposure = self.options.k_exposure
            assert k_exposure is not None  # NavidOptions.check fills in the published default
            u = self.options.ev_per_unit * k_exposure * (e + self.options.ki_ratio * self.integral_exposure)
            # normally gain is 1 here; a frame taken with gain below T_max (a foreign start
            # setting) is corrected on the product T·K, split exposure-first
            if self.gain > 1.0:
                product = self.exposure_us * self.gain * 2.0**u
                exposure = min(product, lim.exposure_max_us)
                gain = product / exposure if exposure > 0 else 1.0
            else:  # the paper: the exposure loop alone, clipped at T_max; gain waits a frame
                exposure, gain = self.exposure_us * 2.0**u, 1.0
        if not (math.isfinite(exposure) and exposure > 0):
            exposure = lim.exposure_max_us if e > 0 else lim.exposure_min_us
        if not (math.isfinite(gain) and gain > 0):
            gain = 1.0
        exposure, gain = lim.clamp(exposure, gain)
        return ExposureCommand(exposure, gain, int(self.now_us), self.name)
