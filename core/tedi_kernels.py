"""TEDI's Numba kernels: the exact per-pixel exposure integral of Eq. 5 with the Eq. 6 compensation.

Each event-free stretch of a pixel is integrated in closed form by
:func:`~necviz.core.event_model.segment_integral` (:func:`stretch_integral`);
:func:`tedi_exposure_integral` sweeps the events of a sensor-sized pixel map (used by
:func:`necviz.core.tedi.tedi_reconstruct`), :func:`tedi_integral_compact` the events of the pixels a
calibration pair keeps (Eq. 7, :mod:`necviz.core.tedi`), and :func:`update_last_polarity` records
each pixel's latest polarity (the calibration's continuation rule). The equations and conventions
are in :mod:`necviz.core.tedi`'s docstring.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from necviz.core.edi import signed_counts_at
from necviz.core.event_model import segment_integral


@nb.njit(cache=True)
def stretch_integral(t0, t1, g, n_on, n_off, c_on, c_off, a_on, b_on, a_off, b_off):
    """``∫_{t0}^{t1} exp(c^T D(g,t)) dt`` with constant signed counts ``n±`` (Eq. 5-6 integrand).

    Splits the stretch at ``g`` and hands each side to :func:`segment_integral` with
    ``u = |t - g|`` and ``σ = sign(t - g)``. ``b±`` per µs. O(1).
    """
    if t1 <= t0:
        return 0.0
    m_on = float(abs(n_on))
    m_off = float(abs(n_off))
    if t0 >= g:
        return segment_integral(float(t0 - g), float(t1 - g), 1.0, m_on, m_off, c_on, c_off, a_on, b_on, a_off, b_off)
    if t1 <= g:
        return segment_integral(float(g - t1), float(g - t0), -1.0, m_on, m_off, c_on, c_off, a_on, b_on, a_off, b_off)
    return segment_integral(
        0.0, float(g - t0), -1.0, m_on, m_off, c_on, c_off, a_on, b_on, a_off, b_off
    ) + segment_integral(0.0, float(t1 - g), 1.0, m_on, m_off, c_on, c_off, a_on, b_on, a_off, b_off)


@nb.njit(cache=True)
def tedi_exposure_integral(t, x, y, p, pixmap, width, npix, s, e, g, c_on, c_off, a_on, b_on, a_off, b_off):
    """TEDI: ``∫_s^e exp(c^T D(g,t,x)) dt`` per pixel, exact (Eq. 5 with the Eq. 6 compensation).

    One pass gives the signed counts at ``s`` (events between ``g`` and ``s``); then a
    time-ordered sweep over the events in ``[s, e)`` keeps per-pixel state (signed counts,
    time of the last event, accumulated integral): at each event the pixel's event-free
    stretch since its last event is integrated in closed form (:func:`stretch_integral`) and
    its count updated; finally every pixel's last stretch up to ``e`` is added. No buffers.
    ``pixmap[y*width + x]`` maps a pixel to its output index (``-1``: ignore its events).
    Events must be sorted by time and may extend beyond ``[min(g,s), max(g,e))``.
    O(events + pixels) time, O(pixels) memory. ``b±`` per µs.
    """
    n_on, n_off = signed_counts_at(t, x, y, p, pixmap, width, npix, g, s)
    last = np.full(npix, s, np.int64)
    acc = np.zeros(npix)
    for i in range(t.shape[0]):
        ti = t[i]
        if ti < s:
            continue
        if ti >= e:
            break
        k = pixmap[np.int64(y[i]) * width + np.int64(x[i])]
        if k < 0:
            continue
        if ti > last[k]:
            acc[k] += stretch_integral(last[k], ti, g, n_on[k], n_off[k], c_on, c_off, a_on, b_on, a_off, b_off)
            last[k] = ti
        if p[i] > 0:
            n_on[k] += 1
        else:
            n_off[k] += 1
    for k in range(npix):
        acc[k] += stretch_integral(last[k], e, g, n_on[k], n_off[k], c_on, c_off, a_on, b_on, a_off, b_off)
    return acc


@nb.njit(cache=True)
def tedi_integral_compact(t, k, p, npix, s, e, g, c_on, c_off, a_on, b_on, a_off, b_off):
    """:func:`tedi_exposure_integral` for events already mapped to compact pixel indices.

    ``k[i]`` in ``0..npix-1`` is the output index of event ``i``'s pixel (the calibration keeps
    only the pixels it uses, so no sensor-sized map is stored per frame pair). Same conventions:
    events sorted by time, possibly extending beyond ``[min(g,s), max(g,e))``; ``b±`` per µs.
    Returns ``∫_s^e exp(c^T D(g,t,x)) dt`` per pixel (Eq. 5-6). O(events + pixels).
    """
    n_on = np.zeros(npix, np.int64)
    n_off = np.zeros(npix, np.int64)
    for i in range(t.shape[0]):  # signed counts between g and s
        ti = t[i]
        if g <= ti and ti < s:
            sgn = 1
        elif s <= ti and ti < g:
            sgn = -1
        else:
            continue
        if p[i] > 0:
            n_on[k[i]] += sgn
        else:
            n_off[k[i]] += sgn
    last = np.full(npix, s, np.int64)
    acc = np.zeros(npix)
    for i in range(t.shape[0]):
        ti = t[i]
        if ti < s:
            continue
        if ti >= e:
            break
        j = k[i]
        if ti > last[j]:
            acc[j] += stretch_integral(last[j], ti, g, n_on[j], n_off[j], c_on, c_off, a_on, b_on, a_off, b_off)
            last[j] = ti
        if p[i] > 0:
            n_on[j] += 1
        else:
            n_off[j] += 1
    for j in range(npix):
        acc[j] += stretch_integral(last[j], e, g, n_on[j], n_off[j], c_on, c_off, a_on, b_on, a_off, b_off)
    return acc


@nb.njit(cache=True)
def update_last_polarity(x, y, p, width, last):
    """``last[y*width + x] = ±1``: the polarity of each pixel's latest event, events in time order. O(events)."""
    for i in range(x.shape[0]):
        last[np.int64(y[i]) * width + np.int64(x[i])] = 1 if p[i] > 0 else -1
