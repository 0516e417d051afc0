"""Bégin & Hunter (Sensors 2022): CRF-predicted gradient-optimal exposure with motion-aware gain.

Algorithm, per frame (summary in docs/baselines.md; the default mode of the ROS node in the public
implementation github.com/MIT-Bilab/vo-autoexpose, ``GRADINFO_SCORE, EV_CORRECTIONS, OPTIFLOW_ESTIM``):

1. Resize the frame to the working size 360×270 (``work_size``; linear interpolation; the
   original's median blur is overwritten in its code, so there is none here either).
2. Predict 7 images at ``ΔEV ∈ {−2, −1, −0.5, 0, 0.5, 1, 2}`` with 256-entry LUTs built from
   the camera response ``crf``: ``Z' = f(f⁻¹(Z)·2^{−ΔEV})``, i.e. ``Z' = intensity(g(Z) −
   ΔEV·ln 2)`` rounded and clipped to 0..255 (the original hard-codes LUTs of its FLIR camera).
   **EV convention: larger EV = darker**; ``ΔEV > 0`` predicts a darker image and the
   exposure-gain product scales as ``2^{−EV}``.
3. Score each prediction: 3×3 Sobel magnitude → 8 bit (rounded, saturated at 255) → Shim-style
   LUT ``q(i) = 255·log10(λ(i − σ)/255 + 1)/log10(λ(255 − σ)/255 + 1)`` for ``i ≥ σ`` (else 0)
   with published ``σ = 255·0.3``, ``λ = 1000``; ``score = Σ q / 1e5``.
4. Degree-6 polynomial through the 7 (ΔEV, score) points (an interpolation); Newton's method
   on its derivative from ``ΔEV = 0`` (≤ 10 iterations, tolerance 1e-5). Fallback to the argmax
   of the 7 samples if the second derivative at 0 is ≥ 0, Newton does not converge or its
   result leaves [−2, 2]. Mean intensity < 10 → ``ΔEV* = −2`` (brighten); > 245 → ``+2``.
5. Saturation feedback from the frame two frames back: ``predicted = score_pred(t−2) −
   score_0(t−2)`` (``score_pred`` = the fitted score at the ΔEV* chosen then),
   ``actual = score_0(t) − score_0(t−2)``; ``fb = 1.5`` if ``predicted > 0`` and
   ``actual/(predicted + 0.1) > 1.1`` else 1. ``EV_next = EV + fb·ΔEV*``.
6. Motion: Farneback optical flow between consecutive frames downsampled 4× (published
   parameters ``pyr_scale 0.5, levels 1, winsize 5, iterations 3, poly_n 5, poly_sigma 1.1``),
   the flow rescaled to the frame's full resolution, ``v = (mean |flow|)²`` (px²/frame², the
   code squares the mean). Frames whose 4× downsampled size is below 8 px give ``v = 0``.
7. Exposure/gain split: minimise ``v·T + w·(K − 1)`` subject to ``T·K = c`` →
   ``K* = sqrt((v·c + 8)/w)``, ``w = 0.02``; then K clamped to ``[1, gain_max]``,
   ``T = c/K`` clamped to the exposure limits, ``K = c/T`` clamped again.

Mapping decisions (ours):

* ``c`` is the exposure-gain product of the next frame **in milliseconds at unit gain**
  (``c = T_ms·K_linear``), derived from the product the camera applied to this frame:
  ``c_next = T·K·2^{−fb·ΔEV*}``. The original computes ``c = F²·2^{−EV}`` with ``T`` in seconds,
  which makes ``v·c ≪ 8`` for any plausible motion (the motion term would be inert); in µs it
  would always dominate. In ms, 1–3 px/frame of motion at a few-ms exposure is comparable with
  the constant 8, which is the balance the published constants express.
* ``K*`` is in **dB** (the original clamps it to [0.1, 40] dB) and converted to linear gain
  ``10^{K*/20}`` before the camera clamp. Consequence of the published constants: at rest
  ``K* = sqrt(8/0.02) = 20 dB`` (10×); motion raises it. On a camera without gain
  (``gain_max = 1``, the DAVIS346 default) the split is always ``K = 1, T = c``.
* ``v`` is measured in pixels of the incoming frame (not of the 360×270 working image).
* Exposure/gain of the current frame come from the frame itself (``Controller.on_frame``),
  so the EV the correction is applied to is always the EV actually used.

Commands are always finite and inside ``self.limits`` (gain ≥ 1), whatever the image.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import ClassVar

import cv2
import numpy as np

from necviz.core.checks import check_number as _num
from necviz.core.control.controller import CameraLimits, Controller, ControllerOptions, ExposureCommand, Tunable
from necviz.core.crf import CameraResponse, default_davis346
from necviz.core.errors import ParameterError
from necviz.core.frames import Frame

#: The published ΔEV corrections (larger EV = darker).
DELTA_EVS = np.array([-2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 2.0])
EV_RANGE = 2.0
#: Farneback parameters of the original (pyr_scale, levels, winsize, iterations, poly_n, poly_sigma).
FARNEBACK = (0.5, 1, 5, 3, 5, 1.1)
FLOW_DOWNSAMPLE = 4


def ev_luts(crf: CameraResponse, delta_evs=DELTA_EVS) -> np.ndarray:
    """``(len(delta_evs), 256)`` uint8 LUTs ``Z' = f(f⁻¹(Z)·2^{−ΔEV})`` (rounded, clipped)."""
    out = np.empty((len(delta_evs), 256), dtype=np.uint8)
    for i, dev in enumerate(delta_evs):
        z = crf.intensity(crf.g - float(dev) * math.log(2.0))
        out[i] = np.clip(np.round(z), 0, 255).astype(np.uint8)
    return out


