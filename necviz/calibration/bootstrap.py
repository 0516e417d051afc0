"""How far the fitted thresholds could move on other frame pairs: a bootstrap over pairs.

The Gauss-Newton standard error of a least-squares fit (:func:`necviz.core.tedi.fit_tedi_pairs`)
takes every pixel residual as independent. They are not: the pixels of one frame pair share its
frames, its exposure and its lighting episode, so a pair's residuals err together. On a simulated
DAVIS346 stream (thresholds 0.26 / 0.24) that standard error is ±0.0003 for a ``c_off`` of 0.2423,
seven of them from the truth. The interval here resamples what is independent enough — whole
frame pairs, which never overlap in time — with replacement (Efron & Tibshirani, *An Introduction
to the Bootstrap*, 1993, ch. 6: the nonparametric bootstrap and its standard error).

Each resample's fit is taken one Gauss-Newton step from the full fit (the "one-step bootstrap",
Davison & Hinkley, *Bootstrap Methods and their Application*, 1997, sec. 9.4): per pair ``i`` the
Jacobian ``J_i`` of its residuals in the fitted parameters (forward differences at the fit) gives
``A_i = J_i^T W_i J_i`` and ``g_i = J_i^T W_i r_i`` (``W_i``: the robust loss's weights, 1 for the
default squared residuals); a resample that draws pair ``i`` ``n_i`` times moves the parameters by
``-(sum n_i A_i)^-1 sum n_i g_i``. With ``a = b = 0`` the model is nearly linear in ``c±`` (measured
on four simulated seeds: the one-step percentile bounds lie within 0.006 ln of those of 100 full
refits), and a resample costs O(parameters²) instead of a fit: 2,000 of them take well under a
second. Cost: one residual evaluation per fitted parameter plus one, O(events + pixels) each.

**Few pairs carry a threshold.** A threshold is set only by the pairs with events of its polarity,
and among those the pairs with the most pixels and events weigh most: on the simulated DAVIS346
(6 s of its calibration scene) ``c_on`` rests on 3-9 pairs' worth of data, one pair often carrying
half the weight, and the pairs' own estimates differ by more than their pixels' noise (a pair's
size and change bias it). The plain 95 % percentile interval then held the simulator's thresholds
on only 15 and 16 of 20 seeds (seeds 100-119 of ``benchmarks/calibration_coverage.py``, the seeds
this choice was made on). The interval is therefore Student's: ``θ ± t_{n-1, 0.975} sqrt(n/(n-1)) s``
with ``s`` the bootstrap standard error (the sd of the resampled fits; Efron & Tibshirani ch. 12-13)
and ``n`` the pairs' effective number for that parameter, ``(Σ w_i)² / Σ w_i²`` (Kish), ``w_i`` the
diagonal of ``A_i`` (what pair ``i`` adds to that parameter's curvature): it widens as the data
come down to a few pairs, as it must. Below :data:`FEW_PAIRS` effective pairs the summary says the
threshold rests on too few pairs. The plain percentile interval stays in the result (``percentile``)
for comparison; how the two cover held-out seeds is in docs/results.md.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.stats import t as student_t

from necviz.core.event_model import TediParams
from necviz.core.tedi import pair_residuals

#: Resamples of the bootstrap and the interval's coverage level.
REPLICATES = 2000
LEVEL = 0.95
SEED = 0  # the resamples' seed: a calibration prints the same interval every time
STEP = 1e-3  # forward-difference step of the Jacobian (ln units)
#: Below this many effective pairs a parameter's interval is said to rest on too few pairs.
FEW_PAIRS = 3.0
#: Below this many effective pairs there is no interval (the summary says the threshold is not determined).
MIN_PAIRS = 2.0


def _loss_weights(r: np.ndarray, loss: str, f_scale: float) -> np.ndarray | None:
    """Per-residual weights ``rho'(z)``, ``z = (r / f_scale)²``, of SciPy's robust losses (None: squares)."""
    if loss == "linear":
        return None
    z = (r / f_scale) ** 2
    if loss == "soft_l1":
        return 1.0 / np.sqrt(1.0 + z)
    if loss == "huber":
        return np.where(z <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z, 1.0)))
    if loss == "cauchy":
        return 1.0 / (1.0 + z)
    if loss == "arctan":
        return 1.0 / (1.0 + z**2)
    raise ValueError(f"unknown loss {loss!r}")


def effective_pairs(weights) -> float:
    """Kish's effective number of pairs, ``(Σ w)² / Σ w²`` (``n`` equal weights: ``n``; one dominant: ~1)."""
    w = np.asarray(weights, dtype=np.float64)
    w = w[w > 0]
    return float(w.sum() ** 2 / (w**2).sum()) if w.size else 0.0


