"""``live``: one camera for tuning — big frame and events side by side, curves of the last seconds below."""

from __future__ import annotations

import rerun.blueprint as rrb

from necviz import schema as S

from .common import image_view, panels, series_view


#: the curves show the last this many seconds of sensor time
WINDOW_S = 10.0


def blueprint(lanes: list[str], width: int, height: int) -> rrb.Blueprint:
    n = lanes[0]
    window_s = WINDOW_S
    p = lambda leaf: S.path(n, leaf)  # noqa: E731
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(image_view(p(S.FRAME_IMAGE), "frame", width, height),
                           image_view(S.EVENTS, "events", width, height)),
            rrb.Horizontal(
                series_view("exposure (µs)", [p(S.EXPOSURE_COMMANDED), p(S.EXPOSURE_APPLIED)], window_s),
                series_view("ln irradiance", [p(S.IRRADIANCE_PREDICTED), p(S.IRRADIANCE_FRAME)], window_s),
                series_view("saturated fraction", [p(S.OVER_EXPOSED), p(S.UNDER_EXPOSED), p(S.SATURATED)],
                            window_s, y_range=(0.0, 1.0)),
                series_view("events/s", [S.EVENT_RATE], window_s),
                series_view("command latency (µs)", [p(S.LATENCY)], window_s),
            ),
            row_shares=[3, 2],
        ),
        *panels(),
    )
