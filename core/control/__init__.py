"""Exposure controllers behind one interface (:class:`Controller`)."""

from .base import CameraLimits, Controller, ExposureCommand
from .nec import NECController, error_weight

#: name -> controller class; the baselines register here as they are added.
CONTROLLERS: dict[str, type[Controller]] = {"nec": NECController}

__all__ = ["CONTROLLERS", "CameraLimits", "Controller", "ExposureCommand", "NECController", "error_weight"]
