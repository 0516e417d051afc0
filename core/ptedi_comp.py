"""P-TEDI's per-pixel TEDI compensation averaged over a zone (Eq. 11 with the Eq. 6 terms), as Numba kernels.

Exact integer bookkeeping per (slot, polarity, zone) — a histogram of per-pixel counts and
the sums ``K``, ``S`` at the current level — so the compensated exponent and its exposure
integral are evaluated in closed form (the derivation follows, and :mod:`necviz.core.ptedi`'s
docstring). The state is an :class:`~necviz.core.ptedi_side.EventSide`'s; the per-event loop is
:func:`side_update` (any zones) with its single-zone form :func:`side_update_one`, both written
from the same steps (the ``inline="always"`` helpers below), so they cannot drift apart.
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
# is a sum of exp-of-linear pieces in closed form. Arrays: hist[slot, q, zone, k] (int32),
# lev/kk/ss[slot, q, zone] (int64), a slot being a reference time (an exposure start, which becomes an
# anchor when its frame is usable; position 0 unused); q 0 = ON, 1 = OFF.
#
# Per pixel, pc[pixel] holds its counts since each slot directly (columns 2 (slot - 1) + q: one row,
# so an event touches one cache line), as uint16 while every count fits (the side widens them to int32
# before one could overflow). A new exposure start zeroes its slot's pair (one word per pixel);
# re-anchoring on an exposure start just uses that start's slot.

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
def comp_sweep(hist, ref, q, z, lev, kk, ss, r, u):
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


@nb.njit(cache=True, inline="always")
def _one_advance(h, lv, k, s, r, hi):
    """One polarity of the exposure integral (Eq. 13-14)'s level bookkeeping for a zone held in locals:
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
def _one_window_integral(lo, hi, m_on, m_off, inv, h_on, h_off, lks, kp, rr):
    """``∫_lo^hi exp(c^T D_p(s, s+u)) du`` for one zone of a slot, no events inside:
    ``c^T D_p = c+ (m+ + C+(u)/N) - c- (m- + C-(u)/N)`` with the per-pixel compensation sums
    ``C±(u) = a± S± - b± u K±`` (Eq. 11, 13). ``h_on``, ``h_off``: the zone's count histograms;
    ``lks``: its ``(level, K, S)`` of ON then OFF; ``kp``: ``(c+, c-, a+, b+, a-, b-)``; ``rr``: ``(a+/b+, a-/b-)``.
    The levels advance to ``hi`` as the pieces are integrated (levels left behind ``lo`` are caught up
    first, without integrating). Returns the integral and the updated ``lks``. O(1 + levels crossed)."""
    l_on, k_on, s_on, l_off, k_off, s_off = lks
    c_on, c_off, a_on, b_on, a_off, b_off = kp
    r_on, r_off = rr
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
            return total, (l_on, k_on, s_on, l_off, k_off, s_off)
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


# -- the steps of the per-event loop (inlined into side_update and side_update_one) --------------------
#
# Bundles passed to the loops: ev = (t, x, y, p) the event fields; counts = (counts_on, counts_off, 1/N)
# per zone; slots = (hist, lev, kk, ss, start_t, c0_on, c0_off, w_last, w_int), the side's per-slot arrays
# (module notes; c0_*: the zone counts at the slot's start, w_*: the running exposure integral and its
# last time); kp = (c+, c-, a+, b+, a-, b-).


@nb.njit(cache=True, inline="always")
def _ratios(kp):
    """``(a+/b+, a-/b-)``: µs per count of each polarity's knee (``inf`` where ``b = 0``)."""
    a_on, b_on, a_off, b_off = kp[2], kp[3], kp[4], kp[5]
    return (a_on / b_on if b_on > 0.0 else math.inf, a_off / b_off if b_off > 0.0 else math.inf)


@nb.njit(cache=True, inline="always")
def _event_pixel(ev, i, prev, width, height):
    """Step 1: ``(0, time, pixel index)`` of event ``i``, or code 1 when it is earlier than ``prev``, 2 when it
    lies off the ``width x height`` sensor. O(1)."""
    ti = ev[0][i]
    xi = np.int64(ev[1][i])
    yi = np.int64(ev[2][i])
    if ti < prev:
        return 1, ti, np.int64(0)
    if xi >= width or yi >= height:
        return 2, ti, np.int64(0)
    return 0, ti, yi * width + xi


