"""Does TEDI's compensation earn its place? Its Eq. 7 residual on frame pairs it was not fitted on.

The compensation ``a±, b±`` (:mod:`necviz.core.tedi`) adds four parameters to the two thresholds; a
least-squares fit that may use them can only lower its own residual, so the fit's residual says
nothing about whether they help on new data. :func:`validate_compensation` answers that:

1. **Split** (:func:`split_pairs`): each source's pairs, by the exposure start of their earlier
   frame, in blocks of ``block_s`` seconds from the source's first pair; even blocks are the *fit*
   set, odd blocks the *held-out* set. Blocks keep neighbouring pairs (which share a frame and the
   same lighting episode) on the same side. Data too short for two blocks fall back to alternate
   pairs (said in the report).
2. **Fit** on the fit set exactly as :func:`necviz.calibration.fit.calibrate_collected` fits all pairs:
   thresholds on the unsaturated fit pairs, then the compensation with the thresholds fixed on all
   fit pairs (or the named parameters jointly when there are too few unsaturated pairs).
3. **Compare** on the held-out pairs the RMS residual with the fitted compensation and without it
   (the same thresholds, ``a = b = 0``): on every held-out pair, on those below the sensor's bus
   ceiling and on those that reached it.

The compensation is **kept** only if it lowers the held-out RMS over all held-out pairs and does
not raise it on the held-out pairs below the bus ceiling (where counts are complete and the model
should already hold). Otherwise the profile gets ``a± = b± = 0`` and the report says why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from necviz.core.event_model import TediParams
from necviz.core.tedi import TediFitOptions, fit_tedi_pairs, pair_residuals
from necviz.progress import plural

#: Length of the alternating fit / held-out blocks (sensor time, s).
BLOCK_S = 1.0


def split_pairs(pairs, block_s: float = BLOCK_S) -> tuple[list[int], list[int], str]:
    """Indices of the fit and held-out pairs, and how they were split (module docstring)."""
    block_us = block_s * 1e6
    first: dict = {}
    for pr in pairs:
        first[pr.source] = min(first.get(pr.source, pr.s_prev), pr.s_prev)
    blocks = [int((pr.s_prev - first[pr.source]) // block_us) for pr in pairs]
    fit = [i for i, b in enumerate(blocks) if b % 2 == 0]
    held = [i for i, b in enumerate(blocks) if b % 2 == 1]
    if fit and held:
        return fit, held, f"alternate {block_s:g} s blocks of each source (even: fit, odd: held out)"
    fit, held = list(range(0, len(pairs), 2)), list(range(1, len(pairs), 2))
    return fit, held, f"alternate pairs (the data span less than two {block_s:g} s blocks)"


def _rms(residuals, idx) -> float | None:
    parts = [residuals[i] for i in idx if residuals[i].size]
    if not parts:
        return None
    r = np.concatenate(parts)
    return float(np.sqrt(np.mean(r**2)))


@dataclass(frozen=True)
class FitPlan:
    """How :func:`necviz.calibration.fit.calibrate_collected` fits, so the held-out fit is the same fit.

    Parameters
    ----------
    solver : TediFitOptions
        The solver settings every fit shares (iterations, loss).
    init : TediParams
        The starting parameters.
    c_names, comp_names : tuple of str
        The thresholds and the compensation parameters being fitted.
    knee : float
        The lower bound of the knee ``b/a`` (events per pixel per second) when both of a polarity are fitted.
    """

    solver: TediFitOptions
    init: TediParams
    c_names: tuple[str, ...]
    comp_names: tuple[str, ...]
    knee: float = 0.0


def _fit(pairs, saturated, crf, plan: FitPlan, progress) -> TediParams:
    """The fit of :func:`calibrate_collected` on ``pairs``: the fitted parameters.

    On a part of the data a trial step can overflow the exposure integral (a large ``a``); SciPy's
    trust region rejects such a step (its residuals are not finite), so NumPy's warning about it is
    silenced here."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        return _fit_stages(pairs, saturated, crf, plan, progress)


def _fit_stages(pairs, saturated, crf, plan: FitPlan, progress) -> TediParams:
    init, c_names, comp_names, solver = plan.init, plan.c_names, plan.comp_names, plan.solver
    complete = [pr for pr, sat in zip(pairs, saturated, strict=True) if not sat]
    if c_names and comp_names and len(complete) >= 3:
        s1 = fit_tedi_pairs(
            complete, crf, replace(solver, init=TediParams(init.c_on, init.c_off), fit=c_names), progress
        )
        start = TediParams(s1.params.c_on, s1.params.c_off, init.a_on, init.b_on, init.a_off, init.b_off)
        return fit_tedi_pairs(
            pairs, crf, replace(solver, init=start, fit=comp_names, knee_min=plan.knee), progress
        ).params
    opts = replace(solver, init=init, fit=c_names + comp_names, knee_min=plan.knee)
    return fit_tedi_pairs(pairs, crf, opts, progress).params


