"""Exposure-control metrics: per frame, per run, the downstream SIFT evidence and simulator ground truth.

Per frame: the over-exposed rate (fraction of pixels ``Z >= 250``) and the under-exposed rate
(``Z <= 9``); their sum is the saturated rate. Per run: frames saturated at 50 % (the paper's
threshold) and at 10 % ("slightly saturated"), the mean over-/under-exposed rates, the recovery
time after each lighting step, and SIFT inlier matches between consecutive frames (the paper's
3D-reconstruction evidence: OpenCV SIFT, Lowe's ratio test, RANSAC on the fundamental matrix),
on the raw frames and on brightness-normalised frames (:func:`normalise_brightness`): SIFT's
contrast threshold is absolute, so a controller exposing darker frames loses keypoints for a
reason unrelated to what its frames recorded.

Ground truth (simulated frames only, :class:`GroundTruth`): the fraction of pixels whose true
irradiance was recorded inside the valid range (:func:`true_valid_fraction`), how well the frame's
digits track the true irradiance (:func:`rank_correlation`, Spearman's ρ on valid pixels) and
whether a region of interest — ``tunnel_exit``'s pedestrian — is well exposed on its first
visible frame (:func:`region_valid_fraction`). :func:`summarise_details` turns the per-frame
values (and the diagnosed saturation causes, :mod:`necviz.core.diagnosis`) into per-run figures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from .errors import ParameterError

OVER = 250
UNDER = 9


def over_exposed_rate(image: np.ndarray, threshold: int = OVER) -> float:
    """Fraction of pixels at or above ``threshold`` (default 250)."""
    return float(np.count_nonzero(image >= threshold)) / image.size


def under_exposed_rate(image: np.ndarray, threshold: int = UNDER) -> float:
    """Fraction of pixels at or below ``threshold`` (default 9)."""
    return float(np.count_nonzero(image <= threshold)) / image.size


def saturated_frames(over: np.ndarray, under: np.ndarray, fraction: float) -> int:
    """Frames whose over- or under-exposed rate exceeds ``fraction`` (0.5: saturated; 0.1: slightly)."""
    over, under = np.asarray(over), np.asarray(under)
    return int(np.count_nonzero((over > fraction) | (under > fraction)))


def recovery_times_ms(starts_us, saturated_rate, step_times_us, threshold: float = 0.1,
                      end_us: int | None = None) -> list[float | None]:
    """For each lighting step: ms from the step until the first frame from which on every frame
    (until the next step) has a saturated rate below ``threshold``; ``None`` if that never happens.

    ``starts_us``: exposure start of each frame (ascending); ``saturated_rate``: over + under.
    A frame that started before the step does not count as recovered.
    """
    starts = np.asarray(starts_us, dtype=np.int64)
    rate = np.asarray(saturated_rate, dtype=np.float64)
    if starts.shape != rate.shape:
        raise ParameterError("recovery_times_ms needs one saturated rate per frame start")
    steps = sorted(int(t) for t in step_times_us)
    out: list[float | None] = []
    for i, ts in enumerate(steps):
        t_next = steps[i + 1] if i + 1 < len(steps) else (end_us if end_us is not None else np.iinfo(np.int64).max)
        sel = np.flatnonzero((starts >= ts) & (starts < t_next))
        if sel.size == 0:
            out.append(None)
            continue
        bad = np.flatnonzero(rate[sel] >= threshold)
        if bad.size == 0:
            out.append((starts[sel[0]] - ts) / 1e3)
        elif bad[-1] + 1 < sel.size:
            out.append((starts[sel[bad[-1] + 1]] - ts) / 1e3)
        else:
            out.append(None)
    return out


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Mean structural similarity of two grey 8-bit images (Wang, Bovik, Sheikh & Simoncelli 2004,
    Eq. 13): Gaussian window σ = 1.5 truncated at 11x11, C1 = (0.01·255)², C2 = (0.03·255)²; the
    5-pixel border, where the window leaves the image, is not averaged. 1.0 for identical images.
    Used to choose the recordings' JPEG table (:mod:`necviz.sink`). O(pixels)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 2:
        raise ParameterError(f"ssim needs two grey images of one shape, got {a.shape} and {b.shape}")
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2

    def g(x):
        return cv2.GaussianBlur(x, (11, 11), 1.5, borderType=cv2.BORDER_REFLECT)

    ma, mb = g(a), g(b)
    va, vb, cov = g(a * a) - ma * ma, g(b * b) - mb * mb, g(a * b) - ma * mb
    m = ((2 * ma * mb + c1) * (2 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2))
    return float(m[5:-5, 5:-5].mean())


def normalise_brightness(image: np.ndarray, target: float = 128.0) -> np.ndarray:
    """The frame scaled so its mean digit is ``target`` (clipped to 0..255, rounded): ``Z' = Z · target / mean Z``.

    Removes the brightness bias of an absolute contrast threshold (SIFT's ``contrastThreshold``
    is on intensities scaled to [0, 1], so a frame exposed at 72 DN yields fewer keypoints than
    the same scene at 128 DN although it recorded the same structure). An all-black frame is
    returned unchanged.
    """
    img = np.asarray(image)
    mean = float(img.mean()) if img.size else 0.0
    if mean <= 0.0:
        return img
    out = img.astype(np.float32) * np.float32(target / mean)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


class SiftMatcher:
    """SIFT inlier matches between consecutive frames of one camera (keeps the previous frame's features).

    Matches pass Lowe's ratio test (``ratio``) and RANSAC on the fundamental matrix (``ransac_px``);
    fewer than 8 ratio-test matches count as 0 inliers.
    ``normalise``: match brightness-normalised frames (:func:`normalise_brightness`, mean 128 DN).
    """

    def __init__(self, ratio: float = 0.75, ransac_px: float = 3.0, max_features: int = 1000, normalise: bool = False):
        if not (0 < ratio < 1) or not (ransac_px > 0) or max_features < 8:
            raise ParameterError("SiftMatcher needs 0 < ratio < 1, ransac_px > 0, max_features >= 8")
        self.normalise = bool(normalise)
        self.sift = cv2.SIFT_create(nfeatures=max_features)
        self.matcher = cv2.BFMatcher(cv2.NORM_L2)
        self.ratio, self.ransac_px = ratio, ransac_px
        self._prev = None

    def features(self, image: np.ndarray):
        if self.normalise:
            image = normalise_brightness(image)
        kp, desc = self.sift.detectAndCompute(image, None)
        return (np.float32([k.pt for k in kp]) if kp else np.zeros((0, 2), np.float32)), desc

    def inliers(self, a, b) -> int:
        (pa, da), (pb, db) = a, b
        if da is None or db is None or len(pa) < 8 or len(pb) < 8:
            return 0
        good = [m for m, *rest in self.matcher.knnMatch(da, db, k=2) if rest and m.distance < self.ratio * rest[0].distance]
        if len(good) < 8:
            return 0
        src = pa[[m.queryIdx for m in good]]
        dst = pb[[m.trainIdx for m in good]]
        _, mask = cv2.findFundamentalMat(src, dst, cv2.FM_RANSAC, self.ransac_px, 0.99)
        return int(mask.sum()) if mask is not None else 0

    def next(self, image: np.ndarray) -> int | None:
        """Inliers between this frame and the previous one (``None`` for the first frame)."""
        cur = self.features(image)
        prev, self._prev = self._prev, cur
        return None if prev is None else self.inliers(prev, cur)


@dataclass
class RunMetrics:
    """Everything measured about one controller's frames in one run."""

    frames: int
    saturated_frames_50: int
    saturated_frames_10: int
    mean_over_exposed_rate: float
    mean_under_exposed_rate: float
    recovery_ms: float | None
    recovery_ms_per_step: list
    sift_inliers_mean: float | None

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def summarise(starts_us, over, under, step_times_us, sift_inliers=None, end_us=None) -> RunMetrics:
    """Per-run metrics from per-frame rates. ``recovery_ms`` is the mean over steps, ``None`` if any
    step never recovered (a controller that stays blind after one step gets no finite figure)."""
    over = np.asarray(over, dtype=np.float64)
    under = np.asarray(under, dtype=np.float64)
    rec = recovery_times_ms(starts_us, over + under, step_times_us, end_us=end_us)
    rec_mean = None if (not rec or any(r is None for r in rec)) else float(np.mean(rec))
    sift = [s for s in (sift_inliers or []) if s is not None]
    return RunMetrics(
        frames=int(over.size),
        saturated_frames_50=saturated_frames(over, under, 0.5),
        saturated_frames_10=saturated_frames(over, under, 0.1),
        mean_over_exposed_rate=float(over.mean()) if over.size else math.nan,
        mean_under_exposed_rate=float(under.mean()) if under.size else math.nan,
        recovery_ms=rec_mean,
        recovery_ms_per_step=rec,
        sift_inliers_mean=float(np.mean(sift)) if sift else None,
    )


# ---------------------------------------------------------------------------------------------
# ground truth (simulated frames only)
# ---------------------------------------------------------------------------------------------
#: A region is *well exposed* when at least this fraction of its pixels is valid (10..249 DN): the
#: complement of the "slightly saturated" threshold (more than 10 % clipped).
WELL_EXPOSED = 0.9
#: The lighting trace and the frame's level on it are means over every ``TRACE_STEP``-th pixel in each
#: direction (a fixed grid: a sixteenth of the pixels, ~13 µs a sample on a DAVIS346).
TRACE_STEP = 4


@dataclass(eq=False)
class GroundTruth:
    """What the simulator knows about one frame and a real camera cannot (``Frame.truth``).

    ``mean_irradiance``: ``Lbar(x) = (1/T) ∫_s^e L(x, t) dt`` per pixel (linear necviz units,
    float32, H x W), the exposure-averaged irradiance the frame was formed from
    (:func:`necviz.drivers.sim.aps.integrate_samples`); its noiseless digit is
    ``round(f(ln T + ln K + ln Lbar))`` (Eq. 1 of the paper, ``T`` in seconds).
    ``crf``: the camera's true response. ``light_t_us`` / ``light_log``: the scene's lighting
    trace — the mean of ``ln L`` over the sensor (on the grid of :data:`TRACE_STEP`) at each
    rendered scene sample from a look-back before the exposure to its end. ``latency_us``: a
    command takes effect at the first exposure starting at least this long after it was issued.
    ``exposure_min_us`` .. ``exposure_max_us``, ``gain_max``: what the camera accepts.
    ``readout_us``: the frame is delivered this long after its exposure ends. ``changes``: the
    scene's documented lighting changes (:class:`~necviz.drivers.sim.scene.LightingChange`).
    ``pedestrian_box``: ``(x0, y0, x1, y1)`` (pixels, end-exclusive) of the scene's pedestrian at
    mid-exposure, ``None`` when the scene has none or it is not visible.
    """

    mean_irradiance: np.ndarray
    crf: object
    light_t_us: np.ndarray
    light_log: np.ndarray
    latency_us: float = 0.0
    exposure_min_us: float = 1.0
    exposure_max_us: float = math.inf
    gain_max: float = 1.0
    readout_us: float = 0.0
    changes: tuple = ()
    pedestrian_box: tuple | None = None
    _log_mean: float | None = field(default=None, init=False, repr=False)

    def light_at(self, t_us: float) -> float:
        """The scene's mean ``ln L`` at ``t_us`` (linear between trace samples, held beyond them)."""
        if self.light_t_us.size == 0:
            return math.nan
        return float(np.interp(float(t_us), self.light_t_us.astype(np.float64), self.light_log))

    def log_mean(self) -> float:
        """Mean over the sensor (same grid as the trace) of ``ln Lbar``: the frame's light level on the trace's scale."""
        if self._log_mean is None:
            sub = self.mean_irradiance[::TRACE_STEP, ::TRACE_STEP]
            self._log_mean = float(np.mean(np.log(np.maximum(sub, np.float32(1e-30)))))
        return self._log_mean

    def bounds(self, exposure_us: float, gain: float, shift: float = 0.0) -> tuple[float, float]:
        """Linear irradiance bounds ``[lo, hi)`` of pixels recorded valid (``UNDER < Z < OVER``) at this
        exposure, with the light scaled by ``e^-shift``: ``g(UNDER + ½) <= ln T + ln K + ln Lbar - shift < g(OVER - ½)``."""
        log_tk = math.log(exposure_us / 1e6) + math.log(gain)
        g_lo = float(self.crf.log_exposure(UNDER + 0.5))
        g_hi = float(self.crf.log_exposure(OVER - 0.5))
        return math.exp(g_lo - log_tk + shift), math.exp(g_hi - log_tk + shift)


def true_rates(truth: GroundTruth, exposure_us: float, gain: float, shift: float = 0.0, step: int = 1) -> tuple[float, float]:
    """``(over, under)``: fractions of pixels whose noiseless digit would clip at this exposure if the
    light were ``shift`` ln units lower than it was (``shift = 0``: as it was). ``step`` subsamples a
    fixed grid (every ``step``-th pixel in each direction)."""
    lo, hi = truth.bounds(exposure_us, gain, shift)
    lb = truth.mean_irradiance if step == 1 else truth.mean_irradiance[::step, ::step]
    n = lb.size
    return float(np.count_nonzero(lb >= np.float32(hi))) / n, float(np.count_nonzero(lb < np.float32(lo))) / n


def true_valid_fraction(truth: GroundTruth, exposure_us: float, gain: float) -> float:
    """Fraction of pixels whose true exposure-averaged irradiance falls inside the recordable range:
    ``g(9.5) <= ln T + ln K + ln Lbar < g(249.5)`` — the pixels a noiseless camera records in 10..249 DN."""
    over, under = true_rates(truth, exposure_us, gain)
    return 1.0 - over - under


def rank_correlation(image: np.ndarray, mean_irradiance: np.ndarray, max_samples: int = 10_000,
                     min_pixels: int = 64) -> float:
    """Spearman's ρ between the frame's digits and the true irradiance, on pixels recorded valid (10..249).

    Any monotone response preserves ranks, so ρ measures what noise, quantisation and too few digit
    levels (a dark frame) leave of the scene's order; clipped pixels are excluded (their share is
    :func:`true_valid_fraction`'s business). Pixels on a fixed grid (every ``k``-th in each
    direction, ``k`` chosen so at most ``max_samples`` remain: ~0.5 ms a frame). Digit ties get
    their average rank (from the 256-bin histogram). NaN with fewer than ``min_pixels`` valid pixels.
    """
    z = np.asarray(image)
    k = max(1, int(math.ceil(math.sqrt(z.size / max_samples))))
    zs = z[::k, ::k].ravel()
    ls = np.asarray(mean_irradiance)[::k, ::k].ravel()
    m = (zs > UNDER) & (zs < OVER)
    n = int(np.count_nonzero(m))
    if n < min_pixels:
        return math.nan
    zz, ll = zs[m], ls[m]
    counts = np.bincount(zz, minlength=256)
    cum = np.cumsum(counts)
    rz = (cum - (counts - 1) / 2.0)[zz]  # average rank of each digit value (1-based)
    rl = np.empty(n, np.float64)
    rl[np.argsort(ll)] = np.arange(1, n + 1)
    rz -= rz.mean()
    rl -= rl.mean()
    # element-wise sums, not np.dot: a BLAS call on a busy machine can cost milliseconds (thread hand-off)
    den = math.sqrt(float((rz * rz).sum()) * float((rl * rl).sum()))
    return float((rz * rl).sum() / den) if den > 0 else math.nan


def region_valid_fraction(image: np.ndarray, box) -> float:
    """Fraction of the pixels in ``box = (x0, y0, x1, y1)`` (end-exclusive) recorded valid (10..249 DN)."""
    x0, y0, x1, y1 = (int(v) for v in box)
    roi = np.asarray(image)[max(y0, 0):y1, max(x0, 0):x1]
    if roi.size == 0:
        return math.nan
    return float(np.count_nonzero((roi > UNDER) & (roi < OVER))) / roi.size


def _finite_mean(values) -> float | None:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else None


def summarise_details(sequence, sift_normalised=None, true_valid=None, rank_corr=None, pedestrian_valid=None,
                      causes=None) -> dict:
    """Per-run figures beyond :func:`summarise`, from per-frame columns (NaN / ``''`` where not measured).

    * ``sift_inliers_normalised_mean``: mean SIFT inliers between consecutive brightness-normalised frames;
    * ``true_valid_fraction_mean``: mean over frames of :func:`true_valid_fraction`;
    * ``rank_correlation_mean``: mean over frames of :func:`rank_correlation`;
    * ``pedestrian_frame``, ``pedestrian_valid_fraction``, ``pedestrian_well_exposed``: the first frame
      on which the scene's pedestrian is visible, the valid fraction of its box there, and whether that
      is at least :data:`WELL_EXPOSED` (``None`` without a pedestrian);
    * ``saturation_causes``: ``{cause: frames}`` over the saturated frames, every cause of
      :data:`necviz.core.diagnosis.CAUSES` present (0 when it did not occur).

    ``None`` where nothing was measured (no SIFT, real frames without ground truth).
    """
    seq = np.asarray(sequence)
    out = {"sift_inliers_normalised_mean": _finite_mean(sift_normalised if sift_normalised is not None else []),
           "true_valid_fraction_mean": _finite_mean(true_valid if true_valid is not None else []),
           "rank_correlation_mean": _finite_mean(rank_corr if rank_corr is not None else []),
           "pedestrian_frame": None, "pedestrian_valid_fraction": None, "pedestrian_well_exposed": None}
    if pedestrian_valid is not None:
        pv = np.asarray(pedestrian_valid, dtype=np.float64)
        idx = np.flatnonzero(np.isfinite(pv))
        if idx.size:
            i = int(idx[0])
            out["pedestrian_frame"] = int(seq[i])
            out["pedestrian_valid_fraction"] = float(pv[i])
            out["pedestrian_well_exposed"] = bool(pv[i] >= WELL_EXPOSED)
    from .diagnosis import CAUSES  # (diagnosis imports this module)

    counts = dict.fromkeys(CAUSES, 0)  # every cause, so tables of many runs share their columns
    for c in (causes if causes is not None else []):
        if c:
            counts[str(c)] = counts.get(str(c), 0) + 1
    out["saturation_causes"] = counts
    return out
