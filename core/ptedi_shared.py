"""P-TEDI's compensated event side, shared by the estimators of one rig's lanes.

The per-pixel bookkeeping of the TEDI compensation (:mod:`necviz.core.ptedi_comp`) depends only on the
events, the thresholds, the region and the *reference times* (an exposure start, an anchor) — not on the
camera or the controller. The lanes of a :class:`~necviz.drivers.sim.rig.SimRig` see the same events, use
the same thresholds and start their exposures at the same times, so one :class:`EventSide` keeps it for
all of them: per pixel, its ON/OFF counts since each *slot* (a reference time some lane needs: an exposure
start, which later becomes an anchor), with per slot and zone the count histograms, the levels and the
exact sums ``K``, ``S``, and, while a lane's exposure from that start is open, the exposure integral. Each
estimator (a *member*) keeps only what is its own — which slot each zone is anchored on, ``ln P`` there,
its exposure windows and their integrals from the slot's at its own exposure end.

Per event the work is O(live slots) (about two for a rig: the latest exposure start and the anchor most
lanes share) instead of O(2 x lanes), and one pixel row instead of one per lane. Every estimate is the
one a stand-alone estimator gives, bit for bit: the slot's integer state is the same, and the exposure
integral is the same sequence of floating-point operations (the pieces up to the last event before the
lane's exposure end, then its closing piece, computed on copies of the slot's levels).

Members are fed in lock step: every member receives every event batch (the pipeline feeds each lane the
same array); the first member to receive a batch applies it, the others only note that they have seen
it. A member whose thresholds change (live tuning) leaves the side and continues on its own
(:meth:`EventSide.detach`), with the state it would have had.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from necviz.core.errors import EventFormatError, ParameterError, StreamError
from necviz.core.ptedi_comp import (
    _comp_sweep,
    _comp_window_integral,
    _one_window_integral,
    comp_between,
    comp_restate,
    comp_sums,
)

__all__ = ["EventSide", "share_event_side"]


@nb.njit(cache=True)
def side_update(
    t,
    x,
    y,
    p,
    zflat,
    whole,
    width,
    height,
    last_t,
    counts_on,
    counts_off,
    inv_n,
    pc,
    live,
    integ,
    hist,
    lev,
    kk,
    ss,
    start_t,
    c0_on,
    c0_off,
    w_last,
    w_int,
    c_on,
    c_off,
    a_on,
    b_on,
    a_off,
    b_off,
):
    """Apply an event batch to every live slot of an :class:`EventSide` (Eq. 11 with the Eq. 6 terms per
    pixel, as :func:`necviz.core.ptedi_comp.ptedi_update_comp`, for any number of references).

    ``live``: the slot positions (1..M) to update; slot ``s`` keeps its pixels' counts in ``pc`` columns
    ``2 (s - 1) + q``; ``integ[s]``: an exposure from the slot's start is open (its integral runs). Per
    event and live slot: the slot's exposure integral up to the event when it runs (the same operations as
    the stand-alone kernels), then the O(1) update of its histogram, ``K`` and ``S``; at the batch end
    the levels of the live slots not integrating follow time. O(live slots) per event plus the levels crossed.

    Returns ``(index, code, last time)``: code 0 all applied, 1 time decreased, 2 coordinates off the
    sensor, 3 a histogram is full (grow it and resume at ``index``).
    """
    r_on = a_on / b_on if b_on > 0.0 else math.inf
    r_off = a_off / b_off if b_off > 0.0 else math.inf
    cap = hist.shape[3]
    ns = live.shape[0]
    prev = last_t
    stop = -1
    code = 0
    for i in range(t.shape[0]):
        ti = t[i]
        if ti < prev:
            stop = i
            code = 1
            break
        xi = np.int64(x[i])
        yi = np.int64(y[i])
        if xi >= width or yi >= height:
            stop = i
            code = 2
            break
        pix = yi * width + xi
        z = 0 if whole else zflat[pix]
        if z < 0:
            prev = ti
            continue
        q = 0 if p[i] > 0 else 1
        full = False
        for j in range(ns):
            if np.int64(pc[pix, 2 * (live[j] - 1) + q]) + 2 > cap:
                full = True
        if full:
            stop = i
            code = 3
            break
        prev = ti
        for j in range(ns):
            s = live[j]
            if integ[s]:
                last = w_last[s, z]
                if ti > last:
                    m_on = (counts_on[z] - c0_on[s, z]) * inv_n[z]
                    m_off = (counts_off[z] - c0_off[s, z]) * inv_n[z]
                    if (kk[s, 0, z] == 0 or not a_on > 0.0) and (kk[s, 1, z] == 0 or not a_off > 0.0):
                        w_int[s, z] += math.exp(c_on * m_on - c_off * m_off) * float(ti - last)
                    else:  # the slot seen as reference 1 of a two-slot view (the stand-alone kernels' layout)
                        w_int[s, z] += _comp_window_integral(
                            float(last - start_t[s]),
                            float(ti - start_t[s]),
                            z,
                            m_on,
                            m_off,
                            inv_n[z],
                            hist[s - 1 : s + 1],
                            lev[s - 1 : s + 1],
                            kk[s - 1 : s + 1],
                            ss[s - 1 : s + 1],
                            c_on,
                            c_off,
                            a_on,
                            b_on,
                            a_off,
                            b_off,
                            r_on,
                            r_off,
                        )
                    w_last[s, z] = ti
            col = 2 * (s - 1) + q
            n = np.int64(pc[pix, col])
            hist[s, q, z, n] -= 1
            hist[s, q, z, n + 1] += 1
            lv = lev[s, q, z]
            if n + 1 > lv:
                if n > lv:
                    ss[s, q, z] += 1
                else:
                    kk[s, q, z] += 1
                    ss[s, q, z] += n + 1
            pc[pix, col] = n + 1
        if q == 0:
            counts_on[z] += 1
        else:
            counts_off[z] += 1
    for j in range(ns):  # the levels of the live slots follow time, once per batch
        s = live[j]
        if not integ[s] and prev >= start_t[s]:  # (an integrating slot's advance with its integral only,
            # zone by zone, as a stand-alone window's: a sweep would skip breakpoints a zone integrates later)
            u = float(prev - start_t[s])
            for z in range(counts_on.shape[0]):
                if a_on > 0.0:
                    _comp_sweep(hist, s, 0, z, lev, kk, ss, r_on, u)
                if a_off > 0.0:
                    _comp_sweep(hist, s, 1, z, lev, kk, ss, r_off, u)
    return stop, code, prev


@nb.njit(cache=True)
def side_update_one(
    t,
    x,
    y,
    p,
    zflat,
    whole,
    width,
    height,
    last_t,
    counts_on,
    counts_off,
    inv_n,
    pc,
    live,
    ws,
    hist,
    lev,
    kk,
    ss,
    start_t,
    c0_on,
    c0_off,
    w_last,
    w_int,
    c_on,
    c_off,
    a_on,
    b_on,
    a_off,
    b_off,
):
    """:func:`side_update` for one zone with at most one integrating slot ``ws`` (0: none) — the lanes of a rig
    start their exposures together — whose levels, sums and integral are kept in local variables during the
    batch (as :func:`~necviz.core.ptedi_comp.ptedi_update_comp_one` keeps its window's), through the same
    floating-point operations as :func:`side_update`, so the same state bit for bit. Returns what it returns.
    """
    r_on = a_on / b_on if b_on > 0.0 else math.inf
    r_off = a_off / b_off if b_off > 0.0 else math.inf
    cap = hist.shape[3]
    ns = live.shape[0]
    n_on = counts_on[0]
    n_off = counts_off[0]
    inv = inv_n[0]
    live_on = a_on > 0.0
    live_off = a_off > 0.0
    wcol = 2 * (ws - 1)
    h1_on = hist[ws, 0, 0]
    h1_off = hist[ws, 1, 0]
    l1_on, l1_off, k1_on, k1_off, s1_on, s1_off = (
        lev[ws, 0, 0],
        lev[ws, 1, 0],
        kk[ws, 0, 0],
        kk[ws, 1, 0],
        ss[ws, 0, 0],
        ss[ws, 1, 0],
    )
    wl = w_last[ws, 0]
    wi = w_int[ws, 0]
    w_start = start_t[ws]
    b_on0 = c0_on[ws, 0]
    b_off0 = c0_off[ws, 0]
    prev = last_t
    stop = -1
    code = 0
    for i in range(t.shape[0]):
        ti = t[i]
        if ti < prev:
            stop = i
            code = 1
            break
        xi = np.int64(x[i])
        yi = np.int64(y[i])
        if xi >= width or yi >= height:
            stop = i
            code = 2
            break
        pix = yi * width + xi
        if not whole and zflat[pix] < 0:
            prev = ti
            continue
        on = p[i] > 0
        q = 0 if on else 1
        full = False
        for j in range(ns):
            if np.int64(pc[pix, 2 * (live[j] - 1) + q]) + 2 > cap:
                full = True
        if full:
            stop = i
            code = 3
            break
        prev = ti
        if ws > 0:
            if ti > wl:
                m_on = (n_on - b_on0) * inv
                m_off = (n_off - b_off0) * inv
                if (k1_on == 0 or not live_on) and (k1_off == 0 or not live_off):
                    wi += math.exp(c_on * m_on - c_off * m_off) * float(ti - wl)
                else:
                    piece, l1_on, k1_on, s1_on, l1_off, k1_off, s1_off = _one_window_integral(
                        float(wl - w_start),
                        float(ti - w_start),
                        m_on,
                        m_off,
                        inv,
                        h1_on,
                        h1_off,
                        l1_on,
                        k1_on,
                        s1_on,
                        l1_off,
                        k1_off,
                        s1_off,
                        c_on,
                        c_off,
                        a_on,
                        b_on,
                        a_off,
                        b_off,
                        r_on,
                        r_off,
                    )
                    wi += piece
                wl = ti
            n = np.int64(pc[pix, wcol + q])
            pc[pix, wcol + q] = n + 1
            if on:
                h1_on[n] -= 1
                h1_on[n + 1] += 1
                if n + 1 > l1_on:
                    if n > l1_on:
                        s1_on += 1
                    else:
                        k1_on += 1
                        s1_on += n + 1
            else:
                h1_off[n] -= 1
                h1_off[n + 1] += 1
                if n + 1 > l1_off:
                    if n > l1_off:
                        s1_off += 1
                    else:
                        k1_off += 1
                        s1_off += n + 1
        for j in range(ns):
            s = live[j]
            if s == ws:
                continue
            col = 2 * (s - 1) + q
            n = np.int64(pc[pix, col])
            hist[s, q, 0, n] -= 1
            hist[s, q, 0, n + 1] += 1
            lv = lev[s, q, 0]
            if n + 1 > lv:
                if n > lv:
                    ss[s, q, 0] += 1
                else:
                    kk[s, q, 0] += 1
                    ss[s, q, 0] += n + 1
            pc[pix, col] = n + 1
        if on:
            n_on += 1
        else:
            n_off += 1
    counts_on[0] = n_on
    counts_off[0] = n_off
    if ws > 0:
        lev[ws, 0, 0], lev[ws, 1, 0], kk[ws, 0, 0], kk[ws, 1, 0], ss[ws, 0, 0], ss[ws, 1, 0] = (
            l1_on,
            l1_off,
            k1_on,
            k1_off,
            s1_on,
            s1_off,
        )
        w_last[ws, 0] = wl
        w_int[ws, 0] = wi
    for j in range(ns):  # the levels of the live slots not integrating follow time, once per batch
        s = live[j]
        if s != ws and prev >= start_t[s]:
            u = float(prev - start_t[s])
            if a_on > 0.0:
                _comp_sweep(hist, s, 0, 0, lev, kk, ss, r_on, u)
            if a_off > 0.0:
                _comp_sweep(hist, s, 1, 0, lev, kk, ss, r_off, u)
    return stop, code, prev


class EventSide:
    """The compensated event side of P-TEDI for estimators that share their events (see the module docstring).

    Parameters
    ----------
    sensor, zmap, sizes : the members' pixel array, zone map and zone sizes (all members equal).
    params : the members' thresholds and compensation (``a+`` or ``a-`` > 0).
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

    def _grow_slots(self) -> None:
        """Twice the slots (a rig whose lanes anchor on many different starts)."""
        old_m = len(self.refs) - 1
        keep = {name: getattr(self, name) for name in ("pc", "hist", "lev", "kk", "ss", "start_t", "c0_on", "c0_off")}
        keep.update(w_last=self.w_last, w_int=self.w_int, integ=self.integ)
        refs, opens, made = self.refs, self.opens, self.made_at
        cap = self.hist.shape[3]
        self._alloc(2 * old_m)
        if cap > self.hist.shape[3]:
            self.hist = np.zeros(self.hist.shape[:3] + (cap,), np.int32)
        if keep["pc"].dtype != self.pc.dtype:
            self.pc = self.pc.astype(keep["pc"].dtype)
        self.pc[:, : 2 * old_m] = keep.pop("pc")
        for name, arr in keep.items():
            getattr(self, name)[: old_m + 1] = arr
        self.hist[old_m + 1 :, :, :, 0] = self.sizes
        self.refs[: old_m + 1], self.opens[: old_m + 1], self.made_at[: old_m + 1] = refs, opens, made

    def _grow_hist(self, need: int) -> None:
        cap = self.hist.shape[3]
        if need < cap:
            return
        size = max(2 * cap, need + 1)
        if self.pc.dtype == np.uint16 and size > np.iinfo(np.uint16).max + 1:
            self.pc = self.pc.astype(np.int32)
        new = np.zeros(self.hist.shape[:3] + (size,), np.int32)
        new[..., :cap] = self.hist
        self.hist = new

    def _words(self) -> np.ndarray:
        return self.pc.view(np.uint32 if self.pc.itemsize == 2 else np.uint64)

    def acquire_start(self, t_us: int) -> int:
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
        self.refs[s] += 1

    def release(self, s: int) -> None:
        if s > 0:
            self.refs[s] -= 1
            if self.refs[s] == 0:
                self.made_at[s] = -1
                self.opens[s] = 0
                self.integ[s] = False

    def counts(self, s: int) -> np.ndarray:
        """Per pixel, the ON/OFF counts since slot ``s``'s start (a view)."""
        return self.pc[:, 2 * (s - 1) : 2 * s]

    # -- what members call ------------------------------------------------------------------------------
    def update(self, member, events: np.ndarray) -> None:
        """Member ``member`` received ``events``: apply them if no member has (in lock step, see the module docstring)."""
        if member._seen == self.batches:
            self._apply(events)
            self._last_batch = events
            self.batches += 1
        elif member._seen != self.batches - 1 or events is not self._last_batch:
            raise StreamError(
                "estimators sharing their event side must each receive every event batch, in the same order "
                "(the lanes of one source)"
            )
        member._seen += 1
        member.last_event_us = self.last_event_us

    def _apply(self, events: np.ndarray) -> None:
        t, x, y, p = events["t"], events["x"], events["y"], events["p"]
        pos, last = 0, self.last_event_us
        live = np.array([s for s in range(1, len(self.refs)) if self.refs[s] > 0], np.int64)
        integ = [s for s in live.tolist() if self.integ[s]]
        one = self.sizes.size == 1 and len(integ) <= 1  # the usual case: one zone, the lanes' common start
        while True:
            kernel, arg = (side_update_one, integ[0] if integ else 0) if one else (side_update, self.integ)
            stop, code, last = kernel(
                t[pos:],
                x[pos:],
                y[pos:],
                p[pos:],
                self.zflat,
                self.whole,
                self.sensor.width,
                self.sensor.height,
                last,
                self.counts_on,
                self.counts_off,
                self.inv_n,
                self.pc,
                live,
                arg,
                self.hist,
                self.lev,
                self.kk,
                self.ss,
                self.start_t,
                self.c0_on,
                self.c0_off,
                self.w_last,
                self.w_int,
                *self.kp,
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
        ev = events[bad]
        if code == 1:
            raise EventFormatError(
                f"event {bad} of the batch at {int(ev['t'])} µs is earlier than events already processed "
                f"({before} µs); the {bad} events before it were applied"
            )
        raise EventFormatError(
            f"event {bad} of the batch at (x={int(ev['x'])}, y={int(ev['y'])}) lies outside the "
            f"{self.sensor.width}x{self.sensor.height} sensor; the {bad} events before it were applied"
        )

    def begin(self, member, w: int, t_us: int) -> None:
        """Member window ``w`` starts at ``t_us``."""
        s = self.acquire_start(t_us)
        member._wslot[w] = s
        self.opens[s] += 1
        self.integ[s] = True

    def end(self, member, w: int, t_us: int) -> None:
        """Member window ``w`` ends at ``t_us``: its integral is the slot's so far plus the closing piece
        (computed on copies of the slot's levels, as :func:`~necviz.core.ptedi_comp.ptedi_close_comp` would)."""
        s = member._wslot[w]
        c_on, c_off, a_on, b_on, a_off, b_off = self.kp
        r_on = a_on / b_on if b_on > 0.0 else math.inf
        r_off = a_off / b_off if b_off > 0.0 else math.inf
        for z in range(self.sizes.size):
            m_on = (self.counts_on[z] - self.c0_on[s, z]) * self.inv_n[z]
            m_off = (self.counts_off[z] - self.c0_off[s, z]) * self.inv_n[z]
            piece = _comp_window_integral(
                float(self.w_last[s, z] - self.start_t[s]),
                float(t_us - self.start_t[s]),
                z,
                m_on,
                m_off,
                self.inv_n[z],
                self.hist[s - 1 : s + 1],
                self.lev[s - 1 : s + 1].copy(),
                self.kk[s - 1 : s + 1].copy(),
                self.ss[s - 1 : s + 1].copy(),
                c_on,
                c_off,
                a_on,
                b_on,
                a_off,
                b_off,
                r_on,
                r_off,
            )
            member._wint[w, z] = self.w_int[s, z] + piece
            member._wlast[w, z] = t_us
        self.opens[s] -= 1
        self.integ[s] = self.opens[s] > 0

    def drop_window(self, member, w: int) -> None:
        """Member window ``w`` is recycled or its frame came: it no longer needs its slot (as a window)."""
        s = member._wslot[w]
        if s > 0:
            member._wslot[w] = 0
            self.release(s)

    def anchor(self, member, w: int, zones: np.ndarray, s_us: int) -> None:
        """Zones ``zones`` of ``member`` re-anchor on its window ``w``: they now use that window's slot."""
        s = member._wslot[w]
        old = member._aslot.copy()
        for z in zones:
            member._aslot[z] = s
        for a in set(member._aslot.tolist()):  # the member holds each slot its zones use once
            if a > 0 and a not in old:
                self.hold(a)
        for a in set(old.tolist()):
            if a > 0 and a not in member._aslot:
                self.release(a)
        flags = np.zeros(self.sizes.size, np.bool_)
        flags[zones] = True
        _, _, a_on, b_on, a_off, b_off = self.kp
        if not self.integ[s]:  # an integrating slot's levels advance with its integral (see side_update)
            u = np.full(self.sizes.size, float(max(0, self.last_event_us - s_us)))
            comp_restate(self.hist, s, flags, u, self.lev, self.kk, self.ss, a_on, b_on, a_off, b_off)

    def sums(self, member, u: np.ndarray) -> np.ndarray:
        """Per zone ``Σ_x max(0, a± n±_x - b± u)`` over the counts since each zone's anchor (as
        :func:`~necviz.core.ptedi_comp.comp_sums` on a stand-alone estimator's reference 0)."""
        _, _, a_on, b_on, a_off, b_off = self.kp
        k = self.sizes.size
        out = np.zeros((2, k))
        for a in set(member._aslot.tolist()):
            if a <= 0:
                continue
            part = np.empty((2, k))
            comp_sums(self.hist, self.lev, self.kk, self.ss, a, u, a_on, b_on, a_off, b_off, part)
            sel = member._aslot == a
            out[:, sel] = part[:, sel]
        return out

    def between(self, member, w: int, u: np.ndarray) -> np.ndarray:
        """Per zone ``Σ_x max(0, a± n±_x - b± u)`` for the counts between each zone's anchor and window ``w``'s
        start: the anchor slot's counts minus the window slot's (:func:`~necviz.core.ptedi_comp.comp_between`)."""
        _, _, a_on, b_on, a_off, b_off = self.kp
        k = self.sizes.size
        sw = member._wslot[w]
        out = np.zeros((2, k))
        base = np.zeros((self.pc.shape[0], 4), np.int64)  # comp_between subtracts columns 2, 3
        base[:, 2:4] = self.counts(sw)
        for a in set(member._aslot.tolist()):
            part = np.empty((2, k))
            counts = self.counts(a) if a > 0 else base[:, 2:4]  # never anchored: nothing between
            comp_between(base, counts, self.zflat, np.asarray(u, np.float64), a_on, b_on, a_off, b_off, part)
            sel = member._aslot == a
            out[:, sel] = part[:, sel]
        return out

    def detach(self, member) -> None:
        """``member`` continues on its own (its thresholds change): its stand-alone per-pixel state, histograms
        and window integrals are built from the slots it uses, and it releases them."""
        npix = self.pc.shape[0]
        k = self.sizes.size
        member._pc = np.zeros((npix, 4), self.pc.dtype)
        member._hist = np.zeros((2, 2, k, self.hist.shape[3]), np.int32)
        member._hist[:, :, :, 0] = self.sizes
        member._lev = np.zeros((2, 2, k), np.int64)
        member._kk = np.zeros((2, 2, k), np.int64)
        member._ss = np.zeros((2, 2, k), np.int64)
        for z in range(k):
            a = int(member._aslot[z])
            if a > 0:
                pix = self.zflat == z
                member._pc[pix, 0:2] = self.counts(a)[pix]
                member._hist[0, :, z] = self.hist[a, :, z]
                member._lev[0, :, z], member._kk[0, :, z], member._ss[0, :, z] = (
                    self.lev[a, :, z],
                    self.kk[a, :, z],
                    self.ss[a, :, z],
                )
        latest = member._latest
        sl = member._wslot[latest] if latest >= 0 else 0
        member._wsnap, member._wacc = None, [False] * len(member._wstate)
        if sl > 0:
            member._iw = 2
            member._pc[:, 2:4] = self.counts(sl)
            member._hist[1] = self.hist[sl]
            member._lev[1], member._kk[1], member._ss[1] = self.lev[sl], self.kk[sl], self.ss[sl]
            if member._open == latest:
                member._wint[latest] = self.w_int[sl]
                member._wlast[latest] = self.w_last[sl]
            for v, st in enumerate(member._wstate):  # windows awaiting their frame: counts up to the latest start
                sv = member._wslot[v]
                if v != latest and sv > 0 and st != 0:
                    if member._wsnap is None:
                        member._wsnap = np.zeros((len(member._wstate), npix, 2), np.int32)
                    member._wsnap[v] = self.counts(sv).astype(np.int32) - self.counts(sl)
                    member._wacc[v] = True
        else:
            member._iw = -1
        for v in range(len(member._wslot)):
            self.drop_window(member, v)
        for a in set(member._aslot.tolist()):
            if a > 0:
                self.release(a)
        member._aslot[:] = 0
        member.counts_on = self.counts_on.copy()
        member.counts_off = self.counts_off.copy()
        if k == 1:  # the stand-alone whole-sensor layout: zone counts are views into _counts2
            member._counts2[:] = (member.counts_on[0], member.counts_off[0])
            member.counts_on, member.counts_off = member._counts2[0:1], member._counts2[1:2]
        member._side = None


def share_event_side(estimators) -> list:
    """Let the compensated estimators in ``estimators`` that see the same events with the same thresholds
    and region share one :class:`EventSide` per such group (fresh estimators only: before any packet).
    Returns the sides made. Estimators without compensation, or alone in their group, stay as they are."""
    groups: dict = {}
    for est in estimators:
        if est is None or getattr(est, "_side", None) is not None or not getattr(est, "_comp", False):
            continue
        if est.frames_seen or est.last_event_us != np.iinfo(np.int64).min or est._open >= 0:
            continue  # already fed: its state is its own
        key = (est.sensor.width, est.sensor.height, est.params.as_tuple(), est.zmap.tobytes())
        groups.setdefault(key, []).append(est)
    sides = []
    for members in groups.values():
        if len(members) < 2:
            continue
        first = members[0]
        side = EventSide(first.sensor, first.zmap, first.sizes, first.params)
        for est in members:
            est.share_events(side)
        sides.append(side)
    return sides
