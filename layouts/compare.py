"""``compare``: one column per controller on a shared timeline, overlaid curves below.

Each column shows the controller's camera frame and the event image; below, every
controller's applied exposure in one plot and every over-exposed rate in another, so the
moment one recovers and another is still blind lines up.
"""

from __future__ import annotations

import rerun.blueprint as rrb

from necviz import schema as S

from .common import image_view, panels, series_view


def blueprint(lanes: list[str], width: int, height: int, window_s: float | None = None) -> rrb.Blueprint:
    columns = [
        rrb.Vertical(image_view(S.path(n, S.FRAME_IMAGE), n, width, height),
                     image_view(S.path(n, S.EVENTS), f"{n} events", width, height), name=n)
        for n in lanes
    ]
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(*columns),
            rrb.Horizontal(
                series_view("exposure applied (µs)", [S.path(n, S.EXPOSURE_APPLIED) for n in lanes], window_s),
                series_view("over-exposed rate", [S.path(n, S.OVER_EXPOSED) for n in lanes], window_s,
                            y_range=(0.0, 1.0)),
                series_view("ln irradiance predicted", [S.path(n, S.IRRADIANCE_PREDICTED) for n in lanes], window_s),
            ),
            row_shares=[3, 2],
        ),
        *panels(),
    )
