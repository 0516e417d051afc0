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

import numpy as np

from ...core.crf import US_PER_S, CameraResponse
from ...core.errors import ParameterError


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


def expose(mean_irradiance: np.ndarray, exposure_us: float, gain: float, crf: CameraResponse,
           params: ApsParams, rng: np.random.Generator | None) -> np.ndarray:
    """One 8-bit frame from the exposure-averaged irradiance ``Lbar`` (float array, linear units)."""
    t_s = exposure_us / US_PER_S
    q = params.electrons_at_mid
    electrons = (q * t_s) * np.asarray(mean_irradiance, dtype=np.float32)
    if params.noise and rng is not None:
        sigma = np.sqrt(np.maximum(electrons, 0.0) + params.read_noise_e**2)
        electrons = electrons + sigma * rng.standard_normal(electrons.shape, dtype=np.float32)
    h = np.maximum(electrons * np.float32(gain / q), np.float32(1e-30))
    z = crf.intensity(np.log(h))
    return np.clip(np.rint(z), 0, 255).astype(np.uint8)


def integrate_samples(times: np.ndarray, values: list[np.ndarray], s: float, e: float) -> np.ndarray:
    """``(1/(e-s)) ∫_s^e L(t) dt`` for ``L`` piecewise linear between samples ``(times[k], values[k])``.

    ``times`` ascending and covering ``[s, e]``. Exact for the piecewise-linear interpolant;
    O(samples in the window · pixels).
    """
    if not (times[0] <= s < e <= times[-1]):
        raise ParameterError(f"exposure [{s}, {e}] is not covered by samples [{times[0]}, {times[-1]}]")
    k0 = int(np.searchsorted(times, s, side="right")) - 1
    k1 = int(np.searchsorted(times, e, side="left"))
    acc = np.zeros_like(values[k0], dtype=np.float32)

    def at(t, k):  # interpolated sample at t in [times[k], times[k+1]]
        t0, t1 = times[k], times[k + 1]
        a = 0.0 if t1 == t0 else (t - t0) / (t1 - t0)
        return values[k] * np.float32(1.0 - a) + values[k + 1] * np.float32(a)

    for k in range(k0, k1):
        lo, hi = max(s, times[k]), min(e, times[k + 1])
        if hi <= lo:
            continue
        # trapezoid of the linear interpolant on [lo, hi]
        acc += (at(lo, k) + at(hi, k)) * np.float32(0.5 * (hi - lo))
    return acc / np.float32(e - s)
