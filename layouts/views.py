"""Pieces the layouts share: image views sized to the sensor, time-series views, lane colours."""

from __future__ import annotations

import rerun.blueprint as rrb

from necviz import schema as S

#: One colour per lane (RGB), stable across layouts and series styles.
LANE_COLORS = {
    "nec": (46, 204, 113),
    "navid": (52, 152, 219),
    "shim": (230, 126, 34),
    "begin": (155, 89, 182),
    "builtin": (149, 165, 166),
    "fixed": (160, 110, 60),
    "camera": (46, 204, 113),
}
_FALLBACK = [(241, 196, 15), (26, 188, 156), (231, 76, 60), (236, 240, 241)]


def lane_color(lane: str, index: int = 0) -> tuple[int, int, int]:
    return LANE_COLORS.get(lane, _FALLBACK[index % len(_FALLBACK)])


def image_view(entity: str, name: str, width: int, height: int) -> rrb.Spatial2DView:
    return rrb.Spatial2DView(
        origin=f"/{entity}",
        contents="$origin",
        name=name,
        visual_bounds=rrb.VisualBounds2D(x_range=[0, width], y_range=[0, height]),
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


def series_view(name: str, entities: list[str], window_s: float | None = None, y_range=None) -> rrb.TimeSeriesView:
    axis = rrb.ScalarAxis(range=y_range, zoom_lock=True) if y_range is not None else None
    return rrb.TimeSeriesView(
        origin="/", contents=[f"/{e}" for e in entities], name=name, axis_y=axis, time_ranges=recent(window_s)
    )


def panels(timeline: str = S.TIME) -> list:
    return [
        rrb.TimePanel(state="expanded", timeline=timeline),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
    ]
