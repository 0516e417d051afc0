"""EDI, Fast-EDI and mEDI: the per-pixel latent log irradiance at a reference time ``g``.

All three evaluate Eq. 5 of the paper with the plain event model (``c±`` only; the TEDI
compensation terms ``a±, b±`` are ignored here, see :mod:`necviz.core.tedi`)::

    ln L(g,x) = ln Lbar(x) - ln E(g,x)
    E(g,x)    = (1/T) ∫_s^e exp(c^T D(g,t,x)) dt
    c^T D     = c+ n+(g,t,x) - c- n-(g,t,x)
    ln Lbar   = g(Z) - ln T - ln K                          (Eq. 1, crf.log_irradiance)

``n±(g,t,x)`` counts the pixel's ON/OFF events between ``g`` and ``t``, positive when
``t > g`` and negative when ``t < g`` (docs/method.md). Half-open convention: an event at time
``τ`` has happened for every time ``t > τ``, so ``n(g,t) = #{g <= τ < t}`` for ``t > g`` and
``-#{t <= τ < g}`` for ``t < g``. Moving forward in time past an event always adds ``+1``.
The reference ``g`` may lie before, inside or after the exposure ``[s, e]``.

* :func:`edi_reconstruct` — EDI (Pan et al. 2019): ``E`` by the midpoint rule,
  O(events + n_samples * pixels).
* :func:`fast_edi_reconstruct` — Fast-EDI (Lin et al. 2023): the exact integral of the
  piecewise-constant integrand from per-pixel event buffers, O(events + pixels).
* :func:`medi_reconstruct` — mEDI (Pan et al. 2020): one latent image shared by several
  frames, least squares in the linear domain.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from necviz.core.crf import CameraResponse
from necviz.core.errors import EventFormatError, FrameFormatError, ParameterError
from necviz.core.event_model import TediParams
from necviz.core.events import EVENT_DTYPE
from necviz.core.frames import Frame

# -- kernels ----------------------------------------------------------------------------------


@nb.njit(cache=True)
def signed_counts_at(t, x, y, p, pixmap, width, npix, g, t_ref):
    """Per-pixel signed direct integral ``n±(g, t_ref, x)`` (the ``D`` of Eq. 5/6, plain counts).

    ``+1`` for each event with ``g <= τ < t_ref``, ``-1`` for each with ``t_ref <= τ < g``;
    every other event is ignored, so the batch may extend beyond ``[min(g,t_ref), max(g,t_ref))``.
    ``pixmap[y*width + x]`` is the pixel's output index (``-1``: skip the pixel).
    ``t_ref`` may be fractional. O(events + pixels).
    """
    n_on = np.zeros(npix, np.int64)
    n_off = np.zeros(npix, np.int64)
    for i in range(t.shape[0]):
        ti = t[i]
        if g <= ti and ti < t_ref:
            sgn = 1
        elif t_ref <= ti and ti < g:
            sgn = -1
        else:
            continue
        k = pixmap[np.int64(y[i]) * width + np.int64(x[i])]
        if k < 0:
            continue
        if p[i] > 0:
            n_on[k] += sgn
        else:
            n_off[k] += sgn
    return n_on, n_off


@nb.njit(cache=True)
def edi_exposure_mean(t, x, y, p, width, height, s, e, g, n_samples, c_on, c_off):
    """EDI (Pan et al. 2019): ``E(g,x) = (1/T) ∫_s^e exp(c^T D(g,t,x)) dt`` by the midpoint rule.

    Eq. 5 with the plain model (Eq. 6 without ``D_c``): samples ``t_k = s + (k + 1/2) T / K``;
    the signed counts at ``t_0`` come from one pass over the events between ``g`` and ``t_0``,
    then for each sample the events before ``t_k`` are added and ``exp(c^T D)`` accumulated
    over all pixels. Events must be sorted by time. O(events + n_samples * pixels).
    Returns ``E`` per pixel (flat, row-major).
    """
    npix = width * height
    pixmap = np.arange(npix)
    dt = (e - s) / n_samples
    t0 = s + 0.5 * dt
    n_on, n_off = signed_counts_at(t, x, y, p, pixmap, width, npix, g, t0)
    n = t.shape[0]
    j = 0
    while j < n and t[j] < t0:
        j += 1
    acc = np.zeros(npix)
    for k in range(n_samples):
        tk = s + (k + 0.5) * dt
        while j < n and t[j] < tk:
            q = np.int64(y[j]) * width + np.int64(x[j])
            if p[j] > 0:
                n_on[q] += 1
            else:
                n_off[q] += 1
            j += 1
        for q in range(npix):
            acc[q] += math.exp(c_on * n_on[q] - c_off * n_off[q])
    for q in range(npix):
        acc[q] /= n_samples
    return acc


@nb.njit(cache=True)
def fast_edi_exposure_integral(t, x, y, p, width, height, s, e, g, c_on, c_off):
    """Fast-EDI (Lin et al. 2023): ``∫_s^e exp(c^T D(g,t,x)) dt`` exactly (Eq. 5, plain model).

    The integrand is piecewise constant per pixel. Each pixel's buffer is a linked list
    (``head``/``tail``/``nxt`` over one preallocated pool): its first node holds
    ``exp(c^T D(g,s))``; on each event in ``[s, e)`` the pixel's running ``c^T D`` is updated,
    ``exp`` computed once and ``(t, value)`` appended. One pass over the buffers then sums
    ``value * (next time - time)``. O(events + pixels) time, O(pixels + events in window) memory.
    Returns the integral per pixel (flat, row-major); divide by ``T`` for ``E``.
    """
    npix = width * height
    pixmap = np.arange(npix)
    n_on, n_off = signed_counts_at(t, x, y, p, pixmap, width, npix, g, s)
    n = t.shape[0]
    m = 0
    for i in range(n):
        if s <= t[i] and t[i] < e:
            m += 1
    pool_t = np.empty(npix + m, np.int64)
    pool_v = np.empty(npix + m)
    nxt = np.full(npix + m, -1, np.int64)
    head = np.empty(npix, np.int64)
    tail = np.empty(npix, np.int64)
    for q in range(npix):
        pool_t[q] = s
        pool_v[q] = math.exp(c_on * n_on[q] - c_off * n_off[q])
        head[q] = q
        tail[q] = q
    used = npix
    for i in range(n):
        ti = t[i]
        if ti < s or ti >= e:
            continue
        q = np.int64(y[i]) * width + np.int64(x[i])
        if p[i] > 0:
            n_on[q] += 1
        else:
            n_off[q] += 1
        pool_t[used] = ti
        pool_v[used] = math.exp(c_on * n_on[q] - c_off * n_off[q])
        nxt[tail[q]] = used
        tail[q] = used
        used += 1
    acc = np.zeros(npix)
    for q in range(npix):
        node = head[q]
        total = 0.0
        while node >= 0:
            nn = nxt[node]
            t_end = pool_t[nn] if nn >= 0 else e
            total += pool_v[node] * (t_end - pool_t[node])
            node = nn
        acc[q] = total
    return acc


# -- input checks shared with tedi.py ------------------------------------------------------------


def check_params(params) -> TediParams:
    if not isinstance(params, TediParams):
        raise ParameterError(f"params must be a TediParams, got {type(params).__name__}")
    return params


def check_crf(crf) -> CameraResponse:
    if not isinstance(crf, CameraResponse):
        raise ParameterError(f"crf must be a CameraResponse, got {type(crf).__name__}")
    return crf


def check_time(g_us, name: str = "reference time g_us") -> int:
    if isinstance(g_us, bool) or not isinstance(g_us, (int, np.integer)):
        raise ParameterError(f"{name} must be an integer (µs), got {g_us!r}")
    return int(g_us)


def check_frame(frame) -> Frame:
    if not isinstance(frame, Frame):
        raise FrameFormatError(f"frame must be a necviz Frame, got {type(frame).__name__}")
    return frame


def check_frames(frames) -> list[Frame]:
    """A non-empty list of frames of one shape."""
    if isinstance(frames, Frame):
        frames = [frames]
    try:
        frames = list(frames)
    except TypeError:
        raise FrameFormatError(f"frames must be a sequence of Frame, got {type(frames).__name__}") from None
    if not frames:
        raise FrameFormatError("no frames given")
    for f in frames:
        check_frame(f)
    shape = frames[0].shape
    for f in frames[1:]:
        if f.shape != shape:
            raise FrameFormatError(
                f"frames have different shapes: frame {frames[0].sequence} is {shape[1]}x{shape[0]}, "
                f"frame {f.sequence} is {f.shape[1]}x{f.shape[0]}"
            )
    return frames


def check_event_array(events) -> np.ndarray:
    if not isinstance(events, np.ndarray) or events.dtype != EVENT_DTYPE or events.ndim != 1:
        desc = f"{events.dtype} {events.shape}" if isinstance(events, np.ndarray) else type(events).__name__
        raise EventFormatError(f"events must be a 1-D array of dtype {EVENT_DTYPE}, got {desc}")
    return events


def check_events_fit(ev: np.ndarray, shape: tuple[int, int]) -> None:
    """Sorted time and coordinates on the ``shape`` (H, W) frame; vectorised, before any kernel."""
    if ev.size == 0:
        return
    t = ev["t"]
    if ev.size > 1 and np.any(t[1:] < t[:-1]):
        i = int(np.flatnonzero(t[1:] < t[:-1])[0])
        raise EventFormatError(f"event times must not decrease: {int(t[i + 1])} µs follows {int(t[i])} µs")
    h, w = shape
    if int(ev["x"].max()) >= w or int(ev["y"].max()) >= h:
        i = int(np.flatnonzero((ev["x"] >= w) | (ev["y"] >= h))[0])
        raise EventFormatError(f"event at (x={int(ev['x'][i])}, y={int(ev['y'][i])}) lies outside the {w}x{h} frame")


def event_window(events: np.ndarray, lo_us: int, hi_us: int, shape: tuple[int, int]) -> np.ndarray:
    """The events with ``lo_us <= t < hi_us`` (a view), checked against the frame ``shape``."""
    check_event_array(events)
    t = events["t"]
    i0, i1 = np.searchsorted(t, [lo_us, hi_us], side="left")
    ev = events[i0:i1]
    check_events_fit(ev, shape)
    return ev


def log_mean_irradiance(frame: Frame, crf: CameraResponse) -> np.ndarray:
    """``ln Lbar(x) = g(Z) - ln T - ln K`` (Eq. 1) as float64 (H, W)."""
    return np.asarray(crf.log_irradiance(frame.image, frame.exposure_us, frame.gain), dtype=np.float64)


def exposure_inputs(events, frame, g_us, params, crf):
    """Check the inputs every single-frame reconstruction shares; return ``(g, s, e, events in the window)``.

    The window is ``[min(g, s), max(g, e))``: the events between the reference and the exposure.
    """
    check_frame(frame)
    check_params(params)
    check_crf(crf)
    g = check_time(g_us)
    s, e = int(frame.exposure_start_us), int(frame.exposure_end_us)
    return g, s, e, event_window(events, min(g, s), max(g, e), frame.shape)


def valid_mask(frame: Frame, crf: CameraResponse) -> np.ndarray:
    """Pixels whose digital value lies in ``crf.valid_min..crf.valid_max`` (bool, H x W)."""
    check_frame(frame)
    check_crf(crf)
    z = frame.image
    return (z >= crf.valid_min) & (z <= crf.valid_max)


def _check_n_samples(n_samples) -> int:
    if isinstance(n_samples, bool) or not isinstance(n_samples, (int, np.integer)) or n_samples < 1:
        raise ParameterError(f"n_samples must be an integer >= 1, got {n_samples!r}")
    return int(n_samples)


def _edi_log_e(events, frame, g, params, n_samples) -> np.ndarray:
    """``ln E(g,x)`` by EDI sampling (H, W); inputs already checked."""
    s, e = int(frame.exposure_start_us), int(frame.exposure_end_us)
    h, w = frame.shape
    ev = event_window(events, min(g, s), max(g, e), frame.shape)
    mean = edi_exposure_mean(ev["t"], ev["x"], ev["y"], ev["p"], w, h, s, e, g, n_samples, params.c_on, params.c_off)
    return np.log(mean).reshape(h, w)


# -- public API ---------------------------------------------------------------------------------


def edi_reconstruct(
    events: np.ndarray, frame: Frame, g_us: int, params: TediParams, crf: CameraResponse, n_samples: int = 64
) -> np.ndarray:
    """EDI: ``ln L(g,x) = ln Lbar(x) - ln E(g,x)`` with ``E`` by the midpoint rule (``n_samples``).

    Uses only ``params.c_on``/``c_off``. ``events`` (sorted) may extend beyond the needed
    interval ``[min(g,s), max(g,e)]``. Returns float64 (H, W) for every pixel (saturated pixels
    included; see :func:`valid_mask`). O(events + n_samples * pixels).
    """
    check_frame(frame)
    check_params(params)
    check_crf(crf)
    g = check_time(g_us)
    n_samples = _check_n_samples(n_samples)
    return log_mean_irradiance(frame, crf) - _edi_log_e(events, frame, g, params, n_samples)


def fast_edi_reconstruct(
    events: np.ndarray, frame: Frame, g_us: int, params: TediParams, crf: CameraResponse
) -> np.ndarray:
    """Fast-EDI: EDI with the exact integral from per-pixel event buffers. O(events + pixels).

    Uses only ``params.c_on``/``c_off``; returns ``ln L(g,x)`` float64 (H, W).
    """
    g, s, e, ev = exposure_inputs(events, frame, g_us, params, crf)
    h, w = frame.shape
    integral = fast_edi_exposure_integral(ev["t"], ev["x"], ev["y"], ev["p"], w, h, s, e, g, params.c_on, params.c_off)
    return log_mean_irradiance(frame, crf) - np.log(integral / (e - s)).reshape(h, w)


def medi_reconstruct(
    events: np.ndarray, frames, g_us: int, params: TediParams, crf: CameraResponse, n_samples: int = 64
) -> np.ndarray:
    """mEDI: one latent image at ``g`` shared by several frames, least squares in the linear domain.

    Each frame ``i`` gives ``Bbar_i = exp(ln Lbar_i)`` and ``E_i(g,x)`` (EDI sampling); per pixel,
    over the frames where it is valid (``crf.valid_min <= Z <= crf.valid_max``),
    ``L(g) = Σ Bbar_i E_i / Σ E_i^2`` (minimises ``Σ (Bbar_i - L E_i)^2``). Returns ``ln L(g,x)``
    float64 (H, W), NaN where no frame is valid. With one frame it equals :func:`edi_reconstruct`
    on valid pixels. O(frames * (events + n_samples * pixels)).
    """
    frames = check_frames(frames)
    check_params(params)
    check_crf(crf)
    g = check_time(g_us)
    n_samples = _check_n_samples(n_samples)
    shape = frames[0].shape
    num = np.zeros(shape)
    den = np.zeros(shape)
    for f in frames:
        ok = valid_mask(f, crf)
        if not ok.any():
            continue
        log_e = _edi_log_e(events, f, g, params, n_samples)
        log_b = log_mean_irradiance(f, crf)
        num[ok] += np.exp(log_b[ok] + log_e[ok])
        den[ok] += np.exp(2.0 * log_e[ok])
    out = np.full(shape, np.nan)
    has = den > 0
    out[has] = np.log(num[has]) - np.log(den[has])
    return out
