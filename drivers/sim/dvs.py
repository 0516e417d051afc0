"""The DVS event model of the simulator: ESIM threshold crossings with v2e's non-idealities.

Per pixel ``i``, between two samples ``(t0, L0)`` and ``(t1, L1)`` of ``ln L`` (natural log,
necviz units, see :mod:`.scene`):

1. **Photoreceptor low-pass** (v2e, first order, intensity dependent bandwidth)::

       tau     = 1 / (2 pi cutoff_hz)
       u       = min(1, exp(L1 - bandwidth_ref_log))        # relative intensity, 1 = reference
       inten01 = (u + d) / (1 + d),   d = 20/255             # v2e's (I + 20) / 275 with I = 255 u
       eps     = 1 - exp(-(t1 - t0) * inten01 / tau)
       lp1     = lp0 + eps (L1 - lp0)

   ``eps`` is the exact zero-order-hold solution of ``tau/inten01 * dlp/dt = L1 - lp``; it equals
   v2e's ``min(1, dt/tau * inten01)`` to first order for ``dt << tau`` but does not saturate
   at 1 when the samples are coarser than ``tau``. So the bandwidth is ``cutoff_hz`` at and
   above ``bandwidth_ref_log`` (``ln L = 5.5`` is a well exposed pixel at 4 ms), falls in
   proportion to the intensity below it and bottoms out at ``0.073 cutoff_hz`` in the dark.
   ``cutoff_hz = None`` or ``0`` makes ``lp = L`` (no filter).

2. **Leak** (v2e): the reference drifts down by ``leak_hz * r_i * theta_on_i`` per second, so a
   static pixel emits ON events at ``leak_hz * r_i`` Hz, ``r_i = 10^(leak_cov_decades N(0,1))``
   fixed per pixel. Implemented as a drift of the signal instead: ``w(t) = lp(t) + k_i (t - t_reset)``
   with ``k_i = leak_hz r_i theta_on_i / 1e6`` per µs. With a leak, :meth:`EventSimulator.reset`
   starts each reference at a random phase ``ref = lp - U(0,1) theta_on_i`` so leak events are
   not synchronised across the array (the reference then still lies within one threshold).
   (v2e's per-event leak jitter is not modelled.)

3. **Threshold crossings** (ESIM): ``w`` is interpolated linearly between the samples; each
   crossing of ``ref + theta_on_i`` (ON) or ``ref - theta_off_i`` (OFF) is an event at
   ``t = t0 + (cross - w0) / (w1 - w0) (t1 - t0)``, rounded to whole µs and clamped into
   ``(t0, t1]``; the reference moves by one threshold per event, so a change of ``k``
   thresholds emits ``k`` events even within one interval. Invariant after every step:
   ``-theta_off_i < w - ref < theta_on_i``. Thresholds ``theta_i = max(0.01, c + sigma N(0,1))``
   are drawn once per pixel and polarity for the whole run.

4. **Refractory period** (ESIM): an event less than ``refractory_us`` after the pixel's previous
   *emitted* event is dropped, but the reference still advances (the information is lost).

5. **Shot noise** (v2e): random events at rate
   ``shot_noise_hz * (1 - 0.75 inten01(L1))`` per pixel (ON and OFF equally likely), i.e.
   ``shot_noise_hz`` is the rate in the dark limit (0.945x at the v2e floor) and a quarter of it at and
   above the reference intensity. Drawn by thinning a homogeneous Poisson process of rate
   ``shot_noise_hz`` over the whole array (O(candidates) per step, not O(pixels)); a shot event
   resets the pixel's reference to its current level ``w(t1)`` (v2e), ignores and does not
   restart the refractory period.

6. **Bandwidth ceiling**: at most ``floor(max_event_rate * (t1 - t0) / 1e6)`` events leave a step;
   when more were generated a uniformly random (seeded) subset is kept and the rest counted in
   :attr:`EventSimulator.dropped_by_ceiling` (by polarity: ``dropped_on_by_ceiling``,
   ``dropped_off_by_ceiling``; the ground truth of every frame carries them, so a diagnosis can tell
   whether lost events explain a prediction's miss).

Every per-pixel operation runs in a Numba kernel; a static pixel costs a few loads and
compares per step (the filter snaps to the input once within 1e-7, so a converged pixel does
no arithmetic). Randomness comes from three independent streams spawned from ``seed``
(thresholds/leak factors, leak phase + shot noise, ceiling subset): same seed, same events.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numba as nb
import numpy as np

from necviz.core.checks import check_number
from necviz.core.errors import ParameterError
from necviz.core.events import EVENT_DTYPE
from necviz.core.sensor import DAVIS_EVENT_RATE_MAX, SensorGeometry

THRESHOLD_MIN = 0.01  # v2e/ESIM-fork clamp of the per-pixel thresholds (ln units)
DARK_FLOOR = 20.0 / 255.0  # v2e's (I + 20) / 275: bandwidth floor 20/275 = 0.073 of the cutoff
SHOT_BRIGHT_FACTOR = 0.25  # v2e SHOT_NOISE_INTEN_FACTOR: shot rate at full intensity / dark rate
SNAP = 1e-7  # the low-pass output snaps to its input within this (ln units)
BLOCK = 256  # pixels per block of the static fast-path scan


@dataclass(frozen=True)
class DvsParams:
    """Parameters of the DVS model (defaults close to a DAVIS346 at default biases).

    Contrast thresholds are in natural-log units of irradiance.

    * ``c_on=0.26, c_off=0.24``: nominal ON/OFF thresholds (Fast-EDI's DAVIS346 values
      0.2609/0.2415).
    * ``sigma_threshold=0.03``: per-pixel threshold mismatch (std, v2e default), fixed for a run;
      each pixel's threshold is clamped to >= 0.01.
    * ``refractory_us=100``: per-pixel refractory period. v2e defaults to 500 µs, which caps a
      pixel at 2 kev/s; a DAVIS346 at default biases recovers in ~tens to a hundred µs, so 100 µs.
    * ``cutoff_hz=300``: photoreceptor 3 dB bandwidth at ``bandwidth_ref_log`` and above (v2e
      default); ``None`` or 0 disables the low-pass filter.
    * ``bandwidth_ref_log=5.5``: ``ln L`` of full bandwidth (``ln L = 5.5`` gives Z = 128 at a 4 ms
      exposure); below it the bandwidth falls with intensity as in v2e (module docstring).
    * ``leak_hz=0.01``: leak ON events per pixel per second (v2e default);
      ``leak_cov_decades=0.1``: per-pixel lognormal spread of that rate (v2e).
    * ``shot_noise_hz=0.001``: shot-noise events per pixel per second, both polarities, in the dark
      limit; a quarter of it at full intensity (v2e).
    * ``max_event_rate=12e6``: sensor-wide ceiling, events per second (DAVIS346 bus ~12 Mev/s);
      ``None`` = unlimited.
    """

    c_on: float = 0.26
    c_off: float = 0.24
    sigma_threshold: float = 0.03
    refractory_us: float = 100.0
    cutoff_hz: float | None = 300.0
    bandwidth_ref_log: float = 5.5
    leak_hz: float = 0.01
    leak_cov_decades: float = 0.1
    shot_noise_hz: float = 0.001
    max_event_rate: float | None = DAVIS_EVENT_RATE_MAX

    def __post_init__(self) -> None:
        def check(name, lo=None, hi=None, **kw):
            check_number(f"DvsParams.{name}", getattr(self, name), lo, hi, **kw)

        check("c_on", THRESHOLD_MIN)
        check("c_off", THRESHOLD_MIN)
        check("sigma_threshold", 0.0)
        check("refractory_us", 0.0)
        if self.cutoff_hz is not None:  # None: no low-pass filter
            check("cutoff_hz", 0.0)
        check("bandwidth_ref_log")
        check("leak_hz", 0.0)
        check("leak_cov_decades", 0.0, 2.0)
        check("shot_noise_hz", 0.0)
        if self.max_event_rate is not None:  # None: no ceiling
            check("max_event_rate", 0.0, lo_open=True)
        if self.sigma_threshold > 0.5 * max(self.c_on, self.c_off) + 0.1:
            raise ParameterError(
                f"DvsParams.sigma_threshold = {self.sigma_threshold:g} is not a mismatch of thresholds "
                f"{self.c_on:g}/{self.c_off:g} (expected a few hundredths)"
            )

    @classmethod
    def ideal(cls, c_on: float = 0.26, c_off: float = 0.24, **overrides) -> DvsParams:
        """ESIM's ideal sensor: no mismatch, no low-pass, no noise, no refractory period, no ceiling."""
        base = dict(
            c_on=c_on,
            c_off=c_off,
            sigma_threshold=0.0,
            refractory_us=0.0,
            cutoff_hz=None,
            leak_hz=0.0,
            leak_cov_decades=0.0,
            shot_noise_hz=0.0,
            max_event_rate=None,
        )
        base.update(overrides)
        return cls(**base)

    def replace(self, **changes) -> DvsParams:
        return replace(self, **changes)

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def params_for_biases(base: DvsParams, biases, family: str = "DAVIS346") -> DvsParams:
    """The simulated pixel at DVS biases ``biases`` (:class:`~necviz.core.biases.DvsBiases`): ``base`` is the
    pixel at libcaer's default biases, scaled by the bias model's ratios (:class:`~necviz.core.biases.BiasModel`)
    — thresholds, refractory period and bandwidth; the same mapping P-TEDI follows. The leak's drift is the
    junction's, not the biases': ``leak_hz`` scales with ``1/c_on`` (as :meth:`EventSimulator.retune` keeps it)."""
    from necviz.core.biases import BiasModel

    r = BiasModel(family).ratios(biases)
    c_on = max(THRESHOLD_MIN, base.c_on * r.c_on)
    return base.replace(
        c_on=c_on,
        leak_hz=base.leak_hz * base.c_on / c_on,
        c_off=max(THRESHOLD_MIN, base.c_off * r.c_off),
        refractory_us=base.refractory_us * r.refractory_us,
        cutoff_hz=None if not base.cutoff_hz else base.cutoff_hz * r.bandwidth_hz,
    )


