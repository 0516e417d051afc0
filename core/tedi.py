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
for ``t > τ``; ``g`` anywhere relative to the exposure). The Numba kernels that evaluate it
(:func:`stretch_integral`, :func:`tedi_exposure_integral`, :func:`tedi_integral_compact`,
:func:`update_last_polarity`) live in :mod:`necviz.core.tedi_kernels` and are re-exported here.

Calibration (Eq. 7, with squared residuals; see docs/method.md): for consecutive frames
``i-1, i`` and a common reference ``g`` (default: the exposure start of frame ``i-1``),
minimise ``Σ_i Σ_x (ln L_i(g,x) - ln L_{i-1}(g,x))^2`` over pixels valid in both frames with
``scipy.optimize.least_squares``.

Parameterisation: when both ``a±`` and ``b±`` of a polarity are fitted, the solver works on
``a±`` and the knee rate ``θ± = b±/a±`` (events/s), so ``D_c = a (m - θ u)``: the gradient in
``a±`` stays non-zero at ``a± = 0`` wherever a pixel fires faster than ``θ±``. (With ``(a, b)``
directly the cost is flat in both once ``a = 0 < b``, a trap observed in practice.) Fitting
``b±`` alone with ``a± = 0`` fixed cannot move: the compensation is then inactive. A knee of
zero makes the compensation ``a m`` a mere rescaling of ``c`` (``c (1 + a)``), so
:func:`fit_tedi_pairs` can bound the knee below (:attr:`TediFitOptions.knee_min`).

Two layers: :func:`prepare_pair` selects the pixels of one frame pair and keeps only their
events (:class:`CalibrationPair`, compact: nothing sensor-sized is stored per pair), and
:func:`fit_tedi_pairs` fits on any list of such pairs — from one array of events
(:func:`calibrate_tedi`) or streamed from long recordings and simulator runs
(:mod:`necviz.calibration`, which also picks the pairs).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.optimize

from necviz.core.crf import CameraResponse
from necviz.core.edi import (
    check_crf,
    check_event_array,
    check_events_fit,
    check_frames,
    check_params,
    event_window,
    exposure_inputs,
    log_mean_irradiance,
    valid_mask,
)
from necviz.core.errors import ParameterError
from necviz.core.event_model import TediParams
from necviz.core.frames import Frame
from necviz.core.tedi_kernels import (
    tedi_exposure_integral,
    tedi_integral_compact,
    update_last_polarity,
)

__all__ = [
    "CalibrationPair",
    "PairSelection",
    "TediCalibration",
    "TediFitOptions",
    "calibrate_tedi",
    "fit_tedi_pairs",
    "last_polarity_before",
    "pair_residuals",
    "prepare_pair",
    "tedi_reconstruct",
    "valid_mask",
    "PARAM_NAMES",
    "REFERENCES",
    "LOSSES",
]

PARAM_NAMES = ("c_on", "c_off", "a_on", "b_on", "a_off", "b_off")
REFERENCES = ("previous_start", "previous_end", "current_start", "current_end")
PEAK_BIN_US = 2_000  # bin of CalibrationPair.peak_rate


def tedi_reconstruct(
    events: np.ndarray, frame: Frame, g_us: int, params: TediParams, crf: CameraResponse
) -> np.ndarray:
    """TEDI: ``ln L(g,x) = ln Lbar(x) - ln E_tri(g,x)`` with the exact integral. O(events + pixels).

    ``events`` (sorted) may extend beyond ``[min(g,s), max(g,e)]``. With ``a = b = 0`` this is
    Fast-EDI. Returns float64 (H, W) for every pixel (see :func:`valid_mask`).
    """
    g, s, e, ev = exposure_inputs(events, frame, g_us, params, crf)
    h, w = frame.shape
    npix = h * w
    integral = tedi_exposure_integral(
        ev["t"], ev["x"], ev["y"], ev["p"], np.arange(npix, dtype=np.int64), w, npix, s, e, g, *params.as_tuple()
    )
    return log_mean_irradiance(frame, crf) - np.log(integral / (e - s)).reshape(h, w)


