"""Fiducial markers drawn into the presets: ArUco ``DICT_4X4_50`` markers at known poses, in ln L.

A marker is two irradiance levels, ``level ± contrast`` (default ±1 ln around its local level):
white cells (and a one-cell white margin, the "quiet zone" the detector needs around the black
border) at ``level + contrast``, black cells at ``level - contrast``. Drawn into a scene's texture
(:func:`paint`, ``level`` = the texture's mean under the patch) the marker moves, warps and is lit
with the scene and saturates as it does; :func:`paste_quad` draws one straight into an image at four
image corners (the billboards of ``tunnel_exit``, whose view is a remap of a corridor, not a warp of
one texture).

Geometry: a texture texel ``i`` has its centre at coordinate ``i`` (OpenCV's convention, which
``cv2.warpAffine`` and the ArUco detector share), so a marker whose black border covers texels
``x0 .. x0 + n - 1`` has its outer edge at ``x0 - 0.5`` and ``x0 + n - 0.5``; its image corners
are the scene's texture-to-image map applied to those (:func:`necviz.core.markers.apply_affine`).
The bit patterns come from OpenCV (``cv2.aruco.generateImageMarker``); nothing random is drawn, so
a scene's textures stay those of its seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from necviz.core.markers import DICTIONARY, apply_homography

#: Cells across a marker's black border: 4 bits and one border cell on each side.
CELLS = 6
#: White cells around the black border (the quiet zone).
QUIET = 1
#: Half the ln L difference between white and black cells.
CONTRAST = 1.0


@dataclass(frozen=True)
class PlacedMarker:
    """A marker drawn into a scene: its id, the texture (or world) corners of its black border
    (``(4, 2)``: top-left, top-right, bottom-right, bottom-left) and the scene layer it belongs to."""

    marker_id: int
    corners: np.ndarray
    layer: str = "scene"


@lru_cache(maxsize=64)
def pattern(marker_id: int) -> np.ndarray:
    """The marker with its quiet zone, one value per cell: ``(CELLS + 2 QUIET)`` squared, +1 white, -1 black."""
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, DICTIONARY))
    bits = cv2.aruco.generateImageMarker(d, int(marker_id), CELLS, borderBits=1)
    cells = np.where(bits > 127, 1.0, -1.0).astype(np.float32)
    out = np.pad(cells, QUIET, constant_values=1.0)
    out.flags.writeable = False
    return out


def patch_size(cell: int) -> int:
    """Side of a painted patch (marker and quiet zone) in texels for ``cell`` texels per cell."""
    return (CELLS + 2 * QUIET) * int(cell)


def paint(
    tex: np.ndarray, marker_id: int, x0: int, y0: int, cell: int, contrast: float = CONTRAST
) -> np.ndarray | None:
    """Paint marker ``marker_id`` into ``tex`` (in place) with its patch's top-left texel at ``(x0, y0)``.

    Cells are ``cell`` texels wide; values are ``mean(tex under the patch) ± contrast``. Returns the
    texture corners of the black border (``(4, 2)``, see the module docstring), or ``None`` (nothing
    painted) when the patch does not fit in the texture.
    """
    n = patch_size(cell)
    h, w = tex.shape
    x0, y0 = int(x0), int(y0)
    if x0 < 0 or y0 < 0 or x0 + n > w or y0 + n > h:
        return None
    roi = tex[y0 : y0 + n, x0 : x0 + n]
    level = float(roi.mean(dtype=np.float64))
    roi[:] = np.float32(level) + np.float32(contrast) * np.kron(pattern(marker_id), np.ones((cell, cell), np.float32))
    a, b = QUIET * cell - 0.5, (QUIET + CELLS) * cell - 0.5
    return np.array([[x0 + a, y0 + a], [x0 + b, y0 + a], [x0 + b, y0 + b], [x0 + a, y0 + b]], np.float64)


def quiet_corners(corners) -> np.ndarray:
    """The corners of the quiet zone around a marker's black border ``(..., 4, 2)`` (scaled about its centre):
    where a scene blends two views, the whole patch must lie in the marker's view to be detectable."""
    c = np.asarray(corners, np.float64)
    centre = c.mean(axis=-2, keepdims=True)
    return centre + (c - centre) * ((CELLS + 2 * QUIET) / CELLS)


