"""P-TEDI's event kernels without compensation (Eq. 11-14 with ``a± = 0``) and the frame pass of Eq. 15.

The streaming estimator (:class:`necviz.core.ptedi.PeripheralEstimator`, whose module docstring
derives the equations) calls these Numba kernels: :func:`ptedi_update` for zones,
:func:`ptedi_update_whole` for the whole-sensor region (coordinates not read),
:func:`ptedi_close` at an exposure's end, :func:`digit_histogram` once per frame.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True)
def ptedi_update(
    t,
    x,
    y,
    p,
    zmap,
    last_t,
    counts_on,
    counts_off,
    inv_n,
    f_on,
    f_off,
    w,
    c0_on,
    c0_off,
    w_last,
    w_int,
    w_ebase,
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


@nb.njit(cache=True)
def digit_histograms(z, zones, num_zones):
    """Per zone, the count of each digit 0..255 of an 8-bit image (``zones[i] < 0``: pixel ignored).
    One pass, O(pixels); ``np.bincount`` would first widen the image to 64-bit integers."""
    out = np.zeros((num_zones, 256), np.int64)
    for i in range(z.shape[0]):
        k = zones[i]
        if k >= 0:
            out[k, z[i]] += 1
    return out


@nb.njit(cache=True)
def digit_histogram(z):
    """:func:`digit_histograms` for one zone covering the image (four interleaved partial histograms,
    so runs of equal digits do not serialise on one counter)."""
    part = np.zeros((4, 256), np.int64)
    n = z.shape[0]
    m = n - n % 4
    for i in range(0, m, 4):
        part[0, z[i]] += 1
        part[1, z[i + 1]] += 1
        part[2, z[i + 2]] += 1
        part[3, z[i + 3]] += 1
    for i in range(m, n):
        part[0, z[i]] += 1
    out = np.zeros((1, 256), np.int64)
    for k in range(4):
        for d in range(256):
            out[0, d] += part[k, d]
    return out
