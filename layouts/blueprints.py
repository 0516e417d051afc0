"""The three blueprints: ``live`` (tuning one camera), ``inspect`` (stepping through a recorded
failure) and ``compare`` (every controller's camera at once). Each takes the lanes (entity roots,
see :mod:`necviz.schema`), the sensor size and the lanes' display names (``labels``: a lane
named ``camera`` is shown by its controller's name)."""

from __future__ import annotations

import math

import rerun.blueprint as rrb

from necviz import schema as S
from necviz.layouts.views import image_view, panels, series_view

#: the ``live`` layout's curves show the last this many seconds of sensor time
WINDOW_S = 10.0
#: Sensor rows' worth of room above each frame for its header (exposure, gain; the lane's colour),
#: which the sink logs as ``NAME/frame/header`` (:mod:`necviz.dashboard.sink`).
HEADER_PX = 22
#: The shared event view: one event stream feeds every lane of a rig.
EVENTS_TITLE = "events: ON blue, OFF red (shared)"
#: The skill plot's y-axis: a skill of −1,000 on one frame would flatten every other value.
SKILL_RANGE = (-1.0, 1.0)
SKILL_TITLE = "skill vs last frame (axis −1…1)"
#: The inspect layout's irradiance plot (``name``: the lane's controller).
INSPECT_IRRADIANCE = "{name}: ln irradiance, P-TEDI predicted vs each frame measured (orange)"
#: The DVS thresholds: the camera's (its biases through the bias model) beside the ones P-TEDI integrates.
DVS_THRESHOLDS = "{name}: DVS thresholds, ln (grey: set by the biases; colour: P-TEDI's)"
DVS_TIMING = "DVS refractory (µs, grey) and bandwidth (Hz, violet)"


def dvs_views(lane: str, name: str) -> list[rrb.TimeSeriesView]:
    """The bias timeline: the camera's contrast thresholds (``dvs/c_on``, ``dvs/c_off``) beside the
    lane's P-TEDI thresholds (``LANE/ptedi/c_on|c_off``), and the refractory period and bandwidth.
    Logged on each bias change only, so the whole run is shown (a 10 s window would drop a setting made
    at the start)."""
    return [
        series_view(
            DVS_THRESHOLDS.format(name=name),
            [f"{S.DVS}/c_on", f"{S.DVS}/c_off", S.path(lane, S.PTEDI_C_ON), S.path(lane, S.PTEDI_C_OFF)],
        ),
        series_view(DVS_TIMING, [f"{S.DVS}/refractory_us", f"{S.DVS}/bandwidth_hz"]),
    ]


def _label(lane: str, labels: dict | None) -> str:
    return (labels or {}).get(lane, lane)


def grid_columns(n: int) -> int:
    """Columns of the frame grid for ``n`` panels: at most four, rows as full as possible
    (8 panels: 4 x 2; 5 or 6: 3 x 2; 3: 3 x 1)."""
    rows = math.ceil(n / 4)
    return max(1, math.ceil(n / rows))


def live(lanes: list[str], width: int, height: int, labels: dict | None = None) -> rrb.Blueprint:
    """``live``: one camera for tuning — big frame and events side by side, curves of the last seconds below."""
    n = lanes[0]
    name = _label(n, labels)
    window_s = WINDOW_S
    p = lambda leaf: S.path(n, leaf)  # noqa: E731
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                image_view(p(S.FRAME_IMAGE), f"{name}: frame", width, height, HEADER_PX),
                image_view(S.EVENTS, EVENTS_TITLE, width, height, HEADER_PX),
            ),
            rrb.Horizontal(
                series_view(
                    f"{name}: exposure µs (grey: commanded)", [p(S.EXPOSURE_COMMANDED), p(S.EXPOSURE_APPLIED)], window_s
                ),
                series_view(
                    "ln irradiance (orange: frame)", [p(S.IRRADIANCE_PREDICTED), p(S.IRRADIANCE_FRAME)], window_s
                ),
                series_view(
                    "clipped (grey: under; red: saturated)",
                    [p(S.OVER_EXPOSED), p(S.UNDER_EXPOSED), p(S.SATURATED)],
                    window_s,
                    y_range=(0.0, 1.0),
                ),
                series_view("events/s", [S.EVENT_RATE], window_s),
                series_view("command latency (µs)", [p(S.LATENCY)], window_s),
                rrb.Vertical(*dvs_views(n, name)),
            ),
            row_shares=[3, 2],
        ),
        *panels(),
    )


