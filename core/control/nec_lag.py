"""NEC's lag tracker (``bound_lag``, see :mod:`necviz.core.control.nec`): events that only catch up with a bound.

After a big step a pixel's events keep arriving well after the frame that already saw the new level (its
photoreceptor follows the light slowly in the dark). When a saturated frame moves P-TEDI's anchor to its
bound, the gap it closes (bound minus the event-propagated level at ``s``) is change the events have yet to
report: :class:`LagTracker` keeps that gap, and the events that follow in its direction count only beyond
it. A window at the bus ceiling between the previous anchor and the frame makes the gap events lost for good:
nothing is absorbed. A normal anchor closes the gap. O(zones) per frame, O(1) per prediction.
"""

from __future__ import annotations

import math

import numpy as np

from necviz.core.ptedi import FrameEstimate

__all__ = ["LagTracker"]


class LagTracker:
    """The gap a saturation bound closed, and how much of P-TEDI's later change only catches up with it.

    Attributes
    ----------
    owed : float
        The gap (signed ln; 0 without one).
    """

    def __init__(self) -> None:
        self.owed = 0.0
        self._base = 0.0  # P-TEDI's level at the bound
        self._anchor_s = np.iinfo(np.int64).min  # exposure start of P-TEDI's last (re-)anchor

    def absorbed(self, lp: float) -> float:
        """The part of P-TEDI's change since the bound (to ``lp``) that only catches up with it: the change in
        the gap's direction, up to the gap (0 without a gap)."""
        owed = self.owed
        if owed == 0.0 or lp != lp:
            return 0.0
        moved = lp - self._base
        if owed < 0.0:
            return max(owed, min(moved, 0.0))
        return min(owed, max(moved, 0.0))

    def after_frame(self, fe: FrameEstimate, sizes: np.ndarray, ceiling_t: int | None) -> None:
        """After a frame: open a gap at a saturation bound no ceiling window explains, close it at a normal
        anchor. ``sizes``: the zones' pixel counts; ``ceiling_t``: the last event time of the last window at
        the bus ceiling (``None``: the bus is not watched)."""
        s = int(fe.exposure_start_us)
        bounded, log_start, predicted = fe.bounded, fe.log_start, fe.predicted_start
        if bounded is None or not bool(bounded.any()) or predicted is None:
            if bool(fe.anchored.any()):
                self.owed = 0.0
                self._anchor_s = s
            return
        assert log_start is not None  # PeripheralEstimator.add_frame sets it on every frame
        w = np.where(bounded, sizes.astype(np.float64), 0.0)
        with np.errstate(invalid="ignore"):
            gap = float(np.nansum(np.where(bounded, log_start - predicted, 0.0) * w) / w.sum())
        lost = ceiling_t is not None and ceiling_t >= self._anchor_s
        self._anchor_s = s
        if lost or not math.isfinite(gap):  # events lost at the ceiling never come: nothing to absorb
            self.owed = 0.0
            return
        self.owed = gap
        self._base = float(np.nansum(np.where(bounded, log_start, 0.0) * w) / w.sum())