# -- calibration (Eq. 7) ----------------------------------------------------------------------------


@dataclass(frozen=True)
class TediCalibration:
    """Result of :func:`calibrate_tedi` / :func:`fit_tedi_pairs`.

    ``cost`` is ``0.5 Σ r^2`` at the solution; ``rms_before``/``rms_after`` the RMS residual
    (ln units) at ``init`` and at the solution; ``num_pairs`` the frame pairs that contributed,
    ``num_residuals`` the pixel residuals per evaluation. ``pair_rms_before``/``pair_rms_after``
    the RMS residual of each pair (same order as the pairs). ``stderr``: the standard error of
    each fitted parameter from the Gauss-Newton covariance ``s² (JᵀJ)⁻¹`` (``s²`` = residual
    variance; it assumes independent residuals, so read it as a lower bound), NaN for parameters
    not fitted or held at a bound (``at_bound``). ``evaluations``: residual evaluations used.
    ``inactive``: polarities (``"on"``/``"off"``) whose fitted compensation acted on no pixel of
    the data (its knee above every rate seen); their ``a, b`` are reported as 0, which gives
    exactly the same residuals.
    """

    params: TediParams
    cost: float
    rms_before: float
    rms_after: float
    num_pairs: int
    num_residuals: int
    success: bool
    message: str
    pair_rms_before: tuple = ()
    pair_rms_after: tuple = ()
    stderr: dict = field(default_factory=dict)
    at_bound: tuple = ()
    evaluations: int = 0
    inactive: tuple = ()


@dataclass
class CalibrationPair:
    """Two consecutive frames ``i-1, i`` prepared for Eq. 7: everything that does not depend on the
    parameters or on the camera response ``g``.

    ``t, k, p``: the events of the used pixels in ``[min(g, s_prev), max(g, e_cur))`` (time, compact
    pixel index ``0..n-1``, polarity); ``z_prev``/``z_cur`` the digital values of the used pixels.
    ``valid_pixels``: pixels valid in both frames before the change threshold and the subsample;
    ``events_per_pixel``: events per used pixel in the window; ``mean_abs_change``: mean
    ``|ln Lbar_i - ln Lbar_{i-1}|`` of the used pixels (response used for the selection);
    ``peak_rate``: the highest event rate per used pixel (events/s) in 2 ms bins of the window,
    a measure of how fast the scene changed (aggregated over all used pixels);
    ``bus_peak_rate``: the highest sensor-wide event rate (all pixels, events/s, 1 ms bins) in the
    window, set by the caller that has all events (0 if unknown): near the sensor's bus ceiling
    events were dropped.
    Memory: 13 bytes per event plus 2 per pixel.
    """

    g: int
    t: np.ndarray
    k: np.ndarray
    p: np.ndarray
    z_prev: np.ndarray
    z_cur: np.ndarray
    s_prev: int
    e_prev: int
    gain_prev: float
    s_cur: int
    e_cur: int
    gain_cur: float
    seq_prev: int = 0
    seq_cur: int = 0
    valid_pixels: int = 0
    events_per_pixel: float = 0.0
    mean_abs_change: float = 0.0
    peak_rate: float = 0.0
    bus_peak_rate: float = 0.0
    source: str = ""

    @property
    def n(self) -> int:
        return int(self.z_prev.size)

    @property
    def nbytes(self) -> int:
        return int(self.t.nbytes + self.k.nbytes + self.p.nbytes + self.z_prev.nbytes + self.z_cur.nbytes)

    def log_lbar(self, crf: CameraResponse) -> tuple[np.ndarray, np.ndarray]:
        """``ln Lbar = g(Z) - ln T - ln K`` (Eq. 1) of the used pixels in both frames."""
        a = np.asarray(crf.log_irradiance(self.z_prev, self.e_prev - self.s_prev, self.gain_prev), np.float64)
        b = np.asarray(crf.log_irradiance(self.z_cur, self.e_cur - self.s_cur, self.gain_cur), np.float64)
        return a, b

    def stats(self) -> dict:
        """Plain numbers describing the pair (for reports)."""
        return {
            "source": self.source,
            "frames": [int(self.seq_prev), int(self.seq_cur)],
            "t_us": [int(self.s_prev), int(self.e_cur)],
            "exposure_us": [int(self.e_prev - self.s_prev), int(self.e_cur - self.s_cur)],
            "gain": [float(self.gain_prev), float(self.gain_cur)],
            "pixels": self.n,
            "valid_pixels": int(self.valid_pixels),
            "events_per_pixel": round(float(self.events_per_pixel), 4),
            "events_per_pixel_per_s": round(float(self.events_per_pixel) * 1e6 / max(1, self.e_cur - self.s_prev), 2),
            "mean_abs_change": round(float(self.mean_abs_change), 4),
            "peak_rate_per_pixel": round(float(self.peak_rate), 1),
            "bus_peak_rate_mev_s": round(float(self.bus_peak_rate) / 1e6, 3),
        }


