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
- With compensation, per-pixel counts since the anchor and since the exposure start are kept
  (snapshots at each exposure start, O(pixels) per frame) with, per zone, a histogram of
  those counts and the exact integer sums ``K = #{n_x > L}``, ``S = Σ_{n_x > L} n_x`` at the
  level ``L = floor(u b/a)``, so ``C(u) = a S - b u K`` (see the notes above
  :func:`ptedi_update_comp`). Per event O(1) plus the levels crossed as time passes (at most
  ``b u/a`` per reference, and never more than the largest per-pixel count); between events
  the exponent is linear in ``u`` with breakpoints at multiples of ``a/b``, integrated exactly
  piece by piece.

Anchor rule: a zone is re-anchored only on a frame whose valid-pixel fraction (9..250) in
that zone is at least ``min_valid_fraction``; otherwise the zone keeps propagating from its
last good anchor with events (the paper's work-around for frames saturated by a change
during their exposure). Exception, the saturation bounds: even a badly clipped frame proves
something. With the paper's image form it always bounds ``ln Pbar`` from below (under-exposed
pixels counted as receiving nothing, over-exposed ones as at the top of the valid range — true
for a frame clipped at both ends too), and from above when essentially nothing is over-exposed;
the zone re-anchors at a bound the event-propagated prediction breaks
(:meth:`PeripheralEstimator.frame_bounds`, :meth:`PeripheralEstimator.add_frame`). The frame's
own ``g(mean Z)`` is *not* a bound when it is clipped at both ends (its mean is lowered at one
end and raised at the other), so it is never used as one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from .crf import US_PER_S, CameraResponse, default_davis346
from .errors import EventFormatError, FrameFormatError, NotAnchoredError, ParameterError, StreamError
from .event_model import TediParams, direct_integral, exp_linear_integral
from .events import EVENT_DTYPE
from .frames import ExposureMarker, Frame
from .imu import ImuBatch, TriggerBatch
from .regions import zone_map, zone_sizes
from .sensor import SensorGeometry

IMAGE_FORMS = ("paper", "mean_log")
_FREE, _OPEN, _CLOSED = 0, 1, 2