# --------------------------------------------------------------------------------------------
# Kernels
# --------------------------------------------------------------------------------------------


TAB_SPAN = 10.0  # ln units below bandwidth_ref_log covered by the low-pass table
TAB_SIZE = 1025


def inten01(log_l, ref_log: float):
    """v2e's relative photoreceptor intensity ``(u + d) / (1 + d)``, ``u = min(1, exp(ln L - ref))``."""
    u = np.minimum(1.0, np.exp(np.minimum(np.asarray(log_l, dtype=np.float64) - ref_log, 0.0)))
    return (u + DARK_FLOOR) / (1.0 + DARK_FLOOR)


def lowpass_table(dt_us: float, omega_per_us: float, ref_log: float):
    """``(a_tab, lo, inv_h)``: ``1 - eps = exp(-dt omega inten01(ln L))`` on ``TAB_SIZE`` points of
    ``ln L`` in ``[ref - TAB_SPAN, ref]`` (exact at and above ``ref``; below the grid the bandwidth
    is within 5e-5 of its floor). Linear interpolation error < 1e-4 for ``dt omega <= 1``."""
    lo = ref_log - TAB_SPAN
    grid = np.linspace(lo, ref_log, TAB_SIZE)
    return np.exp(-dt_us * omega_per_us * inten01(grid, ref_log)), lo, (TAB_SIZE - 1) / TAB_SPAN