def t_half_width(sd: float, n_eff: float, level: float) -> float:
    """``t_{n-1, (1+level)/2} sqrt(n/(n-1)) sd`` for ``n = n_eff`` effective pairs (inf below :data:`MIN_PAIRS`:
    one pair's worth of data says nothing about how the next pair would differ)."""
    if not (n_eff >= MIN_PAIRS and math.isfinite(sd)):
        return math.inf
    return float(student_t.ppf((1 + level) / 2, n_eff - 1)) * math.sqrt(n_eff / (n_eff - 1)) * sd


def bootstrap_intervals(
    pairs,
    crf,
    params: TediParams,
    names=("c_on", "c_off"),
    *,
    loss: str = "linear",
    f_scale: float = 1.0,
    replicates: int = REPLICATES,
    level: float = LEVEL,
) -> dict:
    """Percentile intervals of the parameters ``names`` fitted at ``params`` on ``pairs``.

    ``params`` must be the least-squares fit of ``names`` on exactly these ``pairs`` (the other
    parameters held at their values there). Returns ``{"method", "level", "pairs", "replicates",
    "undetermined", "intervals": {name: [low, high]}, "percentile": {name: [low, high]},
    "effective_pairs": {name: n}, "sd": {name: sd}}``: ``intervals`` the t interval (module
    docstring; ``[None, None]`` below :data:`MIN_PAIRS` effective pairs), ``percentile`` the plain
    percentile one; ``undetermined`` counts the resamples whose pairs
    did not determine every parameter (e.g. no ON event in any drawn pair), left out. With fewer than
    2 pairs every interval is ``[nan, nan]``.
    """
    names = tuple(names)
    pairs = list(pairs)
    out = {
        "method": f"bootstrap over frame pairs ({replicates} resamples, one Gauss-Newton step each, "
        "Student's t on their standard error and effective number)",
        "level": level,
        "pairs": len(pairs),
        "replicates": replicates,
        "undetermined": 0,
        "intervals": {n: [float("nan"), float("nan")] for n in names},
        "percentile": {n: [float("nan"), float("nan")] for n in names},
        "effective_pairs": {n: float("nan") for n in names},
        "sd": {n: float("nan") for n in names},
    }
    if len(pairs) < 2 or not names:
        return out
    k = len(names)
    r0 = pair_residuals(pairs, crf, params)
    moved = [pair_residuals(pairs, crf, replace(params, **{n: getattr(params, n) + STEP})) for n in names]
    a_parts = np.empty((len(pairs), k, k))
    g_parts = np.empty((len(pairs), k))
    for i, r in enumerate(r0):
        jac = np.stack([(m[i] - r) / STEP for m in moved], axis=1)
        w = _loss_weights(r, loss, f_scale)
        jw = jac if w is None else jac * w[:, None]
        a_parts[i] = jw.T @ jac
        g_parts[i] = jw.T @ r
    rng = np.random.default_rng(SEED)
    counts = rng.multinomial(len(pairs), np.full(len(pairs), 1.0 / len(pairs)), size=replicates).astype(np.float64)
    a = (counts @ a_parts.reshape(len(pairs), k * k)).reshape(-1, k, k)
    g = counts @ g_parts
    # a resample determines the parameters when its normal matrix is well conditioned
    cond = np.linalg.cond(a)
    ok = np.isfinite(cond) & (cond < 1e8)
    out["undetermined"] = int((~ok).sum())
    if ok.sum() < 10:
        return out
    step = -np.linalg.solve(a[ok], g[ok][..., None])[..., 0]
    theta = np.array([getattr(params, n) for n in names]) + step
    theta[:, [i for i, n in enumerate(names) if n.startswith("c_")]] = np.maximum(
        theta[:, [i for i, n in enumerate(names) if n.startswith("c_")]], 0.01
    )
    tail = 100 * (1 - level) / 2
    lo, hi = np.percentile(theta, [tail, 100 - tail], axis=0)
    sd = theta.std(axis=0, ddof=1)
    for i, n in enumerate(names):
        n_eff = effective_pairs(a_parts[:, i, i])
        half = t_half_width(float(sd[i]), n_eff, level)
        v = float(getattr(params, n))
        lo_v = max(v - half, 0.01) if n.startswith("c_") else v - half
        out["intervals"][n] = [lo_v, v + half] if math.isfinite(half) else [None, None]  # None: not determined
        out["percentile"][n] = [float(lo[i]), float(hi[i])]
        out["effective_pairs"][n] = round(n_eff, 2)
        out["sd"][n] = float(sd[i])
    return out


__all__ = ["FEW_PAIRS", "LEVEL", "MIN_PAIRS", "REPLICATES", "bootstrap_intervals", "effective_pairs", "t_half_width"]