@nb.njit(cache=True)
def ptedi_update(
    t, x, y, p, zmap, last_t,
    counts_on, counts_off, inv_n, f_on, f_off,
    w, c0_on, c0_off, w_last, w_int, w_ebase,
):
    """Apply an event batch to the P-TEDI state of several zones, without compensation
    (``a± = 0``; Eq. 11 direct integral, Eq. 13 exposure integral).

    Per event: find its zone, and if exposure window ``w`` is open, add ``exp(c^T D_p(s, τ))``
    times the stretch since the zone's last event (the exponent is constant between events),
    then update the zone's counts and its running ``exp`` by a precomputed factor
    ``exp(±c/N_R)``. O(1) per event, O(zones) memory. Stops at the first event whose time
    decreases or whose coordinates lie off the zone map and returns its index (``-1`` when all
    were applied).
    """
    h, wd = zmap.shape
    prev = last_t
    for i in range(t.shape[0]):
        ti = t[i]
        if ti < prev:
            return i
        prev = ti
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
def ptedi_update_whole(t, p, last_t, counts, inv_n, g_tab, h_tab, w, c0, w_last, w_int, c_on, c_off):
    """:func:`ptedi_update` for a single zone covering the whole sensor (the default region).

    Same equations (Eq. 11 and the Eq. 13 integral, no compensation), arranged so no
    floating-point dependency chain runs through the events: within a block of ``B`` events
    starting with ``x_b = c^T D_p``, the integrand after ``i`` events of which ``a`` are ON is
    exactly ``exp(x_b) * G[i] * H[a]`` with ``G[i] = exp(-c- i / N)``,
    ``H[a] = exp((c+ + c-) a / N)``; ``exp(x_b)`` is recomputed from the integer counts at each
    block start (no drift), and the integral is split over four accumulators. Coordinates are
    never read. ``counts = [ON, OFF]``, ``c0 = [ON, OFF]`` at the window start. O(1) per event.
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
            for j in range(i, end):
                tj = t[j]
                if tj < prev:
                    bad = j
                    break
                prev = tj
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
def ptedi_close(t_end, counts_on, counts_off, inv_n, w, c0_on, c0_off, w_last, w_int, c_on, c_off):
    """Integrate every zone of window ``w`` from its last event to the exposure end (no
    compensation: the exponent is constant there). O(zones)."""
    for k in range(counts_on.shape[0]):
        m_on = (counts_on[k] - c0_on[w, k]) * inv_n[k]
        m_off = (counts_off[k] - c0_off[w, k]) * inv_n[k]
        w_int[w, k] += math.exp(c_on * m_on - c_off * m_off) * float(t_end - w_last[w, k])
        w_last[w, k] = t_end


# -- per-pixel TEDI compensation averaged over a zone (Eq. 11 with the Eq. 6 terms) -------------------
#
# For a reference time g (the anchor, or the open exposure's start) and u = t - g >= 0, pixel x
# with n_x events of one polarity since g contributes max(0, a n_x - b u) = a (n_x - u/r) while
# n_x > u/r, where r = a/b (µs per count). A pixel is "active" while n_x > L = floor(u/r)
# ("level" L); the zone's compensation sum is then
#
#     C(u) = Σ_x max(0, a n_x - b u) = a S - b u K,   K = #{n_x > L},  S = Σ_{n_x > L} n_x
#
# kept exactly in integers per (reference, polarity, zone) together with a histogram h[k] of the
# per-pixel counts. An event moves one pixel from k to k+1 (O(1) update of h, K, S); as u grows
# past (L+1) r the pixels with count L+1 stop being active (K -= h[L+1], S -= (L+1) h[L+1]).
# Between events C(u) is linear in u with breakpoints at multiples of r: the exposure integral
# is a sum of exp-of-linear pieces in closed form. Arrays: hist[ref, q, zone, k] (int32),
# lev/kk/ss[ref, q, zone] (int64) with ref 0 = anchor, 1 = open exposure; q 0 = ON, 1 = OFF.

MAX_LEVEL = 1 << 50  # levels beyond any per-pixel count (keeps u/r for a tiny r inside int64)


@nb.njit(cache=True)
def comp_level(u, r):
    """``floor(u / r)``: the count a pixel must exceed to be compensated at ``u`` (0 for ``r = inf``)."""
    if not r < math.inf:
        return 0
    q = u / r
    if q >= MAX_LEVEL:
        return MAX_LEVEL
    lv = np.int64(math.floor(q))
    while (lv + 1) * r <= u:
        lv += 1
    while lv > 0 and lv * r > u:
        lv -= 1
    return lv


@nb.njit(cache=True)
def _comp_sweep(hist, ref, q, z, lev, kk, ss, r, u):
    """Advance the level of ``(ref, q, z)`` to ``u`` (``u`` never decreases for a reference)."""
    target = comp_level(u, r)
    lv = lev[ref, q, z]
    if target <= lv:
        return
    k = kk[ref, q, z]
    s = ss[ref, q, z]
    while lv < target and k > 0:  # k > 0: some count exceeds lv, so lv + 1 < hist.shape[3]
        lv += 1
        hk = hist[ref, q, z, lv]
        k -= hk
        s -= lv * hk
    lev[ref, q, z] = target
    kk[ref, q, z] = k
    ss[ref, q, z] = s


@nb.njit(cache=True)
def _comp_window_integral(lo, hi, z, m_on, m_off, inv, hist, lev, kk, ss,
                          c_on, c_off, a_on, b_on, a_off, b_off, r_on, r_off):
    """``∫_lo^hi exp(c^T D_p(s, s+u)) du`` for zone ``z`` of the open window (ref 1), no events inside.

    ``c^T D_p = c+ (m+ + C+(u)/N) - c- (m- + C-(u)/N)`` with the per-pixel compensation sums
    ``C±(u) = a± S± - b± u K±``; the levels advance to ``hi`` as the pieces are integrated
    (levels left behind ``lo`` are caught up first, without integrating). O(1 + levels crossed).
    """
    total = 0.0
    act_on = a_on > 0.0
    act_off = a_off > 0.0
    while True:
        u_on = math.inf
        if act_on and r_on < math.inf:
            if kk[1, 0, z] == 0:
                lv = comp_level(hi, r_on)
                if lv > lev[1, 0, z]:
                    lev[1, 0, z] = lv
            else:
                lv = lev[1, 0, z]
                while (lv + 1) * r_on <= hi and hist[1, 0, z, lv + 1] == 0:
                    lv += 1
                lev[1, 0, z] = lv
                if (lv + 1) * r_on <= hi:
                    u_on = (lv + 1) * r_on
        u_off = math.inf
        if act_off and r_off < math.inf:
            if kk[1, 1, z] == 0:
                lv = comp_level(hi, r_off)
                if lv > lev[1, 1, z]:
                    lev[1, 1, z] = lv
            else:
                lv = lev[1, 1, z]
                while (lv + 1) * r_off <= hi and hist[1, 1, z, lv + 1] == 0:
                    lv += 1
                lev[1, 1, z] = lv
                if (lv + 1) * r_off <= hi:
                    u_off = (lv + 1) * r_off
        alpha = c_on * m_on - c_off * m_off
        beta = 0.0
        if act_on:
            alpha += c_on * a_on * ss[1, 0, z] * inv
            beta -= c_on * b_on * kk[1, 0, z] * inv
        if act_off:
            alpha -= c_off * a_off * ss[1, 1, z] * inv
            beta += c_off * b_off * kk[1, 1, z] * inv
        end = min(hi, u_on, u_off)
        if end > lo:
            total += exp_linear_integral(alpha + beta * lo, beta, end - lo)
            lo = end
        if u_on == math.inf and u_off == math.inf:
            return total
        if u_on == end:  # the pixels with count lv + 1 stop being compensated here
            lv = lev[1, 0, z] + 1
            hk = hist[1, 0, z, lv]
            kk[1, 0, z] -= hk
            ss[1, 0, z] -= lv * hk
            lev[1, 0, z] = lv
        if u_off == end:
            lv = lev[1, 1, z] + 1
            hk = hist[1, 1, z, lv]
            kk[1, 1, z] -= hk
            ss[1, 1, z] -= lv * hk
            lev[1, 1, z] = lv


@nb.njit(cache=True)
def ptedi_update_comp(
    t, x, y, p, zflat, width, height, last_t, counts_on, counts_off, inv_n,
    pc, hist, lev, kk, ss, anchor_t, anchor_log,
    w, w_start, c0_on, c0_off, w_last, w_int,
    c_on, c_off, a_on, b_on, a_off, b_off,
):
    """:func:`ptedi_update` with the TEDI compensation applied per pixel and averaged (Eq. 11).

    ``pc[pixel] = [count ON, count OFF, ON and OFF counts at the anchor, at the window start]``
    (cumulative); the histograms and sums of the module notes above give each zone's
    ``Σ_x max(0, a± n±_x - b± u)`` exactly. Per event: the open window's integral up to the
    event (one ``exp`` while no pixel of the zone is compensated, else the closed-form pieces
    of :func:`_comp_window_integral`), then O(1) updates of both references. Levels may lag
    behind time (the sums are exact for the kept level; an event is classified against it):
    the window's catch up when a piece is integrated, the anchor's once per batch. O(1) per
    event plus the levels crossed (at most ``b u / a`` per reference in time ``u``, and never
    more than the largest per-pixel count).

    Returns ``(index, code, last time)``: code 0 all applied, 1 time decreased, 2 coordinates
    off the sensor, 3 a histogram is full (grow it and resume at ``index``).
    """
    r_on = a_on / b_on if b_on > 0.0 else math.inf
    r_off = a_off / b_off if b_off > 0.0 else math.inf
    cap = hist.shape[3]
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
        z = zflat[pix]
        if z < 0:
            prev = ti
            continue
        q = 0 if p[i] > 0 else 1
        cnt = pc[pix, q]
        na = cnt - pc[pix, 2 + q]
        nw = cnt - pc[pix, 4 + q]
        if na + 2 > cap or (w >= 0 and nw + 2 > cap):
            stop = i
            code = 3
            break
        prev = ti
        if w >= 0:
            last = w_last[w, z]
            if ti > last:
                m_on = (counts_on[z] - c0_on[w, z]) * inv_n[z]
                m_off = (counts_off[z] - c0_off[w, z]) * inv_n[z]
                if (kk[1, 0, z] == 0 or not a_on > 0.0) and (kk[1, 1, z] == 0 or not a_off > 0.0):
                    # no pixel compensated (at the kept level, hence at the current one): constant exponent
                    w_int[w, z] += math.exp(c_on * m_on - c_off * m_off) * float(ti - last)
                else:
                    w_int[w, z] += _comp_window_integral(
                        float(last - w_start), float(ti - w_start), z, m_on, m_off, inv_n[z], hist, lev, kk, ss,
                        c_on, c_off, a_on, b_on, a_off, b_off, r_on, r_off,
                    )
                w_last[w, z] = ti
            # the pixel moves from count nw to nw + 1 (written out: faster than an inlined helper here)
            hist[1, q, z, nw] -= 1
            hist[1, q, z, nw + 1] += 1
            lv = lev[1, q, z]
            if nw + 1 > lv:
                if nw > lv:
                    ss[1, q, z] += 1
                else:
                    kk[1, q, z] += 1
                    ss[1, q, z] += nw + 1
        hist[0, q, z, na] -= 1
        hist[0, q, z, na + 1] += 1
        lv = lev[0, q, z]
        if na + 1 > lv:
            if na > lv:
                ss[0, q, z] += 1
            else:
                kk[0, q, z] += 1
                ss[0, q, z] += na + 1
        pc[pix, q] = cnt + 1
        if q == 0:
            counts_on[z] += 1
        else:
            counts_off[z] += 1
    for z in range(counts_on.shape[0]):  # the anchor's levels follow time, once per batch
        if math.isfinite(anchor_log[z]) and prev >= anchor_t[z]:
            u = float(prev - anchor_t[z])
            if a_on > 0.0:
                _comp_sweep(hist, 0, 0, z, lev, kk, ss, r_on, u)
            if a_off > 0.0:
                _comp_sweep(hist, 0, 1, z, lev, kk, ss, r_off, u)
    return stop, code, prev


@nb.njit(cache=True, inline="always")
def _one_advance(h, lv, k, s, r, hi):
    """One polarity of :func:`_comp_window_integral`'s level bookkeeping for a zone held in locals:
    skip empty levels up to ``hi``; returns ``(level, next breakpoint or inf)``."""
    if k == 0:
        nl = comp_level(hi, r)
        if nl > lv:
            lv = nl
        return lv, math.inf
    while (lv + 1) * r <= hi and h[lv + 1] == 0:
        lv += 1
    if (lv + 1) * r <= hi:
        return lv, (lv + 1) * r
    return lv, math.inf


@nb.njit(cache=True, inline="always")
def _one_window_integral(lo, hi, m_on, m_off, inv, h_on, h_off, l_on, k_on, s_on, l_off, k_off, s_off,
                         c_on, c_off, a_on, b_on, a_off, b_off, r_on, r_off):
    """:func:`_comp_window_integral` for a zone whose levels and sums are locals (same operations in
    the same order, so the same result bit for bit); returns the integral and the updated
    ``(level, K, S)`` of both polarities. O(1 + levels crossed)."""
    total = 0.0
    act_on = a_on > 0.0
    act_off = a_off > 0.0
    while True:
        u_on = math.inf
        if act_on and r_on < math.inf:
            l_on, u_on = _one_advance(h_on, l_on, k_on, s_on, r_on, hi)
        u_off = math.inf
        if act_off and r_off < math.inf:
            l_off, u_off = _one_advance(h_off, l_off, k_off, s_off, r_off, hi)
        alpha = c_on * m_on - c_off * m_off
        beta = 0.0
        if act_on:
            alpha += c_on * a_on * s_on * inv
            beta -= c_on * b_on * k_on * inv
        if act_off:
            alpha -= c_off * a_off * s_off * inv
            beta += c_off * b_off * k_off * inv
        end = min(hi, u_on, u_off)
        if end > lo:
            total += exp_linear_integral(alpha + beta * lo, beta, end - lo)
            lo = end
        if u_on == math.inf and u_off == math.inf:
            return total, l_on, k_on, s_on, l_off, k_off, s_off
        if u_on == end:  # the pixels with count level + 1 stop being compensated here
            l_on += 1
            hk = h_on[l_on]
            k_on -= hk
            s_on -= l_on * hk
        if u_off == end:
            l_off += 1
            hk = h_off[l_off]
            k_off -= hk
            s_off -= l_off * hk


@nb.njit(cache=True)
def ptedi_update_comp_one(
    t, x, y, p, zflat, width, height, last_t, counts_on, counts_off, inv_n,
    pc, hist, lev, kk, ss, anchor_t, anchor_log,
    w, w_start, c0_on, c0_off, w_last, w_int,
    c_on, c_off, a_on, b_on, a_off, b_off,
):
    """:func:`ptedi_update_comp` for a single zone (``zflat`` 0 or -1): same arguments, same
    equations and the same floating-point operations in the same order, so the same state bit for
    bit — but the zone's counts, the levels and sums ``K``, ``S`` of both references and the open
    window's integral are kept in local variables (registers) during the batch and written back
    at its end, instead of being loaded and stored through arrays at every event (which the
    compiler cannot keep in registers, not knowing that the arrays do not overlap). Per event:
    O(1) plus the levels crossed, as :func:`ptedi_update_comp`; returns what it returns.
    """
    r_on = a_on / b_on if b_on > 0.0 else math.inf
    r_off = a_off / b_off if b_off > 0.0 else math.inf
    cap = hist.shape[3]
    h0_on = hist[0, 0, 0]
    h0_off = hist[0, 1, 0]
    h1_on = hist[1, 0, 0]
    h1_off = hist[1, 1, 0]
    n_on = counts_on[0]
    n_off = counts_off[0]
    inv = inv_n[0]
    l0_on, l0_off, l1_on, l1_off = lev[0, 0, 0], lev[0, 1, 0], lev[1, 0, 0], lev[1, 1, 0]
    k0_on, k0_off, k1_on, k1_off = kk[0, 0, 0], kk[0, 1, 0], kk[1, 0, 0], kk[1, 1, 0]
    s0_on, s0_off, s1_on, s1_off = ss[0, 0, 0], ss[0, 1, 0], ss[1, 0, 0], ss[1, 1, 0]
    wl = np.int64(0)
    wi = 0.0
    b_on0 = np.int64(0)
    b_off0 = np.int64(0)
    if w >= 0:
        wl = w_last[w, 0]
        wi = w_int[w, 0]
        b_on0 = c0_on[w, 0]
        b_off0 = c0_off[w, 0]
    live_on = a_on > 0.0
    live_off = a_off > 0.0
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
        if zflat[pix] < 0:
            prev = ti
            continue
        on = p[i] > 0
        q = 0 if on else 1
        cnt = pc[pix, q]
        na = cnt - pc[pix, 2 + q]
        nw = cnt - pc[pix, 4 + q]
        if na + 2 > cap or (w >= 0 and nw + 2 > cap):
            stop = i
            code = 3
            break
        prev = ti
        if w >= 0:
            if ti > wl:
                m_on = (n_on - b_on0) * inv
                m_off = (n_off - b_off0) * inv
                if (k1_on == 0 or not live_on) and (k1_off == 0 or not live_off):
                    # no pixel compensated (at the kept level, hence at the current one): constant exponent
                    wi += math.exp(c_on * m_on - c_off * m_off) * float(ti - wl)
                else:
                    piece, l1_on, k1_on, s1_on, l1_off, k1_off, s1_off = _one_window_integral(
                        float(wl - w_start), float(ti - w_start), m_on, m_off, inv, h1_on, h1_off,
                        l1_on, k1_on, s1_on, l1_off, k1_off, s1_off, c_on, c_off, a_on, b_on, a_off, b_off,
                        r_on, r_off,
                    )
                    wi += piece
                wl = ti
            # the pixel moves from count nw to nw + 1 in the window's histogram
            if on:
                h1_on[nw] -= 1
                h1_on[nw + 1] += 1
                if nw + 1 > l1_on:
                    if nw > l1_on:
                        s1_on += 1
                    else:
                        k1_on += 1
                        s1_on += nw + 1
            else:
                h1_off[nw] -= 1
                h1_off[nw + 1] += 1
                if nw + 1 > l1_off:
                    if nw > l1_off:
                        s1_off += 1
                    else:
                        k1_off += 1
                        s1_off += nw + 1
        # and from na to na + 1 in the anchor's
        if on:
            h0_on[na] -= 1
            h0_on[na + 1] += 1
            if na + 1 > l0_on:
                if na > l0_on:
                    s0_on += 1
                else:
                    k0_on += 1
                    s0_on += na + 1
            n_on += 1
        else:
            h0_off[na] -= 1
            h0_off[na + 1] += 1
            if na + 1 > l0_off:
                if na > l0_off:
                    s0_off += 1
                else:
                    k0_off += 1
                    s0_off += na + 1
            n_off += 1
        pc[pix, q] = cnt + 1
    counts_on[0] = n_on
    counts_off[0] = n_off
    lev[0, 0, 0], lev[0, 1, 0], lev[1, 0, 0], lev[1, 1, 0] = l0_on, l0_off, l1_on, l1_off
    kk[0, 0, 0], kk[0, 1, 0], kk[1, 0, 0], kk[1, 1, 0] = k0_on, k0_off, k1_on, k1_off
    ss[0, 0, 0], ss[0, 1, 0], ss[1, 0, 0], ss[1, 1, 0] = s0_on, s0_off, s1_on, s1_off
    if w >= 0:
        w_last[w, 0] = wl
        w_int[w, 0] = wi
    if math.isfinite(anchor_log[0]) and prev >= anchor_t[0]:  # the anchor's levels follow time, once per batch
        u = float(prev - anchor_t[0])
        if a_on > 0.0:
            _comp_sweep(hist, 0, 0, 0, lev, kk, ss, r_on, u)
        if a_off > 0.0:
            _comp_sweep(hist, 0, 1, 0, lev, kk, ss, r_off, u)
    return stop, code, prev


@nb.njit(cache=True)
def ptedi_close_comp(
    t_end, counts_on, counts_off, inv_n, hist, lev, kk, ss,
    w, w_start, c0_on, c0_off, w_last, w_int, c_on, c_off, a_on, b_on, a_off, b_off,
):
    """:func:`ptedi_close` with the per-pixel compensation. O(zones + levels crossed)."""
    r_on = a_on / b_on if b_on > 0.0 else math.inf
    r_off = a_off / b_off if b_off > 0.0 else math.inf
    for z in range(counts_on.shape[0]):
        m_on = (counts_on[z] - c0_on[w, z]) * inv_n[z]
        m_off = (counts_off[z] - c0_off[w, z]) * inv_n[z]
        w_int[w, z] += _comp_window_integral(
            float(w_last[w, z] - w_start), float(t_end - w_start), z, m_on, m_off, inv_n[z], hist, lev, kk, ss,
            c_on, c_off, a_on, b_on, a_off, b_off, r_on, r_off,
        )
        w_last[w, z] = t_end


@nb.njit(cache=True)
def comp_snapshot(pc, snap):
    """At an exposure start: ``snap = counts`` (kept for a later anchor) and the window's base. O(pixels)."""
    for i in range(pc.shape[0]):
        a = pc[i, 0]
        b = pc[i, 1]
        snap[i, 0] = a
        snap[i, 1] = b
        pc[i, 4] = a
        pc[i, 5] = b


