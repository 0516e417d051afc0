"""The ``necviz`` command: argparse mapped onto the library's option objects (:mod:`necviz.options`).

Exit codes: 0 success; 2 a user mistake or bad input (one line ``necviz: error: …``); 3 an
internal error (one line saying it is a bug, with the traceback saved to a file for the report);
130 interrupted.

Start-up: building the parser imports nothing heavy (no NumPy, Numba, Rerun or controllers), so
``--version``, ``--help`` and a mistyped flag answer at once; each command imports what it needs
when it runs. The names the help lists come from plain constants (:data:`CONTROLLER_NAMES`,
:data:`SCENARIO_NAMES`), which ``tests/test_cli.py`` keeps equal to the registries.
"""

from __future__ import annotations

import argparse
import sys

from necviz import __version__

EXIT_USER = 2
EXIT_BUG = 3
from necviz.names import CONTROLLER_NAMES, FORMATS, LAYOUT_NAMES, SCENARIO_NAMES  # noqa: E402, F401 - light


# -- shared option groups -----------------------------------------------------------------------
def _controllers():
    return sorted(CONTROLLER_NAMES)


def _controller_list(text: str):
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


def scene_options(args, duration_s=None, *, scene_duration: bool = True):
    """The scene flags as :class:`SceneOptions`; ``scene_duration=False`` (``live``): ``--duration`` is the
    session's length, not the simulated scene's (an emulated camera streams as long as the session)."""
    from necviz.options import SceneOptions, parse_setting

    params = dict(parse_setting(s) for s in args.set)
    duration = getattr(args, "duration", duration_s) if scene_duration else None
    return SceneOptions(args.scenario, args.seed, duration, params)


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


def _clips(args):
    bounds = {"--clip-before": "clip_before", "--clip-after": "clip_after", "--clip-memory": "clip_memory"}
    given = {flag: getattr(args, k, None) for flag, k in bounds.items() if getattr(args, k, None) is not None}
    if not getattr(args, "clips", None):
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


def _video(args):
    if not getattr(args, "video", None):
        return None
    from necviz.options import VideoOptions

    speed = None if str(args.speed).lower() in ("auto", "max", "fast", "0") else args.speed
    return VideoOptions(args.video, speed=speed, fps=args.video_fps, force=args.force)


def _show(args):
    from necviz.options import ShowOptions

    return ShowOptions(
        args.speed,
        event_window_ms=args.event_window_ms,
        event_points=args.event_points,
        image_rate_hz=getattr(args, "image_rate", None),
    )


def _tune(args):
    from pathlib import Path

    from necviz.core.errors import ParameterError
    from necviz.options import TuneOptions

    if args.tune_file and not Path(args.tune_file).is_file():
        raise ParameterError(f"--tune-file: {args.tune_file!r} is not a file")
    from necviz.dvs_controls import check_assignments

    return TuneOptions(prompt=not args.no_prompt, file=args.tune_file, dvs=check_assignments(args.dvs))


# -- commands -----------------------------------------------------------------------------------
def _cmd_info(args) -> int:
    if args.file:
        return _info_file(args)
    import platform

    from necviz.commands.info import collect_info

    info = collect_info()
    print(f"necviz {info['necviz']}  (Python {platform.python_version()}, {info['cpu_count']} CPU cores)")
    print("packages:")
    for name, v in info["packages"].items():
        print(f"  {name:24s} {v}")
    print(f"numba threading layer:    {info['numba_threading_layer']}")
    print(f"controllers:              {', '.join(info['controllers']) or 'none'}")
    print(f"sources:                  {', '.join(info['sources']) or 'none'}")
    print(f"simulator scenarios:      {', '.join(info['scenarios'])}")
    return 0


def _info_file(args) -> int:
    from necviz.drivers.recordings import describe
    from necviz.outputs import check_output, write_json

    if args.json:
        check_output(args.json, "--json", inputs=[args.file], force=args.force)

    def progress(events, frames, seconds):
        print(f"\r  reading: {events:,} events, {frames} frames, {seconds:.1f} s", end="", file=sys.stderr, flush=True)

    live = sys.stderr.isatty()
    info = describe(
        args.file, progress=progress if live else None, exposure_us=args.exposure_us, pipe_timeout_s=args.pipe_timeout
    )
    if live:
        print("\r" + " " * 72 + "\r", end="", file=sys.stderr, flush=True)
    if args.json:
        write_json(args.json, info.to_dict(), flag="--json")
    print(info.to_text())
    return 0


