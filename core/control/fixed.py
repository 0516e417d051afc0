"""Fixed exposure: the setting chosen at the start is never changed (the "no AE" baseline).

The exposure and gain passed to the constructor are clamped to the camera limits and sent once
by :meth:`Controller.initial_command`; every packet afterwards is answered with ``None`` — unless
the user tunes ``exposure`` or ``gain`` while it runs: the new setting is sent with the next frame.
"""

from __future__ import annotations

from necviz.core.control.controller import CameraLimits, Controller, ExposureCommand, Tunable
from necviz.core.errors import ParameterError
from necviz.core.frames import Frame


class FixedController(Controller):
    """Exposure ``exposure_us`` (µs) and linear gain ``gain`` set once, then left alone.

    Parameters
    ----------
    limits : camera exposure/gain limits (the initial setting is clamped to them).
    exposure_us : the fixed exposure in µs (default 5000), a positive finite number.
    gain : the fixed linear gain (default 1), a positive finite number; clamped to [1, gain_max].
    """

    name = "fixed"
    TUNABLE = (
        Tunable("exposure", "µs", "the fixed exposure (sent with the next frame)", 0.0, lo_open=True),
        Tunable("gain", "linear", "the fixed gain (sent with the next frame)", 1.0),
    )

    def __init__(self, limits: CameraLimits, exposure_us: float = 5_000.0, gain: float = 1.0):
        super().__init__(limits, exposure_us, gain)
        self.fixed_exposure_us = self.exposure_us
        self.fixed_gain = self.gain
        self._changed = False

    def initial_command(self, t_us: int = 0) -> ExposureCommand:
        return ExposureCommand(self.fixed_exposure_us, self.fixed_gain, int(t_us), self.name)

    def on_frame(self, frame: Frame) -> ExposureCommand | None:
        super().on_frame(frame)
        if self._changed:
            self._changed = False
            return ExposureCommand(self.fixed_exposure_us, self.fixed_gain, int(self.now_us), self.name)
        return None

    def _check_params(self, params: dict[str, float]) -> None:
        lim = self.limits
        if not lim.exposure_min_us <= params["exposure"] <= lim.exposure_max_us:
            raise ParameterError(
                f"exposure = {params['exposure']:g} µs is outside the camera limits "
                f"{lim.exposure_min_us:g}..{lim.exposure_max_us:g} µs"
            )
        if params["gain"] > lim.gain_max:
            raise ParameterError(f"gain = {params['gain']:g} is above the camera's gain_max {lim.gain_max:g}")

    def _get_param(self, name: str) -> float:
        return self.fixed_exposure_us if name == "exposure" else self.fixed_gain

    def _set_param(self, name: str, value: float) -> None:
        exposure, gain = (value, self.fixed_gain) if name == "exposure" else (self.fixed_exposure_us, value)
        self.fixed_exposure_us, self.fixed_gain = self.limits.clamp(exposure, gain)
        self._changed = True