@nb.njit(cache=True)
def comp_rebase(pc, snap, zflat, zones, sizes, hist):
    """Re-anchor the pixels of the zones flagged in ``zones`` on the counts ``snap`` and rebuild
    their anchor histograms (``hist[0]``). Returns ``-1``, or the histogram size needed when a
    count does not fit (then grow and call again: the rebuild starts from scratch). O(pixels).

    Pixels without events since the snapshot (most of them, usually) are not added one by one:
    bin 0 is the zone size minus the others (a chain of increments of one bin would serialise).
    """
    cap = hist.shape[3]
    need = -1
    every = True
    for z in range(zones.shape[0]):
        if zones[z]:
            hist[0, :, z, :] = 0
        else:
            every = False
    for i in range(pc.shape[0]):
        z = zflat[i]
        if z < 0 or not (every or zones[z]):
            continue
        b0 = snap[i, 0]
        b1 = snap[i, 1]
        n0 = pc[i, 0] - b0
        n1 = pc[i, 1] - b1
        pc[i, 2] = b0
        pc[i, 3] = b1
        if n0 > 0:
            if n0 + 2 > cap:
                need = max(need, n0 + 2)
            else:
                hist[0, 0, z, n0] += 1
        if n1 > 0:
            if n1 + 2 > cap:
                need = max(need, n1 + 2)
            else:
                hist[0, 1, z, n1] += 1
    for z in range(zones.shape[0]):
        if zones[z]:
            for q in range(2):
                others = 0
                for n in range(1, cap):
                    others += hist[0, q, z, n]
                hist[0, q, z, 0] = sizes[z] - others
    return need


