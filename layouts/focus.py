"""A blueprint's time panel looping over one window of sensor time: how a flight-recorder clip and
``necviz replay CLIP`` open at the failure."""

from __future__ import annotations

import rerun.blueprint as rrb
from rerun.encodings import AbsoluteTimeRange, TimeInt

from necviz import schema as S


def focus_blueprint(blueprint, start_s: float, end_s: float):
    """``blueprint`` with its time panel selecting ``[start_s, end_s]`` of sensor time and looping over it
    (how a clip's ``.rrd`` and ``necviz replay CLIP`` open at the failure)."""
    blueprint.time_panel = rrb.TimePanel(
        state="expanded",
        timeline=S.TIME,
        time_selection=AbsoluteTimeRange(TimeInt(seconds=max(0.0, start_s)), TimeInt(seconds=max(0.0, end_s))),
        loop_mode="selection",
        play_state="playing",
    )
    return blueprint


__all__ = ["focus_blueprint"]
