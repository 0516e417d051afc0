"""Image comparisons that need OpenCV: SIFT inlier matches between frames and SSIM.

:class:`SiftMatcher` counts SIFT inlier matches between consecutive frames (the paper's
3D-reconstruction evidence: OpenCV SIFT, Lowe's ratio test, RANSAC on the fundamental matrix), on
the raw frames or on brightness-normalised ones (:func:`normalise_brightness`): SIFT's contrast
threshold is absolute, so a controller exposing darker frames loses keypoints for a reason
unrelated to what its frames recorded. :func:`ssim` compares a recording's frames with the
originals (the recordings' JPEG table is chosen by it).
"""

from __future__ import annotations

import cv2
import numpy as np

from necviz.core.errors import ParameterError


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Mean structural similarity of two grey 8-bit images (Wang, Bovik, Sheikh & Simoncelli 2004,
    Eq. 13): Gaussian window σ = 1.5 truncated at 11x11, C1 = (0.01·255)², C2 = (0.03·255)²; the
    5-pixel border, where the window leaves the image, is not averaged. 1.0 for identical images.
    Used to choose the recordings' JPEG table (:mod:`necviz.dashboard.sink`). O(pixels)."""
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
        good = [
            m for m, *rest in self.matcher.knnMatch(da, db, k=2) if rest and m.distance < self.ratio * rest[0].distance
        ]
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
