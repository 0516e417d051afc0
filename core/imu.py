"""IMU samples and trigger events: packets a source may yield beside events and frames.

The estimator and controllers ignore them; recorders and replayers keep them so nothing a camera
produced is lost. Both are batches (structured arrays) in stream order, like event batches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from necviz.core.errors import EventFormatError

#: One IMU sample: time (µs), accelerometer (g), gyroscope (°/s), temperature (°C).
IMU_DTYPE = np.dtype(
    [
        ("t", "<i8"),
        ("ax", "<f4"),
        ("ay", "<f4"),
        ("az", "<f4"),
        ("gx", "<f4"),
        ("gy", "<f4"),
        ("gz", "<f4"),
        ("temp", "<f4"),
    ]
)

#: Trigger kinds, as stored by AEDAT 4 (``TRIG`` stream) and the DAVIS special events.
TRIGGER_KINDS = (
    "timestamp_reset",
    "external_rising",
    "external_falling",
    "external_pulse",
    "generator_rising",
    "generator_falling",
    "frame_begin",
    "frame_end",
    "exposure_begin",
    "exposure_end",
)

#: One trigger: time (µs) and kind (index into :data:`TRIGGER_KINDS`).
TRIGGER_DTYPE = np.dtype([("t", "<i8"), ("kind", "i1")])


def _check(samples: np.ndarray, dtype: np.dtype, what: str) -> np.ndarray:
    if not isinstance(samples, np.ndarray) or samples.dtype != dtype or samples.ndim != 1:
        desc = f"{samples.dtype} {samples.shape}" if isinstance(samples, np.ndarray) else type(samples).__name__
        raise EventFormatError(f"{what} must be a 1-D array of {dtype}, got {desc}")
    if len(samples) > 1 and np.any(np.diff(samples["t"]) < 0):
        raise EventFormatError(f"{what} timestamps must not decrease")
    return samples


@dataclass(frozen=True, eq=False)
class ImuBatch:
    """IMU samples (:data:`IMU_DTYPE`) in time order."""

    samples: np.ndarray

    def __post_init__(self) -> None:
        _check(self.samples, IMU_DTYPE, "IMU samples")

    def __len__(self) -> int:
        return len(self.samples)


@dataclass(frozen=True, eq=False)
class TriggerBatch:
    """Trigger events (:data:`TRIGGER_DTYPE`) in time order."""

    triggers: np.ndarray

    def __post_init__(self) -> None:
        _check(self.triggers, TRIGGER_DTYPE, "triggers")
        if len(self.triggers) and (
            self.triggers["kind"].min() < 0 or self.triggers["kind"].max() >= len(TRIGGER_KINDS)
        ):
            raise EventFormatError(f"trigger kind must be 0..{len(TRIGGER_KINDS) - 1}")

    def __len__(self) -> int:
        return len(self.triggers)