def shim_lut(sigma: float = 255 * 0.3, lam: float = 1000.0) -> np.ndarray:
    """Bégin's 8-bit Shim mapping ``q(i)`` (float64, 256 entries)."""
    i = np.arange(256, dtype=np.float64)
    q = np.zeros(256)
    on = i >= sigma
    q[on] = 255.0 * np.log10(lam * (i[on] - sigma) / 255.0 + 1.0) / math.log10(lam * (255.0 - sigma) / 255.0 + 1.0)
    return q


def gradient_score(image_u8: np.ndarray, q: np.ndarray) -> float:
    """Sobel magnitude → 8 bit → ``q`` → sum / 1e5."""
    img = np.asarray(image_u8)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3)
    mag8 = cv2.convertScaleAbs(cv2.magnitude(gx, gy))
    hist = np.bincount(mag8.ravel(), minlength=256)
    return float(hist @ q) / 1e5


def newton_optimum(
    coef, x0: float = 0.0, max_iter: int = 10, tol: float = 1e-5, bound: float = EV_RANGE
) -> float | None:
    """Newton on ``p'(x) = 0`` from ``x0`` for polynomial ``coef`` (np.polyfit order).

    Returns ``None`` if ``p''(x0) >= 0`` (not a maximum), Newton does not converge within
    ``max_iter`` steps, produces a non-finite value or leaves ``[−bound, bound]``.
    """
    p = np.poly1d(coef)
    d1, d2 = p.deriv(1), p.deriv(2)
    x = float(x0)
    if not d2(x) < 0:
        return None
    for _ in range(max_iter):
        h = d2(x)
        if not np.isfinite(h) or h == 0:
            return None
        step = d1(x) / h
        x -= step
        if not math.isfinite(x) or abs(x) > bound:
            return None
        if abs(step) < tol:
            return x
    return None


def flow_speed(prev_small: np.ndarray, small: np.ndarray, scale_x: float, scale_y: float) -> float:
    """``v = (mean |flow|)²`` in full-resolution px²/frame² (Farneback, published parameters)."""
    # OpenCV allocates the flow when it is None; the stubs of OpenCV < 5 do not allow None (5.x do)
    flow = cv2.calcOpticalFlowFarneback(prev_small, small, None, *FARNEBACK, 0)  # type: ignore[call-overload, unused-ignore]
    mag = np.hypot(flow[..., 0] * scale_x, flow[..., 1] * scale_y)
    v = float(mag.mean()) ** 2
    return v if math.isfinite(v) else 0.0


