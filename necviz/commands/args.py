"""The flag groups several commands share, and the option objects they become.

Light at import (the parser is built from them before any command runs): every heavy import is inside
the function that needs it.
"""

from __future__ import annotations

import argparse

from necviz.names import CONTROLLER_NAMES, LAYOUT_NAMES, SCENARIO_NAMES


def controller_choices():
    return sorted(CONTROLLER_NAMES)


def controller_list(text: str):
    """``--controllers``: checked against :data:`CONTROLLER_NAMES` without importing the controllers
    (the same rules and message as :func:`necviz.options.parse_controllers`, which checks again)."""
    names = [n.strip() for n in text.split(",") if n.strip()] if isinstance(text, str) else [str(n) for n in text]
    unknown = [
        n
        for n in names
        if n.split("@", 1)[0] not in CONTROLLER_NAMES
        or ("@" in n and not n.split("@", 1)[1].replace("-", "_").isidentifier())
    ]
    if not names or unknown:
        raise argparse.ArgumentTypeError(
            f"unknown controller(s) {', '.join(unknown) or '(none given)'}; "
            f"available: {', '.join(sorted(CONTROLLER_NAMES))} (a variant: KIND@LABEL)"
        )
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError("each controller may appear once in --controllers")
    return tuple(names)


def add_scene_args(parser, emulated: bool = False) -> None:
    """``--scenario`` (a preset or a TOML file), ``--seed``, ``--duration`` and ``--set KEY=VALUE``."""
    from necviz.flags import number

    g = parser.add_argument_group("emulated scene" if emulated else "scene")
    g.add_argument(
        "--scenario",
        default="tunnel_exit",
        metavar="NAME|FILE.toml",
        help=f"a preset ({', '.join(SCENARIO_NAMES)}) or a TOML scenario file (default tunnel_exit)",
    )
    g.add_argument(
        "--seed", type=number("--seed"), default=None, help="scene and noise seed (default: the file's, or 0)"
    )
    if not emulated:
        g.add_argument(
            "--duration",
            type=number("--duration"),
            default=None,
            metavar="S",
            help="simulated seconds (default: the scenario's)",
        )
    g.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a scenario parameter (repeatable), e.g. --set step_db=90",
    )


def scene_options(args, *, scene_duration: bool = True):
    """The scene flags as :class:`SceneOptions`; ``scene_duration=False`` (``live``): ``--duration`` is the
    session's length, not the simulated scene's (an emulated camera streams as long as the session)."""
    from necviz.options import SceneOptions, parse_setting

    params = dict(parse_setting(s) for s in args.set)
    duration = args.duration if scene_duration else None
    return SceneOptions(args.scenario, seed=args.seed, duration_s=duration, params=params)


def add_show_args(parser, tuning: bool = True) -> None:
    from necviz.dashboard.viewer_flags import add_viewer_args
    from necviz.flags import number

    add_viewer_args(parser, LAYOUT_NAMES)
    g = parser.add_argument_group("run")
    g.add_argument(
        "--speed",
        default="auto",
        help="'max' (as fast as possible), 1 (real time) or xN; default: real time when a viewer "
        "watches, max when only saving",
    )
    g.add_argument(
        "--event-window-ms", type=number("--event-window-ms"), default=33.3, help="event image window (default 33.3 ms)"
    )
    g.add_argument(
        "--event-points",
        type=number("--event-points"),
        default=0,
        metavar="N",
        help="also log up to N raw events per window as points (default 0: images only)",
    )
    g.add_argument(
        "--image-rate",
        type=number("--image-rate"),
        default=None,
        metavar="HZ",
        help="log at most HZ frames per lane and HZ event images per second of sensor time (a lighter --save "
        "for long runs: 2 keeps an hour of live in ~0.2 GB; default: every one)",
    )
    g.add_argument("--profile", metavar="FILE.json", help="camera profile (CRF, TEDI thresholds and compensation)")
    g.add_argument("--force", action="store_true", help="replace existing output files")
    if tuning:
        g.add_argument("--tune-file", metavar="FILE", help="watch FILE for 'key = value' changes while running")
        g.add_argument("--no-prompt", action="store_true", help="do not read tuning commands from the terminal")
        g.add_argument(
            "--dvs",
            action="append",
            default=[],
            metavar="KEY=VALUE",
            help="set a DVS control at start (repeatable): c_on, c_off (ln), refractory_us, bandwidth_hz, "
            "ba_filter_us, refractory_filter_us, or bias.NAME=COARSE/FINE; P-TEDI's thresholds follow",
        )


