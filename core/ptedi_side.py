"""P-TEDI's compensated event side: the per-pixel bookkeeping of the TEDI compensation, one object.

The per-pixel bookkeeping of the TEDI compensation (:mod:`necviz.core.ptedi_comp`) depends only on the
events, the thresholds, the region and the *reference times* (an exposure start, an anchor) — not on the
camera or the controller. An :class:`EventSide` keeps it: per pixel, its ON/OFF counts since each *slot* (a
reference time some estimator needs: an exposure start, which later becomes an anchor), with per slot and
zone the count histograms, the levels and the exact sums ``K``, ``S``, and, while an exposure from that start
is open, the exposure integral. Every compensated :class:`~necviz.core.ptedi.PeripheralEstimator` (a
*member*) uses one; it keeps only what is its own — which slot each zone is anchored on, ``ln P`` there, its
exposure windows and their integrals taken from the slot's at its own exposure end.

A stand-alone estimator is the member of a side of its own. The lanes of a
:class:`~necviz.drivers.sim.rig.SimRig` see the same events, use the same thresholds and start their exposures
at the same times, so they share one side (:func:`necviz.core.ptedi_shared.share_event_side`): per event the
work is O(live slots) (about two: the latest exposure start and the anchor most lanes share) instead of
O(2 x lanes), and one pixel row instead of one per lane. Every estimate is the one a side of its own gives,
bit for bit: the slot's integer state is the same, and the exposure integral is the same sequence of
floating-point operations (the pieces up to the last event before the member's exposure end, then its
closing piece, computed on copies of the slot's levels).

The interface (all a member calls; the side never reads or writes a member):

- :meth:`EventSide.update` — an event batch (members in lock step: the first to receive a batch applies it,
  the others only note that they have seen it);
- :meth:`EventSide.begin`, :meth:`EventSide.end` — an exposure's start (its slot) and end (its integral);
- :meth:`EventSide.hold`, :meth:`EventSide.release` — a member's uses of a slot (a window, an anchor);
- :meth:`EventSide.anchor` — zones re-anchor on a slot;
- :meth:`EventSide.sums`, :meth:`EventSide.between` — the compensation sums since each zone's anchor, and
  between the anchor and an exposure start;
- :meth:`EventSide.set_thresholds`, :meth:`EventSide.set_params`, :meth:`EventSide.split` — live tuning: the
  contrast thresholds of every member at once, or one member's own parameters on a copy of its slots.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from necviz.core.errors import EventFormatError, ParameterError, StreamError
from necviz.core.ptedi_comp import comp_between, comp_restate, comp_sums, side_close, side_update, side_update_one

__all__ = ["EventSide", "batch_error"]


def batch_error(events: np.ndarray, bad: int, before: int, sensor) -> EventFormatError:
    """The one-line error for event ``bad`` of a batch, which an event loop stopped at: earlier than
    ``before`` (the last time applied), or off the ``sensor``; the events before it were applied."""
    ev = events[bad]
    if int(ev["t"]) < before:
        return EventFormatError(
            f"event {bad} of the batch at {int(ev['t'])} µs is earlier than events already processed "
            f"({before} µs); the {bad} events before it were applied"
        )
    return EventFormatError(
        f"event {bad} of the batch at (x={int(ev['x'])}, y={int(ev['y'])}) lies outside the "
        f"{sensor.width}x{sensor.height} sensor; the {bad} events before it were applied"
    )


class EventSide:
    """The compensated event side of P-TEDI (see the module docstring).

    Parameters
    ----------
    sensor, zmap, sizes : the members' pixel array, zone map and zone sizes (all members equal).
    params : the members' thresholds and compensation (``a+`` or ``a-`` > 0).
    slots : reference times room is made for at first (more are added when needed).
    """

    def __init__(self, sensor, zmap: np.ndarray, sizes: np.ndarray, params, slots: int = 4):
        if not (params.a_on > 0.0 or params.a_off > 0.0):
            raise ParameterError("an event side is for compensated P-TEDI (a+ or a- > 0)")
        self.sensor = sensor
        self.zmap = zmap
        self.zflat = zmap.ravel()
        self.whole = bool(np.all(self.zmap == 0))
        self.sizes = sizes
        self.params = params
        self.kp = params.as_tuple()
        k = sizes.size
        self.inv_n = 1.0 / sizes.astype(np.float64)
        self.counts_on = np.zeros(k, np.int64)
        self.counts_off = np.zeros(k, np.int64)
        self.last_event_us = np.iinfo(np.int64).min
        self.batches = 0
        self.events = 0
        self.members: list = []  # the estimators using this side (their thresholds are this side's)
        self._last_batch: np.ndarray | None = None
        self._alloc(slots)

    # -- slots ------------------------------------------------------------------------------------------
    def _alloc(self, m: int) -> None:
        k = self.sizes.size
        npix = self.sensor.width * self.sensor.height
        self.pc = np.zeros((npix, 2 * m), np.uint16)
        self.hist = np.zeros((m + 1, 2, k, 64), np.int32)  # position 0 unused: slot s is at position s
        self.hist[:, :, :, 0] = self.sizes
        self.lev = np.zeros((m + 1, 2, k), np.int64)
        self.kk = np.zeros((m + 1, 2, k), np.int64)
        self.ss = np.zeros((m + 1, 2, k), np.int64)
        self.start_t = np.zeros(m + 1, np.int64)
        self.c0_on = np.zeros((m + 1, k), np.int64)
        self.c0_off = np.zeros((m + 1, k), np.int64)
        self.w_last = np.zeros((m + 1, k), np.int64)
        self.w_int = np.zeros((m + 1, k), np.float64)
        self.integ = np.zeros(m + 1, np.bool_)
        self.refs = [0] * (m + 1)  # members' uses of each slot (windows and anchors)
        self.opens = [0] * (m + 1)  # members' open exposures on each slot
        self.made_at = [-1] * (m + 1)  # events processed when each slot started (-1: free)

    _SLOT_ARRAYS = ("hist", "lev", "kk", "ss", "start_t", "c0_on", "c0_off", "w_last", "w_int", "integ")

    def _grow_slots(self) -> None:
        """Twice the slots (estimators that anchor on many different starts)."""
        old_m = len(self.refs) - 1
        keep = {name: getattr(self, name) for name in self._SLOT_ARRAYS}
        pc, refs, opens, made = self.pc, self.refs, self.opens, self.made_at
        cap = self.hist.shape[3]
        self._alloc(2 * old_m)
        if cap > self.hist.shape[3]:
            self.hist = np.zeros(self.hist.shape[:3] + (cap,), np.int32)
        if pc.dtype != self.pc.dtype:
            self.pc = self.pc.astype(pc.dtype)
        self.pc[:, : 2 * old_m] = pc
        for name, arr in keep.items():
            getattr(self, name)[: old_m + 1] = arr
        self.hist[old_m + 1 :, :, :, 0] = self.sizes
        self.refs[: old_m + 1], self.opens[: old_m + 1], self.made_at[: old_m + 1] = refs, opens, made

    def _grow_hist(self, need: int) -> None:
        """Widen the count histograms to hold counts up to ``need`` (and the per-pixel counts to int32 before
        a count could pass what uint16 holds)."""
        cap = self.hist.shape[3]
        if need < cap:
            return
        size = max(2 * cap, need + 1)
        if self.pc.dtype == np.uint16 and size > np.iinfo(np.uint16).max + 1:
            self.pc = self.pc.astype(np.int32)
        new = np.zeros(self.hist.shape[:3] + (size,), np.int32)
        new[..., :cap] = self.hist
        self.hist = new

    @property
    def histogram_size(self) -> int:
        """Bins of each count histogram (grows with the largest per-pixel count since a live slot)."""
        return int(self.hist.shape[3])

    @property
    def count_dtype(self) -> np.dtype:
        """The per-pixel counts' type: uint16 until a count could pass what it holds, then int32."""
        return self.pc.dtype

    def live_slots(self) -> int:
        """Slots some member uses now (its windows and anchors)."""
        return sum(r > 0 for r in self.refs[1:])

    def _slots(self) -> tuple:
        """The per-slot arrays as the kernels take them (:mod:`necviz.core.ptedi_comp`'s bundles)."""
        return (self.hist, self.lev, self.kk, self.ss, self.start_t, self.c0_on, self.c0_off, self.w_last, self.w_int)

    def _words(self) -> np.ndarray:
        return self.pc.view(np.uint32 if self.pc.itemsize == 2 else np.uint64)

    def counts(self, s: int) -> np.ndarray:
        """Per pixel, the ON/OFF counts since slot ``s``'s start (a view)."""
        return self.pc[:, 2 * (s - 1) : 2 * s]

    def _acquire(self, t_us: int) -> int:
        """The slot of an exposure starting at ``t_us`` now: the one another member started at this very point
        of the stream (same time, no event since), else a new one (counts zeroed)."""
        for s in range(1, len(self.refs)):
            if self.made_at[s] == self.events and self.refs[s] > 0 and self.start_t[s] == t_us:
                self.refs[s] += 1
                return s
        free = [s for s in range(1, len(self.refs)) if self.refs[s] == 0]
        if not free:
            self._grow_slots()
            free = [s for s in range(1, len(self.refs)) if self.refs[s] == 0]
        s = free[0]
        self._words()[:, s - 1] = 0
        self.hist[s] = 0
        self.hist[s, :, :, 0] = self.sizes
        self.lev[s] = self.kk[s] = self.ss[s] = 0
        self.start_t[s] = t_us
        self.c0_on[s] = self.counts_on
        self.c0_off[s] = self.counts_off
        self.w_last[s] = t_us
        self.w_int[s] = 0.0
        self.refs[s] = 1
        self.opens[s] = 0
        self.integ[s] = False
        self.made_at[s] = self.events
        return s

    def hold(self, s: int) -> None:
        """One more use of slot ``s`` (a member's zones anchored on it)."""
        self.refs[s] += 1

    def release(self, s: int) -> None:
        """One use of slot ``s`` fewer (0: nothing); the last frees it."""
        if s > 0:
            self.refs[s] -= 1
            if self.refs[s] == 0:
                self.made_at[s] = -1
                self.opens[s] = 0
                self.integ[s] = False

    # -- the interface ----------------------------------------------------------------------------------
    def update(self, events: np.ndarray, seen: int) -> int:
        """A member that has seen ``seen`` batches received ``events``: apply them if no member has (lock
        step, see the module docstring). Returns the batches that member has now seen."""
        if seen == self.batches:
            self._apply(events)
            self._last_batch = events
            self.batches += 1
        elif seen != self.batches - 1 or events is not self._last_batch:
            raise StreamError(
                "estimators sharing their event side must each receive every event batch, in the same order "
                "(the lanes of one source)"
            )
        return seen + 1

    def _apply(self, events: np.ndarray) -> None:
        t, x, y, p = events["t"], events["x"], events["y"], events["p"]
        pos, last = 0, self.last_event_us
        live = np.array([s for s in range(1, len(self.refs)) if self.refs[s] > 0], np.int64)
        # the usual case, one zone and one or two live slots of which one integrates: side_update_one
        one = self.sizes.size == 1 and 0 < live.size <= 2 and int(self.integ[live].sum()) <= 1
        kernel = side_update_one if one else side_update
        while True:
            stop, code, last = kernel(
                (t[pos:], x[pos:], y[pos:], p[pos:]),
                self.zflat,
                self.whole,
                self.sensor.width,
                self.sensor.height,
                last,
                (self.counts_on, self.counts_off, self.inv_n),
                self.pc,
                live,
                self.integ,
                self._slots(),
                self.kp,
            )
            if code != 3:
                break
            pos += stop
            self._grow_hist(2 * self.hist.shape[3])
        done = events.size if code == 0 else pos + stop
        self.events += done
        if code == 0:
            self.last_event_us = int(t[-1])
            return
        bad = pos + stop
        before = int(t[bad - 1]) if bad > 0 else self.last_event_us
        self.last_event_us = before
        raise batch_error(events, bad, before, self.sensor)

    def begin(self, t_us: int) -> int:
        """An exposure starts at ``t_us``: its slot (held once for it; its integral runs)."""
        s = self._acquire(t_us)
        self.opens[s] += 1
        self.integ[s] = True
        return s

    def start_late(self, t_us: int, window: tuple | None = None) -> int:
        """A slot for a reference time ``t_us`` already past (the compensation switched on mid-stream): its
        counts run from now on. ``window``: an exposure from ``t_us`` is open, with its counts at the start,
        last integrated time and integral so far per zone ``(c0_on, c0_off, w_last, w_int)``."""
        s = self._acquire(t_us)
        self.made_at[s] = -2  # not the start of an exposure that begins now
        if window is not None:
            self.c0_on[s], self.c0_off[s], self.w_last[s], self.w_int[s] = window
            self.opens[s] = 1
            self.integ[s] = True
        return s

    def end(self, s: int, t_us: int) -> np.ndarray:
        """An exposure from slot ``s`` ends at ``t_us``: its integral per zone, the slot's so far plus the
        closing piece (computed on copies of the slot's levels)."""
        out = np.empty(self.sizes.size)
        side_close(t_us, s, (self.counts_on, self.counts_off, self.inv_n), self._slots(), self.kp, out)
        self.opens[s] -= 1
        self.integ[s] = self.opens[s] > 0
        return out

    def anchor(self, s: int, zones: np.ndarray, s_us: int) -> None:
        """Zones ``zones`` of a member re-anchor on slot ``s`` (started at ``s_us``): unless an exposure from
        it still integrates (its levels advance with the integral), their levels and sums are restated at the
        last event."""
        if not self.integ[s]:
            flags = np.zeros(self.sizes.size, np.bool_)
            flags[zones] = True
            self.restate(s, flags, np.full(self.sizes.size, float(max(0, self.last_event_us - s_us))))

    def restate(self, s: int, flags: np.ndarray, u: np.ndarray) -> None:
        """Levels and sums of slot ``s``'s flagged zones from their histograms at times ``u`` since its start."""
        _, _, a_on, b_on, a_off, b_off = self.kp
        comp_restate(
            self.hist, s, flags, np.asarray(u, np.float64), self.lev, self.kk, self.ss, a_on, b_on, a_off, b_off
        )

    def sums(self, aslot: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Per zone ``Σ_x max(0, a± n±_x - b± u)`` over the counts since each zone's anchor slot ``aslot[z]``
        (0: never anchored, 0)."""
        _, _, a_on, b_on, a_off, b_off = self.kp
        k = self.sizes.size
        out = np.zeros((2, k))
        for a in set(aslot.tolist()):
            if a <= 0:
                continue
            part = np.empty((2, k))
            comp_sums(self.hist, self.lev, self.kk, self.ss, a, u, a_on, b_on, a_off, b_off, part)
            sel = aslot == a
            out[:, sel] = part[:, sel]
        return out

    def between(self, aslot: np.ndarray, sw: int, u: np.ndarray) -> np.ndarray:
        """Per zone ``Σ_x max(0, a± n±_x - b± u)`` for the counts between each zone's anchor slot and slot
        ``sw``'s start: the anchor slot's counts minus ``sw``'s (:func:`~necviz.core.ptedi_comp.comp_between`).
        O(pixels)."""
        _, _, a_on, b_on, a_off, b_off = self.kp
        k = self.sizes.size
        out = np.zeros((2, k))
        base = np.zeros((self.pc.shape[0], 4), np.int64)  # comp_between subtracts columns 2, 3
        base[:, 2:4] = self.counts(sw)
        for a in set(aslot.tolist()):
            part = np.empty((2, k))
            counts = self.counts(a) if a > 0 else base[:, 2:4]  # never anchored: nothing between
            comp_between(base, counts, self.zflat, np.asarray(u, np.float64), a_on, b_on, a_off, b_off, part)
            sel = aslot == a
            out[:, sel] = part[:, sel]
        return out

    # -- live tuning --------------------------------------------------------------------------------------
    def set_thresholds(self, c_on: float, c_off: float):
        """The contrast thresholds of every member change to ``c_on``, ``c_off`` (the compensation ``a±, b±``
        stays: the levels and sums do not depend on the thresholds). Returns the new parameters (the caller
        hands them to the members)."""
        self.params = replace(self.params, c_on=float(c_on), c_off=float(c_off))
        self.kp = self.params.as_tuple()
        return self.params

    def set_params(self, params) -> None:
        """New thresholds and compensation (``a+`` or ``a-`` > 0) for a side with one member: the caller
        restates the slots it uses (:meth:`restate`)."""
        if not (params.a_on > 0.0 or params.a_off > 0.0):
            raise ParameterError("an event side is for compensated P-TEDI (a+ or a- > 0)")
        self.params = params
        self.kp = params.as_tuple()

    def split(self, slots: list[int], uses: list[int]) -> tuple[EventSide, dict[int, int]]:
        """A side of one member's own, with copies of ``slots`` (the slots it uses, ``uses[i]`` times each,
        ``0`` among them ignored) and this side's counts, last event and batches: what that member would have
        had on a side of its own. Returns the new side and the map from this side's slots to its."""
        own = [s for s in dict.fromkeys(slots) if s > 0]
        new = EventSide(self.sensor, self.zmap, self.sizes, self.params, slots=max(2, len(own)))
        if new.hist.shape[3] < self.hist.shape[3]:
            new.hist = np.zeros(new.hist.shape[:3] + (self.hist.shape[3],), np.int32)
            new.hist[:, :, :, 0] = self.sizes
        if new.pc.dtype != self.pc.dtype:
            new.pc = new.pc.astype(self.pc.dtype)
        where = {}
        for i, s in enumerate(own, start=1):
            where[s] = i
            new.pc[:, 2 * (i - 1) : 2 * i] = self.counts(s)
            for name in self._SLOT_ARRAYS:
                getattr(new, name)[i] = getattr(self, name)[s]
            new.refs[i] = uses[slots.index(s)]
            new.opens[i] = 0
            new.integ[i] = False
            new.made_at[i] = self.made_at[s] - self.events  # negative: never the start of a later exposure
        new.counts_on[:] = self.counts_on
        new.counts_off[:] = self.counts_off
        new.last_event_us = self.last_event_us
        return new, where
