"""P-TEDI: the peripheral trilinear event double integral, as a streaming estimator.

The peripheral region R (default: the whole sensor) is collapsed to one "large pixel";
each event changes the region's direct integral by ``±1/N_R`` (Eq. 11). For a frame with
exposure ``T = [s, e]`` and reference time ``g = s``::

    ln P(g)   = ln Pbar - ln E_p(g)                              (Eq. 14, sign per nec-method.md)
    E_p(g)    = (1/|T|) ∫_T exp(c^T D_p(g, t)) dt                 (Eq. 13-14)
    ln Pbar   = g(mean_R Z) - ln T - ln K                         (Eq. 15, the paper's form)
    ln P(now) = ln P(g) + c^T D_p(g, now)                         (Eq. 12)

Streaming form (O(1) per event, no per-event buffer): the source announces each exposure's
start and end (:class:`~necviz.core.frames.ExposureMarker`) in stream order; while an
exposure is open the integral of ``exp(c^T D_p(s, t))`` is accumulated piecewise as events
arrive (the exponential of the uncompensated part is kept by multiplication, the compensated
pieces in closed form). When the frame arrives (after its exposure) ``ln E_p`` is one division
and one log. Several zones (e.g. a 4x4 metering grid) are independent large pixels.

Anchor rule: a zone is re-anchored only on a frame whose valid-pixel fraction (9..250) in
that zone is at least ``min_valid_fraction``; otherwise the zone keeps propagating from its
last good anchor with events (the paper's work-around for frames saturated by a change
during their exposure).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from .crf import US_PER_S, CameraResponse, default_davis346
from .errors import EventFormatError, FrameFormatError, NotAnchoredError, ParameterError, StreamError
from .event_model import TediParams, direct_integral, segment_integral
from .events import EVENT_DTYPE
from .frames import ExposureMarker, Frame
from .imu import ImuBatch, TriggerBatch
from .regions import zone_map, zone_sizes
from .sensor import SensorGeometry

IMAGE_FORMS = ("paper", "mean_log")
_FREE, _OPEN, _CLOSED = 0, 1, 2


@nb.njit(cache=True)
def ptedi_update(
    t, x, y, p, zmap, whole, last_t,
    counts_on, counts_off, inv_n, f_on, f_off,
    w, w_start, c0_on, c0_off, w_last, w_int, w_ebase,
    c_on, c_off, a_on, b_on, a_off, b_off,
):
    """Apply an event batch to the P-TEDI state (Eq. 11 direct integral, Eq. 13 exposure integral).

    Per event: find its zone (skipped when ``whole``), and if exposure window ``w`` is open,
    add ``∫ exp(c^T D_p(s, τ)) dτ`` since the zone's last event (constant exponent, or the
    closed-form compensated pieces of :func:`segment_integral`), then update the zone's
    counts and the running ``exp`` by a precomputed factor ``exp(±c/N_R)``.
    O(1) per event, O(zones) memory. Stops at the first event whose time decreases or whose
    coordinates lie off the zone map and returns its index (``-1`` when all were applied).
    """
    h, wd = zmap.shape
    prev = last_t
    for i in range(t.shape[0]):
        ti = t[i]
        if ti < prev:
            return i
        prev = ti
        if whole:
            k = 0
        else:
            xi = x[i]
            yi = y[i]
            if xi >= wd or yi >= h:
                return i
            k = zmap[yi, xi]
            if k < 0:
                continue
        on = p[i] > 0
        if w >= 0:
            last = w_last[w, k]
            if ti > last:
                m_on = (counts_on[k] - c0_on[w, k]) * inv_n[k]
                m_off = (counts_off[k] - c0_off[w, k]) * inv_n[k]
                u0 = float(last - w_start)
                if a_on * m_on > b_on * u0 or a_off * m_off > b_off * u0:
                    w_int[w, k] += segment_integral(
                        u0, float(ti - w_start), 1.0, m_on, m_off, c_on, c_off, a_on, b_on, a_off, b_off
                    )
                else:
                    w_int[w, k] += w_ebase[w, k] * (ti - last)
                w_last[w, k] = ti
            w_ebase[w, k] *= f_on[k] if on else f_off[k]
        if on:
            counts_on[k] += 1
        else:
            counts_off[k] += 1
    return -1


_direct_integral_py = direct_integral.py_func

BLOCK = 256  # events per block in the whole-sensor kernel (size of its exp tables)


@nb.njit(cache=True)
def ptedi_update_whole(
    t, p, last_t, counts, inv_n, g_tab, h_tab, w, w_start, c0, w_last, w_int,
    c_on, c_off, a_on, b_on, a_off, b_off,
):
    """:func:`ptedi_update` for a single zone covering the whole sensor (the default region).

    Same equations (Eq. 11 and the Eq. 13 integral), arranged so no floating-point
    dependency chain runs through the events: within a block of ``B`` events starting with
    ``x_b = c^T D_p``, the integrand after ``i`` events of which ``a`` are ON is exactly
    ``exp(x_b) * G[i] * H[a]`` with ``G[i] = exp(-c- i / N)``, ``H[a] = exp((c+ + c-) a / N)``;
    ``exp(x_b)`` is recomputed from the integer counts at each block start (no drift), and the
    integral is split over four accumulators. Coordinates are never read.
    ``counts = [ON, OFF]``, ``c0 = [ON, OFF]`` at the window start. O(1) per event.
    Returns the index of the first event whose time decreases, else -1.
    """
    n_on = counts[0]
    n_off = counts[1]
    prev = last_t
    bad = -1
    if w < 0:
        seen = t.shape[0]
        ons = 0
        for i in range(t.shape[0]):
            ti = t[i]
            if ti < prev:
                bad = i
                seen = i
                break
            prev = ti
            ons += p[i] > 0
        n_on += ons
        n_off += seen - ons
    else:
        blk = g_tab.shape[0] - 1
        last = w_last[w, 0]
        c0_on = c0[0]
        c0_off = c0[1]
        has_comp = a_on > 0.0 or a_off > 0.0
        accs = np.zeros(4)
        row = np.empty(blk + 1)  # exp(x_b) * G[i] for the current block
        eb = math.exp((c_on * (n_on - c0_on) - c_off * (n_off - c0_off)) * inv_n)
        for k in range(blk + 1):
            row[k] = eb * g_tab[k]
        ib = 0
        ab = 0
        n = t.shape[0]
        i = 0
        while i < n and bad < 0:
            end = min(n, i + blk - ib)
            # The compensation is inactive on the whole block if it is inactive with every count
            # raised by the block length and u at its smallest (counts only grow, u only grows).
            checked = False
            if has_comp:
                grow = (end - i) * inv_n
                u_lo = float(last - w_start)
                checked = (a_on * ((n_on + ab - c0_on) * inv_n + grow) > b_on * u_lo
                           or a_off * ((n_off + ib - ab - c0_off) * inv_n + grow) > b_off * u_lo)
            for j in range(i, end):
                tj = t[j]
                if tj < prev:
                    bad = j
                    break
                prev = tj
                if checked:
                    m_on = (n_on + ab - c0_on) * inv_n
                    m_off = (n_off + ib - ab - c0_off) * inv_n
                    u0 = float(last - w_start)
                    if a_on * m_on > b_on * u0 or a_off * m_off > b_off * u0:
                        accs[j & 3] += segment_integral(
                            u0, float(tj - w_start), 1.0, m_on, m_off, c_on, c_off, a_on, b_on, a_off, b_off
                        )
                    else:
                        accs[j & 3] += row[ib] * h_tab[ab] * float(tj - last)
                else:  # repeated timestamps add a zero-length stretch
                    accs[j & 3] += row[ib] * h_tab[ab] * float(tj - last)
                last = tj
                on = p[j] > 0
                ab += on
                ib += 1
            i = end
            if ib == blk or bad >= 0 or i >= n:  # fold the block's counts into the totals
                n_on += ab
                n_off += ib - ab
                ib = 0
                ab = 0
                eb = math.exp((c_on * (n_on - c0_on) - c_off * (n_off - c0_off)) * inv_n)
                for k in range(blk + 1):
                    row[k] = eb * g_tab[k]
        w_last[w, 0] = last
        w_int[w, 0] += accs.sum()
    counts[0] = n_on
    counts[1] = n_off
    return bad


@nb.njit(cache=True)
def ptedi_close(
    t_end, counts_on, counts_off, inv_n, w, w_start, c0_on, c0_off, w_last, w_int,
    c_on, c_off, a_on, b_on, a_off, b_off,
):
    """Integrate every zone of window ``w`` from its last event to the exposure end. O(zones)."""
    for k in range(counts_on.shape[0]):
        m_on = (counts_on[k] - c0_on[w, k]) * inv_n[k]
        m_off = (counts_off[k] - c0_off[w, k]) * inv_n[k]
        w_int[w, k] += segment_integral(
            float(w_last[w, k] - w_start), float(t_end - w_start), 1.0,
            m_on, m_off, c_on, c_off, a_on, b_on, a_off, b_off,
        )
        w_last[w, k] = t_end


@nb.njit(cache=True)
def image_stats(z, vmin, vmax):
    """One integer-only pass over an 8-bit image: ``(sum Z, pixels in vmin..vmax, pixels above vmax)``.

    The image side of Eq. 15 (``mean_R Z``) and the valid/over-exposed fractions of the anchor
    rule. O(pixels).
    """
    total = 0
    nvalid = 0
    nover = 0
    span = vmax - vmin
    for v in z:
        total += v
        nvalid += (np.uint8(v - vmin) <= span)
        nover += v > vmax
    return total, nvalid, nover


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


class PeripheralEstimator:
    """Streaming P-TEDI estimate of the mean log irradiance of one or more peripheral zones.

    Feed it, in stream order: event batches (:meth:`update`), exposure markers
    (:meth:`begin_exposure`, :meth:`end_exposure`) and frames (:meth:`add_frame`), or
    everything through :meth:`feed`. Then :meth:`predict` gives ``ln P(t)`` for any time after
    the last anchor.

    Parameters
    ----------
    sensor : the pixel array.
    params : thresholds and TEDI compensation.
    crf : camera response (default: :func:`default_davis346`).
    rectangle, grid : the peripheral region (see :func:`necviz.core.regions.zone_map`).
    image_form : ``"paper"`` (``g(mean Z)``, Eq. 15) or ``"mean_log"`` (mean over valid pixels
        of ``g(Z)``, consistent with Eq. 8).
    min_valid_fraction : anchor rule threshold on the fraction of pixels in 9..250.
    max_pending : exposures that may await their frame at once.
    """

    def __init__(
        self,
        sensor: SensorGeometry,
        params: TediParams = TediParams(),
        crf: CameraResponse | None = None,
        rectangle: tuple[int, int, int, int] | None = None,
        grid: tuple[int, int] = (1, 1),
        image_form: str = "paper",
        min_valid_fraction: float = 0.5,
        max_pending: int = 4,
    ):
        if image_form not in IMAGE_FORMS:
            raise ParameterError(f"image_form must be one of {IMAGE_FORMS}, got {image_form!r}")
        if not (isinstance(min_valid_fraction, (int, float)) and 0.0 < min_valid_fraction <= 1.0):
            raise ParameterError(f"min_valid_fraction must lie in (0, 1], got {min_valid_fraction!r}")
        if not isinstance(params, TediParams):
            raise ParameterError("params must be a TediParams")
        self.sensor = sensor
        self.params = params
        self.crf = crf if crf is not None else default_davis346()
        self.image_form = image_form
        self.min_valid_fraction = float(min_valid_fraction)
        self.zmap = zone_map(sensor, rectangle, grid)
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
        if not (isinstance(max_pending, int) and max_pending >= 1):
            raise ParameterError(f"max_pending must be a positive integer, got {max_pending!r}")
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

    def set_params(self, params: TediParams) -> None:
        """Change thresholds / compensation while streaming (live tuning).

        Takes effect at once: predictions propagate the counts since the last anchor with the
        new values, and an exposure already open mixes old and new factors in its integral.
        """
        if not isinstance(params, TediParams):
            raise ParameterError("params must be a TediParams")
        self._derive(params)

    # -- stream input -------------------------------------------------------------------------
    def update(self, events: np.ndarray) -> None:
        """Apply an event batch (time-ordered, not before events already processed). O(n)."""
        if not isinstance(events, np.ndarray) or events.dtype != EVENT_DTYPE:
            raise EventFormatError(f"events must be a structured array of dtype {EVENT_DTYPE}")
        if events.size == 0:
            return
        w = self._open
        ws = int(self._wstart[w]) if w >= 0 else 0
        if self.whole:
            c0 = self._c02
            if w >= 0:
                c0[0], c0[1] = self._c0_on[w, 0], self._c0_off[w, 0]
            bad = ptedi_update_whole(
                events["t"], events["p"], self.last_event_us, self._counts2, self._inv_n0, self._g_tab, self._h_tab,
                w, ws, c0, self._wlast, self._wint, *self._kp,
            )
        else:
            bad = ptedi_update(
                events["t"], events["x"], events["y"], events["p"], self.zmap, self.whole, self.last_event_us,
                self.counts_on, self.counts_off, self._inv_n, self._f_on, self._f_off,
                w, ws, self._c0_on, self._c0_off, self._wlast, self._wint, self._webase, *self._kp,
            )
        if bad >= 0:
            ev = events[bad]
            before = int(events["t"][bad - 1]) if bad > 0 else self.last_event_us
            self.last_event_us = before
            if int(ev["t"]) < before:
                raise EventFormatError(
                    f"event {bad} of the batch at {int(ev['t'])} µs is earlier than events already processed "
                    f"({before} µs); the {bad} events before it were applied"
                )
            raise EventFormatError(
                f"event {bad} of the batch at (x={int(ev['x'])}, y={int(ev['y'])}) lies outside the "
                f"{self.sensor.width}x{self.sensor.height} sensor; the {bad} events before it were applied"
            )
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
        self._wstate[w] = _OPEN
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
        ptedi_close(
            t_us, self.counts_on, self.counts_off, self._inv_n, w, int(self._wstart[w]),
            self._c0_on, self._c0_off, self._wlast, self._wint, *self._kp,
        )
        self._wstate[w] = _CLOSED
        self._wend[w] = t_us
        self._open = -1

    def frame_log_irradiance(self, frame: Frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(ln Pbar, valid fraction, over-exposed fraction)`` per zone from the image alone
        (Eq. 15 or the mean-log form)."""
        if self.whole:
            lp, frac, over = self._whole_frame_log_irradiance(frame)
            return np.array([lp]), np.array([frac]), np.array([over])
        z = frame.image.ravel()
        log_tk = math.log(frame.exposure_us / US_PER_S) + math.log(frame.gain)
        zf, inr = self._zone_flat, self._in_region
        valid = (z >= self.crf.valid_min) & (z <= self.crf.valid_max)
        k = self.num_zones
        nvalid = np.bincount(zf[inr & valid], minlength=k).astype(np.float64)
        frac = nvalid / self.sizes
        over = np.bincount(zf[inr & (z > self.crf.valid_max)], minlength=k) / self.sizes
        if self.image_form == "paper":
            mean_z = np.bincount(zf[inr], weights=z[inr].astype(np.float64), minlength=k) / self.sizes
            return np.asarray(self.crf.log_exposure(mean_z), dtype=np.float64) - log_tk, frac, over
        sel = inr & valid
        gsum = np.bincount(zf[sel], weights=self.crf.g[z[sel]], minlength=k)
        with np.errstate(invalid="ignore", divide="ignore"):
            return gsum / nvalid - log_tk, frac, over

    def add_frame(self, frame: Frame) -> FrameEstimate:
        """A frame arrived (after its announced exposure); re-anchor the zones where it is usable."""
        if frame.shape != self.sensor.shape:
            raise FrameFormatError(
                f"frame {frame.sequence} is {frame.shape[1]}x{frame.shape[0]}, the sensor is "
                f"{self.sensor.width}x{self.sensor.height}"
            )
        s, e = int(frame.exposure_start_us), int(frame.exposure_end_us)
        w = next((i for i, st in enumerate(self._wstate)
                  if st == _CLOSED and self._wstart[i] == s and self._wend[i] == e), -1)
        if w < 0:
            raise StreamError(
                f"frame {frame.sequence} with exposure [{s}, {e}] µs was not announced by exposure start/end "
                "markers (or its end has not been seen yet); sources must send them in stream order"
            )
        w0 = self._c0_on[w], self._c0_off[w]
        if self.whole:
            lp, fr, ov = self._whole_frame_log_irradiance(frame)
            log_e = math.log(self._wint[w, 0] / (e - s))
            if fr >= self.min_valid_fraction and math.isfinite(lp - log_e):  # the common case, scalar
                self.anchor_log[0] = lp - log_e
                self.anchor_t[0] = s
                self.anchor_on[0] = w0[0][0]
                self.anchor_off[0] = w0[1][0]
                self._wstate[w] = _FREE
                self.frames_seen += 1
                return FrameEstimate(frame.sequence, s, e, np.array([lp]), np.array([log_e]),
                                     np.array([lp - log_e]), np.array([fr]), np.array([True]), np.array([ov]),
                                     np.array([False]))
            log_pbar, frac, over = np.array([lp]), np.array([fr]), np.array([ov])
            log_e = np.array([log_e])
        else:
            log_pbar, frac, over = self.frame_log_irradiance(frame)
            log_e = np.log(self._wint[w] / (e - s))
        log_anchor = log_pbar - log_e
        ok = (frac >= self.min_valid_fraction) & np.isfinite(log_anchor)
        # Saturation bound: clipping only lowers digits, so a frame dominated by over-exposed pixels
        # proves ln P(s) >= its estimate (and one dominated by under-exposed pixels, <=). Where the
        # event-propagated prediction breaks that bound (events lost to the sensor's rate ceiling,
        # say), re-anchor at the bound instead of keeping a prediction the frame disproves.
        pred_s = self._propagate(w0[0], w0[1], s)
        over_dom = over >= 1.0 - frac - over
        with np.errstate(invalid="ignore"):
            bounded = ~ok & np.isfinite(log_anchor) & (
                ~np.isfinite(pred_s) | (over_dom & (pred_s < log_anchor)) | (~over_dom & (pred_s > log_anchor)))
        new = ok | bounded
        self.anchor_log[new] = log_anchor[new]
        self.anchor_t[new] = s
        self.anchor_on[new] = w0[0][new]
        self.anchor_off[new] = w0[1][new]
        self._wstate[w] = _FREE
        self.frames_seen += 1
        if not ok.all():
            self.frames_skipped += 1
        self.frames_bounded += int(bounded.any())
        return FrameEstimate(frame.sequence, s, e, log_pbar, log_e, log_anchor, frac, ok, over, bounded)

    def _propagate(self, counts_on: np.ndarray, counts_off: np.ndarray, t: int) -> np.ndarray:
        """Eq. 12 from each zone's anchor to time ``t`` with the given cumulative counts (NaN if unanchored)."""
        c_on, c_off, a_on, b_on, a_off, b_off = self._kp
        m_on = (counts_on - self.anchor_on) * self._inv_n
        m_off = (counts_off - self.anchor_off) * self._inv_n
        u = (t - self.anchor_t).astype(np.float64)
        comp_on = np.maximum(0.0, a_on * m_on - b_on * u)
        comp_off = np.maximum(0.0, a_off * m_off - b_off * u)
        return self.anchor_log + c_on * (m_on + comp_on) - c_off * (m_off + comp_off)

    def _whole_frame_log_irradiance(self, frame: Frame) -> tuple[float, float, float]:
        """Scalar :meth:`frame_log_irradiance` for the single whole-sensor zone."""
        crf = self.crf
        z = frame.image.ravel()
        log_tk = math.log(frame.exposure_us / US_PER_S) + math.log(frame.gain)
        if self.image_form == "paper":
            total, nv, no = image_stats(z, crf.valid_min, crf.valid_max)
            mean = total / z.size
            i = min(int(mean), 254)
            g_mean = crf.g[i] + (crf.g[i + 1] - crf.g[i]) * (mean - i)
            return float(g_mean) - log_tk, nv / z.size, no / z.size
        full = np.bincount(z, minlength=256)
        hist = full[crf.valid_min : crf.valid_max + 1]
        nv = int(hist.sum())
        over = int(full[crf.valid_max + 1 :].sum()) / z.size
        if nv == 0:
            # no valid pixel: the clipped mean still bounds the irradiance (see add_frame)
            mean = float(z.mean())
            i = min(int(mean), 254)
            return float(crf.g[i] + (crf.g[i + 1] - crf.g[i]) * (mean - i)) - log_tk, 0.0, over
        return float(np.dot(hist, crf.g[crf.valid_min : crf.valid_max + 1])) / nv - log_tk, nv / z.size, over

    def feed(self, packet) -> FrameEstimate | None:
        """Dispatch one stream packet: an event array, an :class:`ExposureMarker` or a :class:`Frame`."""
        if isinstance(packet, np.ndarray):
            self.update(packet)
        elif isinstance(packet, ExposureMarker):
            (self.begin_exposure if packet.kind == "start" else self.end_exposure)(packet.t_us)
        elif isinstance(packet, Frame):
            return self.add_frame(packet)
        elif not isinstance(packet, (ImuBatch, TriggerBatch)):  # IMU and triggers carry nothing P-TEDI uses
            raise StreamError(f"unknown packet type {type(packet).__name__}")
        return None

    # -- output -----------------------------------------------------------------------------
    @property
    def ready(self) -> bool:
        """True once at least one zone is anchored."""
        if self.num_zones == 1:  # asked on every event batch: skip the array round trip
            return math.isfinite(self.anchor_log[0])
        return bool(np.isfinite(self.anchor_log).any())

    def predict_zones(self, t_us: int | None = None) -> np.ndarray:
        """``ln P(t)`` per zone (Eq. 12 with the compensation); NaN for zones never anchored.

        Uses every event processed so far; ``t_us`` (default: the last event time) enters the
        compensation term and must not precede a zone's anchor.
        """
        t = self.last_event_us if t_us is None else int(t_us)
        anchored = np.isfinite(self.anchor_log)
        if np.any(anchored & (t < self.anchor_t)):
            raise ParameterError(f"prediction time {t} µs precedes the anchor at {int(self.anchor_t[anchored].max())} µs")
        return self._propagate(self.counts_on, self.counts_off, t)

    def predict(self, t_us: int | None = None) -> float:
        """Mean log irradiance ``ln P(t)`` over the anchored zones, weighted by their pixel counts."""
        if self.num_zones == 1:  # scalar path: the controller calls this on every event batch
            if not math.isfinite(self.anchor_log[0]):
                raise NotAnchoredError("P-TEDI has no anchor yet: no usable frame has arrived")
            t = self.last_event_us if t_us is None else int(t_us)
            g = int(self.anchor_t[0])
            if t < g:
                raise ParameterError(f"prediction time {t} µs precedes the anchor at {g} µs")
            inv = self._inv_n0
            counts = self._counts2.tolist()
            m_on = (counts[0] - int(self.anchor_on[0])) * inv
            m_off = (counts[1] - int(self.anchor_off[0])) * inv
            # the kernel's Python form: called from Python, it skips Numba's dispatch
            return float(self.anchor_log[0]) + _direct_integral_py(1.0, float(t - g), m_on, m_off, *self._kp)
        z = self.predict_zones(t_us)
        ok = np.isfinite(z)
        if not ok.any():
            raise NotAnchoredError("P-TEDI has no anchor yet: no usable frame has arrived")
        wts = self.sizes[ok]
        return float(np.dot(z[ok], wts) / wts.sum())
