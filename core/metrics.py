"""Exposure-control metrics: per frame and per run, from the frames' digits (and the simulator's ground truth).

Per frame: the over-exposed rate (fraction of pixels ``Z >= 250``) and the under-exposed rate
(``Z <= 9``); their sum is the saturated rate. Per run: frames saturated at 50 % (the paper's
threshold) and at 10 % ("slightly saturated"), the mean over-/under-exposed rates, the recovery
time after each lighting step, and the mean SIFT inlier matches between consecutive frames
(measured by :class:`necviz.image_quality.SiftMatcher`, which needs OpenCV and so lives outside ``core``).

Ground truth (simulated frames only, :class:`~necviz.core.ground_truth.GroundTruth`): the fraction of pixels whose true
irradiance was recorded inside the valid range (:func:`true_valid_fraction`), how well the frame's
digits track the true irradiance (:func:`rank_correlation`, Spearman's ρ on valid pixels) and
whether a region of interest — ``tunnel_exit``'s pedestrian — is well exposed on its first
visible frame (:func:`region_valid_fraction`). :func:`summarise_details` turns the per-frame
values (and the diagnosed saturation causes, :mod:`necviz.core.diagnosis`) into per-run figures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from necviz.core.diagnosis import CAUSES
from necviz.core.errors import ParameterError
from necviz.core.ground_truth import OVER, UNDER, WELL_EXPOSED


def over_exposed_rate(image: np.ndarray, threshold: int = OVER) -> float:
    """Fraction of pixels at or above ``threshold`` (default 250)."""
    return float(np.count_nonzero(image >= threshold)) / image.size


def under_exposed_rate(image: np.ndarray, threshold: int = UNDER) -> float:
    """Fraction of pixels at or below ``threshold`` (default 9)."""
    return float(np.count_nonzero(image <= threshold)) / image.size


def exposure_rates_from_histogram(hist: np.ndarray, size: int) -> tuple[float, float]:
    """:func:`over_exposed_rate` and :func:`under_exposed_rate` (default thresholds) of an 8-bit image of
    ``size`` values from its digit histogram (256 counts, e.g. P-TEDI's, which counts every frame's
    digits anyway): the same two numbers, without two more passes over the pixels."""
    h = np.asarray(hist).reshape(-1)
    return float(h[OVER:].sum()) / size, float(h[: UNDER + 1].sum()) / size


def saturated_frames(over: np.ndarray, under: np.ndarray, fraction: float) -> int:
    """Frames whose over- or under-exposed rate exceeds ``fraction`` (0.5: saturated; 0.1: slightly)."""
    over, under = np.asarray(over), np.asarray(under)
    return int(np.count_nonzero((over > fraction) | (under > fraction)))


def recovery_times_ms(
    starts_us, saturated_rate, step_times_us, threshold: float = 0.1, end_us: int | None = None
) -> list[float | None]:
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
    recovered = [r for r in rec if r is not None]
    rec_mean = float(np.mean(recovered)) if rec and len(recovered) == len(rec) else None
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


def rank_correlation(
    image: np.ndarray, mean_irradiance: np.ndarray, max_samples: int = 10_000, min_pixels: int = 64
) -> float:
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
    roi = np.asarray(image)[max(y0, 0) : y1, max(x0, 0) : x1]
    if roi.size == 0:
        return math.nan
    return float(np.count_nonzero((roi > UNDER) & (roi < OVER))) / roi.size


def _finite_mean(values) -> float | None:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else None


def summarise_details(
    sequence, sift_normalised=None, true_valid=None, rank_corr=None, pedestrian_valid=None, causes=None
) -> dict:
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
    out: dict[str, object] = {
        "sift_inliers_normalised_mean": _finite_mean(sift_normalised if sift_normalised is not None else []),
        "true_valid_fraction_mean": _finite_mean(true_valid if true_valid is not None else []),
        "rank_correlation_mean": _finite_mean(rank_corr if rank_corr is not None else []),
        "pedestrian_frame": None,
        "pedestrian_valid_fraction": None,
        "pedestrian_well_exposed": None,
    }
    if pedestrian_valid is not None:
        pv = np.asarray(pedestrian_valid, dtype=np.float64)
        idx = np.flatnonzero(np.isfinite(pv))
        if idx.size:
            i = int(idx[0])
            out["pedestrian_frame"] = int(seq[i])
            out["pedestrian_valid_fraction"] = float(pv[i])
            out["pedestrian_well_exposed"] = bool(pv[i] >= WELL_EXPOSED)
    counts = dict.fromkeys(CAUSES, 0)  # every cause, so tables of many runs share their columns
    for c in causes if causes is not None else []:
        if c:
            counts[str(c)] = counts.get(str(c), 0) + 1
    out["saturation_causes"] = counts
    return out


def confidence_interval(values) -> tuple[float, float]:
    """Mean and the half-width of its 95 % confidence interval (Student's t; 0 for one value)."""
    v = np.asarray(values, dtype=np.float64)
    if v.size < 2:
        return float(v.mean()), 0.0
    from scipy.stats import t

    return float(v.mean()), float(t.ppf(0.975, v.size - 1) * v.std(ddof=1) / math.sqrt(v.size))
