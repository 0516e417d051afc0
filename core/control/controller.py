"""The interface every exposure controller shares (NEC and the baselines).

A controller is fed the source's packets in stream order — event batches, exposure markers
and frames — and may answer any of them with an :class:`ExposureCommand`. The camera applies
a command at its next exposure start; the controller learns the applied values from the
frames it receives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from necviz.core.checks import check_number
from necviz.core.errors import ParameterError, StreamError
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import ImuBatch, TriggerBatch


@dataclass(frozen=True)
class CameraLimits:
    """What the camera accepts: exposure in µs and linear gain (``gain_max = 1`` means no gain)."""

    exposure_min_us: float = 10.0
    exposure_max_us: float = 30_000.0
    gain_max: float = 1.0

    def __post_init__(self) -> None:
        lo = check_number("exposure_min_us", self.exposure_min_us, 0.0, lo_open=True)
        hi = check_number("exposure_max_us", self.exposure_max_us, 0.0, lo_open=True)
        check_number("gain_max", self.gain_max, 1.0)  # linear gain; 1 = no gain
        if hi < lo:
            raise ParameterError(f"exposure_max_us ({hi}) must be >= exposure_min_us ({lo})")

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
        e, g = self.exposure_us, self.gain
        if type(e) is float and type(g) is float and 0.0 < e < math.inf and 1.0 <= g < math.inf:
            return  # the common case (every command a controller issues), without the general checks
        check_number("command exposure_us", e, 0.0, lo_open=True)
        check_number("command gain", g, 1.0)


@dataclass(frozen=True)
class Tunable:
    """A parameter a user may change while a controller runs (live tuning, ``--set``, sweeps).

    ``lo``/``hi`` bound the value (open ends with ``lo_open``/``hi_open``); ``unit`` and ``doc``
    are shown by the tuning prompt's ``help`` and ``status``.
    """

    name: str
    unit: str
    doc: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def check(self, value) -> float:
        """``value`` as a float inside the bounds, else a one-line :class:`ParameterError`."""
        return check_number(self.name, value, self.lo, self.hi, lo_open=self.lo_open, hi_open=self.hi_open)


#: Camera limits, tunable on every controller (they change what the controller may command).
LIMIT_TUNABLES = (
    Tunable("exposure_min", "µs", "shortest exposure the controller may command", 0.0, None, lo_open=True),
    Tunable("exposure_max", "µs", "longest exposure the controller may command", 0.0, None, lo_open=True),
    Tunable("gain_max", "linear", "highest gain the controller may command (1: no gain)", 1.0),
)
_LIMIT_FIELDS = {"exposure_min": "exposure_min_us", "exposure_max": "exposure_max_us", "gain_max": "gain_max"}


class Controller:
    """Base class: records the applied exposure from frames; subclasses decide the commands.

    Subclasses override any of :meth:`on_events`, :meth:`on_exposure_start`,
    :meth:`on_exposure_end`, :meth:`on_frame` (calling ``super().on_frame`` first) and return an
    :class:`ExposureCommand` or ``None``.

    Tunable parameters: a subclass lists its own in ``TUNABLE`` (each one an attribute of the
    same name unless it overrides :meth:`_get_param` / :meth:`_set_param`); the camera limits
    (:data:`LIMIT_TUNABLES`) are tunable everywhere. :meth:`set_param` checks the bounds and
    any rule that ties parameters together (:meth:`_check_params`).
    """

    name = "base"
    TUNABLE: tuple[Tunable, ...] = ()

    def __init__(self, limits: CameraLimits, exposure_us: float = 5_000.0, gain: float = 1.0):
        if not isinstance(limits, CameraLimits):
            raise ParameterError("limits must be a CameraLimits")
        self.limits = limits
        exposure_us = check_number("initial exposure_us", exposure_us, 0.0, lo_open=True)
        gain = check_number("initial gain", gain, 0.0, lo_open=True)
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

    # -- tunable parameters --------------------------------------------------------------------
    def tunables(self) -> dict[str, Tunable]:
        """Every parameter that may change while running, by name (the limits first)."""
        return {t.name: t for t in (*LIMIT_TUNABLES, *type(self).TUNABLE)}

    def get_param(self, name: str) -> float:
        if name not in self.tunables():
            raise ParameterError(f"{self.name} has no tunable parameter {name!r}; it has {', '.join(self.tunables())}")
        if name in _LIMIT_FIELDS:
            return float(getattr(self.limits, _LIMIT_FIELDS[name]))
        return float(self._get_param(name))

    def check_param(self, name: str, value) -> float:
        """``value`` as it would be set, or a one-line :class:`ParameterError`; changes nothing."""
        spec = self.tunables().get(name)
        if spec is None:
            raise ParameterError(f"{self.name} has no tunable parameter {name!r}; it has {', '.join(self.tunables())}")
        v = spec.check(value)
        if name in _LIMIT_FIELDS:
            replace(self.limits, **{_LIMIT_FIELDS[name]: v})  # CameraLimits checks min <= max
        else:
            self._check_params({**self.params(), name: v})
        return v

    def set_param(self, name: str, value) -> float:
        """Change a tunable parameter; returns the value set. Refuses out-of-range or inconsistent values."""
        v = self.check_param(name, value)
        if name in _LIMIT_FIELDS:
            self.limits = replace(self.limits, **{_LIMIT_FIELDS[name]: v})
        else:
            self._set_param(name, v)
        return v

    def params(self) -> dict[str, float]:
        """Current values of the controller's own tunable parameters (without the limits)."""
        return {t.name: float(self._get_param(t.name)) for t in type(self).TUNABLE}

    def _get_param(self, name: str) -> float:
        return getattr(self, name)

    def _set_param(self, name: str, value: float) -> None:
        setattr(self, name, value)

    def _check_params(self, params: dict[str, float]) -> None:
        """Rules between parameters (e.g. a dead band below its full band); raise ParameterError."""

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