def _cmd_demo(args) -> int:
    from necviz.commands.demo import run
    from necviz.dashboard.viewer_flags import viewer_options
    from necviz.options import DemoOptions

    run(
        DemoOptions(
            scene_options(args),
            args.controllers,
            record=args.record,
            force=args.force,
            profile=args.profile,
            show=_show(args),
            tune=_tune(args),
            clips=_clips(args),
            video=_video(args),
        ),
        viewer_options(args),
    )
    return 0


def _cmd_replay(args) -> int:
    from necviz.commands.replay import run
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
            show=_show(args),
            video=_video(args),
            pipe_timeout_s=args.pipe_timeout,
        ),
        viewer_options(args),
    )
    return 0


def _usb_transfers(text):
    """``--usb-transfers N,BYTES``: checked, or a one-line argparse error."""
    from necviz.core.errors import ParameterError
    from necviz.drivers.davis.transfers import parse_transfers

    try:
        return parse_transfers(text)
    except ParameterError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _cmd_live(args) -> int:
    from necviz.commands.live import run
    from necviz.dashboard.viewer_flags import viewer_options
    from necviz.options import LiveOptions

    run(
        LiveOptions(
            args.device,
            serial=args.serial,
            reconnect=args.reconnect,
            controller=args.controller,
            duration_s=args.duration,
            scene=scene_options(args, scene_duration=False),
            emulate_unplug_s=args.emulate_unplug,
            usb=args.usb,
            usb_transfers=args.usb_transfers,
            record=args.record,
            force=args.force,
            profile=args.profile,
            show=_show(args),
            tune=_tune(args),
            clips=_clips(args),
            json=args.json,
        ),
        viewer_options(args),
    )
    return 0


def _cmd_compare(args) -> int:
    from necviz.commands.compare import run
    from necviz.options import CompareOptions, parse_params

    sim = {f"{model}.{k}": v for model, kv in parse_params(args.sim, "--sim").items() for k, v in kv.items()}
    run(
        CompareOptions(
            scene_options(args),
            args.controllers,
            seeds=args.seeds,
            sift=not args.no_sift,
            json=args.json,
            save=args.save,
            force=args.force,
            profile=args.profile,
            controller_params=parse_params(args.param),
            sim=sim,
            markers=args.markers,
        )
    )
    return 0


def _cmd_devices(args) -> int:
    from necviz.commands.devices import check, run

    if args.check:
        return check(args.device, args.serial, args.capture, args.seconds)
    if args.capture is not None or args.seconds is not None:
        from necviz.core.errors import ParameterError

        raise ParameterError("--capture and --seconds go with --check")
    return run(include_emulated=not args.no_emulated)


def _bench_json(args):
    if args.json:
        from necviz.outputs import check_output

        check_output(args.json, "--json", force=args.force)
    return args.json


def _cmd_bench_decode(args) -> int:
    from necviz.bench.decode_speed import run

    run(seconds=args.seconds, repeats=args.repeats, seed=args.seed, json_path=_bench_json(args))
    return 0


def _cmd_bench_pipeline(args) -> int:
    from necviz.dashboard.pipeline_speed import run

    run(
        duration_s=args.duration,
        rate_mev_s=args.rate,
        fps=args.fps,
        batch_us=args.batch_us,
        seed=args.seed,
        repeats=args.repeats,
        json_path=_bench_json(args),
    )
    return 0


def _cmd_bench_estimators(args) -> int:
    from necviz.bench.estimator_speed import EstimatorBenchOptions, run

    options = EstimatorBenchOptions(
        events=args.events,
        duration_s=args.duration,
        fps=args.fps,
        exposure_us=args.exposure_us,
        repeats=args.repeats,
        edi_samples=args.edi_samples,
        seed=args.seed,
    )
    run(options, json_path=_bench_json(args))
    return 0


def _cmd_bench_sim(args) -> int:
    from necviz.bench.sim_speed import run

    run(
        duration_s=args.duration or 5.0,
        cameras=args.cameras,
        scene=scene_options(args),
        json_path=_bench_json(args),
        repeats=args.repeats,
    )
    return 0


