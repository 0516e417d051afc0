"""``necviz replay FILE``: a recording in open loop, in the ``inspect`` layout.

The file's packets go through P-TEDI and a controller (NEC by default) exactly as live, but the
commands only show what the controller *would* have done: the recorded exposures are what they
are. For every frame the replay reports what the frame measured (ln Pbar), what P-TEDI predicted
for that exposure from the events before it (``ln P(s) + ln E_p(s)``, the prediction at the
exposure start carried across the exposure by its events) and their difference, and flags
frames more than 50 % saturated.

What the events add: beside P-TEDI's error the replay reports the errors of two predictors that
see frames only — persistence, "the same as the last frame" (also what P-TEDI predicts without
events), and the trend through the last two frames — and P-TEDI's skill score against each,
``1 - MSE_ptedi / MSE_reference`` over the frames both predict (:mod:`necviz.core.prediction_skill`):
in the summary text, in the JSON (``prediction_skill``) and on the dashboard
(``NAME/prediction_error/persistence``, ``NAME/prediction_skill``).

``json`` writes ``{"frames", "events", "duration_s", "saturated_frames_50",
"prediction_error_rmse", "prediction_error_frames", "prediction_skill", "saturation_causes",
"frames_detail": [...]}`` (``prediction_skill``: ``{"persistence" | "trend": {"frames",
"rmse_ptedi", "rmse_reference", "skill"}}``);
each saturated frame in ``frames_detail`` carries its diagnosed ``saturation_cause`` and
``saturation_explanation`` (:mod:`necviz.core.diagnosis`), ``saturation_causes`` counts them.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from necviz.commands import Command
from necviz.commands.args import (
    add_show_args,
    add_video_args,
    controller_choices,
    show_options,
    video_options,
)
from necviz.core.errors import ParameterError
from necviz.progress import output, plural

if TYPE_CHECKING:
    from necviz.options import ReplayOptions, ViewerOptions

LANE = "camera"


def open_for_replay(path, exposure_us=None, start_s=None, end_s=None, fmt=None):
    """Open ``path`` restricted to ``[first + start_s, first + end_s)`` seconds from its first
    timestamp (:mod:`necviz.drivers.recordings.cut`). Returns ``(recording, origin_us)``."""
    from necviz.drivers.recordings.cut import open_cut

    recording, origin = open_cut(path, start_s, end_s, exposure_us=exposure_us, format=fmt)
    if origin is None:
        recording.close()
        raise ParameterError(f"{path}: the recording holds no events or frames")
    return recording, origin


def summarise(stats: dict, lane: str = LANE) -> dict:
    """The replay's JSON summary from the run's statistics (telemetry included)."""
    tel = stats["telemetry"][lane]
    s = tel.summary()
    return {
        "frames": s["frames"],
        "events": stats["events"],
        "duration_s": stats["duration_s"],
        "saturated_frames_50": s["saturated_frames_50"],
        "prediction_error_rmse": s["prediction_error_rmse"],
        "prediction_error_frames": s["prediction_error_frames"],
        "prediction_skill": s["prediction_skill"],
        "saturation_causes": s["saturation_causes"],
        "frames_detail": tel.table.rows(),
    }


def skill_lines(skill: dict) -> list[str]:
    """The summary's lines on P-TEDI against the frame-only predictors (``prediction_skill``)."""
    names = {"persistence": "same as the last frame", "trend": "trend of the last two frames"}
    lines = []
    for ref, label in names.items():
        g = skill[ref]
        if not g["frames"]:
            lines.append(f"  against {label}: no frame to compare")
            continue
        sk = "undefined (the reference is exact)" if g["skill"] is None else f"{g['skill']:+.3f}"
        lines.append(
            f"  against {label} (frames only), {plural(g['frames'], 'frame')}: RMSE P-TEDI {g['rmse_ptedi']:.4f} ln, "
            f"{label} {g['rmse_reference']:.4f} ln; skill score 1 - MSE ratio = {sk}"
        )
    return lines


