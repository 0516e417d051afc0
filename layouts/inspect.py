"""``inspect``: step through a recorded failure frame by frame.

Frame and events on top; below, the P-TEDI prediction against the frame-measured irradiance
(and their difference), exposure and gain, and the saturated fractions with a marker on every
saturated frame; the lane's log (saturated frames, controller switches) at the side. The
plots show the whole recording so the cursor can be scrubbed across the failure.
"""

from __future__ import annotations

import rerun.blueprint as rrb

from necviz import schema as S

from .common import image_view, panels, series_view


def blueprint(lanes: list[str], width: int, height: int) -> rrb.Blueprint:
    n = lanes[0]
    p = lambda leaf: S.path(n, leaf)  # noqa: E731
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Horizontal(image_view(p(S.FRAME_IMAGE), "frame", width, height),
                               image_view(S.EVENTS, "events", width, height)),
                series_view("ln irradiance: predicted vs frame", [p(S.IRRADIANCE_PREDICTED), p(S.IRRADIANCE_FRAME)]),
                rrb.Horizontal(
                    series_view("exposure (µs)", [p(S.EXPOSURE_COMMANDED), p(S.EXPOSURE_APPLIED)]),
                    series_view("gain (linear)", [p(S.GAIN_COMMANDED), p(S.GAIN_APPLIED)]),
                    column_shares=[3, 1],
                ),
                series_view("saturated fraction", [p(S.OVER_EXPOSED), p(S.UNDER_EXPOSED), p(S.SATURATED)],
                            y_range=(0.0, 1.0)),
                row_shares=[3, 2, 2, 2],
            ),
            rrb.Vertical(
                series_view("prediction error (ln)", [p(S.PREDICTION_ERROR)]),
                rrb.TextLogView(origin="/", contents=[f"/{p(S.LOG)}", f"/{S.TUNING}"], name="log"),
            ),
            column_shares=[3, 1],
        ),
        *panels(),  # every entity is on both `t` and `frame`
    )
