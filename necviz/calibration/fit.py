"""The least-squares fit of a camera profile on collected pairs, and its result with the residual statistics.

**Fit** (:func:`calibrate_collected`): thresholds on the pairs that stayed below the sensor's bus
ceiling, then the compensation with the thresholds fixed on all pairs, its knee ``b/a`` bounded
below by ``slow_rate``. The compensation is then validated on pairs it was not fitted on
(:mod:`.holdout`) and kept only if it improves their residual; otherwise ``a± = b± = 0``.

:func:`calibrate_collected` fits (Debevec & Malik, 1997, for the response when brackets were
found; Eq. 7 of Lin et al. with SciPy least squares for the TEDI parameters, :mod:`necviz.core.tedi`)
and returns a :class:`CalibrationResult` (the profile, standard errors, RMS residuals before and
after, per pair and for the unsaturated / saturated pairs).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from necviz.calibration.bootstrap import FEW_PAIRS, bootstrap_intervals
from necviz.calibration.holdout import BLOCK_S, FitPlan, validate_compensation
from necviz.calibration.pairs import DEFAULT_SELECTION, CollectorOptions, PairCollector
from necviz.calibration.settings import DEFAULT_F_SCALE, DEFAULT_LOSS, DEFAULT_SLOW_RATE
from necviz.core.camera_profile import CameraProfile
from necviz.core.control import CameraLimits
from necviz.core.crf import CameraResponse, debevec_malik
from necviz.core.errors import ParameterError
from necviz.core.event_model import TediParams
from necviz.core.sensor import SensorGeometry
from necviz.core.tedi import (
    PARAM_NAMES,
    PairSelection,
    TediCalibration,
    TediFitOptions,
    fit_tedi_pairs,
    pair_residuals,
)

FIT_CHOICES = {"all": PARAM_NAMES, "c": ("c_on", "c_off")}


@dataclass
class CalibrationResult:
    """What a calibration produced and from what.

    ``profile``: the fitted camera profile (``params`` are its TEDI parameters); ``stderr``: the
    standard error of each fitted parameter (Gauss-Newton, independent residuals assumed; NaN when
    not fitted or at a bound, listed in ``at_bound``); ``rms_before``/``rms_after``: RMS Eq. 7
    residual (ln units) over all used pairs at ``init`` and at ``params``; ``plain``: thresholds
    only with ``a = b = 0`` fitted on all pairs (what the data give without compensation; ``None``
    when no compensation term was fitted); ``method``/``stages``: how the fit ran;
    ``crf_fitted``/``crf_info``: the response; ``data``: inputs and selection; ``pairs``: per-pair
    statistics with their RMS residual before and after; ``groups``: RMS before/after for the
    unsaturated and the saturated pairs (see :func:`calibrate_collected`); ``compensation``: whether
    the compensation was kept and why, with its held-out residuals (:mod:`.holdout`; ``None`` when
    no compensation parameter was fitted); ``bootstrap``: the thresholds' intervals, a bootstrap over
    the pairs their fit used (:mod:`.bootstrap`; ``None`` when no threshold was fitted). The
    standard errors take every pixel residual as independent and are far too narrow for the
    thresholds (pixels of a pair err together); the bootstrap intervals are the ones to quote.
    """

    profile: CameraProfile
    params: TediParams
    init: TediParams
    stderr: dict
    at_bound: list
    rms_before: float
    rms_after: float
    num_residuals: int
    plain: TediCalibration | None
    method: str
    stages: list
    crf_fitted: bool
    crf_info: dict
    data: dict
    pairs: list = field(default_factory=list)
    groups: dict = field(default_factory=dict)
    inactive: tuple = ()
    compensation: dict | None = None
    bootstrap: dict | None = None

    @property
    def inactive_names(self) -> tuple:
        return tuple(f"{k}_{pol}" for pol in self.inactive for k in ("a", "b"))

    def to_dict(self) -> dict:
        return {
            "profile": self.profile.to_dict(),
            "init": _params_dict(self.init),
            "fit": {
                "params": _params_dict(self.params),
                "stderr": {k: _num(v) for k, v in self.stderr.items()},
                "at_bound": list(self.at_bound),
                "rms_before": self.rms_before,
                "rms_after": self.rms_after,
                "residuals": self.num_residuals,
                "method": self.method,
                "stages": self.stages,
                "inactive_compensation": list(self.inactive),
                "groups": self.groups,
                "compensation": self.compensation,
                "bootstrap": self.bootstrap,
            },
            "plain": None
            if self.plain is None
            else {"params": _params_dict(self.plain.params), "rms_after": self.plain.rms_after},
            "crf": {"fitted": self.crf_fitted, **self.crf_info},
            "data": self.data,
            "pairs": self.pairs,
        }

    def summary(self) -> str:
        p, se = self.params, self.stderr
        d = self.data
        lines = [
            f"data: {_count(d.get('frames'), 'frame')}, {_count(d.get('pairs_considered'), 'pair')} considered, "
            f"{len(self.pairs)} used ({_plural(self.num_residuals, 'pixel residual')}; "
            f"{self.groups.get('saturated', {}).get('pairs', 0)} reached the sensor's bus ceiling)",
            f"fit: {self.method}",
            "fitted TEDI parameters"
            + (
                f" ([{_pct(self.bootstrap['level'])} interval]: a bootstrap over the {self.bootstrap['pairs']} "
                "frame pairs the thresholds were fitted on; ± standard error otherwise):"
                if self.bootstrap
                else " (± standard error):"
            ),
        ]
        boot = (self.bootstrap or {}).get("intervals", {})
        for name in PARAM_NAMES:
            unit = " ev/s" if name.startswith("b_") else ""
            v, s = getattr(p, name), se.get(name, math.nan)
            comp = self.compensation
            if comp is not None and not comp["kept"] and name[:2] in ("a_", "b_"):
                extra = " (dropped: see below)"
            elif name in self.inactive_names:
                extra = " (inactive: no pixel of the data changed faster than the knee)"
            elif name in self.at_bound and name.startswith("b_") and getattr(p, "a_" + name[2:]) > 0:
                extra = f" (knee b/a = {v / getattr(p, 'a_' + name[2:]):.4g} ev/s: at its lower bound)"
            elif name in self.at_bound:
                extra = " (at bound)"
            elif s == math.inf:
                extra = " (not determined by these data)"
            elif math.isnan(s):
                extra = " (not fitted)"
            else:
                extra = ""
            if name in boot and self.bootstrap["effective_pairs"][name] == self.bootstrap["effective_pairs"][name]:
                n_eff = self.bootstrap["effective_pairs"][name]
                finite = all(b is not None and math.isfinite(b) for b in boot[name])
                spread = f"  [{boot[name][0]:.4f}, {boot[name][1]:.4f}]" if finite else "  [not determined]"
                if n_eff < FEW_PAIRS:
                    spread += (
                        f" (rests on {n_eff:.1f} pairs' worth of data: record more lighting changes "
                        f"{'up' if name == 'c_on' else 'down'} to {'narrow' if finite else 'bound'} it)"
                    )
            else:
                spread = f" ± {s:.2g}" if math.isfinite(s) else ""
            lines.append(f"  {name:6s} {v:10.4g}{unit}" + spread + extra)
        unsat, sat = self.groups.get("unsaturated") or {}, self.groups.get("saturated") or {}
        two_stage = "two stages" in self.method
        lines.append(
            f"RMS residual (ln units), all {len(self.pairs)} pairs: {self.rms_before:.4f} at the start -> "
            f"{self.rms_after:.4f} fitted"
            + (
                f" (it rose: the thresholds are fitted on the {unsat.get('pairs', 0)} pairs below the bus "
                f"ceiling only, where the event counts are complete)"
                if two_stage and sat.get("pairs") and self.rms_after > self.rms_before
                else ""
            )
        )
        for key, what in (
            ("unsaturated", "below the bus ceiling" + (" (the thresholds' fit)" if two_stage else "")),
            ("saturated", "at the bus ceiling (events dropped)"),
        ):
            g = self.groups.get(key)
            if g and g["pairs"]:
                lines.append(
                    f"  {_plural(g['pairs'], 'pair')} {what}: {g['rms_before']:.4f} -> {g['rms_after']:.4f}"
                    + (f" (without compensation: {g['rms_plain']:.4f})" if g.get("rms_plain") is not None else "")
                )
        if self.plain is not None:
            lines.append(
                f"  without compensation (c± only, a = b = 0, all pairs): {self.plain.rms_after:.4f} "
                f"(c_on {self.plain.params.c_on:.4f}, c_off {self.plain.params.c_off:.4f})"
            )
        comp = self.compensation
        if comp is not None:
            lines.append(f"compensation {'kept' if comp['kept'] else 'dropped (a = b = 0)'}: {comp['reason']}")
            ho = comp.get("held_out")
            if ho:
                lines.append(
                    f"  held out ({comp['split']}; fitted on {_plural(comp['fit_pairs'], 'pair')}, tested on "
                    f"{comp['held_out_pairs']}), RMS residual without -> with compensation:"
                )
                for key in ("all", "unsaturated", "saturated"):
                    g = ho[key]
                    if g["pairs"]:
                        lines.append(f"    {key} pairs ({g['pairs']}): {g['without']:.4f} -> {g['with']:.4f}")
            ins = comp["in_sample"]
            lines.append(
                "  in sample (every pair, fitted on all of them), without -> with: "
                + ", ".join(
                    f"{k} {g['without']:.4f} -> {g['with']:.4f}" for k, g in ins.items() if g["pairs"] and g["with"]
                )
            )
        if self.crf_fitted:
            lines.append(
                f"camera response: fitted (Debevec-Malik) from {self.crf_info['frames']} bracketed frames, "
                f"max |change| {self.crf_info['max_abs_change_ln']:.3f} ln over the valid range"
            )
        else:
            lines.append(f"camera response: {self.crf_info.get('reason', 'kept')}")
        return "\n".join(lines)


def _pct(level: float) -> str:
    return f"{100 * level:g} %"


def _plural(n: int, word: str) -> str:
    return f"{n:,} {word}" + ("" if n == 1 else "s")


def _count(n, word: str) -> str:
    return _plural(n, word) if isinstance(n, int) else f"? {word}s"


def _num(v):
    if v is None or math.isnan(v):
        return None
    return "inf" if math.isinf(v) else float(v)


def _params_dict(p: TediParams) -> dict:
    return {n: float(getattr(p, n)) for n in PARAM_NAMES}


def _resolve_fit(fit) -> tuple[str, ...]:
    if isinstance(fit, str):
        if fit in FIT_CHOICES:
            return FIT_CHOICES[fit]
        fit = [f.strip() for f in fit.split(",") if f.strip()]
    fit = tuple(fit)
    bad = [f for f in fit if f not in PARAM_NAMES]
    if not fit or bad or len(set(fit)) != len(fit):
        raise ParameterError(
            f"--fit must be 'all', 'c' or distinct names among {', '.join(PARAM_NAMES)}; "
            f"got {','.join(fit) or 'nothing'}"
        )
    return fit


def _fit_crf(collector: PairCollector, base: CameraResponse, mode: str) -> tuple[CameraResponse, bool, dict]:
    if mode == "keep":
        return base, False, {"reason": "kept the starting response (--crf keep)"}
    group = collector.best_brackets
    if not group:
        return base, False, {"reason": "kept the starting response (no exposure brackets of a static scene found)"}
    images = np.stack([im for im, _ in group])
    products = np.array([p for _, p in group], dtype=np.float64)
    fitted = debevec_malik(images, products)
    crf = CameraResponse(fitted.g, base.valid_min, base.valid_max)
    z = np.arange(base.valid_min, base.valid_max + 1)
    change = float(np.max(np.abs(crf.g[z] - base.g[z])))
    # consistency of the bracket: per pixel, g(Z) - ln(T K) should agree across the frames
    lh = crf.g[images.astype(np.int64)] - np.log(products / 1e6)[:, None, None]
    ok = (images >= crf.valid_min) & (images <= crf.valid_max)
    cnt = ok.sum(axis=0)
    mean = np.where(cnt > 0, (lh * ok).sum(axis=0) / np.maximum(cnt, 1), 0.0)
    dev = (lh - mean)[ok & (cnt >= 2)[None]]
    rms = float(np.sqrt(np.mean(dev**2))) if dev.size else math.nan
    return (
        crf,
        True,
        {
            "frames": len(group),
            "exposure_gain_us": [float(p) for p in sorted(products)],
            "max_abs_change_ln": change,
            "bracket_rms_ln": _num(rms),
        },
    )


def _report(progress, text: str) -> None:
    if progress is not None:
        progress(text)


def _rms(parts) -> float:
    parts = [r for r in parts if r.size]
    if not parts:
        return math.nan
    r = np.concatenate(parts)
    return float(np.sqrt(np.mean(r**2)))


def _stage(name: str, pairs, res: TediCalibration) -> dict:
    return {
        "stage": name,
        "pairs": len(pairs),
        "fitted": [k for k, v in res.stderr.items() if math.isfinite(v)] + list(res.at_bound),
        "rms_before": res.rms_before,
        "rms_after": res.rms_after,
        "evaluations": res.evaluations,
        "success": res.success,
        "message": res.message,
    }


def _check_positive(name: str, v, unit: str) -> None:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
        raise ParameterError(f"{name} must be a positive number of {unit}, got {v!r}")


@dataclass(frozen=True)
class CalibrationOptions:
    """What a calibration fits, from which start, and on which frame pairs (validated here, once).

    Shared by :func:`calibrate_collected`, :func:`~necviz.calibration.calibrate_from_recordings` and
    :func:`~necviz.calibration.calibrate_from_simulation`.

    Parameters
    ----------
    profile : CameraProfile, optional
        The starting profile: response, limits, initial parameters (default: ``CameraProfile()``, DAVIS346).
    init : TediParams, optional
        The fit's start (default: the profile's TEDI parameters).
    fit : str or sequence of str
        ``"all"`` (the six, the default), ``"c"`` (the thresholds) or distinct names among
        :data:`~necviz.core.tedi.PARAM_NAMES` (a comma-separated string or a sequence); kept as a tuple.
    crf_mode : str
        ``"auto"``: fit the response by Debevec-Malik when the data hold a static exposure bracket;
        ``"keep"``: keep the profile's.
    name : str, optional
        The new profile's name (default: the starting profile's).
    max_event_rate : float, "auto" or None
        The sensor's bus ceiling (events/s, > 0); pairs that reached 90 % of it count as saturated
        (:func:`calibrate_collected`). ``"auto"``: the data source's own — 12 Mev/s for DAVIS346 and
        DAVIS240 recordings, the simulated sensor's for simulator runs, unknown for
        :func:`calibrate_collected` alone; ``None``: unknown.
    slow_rate : float
        Lower bound of the compensation knee ``b/a`` (events per pixel per second, > 0).
    loss, f_scale, max_nfev : str, float, int
        The least-squares loss, its scale (ln units) and the residual evaluations per fit
        (:class:`~necviz.core.tedi.TediFitOptions` checks them).
    holdout_block_s : float
        Length of the alternating fit / held-out blocks (s, > 0; :mod:`.holdout`).
    selection : PairSelection
        Which pixels of a frame pair are used (default :data:`~.pairs.DEFAULT_SELECTION`).
    collection : CollectorOptions
        How many pairs are kept and how much is held (:class:`~.pairs.CollectorOptions`).

    Raises
    ------
    ParameterError
        An unknown ``fit`` or ``crf_mode``, a rate, knee or block length that is not positive,
        solver settings :class:`~necviz.core.tedi.TediFitOptions` refuses, or an argument of the wrong type.
    """

    profile: CameraProfile | None = None
    init: TediParams | None = None
    fit: tuple[str, ...] = PARAM_NAMES
    crf_mode: str = "auto"
    name: str | None = None
    max_event_rate: float | str | None = "auto"
    slow_rate: float = DEFAULT_SLOW_RATE
    loss: str = DEFAULT_LOSS
    f_scale: float = DEFAULT_F_SCALE
    max_nfev: int = 200
    holdout_block_s: float = BLOCK_S
    selection: PairSelection = DEFAULT_SELECTION
    collection: CollectorOptions = CollectorOptions()

    def __post_init__(self) -> None:
        kinds: tuple[tuple[str, type, bool], ...] = (
            ("profile", CameraProfile, True),
            ("init", TediParams, True),
            ("selection", PairSelection, False),
            ("collection", CollectorOptions, False),
        )
        for attr, kind, optional in kinds:
            v = getattr(self, attr)
            if not (isinstance(v, kind) or (optional and v is None)):
                raise ParameterError(f"{attr} must be a {kind.__name__}, got {type(v).__name__}")
        object.__setattr__(self, "fit", _resolve_fit(self.fit))
        if self.crf_mode not in ("auto", "keep"):
            raise ParameterError(f"--crf must be auto or keep, got {self.crf_mode!r}")
        _check_positive("slow_rate", self.slow_rate, "events per pixel per second")
        if self.max_event_rate is not None and not (
            isinstance(self.max_event_rate, str) and self.max_event_rate == "auto"
        ):
            _check_positive("max_event_rate", self.max_event_rate, "events per second")
        _check_positive("holdout_block_s", self.holdout_block_s, "seconds")
        self.solver  # noqa: B018 - TediFitOptions checks the solver settings now, not after the data are read

    @property
    def solver(self) -> TediFitOptions:
        """The solver settings every fit of the calibration shares; as it stands, the thresholds-only
        fit without compensation."""
        return TediFitOptions(fit=("c_on", "c_off"), max_nfev=self.max_nfev, loss=self.loss, f_scale=self.f_scale)


def calibrate_collected(
    collector: PairCollector,
    options: CalibrationOptions | None = None,
    *,
    limits: CameraLimits | None = None,
    extra: dict | None = None,
    progress=None,
) -> CalibrationResult:
    """Fit response (if brackets) and TEDI parameters on what ``collector`` kept; build the profile.

    **Saturated pairs.** ``options.max_event_rate`` (events/s) is the sensor's bus ceiling: a pair whose
    sensor-wide event rate reached 90 % of it in any 1 ms bin is *saturated* — the sensor dropped
    events there, so its counts are incomplete whatever the thresholds are (``None`` or ``"auto"``:
    unknown here, no pair counts as saturated).

    **Stages.** When thresholds and compensation are both fitted and at least 3 pairs are not
    saturated, the fit runs in two stages:

    1. ``c±`` (with ``a = b = 0``) on the unsaturated pairs, where the counts are complete;
    2. the compensation ``a±, b±`` with ``c±`` fixed, on all pairs (it is there to credit what the
       sensor missed, at its bus ceiling or in refractory/slow pixels).

    Fitting them jointly lets the saturated pairs inflate the thresholds instead (measured on the
    simulated DAVIS346: c± +25-45 %), since a larger ``c`` credits more change to every event,
    which the least-squares fit prefers to a compensation that acts only above its knee. Otherwise
    (only one kind fitted, or too few unsaturated pairs) the named parameters are fitted jointly on
    all pairs. When ``a±`` and ``b±`` of a polarity are both fitted, the knee ``b±/a±`` is bounded
    below by ``options.slow_rate`` events per pixel per second: with a knee of zero the compensation
    ``a m`` is a mere rescaling of ``c``.

    **Does the compensation earn its place?** Whenever compensation terms are fitted, the same fit is
    repeated on alternate ``options.holdout_block_s`` blocks of the data and its residual compared, with and
    without the compensation, on the blocks left out (:func:`.holdout.validate_compensation`). The
    profile keeps the compensation only if it improves that held-out residual (overall, and not at
    the cost of the pairs below the bus ceiling); otherwise ``a± = b± = 0`` with the thresholds of
    the fit, and ``result.compensation["reason"]`` says why.

    Parameters
    ----------
    collector : PairCollector
        The pairs (and exposure brackets) collected from the data.
    options : CalibrationOptions, optional
        What to fit and how (default: ``CalibrationOptions()``).
    limits : CameraLimits, optional
        The profile's camera limits (default: the starting profile's).
    extra : dict, optional
        More about the data for the report (``{"simulation": ...}`` is kept in the profile too).
    progress : callable, optional
        ``progress(text)`` gets a status line now and then.

    Returns
    -------
    CalibrationResult

    Raises
    ------
    ParameterError
        ``options`` that is not a :class:`CalibrationOptions`, or data without a qualifying pair.
    """
    opts = CalibrationOptions() if options is None else options
    if not isinstance(opts, CalibrationOptions):
        raise ParameterError(f"options must be a CalibrationOptions, got {type(opts).__name__}")
    base = opts.profile or CameraProfile()
    init = opts.init or base.tedi
    fit, slow_rate, loss, f_scale = opts.fit, opts.slow_rate, opts.loss, opts.f_scale
    max_event_rate = None if isinstance(opts.max_event_rate, str) else opts.max_event_rate  # "auto": unknown here
    if not collector.pairs:
        d, sel = collector, collector.selection
        if d.frames < 2:
            raise ParameterError(
                f"calibration needs frames with their exposures: the input held {d.frames} frame(s) "
                f"(formats without stored exposure need --exposure-us)"
            )
        raise ParameterError(
            f"no frame pair qualifies: {d.considered} frames tried against up to {d.options.max_lag} earlier ones, "
            f"none with {sel.min_pixels} pixels valid in both, changed by >= {sel.min_change:g} ln"
            + (" and continuing their last event's direction" if d.options.continuation else "")
            + "; record lighting changes or motion, or lower --min-change / --min-pixels"
        )
    crf, crf_fitted, crf_info = _fit_crf(collector, base.crf, opts.crf_mode)
    pairs = collector.pairs
    t_fit = time.perf_counter()
    last = [0.0]
    label = [""]

    def cb(n, rms):
        now = time.perf_counter()
        if now - last[0] > 0.5:
            last[0] = now
            _report(progress, f"fitting {label[0]}: evaluation {n}, RMS residual {rms:.4f} ln ({now - t_fit:.0f} s)")

    c_names = tuple(n for n in fit if n.startswith("c_"))
    comp_names = tuple(n for n in fit if not n.startswith("c_"))
    solver = opts.solver
    knee = slow_rate if any(f"a_{p}" in fit and f"b_{p}" in fit for p in ("on", "off")) else 0.0
    limit = None if max_event_rate is None else 0.9 * float(max_event_rate)
    saturated = [limit is not None and pr.bus_peak_rate >= limit for pr in pairs]
    complete = [pr for pr, sat in zip(pairs, saturated, strict=True) if not sat]
    robust = f", loss {loss}" + (f" (f_scale {f_scale:g} ln)" if loss != "linear" else "")
    knee_text = f", knee b/a >= {knee:g} ev/s per pixel" if knee else ""
    if c_names and comp_names and len(complete) >= 3:
        label[0] = f"thresholds on {len(complete)} unsaturated pairs"
        s1 = fit_tedi_pairs(complete, crf, replace(solver, init=TediParams(init.c_on, init.c_off), fit=c_names), cb)
        start = TediParams(s1.params.c_on, s1.params.c_off, init.a_on, init.b_on, init.a_off, init.b_off)
        label[0] = f"compensation on {len(pairs)} pairs"
        res = fit_tedi_pairs(pairs, crf, replace(solver, init=start, fit=comp_names, knee_min=knee), cb)
        stages = [
            _stage(f"{', '.join(c_names)} (a = b = 0) on the unsaturated pairs", complete, s1),
            _stage(f"{', '.join(comp_names)} (c fixed) on all pairs", pairs, res),
        ]
        stderr = {k: (s1.stderr[k] if k in c_names else res.stderr[k]) for k in PARAM_NAMES}
        at_bound = list(s1.at_bound) + list(res.at_bound)
        method = (
            f"two stages: {', '.join(c_names)} on the {len(complete)} unsaturated pairs, then "
            f"{', '.join(comp_names)} on all {len(pairs)} pairs{robust}{knee_text}"
        )
    else:
        label[0] = f"{len(pairs)} pairs"
        res = fit_tedi_pairs(pairs, crf, replace(solver, init=init, fit=fit, knee_min=knee), cb)
        stages = [_stage(", ".join(fit) + " on all pairs", pairs, res)]
        stderr, at_bound = dict(res.stderr), list(res.at_bound)
        method = f"{', '.join(fit)} jointly on all {len(pairs)} pairs{robust}{knee_text}"
        if c_names and comp_names:
            method += f" (only {len(complete)} unsaturated pairs: too few for two stages)"
    # the thresholds' intervals: a bootstrap over the pairs of the fit that set them, at its optimum
    if c_names and len(stages) == 2:
        c_fit, c_pairs = s1, complete
    else:
        c_fit, c_pairs = res, pairs
    label[0] = "bootstrap intervals of the thresholds"
    _report(progress, f"{label[0]} ({len(c_pairs)} pairs)")
    bootstrap = (
        bootstrap_intervals(c_pairs, crf, c_fit.params, c_names, loss=loss, f_scale=f_scale) if c_names else None
    )
    params = res.params
    compensation = None
    if comp_names:  # does it earn its place? (held-out pairs; .holdout)
        label[0] = "compensation on held-out pairs"
        plan = FitPlan(solver, init, tuple(c_names), tuple(comp_names), knee)
        compensation = validate_compensation(
            pairs, saturated, crf, plan, params, block_s=opts.holdout_block_s, progress=cb
        )
        if not compensation["kept"]:
            params = TediParams(params.c_on, params.c_off)
            stderr = {k: (math.nan if k in comp_names else v) for k, v in stderr.items()}
            at_bound = [k for k in at_bound if k not in comp_names]
    plain = None
    if comp_names:
        label[0] = "thresholds without compensation"
        plain = fit_tedi_pairs(pairs, crf, replace(solver, init=TediParams(params.c_on, params.c_off)), cb)
    r_before = pair_residuals(pairs, crf, init)
    r_after = pair_residuals(pairs, crf, params)
    r_plain = pair_residuals(pairs, crf, plain.params) if plain is not None else None
    groups = {}
    for key, want in (("unsaturated", False), ("saturated", True)):
        idx = [i for i, v in enumerate(saturated) if v == want]
        groups[key] = {
            "pairs": len(idx),
            "rms_before": _num(_rms([r_before[i] for i in idx])),
            "rms_after": _num(_rms([r_after[i] for i in idx])),
            "rms_plain": None if r_plain is None else _num(_rms([r_plain[i] for i in idx])),
        }
    groups["max_event_rate"] = max_event_rate
    per_pair = []
    for pr, rb, ra, sat in zip(pairs, r_before, r_after, saturated, strict=True):
        per_pair.append(
            {
                **pr.stats(),
                "saturated": sat,
                "rms_before": float(np.sqrt(np.mean(rb**2))),
                "rms_after": float(np.sqrt(np.mean(ra**2))),
            }
        )
    rms_before, rms_after = _rms(r_before), _rms(r_after)
    num_res = int(sum(pr.n for pr in pairs))
    h, w = collector.shape
    sensor = base.sensor if (base.sensor.width, base.sensor.height) == (w, h) else SensorGeometry(w, h, f"{w}x{h}")
    data = {**collector.describe(), **(extra or {})}
    calib = {
        "method": "Eq. 7 frame-to-frame consistency, squared residuals, SciPy least squares (trf); " + method,
        "data": {k: data[k] for k in ("sources", "frames", "pairs_used", "pairs_considered") if k in data}
        | ({"simulation": extra["simulation"]} if extra and "simulation" in extra else {}),
        "selection": {**data["selection"], "slow_rate": slow_rate, "max_event_rate": max_event_rate},
        "fitted": list(fit),
        "init": _params_dict(init),
        "rms_before": rms_before,
        "rms_after": rms_after,
        "rms_without_compensation": None if plain is None else plain.rms_after,
        "compensation": None
        if compensation is None
        else {k: compensation[k] for k in ("kept", "reason", "split", "held_out", "in_sample") if k in compensation},
        "pairs_saturated": int(sum(saturated)),
        "stderr": {k: _num(v) for k, v in stderr.items() if k in fit},
        "intervals": None
        if bootstrap is None
        else {"level": bootstrap["level"], "method": bootstrap["method"], **bootstrap["intervals"]},
        "crf": "fitted (Debevec-Malik)" if crf_fitted else crf_info.get("reason", "kept"),
    }
    profile = CameraProfile(
        name=opts.name or base.name,
        sensor=sensor,
        crf=crf,
        tedi=params,
        limits=limits or base.limits,
        calibration=calib,
    )
    return CalibrationResult(
        profile,
        params,
        init,
        stderr,
        at_bound,
        rms_before,
        rms_after,
        num_res,
        plain,
        method,
        stages,
        crf_fitted,
        crf_info,
        data,
        per_pair,
        groups,
        tuple(res.inactive),
        compensation,
        bootstrap,
    )
