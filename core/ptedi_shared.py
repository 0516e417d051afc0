"""Estimators of one source's lanes sharing P-TEDI's compensated event side.

The lanes of a :class:`~necviz.drivers.sim.rig.SimRig` see the same events, use the same thresholds and start
their exposures at the same times, so one :class:`~necviz.core.ptedi_side.EventSide` can keep the per-pixel
bookkeeping of the TEDI compensation for all of them (every estimate stays the one a side of its own gives, bit
for bit; see that module). Members are fed in lock step: every member receives every event batch (the pipeline
feeds each lane the same array). A member whose own parameters change (:meth:`PeripheralEstimator.set_params`)
continues on a side of its own; a change of the contrast thresholds
(:meth:`PeripheralEstimator.set_contrast_thresholds`) applies to every member.
"""

from __future__ import annotations

import numpy as np

from necviz.core.ptedi_side import EventSide

__all__ = ["EventSide", "share_event_side"]


def share_event_side(estimators) -> list:
    """Let the compensated estimators in ``estimators`` that see the same events with the same thresholds
    and region share one :class:`EventSide` per such group (fresh estimators only: before any packet).
    Returns the sides made. Estimators without compensation, or alone in their group, stay as they are."""
    groups: dict = {}
    for est in estimators:
        side = getattr(est, "event_side", None)
        if side is None or len(side.members) > 1:
            continue
        if est.frames_seen or est.last_event_us != np.iinfo(np.int64).min or est._open >= 0:
            continue  # already fed: its state is its own
        key = (est.sensor.width, est.sensor.height, est.params.as_tuple(), est.zmap.tobytes())
        groups.setdefault(key, []).append(est)
    sides = []
    for members in groups.values():
        if len(members) < 2:
            continue
        first = members[0]
        side = EventSide(first.sensor, first.zmap, first.sizes, first.params)
        for est in members:
            est.share_events(side)
        sides.append(side)
    return sides
