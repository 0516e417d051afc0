"""Fiducial-marker detection on camera frames (OpenCV's ArUco), scored against the simulator's ground truth.

The downstream task that stands in for the paper's object detector (:mod:`necviz.core.markers`
explains the choice and holds the ground-truth geometry and the per-run figures). The detector is
OpenCV's ArUco detector (``cv2.aruco.ArucoDetector``, shipped in ``opencv-python-headless``, no
weights) on the dictionary the presets draw (``DICT_4X4_50``) with its default parameters, except
sub-pixel corner refinement (``CORNER_REFINE_SUBPIX``), without which corners come out on whole
pixels (half a pixel off the true edge).

Cost: about 1.6-2.6 ms of CPU per 346 x 260 frame, +9 to +76 % on a two-controller comparison
(``benchmarks/markers.py``), so the telemetry measures it only when asked (``markers=True``;
``necviz compare --markers``; ``markers = true`` in a sweep).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from necviz.core.markers import DICTIONARY, MarkerTruth, frame_scores


class MarkerDetector:
    """ArUco detection of the presets' markers: :meth:`detect` one frame, :meth:`score` it against truth."""

    def __init__(self, dictionary: str = DICTIONARY):
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        self.dictionary = dictionary
        self._detector = cv2.aruco.ArucoDetector(
            cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)), params
        )

    def detect(self, image: np.ndarray) -> dict[int, np.ndarray]:
        """``{id: corners (4, 2)}`` of the markers found in an 8-bit grey image (corners in the marker's
        own order, pixel centres at integer coordinates). An id found twice keeps its first detection."""
        corners, ids, _ = self._detector.detectMarkers(np.ascontiguousarray(image))
        out: dict[int, np.ndarray] = {}
        if ids is None:
            return out
        for c, i in zip(corners, ids.ravel(), strict=True):
            out.setdefault(int(i), np.asarray(c, np.float64).reshape(4, 2))
        return out

    def score(self, image: np.ndarray, truth: MarkerTruth) -> tuple[int, int, float, float]:
        """``(visible_mask, detected_mask, detection_rate, corner_error_px)`` of one frame
        (:func:`necviz.core.markers.frame_scores`). A frame on which no marker is visible is not
        searched (nothing it could find would count): ``(0, 0, nan, nan)``."""
        if not np.any(truth.visible):
            return 0, 0, math.nan, math.nan
        return frame_scores(truth, self.detect(image))


__all__ = ["MarkerDetector"]
