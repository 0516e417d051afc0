"""APS frame formation: a global-shutter exposure of the simulated irradiance.

For an exposure ``[s, e]`` with time ``T`` and gain ``K``::

    N_e  = Q · T · Lbar              (electrons; Lbar = exposure-averaged irradiance, T in s)
    N_e' = N_e + n_shot + n_read     (n_shot ~ N(0, N_e), n_read ~ N(0, σ_read²))
    H    = K · N_e' / Q              (exposure-gain product, relative to Z = 128 at H = 1)
    Z    = clip(round(f(ln H)), 0, 255)

with ``f`` the camera response (the inverse of ``g``). ``Lbar`` integrates the same scene
samples the event model sees, piecewise linear in irradiance between samples, so light that
changes during an exposure blurs and saturates it as it would a real sensor. Gain multiplies
signal and noise alike; an exposure far beyond the response's range clips to 255 exactly when
``g(255) < ln H``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numba as nb
import numpy as np

from necviz.core.crf import US_PER_S, CameraResponse
from necviz.core.errors import ParameterError


@dataclass(frozen=True)
class ApsParams:
    """APS timing and noise. Defaults: 50 fps, 1 ms readout, DAVIS346-like noise.

    ``electrons_at_mid``: electrons collected at ``H = 1`` (Z = 128, gain 1): sets shot noise
    (about 1.4 % of the signal at mid-grey). ``read_noise_e``: read noise in electrons.
    ``latency_us``: a command takes effect at the first exposure starting at least this long
    after it was issued. Exposure limits in µs; ``exposure_max_us`` must fit in the frame
    interval minus the readout.
    """

    frame_interval_us: int = 20_000
    readout_us: int = 1_000
    latency_us: int = 1_000
    exposure_min_us: int = 1
    exposure_max_us: int = 18_000
    gain_max: float = 16.0
    electrons_at_mid: float = 5_000.0
    read_noise_e: float = 10.0
    noise: bool = True

    def __post_init__(self) -> None:
        for k, v in asdict(self).items():
            if k == "noise":
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ParameterError(f"APS parameter {k} must be a finite number >= 0, got {v!r}")
        if self.frame_interval_us <= 0 or self.exposure_min_us <= 0:
            raise ParameterError("frame_interval_us and exposure_min_us must be positive")
        if self.exposure_max_us < self.exposure_min_us:
            raise ParameterError(f"exposure_max_us ({self.exposure_max_us}) < exposure_min_us ({self.exposure_min_us})")
        if self.exposure_max_us + self.readout_us > self.frame_interval_us:
            raise ParameterError(
                f"exposure_max_us + readout_us ({self.exposure_max_us + self.readout_us} µs) must fit in the "
                f"frame interval ({self.frame_interval_us} µs)"
            )
        if self.gain_max < 1.0:
            raise ParameterError(f"gain_max must be >= 1, got {self.gain_max}")
        if self.electrons_at_mid <= 0:
            raise ParameterError("electrons_at_mid must be positive")


class DigitLut:
    """``Z = round(f(ln H))`` by table lookup: 2^16 bins over ``[g(0) - 0.5, g(255) + 0.5]``.

    A pixel can only differ from the exact rounding if its ``ln H`` lies within one bin
    (about 9e-5 ln units, 0.02 DN) of a rounding boundary; ``np.interp`` per frame cost
    0.8 ms, the lookup about a quarter of that.
    """

    BINS = 1 << 16

    def __init__(self, crf: CameraResponse):
        self.lo = float(crf.g[0] - 0.5)
        hi = float(crf.g[255] + 0.5)
        self.scale = (self.BINS - 1) / (hi - self.lo)
        centres = self.lo + (np.arange(self.BINS) + 0.5) / self.scale
        self.table = np.clip(np.rint(crf.intensity(centres)), 0, 255).astype(np.uint8)


_LUTS: dict = {}


@nb.njit(cache=True, nogil=True)
def _electrons(lin, scale, read_var, noise, out):
    """``out = max(N_e', 1e-30)`` with ``N_e = scale · Lbar`` and ``N_e' = N_e + sqrt(max(N_e, 0) + σ²) · n``
    (``noise`` = the standard normal draws ``n``, or an empty array for no noise), in float32.

    The same float32 operations, in the same order, as the NumPy expression it replaces (every
    intermediate is rounded to float32), so the result is bit for bit that expression's: one
    pass instead of six. O(pixels).
    """
    tiny = np.float32(1e-30)
    zero = np.float32(0.0)
    if noise.size == 0:
        for i in range(lin.size):
            e = np.float32(lin[i] * scale)
            out[i] = tiny if e < tiny else e  # NaN stays NaN, as np.maximum
    else:
        for i in range(lin.size):
            e = np.float32(lin[i] * scale)
            v = np.float32((zero if e < zero else e) + read_var)
            sigma = np.float32(math.sqrt(v))
            e = np.float32(e + np.float32(sigma * noise[i]))
            out[i] = tiny if e < tiny else e


@nb.njit(cache=True, nogil=True)
def _digits(log_e, offset, scale, table, out):
    """``out = table[int(clip((ln N_e' + offset) · scale, 0, len - 1))]`` in float32 (the lookup of
    :class:`DigitLut`); returns False, leaving the rest undone, at a NaN (the caller then takes the
    NumPy path, which reports it). O(pixels)."""
    top = np.float32(table.size - 1)
    zero = np.float32(0.0)
    for i in range(log_e.size):
        v = np.float32(np.float32(log_e[i] + offset) * scale)
        if v != v:
            return False
        if v < zero:
            v = zero
        elif v > top:
            v = top
        out[i] = table[np.int32(v)]
    return True


def expose(
    mean_irradiance: np.ndarray,
    exposure_us: float,
    gain: float,
    crf: CameraResponse,
    params: ApsParams,
    rng: np.random.Generator | None,
) -> np.ndarray:
    """One 8-bit frame from the exposure-averaged irradiance ``Lbar`` (float array, linear units)."""
    lut = _LUTS.get(id(crf))
    if lut is None or lut[0] is not crf:
        lut = _LUTS[id(crf)] = (crf, DigitLut(crf))
    lut = lut[1]
    q = params.electrons_at_mid
    lin = np.ascontiguousarray(mean_irradiance, dtype=np.float32)
    shape = lin.shape
    lin = lin.reshape(-1)
    if params.noise and rng is not None:
        noise = rng.standard_normal(lin.size, dtype=np.float32)  # the same draws as one of ``shape``
    else:
        noise = np.empty(0, np.float32)
    electrons = np.empty(lin.size, np.float32)
    _electrons(lin, np.float32(q * exposure_us / US_PER_S), np.float32(params.read_noise_e**2), noise, electrons)
    # the logarithm stays NumPy's (a compiled log may round differently in the last bit)
    log_h = np.log(electrons, out=electrons)
    offset, scale = np.float32(math.log(gain / q) - lut.lo), np.float32(lut.scale)
    img = np.empty(lin.size, np.uint8)
    if not _digits(log_h, offset, scale, lut.table, img):
        log_h += offset
        log_h *= scale
        img = lut.table[np.clip(log_h, 0, lut.BINS - 1).astype(np.int32)]
    return img.reshape(shape)


def integrate_samples(times: np.ndarray, values: list[np.ndarray], s: float, e: float) -> np.ndarray:
    """``(1/(e-s)) ∫_s^e L(t) dt`` for ``L`` piecewise linear between samples ``(times[k], values[k])``.

    ``times`` ascending and covering ``[s, e]``. The integral of the interpolant is a weighted
    sum of the samples; the weights come from each segment's overlap with ``[s, e]``. Exact for the
    piecewise-linear interpolant; one multiply-add per sample in the window per pixel.
    """
    if not (times[0] <= s < e <= times[-1]):
        raise ParameterError(f"exposure [{s}, {e}] is not covered by samples [{times[0]}, {times[-1]}]")
    k0 = int(np.searchsorted(times, s, side="right")) - 1
    k1 = int(np.searchsorted(times, e, side="left"))
    w = np.zeros(k1 - k0 + 1)
    for k in range(k0, k1):
        t0, t1 = times[k], times[k + 1]
        lo, hi = max(s, t0), min(e, t1)
        if hi <= lo or t1 <= t0:
            continue
        # ∫_lo^hi a(t) dt with a = (t - t0)/(t1 - t0): the weight of the right sample; the rest is the left's
        right = ((hi - t0) ** 2 - (lo - t0) ** 2) / (2.0 * (t1 - t0))
        w[k - k0] += (hi - lo) - right
        w[k - k0 + 1] += right
    w /= e - s
    acc = values[k0] * np.float32(w[0])
    for j in range(1, w.size):
        if w[j] != 0.0:
            acc += values[k0 + j] * np.float32(w[j])
    return acc