#: Steps between checks of the scratch buffers: they shrink to twice the largest step seen since the
#: last check when they are more than 4x that (so a burst's buffers are let go, a busy scene keeps them).
SHRINK_EVERY = 256


@nb.njit(cache=True, nogil=True)
def dvs_pixels(
    lnew,
    lp,
    ref,
    th_on,
    th_off,
    leak_k,
    t_last,
    wake,
    t0,
    t1,
    e0,
    e1,
    omega_s,
    a_tab,
    tab_lo,
    tab_inv_h,
    refractory,
    start,
    out_t,
    out_pix,
    out_p,
    n0,
    stats,
):
    """One sample interval of the per-pixel model (low-pass, leak, ESIM crossings, refractory).

    ``lnew`` float32 (N,) new ``ln L``; state arrays (N,): ``lp`` filtered level (float64),
    ``ref`` reference in the leak-drifted frame ``w = lp + k (t - t_reset)``, ``t_last`` last
    emitted event (µs), ``wake`` (float32) a lower bound of the ``t - t_reset`` at which the
    leak makes an unchanged pixel cross (``inf`` without leak). ``t0 < t1`` integer µs;
    ``e0, e1`` = ``t0, t1 - t_reset``; ``omega_s`` = ``2 pi cutoff`` per µs (0: no filter);
    ``a_tab`` the filter's ``1 - eps`` for this interval on a uniform grid of ``ln L`` starting at
    ``tab_lo`` with spacing ``1 / tab_inv_h`` (:func:`lowpass_table`), interpolated linearly
    and held constant outside the grid.
    Events go to ``out_*`` from index ``n0``; ``stats[0]`` counts refractory drops,
    ``stats[1]`` crossings. Static fast path: blocks of ``BLOCK`` pixels are first scanned
    branch-free (vectorised); a block where every input equals its (converged) filter state
    and no leak wake time has come is skipped.
    Processes pixels from ``start`` and stops *before* a pixel whose events would not fit,
    without touching its state. Returns ``(next pixel, events written so far)``.
    O(pixels + events).
    """
    n = lnew.shape[0]
    cap = out_t.shape[0]
    n_tab = a_tab.shape[0]
    dt = float(t1 - t0)
    w = n0
    e1f = np.float32(e1)
    b0 = np.uint64(start)
    nu = np.uint64(n)
    while b0 < nu:
        b1 = min(nu, b0 + np.uint64(BLOCK))
        # branch-free (vectorised) scan: does any pixel of the block need work?
        busy = 0
        for j in range(b0, b1):
            busy += (np.float64(lnew[j]) != lp[j]) | (wake[j] <= e1f)
        i0 = int(b0)
        b0 = b1
        if busy == 0:
            continue
        for i in range(i0, int(b1)):
            l1 = np.float64(lnew[i])
            l0 = lp[i]
            if l1 == l0 and np.float32(e1) < wake[i]:
                continue
            if omega_s > 0.0:
                d = l1 - l0
                if abs(d) > SNAP:
                    # a = exp(-dt omega inten01(l1)), tabulated over l1 for this dt
                    q = (l1 - tab_lo) * tab_inv_h
                    if q <= 0.0:
                        a = a_tab[0]
                    elif q >= n_tab - 1:
                        a = a_tab[n_tab - 1]
                    else:
                        m = int(q)
                        a = a_tab[m] + (q - m) * (a_tab[m + 1] - a_tab[m])
                    l1 = l1 - a * d
            k = leak_k[i]
            w0 = l0 + k * e0
            w1 = l1 + k * e1
            r = ref[i]
            x = w1 - r
            ton = th_on[i]
            toff = th_off[i]
            if x >= ton:
                need = int(x / ton) + 2
            elif x <= -toff:
                need = int(-x / toff) + 2
            else:
                need = 0
            if w + need > cap:
                return np.int64(i), w
            lp[i] = l1
            if need > 0:
                span = w1 - w0
                tl = t_last[i]
                if x > 0.0:
                    cross = r + ton
                    while cross <= w1:
                        f = (cross - w0) / span if span > 0.0 else 1.0
                        te = int(math.floor(t0 + f * dt + 0.5))
                        if te <= t0:
                            te = t0 + 1
                        elif te > t1:
                            te = t1
                        stats[1] += 1
                        if te - tl >= refractory:
                            out_t[w] = te
                            out_pix[w] = i
                            out_p[w] = 1
                            w += 1
                            tl = te
                        else:
                            stats[0] += 1
                        r = cross
                        cross = r + ton
                else:
                    cross = r - toff
                    while cross >= w1:
                        f = (cross - w0) / span if span < 0.0 else 1.0
                        te = int(math.floor(t0 + f * dt + 0.5))
                        if te <= t0:
                            te = t0 + 1
                        elif te > t1:
                            te = t1
                        stats[1] += 1
                        if te - tl >= refractory:
                            out_t[w] = te
                            out_pix[w] = i
                            out_p[w] = -1
                            w += 1
                            tl = te
                        else:
                            stats[0] += 1
                        r = cross
                        cross = r - toff
                ref[i] = r
                t_last[i] = tl
            if k > 0.0:
                # leak crossing when l1 + k e = r + ton; float32 rounded down with a margin
                we = (r + ton - l1) / k
                wake[i] = np.float32(we - 1.0 - 1e-5 * abs(we))
    return np.int64(n), w


