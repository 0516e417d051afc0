"""Rerun blueprints, built in code: ``live`` (tuning one camera), ``inspect`` (stepping through a
recorded failure) and ``compare`` (one column per controller).

:func:`make_blueprint` builds one by name for the given lanes (entity roots, see
:mod:`necviz.schema`) and sensor size. :func:`style_series` logs the static series styles
(names, lane colours, saturated-frame markers) that make the plots readable.
"""

from __future__ import annotations

if __name__ != "necviz.layouts":  # the folder imported as a top-level package (e.g. from the repository root)
    raise ImportError(
        f"this folder is the package necviz.layouts, not {__name__!r}: import necviz.layouts "
        "(installed by `pip install -e .` from the repository root)"
    )


import rerun as rr
import rerun.blueprint as rrb

from necviz import schema as S
from necviz.core.errors import ParameterError
from necviz.layouts import blueprints
from necviz.layouts.views import lane_color

LAYOUTS = {"live": blueprints.live, "inspect": blueprints.inspect, "compare": blueprints.compare}


def make_blueprint(name: str, lanes: list[str], width: int, height: int) -> rrb.Blueprint:
    """The named layout for these lanes on a ``width`` x ``height`` sensor."""
    if name not in LAYOUTS:
        raise ParameterError(f"unknown layout {name!r}; available: {', '.join(LAYOUTS)}")
    if not lanes:
        raise ParameterError("a layout needs at least one lane")
    return LAYOUTS[name](list(lanes), int(width), int(height))


def style_series(rec: rr.RecordingStream, lanes: list[str]) -> None:
    """Static series styles: lane colour, a name per curve, points for saturated-frame markers."""
    for i, n in enumerate(lanes):
        c = lane_color(n, i)
        dim = tuple(int(v * 0.55) for v in c)
        lines = {
            S.EXPOSURE_COMMANDED: (f"{n} commanded", dim),
            S.EXPOSURE_APPLIED: (f"{n} applied", c),
            S.GAIN_COMMANDED: (f"{n} gain commanded", dim),
            S.GAIN_APPLIED: (f"{n} gain applied", c),
            S.IRRADIANCE_PREDICTED: (f"{n} P-TEDI", c),
            S.IRRADIANCE_FRAME: (f"{n} frame", (255, 160, 40)),
            S.OVER_EXPOSED: (f"{n} over", c),
            S.UNDER_EXPOSED: (f"{n} under", dim),
            S.LATENCY: (f"{n} latency µs", c),
            S.PREDICTION_ERROR: (f"{n} error", c),
            S.PERSISTENCE_ERROR: (f"{n} same as last frame", dim),
            S.PREDICTION_SKILL: (f"{n} skill vs last frame", c),
        }
        for leaf, (label, col) in lines.items():
            rec.log(S.path(n, leaf), rr.SeriesLines(colors=[col], names=[label], widths=[1.5]), static=True)
        for leaf, (label, col) in (
            (S.IRRADIANCE_FRAME, (f"{n} frame", (255, 160, 40))),
            (S.SATURATED, (f"{n} saturated frame", (231, 76, 60))),
        ):
            rec.log(
                S.path(n, leaf),
                rr.SeriesPoints(colors=[col], names=[label], markers=["circle"], marker_sizes=[4.0]),
                static=True,
            )
    rec.log(S.EVENT_RATE, rr.SeriesLines(colors=[(200, 200, 200)], names=["events/s"], widths=[1.5]), static=True)


__all__ = ["LAYOUTS", "make_blueprint", "style_series", "lane_color"]
