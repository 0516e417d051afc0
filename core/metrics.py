"""Exposure-control metrics: per frame, per run, and the downstream SIFT evidence.

Per frame: the over-exposed rate (fraction of pixels ``Z >= 250``) and the under-exposed rate
(``Z <= 9``); their sum is the saturated rate. Per run: frames saturated at 50 % (the paper's
threshold) and at 10 % ("slightly saturated"), the mean over-/under-exposed rates, the recovery
time after each lighting step, and SIFT inlier matches between consecutive frames (the paper's
3D-reconstruction evidence: OpenCV SIFT, Lowe's ratio test, RANSAC on the fundamental matrix).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

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


class SiftMatcher:
    """SIFT inlier matches between consecutive frames of one camera (keeps the previous frame's features).

    Matches pass Lowe's ratio test (``ratio``) and RANSAC on the fundamental matrix (``ransac_px``);
    fewer than 8 ratio-test matches count as 0 inliers.
    """

    def __init__(self, ratio: float = 0.75, ransac_px: float = 3.0, max_features: int = 1000):
        if not (0 < ratio < 1) or not (ransac_px > 0) or max_features < 8:
            raise ParameterError("SiftMatcher needs 0 < ratio < 1, ransac_px > 0, max_features >= 8")
        self.sift = cv2.SIFT_create(nfeatures=max_features)
        self.matcher = cv2.BFMatcher(cv2.NORM_L2)
        self.ratio, self.ransac_px = ratio, ransac_px
        self._prev = None

    def features(self, image: np.ndarray):
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