@nb.njit(cache=True, nogil=True)
def dvs_shot_noise(
    cand_pix, cand_t, cand_u, cand_on, lnew, lp, ref, leak_k, th_on, wake, e1, ref_log, out_t, out_pix, out_p, n0
):
    """Thin homogeneous shot-noise candidates to v2e's intensity-dependent rate and apply them.

    Candidate ``j`` at pixel ``cand_pix[j]`` is kept when ``cand_u[j] < 1 - 0.75 inten01(L1)``
    (``inten01`` as in the low-pass, from the new sample); a kept event resets the pixel's
    reference to ``w(t1) = lp + k e1`` (and its leak wake time). Writes from ``out[n0]`` (caller sized the buffers);
    returns the new count. O(candidates).
    """
    w = n0
    for j in range(cand_pix.shape[0]):
        i = cand_pix[j]
        u = math.exp(np.float64(lnew[i]) - ref_log)
        if u > 1.0:
            u = 1.0
        inten = (u + DARK_FLOOR) / (1.0 + DARK_FLOOR)
        if cand_u[j] < 1.0 - (1.0 - SHOT_BRIGHT_FACTOR) * inten:
            out_t[w] = cand_t[j]
            out_pix[w] = i
            out_p[w] = 1 if cand_on[j] else -1
            w += 1
            k = leak_k[i]
            ref[i] = lp[i] + k * e1
            if k > 0.0:
                we = e1 + th_on[i] / k
                wake[i] = np.float32(we - 1.0 - 1e-5 * abs(we))
    return w


