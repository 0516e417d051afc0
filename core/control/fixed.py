"""Fixed exposure: the setting chosen at the start is never changed (the "no AE" baseline).

The exposure and gain passed to the constructor are clamped to the camera limits and sent once
by :meth:`Controller.initial_command`; every packet afterwards is answered with ``None``.
"""

from __future__ import annotations

from ..frames import Frame
from .base import CameraLimits, Controller, ExposureCommand


class FixedController(Controller):
    """Exposure ``exposure_us`` (µs) and linear gain ``gain`` set once, then left alone.

    Parameters
    ----------
    limits : camera exposure/gain limits (the initial setting is clamped to them).
    exposure_us : the fixed exposure in µs (default 5000), a positive finite number.
    gain : the fixed linear gain (default 1), a positive finite number; clamped to [1, gain_max].
    """

    name = "fixed"

    def __init__(self, limits: CameraLimits, exposure_us: float = 5_000.0, gain: float = 1.0):
        super().__init__(limits, exposure_us, gain)
        self.fixed_exposure_us = self.exposure_us
        self.fixed_gain = self.gain

    def initial_command(self, t_us: int = 0) -> ExposureCommand:
        return ExposureCommand(self.fixed_exposure_us, self.fixed_gain, int(t_us), self.name)

    def on_frame(self, frame: Frame) -> ExposureCommand | None:
        super().on_frame(frame)
        return None
