"""Neuromorphic exposure control: the paper's Eq. 2-4 driven by the P-TEDI estimate.

With ``H = T K`` the exposure-gain product (µs) and ``ln P(now)`` from P-TEDI::

    H_opt = exp(g(I_opt) - ln P(now))           (Eq. 2)
    H_err = H_opt - H_i                          (Eq. 3, sign corrected: the paper's T_i - T_opt
    H_set = H_i + f_w(H_err) H_err                moves away from the target)
    K = max(1, H_set / T_max),  T = H_set / K    (Eq. 4), then clamped to the camera limits

``H_i`` is the product the camera applied to the last frame (Eq. 3's ``T_i``), so commands
issued at high rate between frames do not compound the partial step ``f_w``.
"""

from __future__ import annotations

import math

import numpy as np

from ..checks import check_number
from ..crf import US_PER_S
from ..errors import ParameterError
from ..frames import Frame
from ..ptedi import FrameEstimate, PeripheralEstimator
from .base import CameraLimits, Controller, ExposureCommand, Tunable


def error_weight(relative_error: float, dead_band: float, full_band: float) -> float:
    """``f_w`` (Fig. 8e; exact form unknown, our design): weight in [0, 1] on ``r = |ln(H_opt / H_i)|``.

    0 inside the dead band ``r <= dead_band`` (no flicker from tiny corrections), 1 for
    ``r >= full_band`` (one-shot jumps on big lighting changes), a smoothstep in between.
    """
    r = abs(relative_error)
    if r <= dead_band:
        return 0.0
    if r >= full_band:
        return 1.0
    x = (r - dead_band) / (full_band - dead_band)
    return x * x * (3.0 - 2.0 * x)


