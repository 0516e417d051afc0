"""Shim et al.: gradient-based exposure control (IROS 2014; IEEE TCSVT 2018), image only.

Algorithm, per frame (summary in docs/baselines.md):

1. Gamma-synthesised images ``I_γ = I^γ`` on ``I = Z / 255 ∈ [0, 1]`` for
   ``γ ∈ {1/1.9, 1/1.5, 1/1.2, 1, 1.2, 1.5, 1.9}``. **Convention: γ < 1 brightens** (I^γ > I),
   so an optimum ``γ̂ < 1`` means "the scene wants more light". (Some implementations tabulate
   ``I^{1/γ}``, the inverse convention; with ours the published update rules below already
   have the right sign: ``γ̂ < 1`` lengthens the exposure, ``γ̂ > 1`` shortens it.)
2. Gradient metric ``M = Σ_i m̄_i`` with ``m̄ = log(λ(m − δ) + 1) / log(λ(1 − δ) + 1)`` for
   ``m ≥ δ`` (0 otherwise); published ``δ = 0.06``, ``λ = 10³``.
   *Mapping decision (ours):* ``m`` is the 3×3 Sobel magnitude of the gamma image on the
   0..255 scale, saturated at 255 and divided by 255 — the "Sobel → 8-bit → normalise"
   convention Bégin & Hunter's implementation uses (kept continuous, not quantised). ``δ =
   0.06`` is then a Sobel response of 15.3 DN, i.e. a ~4 DN step edge.
3. 5th-order least-squares polynomial through the 7 samples ``M(γ)``; ``γ̂`` = argmax of the
   polynomial on ``[1/1.9, 1.9]`` (stationary points and end points); if that maximum is lower
   than the best sample (the fit overshoots/undershoots) ``γ̂`` falls back to the best sampled γ.
4. Update (``α = 1/2`` if ``γ̂ ≥ 1`` else 1):

   * ``rule="2018"`` (default, nonlinear): ``R = d·tan{(2 − γ̂)·atan(1/d) − atan(1/d)} + 1``,
     ``T ← (1 + α·Kp·(R − 1))·T``, ``d = 0.1`` (so ``R(1) = 1``, ``R(1/1.9) ≈ 1.084``,
     ``R(1.9) ≈ 0.603``). **Kp default 1.6** for this rule: the value the public 2018
     re-implementation (github.com/MIT-Bilab/vo-autoexpose) pairs with ``d = 0.1``. With the 2014
     gain 0.2 the brightening step would be at most 1.7 % per frame (R − 1 ≤ 0.084), which
     cannot follow any real lighting change.
   * ``rule="2014"`` (linear): ``T ← (1 + α·Kp·(1 − γ̂))·T``, **Kp default 0.2** (uzh, norlab
     and aer configurations).

   The update multiplies the exposure-gain *product* the camera applied to this frame
   (``H = T·K``), not only ``T`` — so a frame taken with gain is corrected for its gain.
5. Gain extension (Mehta et al. 2020, aer): if the new exposure ``H`` (at gain 1) stays inside
   ``[exposure_min_us, exposure_max_us]`` it is used with gain 1; otherwise the exposure is
   clamped and the remaining EV difference ``ΔEV = log2(H / T_clamped)`` goes to the gain at
   **6 dB per EV** (``K = 10^{6·ΔEV/20}`` ≈ 1.995^ΔEV), clamped to ``[1, gain_max]``
   (negative ΔEV, below the exposure minimum, leaves gain 1).

Our additions (robustness, documented): when no pixel passes the threshold in any gamma
image (all-black, all-white or textureless frames) the metric carries no information; then
``γ̂ = 1/1.9`` if the mean intensity is below 10 (brighten as fast as the rule allows),
``1.9`` if above 245 (darken), else 1 (hold) — Bégin & Hunter's saturation thresholds. An
empty image holds the current setting. Commands are always finite and inside ``self.limits``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import cv2
import numpy as np

from necviz.core.checks import check_number as _num
from necviz.core.control.controller import CameraLimits, Controller, ControllerOptions, ExposureCommand, Tunable
from necviz.core.errors import ParameterError
from necviz.core.frames import Frame

#: The published gamma set (Shim 2014/2018), convention I_γ = I^γ (γ < 1 brightens).
GAMMAS = np.array([1 / 1.9, 1 / 1.5, 1 / 1.2, 1.0, 1.2, 1.5, 1.9])
GAMMA_MIN = 1 / 1.9
GAMMA_MAX = 1.9
DB_PER_EV = 6.0  # Mehta et al. 2020 gain extension
DEFAULT_KP = {"2018": 1.6, "2014": 0.2}
DARK_MEAN, BRIGHT_MEAN = 10.0, 245.0  # no-information fallback thresholds (Bégin's)


def nonlinear_ratio(gamma_hat: float, d: float = 0.1) -> float:
    """Shim 2018's ``R(γ̂) = d·tan{(2 − γ̂)·atan(1/d) − atan(1/d)} + 1`` (R(1) = 1)."""
    a = math.atan(1.0 / d)
    return d * math.tan((2.0 - gamma_hat) * a - a) + 1.0