def decide(held_out: dict) -> tuple[bool, str]:
    """The rule (module docstring) on held-out RMS residuals ``{"all" | "unsaturated": {"with", "without",
    "pairs"}}``: ``(kept, why)``."""
    a, u = held_out["all"], held_out["unsaturated"]
    if a["with"] is None or a["without"] is None or not (math.isfinite(a["with"]) and math.isfinite(a["without"])):
        return False, "no finite held-out residual: the compensation cannot be validated"
    if a["with"] >= a["without"]:
        return False, (
            f"it does not improve the held-out residual ({a['without']:.4f} ln without, {a['with']:.4f} with, "
            f"{plural(a['pairs'], 'pair')})"
        )
    if u["pairs"] and u["with"] > u["without"]:
        return False, (
            f"it improves the held-out residual overall ({a['without']:.4f} -> {a['with']:.4f} ln) only by "
            f"making it worse below the bus ceiling ({u['without']:.4f} -> {u['with']:.4f} ln, {plural(u['pairs'], 'pair')}): "
            "it stands in for events lost at the ceiling, not for what TEDI models"
        )
    return True, (
        f"it improves the held-out residual ({a['without']:.4f} -> {a['with']:.4f} ln over {plural(a['pairs'], 'pair')}"
        + (f"; below the bus ceiling {u['without']:.4f} -> {u['with']:.4f} ln" if u["pairs"] else "")
        + ")"
    )


def validate_compensation(
    pairs, saturated, crf, plan: FitPlan, final: TediParams, *, block_s: float = BLOCK_S, progress=None
) -> dict:
    """Whether the compensation improves the held-out residual (module docstring).

    ``pairs``/``saturated``: every collected pair and whether it reached the bus ceiling; ``plan``:
    how the calibration fits (the same fit runs on the fit set); ``final``:
    the parameters fitted on all pairs (for the in-sample comparison). Returns a JSON-ready dict:
    ``kept``, ``reason``, ``split``, pair counts, the parameters fitted on the fit set, and the RMS
    residuals ``{"all" | "unsaturated" | "saturated": {"with", "without", "pairs"}}`` on the held-out
    pairs (``held_out``) and, at ``final``, on all pairs (``in_sample``).
    """
    zero = lambda p: TediParams(p.c_on, p.c_off)  # noqa: E731
    r_with, r_without = pair_residuals(pairs, crf, final), pair_residuals(pairs, crf, zero(final))
    groups = {
        "all": list(range(len(pairs))),
        "unsaturated": [i for i, s in enumerate(saturated) if not s],
        "saturated": [i for i, s in enumerate(saturated) if s],
    }
    in_sample = {
        k: {"pairs": len(idx), "with": _rms(r_with, idx), "without": _rms(r_without, idx)} for k, idx in groups.items()
    }
    out = {"kept": False, "reason": "", "in_sample": in_sample, "block_s": block_s}
    if len(pairs) < 2:
        out["reason"] = f"too few pairs ({len(pairs)}) to hold any out: the compensation cannot be validated"
        return out
    fit_idx, held_idx, how = split_pairs(pairs, block_s)
    out.update({"split": how, "fit_pairs": len(fit_idx), "held_out_pairs": len(held_idx)})
    params = _fit([pairs[i] for i in fit_idx], [saturated[i] for i in fit_idx], crf, plan, progress)
    held = [pairs[i] for i in held_idx]
    h_with, h_without = pair_residuals(held, crf, params), pair_residuals(held, crf, zero(params))
    sat = [saturated[i] for i in held_idx]
    hg = {
        "all": list(range(len(held))),
        "unsaturated": [i for i, s in enumerate(sat) if not s],
        "saturated": [i for i, s in enumerate(sat) if s],
    }
    rms = {k: {"pairs": len(idx), "with": _rms(h_with, idx), "without": _rms(h_without, idx)} for k, idx in hg.items()}
    out["fit_set_params"] = {n: float(getattr(params, n)) for n in ("c_on", "c_off", "a_on", "b_on", "a_off", "b_off")}
    out["held_out"] = rms
    out["kept"], out["reason"] = decide(rms)
    return out


__all__ = ["BLOCK_S", "FitPlan", "decide", "split_pairs", "validate_compensation"]
