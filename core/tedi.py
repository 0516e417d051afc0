"""TEDI: the per-pixel trilinear event double integral (Eq. 5-6) and its calibration (Eq. 7).

Per pixel, with the 6-parameter compensation of :mod:`necviz.core.event_model`::

    ln L(g,x) = ln Lbar(x) - ln E_tri(g,x)                                  (Eq. 5)
    E_tri     = (1/T) ∫_s^e exp(c^T D(g,t,x)) dt
    c^T D     = c+ (n+ + D_c+) - c- (n- + D_c-),
    D_c±      = sign(t-g) max(0, a± |n±| - b± |t-g|)                        (Eq. 6)

The integral is exact: the counts are constant between two events of a pixel, so each
event-free stretch is integrated in closed form by
:func:`~necviz.core.event_model.segment_integral` (split at ``g``; ``u = |t-g|``,
``σ = sign(t-g)``). Conventions as in :mod:`necviz.core.edi` (an event at ``τ`` has happened
for ``t > τ``; ``g`` anywhere relative to the exposure).

Calibration (Eq. 7, with squared residuals as nec-method.md decides): for consecutive frames
``i-1, i`` and a common reference ``g`` (default: the exposure start of frame ``i-1``),
minimise ``Σ_i Σ_x (ln L_i(g,x) - ln L_{i-1}(g,x))^2`` over pixels valid in both frames with
``scipy.optimize.least_squares``.

Parameterisation: when both ``a±`` and ``b±`` of a polarity are fitted, the solver works on
``a±`` and the knee rate ``θ± = b±/a±`` (events/s), so ``D_c = a (m - θ u)``: the gradient in
``a±`` stays non-zero at ``a± = 0`` wherever a pixel fires faster than ``θ±``. (With ``(a, b)``
directly the cost is flat in both once ``a = 0 < b``, a trap observed in practice.) Fitting
``b±`` alone with ``a± = 0`` fixed cannot move: the compensation is then inactive.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
import scipy.optimize

from .crf import CameraResponse
from .edi import (
    check_crf,
    check_event_array,
    check_events_fit,
    check_frames,
    check_params,
    event_window,
    exposure_inputs,
    log_mean_irradiance,
    signed_counts_at,
    valid_mask,
)
from .errors import ParameterError
from .event_model import TediParams, segment_integral
from .frames import Frame

__all__ = ["TediCalibration", "calibrate_tedi", "tedi_reconstruct", "valid_mask", "PARAM_NAMES", "REFERENCES"]

PARAM_NAMES = ("c_on", "c_off", "a_on", "b_on", "a_off", "b_off")
REFERENCES = ("previous_start", "previous_end", "current_start", "current_end")


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
    return (segment_integral(0.0, float(g - t0), -1.0, m_on, m_off, c_on, c_off, a_on, b_on, a_off, b_off)
            + segment_integral(0.0, float(t1 - g), 1.0, m_on, m_off, c_on, c_off, a_on, b_on, a_off, b_off))


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


def tedi_reconstruct(events: np.ndarray, frame: Frame, g_us: int, params: TediParams,
                     crf: CameraResponse) -> np.ndarray:
    """TEDI: ``ln L(g,x) = ln Lbar(x) - ln E_tri(g,x)`` with the exact integral. O(events + pixels).

    ``events`` (sorted) may extend beyond ``[min(g,s), max(g,e)]``. With ``a = b = 0`` this is
    Fast-EDI. Returns float64 (H, W) for every pixel (see :func:`valid_mask`).
    """
    g, s, e, ev = exposure_inputs(events, frame, g_us, params, crf)
    h, w = frame.shape
    npix = h * w
    integral = tedi_exposure_integral(ev["t"], ev["x"], ev["y"], ev["p"], np.arange(npix, dtype=np.int64),
                                      w, npix, s, e, g, *params.as_tuple())
    return log_mean_irradiance(frame, crf) - np.log(integral / (e - s)).reshape(h, w)


# -- calibration (Eq. 7) ----------------------------------------------------------------------------


@dataclass(frozen=True)
class TediCalibration:
    """Result of :func:`calibrate_tedi`.

    ``cost`` is ``0.5 Σ r^2`` at the solution; ``rms_before``/``rms_after`` the RMS residual
    (ln units) at ``init`` and at the solution; ``num_pairs`` the frame pairs that contributed,
    ``num_residuals`` the pixel residuals per evaluation.
    """

    params: TediParams
    cost: float
    rms_before: float
    rms_after: float
    num_pairs: int
    num_residuals: int
    success: bool
    message: str


@dataclass
class _Side:
    """One frame of a pair, everything that does not depend on the parameters."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    p: np.ndarray
    s: int
    e: int
    log_lbar: np.ndarray  # ln Lbar of the selected pixels, in compact order


