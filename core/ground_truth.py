"""What the simulator knows about a frame and a real camera cannot: :class:`GroundTruth`.

Used by the metrics that need it (:mod:`necviz.core.metrics`) and by the diagnosis of saturated
frames (:mod:`necviz.core.diagnosis`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from necviz.core.crf import CameraResponse
from necviz.core.markers import MarkerTruth

#: Digits at or above ``OVER`` are over-exposed, at or below ``UNDER`` under-exposed (the paper's 9..250).
OVER = 250
UNDER = 9

#: A region is *well exposed* when at least this fraction of its pixels is valid (10..249 DN): the
#: complement of the "slightly saturated" threshold (more than 10 % clipped).
WELL_EXPOSED = 0.9
#: The lighting trace and the frame's level on it are means over every ``TRACE_STEP``-th pixel in each
#: direction (a fixed grid: a sixteenth of the pixels, ~13 µs a sample on a DAVIS346).
TRACE_STEP = 4


@dataclass(eq=False)
class GroundTruth:
    """What the simulator knows about one frame and a real camera cannot (``Frame.truth``).

    ``mean_irradiance``: ``Lbar(x) = (1/T) ∫_s^e L(x, t) dt`` per pixel (linear necviz units,
    float32, H x W), the exposure-averaged irradiance the frame was formed from
    (:func:`necviz.drivers.sim.aps.integrate_samples`); its noiseless digit is
    ``round(f(ln T + ln K + ln Lbar))`` (Eq. 1 of the paper, ``T`` in seconds).
    ``crf``: the camera's true response. ``light_t_us`` / ``light_log``: the scene's lighting
    trace — the mean of ``ln L`` over the sensor (on the grid of :data:`TRACE_STEP`) at each
    rendered scene sample from a look-back before the exposure to its end. ``latency_us``: a
    command takes effect at the first exposure starting at least this long after it was issued.
    ``exposure_min_us`` .. ``exposure_max_us``, ``gain_max``: what the camera accepts.
    ``readout_us``: the frame is delivered this long after its exposure ends. ``changes``: the
    scene's documented lighting changes (:class:`~necviz.drivers.sim.scene.LightingChange`).
    ``pedestrian_box``: ``(x0, y0, x1, y1)`` (pixels, end-exclusive) of the scene's pedestrian at
    mid-exposure, ``None`` when the scene has none or it is not visible. ``markers``: where the
    scene's fiducial markers were at mid-exposure (:class:`~necviz.core.markers.MarkerTruth`), ``None``
    when it has none. ``lost_t_us`` /
    ``lost_on`` / ``lost_off``: the events the sensor generated but lost at its event bus ceiling,
    cumulative ON and OFF counts since the run started, at each simulator step from the trace's
    look-back to the exposure's end (:meth:`lost_at`); ``event_thresholds``: the sensor's nominal
    ``(c_on, c_off)``, which turn a count into the log change it carried (:meth:`lost_log_change`).
    """

    mean_irradiance: np.ndarray
    crf: CameraResponse
    light_t_us: np.ndarray
    light_log: np.ndarray
    latency_us: float = 0.0
    exposure_min_us: float = 1.0
    exposure_max_us: float = math.inf
    gain_max: float = 1.0
    readout_us: float = 0.0
    changes: tuple = ()
    pedestrian_box: tuple | None = None
    markers: MarkerTruth | None = None
    lost_t_us: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    lost_on: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    lost_off: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    event_thresholds: tuple = (math.nan, math.nan)
    _log_mean: float | None = field(default=None, init=False, repr=False)

    def lost_at(self, t_us: float) -> tuple[int, int] | None:
        """``(ON, OFF)`` events lost at the bus ceiling from the run's start up to ``t_us`` (the last
        simulator step at or before it); ``None`` when ``t_us`` precedes what the trace covers."""
        t = self.lost_t_us
        if t.size == 0 or t_us < t[0]:
            return None
        i = int(np.searchsorted(t, t_us, side="right")) - 1
        return int(self.lost_on[i]), int(self.lost_off[i])

    def lost_log_change(self, lost_on: int, lost_off: int) -> float:
        """The sensor-mean log change that ``lost_on`` ON and ``lost_off`` OFF lost events carried
        (Eq. 11 with the nominal thresholds): ``(c_on·n_on − c_off·n_off) / N``, ``N`` the pixels."""
        c_on, c_off = self.event_thresholds
        return (c_on * lost_on - c_off * lost_off) / float(self.mean_irradiance.size)

    def light_at(self, t_us: float) -> float:
        """The scene's mean ``ln L`` at ``t_us`` (linear between trace samples, held beyond them)."""
        if self.light_t_us.size == 0:
            return math.nan
        return float(np.interp(float(t_us), self.light_t_us.astype(np.float64), self.light_log))

    def log_mean(self) -> float:
        """Mean over the sensor (same grid as the trace) of ``ln Lbar``: the frame's light level on the trace's scale."""
        if self._log_mean is None:
            sub = self.mean_irradiance[::TRACE_STEP, ::TRACE_STEP]
            self._log_mean = float(np.mean(np.log(np.maximum(sub, np.float32(1e-30)))))
        return self._log_mean

    def bounds(self, exposure_us: float, gain: float, shift: float = 0.0) -> tuple[float, float]:
        """Linear irradiance bounds ``[lo, hi)`` of pixels recorded valid (``UNDER < Z < OVER``) at this
        exposure, with the light scaled by ``e^-shift``: ``g(UNDER + ½) <= ln T + ln K + ln Lbar - shift < g(OVER - ½)``."""
        log_tk = math.log(exposure_us / 1e6) + math.log(gain)
        g_lo = float(self.crf.log_exposure(UNDER + 0.5))
        g_hi = float(self.crf.log_exposure(OVER - 0.5))
        return math.exp(g_lo - log_tk + shift), math.exp(g_hi - log_tk + shift)


def true_rates(
    truth: GroundTruth, exposure_us: float, gain: float, shift: float = 0.0, step: int = 1
) -> tuple[float, float]:
    """``(over, under)``: fractions of pixels whose noiseless digit would clip at this exposure if the
    light were ``shift`` ln units lower than it was (``shift = 0``: as it was). ``step`` subsamples a
    fixed grid (every ``step``-th pixel in each direction)."""
    lo, hi = truth.bounds(exposure_us, gain, shift)
    lb = truth.mean_irradiance if step == 1 else truth.mean_irradiance[::step, ::step]
    n = lb.size
    return float(np.count_nonzero(lb >= np.float32(hi))) / n, float(np.count_nonzero(lb < np.float32(lo))) / n


def true_valid_fraction(truth: GroundTruth, exposure_us: float, gain: float) -> float:
    """Fraction of pixels whose true exposure-averaged irradiance falls inside the recordable range:
    ``g(9.5) <= ln T + ln K + ln Lbar < g(249.5)`` — the pixels a noiseless camera records in 10..249 DN."""
    over, under = true_rates(truth, exposure_us, gain)
    return 1.0 - over - under
