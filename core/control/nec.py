"""Neuromorphic exposure control: the paper's Eq. 2-4 driven by the P-TEDI estimate.

With ``H = T K`` the exposure-gain product (µs), ``M(now)`` the metered log irradiance and
``g*`` the goal log exposure::

    H_opt = exp(g* - M(now))                     (Eq. 2)
    H_err = H_opt - H_i                          (Eq. 3, sign corrected: the paper's T_i - T_opt
    H_set = H_i + f_w(H_err) H_err                moves away from the target)
    K = max(1, H_set / T_max),  T = H_set / K    (Eq. 4), then clamped to the camera limits

``H_i`` is the product the camera applied to the last frame (Eq. 3's ``T_i``), so commands
issued at high rate between frames do not compound the partial step ``f_w``.

Metering (``metering=``): what ``M`` is a statistic of. Every mode is a statistic of the last
frame's per-pixel exposure-averaged log irradiance ``ln Lbar(x) = g(Z(x)) - ln T - ln K``
(Eq. 1), measured at the frame and carried between frames by P-TEDI's event-driven change:

* ``paper``: the paper's ``M = ln P(now)``, P-TEDI's own estimate, anchored on ``g(mean Z)``
  (Eq. 15): the log of the frame's *arithmetic* mean exposure, so a bright minority (sun in a
  shadowed scene) pulls the whole exposure down.
* ``median``: the censored median of ``ln Lbar``. Quantiles commute with the increasing ``g``,
  so it is ``g`` of the median digit (interpolated inside its bin from a 256-bin histogram);
  pixels clipped at the top (``Z >= valid_max``) are only known to lie at or above
  ``g(valid_max - 1/2)``, those at the bottom (``Z <= valid_min``) at or below
  ``g(valid_min + 1/2)``. When the median rank falls among clipped pixels the frame only bounds
  it (:func:`censored_quantiles`).
* ``percentile``: the median with highlight protection,
  ``M = min(max(q_50, q_p - (g(Z_hl) - g*)), q_50 + (g* - g(Z_floor)))``: the exposure that puts
  the median at the goal, shortened if that would put the ``p``-quantile above the digit
  ``Z_hl``, but never so far that the median falls below ``Z_floor``.
* ``zones``: the weighted median, over a grid of P-TEDI zones (each its own "large pixel" with its
  own event count), of the zones' censored medians; weights fall off from the image centre
  (Gaussian, σ = half the half-size); each zone is propagated by its own events.

Propagation (exact for a global change of the light; to first order otherwise): for a frame
exposed over ``[s, e]`` P-TEDI gives ``ln E_p(s)`` (the exposure-mean irradiance relative to
``s``) and its own level ``ln P(s)`` after the frame. The statistic at ``s`` is
``M(s) = M(ln Lbar) - ln E_p(s)`` and its offset from P-TEDI is ``δ = M(s) - ln P(s)``; then

    M(now) = ln P(now) + δ = M(s) + [ln P(now) - ln P(s)] = M(s) + c^T D_p(s, now)

(Eq. 12: the event-measured change since ``s``). ``δ`` is re-measured at every frame where the
statistic is determined; where the frame only bounds it (a censored median), ``δ`` is raised
(lowered) just enough to respect the bound, else kept. ``paper`` is ``δ = 0``.

Goal (``goal_mode=``): ``paper`` is the log mid-point ``(g(valid_min) + g(valid_max)) / 2``
(≈ 72 DN); ``measured`` the digit chosen per metering mode by ``benchmarks/metering.py``
(:data:`MEASURED_GOAL_DN`). The tunable ``goal`` (DN) overrides either.

Escape rule at one-sided uncertainty (``escape=``): the prediction is only a *bound* when
(a) events were lost at the sensor's event-rate ceiling since the last determined frame — the
sensor-wide rate pinned at the bus maximum with one polarity dominant, so the true change in
that direction is at least the counted one — or (b) the last frame was saturated (more than
half clipped at one end: it proves the light lies beyond a bound, not where). In the direction
``d`` of the bound the truth is ``M_true = M + e`` with unknown ``e >= 0``. Aiming ``M`` at the goal
records the median pixel for ``e`` up to ``g(valid_max) - g*`` only; aiming it at the near edge
of the valid range, ``g(valid_min) + m`` (``d = +1``; ``g(valid_max) - m`` for ``d = -1``),
records it for every ``e`` in ``[0, W - m]``, ``W = g(valid_max) - g(valid_min)`` — the widest
one-sided interval a single exposure can cover. ``m`` is ``edge_margin`` (ln). The rule ends
at the first frame that determines the statistic with no ceiling-saturated batch since its
exposure started. A ceiling window that is a flickering light's swing (``flicker_rule``: the windows'
direction reverses within a frame interval, :mod:`necviz.core.control.flicker_watch`; with ``flicker_edges``
also a short burst at the ceiling that follows another, a lamp's edges) is not a loss and does not start
case (a). Case (a) needs the ceiling: ``bus_event_rate``, by default the source's own
(:class:`~necviz.drivers.source.CameraInfo` ``event_rate_max``: the simulator's configured
``dvs.max_event_rate``, 12 Mev/s for a DAVIS346 device or a recording from one), never a literal;
a source without a ceiling makes case (a) impossible.

The paper's controller and necviz's additions (each one switch, so the ladder from the paper to
the default can be measured; ``docs/method.md``): ``saturation_bound`` (P-TEDI re-anchors at the
bound a saturated frame proves, :mod:`necviz.core.ptedi`; off: the paper's skip rule alone),
``metering``, ``goal_mode``, ``escape``, ``bound_lag`` and ``flicker_rule`` (with ``flicker_edges``); ``compensation`` (the
profile's TEDI terms ``a±, b±``; off: zeroed, the thresholds kept) is the paper's own (Eq. 6) and on in
``nec-paper``. ``saturation_bound=False, metering="paper", goal_mode="paper", escape=False,
bound_lag=False, flicker_rule=False, flicker_edges=False`` is the paper's controller wherever the paper is
specific (registered as ``nec-paper``). Where it is silent necviz chooses, in ``nec-paper`` as in every
rung of the ladder: ``f_w``'s smoothstep and its dead band (:func:`error_weight`; the paper's
Fig. 8e gives no form), ``min_command_change`` (a command must differ from the last by 1 %), the
stale-command re-send inside the dead band (:meth:`NECController.command_for`), the skip rule's
threshold of 50 % valid pixels (``PeripheralOptions.min_valid_fraction``) and a first anchor on
whatever frame comes first.
:class:`NECFramesController` (``nec-frames``) is NEC with every event kept from its estimator.

Defaults, chosen by ``benchmarks/metering.py`` over every preset scenario x 10 seeds and checked
on held-out scenes (README, "Metering, goal and the escape rule"): ``metering="median"``,
``goal_mode="measured"`` (100 DN for the median), ``escape=True`` with ``edge_margin=0.4``,
``saturation_bound=True``, ``compensation=True``, ``bound_lag=True`` (``ceiling_rate=False``).

Events that lag (``bound_lag``). A pixel reports a change only as fast as its photoreceptor
follows it, and in the dark that takes tens of ms (the DVS model's bandwidth falls with the
light, as a DAVIS346's does), so after a big step the events keep arriving well after the frame
that already saw the new level. When a saturated frame moves P-TEDI's anchor to its bound, the gap
it closes (bound minus the event-propagated level at ``s``) is then change the events have yet to
report; counting those events again after the bound double-counts it (a 40 dB step down was
over-counted by 0.7 ln and left the next frame 80 % over-exposed). So the events that follow in the
gap's direction count only beyond the gap. When a window at the bus ceiling lies between the
previous anchor and the frame, the gap is events lost for good and nothing is absorbed.

Events at the bus ceiling (``ceiling_rate``, an experiment, off). At the ceiling the bus delivers a
fixed rate whatever the light does, so the count measures the change's duration, not its size. A
saturated frame that moves the anchor to its bound after windows at the ceiling gives the gain
``k = (counted + missed) / counted`` of those windows; later windows at the ceiling (same polarity)
are credited ``k - 1`` times their count, at most ``(W - 2 m) / 2`` (``W = g(valid_max) -
g(valid_min)``) so that the escape rule's exposure still records the level the count and the frame
prove. It rests on the simulator's uniform thinning at the ceiling; docs/method.md has the numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import ClassVar

import numba as nb
import numpy as np

from necviz.core.checks import check_number
from necviz.core.control.controller import CameraLimits, Controller, ControllerOptions, ExposureCommand, Tunable
from necviz.core.control.flicker_watch import FlickerWatch
from necviz.core.control.nec_bus import BusWatch
from necviz.core.control.nec_lag import LagTracker
from necviz.core.crf import US_PER_S
from necviz.core.errors import ParameterError
from necviz.core.frames import Frame
from necviz.core.ptedi import FrameEstimate, PeripheralEstimator
from necviz.core.ptedi_kernels import digit_histograms

#: metering statistics (module docstring)
METERING = ("paper", "median", "percentile", "zones")
#: goal modes: the paper's log mid-point, or the digit measured for the metering mode
GOAL_MODES = ("paper", "measured")
#: goal digit per metering mode for ``goal_mode="measured"`` (``None``: the log mid-point), chosen by
#: ``benchmarks/metering.py`` (README, "Metering and goal")
MEASURED_GOAL_DN: dict[str, float | None] = {"paper": None, "median": 100.0, "percentile": None, "zones": None}
#: default zone grid of ``metering="zones"`` (rows, columns)
ZONE_GRID = (4, 4)


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


def censored_quantiles(hist, q: float, g, valid_min: int, valid_max: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``q``-quantile of ``g(Z)`` per row of a digit histogram, with clipped pixels censored.

    ``hist``: ``(..., 256)`` pixel counts per digit. Pixels at or above ``valid_max`` are only known
    to lie at or above the continuous digit ``valid_max - 1/2``, those at or below ``valid_min`` at
    or below ``valid_min + 1/2``. The quantile of rank ``r = q N`` is interpolated inside its bin
    (a digit ``z`` stands for ``[z - 1/2, z + 1/2)``, pixels spread evenly) and mapped through
    ``g`` (quantiles commute with an increasing ``g``).

    Returns ``(value, side)``: ``side`` 0 where the quantile is determined, +1 where the rank falls
    among top-clipped pixels (``value = g(valid_max - 1/2)`` is then a lower bound), -1 among
    bottom-clipped ones (``value = g(valid_min + 1/2)``, an upper bound), 2 where nothing is known
    (no pixels). O(256) per row.
    """
    h = np.asarray(hist)
    if h.shape[-1] != 256:
        raise ParameterError(f"censored_quantiles needs 256-bin histograms, got shape {h.shape}")
    if not 0.0 < q < 1.0:
        raise ParameterError(f"quantile must lie in (0, 1), got {q!r}")
    h = np.ascontiguousarray(h.reshape(-1, 256), dtype=np.float64)
    pos = np.empty(h.shape[0])
    side = np.empty(h.shape[0], np.int8)
    _quantile_positions(h, float(q), int(valid_min), int(valid_max), pos, side)
    return np.interp(pos, _DIGITS, np.asarray(g, dtype=np.float64)), side