def sobel_magnitude(img: np.ndarray) -> np.ndarray:
    """3×3 Sobel gradient magnitude (float32) of a 2-D image."""
    img = np.asarray(img, dtype=np.float32)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3)
    return cv2.magnitude(gx, gy)


def gradient_metric(image: np.ndarray, delta: float = 0.06, lam: float = 1e3) -> float:
    """``M = Σ m̄_i`` of a 0..255 image (uint8 or float): Sobel magnitude saturated at 255, /255."""
    if np.size(image) == 0:
        return 0.0
    # m̄·N = log(max(λ(m − δ), 0) + 1): zero below the threshold, no masking needed
    m = np.minimum(sobel_magnitude(image), np.float32(255.0))
    x = np.maximum(m * np.float32(lam / 255.0) - np.float32(lam * delta), np.float32(0.0)) + np.float32(1.0)
    norm = math.log(lam * (1.0 - delta) + 1.0)
    return float(cv2.log(x).sum(dtype=np.float64) / norm)


def gamma_images(image: np.ndarray, gammas=GAMMAS) -> list[np.ndarray]:
    """``255·(Z/255)^γ`` for each γ, via 256-entry float LUTs (no re-quantisation)."""
    z = np.asarray(image, dtype=np.uint8)
    base = np.arange(256, dtype=np.float64) / 255.0
    return [(255.0 * base**g).astype(np.float32)[z] for g in gammas]


def best_gamma(gammas: np.ndarray, scores: np.ndarray, degree: int = 5) -> float:
    """Argmax on [1/1.9, 1.9] of the degree-5 LS polynomial through ``(γ, M)``; best sample as fallback."""
    scores = np.asarray(scores, dtype=np.float64)
    i_best = int(np.argmax(scores))
    g_best = float(gammas[i_best])
    scale = float(np.max(np.abs(scores)))
    if not np.all(np.isfinite(scores)) or scale <= 0:
        return g_best
    try:
        coef = np.polyfit(gammas, scores / scale, degree)
    except (np.linalg.LinAlgError, ValueError):
        return g_best
    p = np.poly1d(coef)
    cands = [GAMMA_MIN, GAMMA_MAX]
    for r in p.deriv().roots:
        if abs(r.imag) < 1e-9 and GAMMA_MIN <= r.real <= GAMMA_MAX:
            cands.append(float(r.real))
    vals = p(np.array(cands))
    k = int(np.argmax(vals))
    if not np.isfinite(vals[k]) or vals[k] < scores[i_best] / scale:
        return g_best
    return float(cands[k])


@dataclass(frozen=True)
class ShimOptions(ControllerOptions):
    """Shim's settings.

    Parameters
    ----------
    rule : str
        ``"2018"`` (nonlinear, default) or ``"2014"`` (linear) update.
    kp : float, optional
        Proportional gain in (0, 10); ``None`` picks the rule's default (2018: 1.6, 2014: 0.2).
    d : float
        2018 nonlinearity parameter (published 0.1), > 0.
    delta : float
        Gradient activation threshold δ in [0, 1) (published 0.06).
    lam : float
        λ > 0 of the log mapping (published 1e3).
    """

    TUNABLE: ClassVar[tuple[Tunable, ...]] = (
        Tunable("kp", "1", "proportional gain of the exposure update", 0.0, 10.0, True, True),
        Tunable("d", "1", "damping of the 2018 update rule", 0.0, lo_open=True),
    )

    rule: str = "2018"
    kp: float | None = None
    d: float = 0.1
    delta: float = 0.06
    lam: float = 1e3

    def check(self) -> None:
        if self.rule not in DEFAULT_KP:
            raise ParameterError(f"rule must be '2018' or '2014', got {self.rule!r}")
        if self.kp is None:
            object.__setattr__(self, "kp", DEFAULT_KP[self.rule])
        object.__setattr__(self, "delta", _num("delta", self.delta, 0.0, 1.0, hi_open=True))
        object.__setattr__(self, "lam", _num("lam", self.lam, 0.0, lo_open=True))