# -- the parser ---------------------------------------------------------------------------------
class Parser(argparse.ArgumentParser):
    """argparse with necviz's one-line errors: ``necviz: error: argument --x: ...`` (no usage block;
    ``necviz COMMAND --help`` shows it), exit code 2. Subcommand parsers are of this class too."""

    def error(self, message: str):
        message = " ".join(str(message).split())
        head, sep, rest = message.partition(": ")
        if sep and head.startswith("argument ") and rest.startswith(head.removeprefix("argument ").split("/")[0]):
            message = rest  # "argument --x: --x = 0 is out of range" -> "--x = 0 is out of range"
        hint = f" (see: {self.prog} --help)" if self.prog != "necviz" else " (see: necviz --help)"
        self.exit(EXIT_USER, f"necviz: error: {message}{hint}\n")


def build_parser() -> argparse.ArgumentParser:
    from necviz.flags import number

    p = Parser(prog="necviz", description="Neuromorphic exposure control: estimators, controllers, dashboard.")
    p.add_argument("--version", action="version", version=f"necviz {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    controllers = _controllers()
    from necviz.names import COMPARE_CONTROLLERS, DEFAULT_CONTROLLERS

    info = sub.add_parser("info", help="versions and capabilities; with FILE, what a recording holds")
    info.add_argument("file", nargs="?", metavar="FILE", help="a recording (any supported format)")
    info.add_argument(
        "--exposure-us",
        type=number("--exposure-us"),
        default=None,
        help="exposure for formats that do not store it (AEDAT 2.0, text, HDF5, bags)",
    )
    info.add_argument("--json", metavar="OUT", help="with FILE: also write the summary as JSON")
    info.add_argument(
        "--pipe-timeout",
        type=number("--pipe-timeout"),
        default=None,
        metavar="S",
        help="accept FILE as a named pipe: copy what it delivers, waiting at most S seconds for data",
    )
    info.add_argument("--force", action="store_true", help="replace an existing --json file")
    info.set_defaults(func=_cmd_info)

    cmp_ = sub.add_parser("compare", help="NEC versus the baselines in closed loop on one simulated scene")
    add_scene_args(cmp_)
    cmp_.add_argument(
        "--controllers",
        type=_controller_list,
        default=",".join(COMPARE_CONTROLLERS),
        help=f"comma-separated, from {', '.join(controllers)} (default: {', '.join(COMPARE_CONTROLLERS)})",
    )
    cmp_.add_argument("--seeds", type=number("--seeds"), default=1, help="repeat over this many seeds: mean ± 95 %% CI")
    cmp_.add_argument("--json", metavar="FILE", help="write the results as JSON")
    cmp_.add_argument("--save", metavar="FILE.rrd", help="write a Rerun recording (the demo's schema and layout)")
    cmp_.add_argument("--no-sift", action="store_true", help="skip the SIFT inlier metric (the slowest part)")
    cmp_.add_argument(
        "--markers",
        action="store_true",
        help="detect the scene's fiducial markers on every frame: detection rate, latency after each "
        "lighting change, corner error (about 2 ms a frame)",
    )
    cmp_.add_argument("--profile", metavar="FILE.json", help="camera profile (CRF, TEDI thresholds and compensation)")
    cmp_.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME.KEY=VALUE",
        help="a controller parameter (repeatable), e.g. --param nec.goal=110 --param navid.target_msv=3",
    )
    cmp_.add_argument(
        "--sim",
        action="append",
        default=[],
        metavar="MODEL.KEY=VALUE",
        help="a simulator model parameter (repeatable), e.g. --sim dvs.max_event_rate=1e9",
    )
    cmp_.add_argument("--force", action="store_true", help="replace existing output files")
    cmp_.set_defaults(func=_cmd_compare)

    demo = sub.add_parser(
        "demo",
        help="the dashboard on the simulator: tunnel_exit, NEC versus the baselines side by side",
        description="A simulated scene (tunnel_exit by default), every controller driving its own "
        "camera, shown in the compare layout. No hardware or files needed.",
    )
    add_scene_args(demo)
    demo.add_argument(
        "--controllers",
        type=_controller_list,
        default=",".join(DEFAULT_CONTROLLERS),
        help=f"comma-separated, from {', '.join(controllers)} (default: {', '.join(DEFAULT_CONTROLLERS)})",
    )
    demo.add_argument(
        "--record",
        metavar="FILE.necrec",
        help="also record the first controller's camera (events, frames, commands) to a crash-safe native file",
    )
    add_show_args(demo)
    add_clip_args(demo)
    add_video_args(demo)
    demo.set_defaults(func=_cmd_demo)

    rep = sub.add_parser(
        "replay",
        help="a recording in open loop: frames, events, P-TEDI vs frames, what NEC would do",
        description="Replays FILE (necviz, AEDAT 4/3.1/2.0, ROS bag, RPG text, HDF5) through P-TEDI "
        "and a controller in open loop, in the inspect layout, and reports the per-frame "
        "prediction error and saturated frames.",
    )
    rep.add_argument("file", metavar="FILE", help="the recording")
    rep.add_argument(
        "--start", type=number("--start"), default=None, metavar="S", help="start S seconds into the recording"
    )
    rep.add_argument("--end", type=number("--end"), default=None, metavar="S", help="stop S seconds into the recording")
    rep.add_argument(
        "--exposure-us",
        type=number("--exposure-us"),
        default=None,
        help="exposure for formats that do not store it (AEDAT 2.0 estimates it from frame timing)",
    )
    rep.add_argument("--format", default=None, choices=FORMATS, help="skip detection")
    rep.add_argument("--controller", default="nec", choices=controllers, help="shown in open loop (default nec)")
    rep.add_argument("--json", metavar="OUT", help="write the summary (per-frame detail included) as JSON")
    rep.add_argument(
        "--pipe-timeout",
        type=number("--pipe-timeout"),
        default=None,
        metavar="S",
        help="accept FILE as a named pipe: copy what it delivers, waiting at most S seconds for data",
    )
    add_show_args(rep, tuning=False)
    add_video_args(rep)
    rep.set_defaults(func=_cmd_replay)

    live = sub.add_parser(
        "live",
        help="a DAVIS camera (USB or emulated) with NEC closing the loop",
        description="Runs a controller (NEC by default) in closed loop on a DAVIS346/DAVIS240 over "
        "USB (necviz's driver, or iniVation's dv-processing with --device dv), or on a virtual DAVIS346 "
        "(--device emulated), in the live layout.",
    )
    live.add_argument(
        "--device",
        choices=("usb", "dv", "emulated"),
        default="usb",
        help="usb (a real camera, necviz's driver), dv (the same camera through iniVation's dv-processing: "
        "pip install 'necviz[dv]') or emulated (necviz's driver on a virtual DAVIS346)",
    )
    live.add_argument("--serial", default=None, help="which camera when several are attached")
    live.add_argument("--reconnect", action="store_true", help="if the camera is unplugged, wait for it to return")
    live.add_argument(
        "--usb",
        choices=("auto", "libusb1", "pyusb"),
        default="auto",
        help="how necviz's driver reads the camera: libusb1 (asynchronous transfers in flight, as libcaer: pip "
        "install 'necviz[usb]'), pyusb (reads on a thread of their own) or auto (default: libusb1 if installed)",
    )
    live.add_argument(
        "--usb-transfers",
        type=_usb_transfers,
        default=None,
        metavar="N,BYTES",
        help="transfers in flight and bytes each, whole 1024-byte packets (default 32,8192: libcaer's 8 KiB transfers, more of them in flight; e.g. 8,8k as libcaer)",
    )
    live.add_argument(
        "--controller", default="nec", choices=controllers, help="the controller that drives the camera (default nec)"
    )
    live.add_argument(
        "--duration",
        type=number("--duration", "live"),
        default=None,
        metavar="S",
        help="stop after S seconds of sensor time (emulated: the scene's length)",
    )
    live.add_argument(
        "--emulate-unplug",
        type=number("--emulate-unplug"),
        default=None,
        metavar="S",
        help="emulated device: unplug it after S seconds (shows what an unplug does)",
    )
    live.add_argument(
        "--record", metavar="FILE.necrec", help="record events, frames and commands to a crash-safe native file"
    )
    live.add_argument(
        "--json",
        metavar="FILE",
        help="write the summary per lane as JSON (frames, saturated frames, events, commands, processing latency, "
        "frames late and command-to-exposure time in sensor time)",
    )
    add_scene_args(live, emulated=True)
    add_show_args(live)
    add_clip_args(live)
    live.set_defaults(func=_cmd_live)

    dev = sub.add_parser(
        "devices",
        help="attached (and emulated) DAVIS cameras: serial, firmware, logic version; --check: what one sends",
        description="Lists the DAVIS cameras found through necviz's driver and through dv-processing, and the "
        "emulated one. --check records a camera's raw stream for a few seconds and says what it held "
        "(events, frames, exposure echoes, the first frame's words, transfer timing) with a verdict.",
    )
    dev.add_argument("--no-emulated", action="store_true", help="list real cameras only")
    dev.add_argument("--check", action="store_true", help="record and judge one camera's stream")
    dev.add_argument(
        "--device",
        choices=("usb", "emulated"),
        default="usb",
        help="with --check: usb (default, a real camera) or emulated",
    )
    dev.add_argument("--serial", default=None, help="with --check: which camera when several are attached")
    dev.add_argument(
        "--capture", metavar="FILE", default=None, help="with --check: keep the raw stream in FILE (a new file)"
    )
    dev.add_argument(
        "--seconds",
        type=number("--seconds", "devices"),
        default=None,
        metavar="S",
        help="with --check: how long to record (default 2)",
    )
    dev.set_defaults(func=_cmd_devices)

    _add_bench(sub)
    _add_optional(sub)
    return p


