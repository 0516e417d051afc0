"""P-TEDI's per-pixel TEDI compensation averaged over a zone (Eq. 11 with the Eq. 6 terms), as Numba kernels.

Exact integer bookkeeping per (reference, polarity, zone) — a histogram of per-pixel counts and
the sums ``K``, ``S`` at the current level — so the compensated exponent and its exposure
integral are evaluated in closed form (the derivation follows, and :mod:`necviz.core.ptedi`'s
docstring). Called by :class:`necviz.core.ptedi.PeripheralEstimator` when ``a± > 0``.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from necviz.core.event_model import exp_linear_integral

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
# lev/kk/ss[ref, q, zone] (int64) with ref 0 = anchor, 1 = the latest exposure (open, or awaiting its
# frame); q 0 = ON, 1 = OFF.
#
# Per pixel, pc[pixel] holds its counts since each reference directly (ON/OFF since the anchor, ON/OFF
# since the latest exposure start: one row, so an event touches one cache line), as uint16 while every
# count fits (the estimator widens them to int32 before one could overflow). Re-anchoring on the latest
# exposure's start, the usual case, copies the window's pair of counts over the anchor's (one word per
# pixel) and its histogram; a new exposure start zeroes the window's pair (one word per pixel).

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
def _comp_window_integral(
    lo, hi, z, m_on, m_off, inv, hist, lev, kk, ss, c_on, c_off, a_on, b_on, a_off, b_off, r_on, r_off
):
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
    iw,
    hist,
    lev,
    kk,
    ss,
    anchor_t,
    anchor_log,
    w,
    w_start,
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
    """:func:`ptedi_update` with the TEDI compensation applied per pixel and averaged (Eq. 11).

    ``pc[pixel]`` holds the pixel's counts: columns 0, 1 ON and OFF since the anchor, ``iw, iw + 1``
    (2, 3) since the latest exposure start (``iw < 0``: not kept, no exposure needs them);
    ``whole``: every pixel is in zone 0 (``zflat`` is not read). The histograms and sums of the
    module notes above give each zone's ``Σ_x max(0, a± n±_x - b± u)`` exactly. Per event: the open
    window's integral up to the event (one ``exp`` while no pixel of the zone is compensated, else
    the closed-form pieces of :func:`_comp_window_integral`), then O(1) updates of both references.
    Levels may lag behind time (the sums are exact for the kept level; an event is classified
    against it): the window's catch up when a piece is integrated, the anchor's once per batch.
    O(1) per event plus the levels crossed (at most ``b u / a`` per reference in time ``u``, and
    never more than the largest per-pixel count).

    Returns ``(index, code, last time)``: code 0 all applied, 1 time decreased, 2 coordinates
    off the sensor, 3 a histogram is full (grow it and resume at ``index``).
    """
    r_on = a_on / b_on if b_on > 0.0 else math.inf
    r_off = a_off / b_off if b_off > 0.0 else math.inf
    cap = hist.shape[3]
    keep_w = iw >= 0
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
        na = np.int64(pc[pix, q])
        nw = np.int64(pc[pix, iw + q]) if keep_w else np.int64(0)
        if na + 2 > cap or nw + 2 > cap:
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
                        float(last - w_start),
                        float(ti - w_start),
                        z,
                        m_on,
                        m_off,
                        inv_n[z],
                        hist,
                        lev,
                        kk,
                        ss,
                        c_on,
                        c_off,
                        a_on,
                        b_on,
                        a_off,
                        b_off,
                        r_on,
                        r_off,
                    )
                w_last[w, z] = ti
        if keep_w:  # the pixel moves from count nw to nw + 1 (written out: faster than an inlined helper here)
            hist[1, q, z, nw] -= 1
            hist[1, q, z, nw + 1] += 1
            lv = lev[1, q, z]
            if nw + 1 > lv:
                if nw > lv:
                    ss[1, q, z] += 1
                else:
                    kk[1, q, z] += 1
                    ss[1, q, z] += nw + 1
            pc[pix, iw + q] = nw + 1
        hist[0, q, z, na] -= 1
        hist[0, q, z, na + 1] += 1
        lv = lev[0, q, z]
        if na + 1 > lv:
            if na > lv:
                ss[0, q, z] += 1
            else:
                kk[0, q, z] += 1
                ss[0, q, z] += na + 1
        pc[pix, q] = na + 1
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
def _one_window_integral(
    lo,
    hi,
    m_on,
    m_off,
    inv,
    h_on,
    h_off,
    l_on,
    k_on,
    s_on,
    l_off,
    k_off,
    s_off,
    c_on,
    c_off,
    a_on,
    b_on,
    a_off,
    b_off,
    r_on,
    r_off,
):
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
    iw,
    hist,
    lev,
    kk,
    ss,
    anchor_t,
    anchor_log,
    w,
    w_start,
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
    keep_w = iw >= 0
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
        na = np.int64(pc[pix, q])
        nw = np.int64(pc[pix, iw + q]) if keep_w else np.int64(0)
        if na + 2 > cap or nw + 2 > cap:
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
        if keep_w:  # the pixel moves from count nw to nw + 1 in the latest exposure's histogram
            pc[pix, iw + q] = nw + 1
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
        pc[pix, q] = na + 1
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
    t_end,
    counts_on,
    counts_off,
    inv_n,
    hist,
    lev,
    kk,
    ss,
    w,
    w_start,
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
    """:func:`ptedi_close` with the per-pixel compensation. O(zones + levels crossed)."""
    r_on = a_on / b_on if b_on > 0.0 else math.inf
    r_off = a_off / b_off if b_off > 0.0 else math.inf
    for z in range(counts_on.shape[0]):
        m_on = (counts_on[z] - c0_on[w, z]) * inv_n[z]
        m_off = (counts_off[z] - c0_off[w, z]) * inv_n[z]
        w_int[w, z] += _comp_window_integral(
            float(w_last[w, z] - w_start),
            float(t_end - w_start),
            z,
            m_on,
            m_off,
            inv_n[z],
            hist,
            lev,
            kk,
            ss,
            c_on,
            c_off,
            a_on,
            b_on,
            a_off,
            b_off,
            r_on,
            r_off,
        )
        w_last[w, z] = t_end


@nb.njit(cache=True)
def comp_reanchor(pc, since, zflat, zones, sizes, hist):
    """Re-anchor the pixels of the zones flagged in ``zones`` at an exposure start: their counts since
    the anchor (``pc`` columns 0, 1) become ``since`` (their counts since that start) and
    their anchor histograms (``hist[0]``) are rebuilt. Returns ``-1``, or the histogram size needed
    when a count does not fit (then grow and call again: the rebuild starts from scratch). O(pixels).

    Pixels without events since the start (most of them, usually) are not added one by one: bin 0
    is the zone size minus the others (a chain of increments of one bin would serialise).
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
        n0 = since[i, 0]
        n1 = since[i, 1]
        pc[i, 0] = n0
        pc[i, 1] = n1
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
