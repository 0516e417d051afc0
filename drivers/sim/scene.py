"""The scene interface of the simulator: a time-varying HDR irradiance field at sensor resolution.

Irradiance is in necviz's units (``g(Z) = ln T + ln K + ln L`` with ``T`` in seconds, ``g(128) = 0``):
``ln L = 5`` is well exposed at about 4 ms, every +1 is a factor e (8.7 dB) brighter.
A scene is deterministic: the same parameters and seed give the same field at every time.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from necviz.core.errors import ParameterError
from necviz.core.sensor import DAVIS346, SensorGeometry

if TYPE_CHECKING:
    from necviz.core.markers import MarkerTruth


@dataclass(frozen=True)
class LightingChange:
    """A documented lighting event of a scenario, for recovery-time metrics and plots."""

    t_us: int
    label: str
    delta_log: float  # change of the scene's mean ln L it causes (natural log units)


class Scene:
    """Base class: subclasses implement :meth:`log_irradiance`.

    Attributes: ``name``, ``sensor``, ``duration_us``, ``seed``, ``params`` (the documented
    parameters as a plain dict), ``changes`` (list of :class:`LightingChange`).

    Ground truth a scene may give (``None`` where it has none): ``pedestrian_box(t_us)``, the box of a
    pedestrian seen at ``t_us`` (``tunnel_exit``), ``marker_truth(t_us)``, its fiducial markers
    (:class:`~necviz.core.markers.MarkerTruth`), ``mean_log(t_us)``, its exact mean ``ln L``; and
    ``bracket_us``, the length of a static opening made for exposure brackets (0: none).
    """

    name = "scene"
    pedestrian_box: Callable[..., tuple[int, int, int, int] | None] | None = None
    marker_truth: Callable[[float], MarkerTruth | None] | None = None
    mean_log: Callable[[float], float] | None = None
    bracket_us: int = 0

    def __init__(
        self,
        sensor: SensorGeometry = DAVIS346,
        duration_us: int = 5_000_000,
        seed: int = 0,
        params: dict | None = None,
        changes: list[LightingChange] | None = None,
    ):
        if not isinstance(duration_us, (int, np.integer)) or duration_us <= 0:
            raise ParameterError(f"scene duration must be a positive integer (µs), got {duration_us!r}")
        if not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ParameterError(f"scene seed must be a non-negative integer, got {seed!r}")
        self.sensor = sensor
        self.duration_us = int(duration_us)
        self.seed = int(seed)
        self.params = dict(params or {})
        self.changes = list(changes or [])

    def log_irradiance(self, t_us: float) -> np.ndarray:
        """``ln L(t, x)`` for every pixel: float32 array of shape ``sensor.shape``."""
        raise NotImplementedError

    def max_log_rate(self, t0_us: float, t1_us: float) -> float | None:
        """An upper bound of ``|d ln L / dt|`` (per µs) on ``[t0, t1]``, or ``None`` if unknown.

        The simulator refines its sampling where this is large (ESIM-style adaptive sampling);
        without it, it compares consecutive samples.
        """
        return None

    def describe(self) -> dict:
        return {
            "name": self.name,
            "seed": self.seed,
            "duration_us": self.duration_us,
            "sensor": f"{self.sensor.width}x{self.sensor.height}",
            **self.params,
        }


class FunctionScene(Scene):
    """A user-defined scene from a Python function ``fn(t_us, sensor) -> ln L image``.

    Example::

        def my_scene(t_us, sensor):
            yy, xx = np.mgrid[0:sensor.height, 0:sensor.width]
            base = 5.0 + 0.3 * np.sin(xx / 7.0) * np.cos(yy / 5.0)
            return base + (3.0 if t_us > 1_000_000 else 0.0)     # +26 dB at 1 s

        scene = FunctionScene(my_scene, duration_us=2_000_000)
    """

    name = "custom"

    def __init__(
        self,
        fn,
        sensor: SensorGeometry = DAVIS346,
        duration_us: int = 5_000_000,
        seed: int = 0,
        changes: list[LightingChange] | None = None,
        name: str = "custom",
    ):
        super().__init__(sensor, duration_us, seed, {"function": getattr(fn, "__name__", "fn")}, changes)
        if not callable(fn):
            raise ParameterError("FunctionScene needs a callable fn(t_us, sensor) -> ln L image")
        self._fn = fn
        self.name = name

    def log_irradiance(self, t_us: float) -> np.ndarray:
        img = np.asarray(self._fn(t_us, self.sensor), dtype=np.float32)
        if img.shape != self.sensor.shape:
            raise ParameterError(f"scene function returned shape {img.shape}, expected {self.sensor.shape}")
        if not np.all(np.isfinite(img)):
            raise ParameterError(f"scene function returned NaN or infinite ln L at t = {t_us} µs")
        return img


def db_to_log(db: float) -> float:
    """Irradiance ratio in dB (20 log10) to natural-log units: 120 dB = 13.8."""
    return db * math.log(10.0) / 20.0