@dataclass(frozen=True)
class BeginOptions(ControllerOptions):
    """Bégin's settings.

    Parameters
    ----------
    work_size : tuple of int
        (width, height) the frame is resized to (published 360×270), each in 8..4096.
    sigma, lam : float
        Shim-LUT threshold (8-bit gradient) and λ (published 76.5, 1000).
    w : float
        Noise weight of the exposure/gain split (published 0.02), > 0.
    noise_offset : float
        The constant under the root of ``K*`` (published 8), >= 0.
    feedback_gain : float
        Saturation feedback factor (published 1.5), in [1, 4].
    ev_range : float
        The largest ΔEV the method predicts and applies (published 2): the predicted images are at
        ``ΔEV ∈ ev_range·{−1, −½, −¼, 0, ¼, ½, 1}`` (the published set at 2), Newton's result must
        lie within ``±ev_range`` and a too dark / too bright frame moves ``∓ev_range``. Its step-size
        mapping, as Navid's ``ev_per_unit`` is (``benchmarks/tuning.py`` tunes both); in [0.5, 8].
    """

    TUNABLE: ClassVar[tuple[Tunable, ...]] = (
        Tunable("feedback_gain", "1", "saturation feedback strength", 1.0, 4.0),
        Tunable("w", "1", "weight of the flow term in the exposure/gain split", 0.0, lo_open=True),
        Tunable("ev_range", "EV", "largest ΔEV predicted and applied per frame (published 2)", 0.5, 8.0),
    )

    work_size: tuple[int, int] = (360, 270)
    sigma: float = 255 * 0.3
    lam: float = 1000.0
    w: float = 0.02
    noise_offset: float = 8.0
    feedback_gain: float = 1.5
    ev_range: float = EV_RANGE

    def check(self) -> None:
        work_size = self.work_size
        try:
            ws = tuple(int(v) for v in work_size)
            ok = len(ws) == 2 and all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in work_size)
        except (TypeError, ValueError):
            ok = False
        if not ok or not all(8 <= v <= 4096 for v in ws):
            raise ParameterError(f"work_size must be two integers (width, height) in 8..4096, got {work_size!r}")
        object.__setattr__(self, "work_size", ws)
        object.__setattr__(self, "sigma", _num("sigma", self.sigma, 0.0, hi=254.0))
        object.__setattr__(self, "lam", _num("lam", self.lam, 0.0, lo_open=True))
        object.__setattr__(self, "noise_offset", _num("noise_offset", self.noise_offset, 0.0))


