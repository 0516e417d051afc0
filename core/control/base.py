"""The interface every exposure controller shares (NEC and the baselines).

A controller is fed the source's packets in stream order — event batches, exposure markers
and frames — and may answer any of them with an :class:`ExposureCommand`. The camera applies
a command at its next exposure start; the controller learns the applied values from the
frames it receives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError, StreamError
from ..frames import ExposureMarker, Frame
from ..imu import ImuBatch, TriggerBatch


def _finite_positive(name: str, v) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v) or v <= 0:
        raise ParameterError(f"{name} must be a positive finite number, got {v!r}")
    return float(v)


def check_number(name: str, v, lo: float | None = None, hi: float | None = None, lo_open: bool = False) -> float:
    """A controller parameter: a finite number within ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``)."""
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v):
        raise ParameterError(f"{name} must be a finite number, got {v!r}")
    v = float(v)
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise ParameterError(f"{name} must be {'>' if lo_open else '>='} {lo}, got {v}")
    if hi is not None and v > hi:
        raise ParameterError(f"{name} must be <= {hi}, got {v}")
    return v


@dataclass(frozen=True)
class CameraLimits:
    """What the camera accepts: exposure in µs and linear gain (``gain_max = 1`` means no gain)."""

    exposure_min_us: float = 10.0
    exposure_max_us: float = 30_000.0
    gain_max: float = 1.0

    def __post_init__(self) -> None:
        lo = _finite_positive("exposure_min_us", self.exposure_min_us)
        hi = _finite_positive("exposure_max_us", self.exposure_max_us)
        g = _finite_positive("gain_max", self.gain_max)
        if hi < lo:
            raise ParameterError(f"exposure_max_us ({hi}) must be >= exposure_min_us ({lo})")
        if g < 1.0:
            raise ParameterError(f"gain_max must be >= 1 (linear), got {g}")

    @property
    def has_gain(self) -> bool:
        return self.gain_max > 1.0

    def clamp(self, exposure_us: float, gain: float) -> tuple[float, float]:
        return (
            min(max(exposure_us, self.exposure_min_us), self.exposure_max_us),
            min(max(gain, 1.0), self.gain_max),
        )


@dataclass(frozen=True)
class ExposureCommand:
    """Set exposure (µs) and gain (linear, >= 1); issued at ``issue_time_us`` (sensor time)."""

    exposure_us: float
    gain: float
    issue_time_us: int
    controller: str = ""

    def __post_init__(self) -> None:
        _finite_positive("command exposure_us", self.exposure_us)
        if _finite_positive("command gain", self.gain) < 1.0:
            raise ParameterError(f"command gain must be >= 1, got {self.gain}")


class Controller:
    """Base class: records the applied exposure from frames; subclasses decide the commands.

    Subclasses override any of :meth:`on_events`, :meth:`on_exposure_start`,
    :meth:`on_exposure_end`, :meth:`on_frame` (calling ``super().on_frame`` first) and return an
    :class:`ExposureCommand` or ``None``.
    """

    name = "base"

    def __init__(self, limits: CameraLimits, exposure_us: float = 5_000.0, gain: float = 1.0):
        if not isinstance(limits, CameraLimits):
            raise ParameterError("limits must be a CameraLimits")
        self.limits = limits
        exposure_us = _finite_positive("initial exposure_us", exposure_us)
        gain = _finite_positive("initial gain", gain)
        self.exposure_us, self.gain = limits.clamp(exposure_us, gain)
        self.now_us = np.iinfo(np.int64).min
        self.last_command: ExposureCommand | None = None

    def initial_command(self, t_us: int = 0) -> ExposureCommand:
        """The setting to apply before the first frame."""
        return ExposureCommand(self.exposure_us, self.gain, int(t_us), self.name)

    def on_events(self, events: np.ndarray) -> ExposureCommand | None:
        if events.size:
            self.now_us = max(self.now_us, int(events["t"][-1]))
        return None

    def on_exposure_start(self, t_us: int) -> ExposureCommand | None:
        self.now_us = max(self.now_us, int(t_us))
        return None

    def on_exposure_end(self, t_us: int) -> ExposureCommand | None:
        self.now_us = max(self.now_us, int(t_us))
        return None

    def on_frame(self, frame: Frame) -> ExposureCommand | None:
        """Record the exposure and gain the camera actually applied to this frame."""
        self.exposure_us = float(frame.exposure_us)
        self.gain = float(frame.gain)
        self.now_us = max(self.now_us, int(frame.exposure_end_us))
        return None

    def feed(self, packet) -> ExposureCommand | None:
        """Dispatch one packet (event array, :class:`ExposureMarker` or :class:`Frame`)."""
        if isinstance(packet, np.ndarray):
            cmd = self.on_events(packet)
        elif isinstance(packet, ExposureMarker):
            cmd = self.on_exposure_start(packet.t_us) if packet.kind == "start" else self.on_exposure_end(packet.t_us)
        elif isinstance(packet, Frame):
            cmd = self.on_frame(packet)
        elif isinstance(packet, (ImuBatch, TriggerBatch)):
            cmd = None  # no controller uses IMU samples or triggers
        else:
            raise StreamError(f"unknown packet type {type(packet).__name__}")
        if cmd is not None:
            self.last_command = cmd
        return cmd
