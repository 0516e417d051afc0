"""The interface every exposure controller shares (NEC and the baselines).

A controller is fed the source's packets in stream order — event batches, exposure markers
and frames — and may answer any of them with an :class:`ExposureCommand`. The camera applies
a command at its next exposure start; the controller learns the applied values from the
frames it receives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from necviz.core.checks import check_number
from necviz.core.errors import ParameterError
from necviz.core.frames import Frame
from necviz.core.stream import Packet, PacketHandler, dispatch

if TYPE_CHECKING:
    from necviz.core.ptedi import FrameEstimate, PeripheralEstimator


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


@dataclass(frozen=True)
class ControllerOptions:
    """Base of a controller's settings: a frozen dataclass, validated once, in ``__post_init__``.

    A subclass lists its tunable fields in ``TUNABLE`` (bounds, unit, meaning); ``__post_init__``
    checks each of them against its :class:`Tunable` and then calls :meth:`check` for the rules of
    the other fields and between fields. Changing a setting while running builds a new options
    object with :func:`dataclasses.replace`, so the same checks apply.
    """

    TUNABLE: ClassVar[tuple[Tunable, ...]] = ()

    def __post_init__(self) -> None:
        for t in self.TUNABLE:
            if t.name in self.__dataclass_fields__ and getattr(self, t.name) is not None:
                object.__setattr__(self, t.name, t.check(getattr(self, t.name)))
        self.check()

    def check(self) -> None:
        """Rules beyond the tunable bounds (choices, rules between fields); raise :class:`ParameterError`."""


class Controller(PacketHandler):
    """Base class: records the applied exposure from frames; subclasses decide the commands.

    Subclasses override any of :meth:`on_events`, :meth:`on_exposure_start`,
    :meth:`on_exposure_end`, :meth:`on_frame` (calling ``super().on_frame`` first) and return an
    :class:`ExposureCommand` or ``None``.

    Settings: a controller with settings names its :class:`ControllerOptions` subclass in
    ``OPTIONS`` and takes an instance as ``options`` (default: the defaults); its tunable fields
    (``OPTIONS.TUNABLE``) and the camera limits (:data:`LIMIT_TUNABLES`) may change while it runs
    (:meth:`set_param`). Rules that need the controller's context (its camera response, say) go in
    :meth:`_check_options`; values derived from the settings are recomputed in :meth:`_apply_options`.

    Estimator: :attr:`estimator` is the P-TEDI estimator a controller owns and feeds (NEC), or
    ``None`` for a frame-only controller; a pipeline gives a frame-only controller a passive one so
    every lane has a prediction to show. Whether the controller uses events at all is
    :attr:`uses_events` (``nec-frames`` owns an estimator that it feeds frames only).

    Parameters
    ----------
    limits : CameraLimits
        What the camera accepts.
    exposure_us : float
        Initial exposure (µs), clamped to the limits.
    gain : float
        Initial linear gain, clamped to the limits.
    options : ControllerOptions, optional
        The controller's settings (an instance of ``OPTIONS``); default: ``OPTIONS()``.

    Raises
    ------
    ParameterError
        Limits, initial values or options that are not what the controller accepts.
    """

    name = "base"
    OPTIONS: ClassVar[type[ControllerOptions] | None] = None
    #: tunable attributes of a controller without options (e.g. the fixed exposure itself)
    TUNABLE: ClassVar[tuple[Tunable, ...]] = ()
    #: the P-TEDI estimator this controller owns and feeds; ``None``: it uses frames only
    estimator: PeripheralEstimator | None = None
    #: whether event batches inform its commands (NEC); ``False``: it receives them and ignores
    #: them (every image-only baseline, and ``nec-frames``, whose estimator sees frames only)
    uses_events: ClassVar[bool] = False
    #: what the owned estimator made of the last frame (``None`` without an estimator)
    last_frame_estimate: FrameEstimate | None = None
    #: P-TEDI's ``ln P`` at the last command decision (NaN without an estimator)
    last_log_irradiance: float = math.nan

    def __init__(
        self,
        limits: CameraLimits,
        exposure_us: float = 5_000.0,
        gain: float = 1.0,
        options: ControllerOptions | None = None,
    ):
        if not isinstance(limits, CameraLimits):
            raise ParameterError("limits must be a CameraLimits")
        self.limits = limits
        exposure_us = check_number("initial exposure_us", exposure_us, 0.0, lo_open=True)
        gain = check_number("initial gain", gain, 0.0, lo_open=True)
        self.exposure_us, self.gain = limits.clamp(exposure_us, gain)
        self.now_us = np.iinfo(np.int64).min
        self.last_command: ExposureCommand | None = None
        self.options: ControllerOptions | None = None
        cls = type(self).OPTIONS
        if cls is None:
            if options is not None:
                raise ParameterError(f"controller {self.name!r} has no options")
        else:
            options = cls() if options is None else options
            if not isinstance(options, cls):
                raise ParameterError(f"controller {self.name!r} takes {cls.__name__}, got {type(options).__name__}")
            self._apply_options(options)

    def _check_options(self, options: ControllerOptions) -> None:
        """Rules that need the controller's context (e.g. its camera response); raise ParameterError."""

    def _apply_options(self, options: ControllerOptions) -> None:
        """Adopt ``options`` (checked by :meth:`_check_options`); subclasses recompute derived values after."""
        self._check_options(options)
        self.options = options

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
        options_cls = type(self).OPTIONS
        own = options_cls.TUNABLE if options_cls is not None else type(self).TUNABLE
        return {t.name: t for t in (*LIMIT_TUNABLES, *own)}

    def _spec(self, name: str) -> Tunable:
        spec = self.tunables().get(name)
        if spec is None:
            raise ParameterError(f"{self.name} has no tunable parameter {name!r}; it has {', '.join(self.tunables())}")
        return spec

    def get_param(self, name: str) -> float:
        """The current value of a tunable parameter."""
        self._spec(name)
        if name in _LIMIT_FIELDS:
            return float(getattr(self.limits, _LIMIT_FIELDS[name]))
        return float(self._get_param(name))

    def _replaced(self, name: str, value: float):
        """The limits or options with ``name`` set to ``value`` (checked), and which of the two it is."""
        if name in _LIMIT_FIELDS:
            return "limits", replace(self.limits, **{_LIMIT_FIELDS[name]: value})  # CameraLimits checks min <= max
        if self.options is None:
            self._check_params({**self.params(), name: value})
            return "own", value
        new = replace(self.options, **{name: value})  # the options check themselves
        self._check_options(new)
        return "options", new

    def check_param(self, name: str, value) -> float:
        """``value`` as it would be set, or a one-line :class:`ParameterError`; changes nothing."""
        v = self._spec(name).check(value)
        self._replaced(name, v)
        return v

    def set_param(self, name: str, value) -> float:
        """Change a tunable parameter; returns the value set. Refuses out-of-range or inconsistent values."""
        v = self._spec(name).check(value)
        kind, new = self._replaced(name, v)
        if kind == "limits":
            self.limits = new
        elif kind == "options":
            self._apply_options(new)
        else:
            self._set_param(name, v)
        return v

    def params(self) -> dict[str, float]:
        """Current values of the controller's own tunable parameters (without the limits)."""
        return {name: self.get_param(name) for name in self.tunables() if name not in _LIMIT_FIELDS}

    def _get_param(self, name: str) -> float:
        if self.options is not None:
            return getattr(self.options, name)
        return getattr(self, name)

    def _set_param(self, name: str, value: float) -> None:
        """Set a tunable parameter of a controller without options (its own attribute)."""
        setattr(self, name, value)

    def _check_params(self, params: dict[str, float]) -> None:
        """Rules between the tunable parameters of a controller without options; raise ParameterError."""

    def feed(self, packet: Packet) -> ExposureCommand | None:
        """One stream packet (:data:`~necviz.core.stream.Packet`) to the method for its kind; remembers a command."""
        cmd = dispatch(self, packet)
        if cmd is not None:
            self.last_command = cmd
        return cmd

    def feed_events(self, events: np.ndarray) -> ExposureCommand | None:
        """:meth:`feed` for an :class:`~necviz.core.events.EventBatch`'s ``events``, without the dispatch: the
        pipeline's hot path (one call per event batch, ~10k a second at the sensor's full rate)."""
        cmd = self.on_events(events)
        if cmd is not None:
            self.last_command = cmd
        return cmd