def _add_bench(sub) -> None:
    from necviz.flags import number

    def B(flag):
        return number(flag, "bench")

    bench = sub.add_parser("bench", help="speed benchmarks (print a table, optionally write JSON)")
    bsub = bench.add_subparsers(dest="bench", metavar="BENCH", required=True)

    def common(b):
        b.add_argument("--json", metavar="FILE", help="write the results as JSON")
        b.add_argument("--force", action="store_true", help="replace an existing --json file")

    est = bsub.add_parser(
        "estimators", help="Table 1 of the paper: EDI, mEDI, Fast-EDI, TEDI, P-TEDI and a read-only floor"
    )
    common(est)
    est.add_argument(
        "--events", type=B("--events"), default=10_000_000, help="events in the synthetic 346x260 stream (default 10M)"
    )
    est.add_argument("--duration", type=B("--duration"), default=2.0, help="stream length in seconds (default 2.0)")
    est.add_argument("--fps", type=B("--fps"), default=50.0, help="APS frame rate, 25-100 (default 50)")
    est.add_argument("--exposure-us", type=B("--exposure-us"), default=5_000, help="APS exposure (default 5000 µs)")
    est.add_argument(
        "--repeats", type=B("--repeats"), default=3, help="timed runs per method after a warm-up (default 3)"
    )
    est.add_argument(
        "--edi-samples", type=B("--edi-samples"), default=64, help="samples per exposure for EDI and mEDI (default 64)"
    )
    est.add_argument("--seed", type=number("--seed"), default=0)
    est.set_defaults(func=_cmd_bench_estimators)
    sim = bsub.add_parser("sim", help="closed-loop simulator speed: a scenario with several cameras")
    common(sim)
    add_scene_args(sim)
    sim.add_argument("--cameras", type=B("--cameras"), default=6, help="cameras sharing the scene (default 6)")
    sim.add_argument(
        "--repeats",
        type=B("--repeats"),
        default=3,
        help="timed runs (and replays from a scene cache); the median is reported",
    )
    sim.set_defaults(func=_cmd_bench_sim)
    dec = bsub.add_parser("decode", help="DAVIS stream decoder throughput on a 12 Mev/s-style stream")
    common(dec)
    dec.add_argument("--seconds", type=B("--seconds"), default=1.0, help="stream length in seconds (default 1)")
    dec.add_argument("--repeats", type=B("--repeats"), default=5, help="timed runs (default 5)")
    dec.add_argument("--seed", type=number("--seed"), default=0)
    dec.set_defaults(func=_cmd_bench_decode)
    pipe = bsub.add_parser(
        "pipeline", help="the whole dashboard path at 12 Mev/s: real-time factor and control latency"
    )
    common(pipe)
    pipe.add_argument("--duration", type=B("--duration"), default=10.0, help="stream length in seconds (default 10)")
    pipe.add_argument("--rate", type=B("--rate"), default=12.0, help="event rate in Mev/s (default 12)")
    pipe.add_argument("--fps", type=B("--fps"), default=50.0, help="frame rate (default 50)")
    pipe.add_argument("--batch-us", type=B("--batch-us"), default=1_000, help="event batch period (default 1000 µs)")
    pipe.add_argument(
        "--repeats", type=B("--repeats"), default=3, help="runs per configuration; the median is reported"
    )
    pipe.add_argument("--seed", type=number("--seed"), default=0)
    pipe.set_defaults(func=_cmd_bench_pipeline)


