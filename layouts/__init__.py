"""Rerun blueprints, built in code: ``live`` (tuning one camera), ``inspect`` (stepping through a
recorded failure) and ``compare`` (every controller's camera in a grid).

:func:`make_blueprint` builds one by name for the given lanes (entity roots, see
:mod:`necviz.schema`) and sensor size. :func:`style_series` logs the static series styles
(names, one colour per lane from a fixed palette, steps for commands, saturated-frame markers) that
make the plots readable.
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
from necviz.layouts.views import (
    BACKGROUND_LANES,
    FRAME_HEADER,
    FRAME_SATURATED,
    LANE_COLORS,
    MEASURED_RGB,
    REFERENCE_RGB,
    SATURATED_RGB,
    lane_color,
)

LAYOUTS = {"live": blueprints.live, "inspect": blueprints.inspect, "compare": blueprints.compare}
#: Series a controller holds until it changes them (commands, and each frame's settings): drawn as steps.
STEPPED = (S.EXPOSURE_COMMANDED, S.EXPOSURE_APPLIED, S.GAIN_COMMANDED, S.GAIN_APPLIED)
#: The camera's DVS settings (``dvs/KEY``, one per bias change): names and colours (the thresholds in the
#: reference grey beside P-TEDI's in the lane colour; bandwidth violet beside the grey refractory period).
DVS_STYLES = {
    "c_on": ("DVS c_on (biases)", REFERENCE_RGB),
    "c_off": ("DVS c_off (biases)", REFERENCE_RGB),
    "refractory_us": ("refractory µs", REFERENCE_RGB),
    "bandwidth_hz": ("bandwidth Hz", (170, 120, 255)),
}


def make_blueprint(
    name: str, lanes: list[str], width: int, height: int, labels: dict[str, str] | None = None
) -> rrb.Blueprint:
    """The named layout for these lanes on a ``width`` x ``height`` sensor. ``labels``: lane ->
    the name shown for it (a lane called ``camera`` is shown by its controller's name)."""
    if name not in LAYOUTS:
        raise ParameterError(f"unknown layout {name!r}; available: {', '.join(LAYOUTS)}")
    if not lanes:
        raise ParameterError("a layout needs at least one lane")
    return LAYOUTS[name](list(lanes), int(width), int(height), dict(labels or {}))


def lane_colors(lanes: list[str], labels: dict[str, str] | None = None) -> dict[str, tuple[int, int, int]]:
    """Each lane's colour: its controller's (:data:`~necviz.layouts.views.LANE_COLORS`, by its label),
    else a fallback colour not already taken by another lane."""
    labels = labels or {}
    used = {LANE_COLORS[labels.get(n, n)] for n in lanes if labels.get(n, n) in LANE_COLORS}
    out, k = {}, 0
    for n in lanes:
        key = labels.get(n, n)
        if key in LANE_COLORS:
            out[n] = LANE_COLORS[key]
            continue
        c = lane_color(key, k)
        while c in used and k < 8:
            k += 1
            c = lane_color(key, k)
        used.add(c)
        out[n] = c
        k += 1
    return out


def style_series(rec: rr.RecordingStream, lanes: list[str], labels: dict[str, str] | None = None) -> None:
    """Static styles: each lane's colour and name on its curves (commanded and applied settings drawn
    as steps; the reference series, "same as the last frame" and the commands, in a neutral grey beside
    the lane's colour), points for saturated-frame markers, the frame header's colour."""
    labels = labels or {}
    colors = lane_colors(lanes, labels)
    for n in lanes:
        label = labels.get(n, n)
        c = colors[n]
        alpha = BACKGROUND_LANES.get(label, 255)
        width = 1.0 if alpha < 255 else 2.0
        lane_rgba = (*c, alpha)
        lines = {
            S.EXPOSURE_COMMANDED: (f"{label} commanded", REFERENCE_RGB),
            S.EXPOSURE_APPLIED: (f"{label} applied", lane_rgba),
            S.GAIN_COMMANDED: (f"{label} gain commanded", REFERENCE_RGB),
            S.GAIN_APPLIED: (f"{label} gain applied", lane_rgba),
            S.IRRADIANCE_PREDICTED: (f"{label} P-TEDI", lane_rgba),
            S.IRRADIANCE_FRAME: (f"{label} frame measured", MEASURED_RGB),
            S.OVER_EXPOSED: (f"{label} over-exposed", lane_rgba),
            S.UNDER_EXPOSED: (f"{label} under-exposed", REFERENCE_RGB),
            S.LATENCY: (f"{label} latency µs", lane_rgba),
            S.PREDICTION_ERROR: (f"{label} P-TEDI error", lane_rgba),
            S.PERSISTENCE_ERROR: (f"{label} same-as-last-frame error", REFERENCE_RGB),
            S.PREDICTION_SKILL: (f"{label} skill vs last frame", lane_rgba),
            S.PTEDI_C_ON: (f"{label} P-TEDI c_on", lane_rgba),
            S.PTEDI_C_OFF: (f"{label} P-TEDI c_off", lane_rgba),
        }
        for leaf, (name, col) in lines.items():
            mode = "StepAfter" if leaf in STEPPED or leaf in (S.PTEDI_C_ON, S.PTEDI_C_OFF) else "Linear"
            rec.log(
                S.path(n, leaf),
                rr.SeriesLines(colors=[col], names=[name], widths=[width], interpolation_mode=mode),
                static=True,
            )
        for leaf, (name, col) in (
            (S.IRRADIANCE_FRAME, (f"{label} frame measured", MEASURED_RGB)),
            (S.SATURATED, (f"{label} saturated frame", SATURATED_RGB)),
        ):
            rec.log(
                S.path(n, leaf),
                rr.SeriesPoints(colors=[col], names=[name], markers=["circle"], marker_sizes=[4.0]),
                static=True,
            )
        rec.log(S.path(n, FRAME_HEADER), rr.Boxes2D.from_fields(colors=[c], show_labels=True), static=True)
        rec.log(
            S.path(n, FRAME_SATURATED), rr.Boxes2D.from_fields(colors=[SATURATED_RGB], show_labels=True), static=True
        )
    rec.log(S.EVENT_RATE, rr.SeriesLines(colors=[(200, 200, 200)], names=["events/s"], widths=[1.5]), static=True)
    for key, (name, col) in DVS_STYLES.items():  # camera settings: held until the next bias change
        rec.log(
            f"{S.DVS}/{key}",
            rr.SeriesLines(colors=[col], names=[name], widths=[1.5], interpolation_mode="StepAfter"),
            static=True,
        )


__all__ = ["LAYOUTS", "STEPPED", "make_blueprint", "lane_color", "lane_colors", "style_series"]
