"""P-TEDI: the peripheral trilinear event double integral, as a streaming estimator.

The peripheral region R (default: the whole sensor) is collapsed to one "large pixel";
each event changes the region's direct integral by ``±1/N_R`` (Eq. 11). For a frame with
exposure ``T = [s, e]`` and reference time ``g = s``::

    ln P(g)   = ln Pbar - ln E_p(g)                              (Eq. 14, sign: docs/method.md)
    E_p(g)    = (1/|T|) ∫_T exp(c^T D_p(g, t)) dt                 (Eq. 13-14)
    ln Pbar   = g(mean_R Z) - ln T - ln K                         (Eq. 15, the paper's form)
    ln P(now) = ln P(g) + c^T D_p(g, now)                         (Eq. 12)

``D_p`` is the mean over the zone's pixels of the per-pixel direct integral *including* the
TEDI compensation (Eq. 11 as written, with the terms of :mod:`necviz.core.event_model`)::

    c^T D_p(g,t) = c+ (m+ + C+(u)/N_R) - c- (m- + C-(u)/N_R),   u = t - g,
    C±(u)        = Σ_x max(0, a± n±_x(g,t) - b± u)

where ``m±`` are the zone-mean counts and ``n±_x`` the pixel's counts since ``g``. (The
compensation of the mean counts is not the same: ``max`` is convex, so the mean of the
per-pixel terms is at least the term of the mean.)

Streaming form (no per-event buffer): the source announces each exposure's start and end
(:class:`~necviz.core.frames.ExposureMarker`) in stream order; while an exposure is open the
integral of ``exp(c^T D_p(s, t))`` is accumulated piecewise as events arrive. When the frame
arrives (after its exposure) ``ln E_p`` is one division and one log. Several zones (e.g. a
4x4 metering grid) are independent large pixels.

- Without compensation (``a± = 0``, the default) the exponent is constant between events and
  changes by ``±c/N_R`` per event: O(1) per event, coordinates are not even read for the
  whole-sensor region (:func:`ptedi_update_whole`).
- With compensation, each pixel's counts since the anchor and since each exposure start still
  needed are kept by the estimator's event side (:class:`~necviz.core.ptedi_side.EventSide`: one
  uint16 row per pixel, a pair of columns per reference time; an exposure start zeroes its pair, a
  fill of one word per pixel; re-anchoring on an exposure start takes over its pair, O(1)) with, per
  zone, a histogram of those counts and the exact integer sums ``K = #{n_x > L}``,
  ``S = Σ_{n_x > L} n_x`` at the level ``L = floor(u b/a)``, so ``C(u) = a S - b u K`` (see the
  notes in :mod:`necviz.core.ptedi_comp`). Per event O(1) per reference plus the levels crossed as
  time passes (at most ``b u/a`` per reference, and never more than the largest per-pixel count);
  between events the exponent is linear in ``u`` with breakpoints at multiples of ``a/b``,
  integrated exactly piece by piece. A stand-alone estimator is the one member of a side of its
  own; the lanes of one source may share one (:func:`necviz.core.ptedi_shared.share_event_side`),
  with the same estimates bit for bit.

Anchor rule: a zone is re-anchored only on a frame whose valid-pixel fraction (9..250) in
that zone is at least ``min_valid_fraction``; otherwise the zone keeps propagating from its
last good anchor with events (the paper's work-around for frames saturated by a change
during their exposure). Exception (necviz's addition, ``saturation_bound=True``, the default;
``False`` is the paper's rule alone), the saturation bounds: even a badly clipped frame proves
something. With the paper's image form it always bounds ``ln Pbar`` from below (under-exposed
pixels counted as receiving nothing, over-exposed ones as at the top of the valid range — true
for a frame clipped at both ends too), and from above when essentially nothing is over-exposed;
the zone re-anchors at a bound the event-propagated prediction breaks
(:meth:`PeripheralEstimator.frame_bounds`, :meth:`PeripheralEstimator.add_frame`). The frame's
own ``g(mean Z)`` is *not* a bound when it is clipped at both ends (its mean is lowered at one
end and raised at the other), so it is never used as one. Under either rule a zone that has never
been anchored takes its first frame's estimate, saturated or not: there is no anchor to keep
propagating from.

Layout: this module holds the estimator (exposure windows, anchors, prediction); its frame side
(``ln Pbar`` per zone, the saturation bounds) is in :mod:`necviz.core.ptedi_frame`, its Numba kernels
in :mod:`necviz.core.ptedi_kernels` (no compensation; the frame pass) and :mod:`necviz.core.ptedi_comp`
(the per-pixel compensation), whose state is the event side's (:mod:`necviz.core.ptedi_side`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from necviz.core.crf import CameraResponse, default_davis346
from necviz.core.errors import EventFormatError, FrameFormatError, NotAnchoredError, ParameterError, StreamError
from necviz.core.event_model import TediParams, direct_integral
from necviz.core.events import EVENT_DTYPE
from necviz.core.frames import Frame
from necviz.core.ptedi_comp import MAX_LEVEL
from necviz.core.ptedi_frame import FrameSideMixin
from necviz.core.ptedi_kernels import BLOCK, ptedi_close, ptedi_update, ptedi_update_whole
from necviz.core.ptedi_side import EventSide, batch_error
from necviz.core.regions import zone_map, zone_sizes
from necviz.core.sensor import SensorGeometry
from necviz.core.stream import Packet, PacketHandler, dispatch

__all__ = ["FrameEstimate", "IMAGE_FORMS", "PeripheralEstimator"]

IMAGE_FORMS = ("paper", "mean_log")
_FREE, _OPEN, _CLOSED = 0, 1, 2


#: the integral of Eq. 12 in plain Python (a scalar prediction is cheaper without a Numba dispatch)
_direct_integral_py = direct_integral.py_func


def _comp_level_py(u: float, r: float) -> int:
    """:func:`~necviz.core.ptedi_comp.comp_level` in plain Python integers (the same level)."""
    if not r < math.inf:
        return 0
    q = u / r
    if q >= MAX_LEVEL:
        return MAX_LEVEL
    lv = math.floor(q)
    while (lv + 1) * r <= u:
        lv += 1
    while lv > 0 and lv * r > u:
        lv -= 1
    return lv


def _comp_sum_one(hist, lev, kk, ss, ref, q, u, a, b) -> float:
    """:func:`~necviz.core.ptedi_comp.comp_sums` for zone 0 and polarity ``q`` in plain Python (same
    operations, same result; called on every batch, where a Numba dispatch costs more than the work)."""
    if a <= 0.0:
        return 0.0
    r = a / b if b > 0.0 else math.inf
    target = _comp_level_py(u, r)
    lv, k, s = int(lev[ref, q, 0]), int(kk[ref, q, 0]), int(ss[ref, q, 0])
    if target > lv:
        while lv < target and k > 0:
            lv += 1
            hk = int(hist[ref, q, 0, lv])
            k -= hk
            s -= lv * hk
    else:
        lv = min(lv, hist.shape[3] - 1)
        while lv > target:
            hk = int(hist[ref, q, 0, lv])
            k += hk
            s += lv * hk
            lv -= 1
    return a * s - b * u * k


@dataclass(frozen=True)
class FrameEstimate:
    """What P-TEDI made of one frame, per zone."""

    sequence: int
    exposure_start_us: int
    exposure_end_us: int
    log_mean_irradiance: np.ndarray  # ln Pbar, the frame-measured (exposure-averaged) value
    log_e: np.ndarray  # ln E_p(s)
    log_anchor: np.ndarray  # ln P(s) = ln Pbar - ln E_p(s)
    valid_fraction: np.ndarray
    anchored: np.ndarray  # bool: this frame re-anchored the zone
    over_fraction: np.ndarray | None = None
    bounded: np.ndarray | None = None  # bool: a saturated frame moved the zone's anchor to its bound
    #: ln P(s) after this frame: the new anchor where the zone re-anchored (or was bounded), else the
    #: event-propagated prediction at s (NaN for a zone never anchored). A metering statistic of the
    #: frame minus this is its offset from P-TEDI's level (see necviz.core.control.nec).
    log_start: np.ndarray | None = None
    #: per zone: +1 where the anchor moved up to a lower bound (over-exposed frame), -1 down to an
    #: upper bound, 0 otherwise; None when no zone was bounded
    bound_side: np.ndarray | None = None
    #: per zone: the event-propagated ln P(s) before this frame (Eq. 12 from the previous anchor; NaN
    #: where never anchored); None on a frame every zone anchored on (it is not needed there)
    predicted_start: np.ndarray | None = None


@dataclass(frozen=True)
class PeripheralOptions:
    """Where a :class:`PeripheralEstimator` meters and how it anchors, checked once.

    Parameters
    ----------
    rectangle : tuple of int, optional
        The peripheral region ``(x0, y0, x1, y1)`` (``None``: the whole sensor; see
        :func:`necviz.core.regions.zone_map`).
    grid : tuple of int
        Zones across and down inside the region (``(1, 1)``: one zone).
    image_form : str
        ``"paper"`` (``g(mean Z)``, Eq. 15) or ``"mean_log"`` (mean over valid pixels of ``g(Z)``,
        consistent with Eq. 8).
    min_valid_fraction : float
        Anchor rule threshold on the fraction of pixels in 9..250, in (0, 1].
    max_pending : int
        Exposures that may await their frame at once.
    one_sided_clip : float
        The clipped fraction at the "other" end that a one-sided saturation bound tolerates (a few
        hot or dead pixels; default 5 %, see :meth:`PeripheralEstimator.frame_bounds`).
    saturation_bound : bool
        Re-anchor a zone at the bound a saturated frame proves when the event-propagated prediction
        breaks it (necviz's addition, the default); ``False`` keeps the paper's rule alone (skip the
        frame, keep propagating).

    Raises
    ------
    ParameterError
        An unknown image form, a fraction outside its range, or a ``max_pending`` below 1.
    """

    rectangle: tuple[int, int, int, int] | None = None
    grid: tuple[int, int] = (1, 1)
    image_form: str = "paper"
    min_valid_fraction: float = 0.5
    max_pending: int = 4
    one_sided_clip: float = 0.05
    saturation_bound: bool = True

    def __post_init__(self) -> None:
        if self.image_form not in IMAGE_FORMS:
            raise ParameterError(f"image_form must be one of {IMAGE_FORMS}, got {self.image_form!r}")
        f = self.min_valid_fraction
        if isinstance(f, bool) or not (isinstance(f, (int, float)) and 0.0 < f <= 1.0):
            raise ParameterError(f"min_valid_fraction must lie in (0, 1], got {f!r}")
        c = self.one_sided_clip
        if isinstance(c, bool) or not isinstance(c, (int, float)) or not 0.0 <= c <= 1.0:
            raise ParameterError(f"one_sided_clip must lie in [0, 1], got {c!r}")
        if not isinstance(self.saturation_bound, bool):
            raise ParameterError(f"saturation_bound must be true or false, got {self.saturation_bound!r}")
        m = self.max_pending
        if isinstance(m, bool) or not (isinstance(m, int) and m >= 1):
            raise ParameterError(f"max_pending must be a positive integer, got {m!r}")
        object.__setattr__(self, "min_valid_fraction", float(f))
        object.__setattr__(self, "one_sided_clip", float(c))


class PeripheralEstimator(FrameSideMixin, PacketHandler):
    """Streaming P-TEDI estimate of the mean log irradiance of one or more peripheral zones.

    Feed it, in stream order: event arrays (:meth:`update`), exposure markers
    (:meth:`begin_exposure`, :meth:`end_exposure`) and frames (:meth:`add_frame`), or
    every stream packet (:class:`~necviz.core.events.EventBatch` and the rest) through :meth:`feed`. Then :meth:`predict` gives ``ln P(t)`` for any time after
    the last anchor.

    Parameters
    ----------
    sensor : the pixel array.
    params : thresholds and TEDI compensation.
    crf : camera response (default: :func:`default_davis346`).
    options : region, zones, image form, anchor rule and saturation bound (:class:`PeripheralOptions`;
        default ``PeripheralOptions()``). ``saturation_bound`` is also an attribute: a controller that
        adopts an estimator sets it (:class:`~necviz.core.control.nec.NECController`).
    """

    _side: EventSide | None  # the compensation's event side (a+ or a- > 0), else None

    def __init__(
        self,
        sensor: SensorGeometry,
        params: TediParams = TediParams(),
        crf: CameraResponse | None = None,
        options: PeripheralOptions | None = None,
    ):
        opts = PeripheralOptions() if options is None else options
        if not isinstance(opts, PeripheralOptions):
            raise ParameterError(f"options must be a PeripheralOptions, got {type(opts).__name__}")
        if not isinstance(params, TediParams):
            raise ParameterError("params must be a TediParams")
        self.options = opts
        self.sensor = sensor
        self.params = params
        self.crf = crf if crf is not None else default_davis346()
        self.image_form = opts.image_form
        self.min_valid_fraction = opts.min_valid_fraction
        self.one_sided_clip = opts.one_sided_clip
        self.saturation_bound = opts.saturation_bound
        self.zmap = zone_map(sensor, opts.rectangle, opts.grid)
        self.whole = bool(np.all(self.zmap == 0))
        self.sizes = zone_sizes(self.zmap)
        k = self.sizes.size
        self.num_zones = k
        self._zone_flat = self.zmap.ravel()
        self._in_region = self._zone_flat >= 0
        self._inv_n = 1.0 / self.sizes.astype(np.float64)
        self._inv_n0 = float(self._inv_n[0])
        self._derive(params)
        self._counts2 = np.zeros(2, np.int64)  # whole sensor: [ON, OFF], what the scalar kernel updates
        self._c02 = np.zeros(2, np.int64)
        if k == 1:  # views, so the whole-sensor kernel's counts are the zone counts without copying
            self.counts_on, self.counts_off = self._counts2[0:1], self._counts2[1:2]
        else:
            self.counts_on = np.zeros(k, np.int64)
            self.counts_off = np.zeros(k, np.int64)
        self.last_event_us = np.iinfo(np.int64).min
        # exposure windows
        max_pending = opts.max_pending
        self._wstate = [_FREE] * max_pending  # window bookkeeping stays in Python lists (a few entries)
        self._wstart = [0] * max_pending
        self._wend = [0] * max_pending
        self._wage = [0] * max_pending
        self._c0_on = np.zeros((max_pending, k), np.int64)
        self._c0_off = np.zeros((max_pending, k), np.int64)
        self._wlast = np.zeros((max_pending, k), np.int64)
        self._wint = np.zeros((max_pending, k), np.float64)
        self._webase = np.ones((max_pending, k), np.float64)
        self._open = -1
        self._latest = -1  # the window of the latest exposure start
        self._age = 0
        self.dropped_windows = 0
        # anchors
        self.anchor_log = np.full(k, np.nan)
        self.anchor_t = np.zeros(k, np.int64)
        self.anchor_on = np.zeros(k, np.int64)
        self.anchor_off = np.zeros(k, np.int64)
        self.frames_seen = 0
        self.frames_skipped = 0
        self.frames_bounded = 0
        # the compensation (only while a+ or a- > 0): an event side of its own, or one shared with other
        # estimators (share_events); this estimator keeps which slot each zone is anchored on and each
        # window's slot (0: none)
        self._side = None
        self._seen = 0  # event batches this estimator received (the side's lock step)
        self._wslot = [0] * max_pending
        self._aslot = np.zeros(k, np.int64)
        if self.params.a_on > 0.0 or self.params.a_off > 0.0:
            self._comp_start()

    def _derive(self, params: TediParams) -> None:
        """Per-event factors that depend on the thresholds (``exp(±c/N)`` and their tables)."""
        self.params = params
        self._kp = params.as_tuple()
        c_on, c_off = params.c_on, params.c_off
        self._f_on = np.exp(c_on * self._inv_n)
        self._f_off = np.exp(-c_off * self._inv_n)
        steps = np.arange(BLOCK + 1, dtype=np.float64)
        self._g_tab = np.exp(-c_off * self._inv_n[0] * steps)
        self._h_tab = np.exp((c_on + c_off) * self._inv_n[0] * steps)

    @property
    def event_side(self) -> EventSide | None:
        """The compensation's event side (its own, or shared with the lanes of one source); ``None`` while
        the compensation is off."""
        return self._side

    @property
    def _comp(self) -> bool:
        """The TEDI compensation is on (``a+`` or ``a- > 0``): the per-pixel path, through the event side."""
        return self._side is not None

    def set_params(self, params: TediParams) -> None:
        """Change thresholds / compensation while streaming (live tuning), for this estimator alone.

        Takes effect at once: predictions propagate the counts since the last anchor with the
        new values, and an exposure already open integrates with the new values from now on.
        Per-pixel counts are kept only while the compensation is on (``a+`` or ``a- > 0``):
        switched on mid-stream, it counts the events from the switch on until the next anchor
        and exposure start (after which it is exact again). An estimator sharing its event side
        continues on a side of its own (with the state it would have had); to change the contrast
        thresholds of every estimator on a side, see :meth:`set_contrast_thresholds`.
        """
        if not isinstance(params, TediParams):
            raise ParameterError("params must be a TediParams")
        side = self._side
        if side is not None and len(side.members) > 1:  # its own parameters from now on: a side of its own
            self._split()
        self._derive(params)
        comp = params.a_on > 0.0 or params.a_off > 0.0
        if comp and self._side is None:
            self._comp_start()
        elif comp:
            assert self._side is not None
            self._side.set_params(params)
            self._restate_own()
        elif self._side is not None:
            self._leave()
        self._restart_window_base()

    def set_contrast_thresholds(self, c_on: float, c_off: float) -> None:
        """Change the contrast thresholds ``c+``, ``c-`` while streaming (live tuning of the sensor's biases).

        The thresholds live in one place, the event side: with the compensation on they change for every
        estimator sharing this one's side (the lanes of one source see the same events, hence the same
        thresholds); the compensation ``a±, b±`` stays. Takes effect at once, as :meth:`set_params`.

        Raises
        ------
        ParameterError
            A threshold that is not a positive finite number.
        """
        for name, c in (("c_on", c_on), ("c_off", c_off)):
            if isinstance(c, bool) or not isinstance(c, (int, float)) or not (math.isfinite(c) and c > 0.0):
                raise ParameterError(f"{name} must be a positive number, got {c!r}")
        if self._side is None:
            self._derive(replace(self.params, c_on=float(c_on), c_off=float(c_off)))
            self._restart_window_base()
            return
        params = self._side.set_thresholds(c_on, c_off)
        for member in self._side.members:
            member._derive(params)
            member._restart_window_base()

    def _restart_window_base(self) -> None:
        """The zone kernel's running exp of an open window restarts from the counts with the current thresholds."""
        w = self._open
        if w >= 0:
            p = self.params
            self._webase[w] = np.exp(
                (p.c_on * (self.counts_on - self._c0_on[w]) - p.c_off * (self.counts_off - self._c0_off[w]))
                * self._inv_n
            )

    def share_events(self, side: EventSide) -> None:
        """Keep the compensation's per-pixel bookkeeping in ``side`` (an :class:`~necviz.core.ptedi_side.EventSide`
        shared with the other estimators of one source's lanes; see :func:`~necviz.core.ptedi_shared.share_event_side`).
        Only before the first packet; estimates stay exactly those of a side of its own."""
        if not self._comp or self.frames_seen or self._open >= 0 or self.last_event_us != np.iinfo(np.int64).min:
            raise ParameterError("only a fresh compensated estimator can share its event side")
        if (
            side.params.as_tuple() != self.params.as_tuple()
            or side.sensor.shape != self.sensor.shape
            or not np.array_equal(side.zmap, self.zmap)
        ):
            raise ParameterError("estimators sharing an event side need the same sensor, region and parameters")
        assert self._side is not None
        self._side.members.remove(self)
        self._join(side)

    # -- the compensation's event side (Eq. 11 with the Eq. 6 terms per pixel) -----------------------
    def _join(self, side: EventSide) -> None:
        side.members.append(self)
        self._side = side
        self._seen = side.batches
        self.counts_on, self.counts_off = side.counts_on, side.counts_off

    def _own_counts(self, on: np.ndarray, off: np.ndarray) -> None:
        """Zone counts of this estimator's own (the whole-sensor layout: views into ``_counts2``)."""
        if self.num_zones == 1:
            self._counts2[:] = (on[0], off[0])
            self.counts_on, self.counts_off = self._counts2[0:1], self._counts2[1:2]
        else:
            self.counts_on, self.counts_off = on.copy(), off.copy()

    def _comp_start(self) -> None:
        """A side of its own; counting starts now. Mid-stream (the compensation switched on), each anchor
        and each exposure awaiting its frame gets a slot at its start, with the counts from now on."""
        side = EventSide(self.sensor, self.zmap, self.sizes, self.params, slots=2)
        side.counts_on[:] = self.counts_on
        side.counts_off[:] = self.counts_off
        side.last_event_us = self.last_event_us
        self._join(side)
        anchored = np.isfinite(self.anchor_log)
        for g in sorted(set(self.anchor_t[anchored].tolist())):
            s = side.start_late(int(g))
            zones = anchored & (self.anchor_t == g)
            self._aslot[zones] = s
        for v, st in enumerate(self._wstate):
            if st != _FREE:
                self._wslot[v] = side.start_late(
                    int(self._wstart[v]),
                    (self._c0_on[v], self._c0_off[v], self._wlast[v], self._wint[v]) if v == self._open else None,
                )
        self._restate_own()

    def _restate_own(self) -> None:
        """Levels and sums of this estimator's anchors at the last event, and of its open exposure (its own
        side's parameters changed)."""
        side = self._side
        assert side is not None
        u = self._anchor_u()
        for a in set(self._aslot.tolist()):
            if a > 0:
                side.restate(a, self._aslot == a, u)
        if self._open >= 0:
            side.restate(self._wslot[self._open], np.ones(self.num_zones, np.bool_), self._window_u())

    def _uses(self) -> tuple[list[int], list[int]]:
        """The slots this estimator uses (windows, then the anchors' once each) and how often."""
        slots = [s for s in self._wslot if s > 0] + [a for a in set(self._aslot.tolist()) if a > 0]
        return slots, [slots.count(s) for s in slots]

    def _split(self) -> None:
        """Continue on a side of its own: copies of the slots it uses; it releases the shared ones."""
        side = self._side
        assert side is not None
        slots, uses = self._uses()
        own, where = side.split(slots, uses)
        opened = self._wslot[self._open] if self._open >= 0 else 0
        for s in slots:
            side.release(s)
        side.members.remove(self)
        self._wslot = [where.get(s, 0) for s in self._wslot]
        self._aslot = np.array([where.get(a, 0) for a in self._aslot.tolist()], np.int64)
        if opened:
            own.opens[where[opened]] = 1
            own.integ[where[opened]] = True
        self._join(own)

    def _leave(self) -> None:
        """The compensation is off: no event side; the zone counts become this estimator's own."""
        side = self._side
        assert side is not None
        for s in self._uses()[0]:
            side.release(s)
        side.members.remove(self)
        self._side = None
        self._wslot = [0] * len(self._wstate)
        self._aslot[:] = 0
        self._own_counts(side.counts_on, side.counts_off)

    def _anchor_u(self) -> np.ndarray:
        """Time since each zone's anchor up to the last event (0 where none, or none yet)."""
        if self.last_event_us == np.iinfo(np.int64).min:
            return np.zeros(self.num_zones)
        u = (self.last_event_us - self.anchor_t).astype(np.float64)
        return np.where(np.isfinite(self.anchor_log) & (u > 0), u, 0.0)

    def _window_u(self) -> np.ndarray:
        w = self._open
        u = float(max(0, self.last_event_us - int(self._wstart[w]))) if w >= 0 else 0.0
        return np.full(self.num_zones, u)

    def _drop_window(self, w: int) -> None:
        """Window ``w`` is recycled or its frame came: it no longer needs its slot (as a window)."""
        if self._side is not None and self._wslot[w] > 0:
            self._side.release(self._wslot[w])
            self._wslot[w] = 0

    def _comp_anchor(self, w: int, zones: np.ndarray, s: int) -> None:
        """``zones`` re-anchored on window ``w`` (start ``s``): they now use that window's slot (held once
        for all the zones on it)."""
        side = self._side
        assert side is not None
        sw = self._wslot[w]
        old = self._aslot.copy()
        self._aslot[zones] = sw
        for a in set(self._aslot.tolist()):
            if a > 0 and a not in old:
                side.hold(a)
        for a in set(old.tolist()):
            if a > 0 and a not in self._aslot:
                side.release(a)
        side.anchor(sw, zones, s)

    def _comp_between(self, w: int, u: np.ndarray) -> np.ndarray:
        """Per zone ``Σ_x max(0, a± n±_x - b± u)`` for the counts between the anchor and window ``w``'s
        start (O(pixels); used only for the saturation bound)."""
        assert self._side is not None
        return self._side.between(self._aslot, self._wslot[w], u)

    # -- stream input -------------------------------------------------------------------------
    def update(self, events: np.ndarray) -> None:
        """Apply an event batch (time-ordered, not before events already processed). O(n)."""
        if not isinstance(events, np.ndarray) or events.dtype != EVENT_DTYPE:
            raise EventFormatError(f"events must be a structured array of dtype {EVENT_DTYPE}")
        if events.size == 0:
            return
        side = self._side
        if side is not None:
            try:
                self._seen = side.update(events, self._seen)
            finally:
                self.last_event_us = side.last_event_us
            return
        w = self._open
        if self.whole:
            c0 = self._c02
            if w >= 0:
                c0[0], c0[1] = self._c0_on[w, 0], self._c0_off[w, 0]
            bad = ptedi_update_whole(
                events["t"],
                events["p"],
                self.last_event_us,
                self._counts2,
                self._inv_n0,
                self._g_tab,
                self._h_tab,
                w,
                c0,
                self._wlast,
                self._wint,
                self._kp[0],
                self._kp[1],
            )
        else:
            bad = ptedi_update(
                events["t"],
                events["x"],
                events["y"],
                events["p"],
                self.zmap,
                self.last_event_us,
                self.counts_on,
                self.counts_off,
                self._inv_n,
                self._f_on,
                self._f_off,
                w,
                self._c0_on,
                self._c0_off,
                self._wlast,
                self._wint,
                self._webase,
            )
        if bad >= 0:
            self.last_event_us = before = int(events["t"][bad - 1]) if bad > 0 else self.last_event_us
            raise batch_error(events, bad, before, self.sensor)
        self.last_event_us = int(events["t"][-1])

    def begin_exposure(self, t_us: int) -> None:
        """An exposure starts at ``t_us`` (all events before it already applied)."""
        t_us = int(t_us)
        if t_us < self.last_event_us:
            raise StreamError(
                f"exposure start at {t_us} µs arrived after events up to {self.last_event_us} µs were processed; "
                "markers must be in time order with the events"
            )
        if self._open >= 0:
            raise StreamError(
                f"exposure start at {t_us} µs while the exposure started at {int(self._wstart[self._open])} µs "
                "has not ended"
            )
        if _FREE in self._wstate:
            w = self._wstate.index(_FREE)
        else:  # every slot awaits a frame that never came: recycle the oldest
            w = self._wage.index(min(self._wage))
            self.dropped_windows += 1
            self._drop_window(w)
        if self._side is not None:
            self._wslot[w] = self._side.begin(t_us)
        self._wstate[w] = _OPEN
        self._latest = w
        self._wstart[w] = t_us
        self._age += 1
        self._wage[w] = self._age
        if self.whole:
            self._c0_on[w, 0] = self.counts_on[0]
            self._c0_off[w, 0] = self.counts_off[0]
            self._wlast[w, 0] = t_us
            self._wint[w, 0] = 0.0
        else:
            self._c0_on[w] = self.counts_on
            self._c0_off[w] = self.counts_off
            self._wlast[w] = t_us
            self._wint[w] = 0.0
            self._webase[w] = 1.0
        self._open = w

    def end_exposure(self, t_us: int) -> None:
        """The open exposure ends at ``t_us`` (all events before it already applied)."""
        t_us = int(t_us)
        w = self._open
        if w < 0:
            raise StreamError(f"exposure end at {t_us} µs without a matching start")
        if t_us <= self._wstart[w] or t_us < self.last_event_us:
            raise StreamError(
                f"exposure end at {t_us} µs is not after its start ({int(self._wstart[w])} µs) and the events "
                f"already processed ({self.last_event_us} µs)"
            )
        if self._side is not None:
            self._wint[w] = self._side.end(self._wslot[w], t_us)
            self._wlast[w] = t_us
        else:
            ptedi_close(
                t_us,
                self.counts_on,
                self.counts_off,
                self._inv_n,
                w,
                self._c0_on,
                self._c0_off,
                self._wlast,
                self._wint,
                self._kp[0],
                self._kp[1],
            )
        self._wstate[w] = _CLOSED
        self._wend[w] = t_us
        self._open = -1

    def add_frame(self, frame: Frame) -> FrameEstimate:
        """A frame arrived (after its announced exposure); re-anchor the zones where it is usable."""
        if frame.shape != self.sensor.shape:
            raise FrameFormatError(
                f"frame {frame.sequence} is {frame.shape[1]}x{frame.shape[0]}, the sensor is "
                f"{self.sensor.width}x{self.sensor.height}"
            )
        s, e = int(frame.exposure_start_us), int(frame.exposure_end_us)
        w = next(
            (i for i, st in enumerate(self._wstate) if st == _CLOSED and self._wstart[i] == s and self._wend[i] == e),
            -1,
        )
        if w < 0:
            raise StreamError(
                f"frame {frame.sequence} with exposure [{s}, {e}] µs was not announced by exposure start/end "
                "markers (or its end has not been seen yet); sources must send them in stream order"
            )
        w0 = self._c0_on[w], self._c0_off[w]
        if self.whole:
            lp, fr, ov = self._whole_frame_log_irradiance(frame)
            log_e0 = math.log(self._wint[w, 0] / (e - s))
            if fr >= self.min_valid_fraction and math.isfinite(lp - log_e0):  # the common case, scalar
                self.anchor_log[0] = lp - log_e0
                self.anchor_t[0] = s
                self.anchor_on[0] = w0[0][0]
                self.anchor_off[0] = w0[1][0]
                if self._side is not None:
                    self._comp_anchor(w, np.zeros(1, np.int64), s)
                    self._drop_window(w)
                self._wstate[w] = _FREE
                self.frames_seen += 1
                anchor = np.array([lp - log_e0])
                return FrameEstimate(
                    frame.sequence,
                    s,
                    e,
                    np.array([lp]),
                    np.array([log_e0]),
                    anchor,
                    np.array([fr]),
                    np.array([True]),
                    np.array([ov]),
                    np.array([False]),
                    anchor,
                )
            log_pbar, frac, over = np.array([lp]), np.array([fr]), np.array([ov])
            log_e = np.array([log_e0])
        else:
            log_pbar, frac, over = self.frame_log_irradiance(frame)
            log_e = np.log(self._wint[w] / (e - s))
        log_anchor = log_pbar - log_e
        ok = (frac >= self.min_valid_fraction) & np.isfinite(log_anchor)
        # Saturation bounds (see frame_bounds): a frame with too few valid pixels still bounds ln P(s).
        # Where the event-propagated prediction breaks a bound (events lost to the sensor's rate
        # ceiling, say), re-anchor at the bound instead of keeping a prediction the frame disproves.
        # A zone never anchored takes the frame's estimate (there is nothing better to propagate).
        bounded = np.zeros_like(ok)
        value = log_anchor
        side = None
        start = log_anchor
        pred_s = None
        if not ok.all():
            pred_s = self._predict_at_window(w)
            with np.errstate(invalid="ignore"):
                first = ~ok & ~np.isfinite(pred_s) & np.isfinite(log_anchor)
            raise_ = lower_ = np.zeros_like(ok)
            if self.saturation_bound:
                lo, hi = self.frame_bounds(frame, log_pbar, frac, over)
                lo, hi = lo - log_e, hi - log_e
                with np.errstate(invalid="ignore"):
                    raise_ = ~ok & ~first & np.isfinite(lo) & (pred_s < lo)
                    lower_ = ~ok & ~first & ~raise_ & np.isfinite(hi) & (pred_s > hi)
            bounded = first | raise_ | lower_
            value = np.where(raise_, lo, np.where(lower_, hi, log_anchor)) if self.saturation_bound else log_anchor
            side = raise_.astype(np.int8) - lower_.astype(np.int8)
            start = np.where(ok | bounded, value, pred_s)
        new = ok | bounded
        self.anchor_log[new] = value[new]
        self.anchor_t[new] = s
        self.anchor_on[new] = w0[0][new]
        self.anchor_off[new] = w0[1][new]
        if self._side is not None:
            if new.any():
                self._comp_anchor(w, np.flatnonzero(new), s)
            self._drop_window(w)
        self._wstate[w] = _FREE
        self.frames_seen += 1
        if not ok.all():
            self.frames_skipped += 1
        self.frames_bounded += int(bounded.any())
        return FrameEstimate(
            frame.sequence, s, e, log_pbar, log_e, log_anchor, frac, ok, over, bounded, start, side, pred_s
        )

    def _propagate(self, counts_on: np.ndarray, counts_off: np.ndarray) -> np.ndarray:
        """Eq. 12 without compensation, from each zone's anchor with the given cumulative counts
        (NaN where unanchored)."""
        m_on = (counts_on - self.anchor_on) * self._inv_n
        m_off = (counts_off - self.anchor_off) * self._inv_n
        return self.anchor_log + self._kp[0] * m_on - self._kp[1] * m_off

    def _predict_at_window(self, w: int) -> np.ndarray:
        """Eq. 12 from each zone's anchor to window ``w``'s start, with the counts seen by then."""
        pred = self._propagate(self._c0_on[w], self._c0_off[w])
        if self._side is not None:
            u = np.maximum(0, int(self._wstart[w]) - self.anchor_t).astype(np.float64)
            comp = self._comp_between(w, u)
            pred = pred + (self._kp[0] * comp[0] - self._kp[1] * comp[1]) * self._inv_n
        return pred

    def feed(self, packet: Packet) -> FrameEstimate | None:
        """One stream packet to the method for its kind; a frame returns its :class:`FrameEstimate`."""
        return dispatch(self, packet)

    # PacketHandler: what dispatch calls (methods, not aliases, so a subclass's update is used)
    def on_events(self, events: np.ndarray) -> None:
        self.update(events)

    def on_exposure_start(self, t_us: int) -> None:
        self.begin_exposure(t_us)

    def on_exposure_end(self, t_us: int) -> None:
        self.end_exposure(t_us)

    def on_frame(self, frame: Frame) -> FrameEstimate:
        return self.add_frame(frame)

    # -- output -----------------------------------------------------------------------------
    @property
    def ready(self) -> bool:
        """True once at least one zone is anchored."""
        if self.num_zones == 1:  # asked on every event batch: skip the array round trip
            return math.isfinite(self.anchor_log.item(0))
        return bool(np.isfinite(self.anchor_log).any())

    def event_totals(self) -> tuple[int, int]:
        """ON and OFF events counted in the region so far (every zone)."""
        if self.num_zones == 1:  # asked on every event batch (NEC's bus watch): Python ints without numpy scalars
            return self.counts_on.item(0), self.counts_off.item(0)
        return int(self.counts_on.sum()), int(self.counts_off.sum())

    def predict_zones(self, t_us: int | None = None) -> np.ndarray:
        """``ln P(t)`` per zone (Eq. 12 with the compensation); NaN for zones never anchored.

        Uses every event processed so far; ``t_us`` (default: the last event time) enters the
        compensation term and must not precede a zone's anchor.
        """
        t = self.last_event_us if t_us is None else int(t_us)
        anchored = np.isfinite(self.anchor_log)
        if np.any(anchored & (t < self.anchor_t)):
            raise ParameterError(
                f"prediction time {t} µs precedes the anchor at {int(self.anchor_t[anchored].max())} µs"
            )
        pred = self._propagate(self.counts_on, self.counts_off)
        if self._side is not None:  # Eq. 11: the mean over the zone's pixels of their compensation terms
            u = np.where(anchored, (t - self.anchor_t).astype(np.float64), 0.0)
            c_on, c_off = self._kp[0], self._kp[1]
            comp = self._side.sums(self._aslot, u)
            pred = pred + (c_on * comp[0] - c_off * comp[1]) * self._inv_n
        return pred

    def _scalar_times(self, t_us: int | None) -> tuple[int, int]:
        """One zone: the prediction time (default: the last event's) and the anchor's, checked."""
        if not math.isfinite(self.anchor_log[0]):
            raise NotAnchoredError("P-TEDI has no anchor yet: no usable frame has arrived")
        t = self.last_event_us if t_us is None else int(t_us)
        g = int(self.anchor_t[0])
        if t < g:
            raise ParameterError(f"prediction time {t} µs precedes the anchor at {g} µs")
        return t, g

    def predict(self, t_us: int | None = None) -> float:
        """Mean log irradiance ``ln P(t)`` over the anchored zones, weighted by their pixel counts."""
        if self.num_zones == 1 and not self._comp:  # scalar path: the controller calls this on every batch
            # _scalar_times' checks inline, and .item() (Python numbers) rather than numpy scalars: the same values
            anchor = self.anchor_log.item(0)
            if not math.isfinite(anchor):
                raise NotAnchoredError("P-TEDI has no anchor yet: no usable frame has arrived")
            t = self.last_event_us if t_us is None else int(t_us)
            g = self.anchor_t.item(0)
            if t < g:
                raise ParameterError(f"prediction time {t} µs precedes the anchor at {g} µs")
            inv = self._inv_n0
            on, off = self._counts2.tolist()
            m_on = (on - self.anchor_on.item(0)) * inv
            m_off = (off - self.anchor_off.item(0)) * inv
            # the kernel's Python form: called from Python, it skips Numba's dispatch
            return anchor + _direct_integral_py(1.0, float(t - g), m_on, m_off, *self._kp)
        if self.num_zones == 1:  # compensated, scalar: predict_zones' operations without its arrays
            t, g = self._scalar_times(t_us)
            inv = float(self._inv_n[0])
            c_on, c_off, a_on, b_on, a_off, b_off = self._kp
            m_on = (int(self.counts_on[0]) - int(self.anchor_on[0])) * inv
            m_off = (int(self.counts_off[0]) - int(self.anchor_off[0])) * inv
            pred = float(self.anchor_log[0]) + c_on * m_on - c_off * m_off
            side, ref = self._side, int(self._aslot[0])
            assert side is not None
            hist, lev, kk, ss = side.hist, side.lev, side.kk, side.ss
            u = float(t - g)
            comp_on = _comp_sum_one(hist, lev, kk, ss, ref, 0, u, a_on, b_on)
            comp_off = _comp_sum_one(hist, lev, kk, ss, ref, 1, u, a_off, b_off)
            z0 = pred + (c_on * comp_on - c_off * comp_off) * inv
            n = float(self.sizes[0])
            return z0 * n / n  # the weighted mean of one zone, as np.dot(z, sizes) / sizes.sum() rounds it
        z = self.predict_zones(t_us)
        ok = np.isfinite(z)
        if not ok.any():
            raise NotAnchoredError("P-TEDI has no anchor yet: no usable frame has arrived")
        wts = self.sizes[ok]
        return float(np.dot(z[ok], wts) / wts.sum())