#: Pixels per cell of the pattern image :func:`paste_quad` warps.
_PATTERN_PX = 8
#: Supersampling of :func:`paste_quad` (each image pixel averages this many squared samples).
_SUPERSAMPLE = 4


@lru_cache(maxsize=64)
def _pattern_image(marker_id: int) -> np.ndarray:
    img = np.kron(pattern(marker_id), np.ones((_PATTERN_PX, _PATTERN_PX), np.float32))
    img.flags.writeable = False
    return img


def paste_quad(img: np.ndarray, marker_id: int, corners, contrast: float = CONTRAST, weight=None) -> bool:
    """Draw marker ``marker_id`` into ``img`` (ln L, in place) with its black border at image ``corners``.

    ``corners``: ``(4, 2)`` image coordinates (top-left, top-right, bottom-right, bottom-left); the
    quiet zone extends beyond them by the same homography. The marker's level is the mean of ``img``
    under it; it is drawn by a supersampled perspective warp (area-averaged, so small markers do not
    alias) and alpha-blended at its edges; ``weight`` (0..1, optional image) scales the blend, e.g.
    by how much of the view is the layer the marker is in. Returns False when nothing was drawn
    (the marker is off the image or smaller than a pixel).
    """
    c = np.asarray(corners, np.float64)
    k = _PATTERN_PX
    a, b = QUIET * k - 0.5, (QUIET + CELLS) * k - 0.5
    src = np.array([[a, a], [b, a], [b, b], [a, b]], np.float32)
    hom = cv2.getPerspectiveTransform(src, c.astype(np.float32)).astype(np.float64)
    n = patch_size(k)
    outer = apply_homography(hom, np.array([[-0.5, -0.5], [n - 0.5, -0.5], [n - 0.5, n - 0.5], [-0.5, n - 0.5]]))
    h, w = img.shape
    x0, y0 = max(int(math.floor(outer[:, 0].min())), 0), max(int(math.floor(outer[:, 1].min())), 0)
    x1, y1 = min(int(math.ceil(outer[:, 0].max())) + 1, w), min(int(math.ceil(outer[:, 1].max())) + 1, h)
    if x1 <= x0 or y1 <= y0 or np.linalg.norm(c[1] - c[0]) < 1.0:
        return False
    s = _SUPERSAMPLE
    # supersampled pixel j (centre at j) of the box lies at image coordinate x0 - 0.5 + (j + 0.5) / s
    to_ss = np.array([[s, 0.0, (0.5 - x0) * s - 0.5], [0.0, s, (0.5 - y0) * s - 0.5], [0.0, 0.0, 1.0]])
    m = to_ss @ hom
    size = ((x1 - x0) * s, (y1 - y0) * s)
    pat = cv2.warpPerspective(_pattern_image(marker_id), m, size, flags=cv2.INTER_LINEAR, borderValue=0.0)
    alpha = cv2.warpPerspective(np.ones((n, n), np.float32), m, size, flags=cv2.INTER_LINEAR, borderValue=0.0)
    pat = cv2.resize(pat, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
    alpha = cv2.resize(alpha, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
    roi = img[y0:y1, x0:x1]
    covered = alpha > 0.5
    if not covered.any():
        return False
    level = np.float32(roi[covered].mean(dtype=np.float64))
    # pat is premultiplied by alpha (the warp blends with 0 outside): level + contrast * pattern where covered
    wt = np.float32(1.0) if weight is None else weight[y0:y1, x0:x1]
    roi += wt * (alpha * (level - roi) + np.float32(contrast) * pat)
    return True


__all__ = [
    "CELLS",
    "CONTRAST",
    "DICTIONARY",
    "PlacedMarker",
    "QUIET",
    "paint",
    "paste_quad",
    "patch_size",
    "pattern",
    "quiet_corners",
]