def add_clip_args(parser) -> None:
    """``--clips DIR`` and its bounds: the flight recorder (necviz.dashboard.flight_recorder)."""
    from necviz.flags import number

    g = parser.add_argument_group("flight recorder (a clip around every saturated frame and every 'mark')")
    g.add_argument("--clips", metavar="DIR", help="write a clip (.necrec + .rrd) around every failure into DIR")
    g.add_argument(
        "--clip-before", type=number("--clip-before"), default=None, metavar="S", help="seconds kept before (default 5)"
    )
    g.add_argument(
        "--clip-after",
        type=number("--clip-after"),
        default=None,
        metavar="S",
        help="seconds recorded after (default 5)",
    )
    g.add_argument(
        "--clip-memory",
        type=number("--clip-memory"),
        default=None,
        metavar="MB",
        help="memory budget of the recorder, its writer included; oldest data dropped beyond (512)",
    )


def clip_options(args):
    bounds = {"--clip-before": "clip_before", "--clip-after": "clip_after", "--clip-memory": "clip_memory"}
    given = {flag: vars(args)[k] for flag, k in bounds.items() if vars(args)[k] is not None}
    if not args.clips:
        if given:
            from necviz.core.errors import ParameterError

            raise ParameterError(f"{next(iter(given))} sets the flight recorder: it needs --clips DIR")
        return None
    from necviz.options import ClipOptions

    kw = {"before_s": "--clip-before", "after_s": "--clip-after", "memory_mb": "--clip-memory"}
    return ClipOptions(args.clips, **{k: given[f] for k, f in kw.items() if f in given})


def add_video_args(parser) -> None:

    from necviz.flags import number

    g = parser.add_argument_group("video")
    g.add_argument(
        "--video",
        metavar="OUT.mp4",
        help="also write an H.264 video of the dashboard (frames side by side, events, over-exposure, time); "
        "--speed 0.1 makes it ten times slower than real time (needs: pip install 'necviz[video]')",
    )
    g.add_argument(
        "--video-fps", type=number("--video-fps"), default=30.0, metavar="FPS", help="video frame rate (default 30)"
    )


def video_options(args):
    if not args.video:
        return None
    from necviz.options import VideoOptions

    speed = None if str(args.speed).lower() in ("auto", "max", "fast", "0") else args.speed
    return VideoOptions(args.video, speed=speed, fps=args.video_fps, force=args.force)


def show_options(args):
    from necviz.options import ShowOptions

    return ShowOptions(
        args.speed,
        event_window_ms=args.event_window_ms,
        event_points=args.event_points,
        image_rate_hz=args.image_rate,
    )


def tune_options(args):
    from pathlib import Path

    from necviz.core.errors import ParameterError
    from necviz.options import TuneOptions

    if args.tune_file and not Path(args.tune_file).is_file():
        raise ParameterError(f"--tune-file: {args.tune_file!r} is not a file")
    from necviz.dvs_controls import parse_assignment

    dvs = tuple(parse_assignment(item) for item in args.dvs)  # TuneOptions checks the values
    return TuneOptions(prompt=not args.no_prompt, file=args.tune_file, dvs=dvs)


def add_output_args(parser, json_help: str = "write the results as JSON", force_help="replace an existing --json file"):
    """``--json FILE`` and ``--force`` (the benchmarks)."""
    parser.add_argument("--json", metavar="FILE", help=json_help)
    parser.add_argument("--force", action="store_true", help=force_help)


def json_output(args):
    """``--json``, checked as a new output (or one ``--force`` replaces) before the command runs."""
    if args.json:
        from necviz.outputs import check_output

        check_output(args.json, "--json", force=args.force)
    return args.json