@nb.njit(cache=True, inline="always")
def _fits(pc, pix, live, q, cap):
    """Step 2: every live slot's histogram (``cap`` bins) has room for the pixel's next count. O(slots)."""
    ok = True
    for j in range(live.shape[0]):
        if np.int64(pc[pix, 2 * (live[j] - 1) + q]) + 2 > cap:
            ok = False
    return ok


@nb.njit(cache=True, inline="always")
def _window_step(ti, last, start, n_on, n_off, base_on, base_off, inv, h_on, h_off, lks, kp, rr):
    """Step 3: the open exposure's integral (Eq. 13) from its last event ``last`` to the event at ``ti``, no
    event between: one ``exp`` while no pixel of the zone is compensated (at the kept level, hence at the
    current one: a constant exponent), else the closed-form pieces of :func:`_one_window_integral`.
    ``n_*``: the zone's counts now, ``base_*`` at the exposure's start. Returns the piece and the slot's
    updated ``(level, K, S)`` of both polarities. O(1 + levels crossed)."""
    m_on = (n_on - base_on) * inv
    m_off = (n_off - base_off) * inv
    if (lks[1] == 0 or not kp[2] > 0.0) and (lks[4] == 0 or not kp[4] > 0.0):
        return math.exp(kp[0] * m_on - kp[1] * m_off) * float(ti - last), lks
    return _one_window_integral(float(last - start), float(ti - start), m_on, m_off, inv, h_on, h_off, lks, kp, rr)


@nb.njit(cache=True, inline="always")
def _count_up(h, n, lv, k, s):
    """Step 4: a pixel with count ``n`` since the slot's start gets an event: it moves one bin up the
    histogram ``h``; ``K``, ``S`` at level ``lv`` follow (returned). O(1)."""
    h[n] -= 1
    h[n + 1] += 1
    if n + 1 > lv:
        if n > lv:
            s += 1
        else:
            k += 1
            s += n + 1
    return k, s


@nb.njit(cache=True, inline="always")
def _follow_time(slots, s, z, kp, rr, u):
    """Step 5, once per batch: the levels of slot ``s``, zone ``z`` follow time to ``u`` (both polarities)."""
    hist, lev, kk, ss = slots[0], slots[1], slots[2], slots[3]
    if kp[2] > 0.0:
        comp_sweep(hist, s, 0, z, lev, kk, ss, rr[0], u)
    if kp[4] > 0.0:
        comp_sweep(hist, s, 1, z, lev, kk, ss, rr[1], u)


@nb.njit(cache=True, inline="always")
def _slot_state(lev, kk, ss, s, z):
    """Slot ``s``, zone ``z``: ``(level, K, S)`` of ON then OFF."""
    return (lev[s, 0, z], kk[s, 0, z], ss[s, 0, z], lev[s, 1, z], kk[s, 1, z], ss[s, 1, z])


# -- the per-event loop ---------------------------------------------------------------------------------


