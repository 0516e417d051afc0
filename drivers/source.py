"""The source interface shared by the simulator, the live DAVIS driver and the file replayers.

A source is iterated for packets in stream order — event batches (``EVENT_DTYPE`` arrays),
:class:`~necviz.core.frames.ExposureMarker` and :class:`~necviz.core.frames.Frame`, plus optional
:class:`~necviz.core.imu.ImuBatch` and :class:`~necviz.core.imu.TriggerBatch` — and may accept
exposure commands with :meth:`set_exposure`. The pipeline never needs to know whether a
source is simulated, live or recorded.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol, Union, runtime_checkable

import numpy as np

from ..core.frames import ExposureMarker, Frame
from ..core.imu import ImuBatch, TriggerBatch
from ..core.sensor import SensorGeometry

#: What a source yields. Consumers that do not use IMU samples or triggers skip them.
Packet = Union[np.ndarray, ExposureMarker, Frame, ImuBatch, TriggerBatch]


@dataclass(frozen=True)
class CommandRecord:
    """An exposure command as the camera received it, and when it took effect.

    ``applied_start_us`` is the start of the first exposure that used it (``None``: superseded
    or not yet applied).
    """

    issue_time_us: int
    exposure_us: float
    gain: float
    applied_start_us: int | None = None


@runtime_checkable
class Source(Protocol):
    sensor: SensorGeometry

    def __iter__(self) -> Iterator[Packet]: ...

    def set_exposure(self, exposure_us: float, gain: float = 1.0, issue_time_us: int | None = None) -> None: ...

    def close(self) -> None: ...
