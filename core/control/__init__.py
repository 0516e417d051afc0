"""Exposure controllers behind one interface (:class:`Controller`): NEC and the baselines."""

from __future__ import annotations

import inspect

from necviz.core.control.begin import BeginController
from necviz.core.control.builtin import BuiltinController
from necviz.core.control.controller import CameraLimits, Controller, ExposureCommand
from necviz.core.control.fixed import FixedController
from necviz.core.control.navid import NavidController
from necviz.core.control.nec import ZONE_GRID, NECController, error_weight
from necviz.core.control.shim import ShimController
from necviz.core.crf import CameraResponse, default_davis346
from necviz.core.errors import ParameterError
from necviz.core.event_model import TediParams
from necviz.core.sensor import SensorGeometry

#: name -> controller class
CONTROLLERS: dict[str, type[Controller]] = {
    "nec": NECController,
    "nec-raw": NECController,  # NEC without the TEDI compensation (a± = b± = 0): shows what it adds
    "navid": NavidController,
    "shim": ShimController,
    "begin": BeginController,
    "builtin": BuiltinController,
    "fixed": FixedController,
}


def make_controller(
    name: str,
    *,
    sensor: SensorGeometry,
    limits: CameraLimits,
    exposure_us: float = 5_000.0,
    gain: float = 1.0,
    crf: CameraResponse | None = None,
    tedi: TediParams | None = None,
    **params,
) -> Controller:
    """Build controller ``name`` with its documented defaults (``params`` override them).

    NEC gets a whole-sensor P-TEDI estimator with ``tedi`` (thresholds and compensation), or a
    ``zone_grid`` of zones (``[columns, rows]``, default :data:`~necviz.core.control.nec.ZONE_GRID`
    for ``metering="zones"``); ``nec-raw`` is the same controller (same metering, goal and escape
    rule) with the compensation switched off (``a± = b± = 0``, the thresholds kept), so a
    comparison shows what the compensation adds. Controllers that use
    the camera response (Bégin) get ``crf``.
    """
    if name not in CONTROLLERS:
        raise ParameterError(f"unknown controller {name!r}; available: {', '.join(sorted(CONTROLLERS))}")
    crf = crf or default_davis346()
    if CONTROLLERS[name] is NECController:
        from dataclasses import replace

        from necviz.core.ptedi import PeripheralEstimator

        tedi = tedi or TediParams()
        if name == "nec-raw":
            tedi = replace(tedi, a_on=0.0, b_on=0.0, a_off=0.0, b_off=0.0)
        grid = params.pop("zone_grid", None)
        metering = params.get("metering", inspect.signature(NECController).parameters["metering"].default)
        if grid is None:
            grid = ZONE_GRID if metering == "zones" else (1, 1)
        if not (isinstance(grid, (list, tuple)) and len(grid) == 2):
            raise ParameterError(f"controller {name!r}: zone_grid must be [columns, rows], got {grid!r}")
        est = PeripheralEstimator(sensor, tedi, crf, grid=tuple(grid))
        try:
            ctrl = NECController(est, limits, exposure_us, gain, **params)
        except TypeError as e:
            raise ParameterError(f"controller {name!r}: {e}") from None
        ctrl.name = name
        return ctrl
    cls = CONTROLLERS[name]
    if "crf" in inspect.signature(cls).parameters:
        params.setdefault("crf", crf)
    try:
        return cls(limits, exposure_us, gain, **params)
    except TypeError as e:
        raise ParameterError(f"controller {name!r}: {e}") from None


__all__ = [
    "CONTROLLERS",
    "CameraLimits",
    "Controller",
    "ExposureCommand",
    "NECController",
    "error_weight",
    "make_controller",
    "NavidController",
    "ShimController",
    "BeginController",
    "BuiltinController",
    "FixedController",
]
