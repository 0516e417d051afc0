"""The three blueprints: ``live`` (tuning one camera), ``inspect`` (stepping through a recorded
failure) and ``compare`` (one column per controller). Each takes the lanes (entity roots, see
:mod:`necviz.schema`) and the sensor size."""

from __future__ import annotations

import rerun.blueprint as rrb

from necviz import schema as S
from necviz.layouts.views import image_view, panels, series_view

#: the ``live`` layout's curves show the last this many seconds of sensor time
WINDOW_S = 10.0


def live(lanes: list[str], width: int, height: int) -> rrb.Blueprint:
    """``live``: one camera for tuning — big frame and events side by side, curves of the last seconds below."""
    n = lanes[0]
    window_s = WINDOW_S
    p = lambda leaf: S.path(n, leaf)  # noqa: E731
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                image_view(p(S.FRAME_IMAGE), "frame", width, height), image_view(S.EVENTS, "events", width, height)
            ),
            rrb.Horizontal(
                series_view("exposure (µs)", [p(S.EXPOSURE_COMMANDED), p(S.EXPOSURE_APPLIED)], window_s),
                series_view("ln irradiance", [p(S.IRRADIANCE_PREDICTED), p(S.IRRADIANCE_FRAME)], window_s),
                series_view(
                    "saturated fraction",
                    [p(S.OVER_EXPOSED), p(S.UNDER_EXPOSED), p(S.SATURATED)],
                    window_s,
                    y_range=(0.0, 1.0),
                ),
                series_view("events/s", [S.EVENT_RATE], window_s),
                series_view("command latency (µs)", [p(S.LATENCY)], window_s),
            ),
            row_shares=[3, 2],
        ),
        *panels(),
    )


def inspect(lanes: list[str], width: int, height: int) -> rrb.Blueprint:
    """``inspect``: step through a recorded failure frame by frame.

    Frame and events on top; below, the P-TEDI prediction against the frame-measured irradiance
    (and their difference, beside the error of "the same as the last frame" and P-TEDI's running
    skill score against it), exposure and gain, and the saturated fractions with a marker on every
    saturated frame; the lane's log (saturated frames, controller switches) at the side. The
    plots show the whole recording so the cursor can be scrubbed across the failure.
    """
    n = lanes[0]
    p = lambda leaf: S.path(n, leaf)  # noqa: E731
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Horizontal(
                    image_view(p(S.FRAME_IMAGE), "frame", width, height), image_view(S.EVENTS, "events", width, height)
                ),
                series_view("ln irradiance: predicted vs frame", [p(S.IRRADIANCE_PREDICTED), p(S.IRRADIANCE_FRAME)]),
                rrb.Horizontal(
                    series_view("exposure (µs)", [p(S.EXPOSURE_COMMANDED), p(S.EXPOSURE_APPLIED)]),
                    series_view("gain (linear)", [p(S.GAIN_COMMANDED), p(S.GAIN_APPLIED)]),
                    column_shares=[3, 1],
                ),
                series_view(
                    "saturated fraction", [p(S.OVER_EXPOSED), p(S.UNDER_EXPOSED), p(S.SATURATED)], y_range=(0.0, 1.0)
                ),
                row_shares=[3, 2, 2, 2],
            ),
            rrb.Vertical(
                series_view(
                    "prediction error (ln): P-TEDI, same as last frame", [p(S.PREDICTION_ERROR), p(S.PERSISTENCE_ERROR)]
                ),
                series_view("skill vs last frame: 1 − MSE ratio", [p(S.PREDICTION_SKILL)]),
                rrb.TextLogView(origin="/", contents=[f"/{p(S.LOG)}", f"/{S.TUNING}"], name="log"),
            ),
            column_shares=[3, 1],
        ),
        *panels(),  # every entity is on both `t` and `frame`
    )


def compare(lanes: list[str], width: int, height: int) -> rrb.Blueprint:
    """``compare``: every controller's frames side by side, the shared events once, overlaid curves below.

    The top row shows each controller's camera frame and, once, the event image all cameras share;
    below, every controller's applied exposure in one plot, every over-exposed rate in another and
    every P-TEDI prediction in a third, so the moment one recovers and another is still blind lines up.
    """
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
