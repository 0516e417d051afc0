"""Fiducial markers as a downstream task: their ground-truth geometry and the per-run figures (pure).

The paper measures what exposure control is worth to a downstream detector with YOLO's mAP and the
time a pedestrian is first detected after a tunnel exit ("460 ms earlier"). necviz replaces the
network, which needs weights and a labelled data set, by a detector that needs neither: square
fiducial markers (ArUco's ``DICT_4X4_50``; Garrido-Jurado et al., "Automatic generation and
detection of highly reliable fiducial markers under occlusion", Pattern Recognition 47, 2014)
drawn into every simulator preset at known poses
(:mod:`necviz.drivers.sim.scenes.fiducials`). The detection itself needs OpenCV and lives in
:mod:`necviz.marker_detection`; this module holds what needs none:

* :class:`MarkerTruth`: where the scene drew each marker at a frame's mid-exposure — the image
  corners of its black border (top-left, top-right, bottom-right, bottom-left of the marker's own
  orientation, pixel centres at integer coordinates, as OpenCV reports them) and whether it counts
  as *visible* (:func:`visibility`: all four corners at least :data:`MARGIN_PX` inside the image,
  every side at least :data:`MIN_SIDE_PX` long, and, in scenes that blend two views, drawn with at
  least 90 % weight);
* the per-frame scores (:func:`frame_scores`): which visible markers were detected, and the mean
  distance of the detected corners from the true ones;
* the per-run figures (:func:`summarise_markers`): detection rate, detection latency after each
  lighting change, corner error.

Marker ids are kept as bit masks (``1 << id``, ids 0..62) so a frame's visible and detected sets are
two integers in the per-frame tables.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from necviz.core.errors import ParameterError

#: The ArUco dictionary the presets draw and the detector reads (4 x 4 bits, ids 0..49).
DICTIONARY = "DICT_4X4_50"
#: A marker counts as visible only if all four corners lie at least this far inside the image (px):
#: the detector needs the black border whole and some of the white margin around it.
MARGIN_PX = 4.0
#: ... and every side of its black border is at least this long (px): 3 px per cell of the 6 x 6
#: cells (4 x 4 bits and the border) of a ``DICT_4X4_50`` marker; smaller ones cannot be decoded.
MIN_SIDE_PX = 18.0
#: ... and, where a scene blends two views (a door or tunnel portal), its view has at least this weight.
MIN_LAYER_WEIGHT = 0.9
#: Largest marker id a bit mask can hold.
MAX_ID = 62
#: The per-run figures of :func:`summarise_markers` (``None`` each when markers were not measured).
MARKER_KEYS = (
    "marker_detection_rate",
    "marker_corner_error_px",
    "marker_latency_ms",
    "marker_missed",
    "marker_pairs",
    "marker_changes",
)


@dataclass(frozen=True, eq=False)
class MarkerTruth:
    """Where the scene drew its markers at one instant (usually a frame's mid-exposure).

    ``ids``: int array (n,); ``corners``: float64 array (n, 4, 2) of image ``(x, y)`` (pixel centres at
    integer coordinates) of each marker's black border, in the marker's own corner order (top-left,
    top-right, bottom-right, bottom-left); ``visible``: bool array (n,) (:func:`visibility`).
    """

    ids: np.ndarray
    corners: np.ndarray
    visible: np.ndarray

    def __post_init__(self) -> None:
        ids = np.asarray(self.ids)
        c = np.asarray(self.corners)
        v = np.asarray(self.visible)
        if ids.ndim != 1 or c.shape != (ids.size, 4, 2) or v.shape != ids.shape:
            raise ParameterError(
                f"MarkerTruth needs ids (n,), corners (n, 4, 2) and visible (n,); got {ids.shape}, {c.shape}, {v.shape}"
            )
        if ids.size and (ids.min() < 0 or ids.max() > MAX_ID or np.unique(ids).size != ids.size):
            raise ParameterError(f"marker ids must be distinct integers in 0..{MAX_ID}, got {ids.tolist()}")

    @property
    def visible_mask(self) -> int:
        """The visible markers as a bit mask (``1 << id`` each)."""
        return ids_mask(np.asarray(self.ids)[np.asarray(self.visible, bool)])

    def corners_of(self, marker_id: int) -> np.ndarray:
        """The four corners of marker ``marker_id``."""
        i = np.flatnonzero(np.asarray(self.ids) == marker_id)
        if i.size == 0:
            raise KeyError(marker_id)
        return np.asarray(self.corners[i[0]], np.float64)


def apply_affine(m, points) -> np.ndarray:
    """Points ``(..., 2)`` mapped by the 2 x 3 affine matrix ``m`` (``[x', y'] = m [x, y, 1]``)."""
    m = np.asarray(m, np.float64)
    p = np.asarray(points, np.float64)
    return p @ m[:, :2].T + m[:, 2]


def apply_homography(h, points) -> np.ndarray:
    """Points ``(..., 2)`` mapped by the 3 x 3 homography ``h``."""
    h = np.asarray(h, np.float64)
    p = np.asarray(points, np.float64)
    q = p @ h[:, :2].T + h[:, 2]
    return q[..., :2] / q[..., 2:3]


def side_lengths(corners) -> np.ndarray:
    """Lengths of the four sides of each quadrilateral ``(n, 4, 2)``: an (n, 4) array."""
    c = np.asarray(corners, np.float64)
    return np.linalg.norm(np.roll(c, -1, axis=-2) - c, axis=-1)


def visibility(
    corners, width: int, height: int, layer_weight=None, *, margin: float = MARGIN_PX, min_side: float = MIN_SIDE_PX
) -> np.ndarray:
    """Which markers ``(n, 4, 2)`` count as visible in a ``width`` x ``height`` image (module docstring).

    ``layer_weight``: per marker, the smallest weight (0..1) its view has at its corners where the
    scene blends two views (``None``: 1, a single view).
    """
    c = np.asarray(corners, np.float64)
    if c.size == 0:
        return np.zeros(0, bool)
    x, y = c[..., 0], c[..., 1]
    inside = (x >= margin) & (x <= width - 1 - margin) & (y >= margin) & (y <= height - 1 - margin)
    ok = inside.all(axis=-1) & (side_lengths(c).min(axis=-1) >= min_side)
    if layer_weight is not None:
        ok &= np.asarray(layer_weight, np.float64) >= MIN_LAYER_WEIGHT
    return ok


def ids_mask(ids) -> int:
    """Marker ids -> bit mask (``sum 1 << id``); ids outside 0..62 are ignored."""
    m = 0
    for i in np.asarray(ids, np.int64).ravel():
        if 0 <= i <= MAX_ID:
            m |= 1 << int(i)
    return m


def mask_ids(mask: int) -> list[int]:
    """Bit mask -> sorted marker ids."""
    m = int(mask)
    return [i for i in range(MAX_ID + 1) if m >> i & 1]


def popcount(masks) -> np.ndarray:
    """Number of set bits of each mask (int64 array)."""
    m = np.asarray(masks, np.int64).ravel()
    return np.array([bin(int(v)).count("1") for v in m], np.int64).reshape(np.shape(masks))


def corner_error_px(detected, truth) -> float:
    """Mean Euclidean distance (px) between four detected corners and the four true ones, same order."""
    d, t = np.asarray(detected, np.float64).reshape(4, 2), np.asarray(truth, np.float64).reshape(4, 2)
    return float(np.linalg.norm(d - t, axis=1).mean())


def frame_scores(truth: MarkerTruth, detections: dict) -> tuple[int, int, float, float]:
    """A frame's marker scores: ``(visible_mask, detected_mask, detection_rate, corner_error_px)``.

    ``detections``: ``{id: corners (4, 2)}`` as a detector found them. ``detected_mask`` holds every
    detected id (visible or not); the rate is the share of the visible markers that were detected
    (NaN when none is visible); the corner error is the mean :func:`corner_error_px` over the
    detected visible markers (NaN when there is none).
    """
    vis_ids = [int(i) for i, v in zip(np.asarray(truth.ids), np.asarray(truth.visible), strict=True) if v]
    det_mask = ids_mask([i for i in detections])
    hits = [i for i in vis_ids if i in detections]
    rate = len(hits) / len(vis_ids) if vis_ids else math.nan
    err = float(np.mean([corner_error_px(detections[i], truth.corners_of(i)) for i in hits])) if hits else math.nan
    return ids_mask(vis_ids), det_mask, rate, err


def summarise_markers(
    starts_us, visible_masks, detected_masks, corner_errors, change_times_us, end_us: int | None = None
) -> dict:
    """A run's marker figures from its per-frame columns (frames in exposure-start order).

    * ``marker_detection_rate``: detected visible markers / visible markers, summed over frames
      (``None`` when no frame showed a visible marker);
    * ``marker_corner_error_px``: mean corner error over every detected visible marker of every frame;
    * per lighting change ``t_c`` (window ``[t_c, next change)``, the last one to ``end_us``) and per
      marker visible on some frame of the window: the *latency*, from ``t_c`` to the exposure start
      of the first frame of the window that detected it (as :func:`necviz.core.metrics.recovery_times_ms`,
      a frame that started before the change does not count); ``None`` if no frame of the window did;
    * ``marker_latency_ms``: the mean latency over those (change, marker) pairs, a pair never detected
      counting as the whole window (so it is a lower bound when some are missed, and a controller
      cannot look faster by missing markers); ``marker_missed``: the pairs never detected;
      ``marker_pairs``: the pairs; ``None`` when there is no pair;
    * ``marker_changes``: per change ``{"t_us", "window_ms", "markers": {id: {"visible_ms",
      "detected_ms"}}}``, ``visible_ms`` the first frame of the window on which the marker was
      visible (the bound no controller can beat).
    """
    starts = np.asarray(starts_us, np.int64)
    vis = np.asarray(visible_masks, np.int64)
    det = np.asarray(detected_masks, np.int64)
    err = np.asarray(corner_errors, np.float64)
    if not (starts.shape == vis.shape == det.shape == err.shape):
        raise ParameterError("summarise_markers needs one value per frame in every column")
    hit = det & vis
    n_vis, n_hit = popcount(vis), popcount(hit)
    total_vis = int(n_vis.sum())
    ok = np.isfinite(err) & (n_hit > 0)
    out: dict[str, object] = {
        "marker_detection_rate": float(n_hit.sum() / total_vis) if total_vis else None,
        "marker_corner_error_px": float((err[ok] * n_hit[ok]).sum() / n_hit[ok].sum()) if ok.any() else None,
    }
    steps = sorted(int(t) for t in change_times_us)
    last = end_us if end_us is not None else (int(starts[-1]) + 1 if starts.size else 0)
    per_change, lat, missed = [], [], 0
    for i, tc in enumerate(steps):
        t_next = steps[i + 1] if i + 1 < len(steps) else max(int(last), tc)
        sel = np.flatnonzero((starts >= tc) & (starts < t_next))
        window_ms = (t_next - tc) / 1e3
        markers = {}
        seen = 0
        for k in sel:
            seen |= int(vis[k])
        for mid in mask_ids(seen):
            bit = 1 << mid
            first_vis = next(int(starts[k]) for k in sel if vis[k] & bit)
            first_det = next((int(starts[k]) for k in sel if hit[k] & bit), None)
            d_ms = None if first_det is None else (first_det - tc) / 1e3
            markers[mid] = {"visible_ms": (first_vis - tc) / 1e3, "detected_ms": d_ms}
            lat.append(window_ms if d_ms is None else d_ms)
            missed += d_ms is None
        per_change.append({"t_us": tc, "window_ms": window_ms, "markers": markers})
    out.update(
        {
            "marker_latency_ms": float(np.mean(lat)) if lat else None,
            "marker_missed": missed if lat else None,
            "marker_pairs": len(lat),
            "marker_changes": per_change,
        }
    )
    return out


__all__ = [
    "DICTIONARY",
    "MARGIN_PX",
    "MARKER_KEYS",
    "MAX_ID",
    "MIN_LAYER_WEIGHT",
    "MIN_SIDE_PX",
    "MarkerTruth",
    "apply_affine",
    "apply_homography",
    "corner_error_px",
    "frame_scores",
    "ids_mask",
    "mask_ids",
    "popcount",
    "side_lengths",
    "summarise_markers",
    "visibility",
]