_DIGITS = np.arange(256.0)


@nb.njit(cache=True, nogil=True)
def _quantile_positions(h, q, valid_min, valid_max, pos, side):
    """:func:`censored_quantiles` before ``g``: per row of ``h`` (float64 counts, 256 bins) the
    continuous digit of rank ``r = q N`` and its censoring side; NaN and side 2 for an empty row.
    The first bin whose cumulative count reaches ``r`` is ``b``; inside it, pixels are spread
    evenly: ``b - 1/2 + (r - cum[b-1]) / h[b]``. O(256) per row."""
    for i in range(h.shape[0]):
        cum = np.empty(256)
        acc = 0.0
        for d in range(256):
            acc += h[i, d]
            cum[d] = acc
        n = cum[255]
        if n <= 0.0:
            pos[i] = np.nan
            side[i] = 2
            continue
        r = q * n
        below = r <= cum[valid_min]  # Z <= valid_min
        above = r >= cum[valid_max - 1]  # Z < valid_max
        if below and above:
            side[i] = 2
        elif above:
            side[i] = 1
        elif below:
            side[i] = -1
        else:
            side[i] = 0
        if below:
            pos[i] = valid_min + 0.5
        elif above:
            pos[i] = valid_max - 0.5
        else:
            b = 0
            while b < 255 and cum[b] < r:
                b += 1
            prev = cum[b - 1] if b > 0 else 0.0
            pos[i] = (b - 0.5) + (r - prev) / h[i, b]