@nb.njit(cache=True)
def side_update(ev, zflat, whole, width, height, last_t, counts, pc, live, integ, slots, kp):
    """Apply an event batch to every live slot of an :class:`~necviz.core.ptedi_side.EventSide` (Eq. 11
    with the Eq. 6 terms per pixel, for any number of reference times and zones; bundles: see above).

    ``live``: the slot positions (1..M) to update; slot ``s`` keeps its pixels' counts in ``pc`` columns
    ``2 (s - 1) + q``; ``integ[s]``: an exposure from the slot's start is open (its integral runs). Per
    event and live slot: the slot's exposure integral up to the event when it runs (step 3), then the O(1)
    update of its histogram, ``K`` and ``S`` (step 4); at the batch end the levels of the live slots not
    integrating follow time (an integrating slot's advance with its integral only, zone by zone: a sweep
    would skip breakpoints a zone integrates later). O(live slots) per event plus the levels crossed.

    Returns ``(index, code, last time)``: code 0 all applied, 1 time decreased, 2 coordinates off the
    sensor, 3 a histogram is full (grow it and resume at ``index``).
    """
    p = ev[3]
    counts_on, counts_off, inv_n = counts
    hist, lev, kk, ss, start_t, c0_on, c0_off, w_last, w_int = slots
    rr = _ratios(kp)
    cap = hist.shape[3]
    prev, stop, code = last_t, -1, 0
    for i in range(ev[0].shape[0]):
        code, ti, pix = _event_pixel(ev, i, prev, width, height)
        if code != 0:
            stop = i
            break
        z = 0 if whole else zflat[pix]
        if z < 0:
            prev = ti
            continue
        q = 0 if p[i] > 0 else 1
        if not _fits(pc, pix, live, q, cap):
            stop = i
            code = 3
            break
        prev = ti
        for j in range(live.shape[0]):
            s = live[j]
            if integ[s] and ti > w_last[s, z]:
                hs = hist[s]
                piece, lks = _window_step(
                    ti, w_last[s, z], start_t[s], counts_on[z], counts_off[z], c0_on[s, z], c0_off[s, z],
                    inv_n[z], hs[0, z], hs[1, z], _slot_state(lev, kk, ss, s, z), kp, rr,
                )  # fmt: skip
                lev[s, 0, z], kk[s, 0, z], ss[s, 0, z], lev[s, 1, z], kk[s, 1, z], ss[s, 1, z] = lks
                w_int[s, z] += piece
                w_last[s, z] = ti
            col = 2 * (s - 1) + q
            n = np.int64(pc[pix, col])
            kk[s, q, z], ss[s, q, z] = _count_up(hist[s, q, z], n, lev[s, q, z], kk[s, q, z], ss[s, q, z])
            pc[pix, col] = n + 1
        if q == 0:
            counts_on[z] += 1
        else:
            counts_off[z] += 1
    for j in range(live.shape[0]):
        s = live[j]
        if not integ[s] and prev >= start_t[s]:
            for z in range(counts_on.shape[0]):
                _follow_time(slots, s, z, kp, rr, float(prev - start_t[s]))
    return stop, code, prev