@nb.njit(cache=True)
def comp_between(pc, snap, zflat, u, a_on, b_on, a_off, b_off, out):
    """``out[q, z] = Σ_{x in z} max(0, a_q n_x - b_q u[z])`` with ``n_x`` = the pixel's counts between the
    anchor (``pc[:, 2:4]``) and the snapshot ``snap`` (a window's start), added in pixel order (the
    order of the ``np.bincount`` it replaced, so the same sums bit for bit). O(pixels)."""
    out[:] = 0.0
    for i in range(pc.shape[0]):
        z = zflat[i]
        if z < 0:
            continue
        uz = u[z]
        v = a_on * float(snap[i, 0] - pc[i, 2]) - b_on * uz
        out[0, z] += v if (v > 0.0 or v != v) else 0.0  # np.maximum(0, v): NaN stays NaN
        v = a_off * float(snap[i, 1] - pc[i, 3]) - b_off * uz
        out[1, z] += v if (v > 0.0 or v != v) else 0.0


@nb.njit(cache=True)
def comp_restate(hist, ref, zones, u, lev, kk, ss, a_on, b_on, a_off, b_off):
    """Set the level of every flagged zone of ``ref`` to ``floor(u[z] b/a)`` and its sums from the
    histogram. O(zones x histogram size)."""
    for z in range(zones.shape[0]):
        if not zones[z]:
            continue
        for q in range(2):
            a = a_on if q == 0 else a_off
            b = b_on if q == 0 else b_off
            lv = 0
            if a > 0.0:
                lv = comp_level(u[z], a / b if b > 0.0 else math.inf)
            k = 0
            s = 0
            for n in range(lv + 1, hist.shape[3]):
                k += hist[ref, q, z, n]
                s += n * hist[ref, q, z, n]
            lev[ref, q, z] = lv
            kk[ref, q, z] = k
            ss[ref, q, z] = s