@nb.njit(cache=True, nogil=True)
def dvs_assemble(out_t, out_pix, out_p, n, t0, width, ev):
    """Stable counting sort of ``n`` events by time in ``(t0, t0 + span]`` into the record array ``ev``.

    Ties keep their generation order (pixel order, then noise). ``y = floor((pix + 0.5) / width)``
    by a reciprocal multiply (exact: the quotient is never within ``0.5 / width`` of an integer).
    O(n + span); the caller uses it when the span is not much larger than ``n``.
    """
    span = 0
    for j in range(n):
        d = out_t[j] - t0
        if d > span:
            span = d
    cnt = np.zeros(span + 2, np.int64)
    for j in range(n):
        cnt[out_t[j] - t0 + 1] += 1
    for s in range(1, span + 2):
        cnt[s] += cnt[s - 1]
    inv_w = 1.0 / width
    for j in range(n):
        b = out_t[j] - t0
        k = cnt[b]
        cnt[b] = k + 1
        pix = out_pix[j]
        y = int((pix + 0.5) * inv_w)
        ev[k].t = out_t[j]
        ev[k].y = y
        ev[k].x = pix - y * width
        ev[k].p = out_p[j]


# --------------------------------------------------------------------------------------------
# Simulator
# --------------------------------------------------------------------------------------------


def _as_time(t_us, what: str) -> int:
    if isinstance(t_us, bool) or not isinstance(t_us, (int, float, np.integer, np.floating)):
        raise ParameterError(f"{what} must be a time in whole microseconds, got {t_us!r}")
    tf = float(t_us)
    if not math.isfinite(tf) or tf != round(tf):
        raise ParameterError(f"{what} must be a whole number of microseconds, got {t_us!r}")
    return int(round(tf))


