"""Peripheral regions: which pixels P-TEDI collapses into each "large pixel" (zone).

A region is described by a zone map: an int32 image with the zone index of every pixel
and -1 for pixels outside every zone. The default is one zone covering the whole sensor.
"""

from __future__ import annotations

import numpy as np

from necviz.core.errors import ParameterError
from necviz.core.sensor import SensorGeometry


def zone_map(
    sensor: SensorGeometry,
    rectangle: tuple[int, int, int, int] | None = None,
    grid: tuple[int, int] = (1, 1),
) -> np.ndarray:
    """Zone index per pixel (``-1`` = ignored), shape ``(height, width)``.

    ``rectangle = (x0, y0, x1, y1)`` (half-open, pixels) restricts the region; ``grid = (nx, ny)``
    splits the region into ``nx * ny`` equal metering zones numbered row by row
    (e.g. ``(4, 4)`` for a 4x4 metering grid).
    """
    x0, y0, x1, y1 = rectangle if rectangle is not None else (0, 0, sensor.width, sensor.height)
    if not (0 <= x0 < x1 <= sensor.width and 0 <= y0 < y1 <= sensor.height):
        raise ParameterError(
            f"peripheral rectangle {(x0, y0, x1, y1)} must satisfy 0 <= x0 < x1 <= {sensor.width} "
            f"and 0 <= y0 < y1 <= {sensor.height}"
        )
    nx, ny = grid
    if not (isinstance(nx, int) and isinstance(ny, int) and 1 <= nx <= x1 - x0 and 1 <= ny <= y1 - y0):
        raise ParameterError(
            f"zone grid {grid} must be positive integers no larger than the region ({x1 - x0}x{y1 - y0})"
        )
    zmap = np.full(sensor.shape, -1, dtype=np.int32)
    xs = np.arange(x1 - x0)
    ys = np.arange(y1 - y0)
    zx = (xs * nx) // (x1 - x0)
    zy = (ys * ny) // (y1 - y0)
    zmap[y0:y1, x0:x1] = (zy[:, None] * nx + zx[None, :]).astype(np.int32)
    return zmap


def zone_sizes(zmap: np.ndarray) -> np.ndarray:
    """Number of pixels ``N_R`` in each zone."""
    k = int(zmap.max()) + 1
    return np.bincount(zmap[zmap >= 0].ravel(), minlength=k).astype(np.int64)