@nb.njit(cache=True)
def comp_sums(hist, lev, kk, ss, ref, u, a_on, b_on, a_off, b_off, out):
    """``out[q, z] = Σ_{x in z} max(0, a_q n_x - b_q u[z])`` for reference ``ref`` (read only).

    From the kept level, walks the histogram up or down to ``floor(u/r)``: O(1) when ``u`` is
    the time the levels were last advanced to, else O(levels between).
    """
    cap = hist.shape[3]
    for z in range(out.shape[1]):
        for q in range(2):
            a = a_on if q == 0 else a_off
            b = b_on if q == 0 else b_off
            if a <= 0.0:
                out[q, z] = 0.0
                continue
            r = a / b if b > 0.0 else math.inf
            target = comp_level(u[z], r)
            lv = lev[ref, q, z]
            k = kk[ref, q, z]
            s = ss[ref, q, z]
            if target > lv:
                while lv < target and k > 0:
                    lv += 1
                    hk = hist[ref, q, z, lv]
                    k -= hk
                    s -= lv * hk
            else:
                lv = min(lv, cap - 1)
                while lv > target:
                    hk = hist[ref, q, z, lv]
                    k += hk
                    s += lv * hk
                    lv -= 1
            out[q, z] = a * s - b * u[z] * k


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
    #: ln P(s) after this frame: the new anchor where the zone re-anchored (or was bounded), else the
    #: event-propagated prediction at s (NaN for a zone never anchored). A metering statistic of the
    #: frame minus this is its offset from P-TEDI's level (see necviz.core.control.nec).
    log_start: np.ndarray | None = None
    #: per zone: +1 where the anchor moved up to a lower bound (over-exposed frame), -1 down to an
    #: upper bound, 0 otherwise; None when no zone was bounded
    bound_side: np.ndarray | None = None


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
    one_sided_clip : the clipped fraction at the "other" end that a one-sided saturation bound
        tolerates (a few hot or dead pixels; default 5 %, see :meth:`frame_bounds`).
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
        one_sided_clip: float = 0.05,
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
        if (isinstance(one_sided_clip, bool) or not isinstance(one_sided_clip, (int, float))
                or not 0.0 <= one_sided_clip <= 1.0):
            raise ParameterError(f"one_sided_clip must lie in [0, 1], got {one_sided_clip!r}")
        self.one_sided_clip = float(one_sided_clip)
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
        # per-pixel compensation state (only while a+ or a- > 0; see the notes above ptedi_update_comp)
        self._comp = False
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

    def set_params(self, params: TediParams) -> None:
        """Change thresholds / compensation while streaming (live tuning).

        Takes effect at once: predictions propagate the counts since the last anchor with the
        new values, and an exposure already open integrates with the new values from now on.
        Per-pixel counts are kept only while the compensation is on (``a+`` or ``a- > 0``):
        switched on mid-stream, it counts the events from the switch on until the next anchor
        and exposure start (after which it is exact again).
        """
        if not isinstance(params, TediParams):
            raise ParameterError("params must be a TediParams")
        self._derive(params)
        comp = params.a_on > 0.0 or params.a_off > 0.0
        if comp and not self._comp:
            self._comp_start()
        elif comp:
            self._comp_restate(0, np.arange(self.num_zones), self._anchor_u())
            if self._open >= 0:
                self._comp_restate(1, np.arange(self.num_zones), self._window_u())
        elif self._comp:
            self._comp = False
            self._pc = self._wsnap = self._hist = self._lev = self._kk = self._ss = None
        w = self._open
        if w >= 0:  # the zone kernel's running exp restarts from the counts with the new thresholds
            self._webase[w] = np.exp((params.c_on * (self.counts_on - self._c0_on[w])
                                      - params.c_off * (self.counts_off - self._c0_off[w])) * self._inv_n)

    # -- per-pixel compensation bookkeeping (Eq. 11 with the Eq. 6 terms per pixel) ---------------
    def _comp_start(self) -> None:
        """Allocate the per-pixel counts and the per-zone histograms; counting starts now."""
        k = self.num_zones
        npix = self.sensor.width * self.sensor.height
        self._comp = True
        self._pc = np.zeros((npix, 6), np.int32)  # [ON, OFF, ON/OFF at the anchor, ON/OFF at the window start]
        self._wsnap = np.zeros((len(self._wstate), npix, 2), np.int32)  # counts at each window's start
        self._hist = np.zeros((2, 2, k, 64), np.int32)
        self._hist[:, :, :, 0] = self.sizes
        self._lev = np.zeros((2, 2, k), np.int64)
        self._kk = np.zeros((2, 2, k), np.int64)
        self._ss = np.zeros((2, 2, k), np.int64)
        self._comp_restate(0, np.arange(k), self._anchor_u())
        if self._open >= 0:
            self._comp_restate(1, np.arange(k), self._window_u())

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

    def _comp_restate(self, ref: int, zones: np.ndarray, u: np.ndarray) -> None:
        """Levels and sums of ``zones`` for reference ``ref`` from their histograms at times ``u``."""
        flags = np.zeros(self.num_zones, np.bool_)
        flags[zones] = True
        _, _, a_on, b_on, a_off, b_off = self._kp
        comp_restate(self._hist, ref, flags, np.asarray(u, np.float64), self._lev, self._kk, self._ss,
                     a_on, b_on, a_off, b_off)

    def _comp_grow(self, need: int) -> None:
        """Widen the count histograms to hold counts up to ``need``."""
        cap = self._hist.shape[3]
        if need < cap:
            return
        new = np.zeros(self._hist.shape[:3] + (max(2 * cap, need + 1),), np.int32)
        new[..., :cap] = self._hist
        self._hist = new

    def _comp_anchor(self, w: int, zones: np.ndarray, s: int) -> None:
        """``zones`` re-anchored on window ``w`` (start ``s``): their per-pixel counts restart there."""
        flags = np.zeros(self.num_zones, np.bool_)
        flags[zones] = True
        while (need := comp_rebase(self._pc, self._wsnap[w], self._zone_flat, flags, self.sizes, self._hist)) >= 0:
            self._comp_grow(need)
        self._comp_restate(0, zones, np.full(self.num_zones, float(max(0, self.last_event_us - s))))

    def _comp_between(self, w: int, u: np.ndarray) -> np.ndarray:
        """Per zone ``Σ_x max(0, a± n±_x - b± u)`` for the counts between the anchor and window ``w``'s
        start (brute force over the pixels, O(pixels), :func:`comp_between`; used only for the saturation bound)."""
        c_on, c_off, a_on, b_on, a_off, b_off = self._kp
        out = np.empty((2, self.num_zones))
        comp_between(self._pc, self._wsnap[w], self._zone_flat, np.asarray(u, np.float64), a_on, b_on, a_off, b_off,
                     out)
        return out

    # -- stream input -------------------------------------------------------------------------
    def update(self, events: np.ndarray) -> None:
        """Apply an event batch (time-ordered, not before events already processed). O(n)."""
        if not isinstance(events, np.ndarray) or events.dtype != EVENT_DTYPE:
            raise EventFormatError(f"events must be a structured array of dtype {EVENT_DTYPE}")
        if events.size == 0:
            return
        w = self._open
        if self._comp:
            bad = self._update_comp(events, w)
        elif self.whole:
            c0 = self._c02
            if w >= 0:
                c0[0], c0[1] = self._c0_on[w, 0], self._c0_off[w, 0]
            bad = ptedi_update_whole(
                events["t"], events["p"], self.last_event_us, self._counts2, self._inv_n0, self._g_tab, self._h_tab,
                w, c0, self._wlast, self._wint, self._kp[0], self._kp[1],
            )
        else:
            bad = ptedi_update(
                events["t"], events["x"], events["y"], events["p"], self.zmap, self.last_event_us,
                self.counts_on, self.counts_off, self._inv_n, self._f_on, self._f_off,
                w, self._c0_on, self._c0_off, self._wlast, self._wint, self._webase,
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

    def _update_comp(self, events: np.ndarray, w: int) -> int:
        """The batch through :func:`ptedi_update_comp` (:func:`ptedi_update_comp_one` for a single zone),
        widening the histograms when needed."""
        t, x, y, p = events["t"], events["x"], events["y"], events["p"]
        ws = int(self._wstart[w]) if w >= 0 else 0
        pos, last = 0, self.last_event_us
        kernel = ptedi_update_comp_one if self.num_zones == 1 else ptedi_update_comp
        while True:
            stop, code, last = kernel(
                t[pos:], x[pos:], y[pos:], p[pos:], self._zone_flat, self.sensor.width, self.sensor.height, last,
                self.counts_on, self.counts_off, self._inv_n, self._pc, self._hist, self._lev, self._kk, self._ss,
                self.anchor_t, self.anchor_log, w, ws, self._c0_on, self._c0_off, self._wlast, self._wint, *self._kp,
            )
            if code != 3:
                return -1 if code == 0 else pos + stop
            pos += stop
            self._comp_grow(2 * self._hist.shape[3])

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
        if self._comp:
            comp_snapshot(self._pc, self._wsnap[w])
            self._hist[1] = 0
            self._hist[1, :, :, 0] = self.sizes
            self._lev[1] = 0
            self._kk[1] = 0
            self._ss[1] = 0
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
        if self._comp:
            ptedi_close_comp(
                t_us, self.counts_on, self.counts_off, self._inv_n, self._hist, self._lev, self._kk, self._ss,
                w, int(self._wstart[w]), self._c0_on, self._c0_off, self._wlast, self._wint, *self._kp,
            )
        else:
            ptedi_close(t_us, self.counts_on, self.counts_off, self._inv_n, w, self._c0_on, self._c0_off,
                        self._wlast, self._wint, self._kp[0], self._kp[1])
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

    def frame_bounds(self, frame: Frame, log_pbar=None, frac=None, over=None) -> tuple[np.ndarray, np.ndarray]:
        """Per zone, what a frame proves about its ``ln Pbar`` even when too many pixels are clipped:
        ``(lower, upper)`` bounds, NaN where it proves nothing.

        Clipping hides how far beyond the valid range a pixel's irradiance lies, but not on which side.
        With the paper's image form (``g(mean Z)``: the log of the zone's mean exposure), a lower bound
        always exists: count every under-exposed pixel as receiving nothing and every over-exposed one
        as exactly at the top of the valid range, ``ln((Σ_valid E(Z) + N_over E(250)) / N) - ln T K``
        with ``E = exp(g)``; this holds for frames clipped at both ends too. An upper bound exists only
        when (essentially) nothing is over-exposed — at most ``one_sided_clip`` of the zone, a few hot
        pixels — with under-exposed pixels counted at the bottom of the valid range. With the
        ``mean_log`` form a clipped pixel's log is unbounded, so only a frame clipped at one end
        (the other end at most ``one_sided_clip``) bounds it, from that side. O(pixels).
        """
        if log_pbar is None:
            log_pbar, frac, over = self.frame_log_irradiance(frame)
        under = 1.0 - frac - over
        nan = np.full(self.num_zones, np.nan)
        if self.image_form == "mean_log":
            lower = np.where((over > under) & (under <= self.one_sided_clip), log_pbar, nan)
            upper = np.where((under > over) & (over <= self.one_sided_clip), log_pbar, nan)
            return lower, upper
        crf = self.crf
        z = frame.image.ravel()
        log_tk = math.log(frame.exposure_us / US_PER_S) + math.log(frame.gain)
        e_valid = np.where((np.arange(256) >= crf.valid_min) & (np.arange(256) <= crf.valid_max), np.exp(crf.g), 0.0)
        if self.whole:
            sums = np.array([float(np.bincount(z, minlength=256) @ e_valid)])
        else:
            inr = self._in_region
            sums = np.bincount(self._zone_flat[inr], weights=e_valid[z[inr]], minlength=self.num_zones)
        e_top, e_bottom = math.exp(crf.g[crf.valid_max]), math.exp(crf.g[crf.valid_min])
        with np.errstate(divide="ignore", invalid="ignore"):
            lower = np.log((sums / self.sizes) + over * e_top) - log_tk
            upper = np.log((sums / self.sizes) + under * e_bottom + over * e_top) - log_tk
        lower = np.where(np.isfinite(lower), lower, nan)
        upper = np.where((over <= self.one_sided_clip) & np.isfinite(upper), upper, nan)
        return lower, upper

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
                if self._comp:
                    self._comp_anchor(w, np.zeros(1, np.int64), s)
                self._wstate[w] = _FREE
                self.frames_seen += 1
                anchor = np.array([lp - log_e])
                return FrameEstimate(frame.sequence, s, e, np.array([lp]), np.array([log_e]),
                                     anchor, np.array([fr]), np.array([True]), np.array([ov]),
                                     np.array([False]), anchor)
            log_pbar, frac, over = np.array([lp]), np.array([fr]), np.array([ov])
            log_e = np.array([log_e])
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
        if not ok.all():
            pred_s = self._predict_at_window(w)
            lo, hi = self.frame_bounds(frame, log_pbar, frac, over)
            lo, hi = lo - log_e, hi - log_e
            with np.errstate(invalid="ignore"):
                first = ~ok & ~np.isfinite(pred_s) & np.isfinite(log_anchor)
                raise_ = ~ok & ~first & np.isfinite(lo) & (pred_s < lo)
                lower_ = ~ok & ~first & ~raise_ & np.isfinite(hi) & (pred_s > hi)
            bounded = first | raise_ | lower_
            value = np.where(raise_, lo, np.where(lower_, hi, log_anchor))
            side = raise_.astype(np.int8) - lower_.astype(np.int8)
            start = np.where(ok | bounded, value, pred_s)
        new = ok | bounded
        self.anchor_log[new] = value[new]
        self.anchor_t[new] = s
        self.anchor_on[new] = w0[0][new]
        self.anchor_off[new] = w0[1][new]
        if self._comp and new.any():
            self._comp_anchor(w, np.flatnonzero(new), s)
        self._wstate[w] = _FREE
        self.frames_seen += 1
        if not ok.all():
            self.frames_skipped += 1
        self.frames_bounded += int(bounded.any())
        return FrameEstimate(frame.sequence, s, e, log_pbar, log_e, log_anchor, frac, ok, over, bounded, start, side)

    def _propagate(self, counts_on: np.ndarray, counts_off: np.ndarray) -> np.ndarray:
        """Eq. 12 without compensation, from each zone's anchor with the given cumulative counts
        (NaN where unanchored)."""
        m_on = (counts_on - self.anchor_on) * self._inv_n
        m_off = (counts_off - self.anchor_off) * self._inv_n
        return self.anchor_log + self._kp[0] * m_on - self._kp[1] * m_off

    def _predict_at_window(self, w: int) -> np.ndarray:
        """Eq. 12 from each zone's anchor to window ``w``'s start, with the counts seen by then."""
        pred = self._propagate(self._c0_on[w], self._c0_off[w])
        if self._comp:
            u = np.maximum(0, int(self._wstart[w]) - self.anchor_t).astype(np.float64)
            comp = self._comp_between(w, u)
            pred = pred + (self._kp[0] * comp[0] - self._kp[1] * comp[1]) * self._inv_n
        return pred

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
        pred = self._propagate(self.counts_on, self.counts_off)
        if self._comp:  # Eq. 11: the mean over the zone's pixels of their compensation terms
            u = np.where(anchored, (t - self.anchor_t).astype(np.float64), 0.0)
            comp = np.empty((2, self.num_zones))
            c_on, c_off, a_on, b_on, a_off, b_off = self._kp
            comp_sums(self._hist, self._lev, self._kk, self._ss, 0, u, a_on, b_on, a_off, b_off, comp)
            pred = pred + (c_on * comp[0] - c_off * comp[1]) * self._inv_n
        return pred

    def predict(self, t_us: int | None = None) -> float:
        """Mean log irradiance ``ln P(t)`` over the anchored zones, weighted by their pixel counts."""
        if self.num_zones == 1 and not self._comp:  # scalar path: the controller calls this on every batch
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