def _reference_time(reference: str, prev: Frame, cur: Frame) -> int:
    return {
        "previous_start": prev.exposure_start_us,
        "previous_end": prev.exposure_end_us,
        "current_start": cur.exposure_start_us,
        "current_end": cur.exposure_end_us,
    }[reference]


def calibrate_tedi(
    events: np.ndarray,
    frames,
    crf: CameraResponse,
    init: TediParams = TediParams(),
    reference: str = "previous_start",
    fit=PARAM_NAMES,
    max_pixels: int | None = 20_000,
    progress=None,
) -> TediCalibration:
    """Fit the TEDI parameters by frame-to-frame consistency (Eq. 7, squared residuals).

    For each pair of consecutive frames ``(i-1, i)`` and reference ``g`` (``reference``:
    ``"previous_start"`` = exposure start of frame ``i-1`` (default), ``"previous_end"``,
    ``"current_start"``, ``"current_end"``), the residual of a pixel valid in both frames is
    ``ln L_i(g,x) - ln L_{i-1}(g,x)`` by :func:`tedi_reconstruct`. ``fit`` names the parameters
    to optimise (the others stay at ``init``); bounds ``c in [0.01, 2]``, ``a, b >= 0``.
    ``max_pixels`` caps the pixels used per pair (an even subsample of the valid ones; ``None``:
    all). ``progress(evaluations, rms)`` is called after every residual evaluation.
    Event slices, ``ln Lbar`` and masks are computed once; each evaluation costs
    O(events + pixels) per pair.
    """
    frames = check_frames(frames)
    check_crf(crf)
    check_params(init)
    check_event_array(events)
    if len(frames) < 2:
        raise ParameterError(f"TEDI calibration needs at least 2 frames, got {len(frames)}")
    if reference not in REFERENCES:
        raise ParameterError(f"reference must be one of {REFERENCES}, got {reference!r}")
    fit = (fit,) if isinstance(fit, str) else tuple(fit)
    if not fit:
        raise ParameterError("fit names no parameter")
    bad = [n for n in fit if n not in PARAM_NAMES]
    if bad or len(set(fit)) != len(fit):
        raise ParameterError(f"fit must name distinct parameters among {PARAM_NAMES}, got {fit}")
    if max_pixels is not None and (isinstance(max_pixels, bool) or not isinstance(max_pixels, (int, np.integer))
                                   or max_pixels < 1):
        raise ParameterError(f"max_pixels must be a positive integer or None, got {max_pixels!r}")
    if progress is not None and not callable(progress):
        raise ParameterError("progress must be callable or None")
    h, w = frames[0].shape
    check_events_fit(events, (h, w))

    # --- precompute everything that does not depend on the parameters
    pairs = []
    num_res = 0
    for prev, cur in zip(frames[:-1], frames[1:]):
        g = int(_reference_time(reference, prev, cur))
        ok = (valid_mask(prev, crf) & valid_mask(cur, crf)).ravel()
        sel = np.flatnonzero(ok)
        if sel.size == 0:
            continue
        if max_pixels is not None and sel.size > max_pixels:
            sel = sel[np.linspace(0, sel.size - 1, int(max_pixels)).round().astype(np.int64)]
        pixmap = np.full(h * w, -1, np.int64)
        pixmap[sel] = np.arange(sel.size)
        sides = []
        for f in (prev, cur):
            s, e = int(f.exposure_start_us), int(f.exposure_end_us)
            ev = event_window(events, min(g, s), max(g, e), (h, w))
            keep = pixmap[ev["y"].astype(np.int64) * w + ev["x"]] >= 0
            ev = ev[keep]
            sides.append(_Side(ev["t"], ev["x"], ev["y"], ev["p"], s, e, log_mean_irradiance(f, crf).ravel()[sel]))
        pairs.append((g, pixmap, sel.size, sides[0], sides[1]))
        num_res += sel.size
    if not pairs:
        raise ParameterError("no pixel is valid (within the camera response's valid range) in two consecutive frames")

    names = list(PARAM_NAMES)
    base = np.array([getattr(init, n) for n in names], dtype=np.float64)
    # Internal variables, each O(1) after scaling. When both a± and b± of a polarity are fitted,
    # b± is replaced by the knee rate θ± = b±/a± (events/s): the compensation a (m - θ u) then
    # keeps a non-zero gradient in a± even when a± reaches 0, whereas with (a, b) the cost is
    # flat in both once a = 0 < b (observed to trap the fit).
    knee = {pol for pol in ("on", "off") if f"a_{pol}" in fit and f"b_{pol}" in fit}
    spec = []  # (internal name, index into the six, scale, lower, upper, start)
    for n in fit:
        i = names.index(n)
        v = base[i]
        if n.startswith("c_"):
            spec.append((n, i, 1.0, 0.01, 2.0, min(max(v, 0.01), 2.0)))
        elif n.startswith("a_"):
            spec.append((n, i, 1.0, 0.0, np.inf, v))
        elif n[2:] in knee:
            a0 = base[names.index("a_" + n[2:])]
            theta0 = v / a0 if a0 > 0 else v
            spec.append(("knee_" + n[2:], i, max(100.0, theta0), 0.0, np.inf, theta0))
        else:
            spec.append((n, i, max(100.0, v), 0.0, np.inf, v))
    scale = np.array([sp[2] for sp in spec])
    lb = np.array([sp[3] for sp in spec]) / scale
    ub = np.array([sp[4] for sp in spec]) / scale
    x0 = np.clip(np.array([sp[5] for sp in spec]) / scale, lb, ub)
    evaluations = 0

    def values(xv):
        v = base.copy()
        knees = {}
        for (name, i, *_), val in zip(spec, xv * scale):
            if name.startswith("knee_"):
                knees[i] = val
            else:
                v[i] = val
        for i, theta in knees.items():  # b = a θ, with the (possibly fitted) a of the polarity
            v[i] = v[names.index("a_" + names[i][2:])] * theta
        return v

    def residuals(xv):
        nonlocal evaluations
        c_on, c_off, a_on, b_on, a_off, b_off = values(xv)
        kp = (c_on, c_off, a_on, b_on * 1e-6, a_off, b_off * 1e-6)
        out = np.empty(num_res)
        pos = 0
        for g, pixmap, n, a, b in pairs:
            ia = tedi_exposure_integral(a.t, a.x, a.y, a.p, pixmap, w, n, a.s, a.e, g, *kp)
            ib = tedi_exposure_integral(b.t, b.x, b.y, b.p, pixmap, w, n, b.s, b.e, g, *kp)
            la = a.log_lbar - np.log(ia / (a.e - a.s))
            lb_ = b.log_lbar - np.log(ib / (b.e - b.s))
            out[pos:pos + n] = lb_ - la
            pos += n
        evaluations += 1
        if progress is not None:
            progress(evaluations, float(np.sqrt(np.mean(out ** 2))))
        return out

    r0 = residuals(x0)
    rms_before = float(np.sqrt(np.mean(r0 ** 2)))
    res = scipy.optimize.least_squares(residuals, x0, bounds=(lb, ub), method="trf", x_scale=1.0,
                                       diff_step=1e-3, xtol=1e-8, ftol=1e-10, gtol=1e-10, max_nfev=200)
    v = values(res.x)
    params = TediParams(**{n: float(val) for n, val in zip(names, v)})
    rms_after = float(np.sqrt(np.mean(res.fun ** 2)))
    return TediCalibration(params, float(res.cost), rms_before, rms_after, len(pairs), num_res,
                           bool(res.success), str(res.message))