def _reference_time(reference: str, prev: Frame, cur: Frame) -> int:
    return {
        "previous_start": prev.exposure_start_us,
        "previous_end": prev.exposure_end_us,
        "current_start": cur.exposure_start_us,
        "current_end": cur.exposure_end_us,
    }[reference]


def _check_count(name: str, v, allow_none: bool = False, minimum: int = 1) -> None:
    if v is None and allow_none:
        return
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < minimum:
        extra = " or None" if allow_none else ""
        raise ParameterError(f"{name} must be an integer >= {minimum}{extra}, got {v!r}")


@dataclass(frozen=True)
class PairSelection:
    """Which pixels of a frame pair Eq. 7 uses (:func:`prepare_pair`); validated here, once.

    Parameters
    ----------
    reference : str
        The common reference time ``g``: one of :data:`REFERENCES` (``"previous_start"``, the
        exposure start of frame ``i-1``, by default; see :func:`calibrate_tedi`).
    max_pixels : int, optional
        At most this many pixels per pair (an even subsample of those that qualify); ``None``: all.
    min_change : float
        A pixel is used only if its frame-measured change ``|ln Lbar_i - ln Lbar_{i-1}|`` is at
        least this (ln units, >= 0).
    min_pixels : int
        A pair with fewer qualifying pixels is rejected (>= 1).

    Raises
    ------
    ParameterError
        An unknown reference, a pixel count that is not an integer >= 1, or a negative or
        non-finite ``min_change``.
    """

    reference: str = "previous_start"
    max_pixels: int | None = 20_000
    min_change: float = 0.0
    min_pixels: int = 1

    def __post_init__(self) -> None:
        if self.reference not in REFERENCES:
            raise ParameterError(f"reference must be one of {REFERENCES}, got {self.reference!r}")
        _check_count("max_pixels", self.max_pixels, allow_none=True)
        _check_count("min_pixels", self.min_pixels, minimum=1)
        c = self.min_change
        if isinstance(c, bool) or not isinstance(c, (int, float, np.floating)) or not (np.isfinite(c) and c >= 0):
            raise ParameterError(f"min_change must be a number >= 0 (ln units), got {c!r}")