def inspect(lanes: list[str], width: int, height: int, labels: dict | None = None) -> rrb.Blueprint:
    """``inspect``: step through a recorded failure frame by frame.

    Frame and events on top; below, the P-TEDI prediction against the frame-measured irradiance,
    exposure and gain (commanded as steps: a command holds until the next), and the clipped
    fractions with a marker on every saturated frame; at the side P-TEDI's prediction error beside
    the error of "the same as the last frame", and P-TEDI's running skill score against it (its axis
    held at −1..1, so one wild frame cannot flatten it); the lane's log (saturated frames and their
    diagnosed causes, controller switches) across the bottom, wide enough for a whole line. The
    plots show the whole recording so the cursor can be scrubbed across the failure.
    """
    n = lanes[0]
    name = _label(n, labels)
    p = lambda leaf: S.path(n, leaf)  # noqa: E731
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                rrb.Vertical(
                    rrb.Horizontal(
                        image_view(p(S.FRAME_IMAGE), f"{name}: frame", width, height, HEADER_PX),
                        image_view(S.EVENTS, EVENTS_TITLE, width, height, HEADER_PX),
                    ),
                    series_view(
                        INSPECT_IRRADIANCE.format(name=name),
                        [p(S.IRRADIANCE_PREDICTED), p(S.IRRADIANCE_FRAME)],
                    ),
                    rrb.Horizontal(
                        series_view(
                            f"{name}: exposure (µs) of each frame, commanded in grey",
                            [p(S.EXPOSURE_COMMANDED), p(S.EXPOSURE_APPLIED)],
                        ),
                        series_view("gain (grey: commanded)", [p(S.GAIN_COMMANDED), p(S.GAIN_APPLIED)]),
                        column_shares=[3, 1],
                    ),
                    series_view(
                        f"{name}: clipped fraction, over-exposed (under-exposed grey, saturated frames red)",
                        [p(S.OVER_EXPOSED), p(S.UNDER_EXPOSED), p(S.SATURATED)],
                        y_range=(0.0, 1.0),
                    ),
                    row_shares=[4, 2, 2, 2],
                ),
                rrb.Vertical(
                    series_view(
                        "prediction error, ln (grey: last frame)",
                        [p(S.PREDICTION_ERROR), p(S.PERSISTENCE_ERROR)],
                    ),
                    series_view(SKILL_TITLE, [p(S.PREDICTION_SKILL)], y_range=SKILL_RANGE),
                    dvs_views(n, name)[0],
                ),
                column_shares=[3, 1],
            ),
            rrb.TextLogView(
                origin="/",
                contents=[f"/{p(S.LOG)}", f"/{S.TUNING}"],
                name=f"{name}: log (saturated frames and their causes, controller switches)",
                columns=rrb.TextLogColumns(
                    # the frame number (the time is under the cursor; its narrow column showed only "…")
                    timeline_columns=[
                        rrb.encodings.TimelineColumn(S.FRAME),
                        rrb.encodings.TimelineColumn(S.TIME, visible=False),
                    ],
                    text_log_columns=[
                        rrb.encodings.TextLogColumn("LogLevel"),
                        rrb.encodings.TextLogColumn("Body"),
                        rrb.encodings.TextLogColumn("EntityPath", visible=False),
                    ],
                ),
            ),
            row_shares=[6, 1],
        ),
        *panels(),  # every entity is on both `t` and `frame`
    )


def compare(lanes: list[str], width: int, height: int, labels: dict | None = None) -> rrb.Blueprint:
    """``compare``: every controller's camera in a grid, the shared events once, overlaid curves below.

    The frames fill a grid of at most four columns (the seven demo lanes and the events: 4 x 2), each
    under a header in its lane's colour with the frame's exposure and gain, outlined in red while
    saturated. Below, every lane's exposure in one plot, every over-exposed fraction in another and
    every P-TEDI prediction in a third, so the moment one recovers and another is still blind lines
    up. No plot carries a legend to cover its curves: a curve's colour is its lane's header colour,
    and hovering it names it.
    """
    views = [image_view(S.path(n, S.FRAME_IMAGE), _label(n, labels), width, height, HEADER_PX) for n in lanes]
    views.append(image_view(S.EVENTS, EVENTS_TITLE, width, height, HEADER_PX))
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Grid(*views, grid_columns=grid_columns(len(views))),
            rrb.Horizontal(
                series_view("exposure of each frame (µs)", [S.path(n, S.EXPOSURE_APPLIED) for n in lanes]),
                series_view(
                    "over-exposed pixels (fraction ≥ 250 DN)",
                    [S.path(n, S.OVER_EXPOSED) for n in lanes],
                    y_range=(0.0, 1.0),
                ),
                series_view("P-TEDI prediction (ln irradiance)", [S.path(n, S.IRRADIANCE_PREDICTED) for n in lanes]),
            ),
            row_shares=[2, 1],
        ),
        *panels(),
    )
