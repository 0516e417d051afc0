"""Camera response: the log inverse response ``g(Z) = ln f^-1(Z)`` and its calibration.

Eq. (1) of the paper: ``g(Z(x)) = ln T + ln K + ln L(x)``. necviz fixes the units:
``T`` in **seconds** inside the logarithm (exposures are stored in µs and divided by 1e6),
``K`` linear gain, ``L`` irradiance in arbitrary linear units normalised so that
``g(128) = 0``: an exposure-gain product of 1 s on irradiance ``L = 1`` gives ``Z = 128``.

Valid digits are 9..250 (the paper); the goal intensity is the log mid-point
``g(I_opt) = (g(9) + g(250)) / 2`` (Eq. 2; see docs/method.md).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg

from necviz.core.errors import ParameterError

VALID_MIN = 9
VALID_MAX = 250
US_PER_S = 1e6


class CameraResponse:
    """A strictly increasing 256-entry log inverse response ``g``, normalised to ``g(128) = 0``.

    ``log_exposure(Z)`` evaluates ``g`` (linear interpolation for non-integer Z);
    ``intensity(h)`` is its continuous inverse (``h`` = log exposure), clipped to [0, 255].
    """

    def __init__(self, g, valid_min: int = VALID_MIN, valid_max: int = VALID_MAX):
        g = np.asarray(g, dtype=np.float64)
        if g.shape != (256,):
            raise ParameterError(f"camera response needs 256 values g(0..255), got shape {g.shape}")
        if not np.all(np.isfinite(g)):
            raise ParameterError("camera response contains NaN or infinite values")
        if not np.all(np.diff(g) > 0):
            z = int(np.flatnonzero(np.diff(g) <= 0)[0])
            raise ParameterError(f"camera response must increase strictly; g({z + 1}) <= g({z})")
        if not (0 <= valid_min < 128 < valid_max <= 255):
            raise ParameterError(f"valid range must satisfy 0 <= min < 128 < max <= 255, got {valid_min}..{valid_max}")
        self.g = g - g[128]
        self.g.setflags(write=False)
        self.valid_min = int(valid_min)
        self.valid_max = int(valid_max)

    # -- evaluation -------------------------------------------------------------------------
    def log_exposure(self, z) -> np.ndarray | float:
        """``g(Z)``; integer Z index the table, fractional Z interpolate linearly."""
        z = np.asarray(z)
        if np.issubdtype(z.dtype, np.integer):
            out = self.g[np.clip(z, 0, 255)]
        else:
            out = np.interp(z, np.arange(256.0), self.g)
        return float(out) if out.ndim == 0 else out

    def intensity(self, log_exposure) -> np.ndarray | float:
        """Continuous inverse ``f(h)``: the (unquantised) digital value for log exposure ``h``."""
        h = np.asarray(log_exposure, dtype=np.float64)
        out = np.interp(h, self.g, np.arange(256.0))
        return float(out) if out.ndim == 0 else out

    def log_irradiance(self, z, exposure_us: float, gain: float = 1.0):
        """Eq. (1) solved for ``ln L``: ``g(Z) - ln T - ln K`` with ``T`` in µs."""
        return self.log_exposure(z) - math.log(exposure_us / US_PER_S) - math.log(gain)

    # -- the control target -----------------------------------------------------------------
    @property
    def goal_log_exposure(self) -> float:
        """``g(I_opt) = (g(9) + g(250)) / 2`` (Eq. 2)."""
        return 0.5 * (self.g[self.valid_min] + self.g[self.valid_max])

    @property
    def goal_intensity(self) -> float:
        """``I_opt``, the digital value at the log mid-point of the valid range."""
        return float(self.intensity(self.goal_log_exposure))

    def to_list(self) -> list[float]:
        return [float(v) for v in self.g]

    def __eq__(self, other) -> bool:
        return (
            isinstance(other, CameraResponse)
            and np.array_equal(self.g, other.g)
            and (self.valid_min, self.valid_max) == (other.valid_min, other.valid_max)
        )

    def __repr__(self) -> str:
        return (
            f"CameraResponse(g(9)={self.g[9]:.3f}, g(250)={self.g[250]:.3f}, valid={self.valid_min}..{self.valid_max})"
        )


# Parameters of the default curve (see default_davis346).
_BLACK_OFFSET = (128.0 * math.exp(-2.20) - 9.0) / (1.0 - math.exp(-2.20))  # makes g(9) = -2.20 exactly
_KNEE = 236
_KNEE_GAIN = (1.11 - math.log((250 + _BLACK_OFFSET) / (128 + _BLACK_OFFSET))) / (
    (250 - _KNEE) / (255 - _KNEE)
) ** 2  # makes g(250) = 1.11


def default_davis346() -> CameraResponse:
    """A documented DAVIS346-like response (not a calibration of any particular unit).

    * Affine (linear with a black-level offset) below the knee: exposure ∝ ``Z + b`` with
      ``b ≈ 5.83`` DN, so ``g(Z) = ln((Z + b) / (128 + b))``; ``b`` is chosen so ``g(9) = -2.20``.
      Hence ``g(128) = 0`` and the curve is linear in exposure over 16..230 DN.
    * A knee above ``Z = 236`` where highlights compress: ``g`` gains an extra
      ``k * ((Z - 236) / 19)^2`` (continuous with a continuous slope at the knee), with ``k``
      chosen so ``g(250) = 1.11``.

    The goal intensity is then about 72 DN.
    """
    z = np.arange(256, dtype=np.float64)
    g = np.log((z + _BLACK_OFFSET) / (128.0 + _BLACK_OFFSET))
    above = z > _KNEE
    g[above] += _KNEE_GAIN * ((z[above] - _KNEE) / (255 - _KNEE)) ** 2
    return CameraResponse(g)


def debevec_malik(
    images,
    exposures_us,
    smoothness: float = 50.0,
    num_samples: int = 400,
    seed: int = 0,
) -> CameraResponse:
    """Recover ``g`` from frames of a static scene at known exposures (Debevec & Malik 1997).

    Solves, in the least-squares sense, over ``g(0..255)`` and the log irradiance ``ln L_i`` of
    sampled pixels ``i``::

        w(Z_ij) [g(Z_ij) - ln L_i - ln T_j] = 0            (data, every pixel i and image j)
        smoothness * w(z) [g(z-1) - 2 g(z) + g(z+1)] = 0   (z = 1..254)
        g(128) = 0

    with the hat weight ``w(z) = min(z, 255 - z) + 1``. Pixels are sampled evenly across
    the intensity range of the middle exposure. Values never observed are filled by the
    smoothness term; the result is made strictly increasing before it is returned.
    Cost: one dense least-squares solve with ``256 + num_samples`` unknowns.
    """
    exposures = np.asarray(exposures_us, dtype=np.float64)
    if isinstance(images, np.ndarray) and images.ndim == 3:
        stack = images
    else:
        stack = np.stack([np.asarray(im) for im in images])
    if stack.dtype != np.uint8 or stack.ndim != 3:
        raise ParameterError(f"Debevec-Malik needs a stack of 2-D uint8 images, got {stack.dtype} {stack.shape}")
    if exposures.shape != (stack.shape[0],):
        raise ParameterError(f"need one exposure per image: {stack.shape[0]} images, {exposures.size} exposures")
    if stack.shape[0] < 2:
        raise ParameterError("Debevec-Malik needs at least two exposures")
    if not np.all(np.isfinite(exposures)) or np.any(exposures <= 0):
        raise ParameterError("exposures must be positive and finite")
    if not (math.isfinite(smoothness) and smoothness > 0):
        raise ParameterError(f"smoothness must be positive, got {smoothness}")

    flat = stack.reshape(stack.shape[0], -1)
    mid = flat[int(np.argsort(exposures)[len(exposures) // 2])]
    order = np.argsort(mid, kind="stable")
    n = min(num_samples, order.size)
    picks = order[np.linspace(0, order.size - 1, n).round().astype(np.int64)]
    rng = np.random.default_rng(seed)
    picks = np.unique(np.concatenate([picks, rng.choice(order.size, size=min(n // 4, order.size), replace=False)]))
    zs = flat[:, picks].T.astype(np.int64)  # (P, J)
    p, j = zs.shape
    w = np.minimum(np.arange(256), 255 - np.arange(256)).astype(np.float64) + 1.0
    log_t = np.log(exposures / US_PER_S)

    rows = p * j + 254 + 1
    a = np.zeros((rows, 256 + p))
    b = np.zeros(rows)
    r = np.arange(p * j)
    wij = w[zs.ravel()]
    a[r, zs.ravel()] = wij
    a[r, 256 + np.repeat(np.arange(p), j)] = -wij
    b[: p * j] = wij * np.tile(log_t, p)
    k = p * j
    for z in range(1, 255):
        a[k, z - 1 : z + 2] = smoothness * w[z] * np.array([1.0, -2.0, 1.0])
        k += 1
    a[k, 128] = 1.0
    sol = scipy.linalg.lstsq(a, b, lapack_driver="gelsy")[0]
    g = sol[:256]
    # enforce strict monotonicity where the data did not pin the curve (extreme, unobserved values)
    for z in range(129, 256):
        g[z] = max(g[z], g[z - 1] + 1e-6)
    for z in range(127, -1, -1):
        g[z] = min(g[z], g[z + 1] - 1e-6)
    return CameraResponse(g)