def prepare_pair(
    events: np.ndarray,
    prev: Frame,
    cur: Frame,
    crf: CameraResponse,
    *,
    selection: PairSelection | None = None,
    last_polarity: np.ndarray | None = None,
    mask: np.ndarray | None = None,
    source: str = "",
) -> CalibrationPair | None:
    """Select the pixels of one frame pair for Eq. 7 and keep their events; ``None`` if too few qualify.

    A pixel is used when its digital value is valid (``crf.valid_min..valid_max``) in both frames
    and its frame-measured change ``|ln Lbar_i - ln Lbar_{i-1}|`` is at least
    ``selection.min_change`` (ln units). Selecting on the frames, not on the event counts, keeps the
    selection independent of the event quantisation noise (selecting on counts would bias the
    thresholds). When more than ``selection.max_pixels`` qualify an even subsample is kept. The pair
    is rejected (``None``) when fewer than ``selection.min_pixels`` qualify. ``events`` must be
    sorted and cover ``[min(g, s_prev), max(g, e_cur))`` (``g`` from ``selection.reference``, see
    :func:`calibrate_tedi`); they may extend beyond it.

    ``last_polarity`` (flat or (H, W) int8: each pixel's last event polarity before ``s_prev``,
    0 for none; :func:`last_polarity_before`) enables the *continuation rule*: a pixel is used only
    when its change continues in the direction of its previous event (``sign(change) ==
    last_polarity``). A DVS pixel is a hysteretic quantiser: after ON events its reference lies
    below the level (by ``[0, c+)``), after OFF events above it, so the first change after a
    reversal emits on average about ``(c+ + c-) / 2`` less than the model credits, which Eq. 7
    would absorb into larger thresholds. The rule uses the history before the pair and the
    frames, never the pair's own event counts.

    ``mask`` (bool, flat or (H, W)): the pixels to use, selected by the caller with the same rules
    (:class:`necviz.calibration.PairCollector` caches the per-frame arrays); it replaces the
    selection above (``selection.min_change`` and ``last_polarity`` are then ignored).

    Parameters
    ----------
    events : numpy.ndarray
        Sorted events (``EVENT_DTYPE``) covering the pair's window.
    prev, cur : Frame
        Frames ``i-1`` and ``i`` (same shape).
    crf : CameraResponse
        The camera response ``g``.
    selection : PairSelection, optional
        Which pixels qualify (default: ``PairSelection()``).
    last_polarity, mask : numpy.ndarray, optional
        The continuation rule's history, or the caller's own selection (above).
    source : str
        Where the pair comes from (kept in :class:`CalibrationPair` for reports).

    Returns
    -------
    CalibrationPair or None

    Raises
    ------
    ParameterError
        ``selection`` that is not a :class:`PairSelection`, or frames of different shapes.
    """
    opts = PairSelection() if selection is None else selection
    if not isinstance(opts, PairSelection):
        raise ParameterError(f"selection must be a PairSelection, got {type(opts).__name__}")
    reference, max_pixels = opts.reference, opts.max_pixels
    min_change, min_pixels = opts.min_change, opts.min_pixels
    h, w = prev.shape
    if cur.shape != (h, w):
        raise ParameterError(f"frames {prev.sequence} and {cur.sequence} have different shapes")
    g = int(_reference_time(reference, prev, cur))
    ok = valid_mask(prev, crf) & valid_mask(cur, crf)
    n_valid = int(ok.sum())
    if mask is not None:
        ok = np.asarray(mask, dtype=bool).reshape(h, w)
    else:
        diff = log_mean_irradiance(cur, crf) - log_mean_irradiance(prev, crf)
        if min_change > 0:
            ok &= np.abs(diff) >= min_change
        if last_polarity is not None:
            lp = np.asarray(last_polarity).reshape(h, w)
            ok &= (lp != 0) & (np.sign(diff) == lp)
    sel = np.flatnonzero(ok.ravel())
    if sel.size < min_pixels or sel.size == 0:
        return None
    if max_pixels is not None and sel.size > max_pixels:
        sel = sel[np.linspace(0, sel.size - 1, int(max_pixels)).round().astype(np.int64)]
    pixmap = np.full(h * w, -1, np.int32)
    pixmap[sel] = np.arange(sel.size, dtype=np.int32)
    lo = min(g, int(prev.exposure_start_us))
    hi = max(g, int(cur.exposure_end_us))
    ev = event_window(events, lo, hi, (h, w))
    kk = pixmap[ev["y"].astype(np.int64) * w + ev["x"]]
    keep = kk >= 0
    ev = ev[keep]
    z_prev, z_cur = prev.image.ravel()[sel].copy(), cur.image.ravel()[sel].copy()
    change = np.abs(
        crf.log_irradiance(z_cur, cur.exposure_us, cur.gain) - crf.log_irradiance(z_prev, prev.exposure_us, prev.gain)
    )
    peak = 0.0
    if ev.size:
        peak = float(np.bincount((ev["t"] - lo) // PEAK_BIN_US).max()) / (sel.size * PEAK_BIN_US * 1e-6)
    return CalibrationPair(
        g=g,
        t=np.ascontiguousarray(ev["t"], dtype=np.int64),
        k=np.ascontiguousarray(kk[keep]),
        p=np.ascontiguousarray(ev["p"], dtype=np.int8),
        z_prev=z_prev,
        z_cur=z_cur,
        s_prev=int(prev.exposure_start_us),
        e_prev=int(prev.exposure_end_us),
        gain_prev=float(prev.gain),
        s_cur=int(cur.exposure_start_us),
        e_cur=int(cur.exposure_end_us),
        gain_cur=float(cur.gain),
        seq_prev=int(prev.sequence),
        seq_cur=int(cur.sequence),
        valid_pixels=n_valid,
        events_per_pixel=float(ev.size) / sel.size,
        mean_abs_change=float(np.mean(change)),
        peak_rate=peak,
        source=source,
    )


def last_polarity_before(events: np.ndarray, t_us: int, shape: tuple[int, int]) -> np.ndarray:
    """Per pixel (flat, int8): the polarity of its last event before ``t_us`` (0: none). O(events)."""
    h, w = shape
    last = np.zeros(h * w, np.int8)
    ev = events[: int(np.searchsorted(events["t"], t_us, side="left"))]
    update_last_polarity(ev["x"], ev["y"], ev["p"], w, last)
    return last


LOSSES = ("linear", "soft_l1", "huber", "cauchy", "arctan")


@dataclass(frozen=True)
class TediFitOptions:
    """What Eq. 7's least-squares fit optimises, from where and how (validated here, once).

    Parameters
    ----------
    init : TediParams
        The start of the fit; the parameters not named in ``fit`` stay at their ``init`` value.
    fit : str or tuple of str
        The parameters to optimise, distinct names among :data:`PARAM_NAMES` (kept as a tuple).
    max_nfev : int
        At most this many residual evaluations (>= 1).
    knee_min : float
        Lower bound of the knee ``b±/a±`` (events per pixel per second, >= 0) when both of a
        polarity are fitted (:func:`fit_tedi_pairs`).
    loss : str
        SciPy's loss, one of :data:`LOSSES` (``"linear"``: plain squared residuals, Eq. 7).
    f_scale : float
        The robust losses' scale (ln units, > 0).

    Raises
    ------
    ParameterError
        ``init`` that is not a :class:`TediParams`, an empty or unknown ``fit``, or a count,
        knee, loss or scale out of its range.
    """

    init: TediParams = TediParams()
    fit: tuple[str, ...] = PARAM_NAMES
    max_nfev: int = 200
    knee_min: float = 0.0
    loss: str = "linear"
    f_scale: float = 1.0

    def __post_init__(self) -> None:
        check_params(self.init)
        fit = (self.fit,) if isinstance(self.fit, str) else tuple(self.fit)
        if not fit:
            raise ParameterError("fit names no parameter")
        bad = [n for n in fit if n not in PARAM_NAMES]
        if bad or len(set(fit)) != len(fit):
            raise ParameterError(f"fit must name distinct parameters among {PARAM_NAMES}, got {fit}")
        object.__setattr__(self, "fit", fit)
        _check_count("max_nfev", self.max_nfev, minimum=1)
        k = self.knee_min
        if isinstance(k, bool) or not isinstance(k, (int, float)) or not (np.isfinite(k) and k >= 0):
            raise ParameterError(f"knee_min must be a number >= 0 (events per pixel per second), got {k!r}")
        if self.loss not in LOSSES:
            raise ParameterError(f"loss must be linear, soft_l1, huber, cauchy or arctan, got {self.loss!r}")
        f = self.f_scale
        if isinstance(f, bool) or not isinstance(f, (int, float)) or not (np.isfinite(f) and f > 0):
            raise ParameterError(f"f_scale must be a positive number (ln units), got {f!r}")


def fit_tedi_pairs(pairs, crf: CameraResponse, options: TediFitOptions | None = None, progress=None) -> TediCalibration:
    """Fit the TEDI parameters on prepared frame pairs (Eq. 7 with squared residuals).

    The residual of a used pixel of a pair is ``ln L_i(g,x) - ln L_{i-1}(g,x)`` (Eq. 5 on both
    frames, the exact integral of :func:`tedi_integral_compact`). ``options.fit`` names the
    parameters to optimise (the others stay at ``options.init``); bounds ``c in [0.01, 2]``,
    ``a, b >= 0``. See the module docstring for the ``(a, b/a)`` parameterisation.
    ``options.knee_min`` (events per pixel per second) bounds the knee ``b±/a±`` from below when
    both of a polarity are fitted: with a knee of zero the compensation ``a m`` is only a rescaling
    of ``c`` (``c (1 + a)``), so thresholds and compensation are separable only if pixels changing
    slower than the knee exist in the data and the knee cannot fall below them.
    ``options.loss``/``options.f_scale``: SciPy's robust losses (``"linear"`` = plain squared
    residuals, Eq. 7 as docs/method.md states it; ``"soft_l1"``, ``"huber"``, ``"cauchy"`` act like
    squares below ``f_scale`` ln units and grow slower above, so pixels the model cannot explain
    weigh less). ``cost`` is then the robust cost; the RMS figures are always plain RMS residuals.
    Each evaluation costs O(events + pixels) per pair.

    Parameters
    ----------
    pairs : iterable of CalibrationPair
        The prepared pairs (:func:`prepare_pair`), at least one.
    crf : CameraResponse
        The camera response ``g``.
    options : TediFitOptions, optional
        What to fit and how (default: ``TediFitOptions()``, all six from the defaults).
    progress : callable, optional
        ``progress(evaluations, rms)``, called after every residual evaluation.

    Returns
    -------
    TediCalibration

    Raises
    ------
    ParameterError
        A bad ``crf``, ``options`` or ``progress``, or no pairs.
    """
    check_crf(crf)
    options = TediFitOptions() if options is None else options
    if not isinstance(options, TediFitOptions):
        raise ParameterError(f"options must be a TediFitOptions, got {type(options).__name__}")
    init, fit, knee_min = options.init, options.fit, options.knee_min
    if progress is not None and not callable(progress):
        raise ParameterError("progress must be callable or None")
    pairs = list(pairs)
    if not pairs or not all(isinstance(pr, CalibrationPair) for pr in pairs):
        raise ParameterError("fit_tedi_pairs needs a non-empty list of CalibrationPair")
    prepared = []
    num_res = 0
    for pr in pairs:
        la, lb = pr.log_lbar(crf)
        prepared.append((pr, la, lb, num_res))
        num_res += pr.n

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
            theta0 = max(v / a0 if a0 > 0 else v, knee_min)
            spec.append(("knee_" + n[2:], i, max(100.0, theta0), float(knee_min), np.inf, theta0))
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
        for (name, i, *_), val in zip(spec, xv * scale, strict=True):
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
        for pr, la, lb_, pos in prepared:
            n = pr.n
            ia = tedi_integral_compact(pr.t, pr.k, pr.p, n, pr.s_prev, pr.e_prev, pr.g, *kp)
            ib = tedi_integral_compact(pr.t, pr.k, pr.p, n, pr.s_cur, pr.e_cur, pr.g, *kp)
            out[pos : pos + n] = (lb_ - np.log(ib / (pr.e_cur - pr.s_cur))) - (
                la - np.log(ia / (pr.e_prev - pr.s_prev))
            )
        evaluations += 1
        if progress is not None:
            progress(evaluations, float(np.sqrt(np.mean(out**2))))
        return out

    def per_pair(r):
        return tuple(float(np.sqrt(np.mean(r[pos : pos + pr.n] ** 2))) for pr, _, _, pos in prepared)

    r0 = residuals(x0)
    rms_before = float(np.sqrt(np.mean(r0**2)))
    res = scipy.optimize.least_squares(
        residuals,
        x0,
        bounds=(lb, ub),
        method="trf",
        x_scale=1.0,
        diff_step=1e-3,
        xtol=1e-8,
        ftol=1e-10,
        gtol=1e-10,
        max_nfev=options.max_nfev,
        loss=options.loss,
        f_scale=float(options.f_scale),
    )
    v = values(res.x)
    params = TediParams(**{n: float(val) for n, val in zip(names, v, strict=True)})
    rms_after = float(np.sqrt(np.mean(res.fun**2)))
    stderr, at_bound = _standard_errors(res, values, spec, names, num_res)
    # A compensation that acts on no pixel of the data (knee above every rate seen) leaves the
    # residuals unchanged (within 1e-9 ln) whatever a± and b± are: report it as a = b = 0, "inactive".
    inactive = []
    for pol in ("on", "off"):
        ia, ib = names.index(f"a_{pol}"), names.index(f"b_{pol}")
        if v[ia] <= 0 or not ({f"a_{pol}", f"b_{pol}"} & set(fit)):
            continue
        w = v.copy()
        w[ia] = w[ib] = 0.0
        r_off = pair_residuals(pairs, crf, TediParams(**{n: float(val) for n, val in zip(names, w, strict=True)}))
        if np.max(np.abs(np.concatenate(r_off) - res.fun)) <= 1e-9:
            v = w
            inactive.append(pol)
            for n in (f"a_{pol}", f"b_{pol}"):
                stderr[n] = float("nan")
    if inactive:
        params = TediParams(**{n: float(val) for n, val in zip(names, v, strict=True)})
    return TediCalibration(
        params,
        float(res.cost),
        rms_before,
        rms_after,
        len(pairs),
        num_res,
        bool(res.success),
        str(res.message),
        per_pair(r0),
        per_pair(res.fun),
        stderr,
        at_bound,
        evaluations,
        tuple(inactive),
    )


def pair_residuals(pairs, crf: CameraResponse, params: TediParams) -> list[np.ndarray]:
    """The Eq. 7 residuals ``ln L_i(g,x) - ln L_{i-1}(g,x)`` of each prepared pair at ``params``."""
    check_crf(crf)
    check_params(params)
    kp = params.as_tuple()
    out = []
    for pr in pairs:
        la, lb = pr.log_lbar(crf)
        ia = tedi_integral_compact(pr.t, pr.k, pr.p, pr.n, pr.s_prev, pr.e_prev, pr.g, *kp)
        ib = tedi_integral_compact(pr.t, pr.k, pr.p, pr.n, pr.s_cur, pr.e_cur, pr.g, *kp)
        out.append((lb - np.log(ib / (pr.e_cur - pr.s_cur))) - (la - np.log(ia / (pr.e_prev - pr.s_prev))))
    return out


def _propagate_inf(vj, cov_x):
    """``vj cov_x vjᵀ`` where infinite variances (non-identifiable directions) stay infinite."""
    finite = np.where(np.isinf(cov_x), 0.0, cov_x)
    cov = vj @ finite @ vj.T
    bad = np.isinf(np.diag(cov_x))
    touched = (np.abs(vj[:, bad]) > 0).any(axis=1)
    cov[touched, :] = np.inf
    cov[:, touched] = np.inf
    return cov


def _standard_errors(res, values, spec, names, num_res):
    """Gauss-Newton standard errors of the six parameters (delta method through ``values``)."""
    q = len(spec)
    stderr = {n: float("nan") for n in names}
    at_bound = tuple(names[spec[j][1]] for j in range(q) if res.active_mask[j] != 0)
    dof = num_res - q
    if dof <= 0:
        return stderr, at_bound
    s2 = 2.0 * float(res.cost) / dof
    jac = np.asarray(res.jac, dtype=np.float64)
    norms = np.sqrt((jac**2).sum(axis=0))
    flat = norms <= 1e-9 * max(float(norms.max()), 1e-300)  # the residuals do not depend on it here
    cov_x = np.linalg.pinv(jac.T @ jac) * s2
    cov_x[flat, :] = 0.0
    cov_x[:, flat] = 0.0
    cov_x[flat, flat] = np.inf
    # d values / d x by central differences (values is linear except b = a θ)
    vj = np.zeros((len(names), q))
    for j in range(q):
        h = 1e-6 * max(1.0, abs(res.x[j]))
        xp, xm = res.x.copy(), res.x.copy()
        xp[j] += h
        xm[j] -= h
        vj[:, j] = (values(xp) - values(xm)) / (2 * h)
    cov = _propagate_inf(vj, cov_x)
    fitted = {spec[j][1] for j in range(q)}
    for i, n in enumerate(names):
        if i in fitted and n not in at_bound:
            stderr[n] = float(np.sqrt(max(cov[i, i], 0.0)))  # inf: the data do not determine it
    return stderr, at_bound


def calibrate_tedi(
    events: np.ndarray,
    frames,
    crf: CameraResponse,
    options: TediFitOptions | None = None,
    selection: PairSelection | None = None,
    progress=None,
) -> TediCalibration:
    """Fit the TEDI parameters by frame-to-frame consistency (Eq. 7, squared residuals).

    For each pair of consecutive frames ``(i-1, i)`` and reference ``g`` (``selection.reference``:
    ``"previous_start"`` = exposure start of frame ``i-1`` (default), ``"previous_end"``,
    ``"current_start"``, ``"current_end"``), the residual of a pixel valid in both frames (and
    whose frame-measured change is at least ``selection.min_change``, default 0) is
    ``ln L_i(g,x) - ln L_{i-1}(g,x)`` by :func:`tedi_reconstruct`. ``options.fit`` names the
    parameters to optimise (the others stay at ``options.init``); bounds ``c in [0.01, 2]``,
    ``a, b >= 0``. ``selection.max_pixels`` caps the pixels used per pair (an even subsample of the
    valid ones; ``None``: all). Event slices and masks are computed once (:func:`prepare_pair`);
    each evaluation costs O(events + pixels) per pair (:func:`fit_tedi_pairs`).

    Parameters
    ----------
    events : numpy.ndarray
        Sorted events (``EVENT_DTYPE``) inside the frames.
    frames : sequence of Frame
        At least two frames of one shape.
    crf : CameraResponse
        The camera response ``g``.
    options : TediFitOptions, optional
        What to fit and how (default: ``TediFitOptions()``).
    selection : PairSelection, optional
        Which pixels of each pair are used (default: ``PairSelection()``).
    progress : callable, optional
        ``progress(evaluations, rms)``, called after every residual evaluation.

    Returns
    -------
    TediCalibration

    Raises
    ------
    ParameterError
        Fewer than two frames, bad options, or no pixel valid in two consecutive frames.
    FrameFormatError, EventFormatError
        Frames or events that are not what the functions accept.
    """
    frames = check_frames(frames)
    check_crf(crf)
    check_event_array(events)
    if len(frames) < 2:
        raise ParameterError(f"TEDI calibration needs at least 2 frames, got {len(frames)}")
    check_events_fit(events, frames[0].shape)
    pairs = []
    for prev, cur in zip(frames[:-1], frames[1:], strict=True):
        pr = prepare_pair(events, prev, cur, crf, selection=selection)
        if pr is not None:
            pairs.append(pr)
    if not pairs:
        raise ParameterError("no pixel is valid (within the camera response's valid range) in two consecutive frames")
    return fit_tedi_pairs(pairs, crf, options, progress)
