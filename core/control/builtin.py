"""The DAVIS host-side auto-exposure of libcaer (``autoexposure.c``), image only.

Algorithm, per frame (libcaer, github.com/inivation/libcaer, ``src/autoexposure.c``; constants from
its ``autoexposure.h``; summary in docs/baselines.md):

0. **Runs only when the frame's exposure equals the last value it set** (libcaer compares the
   frame's exposure with ``exposureLastSetValue`` and returns "no change" otherwise), so it
   never reacts twice to the same stale frame. The comparison is on integer µs, as the camera
   applies them (``max(1, round(T))``).
1. 256-bin histogram of the 8-bit image. ``frac_low`` = fraction of pixels in the lowest
   ``int(0.10·256) = 25`` bins (Z ≤ 24), ``frac_high`` = fraction in bins from
   ``int(0.90·256) = 230`` on (Z ≥ 230).
2. With ``F = 0.33``:

   * ``frac_low ≥ F`` and ``frac_high < F`` (under-exposed):
     ``T ← T + int(14000·(frac_low − F)^1.65)`` µs;
   * ``frac_high ≥ F`` and ``frac_low < F`` (over-exposed):
     ``T ← T − int(14000·(frac_high − F)^1.65)`` µs;
   * otherwise the **pixel-value-weighted** mean sample value over 5 equal regions,
     ``MSV = Σ(i+1)·S_i / ΣS_i`` with ``S_i`` the *sum of pixel values* in region i
     (``ΣS_i = 0``, an all-black image, is replaced by 1 as libcaer does, giving MSV = 0),
     error ``e = 2.5 − MSV``; divisor ``div = 1``, 5 if ``|frac_low − F| < 0.1`` or
     ``|frac_high − F| < 0.1``, 10 if either is ``< 0.05``; if ``e > 0.1``:
     ``T ← T + int(100·e²) // div``; if ``e < −0.1``: ``T ← T − int(100·e²) // div``.

   A step that rounds to zero becomes ±1 µs (libcaer's "ensure increase/decrease").
3. Clip to ``[1 µs, 1 s]`` (libcaer), then to the camera limits. The result is issued only if it
   differs from the last set value. Gain is always 1 (libcaer's AE does not use gain).

Region index for the MSV follows libcaer on DAVIS 8-bit pixels left-shifted to 16 bits:
``(Z·256) // 13107`` (13107 = 65536 // 5), i.e. region boundaries at Z = 52, 103, 154, 205.
Steps are absolute µs (not relative): from a short exposure the rule is slow to brighten,
from a long one the MSV steps (≤ 625 µs) are slow to darken — that is the baseline's nature.
"""

from __future__ import annotations

import math

import numpy as np

from necviz.core.control.controller import CameraLimits, Controller, ExposureCommand
from necviz.core.frames import Frame

HISTOGRAM_PIXELS = 256
HISTOGRAM_MSV = 5
LOW_BOUNDARY = 0.10
HIGH_BOUNDARY = 0.90
UNDEROVER_FRAC = 0.33
UNDEROVER_CORRECTION = 14000.0
UNDEROVER_EXPONENT = 1.65
MSV_CORRECTION = 100.0
MSV_DEAD_BAND = 0.1
LIBCAER_MIN_US = 1
LIBCAER_MAX_US = 1_000_000

_BIN_LOW = int(np.float32(LOW_BOUNDARY) * np.float32(HISTOGRAM_PIXELS))  # 25
_BIN_HIGH = int(np.float32(HIGH_BOUNDARY) * np.float32(HISTOGRAM_PIXELS))  # 230
_MSV_INDEX = (np.arange(256) * 256) // (65536 // HISTOGRAM_MSV)  # region of each 8-bit value


def _applied_us(exposure_us: float) -> int:
    """The integer exposure the camera applies for a requested value."""
    return max(1, int(round(exposure_us)))