def run(options: ReplayOptions, viewer: ViewerOptions | None = None, out=...) -> dict:
    """Replay a recording through P-TEDI and a controller in open loop, frame by frame.

    Parameters
    ----------
    options : ReplayOptions
        The file, the range, the controller, the JSON summary, video.
    viewer : ViewerOptions, optional
        Where the Rerun data goes (default: a native viewer with a display, else a file).
    out : file, optional
        Where progress and the summary are printed (default: standard output; ``None``: nothing).

    Returns
    -------
    dict
        The summary: per-frame prediction errors, P-TEDI's skill score against the frame-only
        predictors, saturated frames and their diagnosed causes.

    Raises
    ------
    RecordingError
        A missing, unreadable or damaged file (what preceded the damage is replayed first).
    ParameterError
        Bad options or output files, or an empty range.
    """
    from necviz.dashboard.viewer import resolve
    from necviz.options import ViewerOptions
    from necviz.profiles import load_profile

    out = output(out)
    path = Path(options.file)
    viewer = resolve(viewer or ViewerOptions(), "replay")  # the headless default filled in
    options.check_outputs(viewer)  # before anything is opened
    profile = load_profile(options.profile) if options.profile is not None else None
    from necviz.drivers.recordings import readable_copy

    with readable_copy(path, options.pipe_timeout_s) as source:
        return _replay(options, viewer, out, path, source, profile)


def _replay(options: ReplayOptions, viewer, out, path: Path, source: Path, profile) -> dict:
    from necviz.core.control import CameraLimits, make_controller
    from necviz.dashboard import session as dashboard
    from necviz.dashboard.session import Session, lane_labels
    from necviz.dashboard.video import video_observer
    from necviz.layouts import make_blueprint
    from necviz.layouts.focus import focus_blueprint
    from necviz.outputs import write_json
    from necviz.pipeline import Lane
    from necviz.wording import diagnosed_causes, saturated_frames

    show = options.show
    video_options = options.video
    if video_options is not None:  # only files: the run goes as fast as it can, the video keeps its own pace
        from necviz.dashboard.video import plan

        show, video_options = plan(show, video_options, viewer)
    recording, origin = open_for_replay(source, options.exposure_us, options.start_s, options.end_s, options.format)
    sensor = recording.sensor
    limits = CameraLimits()
    kw = {} if profile is None else {"tedi": profile.tedi, "crf": profile.crf}
    rate = recording.camera_info.event_rate_max  # the recorded sensor's bus ceiling, if known (NEC's escape rule)
    ctrl = make_controller(options.controller, sensor=sensor, limits=limits, event_rate_max=rate, **kw)
    lane = Lane(LANE, ctrl, drives=False)
    props = {
        "command": "replay",
        "file": str(path),
        "format": recording.format,
        "exposure_source": recording.exposure_source,
        "controller": options.controller,
        "camera_limits": limits,
        "camera_profile": str(options.profile) if options.profile else "default DAVIS346 response",
        **{f"recorded.{k}": v for k, v in recording.properties.items()},
    }
    print(
        f"  replay: {path} ({recording.format}, {sensor.width}x{sensor.height}, exposure "
        f"{recording.exposure_source}); {options.controller} in open loop",
        file=out,
    )
    from necviz.dashboard.flight_recorder import clip_focus

    focus = clip_focus(recording.properties)  # a clip: the session's time axis and window
    if focus is not None:
        origin = focus[3]
        print(
            f"  clip: {recording.properties.get('clip_cause', 'failure')} at {focus[2]:.3f} s; the viewer loops over "
            f"{focus[0]:.3f}..{focus[1]:.3f} s",
            file=out,
        )
    result = {}

    def finish(stats):  # before the --save file is committed: a failure here leaves no file at all
        summary = summarise(stats)
        if (
            not summary["events"]
            and not summary["frames"]
            and (options.start_s is not None or options.end_s is not None)
        ):
            raise ParameterError(
                f"nothing in the selected range (--start {options.start_s} --end {options.end_s} s): it "
                f"lies past the end of {path.name}; `necviz info {path}` shows its duration"
            )
        if options.json is not None:
            write_json(options.json, summary, flag="--json")
        result["summary"] = summary

    layout = viewer.layout or "inspect"
    blueprint = make_blueprint(layout, [LANE], sensor.width, sensor.height, lane_labels([lane]))
    if focus is not None:
        blueprint = focus_blueprint(blueprint, *focus[:2])
    settings = Session(
        command="replay",
        layout=layout,
        title=f"necviz replay: {path.name}",
        properties=props,
        show=show,
        origin_us=origin,
        lossless=True,
        observers=[video_observer(video_options)] if video_options is not None else [],
        before_commit=finish,
    )
    dashboard.run(recording, [lane], viewer, blueprint, settings, out)
    summary = result["summary"]
    for w in recording.warnings:
        print(f"  warning: {w}", file=out)
    rmse = summary["prediction_error_rmse"]
    print(
        f"  prediction error (P-TEDI vs frame, ln): RMSE {rmse:.3f} over {plural(summary['prediction_error_frames'], 'frame')}"
        if rmse is not None
        else "  prediction error: no frame pair to compare (need two usable frames)",
        file=out,
    )
    for line in skill_lines(summary["prediction_skill"]):
        print(line, file=out)
    sat = [d["sequence"] for d in summary["frames_detail"] if d["saturated"]]
    if sat:
        print(f"  {saturated_frames(sat)}", file=out)
        causes = diagnosed_causes(summary["saturation_causes"])
        if causes:
            print(f"  {causes}" + ("; each frame's explanation is in --json" if options.json is None else ""), file=out)
    if options.json is not None:
        print(f"  wrote {options.json}", file=out)
    return summary