def update_offsets(old: np.ndarray, cand: np.ndarray, side: np.ndarray) -> np.ndarray:
    """The metering offsets ``δ`` per zone after a frame (module docstring): where the frame's statistic
    is determined (``side`` 0) or ``δ`` was never measured, the candidate ``cand``; where the statistic
    is censored, ``δ`` only rises (+1, a lower bound) or falls (-1, an upper bound) to it; where nothing
    is known (2), or the candidate is not finite, ``δ`` is kept. O(zones)."""
    with np.errstate(invalid="ignore"):
        new = np.where(
            ~np.isfinite(old) | (side == 0),
            cand,
            np.where(side == 1, np.fmax(old, cand), np.where(side == -1, np.fmin(old, cand), old)),
        )
    return np.where(np.isfinite(cand), new, old)


def update_offset(old: float, cand: float, side: int) -> float:
    """:func:`update_offsets` for one zone, on Python floats (bit for bit the same value; the
    whole-sensor metering runs it every frame without ten one-element array round trips)."""
    if not math.isfinite(cand):
        return old
    if not math.isfinite(old) or side == 0:
        return cand
    if side == 1:
        return max(old, cand)
    if side == -1:
        return min(old, cand)
    return old


def weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The weighted median of the finite ``values`` (lower median at an exact half); NaN if none."""
    ok = np.isfinite(values)
    if not ok.any():
        return math.nan
    v, w = values[ok], weights[ok]
    order = np.argsort(v)
    cw = np.cumsum(w[order])
    return float(v[order][np.searchsorted(cw, 0.5 * cw[-1])])


def zone_weights(estimator: PeripheralEstimator, sigma: float = 0.5) -> np.ndarray:
    """Centre weights of the estimator's zones: ``exp(-r^2 / 2σ^2)``, ``r`` the distance of the zone's
    centroid from the image centre in units of the half width/height."""
    zmap = estimator.zmap
    h, w = zmap.shape
    yy, xx = np.mgrid[0:h, 0:w]
    zf = zmap.ravel()
    sel = zf >= 0
    k = estimator.num_zones
    n = np.bincount(zf[sel], minlength=k).astype(np.float64)
    cx = np.bincount(zf[sel], weights=xx.ravel()[sel] + 0.5, minlength=k) / n
    cy = np.bincount(zf[sel], weights=yy.ravel()[sel] + 0.5, minlength=k) / n
    r2 = ((cx - w / 2) / (w / 2)) ** 2 + ((cy - h / 2) / (h / 2)) ** 2
    return np.exp(-r2 / (2 * sigma * sigma))


@dataclass(frozen=True)
class NECOptions(ControllerOptions):
    """NEC's settings (validated here, once; :class:`NECController` adds the rules that need its camera response).

    Parameters
    ----------
    dead_band, full_band : float
        ``f_w`` corners on the relative error ``|ln(H_opt/H_i)|`` (defaults: no change below ~10 %,
        a full jump from ~65 % on); ``dead_band < full_band``.
    goal : float, optional
        Goal intensity ``I_opt`` in DN (overrides ``goal_mode``); ``None``: from ``goal_mode``.
    min_command_change : float
        A new command is only issued if it differs from the last one by more than this relative
        amount (avoids re-sending the same setting every batch).
    metering : str
        ``"paper"``, ``"median"``, ``"percentile"`` or ``"zones"`` (module docstring).
    goal_mode : str
        ``"paper"`` (log mid-point) or ``"measured"`` (:data:`MEASURED_GOAL_DN`).
    percentile, highlight, floor : float
        ``p``, ``Z_hl`` and ``Z_floor`` of ``metering="percentile"``.
    escape : bool
        Apply the escape rule at one-sided uncertainty (module docstring).
    edge_margin : float
        ``m`` of the escape rule (ln): how far inside the valid range's edge it aims.
    bus_event_rate : float, optional
        The sensor's event-rate ceiling (events/s) for the escape rule's case (a); ``None`` (the
        default): the source's own (``event_rate_max`` of its
        :class:`~necviz.drivers.source.CameraInfo`, given to the controller when it is built), and
        no ceiling (case (a) never holds) when the source knows none.
    saturation_bound : bool
        P-TEDI re-anchors at the bound a saturated frame proves (necviz's addition); ``False``:
        the paper's rule alone (skip the frame, keep propagating with events).
    compensation : bool
        Use the camera profile's TEDI compensation ``a±, b±``; ``False`` zeroes them (thresholds kept).
    ceiling_rate : bool
        While the event bus is at its ceiling, credit the events with the rate of change a saturated
        frame proved (module docstring, "Events at the bus ceiling"); needs ``escape`` (its bus watch).
    bound_lag : bool
        When a saturated frame moves P-TEDI's anchor to its bound and no event window since the previous
        anchor was at the bus ceiling, count the events that follow in the bound's direction only beyond
        the gap the bound closed: they are the photoreceptor's lag catching up with a change the frame
        already saw (module docstring, "Events that lag").
    flicker_rule : bool
        A window at the bus ceiling that is a flickering light's swing (the ceiling windows' direction
        reverses within a frame interval, :class:`~necviz.core.control.flicker_watch.FlickerWatch`) is not
        a one-sided loss: it does not start the escape rule's case (a).
    flicker_edges : bool
        With ``flicker_rule``: a short burst of ceiling windows (at most 1.5 ms) that follows another short
        burst within two frame intervals is a lamp's edge, a flicker's swing, even when the windows do not
        alternate (a lamp that reaches the ceiling on one swing only, or on some periods only, or a switched
        light's ramp riding on a lamp's edges); :mod:`~necviz.core.control.flicker_watch`, "Edges".
    zone_grid : tuple of int, optional
        ``(columns, rows)`` of the P-TEDI zones :func:`~necviz.core.control.make_controller` builds
        (default: :data:`ZONE_GRID` for ``metering="zones"``, else the whole sensor).

    ``saturation_bound=False, metering="paper", goal_mode="paper", escape=False, bound_lag=False,
    flicker_rule=False, flicker_edges=False`` (compensation on: the paper's Eq. 6) is the paper's controller wherever the
    paper is specific (``nec-paper``; the necviz choices it keeps are named in the module docstring).
    """

    TUNABLE: ClassVar[tuple[Tunable, ...]] = (
        Tunable(
            "dead_band", "ln", "f_w is 0 while |ln(H_opt/H_i)| is at most this (no flicker from tiny corrections)", 0.0
        ),
        Tunable(
            "full_band",
            "ln",
            "f_w is 1 from this |ln(H_opt/H_i)| on (one-shot jumps on big changes)",
            0.0,
            lo_open=True,
        ),
        # its range depends on the camera response and the metering: checked in NECController._check_goal alone
        Tunable("goal", "DN", "goal intensity I_opt: the digit the metered statistic aims at"),
        Tunable("min_command_change", "ln", "a new command must differ from the last by more than this", 0.0),
        Tunable(
            "edge_margin",
            "ln",
            "escape rule: aim this far inside the valid range's edge when the prediction is only a one-sided bound",
            0.0,
        ),
        Tunable("percentile", "fraction", "percentile metering: the highlight quantile p", 0.5, 1.0, True, True),
        Tunable(
            "highlight",
            "DN",
            "percentile metering: the p-quantile is kept at or below this digit",
            0.0,
            255.0,
            True,
            True,
        ),
        Tunable(
            "floor",
            "DN",
            "percentile metering: highlight protection never puts the median below this digit",
            0.0,
            255.0,
            True,
            True,
        ),
    )

    dead_band: float = 0.1
    full_band: float = 0.5
    goal: float | None = None
    min_command_change: float = 0.01
    metering: str = "median"
    goal_mode: str = "measured"
    percentile: float = 0.95
    highlight: float = 235.0
    floor: float = 30.0
    escape: bool = True
    edge_margin: float = 0.4
    bus_event_rate: float | None = None
    zone_grid: tuple[int, int] | None = None
    saturation_bound: bool = True
    compensation: bool = True
    ceiling_rate: bool = False
    bound_lag: bool = True
    flicker_rule: bool = True
    flicker_edges: bool = True

    def check(self) -> None:
        if self.full_band <= self.dead_band:
            raise ParameterError(f"need dead_band < full_band, got {self.dead_band:g} and {self.full_band:g}")
        if self.metering not in METERING:
            raise ParameterError(f"metering must be one of {', '.join(METERING)}, got {self.metering!r}")
        if self.goal_mode not in GOAL_MODES:
            raise ParameterError(f"goal_mode must be one of {', '.join(GOAL_MODES)}, got {self.goal_mode!r}")
        for name in (
            "escape",
            "saturation_bound",
            "compensation",
            "ceiling_rate",
            "bound_lag",
            "flicker_rule",
            "flicker_edges",
        ):
            if not isinstance(getattr(self, name), bool):
                raise ParameterError(f"{name} must be true or false, got {getattr(self, name)!r}")
        if self.bus_event_rate is not None:
            object.__setattr__(
                self, "bus_event_rate", check_number("bus_event_rate", self.bus_event_rate, 0.0, lo_open=True)
            )
        if self.zone_grid is not None:
            g = self.zone_grid
            if not (
                isinstance(g, (list, tuple))
                and len(g) == 2
                and all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in g)
            ):
                raise ParameterError(f"zone_grid must be [columns, rows] of positive integers, got {g!r}")
            object.__setattr__(self, "zone_grid", tuple(g))


class NECController(Controller):
    """NEC: P-TEDI irradiance prediction -> exposure and gain, on every event batch and frame.

    Parameters
    ----------
    estimator : PeripheralEstimator
        The P-TEDI estimator (owned: the controller feeds it). ``metering="zones"`` needs one with
        several zones (a grid, see :func:`necviz.core.control.make_controller`).
    limits : CameraLimits
        Camera exposure/gain limits.
    exposure_us, gain : float
        The initial setting.
    options : NECOptions, optional
        The settings (default: ``NECOptions()``, the measured defaults).
    event_rate_max : float, optional
        The source's event bus ceiling (events/s; :class:`~necviz.drivers.source.CameraInfo`), used by
        the escape rule unless ``options.bus_event_rate`` names one; ``None``: the source knows none.

    Raises
    ------
    ParameterError
        An estimator that is not a :class:`PeripheralEstimator`, options that do not fit its
        camera response (a goal outside the valid range), or zones metering on a one-zone estimator.

    Notes
    -----
    The controller owns its estimator and sets the estimator's own switches from the options:
    ``saturation_bound``, and with ``compensation=False`` the thresholds without ``a±, b±``.
    """

    name = "nec"
    OPTIONS = NECOptions
    uses_events = True
    options: NECOptions  # set by Controller.__init__ (always an instance of OPTIONS)
    estimator: PeripheralEstimator  # NEC always owns one

    def __init__(
        self,
        estimator: PeripheralEstimator,
        limits: CameraLimits,
        exposure_us: float = 5_000.0,
        gain: float = 1.0,
        options: NECOptions | None = None,
        event_rate_max: float | None = None,
    ):
        if not isinstance(estimator, PeripheralEstimator):
            raise ParameterError("NECController needs a PeripheralEstimator")
        if event_rate_max is not None:
            event_rate_max = check_number("event_rate_max", event_rate_max, 0.0, lo_open=True)
        self.estimator = estimator
        self.event_rate_max = event_rate_max
        self.flicker = FlickerWatch()  # which ceiling windows are a flicker's swings (flicker_rule, flicker_edges)
        super().__init__(limits, exposure_us, gain, options)
        self.last_log_irradiance = math.nan  # P-TEDI's ln P at the last command decision
        self.last_metered = math.nan  # the metered statistic M at the last command decision
        self.last_frame_estimate: FrameEstimate | None = None
        # metering state: offsets delta per zone (NaN until a frame measured one)
        self._offset = np.full(estimator.num_zones, np.nan)
        self._offset0 = math.nan  # whole-sensor modes: the scalar used on the hot path
        self._weights = zone_weights(estimator) if self.options.metering == "zones" else None
        # escape state
        self.escape_direction = 0  # +1 / -1 while the prediction is a lower / upper bound, else 0
        self._frame_dir = 0  # the last frame: +1 more than half over-exposed, -1 under, 0 neither
        self._determined_s = np.iinfo(np.int64).min  # exposure start of the last frame that determined M
        self.bus = BusWatch()  # windows of events at the bus ceiling (case (a); nec_bus)
        # rate at the ceiling: counted change of each ceiling-saturated window since the anchor, the gain a
        # saturated frame calibrated, and the change credited beyond the count (ln; added to M)
        self._sat_log: list[tuple[int, float]] = []
        self._gain = 1.0
        self._gain_dir = 0
        self.ceiling_credit = 0.0
        self.lag = LagTracker()  # lag after a saturation bound (bound_lag; nec_lag)

    # -- settings -------------------------------------------------------------------------------
    def _goal_log_exposure(self, options: NECOptions) -> float:
        """``g*`` for these options: the goal digit's log exposure, else the goal mode's."""
        crf = self.estimator.crf
        dn = options.goal
        if dn is None and options.goal_mode == "measured":
            dn = MEASURED_GOAL_DN.get(options.metering)
        return crf.goal_log_exposure if dn is None else float(crf.log_exposure(float(dn)))

    def _check_options(self, options: ControllerOptions) -> None:
        assert isinstance(options, NECOptions)  # Controller checks it; replace() keeps the class
        crf = self.estimator.crf
        if options.metering == "zones" and self.estimator.num_zones < 2:
            raise ParameterError(
                "metering='zones' needs a P-TEDI estimator with a zone grid (make_controller builds one)"
            )
        if self.options is not None and options.metering != self.options.metering:
            raise ParameterError("the metering mode is chosen when NEC is built; it cannot change while running")
        if options.metering == "percentile":  # percentile, highlight and floor are percentile metering's alone
            for label, v in (("highlight", options.highlight), ("floor", options.floor)):
                if not crf.valid_min < v < crf.valid_max:
                    raise ParameterError(
                        f"percentile metering needs {crf.valid_min} < {label} < {crf.valid_max} DN, got {v:g}"
                    )
        self._check_goal(options)

    def _check_goal(self, options: NECOptions) -> None:
        """NEC's goal range, checked here and nowhere else: the goal digit (``goal``, else the goal mode's)
        lies strictly inside the camera response's valid range and, with percentile metering, strictly
        between ``floor`` and ``highlight``."""
        crf = self.estimator.crf
        lo, hi = float(crf.valid_min), float(crf.valid_max)
        where = f"the valid range {crf.valid_min}..{crf.valid_max} DN"
        if options.metering == "percentile":
            lo, hi = max(lo, options.floor), min(hi, options.highlight)
            where += (
                f" and, for percentile metering, floor < goal < highlight ({options.floor:g}..{options.highlight:g} DN)"
            )
        goal = options.goal if options.goal is not None else float(crf.intensity(self._goal_log_exposure(options)))
        if not lo < goal < hi:
            raise ParameterError(f"goal = {goal:g} is out of range: it must lie inside {where}")

    def _apply_options(self, options: ControllerOptions) -> None:
        assert isinstance(options, NECOptions)  # Controller checks it; replace() keeps the class
        super()._apply_options(options)
        self.goal_log_exposure = self._goal_log_exposure(options)
        rate = options.bus_event_rate
        self._bus_rate = self.event_rate_max if rate is None else rate
        est = self.estimator
        # what the hot path (every event batch) asks of the options, worked out once per setting
        self._watching = options.escape and self._bus_rate is not None
        self._paper_law = options.metering == "paper" and not options.escape
        self._dead_band, self._full_band = options.dead_band, options.full_band
        self._min_change = options.min_command_change
        crf = est.crf  # fixed when the estimator is built
        self._aim_up = min(self.goal_log_exposure, float(crf.g[crf.valid_min]) + options.edge_margin)
        self._aim_down = max(self.goal_log_exposure, float(crf.g[crf.valid_max]) - options.edge_margin)
        est.saturation_bound = options.saturation_bound
        self.flicker.edges = options.flicker_edges
        p = est.params
        if not options.compensation and (p.a_on or p.b_on or p.a_off or p.b_off):
            est.set_params(replace(p, a_on=0.0, b_on=0.0, a_off=0.0, b_off=0.0))

    @property
    def bus_event_rate(self) -> float | None:
        """The event bus ceiling the escape rule uses: ``options.bus_event_rate``, else the source's."""
        return self._bus_rate

    def _get_param(self, name: str) -> float:
        if name == "goal":
            return float(self.estimator.crf.intensity(self.goal_log_exposure))
        return getattr(self.options, name)

    # -- the control law ----------------------------------------------------------------------
    def command_for(
        self, log_irradiance: float, t_us: int, goal_log_exposure: float | None = None
    ) -> ExposureCommand | None:
        """Eq. 2-4 for a metered log irradiance ``M``; ``None`` inside the dead band.

        ``goal_log_exposure`` replaces ``g*`` (the escape rule's aim). Inside the dead band of the
        applied setting ``H_i`` nothing needs to change, but the camera applies the newest command
        it received at its next exposure start: a command issued for a transient that has passed
        would still take effect. So when the outstanding command (:attr:`last_command`) differs
        from ``H_i`` by more than ``min_command_change`` and lies outside the dead band of
        ``H_opt`` itself, the applied setting is commanded again (which cancels the stale one);
        otherwise ``None``.
        """
        if not math.isfinite(log_irradiance):
            return None
        goal = self.goal_log_exposure if goal_log_exposure is None else goal_log_exposure
        h_i = self.exposure_us * self.gain
        h_opt = math.exp(goal - log_irradiance) * US_PER_S
        dead_band = self._dead_band
        w = error_weight(math.log(h_opt / h_i), dead_band, self._full_band)
        if w == 0.0:
            last = self.last_command
            if last is None:
                return None
            h_last = last.exposure_us * last.gain
            if abs(math.log(h_last / h_i)) <= self._min_change or abs(math.log(h_opt / h_last)) <= dead_band:
                return None  # nothing outstanding, or what is outstanding is as good as H_i
            return ExposureCommand(self.exposure_us, self.gain, int(t_us), self.name)
        h_set = h_i + w * (h_opt - h_i)
        lim = self.limits
        gain = max(1.0, h_set / lim.exposure_max_us)
        exposure = h_set / gain
        exposure, gain = lim.clamp(exposure, gain)  # a capped gain leaves exposure at T_max (under-exposed)
        last = self.last_command
        if last is not None and abs(math.log(last.exposure_us * last.gain / (exposure * gain))) < self._min_change:
            return None
        return ExposureCommand(exposure, gain, int(t_us), self.name)

    # -- metering -----------------------------------------------------------------------------
    def metered(self, t_us: int | None = None) -> float:
        """``M(t)``: the metered log irradiance (module docstring) from P-TEDI's state now."""
        est = self.estimator
        frame_level = self._flicker_level(t_us)
        if frame_level is not None:  # a flickering light: the last frame's exposure-averaged level
            if self.options.metering == "zones":
                offsets = np.where(np.isfinite(self._offset), self._offset, 0.0)
                assert self._weights is not None
                return weighted_median(frame_level + offsets, self._weights)
            lp = float(frame_level[0])
            off = self._offset0
            return lp if self.options.metering == "paper" or off != off else lp + off
        if self.options.metering == "zones":
            z = est.predict_zones(t_us)
            ok = np.isfinite(z)
            if ok.any():
                self.last_log_irradiance = float(np.dot(z[ok], est.sizes[ok]) / est.sizes[ok].sum())
            offsets = np.where(np.isfinite(self._offset), self._offset, 0.0)
            lp = self.last_log_irradiance
            assert self._weights is not None  # built for zones metering, which cannot change while running
            return weighted_median(z + offsets, self._weights) + self._credit() - self._absorbed(lp)
        lp = est.predict(t_us)
        self.last_log_irradiance = lp
        lp = lp + self._credit() - self._absorbed(lp)
        if self.options.metering == "paper":
            return lp
        off = self._offset0
        return lp + off if off == off else lp  # before the first measured offset: P-TEDI's level

    def _flicker_level(self, t_us: int | None) -> np.ndarray | None:
        """P-TEDI's exposure-averaged level over the last frame (per zone) while the light flickers
        (``flicker_rule``, :meth:`FlickerWatch.active`), else ``None``."""
        fe = self.last_frame_estimate
        if not self.options.flicker_rule or fe is None:
            return None
        if not self.flicker.active(self.now_us if t_us is None else t_us):
            return None
        start = fe.log_start if fe.log_start is not None else fe.log_anchor
        return start + fe.log_e

    def frame_statistic(self, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
        """The metering statistic of a frame's ``g(Z)`` per zone (log exposure, before ``- ln T K``)
        and its censoring side (0 determined, +1 lower bound, -1 upper bound, 2 unknown); see
        :func:`censored_quantiles`. Not used by ``paper``. One 256-bin histogram per zone."""
        est, crf = self.estimator, self.estimator.crf
        z = frame.image.ravel()
        if self.options.metering == "zones":
            hist = digit_histograms(z, est._zone_flat, est.num_zones)
        else:
            hist = est.digit_histogram_of(frame)  # shared with P-TEDI's anchor (one pass per frame)
        med, s50 = censored_quantiles(hist, 0.5, crf.g, crf.valid_min, crf.valid_max)
        if self.options.metering != "percentile":
            return med, s50
        qp, sp = censored_quantiles(hist, self.options.percentile, crf.g, crf.valid_min, crf.valid_max)
        goal = self.goal_log_exposure
        cap = med + (goal - crf.log_exposure(self.options.floor))
        m = np.minimum(np.maximum(med, qp - (crf.log_exposure(self.options.highlight) - goal)), cap)
        side = np.where(
            s50 == 2,
            2,
            np.where(s50 == 1, 1, np.where(s50 == -1, np.where(sp == 1, 2, -1), np.where((sp == 1) & (m < cap), 1, 0))),
        )
        return m, side.astype(np.int8)

    def _update_offsets(self, frame: Frame, fe: FrameEstimate) -> bool:
        """Re-measure ``δ`` per zone from the frame (module docstring); True if the statistic was
        determined (over the zones' weights for ``zones``)."""
        stat, side = self.frame_statistic(frame)
        log_tk = math.log(frame.exposure_us / US_PER_S) + math.log(frame.gain)
        start = fe.log_start if fe.log_start is not None else fe.log_anchor
        if self._weights is None and stat.size == 1:  # one zone (every mode but zones): the rule on floats
            side0 = side.item(0)
            self._offset0 = update_offset(
                self._offset0, stat.item(0) - log_tk - fe.log_e.item(0) - start.item(0), side0
            )
            self._offset = np.array([self._offset0])
            return side0 == 0
        new = update_offsets(self._offset, stat - log_tk - fe.log_e - start, side)
        self._offset = new
        self._offset0 = float(new[0])
        if self._weights is None:
            return bool(side[0] == 0)
        return float(self._weights[side == 0].sum()) >= 0.5 * float(self._weights.sum())

    # -- the escape rule ------------------------------------------------------------------------
    @property
    def saturated_windows(self) -> int:
        """Windows of events found at the bus ceiling so far (diagnostics)."""
        return self.bus.saturated_windows

    @property
    def bound_owed(self) -> float:
        """The gap a saturation bound closed that later events only catch up with (signed ln; ``bound_lag``)."""
        return self.lag.owed

    def _watch_bus(self, n: int, t_last: int) -> None:
        """Case (a) of the escape rule: a window at the bus ceiling (:class:`BusWatch`), credited when
        ``ceiling_rate`` is on."""
        rate = self._bus_rate
        assert rate is not None  # on_events watches the bus only when it has a rate
        flicker = self.flicker if self.options.flicker_rule else None
        hit = self.bus.watch(n, t_last, self.estimator.event_totals(), rate, flicker)
        if hit is not None and self.options.ceiling_rate:
            self._ceiling_window(t_last, *hit)

    def _ceiling_window(self, t_end: int, n_on: int, n_off: int) -> None:
        """A window at the bus ceiling: remember its counted change; credit the calibrated extra."""
        est = self.estimator
        p = est.params
        counted = (p.c_on * n_on - p.c_off * n_off) / float(est.sizes.sum())
        self._sat_log.append((int(t_end), counted))
        if len(self._sat_log) > 4096:  # hours at the ceiling without a usable frame: keep the newest
            del self._sat_log[:2048]
        if self._gain > 1.0 and counted * self._gain_dir > 0:
            self.ceiling_credit += (self._gain - 1.0) * counted

    def _absorbed(self, lp: float) -> float:
        """The part of P-TEDI's change since the bound that only catches up with it (``bound_lag``)."""
        return self.lag.absorbed(lp)

    def _track_lag(self, fe: FrameEstimate) -> None:
        """After a frame: the lag tracker's gap (``bound_lag``; module docstring). A window at the bus ceiling
        counts only while the bus is watched."""
        watched = self._bus_rate is not None and self.options.escape
        self.lag.after_frame(fe, self.estimator.sizes, self.bus.saturated_t if watched else None)

    def _credit(self) -> float:
        """The change credited beyond the count, at most half the slack of the valid range
        (``(W - 2 m) / 2``): the exposure the escape rule then aims at still records the level the
        count and the frame prove if the credit was too much by up to that (module docstring)."""
        c = self.ceiling_credit
        if c == 0.0:
            return 0.0
        crf = self.estimator.crf
        cap = 0.5 * max(0.0, float(crf.g[crf.valid_max] - crf.g[crf.valid_min]) - 2.0 * self.options.edge_margin)
        return max(-cap, min(cap, c))

    def _calibrate_ceiling(self, fe: FrameEstimate) -> None:
        """After a frame: re-calibrate the rate at the ceiling from a frame that moved P-TEDI's anchor to
        a saturation bound (the frame proves the change the events missed), or reset it on a frame that
        anchored P-TEDI normally (module docstring)."""
        s = int(fe.exposure_start_us)
        sizes = self.estimator.sizes.astype(np.float64)
        bounded, log_start, predicted = fe.bounded, fe.log_start, fe.predicted_start
        if bounded is None or not bool(bounded.any()) or predicted is None:
            if bool(fe.anchored.any()):  # a new anchor: the count is exact again from s on
                self._sat_log = [w for w in self._sat_log if w[0] > s]
                self._gain, self._gain_dir, self.ceiling_credit = 1.0, 0, 0.0
            return
        assert log_start is not None  # PeripheralEstimator.add_frame sets it on every frame
        with np.errstate(invalid="ignore"):
            miss_zones = np.where(bounded, log_start - predicted, 0.0)
        miss = float(np.nansum(miss_zones * sizes) / sizes.sum())
        d = 1 if miss > 0 else -1
        before = sum(c for t, c in self._sat_log if t <= s and c * d > 0)
        after = sum(c for t, c in self._sat_log if t > s and c * d > 0)
        self._sat_log = [w for w in self._sat_log if w[0] > s]
        if before * d <= 0:  # no window at the ceiling before the frame: nothing to calibrate with
            self._gain, self._gain_dir, self.ceiling_credit = 1.0, 0, 0.0
            return
        self._gain = (before + miss) / before
        self._gain_dir = d
        self.ceiling_credit = (self._gain - 1.0) * after  # the windows since s, counted from the new anchor

    def _escape_direction(self) -> int:
        """+1 / -1 while the metered level is only a lower / upper bound, else 0 (module docstring)."""
        d = self._frame_dir
        if self.bus.saturated_t >= self._determined_s:
            if d == 0:
                d = self.bus.saturated_dir
            elif d != self.bus.saturated_dir:
                d = 0  # the frame bounds it one way, lost events the other: nothing one-sided is known
        return d

    def _aim(self) -> float | None:
        """The goal to aim at now: ``None`` (``g*``) unless the escape rule applies."""
        if not self.options.escape:
            return None
        d = self._escape_direction()
        self.escape_direction = d
        if d == 0:
            return None
        return self._aim_up if d > 0 else self._aim_down  # worked out in _apply_options

    # -- packets ------------------------------------------------------------------------------
    def _command_now(self) -> ExposureCommand | None:
        if not self.estimator.ready:
            return None
        t = max(self.now_us, self.estimator.last_event_us)
        m = self.metered(t)
        self.last_metered = m
        return self.command_for(m, t, self._aim())

    def on_events(self, events: np.ndarray) -> ExposureCommand | None:
        est = self.estimator  # the hot path (every event batch): kept short
        est.update(events)
        t = est.last_event_us
        if t > self.now_us:
            self.now_us = t
        if self._watching and events.size:
            self._watch_bus(events.size, t)
        if not est.ready:
            return None
        t = self.now_us
        if self._paper_law:  # the paper's controller, as it always was
            self.last_log_irradiance = lp = est.predict(t)
            return self.command_for(lp, t)
        if self._weights is not None:  # zones metering: the general path
            return self._command_now()
        # whole-sensor metering: _command_now's steps (t >= est.last_event_us here) without its calls
        m = self._metered_whole(t)
        self.last_metered = m
        return self.command_for(m, t, self._aim())

    def _metered_whole(self, t: int) -> float:
        """:meth:`metered` for every mode but ``zones`` (``paper``, ``median``, ``percentile``): the same
        operations in the same order (bit-identical ``M``), but the credit and the lag's absorbed part are
        asked for only when they can be non-zero, and without :meth:`metered`'s mode dispatch."""
        if self.options.flicker_rule and self.last_frame_estimate is not None and self.flicker.active(t):
            return self.metered(t)  # a flickering light: the last frame's level
        lp = self.estimator.predict(t)
        self.last_log_irradiance = lp
        credit = 0.0 if self.ceiling_credit == 0.0 else self._credit()
        absorbed = 0.0 if self.lag.owed == 0.0 else self._absorbed(lp)
        lp = lp + credit - absorbed
        if self.options.metering == "paper":
            return lp
        off = self._offset0
        return lp + off if off == off else lp  # before the first measured offset: P-TEDI's level

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
        fe = self.estimator.add_frame(frame)
        self.last_frame_estimate = fe
        if self.options.ceiling_rate and self.options.escape:
            self._calibrate_ceiling(fe)
        if self.options.bound_lag:
            self._track_lag(fe)
        determined = bool(fe.anchored.any())
        if self.options.metering != "paper":
            determined = self._update_offsets(frame, fe)
        if self.options.escape:
            valid = float(np.dot(fe.valid_fraction, self.estimator.sizes)) / float(self.estimator.sizes.sum())
            over = (
                float(np.dot(fe.over_fraction, self.estimator.sizes)) / float(self.estimator.sizes.sum())
                if fe.over_fraction is not None
                else 0.0
            )
            under = 1.0 - valid - over
            self._frame_dir = 1 if over > 0.5 else (-1 if under > 0.5 else 0)
            if determined and self._frame_dir == 0:
                self._determined_s = int(frame.exposure_start_us)
        return self._command_now()


class NECFramesController(NECController):
    """``nec-frames``: NEC with no event reaching its estimator — a frame-based auto-exposure.

    The same metering, goal, control law (Eq. 2-4: a one-step jump through the camera response
    when the error is large) and escape rule as :class:`NECController`, with the same options; but
    event batches only advance its clock. Its P-TEDI estimator still brackets every exposure and
    anchors on every usable frame (the saturation bound included: that is frame-side), so between
    frames its prediction is the last frame's level and commands follow frames only. The escape
    rule's case (a), lost events at the bus ceiling, cannot arise; case (b), a saturated frame, does.
    The difference between ``nec`` and ``nec-frames`` on the same scene is what the events add.
    A lane switched to ``nec-frames`` while running adopts the lane's estimator (with whatever events
    it counted before the switch) and feeds it none from then on; built as ``nec-frames`` its
    estimator never counts one (``estimator.event_totals() == (0, 0)``).
    """

    name = "nec-frames"
    uses_events = False

    def on_events(self, events: np.ndarray) -> ExposureCommand | None:
        return Controller.on_events(self, events)
