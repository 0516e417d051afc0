"""What the events add to the next-frame prediction: P-TEDI against predictors that see frames only.

For every usable frame ``i`` (its ln P̄ measured, :class:`necviz.telemetry.FrameRecord`)
P-TEDI predicts the frame's ln P̄ from the last anchor and the events since (``ln P(s) + ln E_p(s)``).
Two predictors that see the frames alone give the yardstick:

* **persistence**, "the same as the last frame": ln P̄ of the last usable frame before ``i``. It is
  also what P-TEDI itself predicts without events (its anchor, carried by no events);
* **trend**: the straight line through the last two usable frames, at ``i``'s mid-exposure time
  (``m1 + (m1 - m2) (t_i - t1) / (t1 - t2)``): a frame-based predictor that follows a steady drift.

The *skill score* of P-TEDI against a reference predictor (the forecasting skill score, e.g. Murphy,
"Skill scores based on the mean square error", Monthly Weather Review 116, 1988) is
``1 - MSE_ptedi / MSE_reference`` over the frames where both predict: 1 is perfect, 0 no better than
the reference, negative worse. :class:`SkillTracker` keeps it running, frame by frame, in O(1)
memory; :func:`skill_from_columns` computes it from per-frame columns in one pass (the same figures).
"""

from __future__ import annotations

import math

import numpy as np

#: The reference predictors, in the order they are reported.
REFERENCES = ("persistence", "trend")


def _summary(n: int, sse_ptedi: float, sse_ref: float) -> dict:
    return {
        "frames": n,
        "rmse_ptedi": math.sqrt(sse_ptedi / n) if n else None,
        "rmse_reference": math.sqrt(sse_ref / n) if n else None,
        "skill": (1.0 - sse_ptedi / sse_ref) if n and sse_ref > 0 else None,
    }


class SkillTracker:
    """Running persistence and trend predictions of a frame sequence, and P-TEDI's skill against them.

    Call :meth:`update` for every frame in order; it returns the frame's persistence and trend
    errors (reference prediction minus measured ln P̄; NaN where the frame or the reference has no
    value) and P-TEDI's skill against persistence over the frames so far (NaN while undefined).
    """

    def __init__(self):
        self._last: list[tuple[float, float]] = []  # (measured ln P̄, mid-exposure µs) of the last two usable frames
        self._sums = {r: [0, 0.0, 0.0] for r in REFERENCES}  # frames, SSE P-TEDI, SSE reference

    def predictions(self, t_mid_us: float) -> tuple[float, float]:
        """``(persistence, trend)`` predictions of a frame at mid-exposure ``t_mid_us`` (NaN if none)."""
        last = self._last
        persist = last[-1][0] if last else math.nan
        trend = math.nan
        if len(last) == 2:
            (m2, t2), (m1, t1) = last
            if t1 > t2:
                trend = m1 + (m1 - m2) * (t_mid_us - t1) / (t1 - t2)
        return persist, trend

    def update(self, measured: float, prediction_error: float, t_mid_us: float) -> tuple[float, float, float]:
        """One frame: its measured ln P̄ (NaN if unusable), P-TEDI's error (predicted − measured, NaN if
        none) and mid-exposure time. Returns ``(persistence_error, trend_error, skill_vs_persistence)``."""
        persist, trend = self.predictions(t_mid_us)
        errors = {"persistence": math.nan, "trend": math.nan}
        if math.isfinite(measured):
            for ref, pred in (("persistence", persist), ("trend", trend)):
                if math.isfinite(pred):
                    errors[ref] = pred - measured
                    if math.isfinite(prediction_error):
                        s = self._sums[ref]
                        s[0] += 1
                        s[1] += prediction_error**2
                        s[2] += errors[ref] ** 2
            self._last = [*self._last[-1:], (float(measured), float(t_mid_us))]
        skill = self.summary()["persistence"]["skill"]
        return errors["persistence"], errors["trend"], math.nan if skill is None else skill

    def summary(self) -> dict:
        """``{"persistence" | "trend": {"frames", "rmse_ptedi", "rmse_reference", "skill"}}`` (``None`` where undefined)."""
        return {r: _summary(int(n), sse_p, sse_r) for r, (n, sse_p, sse_r) in self._sums.items()}


def skill_from_columns(measured, prediction_error, t_mid_us) -> dict:
    """:meth:`SkillTracker.summary` of a whole sequence from its per-frame columns (frames in order)."""
    tr = SkillTracker()
    for m, e, t in zip(
        np.asarray(measured, np.float64),
        np.asarray(prediction_error, np.float64),
        np.asarray(t_mid_us, np.float64),
        strict=True,
    ):
        tr.update(float(m), float(e), float(t))
    return tr.summary()


__all__ = ["REFERENCES", "SkillTracker", "skill_from_columns"]