def add_arguments(p) -> None:
    from necviz.flags import number
    from necviz.names import FORMATS

    p.add_argument("file", metavar="FILE", help="the recording")
    p.add_argument(
        "--start", type=number("--start"), default=None, metavar="S", help="start S seconds into the recording"
    )
    p.add_argument("--end", type=number("--end"), default=None, metavar="S", help="stop S seconds into the recording")
    p.add_argument(
        "--exposure-us",
        type=number("--exposure-us"),
        default=None,
        help="exposure for formats that do not store it (AEDAT 2.0 estimates it from frame timing)",
    )
    p.add_argument("--format", default=None, choices=FORMATS, help="skip detection")
    p.add_argument("--controller", default="nec", choices=controller_choices(), help="shown in open loop (default nec)")
    p.add_argument("--json", metavar="OUT", help="write the summary (per-frame detail included) as JSON")
    p.add_argument(
        "--pipe-timeout",
        type=number("--pipe-timeout"),
        default=None,
        metavar="S",
        help="accept FILE as a named pipe: copy what it delivers, waiting at most S seconds for data",
    )
    add_show_args(p, tuning=False)
    add_video_args(p)


def _command(args) -> int:
    from necviz.dashboard.viewer_flags import viewer_options
    from necviz.options import ReplayOptions

    run(
        ReplayOptions(
            args.file,
            start_s=args.start,
            end_s=args.end,
            exposure_us=args.exposure_us,
            format=args.format,
            controller=args.controller,
            json=args.json,
            force=args.force,
            profile=args.profile,
            show=show_options(args),
            video=video_options(args),
            pipe_timeout_s=args.pipe_timeout,
        ),
        viewer_options(args),
    )
    return 0


COMMAND = Command(
    name="replay",
    help="a recording in open loop: frames, events, P-TEDI vs frames, what NEC would do",
    description="Replays FILE (necviz, AEDAT 4/3.1/2.0, ROS bag, RPG text, HDF5) through P-TEDI "
    "and a controller in open loop, in the inspect layout, and reports the per-frame "
    "prediction error and saturated frames.",
    add_arguments=add_arguments,
    run=_command,
)
