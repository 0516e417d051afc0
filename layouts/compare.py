"""``compare``: every controller's frames side by side, the shared events once, overlaid curves below.

The top row shows each controller's camera frame and, once, the event image all cameras share;
below, every controller's applied exposure in one plot, every over-exposed rate in another and
every P-TEDI prediction in a third, so the moment one recovers and another is still blind lines up.
"""

from __future__ import annotations

import rerun.blueprint as rrb

from necviz import schema as S

from .common import image_view, panels, series_view


def blueprint(lanes: list[str], width: int, height: int) -> rrb.Blueprint:
    views = [image_view(S.path(n, S.FRAME_IMAGE), n, width, height) for n in lanes]
    views.append(image_view(S.EVENTS, "events (all cameras)", width, height))
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(*views),
            rrb.Horizontal(
                series_view("exposure applied (µs)", [S.path(n, S.EXPOSURE_APPLIED) for n in lanes]),
                series_view("over-exposed rate", [S.path(n, S.OVER_EXPOSED) for n in lanes], y_range=(0.0, 1.0)),
                series_view("ln irradiance predicted", [S.path(n, S.IRRADIANCE_PREDICTED) for n in lanes]),
            ),
            row_shares=[3, 2],
        ),
        *panels(),
    )