class ShimController(Controller):
    """Shim et al. gradient-based AE with the Mehta et al. 2020 gain extension (image only).

    Parameters
    ----------
    limits : CameraLimits
        Camera exposure/gain limits (every command is clamped to them).
    exposure_us, gain : float
        Initial setting.
    options : ShimOptions, optional
        The settings (default: the published 2018 rule).
    """

    name = "shim"
    OPTIONS = ShimOptions
    options: ShimOptions  # set by Controller.__init__ (always an instance of OPTIONS)

    def __init__(
        self,
        limits: CameraLimits,
        exposure_us: float = 5_000.0,
        gain: float = 1.0,
        options: ShimOptions | None = None,
    ):
        super().__init__(limits, exposure_us, gain, options)
        self.last_scores: np.ndarray | None = None
        self.last_gamma: float = 1.0
        self.last_ratio: float = 1.0

    # -- the pieces ---------------------------------------------------------------------------
    def metric(self, image: np.ndarray) -> float:
        return gradient_metric(image, self.options.delta, self.options.lam)

    def gamma_scores(self, image: np.ndarray) -> np.ndarray:
        return np.array([self.metric(im) for im in gamma_images(image)])

    def estimate_gamma(self, image: np.ndarray) -> float:
        """``γ̂`` for an image (with the no-information fallback, see the module docstring)."""
        scores = self.gamma_scores(image)
        self.last_scores = scores
        if not np.any(scores > 0):
            mean = float(np.mean(image)) if image.size else 128.0
            return GAMMA_MIN if mean < DARK_MEAN else (GAMMA_MAX if mean > BRIGHT_MEAN else 1.0)
        return best_gamma(GAMMAS, scores)

    def exposure_ratio(self, gamma_hat: float) -> float:
        """The multiplicative exposure update ``T_{t+1}/T_t`` for ``γ̂`` under the chosen rule."""
        alpha = 0.5 if gamma_hat >= 1.0 else 1.0
        if self.options.rule == "2018":
            step = nonlinear_ratio(gamma_hat, self.options.d) - 1.0
        else:
            step = 1.0 - gamma_hat
        kp = self.options.kp
        assert kp is not None  # ShimOptions.check fills in the rule's default
        ratio = 1.0 + alpha * kp * step
        if not math.isfinite(ratio):
            return 1.0
        return min(max(ratio, 0.05), 20.0)  # a non-positive factor (large kp) would be meaningless

    def split(self, product_us: float) -> tuple[float, float]:
        """Mehta et al. gain extension: exposure first, leftover EV to gain at 6 dB/EV."""
        lim = self.limits
        if not math.isfinite(product_us) or product_us <= 0:
            product_us = lim.exposure_min_us
        t = min(max(product_us, lim.exposure_min_us), lim.exposure_max_us)
        gain = 1.0
        if product_us > lim.exposure_max_us:
            d_ev = math.log2(product_us / t)
            gain = 10.0 ** (DB_PER_EV * d_ev / 20.0)
        return lim.clamp(t, gain)

    # -- packets ------------------------------------------------------------------------------
    def on_frame(self, frame: Frame) -> ExposureCommand | None:
        super().on_frame(frame)
        if frame.image.size == 0:
            exposure, gain = self.split(self.exposure_us * self.gain)
            return ExposureCommand(exposure, gain, int(self.now_us), self.name)
        g = self.estimate_gamma(frame.image)
        self.last_gamma = g
        self.last_ratio = self.exposure_ratio(g)
        exposure, gain = self.split(self.exposure_us * self.gain * self.last_ratio)
        return ExposureCommand(exposure, gain, int(self.now_us), self.name)