class EventSimulator:
    """Stateful DVS pixel array: feed it samples of ``ln L``, get the events in between.

    ``reset(log_image, t_us)`` sets every pixel's filter and reference to the first image;
    ``step(log_image, t_us)`` returns the events (EVENT_DTYPE, sorted by ``t``, ties in pixel
    order) of ``(t_prev, t_us]``. Model and equations: module docstring.

    Counters (cumulative since construction): ``events_generated`` (events the pixels produced,
    including noise, before the ceiling), ``events_emitted``, ``dropped_by_refractory``,
    ``dropped_by_ceiling`` (of which ON: ``dropped_on_by_ceiling``, OFF: ``dropped_off_by_ceiling``),
    ``shot_noise_events``, ``steps``. Per-pixel constants for inspection:
    ``threshold_on``, ``threshold_off`` (H, W) and ``leak_rate_hz`` (H, W).
    """

    def __init__(self, sensor: SensorGeometry, params: DvsParams | None = None, seed: int = 0):
        if not isinstance(sensor, SensorGeometry):
            raise ParameterError(f"EventSimulator needs a SensorGeometry, got {type(sensor).__name__}")
        if params is None:
            params = DvsParams()
        if not isinstance(params, DvsParams):
            raise ParameterError(f"EventSimulator params must be DvsParams, got {type(params).__name__}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ParameterError(f"EventSimulator seed must be a non-negative integer, got {seed!r}")
        self.sensor = sensor
        self.params = params
        self.seed = int(seed)
        ss_const, ss_noise, ss_ceiling = np.random.SeedSequence(self.seed).spawn(3)
        rng_const = np.random.default_rng(ss_const)
        self._rng = np.random.default_rng(ss_noise)
        self._rng_ceiling = np.random.default_rng(ss_ceiling)
        n = sensor.num_pixels
        self._n = n
        z = rng_const.standard_normal((3, n))
        p = params
        self._th_on = np.maximum(THRESHOLD_MIN, p.c_on + p.sigma_threshold * z[0])
        self._th_off = np.maximum(THRESHOLD_MIN, p.c_off + p.sigma_threshold * z[1])
        self._z_th = z[:2]  # each pixel's threshold deviation, kept for retune()
        self._retune: DvsParams | None = None
        self.retuned_us: int | None = None
        self._leak_factor = 10.0 ** (p.leak_cov_decades * z[2])
        self._leak_k = p.leak_hz * self._leak_factor * self._th_on / 1e6  # ln units per µs
        self._omega = 0.0 if not p.cutoff_hz else 2.0 * math.pi * float(p.cutoff_hz) / 1e6  # per µs
        self._refractory = float(p.refractory_us)
        self._tab = (np.ones(2), 0.0, 1.0)
        self._tab_dt = -1
        self._lp = np.zeros(n)
        self._ref = np.zeros(n)
        self._t_last = np.zeros(n, np.int64)
        self._wake = np.full(n, np.inf, np.float32)
        self._stats = np.zeros(2, np.int64)
        self._base_cap = max(4096, n // 4)
        self._shrink(self._base_cap)
        self._peak = self._since = 0  # the largest step's events over the last SHRINK_EVERY steps
        self.t_us: int | None = None
        self.t_reset_us: int | None = None
        self.events_generated = 0
        self.events_emitted = 0
        self.dropped_by_ceiling = 0
        self.dropped_on_by_ceiling = 0
        self.dropped_off_by_ceiling = 0
        self.shot_noise_events = 0
        self.steps = 0

    # -- inspection ------------------------------------------------------------------------------
    @property
    def threshold_on(self) -> np.ndarray:
        return self._th_on.reshape(self.sensor.shape).copy()

    @property
    def threshold_off(self) -> np.ndarray:
        return self._th_off.reshape(self.sensor.shape).copy()

    @property
    def leak_rate_hz(self) -> np.ndarray:
        return (self.params.leak_hz * self._leak_factor).reshape(self.sensor.shape)

    @property
    def dropped_by_refractory(self) -> int:
        return int(self._stats[0])

    @property
    def crossings(self) -> int:
        """Threshold crossings (emitted or dropped by the refractory period), noise excluded."""
        return int(self._stats[1])

    def filtered_log(self) -> np.ndarray:
        """The photoreceptor's current (low-passed) ``ln L``, (H, W) float64."""
        return self._lp.reshape(self.sensor.shape).copy()

    # -- simulation ------------------------------------------------------------------------------
    def _check_image(self, log_image, what: str) -> np.ndarray:
        img = np.asarray(log_image)
        if img.shape != self.sensor.shape:
            raise ParameterError(
                f"{what}: ln L image has shape {img.shape}, expected {self.sensor.shape} (height, width)"
            )
        if not (np.issubdtype(img.dtype, np.floating) or np.issubdtype(img.dtype, np.integer)):
            raise ParameterError(f"{what}: ln L image must be numeric, got dtype {img.dtype}")
        img = np.ascontiguousarray(img, dtype=np.float32).reshape(-1)
        if not np.isfinite(img).all():
            bad = int(np.flatnonzero(~np.isfinite(img))[0])
            raise ParameterError(
                f"{what}: ln L image has NaN or infinite values (first at x={bad % self.sensor.width}, "
                f"y={bad // self.sensor.width})"
            )
        return img

    def reset(self, log_image, t_us) -> None:
        """Start (or restart) at ``t_us`` with filter and references at ``log_image``.

        Thresholds and leak factors are kept (fixed for the run); with a leak, each reference
        starts at a random phase within one ON threshold below the level.
        """
        img = self._check_image(log_image, "reset")
        t = _as_time(t_us, "reset time")
        self._lp[:] = img
        self._ref[:] = img
        if self.params.leak_hz > 0:
            self._ref -= self._rng.random(self._n) * self._th_on
        self._t_last[:] = np.iinfo(np.int64).min // 2
        self._wake[:] = np.inf
        if self.params.leak_hz > 0:
            we = (self._ref + self._th_on - self._lp) / self._leak_k
            self._wake[:] = we - 1.0 - 1e-5 * np.abs(we)
        self.t_us = t
        self.t_reset_us = t

    def _shrink(self, cap: int) -> None:
        """Scratch buffers for ``cap`` events (fresh: nothing in them is kept between steps)."""
        self._buf_t = np.empty(cap, np.int64)
        self._buf_pix = np.empty(cap, np.int32)
        self._buf_p = np.empty(cap, np.int8)

    def _grow(self, need: int) -> None:
        cap = max(2 * self._buf_t.shape[0], need)
        for name, dt in (("_buf_t", np.int64), ("_buf_pix", np.int32), ("_buf_p", np.int8)):
            old = getattr(self, name)
            new = np.empty(cap, dt)
            new[: old.shape[0]] = old
            setattr(self, name, new)

    def retune(self, params: DvsParams) -> None:
        """Change thresholds, refractory period and bandwidth while running (e.g. new DVS biases); from the
        next :meth:`step` on, whose start becomes :attr:`retuned_us`. Thread-safe against a step on another thread.

        Each pixel keeps its mismatch: ``theta_i = max(0.01, c + sigma N_i)`` with the same ``N_i``. The leak's
        drift (ln units per µs) is the junction's and stays, so the leak event rate scales with ``1/theta``
        (``leak_hz`` may differ only as :func:`params_for_biases` scales it; it is not applied otherwise).
        With a leak, pixels whose signal is past a lowered threshold fire at the next step. Nothing else may differ
        from the current parameters.
        """
        if not isinstance(params, DvsParams):
            raise ParameterError(f"retune takes DvsParams, got {type(params).__name__}")
        keep = ("c_on", "c_off", "refractory_us", "cutoff_hz", "leak_hz")
        other = {k: v for k, v in params.as_dict().items() if k not in keep}
        if other != {k: v for k, v in self.params.as_dict().items() if k not in keep}:
            raise ParameterError("retune changes only c_on, c_off, refractory_us, cutoff_hz (and leak_hz)")
        self._retune = params

    def _apply_retune(self, t0: int) -> None:
        p, self._retune = self._retune, None
        self._th_on = np.maximum(THRESHOLD_MIN, p.c_on + p.sigma_threshold * self._z_th[0])
        self._th_off = np.maximum(THRESHOLD_MIN, p.c_off + p.sigma_threshold * self._z_th[1])
        self._omega = 0.0 if not p.cutoff_hz else 2.0 * math.pi * float(p.cutoff_hz) / 1e6
        self._tab_dt = -1  # the low-pass table is rebuilt for the new bandwidth
        self._refractory = float(p.refractory_us)
        if p.leak_hz > 0:  # every pixel is looked at once (a lowered threshold may already be crossed)
            self._wake[:] = -np.inf  # (without a leak a pixel is looked at when its input next changes)
        self.params = p
        self.retuned_us = int(t0)

    def step(self, log_image, t_us) -> np.ndarray:
        """Advance to ``t_us`` (after the previous sample) with ``ln L = log_image``; return its events."""
        if self.t_us is None:
            raise ParameterError("EventSimulator.step called before reset(first image, start time)")
        t1 = _as_time(t_us, "step time")
        t0 = self.t_us
        if t1 <= t0:
            raise ParameterError(f"step time {t1} µs must be after the previous sample at {t0} µs")
        img = self._check_image(log_image, f"step at {t1} µs")
        if self._retune is not None:
            self._apply_retune(t0)
        p = self.params
        e0 = float(t0 - self.t_reset_us)
        e1 = float(t1 - self.t_reset_us)
        if self._omega > 0 and self._tab_dt != t1 - t0:
            self._tab = lowpass_table(t1 - t0, self._omega, float(p.bandwidth_ref_log))
            self._tab_dt = t1 - t0
        a_tab, tab_lo, tab_inv_h = self._tab
        start, n = 0, 0
        while True:
            start, n = dvs_pixels(
                img,
                self._lp,
                self._ref,
                self._th_on,
                self._th_off,
                self._leak_k,
                self._t_last,
                self._wake,
                t0,
                t1,
                e0,
                e1,
                self._omega,
                a_tab,
                tab_lo,
                tab_inv_h,
                self._refractory,
                start,
                self._buf_t,
                self._buf_pix,
                self._buf_p,
                n,
                self._stats,
            )
            if start >= self._n:
                break
            self._grow(n + 4096)
        if p.shot_noise_hz > 0:
            lam = p.shot_noise_hz * self._n * (t1 - t0) / 1e6
            m = int(self._rng.poisson(lam))
            if m:
                pix = self._rng.integers(0, self._n, m).astype(np.int32)
                tt = self._rng.integers(t0 + 1, t1 + 1, m, dtype=np.int64)
                uu = self._rng.random(m)
                on = self._rng.random(m) < 0.5
                if n + m > self._buf_t.shape[0]:
                    self._grow(n + m)
                n2 = dvs_shot_noise(
                    pix,
                    tt,
                    uu,
                    on,
                    img,
                    self._lp,
                    self._ref,
                    self._leak_k,
                    self._th_on,
                    self._wake,
                    e1,
                    float(p.bandwidth_ref_log),
                    self._buf_t,
                    self._buf_pix,
                    self._buf_p,
                    n,
                )
                self.shot_noise_events += n2 - n
                n = n2
        self.events_generated += n
        bt, bpix, bp = self._buf_t[:n], self._buf_pix[:n], self._buf_p[:n]
        if p.max_event_rate is not None:
            cap = int(math.floor(p.max_event_rate * (t1 - t0) / 1e6))
            if n > cap:
                keep = np.sort(self._rng_ceiling.choice(n, size=cap, replace=False))
                on_before = int(np.count_nonzero(bp > 0))
                bt, bpix, bp = bt[keep], bpix[keep], bp[keep]
                on_lost = on_before - int(np.count_nonzero(bp > 0))
                self.dropped_by_ceiling += n - cap
                self.dropped_on_by_ceiling += on_lost
                self.dropped_off_by_ceiling += n - cap - on_lost
                n = cap
        ev = np.empty(n, EVENT_DTYPE)
        if n:
            if t1 - t0 <= 8 * n + 65536:
                dvs_assemble(bt, bpix, bp, n, t0, self.sensor.width, ev)
            else:
                order = np.argsort(bt, kind="stable")
                ev["t"] = bt[order]
                pix = bpix[order]
                ev["x"] = pix % self.sensor.width
                ev["y"] = pix // self.sensor.width
                ev["p"] = bp[order]
        self.events_emitted += n
        self.t_us = t1
        self.steps += 1
        self._peak = max(self._peak, n)
        self._since += 1
        if self._since >= SHRINK_EVERY:  # a burst (a lighting step) is over: do not hold its buffers all run
            want = max(self._base_cap, 2 * self._peak)
            if self._buf_t.shape[0] > 4 * want:
                self._shrink(want)
            self._peak = self._since = 0
        return ev