class NECController(Controller):
    """NEC: P-TEDI irradiance prediction -> exposure and gain, on every event batch and frame.

    Parameters
    ----------
    estimator : the P-TEDI estimator (owned: the controller feeds it).
    limits : camera exposure/gain limits.
    dead_band, full_band : ``f_w`` corners on the relative error ``|ln(H_opt/H_i)|``
        (defaults: no change below ~10 %, a full jump from ~65 % on).
    goal_log_exposure : ``g(I_opt)``; default the log mid-point of the CRF's valid range.
    min_command_change : a new command is only issued if it differs from the last one by
        more than this relative amount (avoids re-sending the same setting every batch).
    """

    name = "nec"
    TUNABLE = (
        Tunable("dead_band", "ln", "f_w is 0 while |ln(H_opt/H_i)| is at most this (no flicker from tiny corrections)", 0.0),
        Tunable("full_band", "ln", "f_w is 1 from this |ln(H_opt/H_i)| on (one-shot jumps on big changes)", 0.0, lo_open=True),
        Tunable("goal", "DN", "goal intensity I_opt: the digit the mean exposure aims at", 0.0, 255.0, True, True),
        Tunable("min_command_change", "ln", "a new command must differ from the last by more than this", 0.0),
    )

    def __init__(
        self,
        estimator: PeripheralEstimator,
        limits: CameraLimits,
        exposure_us: float = 5_000.0,
        gain: float = 1.0,
        dead_band: float = 0.1,
        full_band: float = 0.5,
        goal_log_exposure: float | None = None,
        min_command_change: float = 0.01,
    ):
        super().__init__(limits, exposure_us, gain)
        if not isinstance(estimator, PeripheralEstimator):
            raise ParameterError("NECController needs a PeripheralEstimator")
        for label, v in (("dead_band", dead_band), ("full_band", full_band), ("min_command_change", min_command_change)):
            check_number(label, v, 0.0)
        if full_band <= dead_band:
            raise ParameterError(f"full_band ({full_band}) must exceed dead_band ({dead_band})")
        self.estimator = estimator
        self.dead_band = float(dead_band)
        self.full_band = float(full_band)
        goal = estimator.crf.goal_log_exposure if goal_log_exposure is None else goal_log_exposure
        self.goal_log_exposure = check_number("goal_log_exposure", goal)
        self.min_command_change = float(min_command_change)
        self.last_log_irradiance = math.nan
        self.last_frame_estimate: FrameEstimate | None = None

    # -- tunable parameters --------------------------------------------------------------------
    def _get_param(self, name: str) -> float:
        if name == "goal":
            return float(self.estimator.crf.intensity(self.goal_log_exposure))
        return getattr(self, name)

    def _set_param(self, name: str, value: float) -> None:
        if name == "goal":
            self.goal_log_exposure = float(self.estimator.crf.log_exposure(value))
        else:
            setattr(self, name, value)

    def _check_params(self, params: dict[str, float]) -> None:
        if params["full_band"] <= params["dead_band"]:
            raise ParameterError(f"need dead_band < full_band, got {params['dead_band']:g} and {params['full_band']:g}")
        crf = self.estimator.crf
        if not crf.valid_min < params["goal"] < crf.valid_max:
            raise ParameterError(f"goal must lie inside the valid range {crf.valid_min}..{crf.valid_max} DN, "
                                 f"got {params['goal']:g}")

    # -- the control law ----------------------------------------------------------------------
    def command_for(self, log_irradiance: float, t_us: int) -> ExposureCommand | None:
        """Eq. 2-4 for a given mean log irradiance; ``None`` inside the dead band.

        Inside the dead band of the applied setting ``H_i`` nothing needs to change, but the
        camera applies the newest command it received at its next exposure start: a command
        issued for a transient that has passed would still take effect. So when the outstanding
        command (:attr:`last_command`) differs from ``H_i`` by more than ``min_command_change``
        and lies outside the dead band of ``H_opt`` itself, the applied setting is commanded
        again (which cancels the stale one); otherwise ``None``.
        """
        if not math.isfinite(log_irradiance):
            return None
        h_i = self.exposure_us * self.gain
        h_opt = math.exp(self.goal_log_exposure - log_irradiance) * US_PER_S
        w = error_weight(math.log(h_opt / h_i), self.dead_band, self.full_band)
        if w == 0.0:
            last = self.last_command
            if last is None:
                return None
            h_last = last.exposure_us * last.gain
            if (abs(math.log(h_last / h_i)) <= self.min_command_change
                    or abs(math.log(h_opt / h_last)) <= self.dead_band):
                return None  # nothing outstanding, or what is outstanding is as good as H_i
            return ExposureCommand(self.exposure_us, self.gain, int(t_us), self.name)
        h_set = h_i + w * (h_opt - h_i)
        lim = self.limits
        gain = max(1.0, h_set / lim.exposure_max_us)
        exposure = h_set / gain
        exposure, gain = lim.clamp(exposure, gain)  # a capped gain leaves exposure at T_max (under-exposed)
        last = self.last_command
        if last is not None and abs(math.log(last.exposure_us * last.gain / (exposure * gain))) < self.min_command_change:
            return None
        return ExposureCommand(exposure, gain, int(t_us), self.name)

    def _command_now(self) -> ExposureCommand | None:
        if not self.estimator.ready:
            return None
        t = max(self.now_us, self.estimator.last_event_us)
        self.last_log_irradiance = self.estimator.predict(t)
        return self.command_for(self.last_log_irradiance, t)

    # -- packets ------------------------------------------------------------------------------
    def on_events(self, events: np.ndarray) -> ExposureCommand | None:
        est = self.estimator  # the hot path (every event batch): kept short
        est.update(events)
        t = est.last_event_us
        if t > self.now_us:
            self.now_us = t
        if not est.ready:
            return None
        t = self.now_us
        self.last_log_irradiance = lp = est.predict(t)
        return self.command_for(lp, t)

    def on_exposure_start(self, t_us: int) -> ExposureCommand | None:
        super().on_exposure_start(t_us)
        self.estimator.begin_exposure(t_us)
        return None

    def on_exposure_end(self, t_us: int) -> ExposureCommand | None:
        super().on_exposure_end(t_us)
        self.estimator.end_exposure(t_us)
        return None

    def on_frame(self, frame: Frame) -> ExposureCommand | None:
        super().on_frame(frame)
        self.last_frame_estimate = self.estimator.add_frame(frame)
        return self._command_now()