def libcaer_step(image: np.ndarray, last_set_us: int) -> tuple[int, dict]:
    """libcaer's new exposure (integer µs, clipped to [1, 1e6]) for ``image`` taken at ``last_set_us``.

    Returns the new value (equal to ``last_set_us`` for "no change") and the statistics used.
    """
    z = np.asarray(image, dtype=np.uint8).ravel()
    n = z.size
    stats: dict = {"frac_low": math.nan, "frac_high": math.nan, "msv": math.nan, "branch": "none"}
    if n == 0:
        return last_set_us, stats
    hist = np.bincount(z, minlength=HISTOGRAM_PIXELS)
    frac_low = float(hist[:_BIN_LOW].sum()) / n
    frac_high = float(hist[_BIN_HIGH:].sum()) / n
    stats.update(frac_low=frac_low, frac_high=frac_high)
    err_low = frac_low - UNDEROVER_FRAC
    err_high = frac_high - UNDEROVER_FRAC
    new = last_set_us
    if frac_low >= UNDEROVER_FRAC and frac_high < UNDEROVER_FRAC:
        stats["branch"] = "under"
        new = last_set_us + int(UNDEROVER_CORRECTION * err_low**UNDEROVER_EXPONENT)
        if new == last_set_us:
            new += 1
    elif frac_high >= UNDEROVER_FRAC and frac_low < UNDEROVER_FRAC:
        stats["branch"] = "over"
        new = last_set_us - int(UNDEROVER_CORRECTION * err_high**UNDEROVER_EXPONENT)
        if new == last_set_us:
            new -= 1
    else:
        sums = np.bincount(_MSV_INDEX, weights=hist * np.arange(256.0), minlength=HISTOGRAM_MSV)
        denom = float(sums.sum()) or 1.0
        msv = float((np.arange(1, HISTOGRAM_MSV + 1) * sums).sum()) / denom
        e = HISTOGRAM_MSV / 2.0 - msv
        stats.update(msv=msv, branch="msv")
        div = 1
        if abs(err_low) < 0.1 or abs(err_high) < 0.1:
            div = 5
        if abs(err_low) < 0.05 or abs(err_high) < 0.05:
            div = 10
        if e > MSV_DEAD_BAND:
            new = last_set_us + int(MSV_CORRECTION * e * e) // div
            if new == last_set_us:
                new += 1
        elif e < -MSV_DEAD_BAND:
            new = last_set_us - int(MSV_CORRECTION * e * e) // div
            if new == last_set_us:
                new -= 1
    return min(max(new, LIBCAER_MIN_US), LIBCAER_MAX_US), stats


class BuiltinController(Controller):
    """The DAVIS camera's own host-side AE (libcaer), exposure only, gain fixed at 1.

    Parameters
    ----------
    limits : camera exposure/gain limits (every command is clamped to them).
    exposure_us : initial exposure in µs (default 5000); it is the first "last set value".
    gain : accepted for interface compatibility but ignored: libcaer's AE has no gain control,
        so the initial command and every later one use gain 1.
    """

    name = "builtin"

    def __init__(self, limits: CameraLimits, exposure_us: float = 5_000.0, gain: float = 1.0):
        super().__init__(limits, exposure_us, gain)  # validates gain (finite, > 0), then ignores it
        self.gain = 1.0
        self.last_set_us = _applied_us(self.exposure_us)
        self.last_stats: dict = {}

    def initial_command(self, t_us: int = 0) -> ExposureCommand:
        return ExposureCommand(self.exposure_us, 1.0, int(t_us), self.name)

    def on_frame(self, frame: Frame) -> ExposureCommand | None:
        super().on_frame(frame)
        if frame.exposure_us != self.last_set_us:
            self.last_stats = {"branch": "skipped"}
            return None
        new, self.last_stats = libcaer_step(frame.image, self.last_set_us)
        exposure, gain = self.limits.clamp(float(new), 1.0)
        applied = _applied_us(exposure)
        if applied == self.last_set_us and frame.gain == 1.0:
            return None
        self.last_set_us = applied
        return ExposureCommand(exposure, gain, int(self.now_us), self.name)
