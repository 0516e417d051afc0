"""Pieces the layouts share: image views sized to the sensor, time-series views, the lane palette."""

from __future__ import annotations

import rerun.blueprint as rrb

from necviz import schema as S

#: One colour per controller (RGB), the same in every layout, plot and frame header. Keyed by the
#: controller's registered name (a lane named otherwise, e.g. ``camera`` in ``live`` and ``replay``,
#: takes its controller's colour). Every pair is at least 100 apart in RGB (Euclidean distance in
#: 0..255; ``tests/test_dashboard.py`` checks it here and in a demo's recording):
#: the demo's seven lanes were picked by hand (NEC green and its ablation ``nec-frames`` lime, the
#: baselines blue, orange, purple, grey and cyan), the others by a greedy max-min search over a
#: 15-step RGB grid restricted to mid luminance (readable on Rerun's dark and light themes) and
#: kept at least 100 from :data:`SATURATED_RGB` too. Closest pair: ``navid`` and ``fixed``, 104.5.
LANE_COLORS: dict[str, tuple[int, int, int]] = {
    "nec": (0, 200, 80),
    "nec-frames": (170, 220, 0),
    "navid": (40, 120, 255),
    "shim": (255, 140, 0),
    "begin": (190, 70, 230),
    "builtin": (140, 140, 140),
    "fixed": (0, 210, 220),
    "nec-paper": (60, 255, 0),
    "nec-raw": (135, 210, 255),
    "nec-tuned": (255, 180, 195),
    "navid-tuned": (0, 75, 135),
    "shim-tuned": (90, 60, 0),
    "begin-tuned": (150, 30, 105),
}
#: Lanes outside the palette (custom controllers) take these in turn.
FALLBACK_COLORS = [(255, 255, 255), (255, 220, 60), (120, 90, 255), (0, 130, 90)]
#: Under each lane's frame entity (``NAME/frame``), logged by :mod:`necviz.dashboard.sink`: the header
#: above the frame (a line in the lane's colour, labelled with the frame's exposure and gain) and a red
#: outline around the frame while it is saturated (more than half its pixels clipped).
FRAME_HEADER = "frame/header"
FRAME_SATURATED = "frame/saturated_outline"
#: Saturated frames: their markers in the plots and the outline around the frame.
SATURATED_RGB = (255, 30, 60)
#: Series that are a reference for the lane's own (commanded beside applied, "same as the last
#: frame" beside P-TEDI's error): a neutral light grey, far from every lane colour's hue.
REFERENCE_RGB = (225, 225, 225)
#: The frame-measured irradiance beside P-TEDI's prediction.
MEASURED_RGB = (255, 160, 40)
#: A lane whose curve moves on every frame (``builtin``'s sawtooth) would hide the others: drawn thin
#: and translucent (alpha of 255).
BACKGROUND_LANES = {"builtin": 110}


def lane_color(lane: str, index: int = 0) -> tuple[int, int, int]:
    """The palette colour of ``lane`` (a controller name), else the ``index``-th fallback colour."""
    return LANE_COLORS.get(lane, FALLBACK_COLORS[index % len(FALLBACK_COLORS)])


def image_view(entity: str, name: str, width: int, height: int, header_px: int = 0) -> rrb.Spatial2DView:
    """A 2D view of ``entity`` and what is logged under it (the frame header and saturated outline),
    framing the sensor plus ``header_px`` above it for the header."""
    return rrb.Spatial2DView(
        origin=f"/{entity}",
        contents="$origin/**",
        name=name,
        visual_bounds=rrb.VisualBounds2D(x_range=[0, width], y_range=[-header_px, height]),
    )


def recent(seconds: float | None):
    """A visible time range of the last ``seconds`` before the cursor (``None``: everything)."""
    if seconds is None:
        return None
    return [
        rrb.VisibleTimeRange(
            S.TIME,
            start=rrb.TimeRangeBoundary.cursor_relative(seconds=-seconds),
            end=rrb.TimeRangeBoundary.cursor_relative(),
        )
    ]


def series_view(
    name: str, entities: list[str], window_s: float | None = None, y_range=None, legend: str | None = None
) -> rrb.TimeSeriesView:
    """A time series of ``entities``. ``y_range``: a fixed y-axis (zoom still works); ``legend``: its
    corner (``LeftTop``, ``RightTop``, ``LeftBottom``, ``RightBottom``), by default none: a legend
    inside the plot covers curves wherever the data go, so the view's name says which colour is what
    (the lane's own colour for its curves, grey for references; hovering a curve names it)."""
    axis = rrb.ScalarAxis(range=y_range, zoom_lock=False) if y_range is not None else None
    plot_legend = rrb.PlotLegend(visible=False) if legend is None else rrb.PlotLegend(corner=legend, visible=True)
    return rrb.TimeSeriesView(
        origin="/",
        contents=[f"/{e}" for e in entities],
        name=name,
        axis_y=axis,
        plot_legend=plot_legend,
        time_ranges=recent(window_s),
    )


def panels(timeline: str = S.TIME, time_panel: str = "collapsed") -> list:
    """The panels around the views: the time panel (collapsed: the scrubber and play controls only,
    the views keep the room), the blueprint and selection panels hidden away."""
    return [
        rrb.TimePanel(state=time_panel, timeline=timeline),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
    ]
