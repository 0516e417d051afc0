"""APS frames and exposure markers.

A :class:`Frame` arrives *after* its exposure with the interval it was exposed over.
:class:`ExposureMarker` tells an estimator, in stream order, when an exposure starts
and ends, so integrals over the exposure can be accumulated as events stream in
(see ``PeripheralEstimator``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from necviz.core.errors import FrameFormatError

if TYPE_CHECKING:
    from necviz.core.ground_truth import GroundTruth


@dataclass(frozen=True, eq=False)
class Frame:
    """An 8-bit image ``Z`` (H x W) with exposure ``[exposure_start_us, exposure_end_us]`` and gain ``K >= 1``.

    ``truth``: what a real camera cannot know, attached by the simulator only — a
    :class:`necviz.core.ground_truth.GroundTruth` (the exposure-averaged true irradiance of every pixel,
    the scene's lighting trace around the exposure, the camera's true limits and latency). ``None``
    for frames from cameras and files; never written by recorders, not part of equality or ``repr``.
    """

    image: np.ndarray
    exposure_start_us: int
    exposure_end_us: int
    gain: float = 1.0
    sequence: int = 0
    truth: GroundTruth | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        img = self.image
        if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.ndim != 2:
            desc = f"{img.dtype} {img.shape}" if isinstance(img, np.ndarray) else type(img).__name__
            raise FrameFormatError(f"frame {self.sequence}: image must be a 2-D uint8 array, got {desc}")
        for label in ("exposure_start_us", "exposure_end_us", "sequence"):
            v = getattr(self, label)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise FrameFormatError(f"frame {self.sequence}: {label} must be an integer (µs), got {v!r}")
        if self.exposure_end_us <= self.exposure_start_us:
            raise FrameFormatError(
                f"frame {self.sequence}: exposure must be positive, got [{self.exposure_start_us}, "
                f"{self.exposure_end_us}] µs"
            )
        g = self.gain
        if not isinstance(g, (int, float, np.floating, np.integer)) or not math.isfinite(g) or g < 1.0:
            raise FrameFormatError(f"frame {self.sequence}: gain must be a finite linear factor >= 1, got {g!r}")

    @property
    def exposure_us(self) -> int:
        """Exposure length ``T`` in µs."""
        return int(self.exposure_end_us - self.exposure_start_us)

    @property
    def shape(self) -> tuple[int, int]:
        return self.image.shape


@dataclass(frozen=True)
class ExposureMarker:
    """An exposure starts (``kind='start'``) or ends (``kind='end'``) at ``t_us``."""

    t_us: int
    kind: str

    def __post_init__(self) -> None:
        if self.kind not in ("start", "end"):
            raise FrameFormatError(f"exposure marker kind must be 'start' or 'end', got {self.kind!r}")
        if isinstance(self.t_us, bool) or not isinstance(self.t_us, (int, np.integer)):
            raise FrameFormatError(f"exposure marker time must be an integer (µs), got {self.t_us!r}")