@nb.njit(cache=True)
def side_update_one(ev, zflat, whole, width, height, last_t, counts, pc, live, integ, slots, kp):
    """:func:`side_update` (same arguments) for one zone (``zflat`` 0 or -1) and one or two live slots, of which
    at most one integrates: the usual case (one estimator's anchor and open exposure, or the lanes of a rig
    starting their exposures together). Same steps, same floating-point operations in the same order, so the
    same state bit for bit; but both slots keep their levels, sums and counts (and the integrating one its
    integral) in local variables (registers) during the batch, written back at its end, instead of being loaded
    and stored through arrays at every event (the compiler cannot keep those in registers, not knowing that the
    arrays do not overlap). Per event: O(1) plus the levels crossed; returns what :func:`side_update` returns.
    """
    p = ev[3]
    counts_on, counts_off, inv_n = counts
    hist, lev, kk, ss, start_t, c0_on, c0_off, w_last, w_int = slots
    rr = _ratios(kp)
    cap = hist.shape[3]
    n_on = counts_on[0]
    n_off = counts_off[0]
    inv = inv_n[0]
    ws = 0  # the first slot in locals: the integrating one if any (runs), else the first live one
    for j in range(live.shape[0]):
        if integ[live[j]]:
            ws = live[j]
    so = 0  # the second (0: none)
    for j in range(live.shape[0]):
        if live[j] != ws:
            if ws == 0:
                ws = live[j]
            else:
                so = live[j]
    runs = ws > 0 and integ[ws]
    wcol = 2 * (ws - 1)
    h1_on, h1_off = hist[ws, 0, 0], hist[ws, 1, 0]
    l1_on, k1_on, s1_on, l1_off, k1_off, s1_off = _slot_state(lev, kk, ss, ws, 0)
    wl = w_last[ws, 0] if runs else np.iinfo(np.int64).max  # (not integrating: never later than wl)
    wi = w_int[ws, 0]
    w_start = start_t[ws]
    base_on = c0_on[ws, 0]
    base_off = c0_off[ws, 0]
    ocol = 2 * (so - 1)
    h2_on, h2_off = hist[so, 0, 0], hist[so, 1, 0]
    l2_on, k2_on, s2_on, l2_off, k2_off, s2_off = _slot_state(lev, kk, ss, so, 0)
    prev, stop, code = last_t, -1, 0
    for i in range(ev[0].shape[0]):
        code, ti, pix = _event_pixel(ev, i, prev, width, height)
        if code != 0:
            stop = i
            break
        if not whole and zflat[pix] < 0:
            prev = ti
            continue
        on = p[i] > 0
        q = 0 if on else 1
        n1 = np.int64(pc[pix, wcol + q])  # the pixel's counts in the two local slots
        n2 = np.int64(pc[pix, ocol + q]) if so > 0 else np.int64(0)
        if n1 + 2 > cap or n2 + 2 > cap:
            stop = i
            code = 3
            break
        prev = ti
        if ti > wl:
            lks = (l1_on, k1_on, s1_on, l1_off, k1_off, s1_off)
            piece, lks = _window_step(ti, wl, w_start, n_on, n_off, base_on, base_off, inv, h1_on, h1_off, lks, kp, rr)
            l1_on, k1_on, s1_on, l1_off, k1_off, s1_off = lks
            wi += piece
            wl = ti
        pc[pix, wcol + q] = n1 + 1
        if so > 0:
            pc[pix, ocol + q] = n2 + 1
        if on:
            k1_on, s1_on = _count_up(h1_on, n1, l1_on, k1_on, s1_on)
            if so > 0:
                k2_on, s2_on = _count_up(h2_on, n2, l2_on, k2_on, s2_on)
            n_on += 1
        else:
            k1_off, s1_off = _count_up(h1_off, n1, l1_off, k1_off, s1_off)
            if so > 0:
                k2_off, s2_off = _count_up(h2_off, n2, l2_off, k2_off, s2_off)
            n_off += 1
    counts_on[0] = n_on
    counts_off[0] = n_off
    lev[ws, 0, 0], kk[ws, 0, 0], ss[ws, 0, 0] = l1_on, k1_on, s1_on
    lev[ws, 1, 0], kk[ws, 1, 0], ss[ws, 1, 0] = l1_off, k1_off, s1_off
    if runs:
        w_last[ws, 0] = wl
        w_int[ws, 0] = wi
    if so > 0:
        lev[so, 0, 0], kk[so, 0, 0], ss[so, 0, 0] = l2_on, k2_on, s2_on
        lev[so, 1, 0], kk[so, 1, 0], ss[so, 1, 0] = l2_off, k2_off, s2_off
    for j in range(live.shape[0]):  # the levels of the live slots not integrating follow time, once per batch
        s = live[j]
        if not integ[s] and prev >= start_t[s]:
            _follow_time(slots, s, 0, kp, rr, float(prev - start_t[s]))
    return stop, code, prev


@nb.njit(cache=True)
def side_close(t_end, s, counts, slots, kp, out):
    """An exposure from slot ``s``'s start ends at ``t_end``: ``out[z]`` = the slot's integral so far plus the
    closing piece (Eq. 13 from the last event to ``t_end``, no event between), computed on copies of the
    slot's levels (the slot's own stay for the other estimators whose exposures from it are still open).
    Bundles: see above. O(zones + levels crossed)."""
    counts_on, counts_off, inv_n = counts
    hist, lev, kk, ss, start_t, c0_on, c0_off, w_last, w_int = slots
    rr = _ratios(kp)
    for z in range(counts_on.shape[0]):
        m_on = (counts_on[z] - c0_on[s, z]) * inv_n[z]
        m_off = (counts_off[z] - c0_off[s, z]) * inv_n[z]
        lo, hi = float(w_last[s, z] - start_t[s]), float(t_end - start_t[s])
        lks = _slot_state(lev, kk, ss, s, z)
        out[z] = (
            w_int[s, z]
            + _one_window_integral(lo, hi, m_on, m_off, inv_n[z], hist[s, 0, z], hist[s, 1, z], lks, kp, rr)[0]
        )


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