class BeginController(Controller):
    """Bégin & Hunter 2022: CRF-predicted ΔEV maximising Shim's gradient score, motion-aware gain.

    Parameters
    ----------
    limits : CameraLimits
        Camera exposure/gain limits (every command is clamped to them).
    exposure_us, gain : float
        Initial setting.
    options : BeginOptions, optional
        The settings (default: the published ones).
    crf : CameraResponse, optional
        The camera response used to predict the ΔEV images (default ``default_davis346()``).
    """

    name = "begin"
    OPTIONS = BeginOptions
    options: BeginOptions  # set by Controller.__init__ (always an instance of OPTIONS)

    def __init__(
        self,
        limits: CameraLimits,
        exposure_us: float = 5_000.0,
        gain: float = 1.0,
        options: BeginOptions | None = None,
        crf: CameraResponse | None = None,
    ):
        if crf is None:
            crf = default_davis346()
        if not isinstance(crf, CameraResponse):
            raise ParameterError(f"crf must be a CameraResponse, got {type(crf).__name__}")
        self.crf = crf
        super().__init__(limits, exposure_us, gain, options)
        self._history: deque[tuple[float, float]] = deque(maxlen=2)  # (score_0, score_pred) per frame
        self._prev_small: np.ndarray | None = None
        # diagnostics of the last frame
        self.last_scores: np.ndarray | None = None
        self.last_delta_ev = 0.0
        self.last_feedback = 1.0
        self.last_motion = 0.0
        self.last_ev = -math.log2(self.exposure_us * self.gain / 1e6)

    def _apply_options(self, options: ControllerOptions) -> None:
        assert isinstance(options, BeginOptions)  # Controller checks it; replace() keeps the class
        super()._apply_options(options)
        self.q = shim_lut(options.sigma, options.lam)
        self.delta_evs = DELTA_EVS * (options.ev_range / EV_RANGE)
        self.luts = ev_luts(self.crf, self.delta_evs)

    # -- the pieces ---------------------------------------------------------------------------
    def working_image(self, image: np.ndarray) -> np.ndarray:
        return cv2.resize(image, self.options.work_size, interpolation=cv2.INTER_LINEAR)

    def predict(self, image: np.ndarray, delta_ev: float) -> np.ndarray:
        """The image the camera would give at ``EV + delta_ev`` (any ΔEV, via a fresh LUT)."""
        lut = ev_luts(self.crf, [delta_ev])[0]
        return lut[np.asarray(image, dtype=np.uint8)]

    def scores(self, work: np.ndarray) -> np.ndarray:
        return np.array([gradient_score(cv2.LUT(work, lut), self.q) for lut in self.luts])

    def optimal_delta_ev(self, work: np.ndarray) -> tuple[float, float, float]:
        """``(ΔEV*, predicted score at ΔEV*, score at ΔEV = 0)`` for a working image."""
        s = self.scores(work)
        self.last_scores = s
        s0 = float(s[3])
        mean = float(work.mean())
        r = self.options.ev_range
        if mean < 10.0:
            return -r, float(s[0]), s0
        if mean > 245.0:
            return r, float(s[-1]), s0
        i_best = int(np.argmax(s))
        if np.all(s == s[0]):  # no information (e.g. textureless): hold
            return 0.0, s0, s0
        coef = np.polyfit(self.delta_evs, s, 6)
        x = newton_optimum(coef, bound=r)
        if x is None:
            return float(self.delta_evs[i_best]), float(s[i_best]), s0
        pred = float(np.polyval(coef, x))
        return x, pred if math.isfinite(pred) else float(s[i_best]), s0

    def feedback(self, s0: float) -> float:
        """Saturation feedback against the frame two frames back (1 until there is one)."""
        if len(self._history) < 2:
            return 1.0
        s0_old, pred_old = self._history[0]
        predicted = pred_old - s0_old
        actual = s0 - s0_old
        if predicted > 0 and actual / (predicted + 0.1) > 1.1:
            return self.options.feedback_gain
        return 1.0

    def motion(self, image: np.ndarray) -> float:
        """``v`` between the previous frame and this one (0 for the first or tiny frames)."""
        h, w = image.shape
        sw, sh = w // FLOW_DOWNSAMPLE, h // FLOW_DOWNSAMPLE
        if min(sw, sh) < 8:
            self._prev_small = None
            return 0.0
        small = cv2.resize(image, (sw, sh), interpolation=cv2.INTER_AREA)
        prev, self._prev_small = self._prev_small, small
        if prev is None or prev.shape != small.shape:
            return 0.0
        try:
            return flow_speed(prev, small, w / sw, h / sh)
        except cv2.error:
            return 0.0

    def split(self, c_us: float, v: float) -> tuple[float, float]:
        """Exposure/gain split of the product ``c`` (µs at unit gain) under motion ``v``."""
        lim = self.limits
        c_us = min(max(c_us, lim.exposure_min_us), lim.exposure_max_us * lim.gain_max)
        c_ms = c_us / 1000.0
        k_db = math.sqrt((max(v, 0.0) * c_ms + self.options.noise_offset) / self.options.w)
        k = 10.0 ** (min(k_db, 400.0) / 20.0)
        k = min(max(k, 1.0), lim.gain_max)
        t = min(max(c_us / k, lim.exposure_min_us), lim.exposure_max_us)
        k = min(max(c_us / t, 1.0), lim.gain_max)
        return lim.clamp(t, k)

    # -- packets ------------------------------------------------------------------------------
    def on_frame(self, frame: Frame) -> ExposureCommand | None:
        super().on_frame(frame)
        image = frame.image
        c_now = self.exposure_us * self.gain
        if image.size == 0:
            t, k = self.split(c_now, 0.0)
            return ExposureCommand(t, k, int(self.now_us), self.name)
        work = self.working_image(image)
        dev, pred, s0 = self.optimal_delta_ev(work)
        fb = self.feedback(s0)
        self._history.append((s0, pred))
        v = self.motion(image)
        step = fb * dev
        c_next = c_now * 2.0 ** (-step)
        if not math.isfinite(c_next) or c_next <= 0:
            c_next = c_now
        t, k = self.split(c_next, v)
        self.last_delta_ev, self.last_feedback, self.last_motion = dev, fb, v
        self.last_ev = -math.log2(t * k / 1e6)
        return ExposureCommand(t, k, int(self.now_us), self.name)