def _add_optional(sub) -> None:
    """Commands that live in their own modules and bring their own parsers."""
    import importlib

    for module in (
        "necviz.commands.calibrate",
        "necviz.commands.export",
        "necviz.commands.repair",
        "necviz.commands.sweep",
    ):
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as e:
            if e.name != module and not module.startswith(str(e.name)):
                raise
            continue
        mod.add_parser(sub)


# -- running ------------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    code = _main(argv)
    if argv is None:  # the necviz program itself (a test passes its argv and keeps running)
        _leave_if_wedged(code)
    return code


def _leave_if_wedged(code: int) -> None:
    """A Rerun stream whose file writer failed cannot be flushed or dropped without blocking for ever
    (:data:`necviz.dashboard.viewer.WEDGED`): after the error line, leave at once."""
    viewer = sys.modules.get("necviz.dashboard.viewer")
    if viewer is not None and viewer.WEDGED:
        import os

        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def _main(argv: list[str] | None = None) -> int:
    for stream in (sys.stdout, sys.stderr):  # file names that are not UTF-8 print as the user typed them
        try:
            stream.reconfigure(errors="surrogateescape")
        except (AttributeError, ValueError, OSError):
            pass
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # a bad flag (one line printed), --help or --version: an exit code, not an exception
        return e.code if isinstance(e.code, int) else (0 if e.code is None else EXIT_USER)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    from necviz.core.errors import NecvizError

    _terminate_as_interrupt()
    try:
        return int(args.func(args) or 0)
    except NecvizError as e:
        print(f"necviz: error: {_one_line(e)}", file=sys.stderr)
        return EXIT_USER
    except KeyboardInterrupt:
        print("necviz: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into `head` and the like: not an error
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as e:  # a file or device the user named: missing, unreadable, full disk
        if e.filename is None and not isinstance(e, (FileNotFoundError, PermissionError)):
            return _bug(e, argv)
        print(f"necviz: error: {e.strerror or e}{f': {e.filename}' if e.filename else ''}", file=sys.stderr)
        return EXIT_USER
    except (SystemExit, GeneratorExit):
        raise
    except BaseException as e:  # noqa: BLE001 - the last resort (a Rust panic derives from BaseException)
        return _bug(e, argv)


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


def _bug(e: BaseException, argv) -> int:
    """An exception necviz did not expect: one line for the user, the traceback in a file for the report."""
    import tempfile
    import time
    import traceback

    text = "".join(traceback.format_exception(e))
    try:
        fd, path = tempfile.mkstemp(prefix=f"necviz-bug-{time.strftime('%Y%m%d-%H%M%S')}-", suffix=".txt")
        with open(fd, "w", encoding="utf-8", errors="backslashreplace") as f:
            f.write(f"necviz {__version__}\ncommand: necviz {' '.join(argv if argv is not None else sys.argv[1:])}\n\n")
            f.write(text)
        where = f"; details in {path}"
    except OSError:
        where = ""
    print(
        f"necviz: internal error: {type(e).__name__}: {_one_line(e)} — this is a bug in necviz, please report it "
        f"with the command you ran{where}",
        file=sys.stderr,
    )
    return EXIT_BUG


def _terminate_as_interrupt() -> None:
    """SIGTERM stops a run like Ctrl-C does, so recordings are flushed (an .rrd killed mid-write has no footer)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return

    def handler(signum, frame):
        raise KeyboardInterrupt

    try:
        signal.signal(signal.SIGTERM, handler)
    except (ValueError, OSError):  # pragma: no cover - not in the main thread of the main interpreter
        pass


if __name__ == "__main__":
    sys.exit(main())
