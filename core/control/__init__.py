"""Exposure controllers behind one interface (:class:`Controller`): NEC and the baselines."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace

from necviz.core.control.begin import BeginController, BeginOptions
from necviz.core.control.builtin import BuiltinController
from necviz.core.control.controller import CameraLimits, Controller, ControllerOptions, ExposureCommand, Tunable
from necviz.core.control.fixed import FixedController
from necviz.core.control.navid import NavidController, NavidOptions
from necviz.core.control.nec import ZONE_GRID, NECController, NECFramesController, NECOptions, error_weight
from necviz.core.control.shim import ShimController, ShimOptions
from necviz.core.crf import CameraResponse, default_davis346
from necviz.core.errors import ParameterError
from necviz.core.event_model import TediParams
from necviz.core.ptedi import PeripheralEstimator, PeripheralOptions
from necviz.core.sensor import SensorGeometry


@dataclass(frozen=True)
class ControllerContext:
    """What building a controller for one camera needs (besides the controller's own options).

    Parameters
    ----------
    sensor : SensorGeometry
        The pixel array (NEC's P-TEDI estimator is built on it).
    limits : CameraLimits
        What the camera accepts.
    exposure_us, gain : float
        The camera's setting when the controller takes over.
    crf : CameraResponse
        The camera response (NEC, Bégin).
    tedi : TediParams
        Event thresholds and compensation (NEC's estimator).
    estimator : PeripheralEstimator, optional
        An estimator to adopt instead of building one (a lane switching to NEC keeps its anchor).
    event_rate_max : float, optional
        The source's event bus ceiling (events/s, its :class:`~necviz.drivers.source.CameraInfo`):
        NEC's escape rule reads it; ``None`` when the source knows none (no ceiling).
    """

    sensor: SensorGeometry
    limits: CameraLimits
    exposure_us: float = 5_000.0
    gain: float = 1.0
    crf: CameraResponse = field(default_factory=default_davis346)
    tedi: TediParams = TediParams()
    estimator: PeripheralEstimator | None = None
    event_rate_max: float | None = None


#: A builder makes a controller from the context and its options (``None`` for a controller without options).
Builder = Callable[[ControllerContext, "ControllerOptions | None"], Controller]


@dataclass(frozen=True)
class ControllerEntry:
    """A registered controller: its class (whose ``OPTIONS`` are its settings), how to build it and the
    option values it starts from where they differ from ``OPTIONS``' defaults (``nec-paper``, a tuned
    baseline)."""

    cls: type[Controller]
    build: Builder
    doc: str = ""
    defaults: dict = field(default_factory=dict)


def _plain(cls: type[Controller]) -> Builder:
    """The builder of a controller that needs only the camera's limits and setting."""
    if cls.OPTIONS is None:
        return lambda ctx, options: cls(ctx.limits, ctx.exposure_us, ctx.gain)
    return lambda ctx, options: cls(ctx.limits, ctx.exposure_us, ctx.gain, options)


def _estimator(ctx: ControllerContext, options: NECOptions, tedi: TediParams) -> PeripheralEstimator:
    """NEC's P-TEDI estimator: the context's own if it has one, else a new one with ``tedi``."""
    if ctx.estimator is not None:
        return ctx.estimator
    if not options.compensation:  # the controller would zero them anyway: never allocate their state
        tedi = replace(tedi, a_on=0.0, b_on=0.0, a_off=0.0, b_off=0.0)
    grid = options.zone_grid or (ZONE_GRID if options.metering == "zones" else (1, 1))
    return PeripheralEstimator(
        ctx.sensor, tedi, ctx.crf, options=PeripheralOptions(grid=grid, saturation_bound=options.saturation_bound)
    )


def _build_nec(ctx: ControllerContext, options: ControllerOptions | None) -> Controller:
    assert isinstance(options, NECOptions)  # make_options gives an instance of NECController.OPTIONS
    est = _estimator(ctx, options, ctx.tedi)
    return NECController(est, ctx.limits, ctx.exposure_us, ctx.gain, options, ctx.event_rate_max)


def _build_nec_frames(ctx: ControllerContext, options: ControllerOptions | None) -> Controller:
    assert isinstance(options, NECOptions)  # make_options gives an instance of NECController.OPTIONS
    est = _estimator(ctx, options, ctx.tedi)
    return NECFramesController(est, ctx.limits, ctx.exposure_us, ctx.gain, options, ctx.event_rate_max)


#: ``nec-paper``'s options: every necviz addition switched off, the paper's setting wherever the paper is
#: specific — including its TEDI compensation (Eq. 6: the trilinear TEDI applies ``a±, b±``; with the shipped
#: simulator profile, whose ``a = b = 0``, on and off are the same). What the paper leaves open stays
#: necviz's and is named in ``nec-paper``'s description and the ladder (docs/method.md): f_w's smoothstep and
#: dead band, ``min_command_change``, the stale-command re-send, the 50 % valid-pixel skip threshold, the
#: first anchor on any frame.
PAPER_OPTIONS = {
    "saturation_bound": False,
    "metering": "paper",
    "goal_mode": "paper",
    "escape": False,
    "compensation": True,
    "bound_lag": False,
    "flicker_rule": False,
    "flicker_edges": False,
}


def _build_begin(ctx: ControllerContext, options: ControllerOptions | None) -> Controller:
    assert isinstance(options, BeginOptions)  # make_options gives an instance of BeginController.OPTIONS
    return BeginController(ctx.limits, ctx.exposure_us, ctx.gain, options, crf=ctx.crf)


#: name -> registered controller (:func:`register_controller` adds one)
CONTROLLERS: dict[str, ControllerEntry] = {}


def register_controller(
    name: str, cls: type[Controller], build: Builder | None = None, doc: str = "", defaults: dict | None = None
) -> None:
    """Make controller ``name`` known to :func:`make_controller` (and so to every command).

    Parameters
    ----------
    name : str
        The name commands, sweeps and the tuning prompt use.
    cls : type of Controller
        Its class; ``cls.OPTIONS`` (if any) holds the settings ``make_controller`` accepts.
    build : callable, optional
        ``build(context, options) -> Controller``; default: ``cls(limits, exposure_us, gain[, options])``.
    doc : str
        One line for listings.
    defaults : dict, optional
        Option values this name starts from instead of ``cls.OPTIONS``' defaults (parameters given
        when building still override them): ``nec-paper`` is ``nec`` with the paper's switches, a
        tuned baseline the baseline with its tuned parameters.

    Raises
    ------
    ParameterError
        ``cls`` is not a :class:`Controller` subclass, or ``defaults`` are not valid options of it.
    """
    if not (isinstance(cls, type) and issubclass(cls, Controller)):
        raise ParameterError(f"controller {name!r}: {cls!r} is not a Controller subclass")
    defaults = dict(defaults or {})
    if defaults:
        if cls.OPTIONS is None:
            raise ParameterError(f"controller {name!r}: {cls.__name__} has no options to give defaults")
        known = {f.name for f in fields(cls.OPTIONS)}
        unknown = sorted(set(defaults) - known)
        if unknown:
            raise ParameterError(f"controller {name!r}: {cls.OPTIONS.__name__} has no option {unknown[0]!r}")
        cls.OPTIONS(**defaults)  # refuse values the options refuse, now rather than at first use
    CONTROLLERS[name] = ControllerEntry(cls, build or _plain(cls), doc, defaults)


register_controller("nec", NECController, _build_nec, "NEC: P-TEDI prediction from events and frames")
register_controller(
    "nec-frames",
    NECFramesController,
    _build_nec_frames,
    "NEC with no events: the same metering, goal, law and escape rule from frames alone (what the events add)",
)
register_controller(
    "nec-paper",
    NECController,
    _build_nec,
    "the paper's controller where the paper is specific (mean metering, mid-point goal, skip saturated anchors, no "
    "escape, TEDI with its compensation); necviz's where it is silent: f_w's smoothstep and dead band, "
    "min_command_change, the stale-command re-send, the 50 % valid-pixel skip threshold",
    PAPER_OPTIONS,
)
register_controller(
    "nec-raw",
    NECController,
    _build_nec,
    "NEC without the TEDI compensation (a± = b± = 0): what it adds",
    {"compensation": False},
)
register_controller("navid", NavidController, doc="Nourani-Vatani & Roberts 2007: histogram MSV, PI loops")
register_controller("shim", ShimController, doc="Shim et al. 2014/2018: gradient metric over gamma images")
register_controller("begin", BeginController, _build_begin, doc="Bégin & Hunter 2022: CRF prediction, flow, saturation")
register_controller("builtin", BuiltinController, doc="the DAVIS built-in auto-exposure (libcaer)")
register_controller("fixed", FixedController, doc="the starting exposure, kept")


def make_options(name: str, params: dict | None = None) -> ControllerOptions | None:
    """Controller ``name``'s options with ``params`` replacing the defaults.

    Raises
    ------
    ParameterError
        An unknown controller, a parameter it does not have, or a value its options refuse.
    """
    entry = CONTROLLERS.get(name)
    if entry is None:
        raise ParameterError(f"unknown controller {name!r}; available: {', '.join(sorted(CONTROLLERS))}")
    params = dict(params or {})
    cls = entry.cls.OPTIONS
    if cls is None:
        if params:
            raise ParameterError(f"controller {name!r} has no option {next(iter(params))!r}")
        return None
    known = [f.name for f in fields(cls)]
    unknown = [k for k in params if k not in known]
    if unknown:
        raise ParameterError(f"controller {name!r} has no option {unknown[0]!r}; it has {', '.join(known)}")
    return cls(**{**entry.defaults, **params})


def make_controller(
    name: str,
    *,
    sensor: SensorGeometry,
    limits: CameraLimits,
    exposure_us: float = 5_000.0,
    crf: CameraResponse | None = None,
    tedi: TediParams | None = None,
    event_rate_max: float | None = None,
    **params,
) -> Controller:
    """Build controller ``name`` with its documented defaults (``params`` override its options).

    NEC gets a whole-sensor P-TEDI estimator with ``tedi`` (thresholds and compensation), or a
    ``zone_grid`` of zones (``[columns, rows]``, default :data:`~necviz.core.control.nec.ZONE_GRID`
    for ``metering="zones"``); ``nec-raw`` is the same controller (same metering, goal and escape
    rule) with the compensation switched off (``a± = b± = 0``, the thresholds kept), so a
    comparison shows what the compensation adds; ``nec-paper`` is NEC with every necviz addition
    off and the paper's setting where the paper is specific (:data:`PAPER_OPTIONS`); ``nec-frames`` is NEC whose estimator never sees an event.
    Controllers that use the camera response (Bégin) get ``crf``.

    Parameters
    ----------
    name : str
        A registered controller (:data:`CONTROLLERS`).
    sensor, limits, exposure_us, crf, tedi, event_rate_max
        The camera (see :class:`ControllerContext`; the starting gain is 1: for another, build the
        context and call :func:`create_controller`); ``event_rate_max`` is the source's event bus
        ceiling (pass ``source.camera_info.event_rate_max``).
    **params
        Fields of the controller's options (e.g. ``metering="paper"`` for NEC).

    Returns
    -------
    Controller
        The controller, named ``name``.

    Raises
    ------
    ParameterError
        An unknown controller or option, or a value its options refuse.
    """
    ctx = ControllerContext(
        sensor, limits, exposure_us, 1.0, crf or default_davis346(), tedi or TediParams(), None, event_rate_max
    )
    return create_controller(name, ctx, params)


def create_controller(name: str, context: ControllerContext, params: dict | None = None) -> Controller:
    """Build registered controller ``name`` for ``context`` with ``params`` replacing its option defaults.

    Raises
    ------
    ParameterError
        An unknown controller or option, or a value its options refuse.
    """
    options = make_options(name, params)
    ctrl = CONTROLLERS[name].build(context, options)
    ctrl.name = name
    return ctrl


__all__ = [
    "CONTROLLERS",
    "BeginOptions",
    "ControllerContext",
    "ControllerEntry",
    "ControllerOptions",
    "NECOptions",
    "NavidOptions",
    "ShimOptions",
    "Tunable",
    "create_controller",
    "make_options",
    "register_controller",
    "CameraLimits",
    "Controller",
    "ExposureCommand",
    "NECController",
    "NECFramesController",
    "PAPER_OPTIONS",
    "error_weight",
    "make_controller",
    "NavidController",
    "ShimController",
    "BeginController",
    "BuiltinController",
    "FixedController",
]
