"""What ``demo``, ``replay`` and ``live`` share: open the viewer, run the pipeline, show progress.

:func:`run_dashboard` opens the Rerun recording the viewer flags ask for (with the command's
layout), logs run properties and series styles, starts the streaming thread with a
:class:`~necviz.sink.RerunSink`, optionally a tuning prompt / watched file, prints a live
count until the source ends or Ctrl-C, then flushes everything and prints a summary.
"""

from __future__ import annotations

import json
import math
import sys
import time

import rerun as rr

from .core.errors import ParameterError
from .layouts import LAYOUTS, make_blueprint, style_series
from .pipeline import Pipeline
from .sink import RerunSink
from .tuning import HELP, TuningConsole, TuningFile
from .viewer import open_viewer


def parse_speed(text: str | None) -> float | None:
    """``max`` (as fast as possible) -> None; ``1`` / ``x1`` real time; ``x4`` or ``4`` four times."""
    if text is None or str(text).lower() in ("max", "fast", "0"):
        return None
    s = str(text).lower().removeprefix("x")
    try:
        v = float(s)
    except ValueError:
        raise ParameterError(f"--speed must be 'max', a factor like 1 or x4, got {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise ParameterError(f"--speed must be positive, got {text!r}")
    return v


def check_run_args(args) -> None:
    """Check every run flag before anything is opened (camera, recorder, viewer), so a typo never
    truncates a recording or leaves a camera running. One-line :class:`ParameterError` s."""
    from pathlib import Path

    from .viewer import check_save_path

    speed = getattr(args, "speed", None)
    if speed is not None:
        v = parse_speed(speed)
        if v is not None and not 1e-3 <= v <= 1e4:
            raise ParameterError(f"--speed must lie between x0.001 and x10000, got {speed!r}")
    window_ms = getattr(args, "event_window_ms", 33.3)
    if not (0.1 <= window_ms <= 10_000):
        raise ParameterError(f"--event-window-ms must lie in 0.1..10000, got {window_ms}")
    if getattr(args, "event_points", 0) < 0:
        raise ParameterError(f"--event-points must be >= 0, got {args.event_points}")
    tune = getattr(args, "tune_file", None)
    if tune and not Path(tune).is_file():
        raise ParameterError(f"--tune-file: {tune!r} is not a file")
    if getattr(args, "save", None) is not None:
        check_save_path(args.save)
    for flag in ("json", "record"):
        out_path = getattr(args, flag, None)
        if out_path:
            check_output_path(out_path, f"--{flag}")


def check_output_path(path, flag: str) -> None:
    """An output file we are about to write: its folder exists and it is not a folder itself."""
    from pathlib import Path

    p = Path(path)
    if p.is_dir():
        raise ParameterError(f"{flag}: {str(p)!r} is a folder, not a file")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise ParameterError(f"{flag}: folder {str(parent)!r} does not exist")


def add_run_args(parser, layouts=tuple(LAYOUTS), tuning: bool = True) -> None:
    from .viewer import add_viewer_args

    add_viewer_args(parser, layouts)
    g = parser.add_argument_group("run")
    g.add_argument("--speed", default=None,
                   help="'max' (as fast as possible), 1 (real time) or xN; default: real time when a viewer "
                        "watches, max when only saving")
    g.add_argument("--event-window-ms", type=float, default=33.3, help="event image window (default 33.3 ms)")
    g.add_argument("--event-points", type=int, default=0, metavar="N",
                   help="also log up to N raw events per window as points (default 0: images only)")
    if tuning:
        g.add_argument("--tune-file", metavar="FILE", help="watch FILE for 'key = value' changes while running")
        g.add_argument("--no-prompt", action="store_true", help="do not read tuning commands from the terminal")


def run_dashboard(args, command: str, source, lanes, layout: str, properties: dict, title: str, sensor,
                  event_lanes=None, recorder=None, record_lane=None, controller_factory=None,
                  expected_duration_s: float | None = None, sink_options: dict | None = None, out=...,
                  stdin=None, stop_after_s: float | None = None) -> dict:
    """Run ``lanes`` over ``source`` into the viewer; returns the pipeline statistics."""
    out = sys.stdout if out is ... else out
    try:
        return _run_dashboard(args, command, source, lanes, layout, properties, title, sensor, event_lanes,
                              recorder, record_lane, controller_factory, expected_duration_s, sink_options, out,
                              stdin, stop_after_s)
    except BaseException:
        if recorder is not None:  # a failure before the pipeline took it over: keep what it holds readable
            recorder.close()
        if hasattr(source, "close"):
            source.close()
        raise


def _run_dashboard(args, command, source, lanes, layout, properties, title, sensor, event_lanes, recorder,
                   record_lane, controller_factory, expected_duration_s, sink_options, out, stdin,
                   stop_after_s) -> dict:
    check_run_args(args)  # the commands check first (before opening anything); callers of the API get it here
    layout = getattr(args, "layout", None) or layout
    names = [lane.name for lane in lanes]
    blueprint = make_blueprint(layout, names, sensor.width, sensor.height)
    window_ms = getattr(args, "event_window_ms", 33.3)
    points = getattr(args, "event_points", 0)
    viewer = open_viewer(args, command, blueprint, title)
    for m in viewer.messages:
        print(f"  {m}", file=out)
    watched = bool(getattr(args, "spawn", False) or getattr(args, "serve", False) or getattr(args, "connect", None))
    speed_arg = getattr(args, "speed", None)
    speed = parse_speed(speed_arg) if speed_arg is not None else (1.0 if watched or viewer.save_path is None else None)
    rec = viewer.rec
    rec.send_property("run", rr.AnyValues(**{k: str(v) for k, v in properties.items()}, layout=layout))
    style_series(rec, names)
    sink_options = dict(sink_options or {})
    if sink_options.pop("lossless_when_unpaced", False):
        sink_options["lossless"] = speed is None and not watched  # offline into a file: keep everything
    sink = RerunSink(rec, names, sensor.height, sensor.width, event_lanes=event_lanes,
                     event_window_us=int(window_ms * 1000), raw_points=points, **sink_options)
    pipe = Pipeline(source, lanes, sink, recorder, record_lane=record_lane, speed=speed, stop_after_s=stop_after_s)
    pipe.controller_factory = controller_factory
    tune_file = None
    try:
        if getattr(args, "tune_file", None):
            tune_file = TuningFile(pipe, args.tune_file, out=out)
        stream = stdin if stdin is not None else sys.stdin
        prompt = (hasattr(args, "no_prompt") and not args.no_prompt and stream is not None
                  and (stdin is not None or (hasattr(stream, "isatty") and stream.isatty())))
        pipe.start()
        if tune_file is not None:
            tune_file.start()
        if prompt:
            TuningConsole(pipe, stream, out=out).start()
            print(f"  tuning: type commands and Enter ({HELP})", file=out)
        t0 = time.perf_counter()
        try:
            while not pipe.wait(0.5):
                _progress(out, command, pipe, expected_duration_s, time.perf_counter() - t0)
        except KeyboardInterrupt:
            print("\n  stopping (Ctrl-C): flushing the recording…", file=out, flush=True)
            pipe.stop()
        _progress(out, command, pipe, expected_duration_s, time.perf_counter() - t0)
        print(file=out)
    finally:
        if tune_file is not None:
            tune_file.stop()
        try:
            stats = pipe.finish()
        except BaseException:
            if viewer.save_path is not None:  # the error ends the run; what was seen is flushed and readable
                print(f"  recording so far: {viewer.save_path} (open it with: rerun {viewer.save_path})", file=out)
            raise
        finally:
            viewer.close()
    _summary(out, stats)
    if viewer.save_path is not None:
        print(f"  recording: {viewer.save_path} (open it with: rerun {viewer.save_path})", file=out)
    stats["rrd"] = str(viewer.save_path) if viewer.save_path is not None else None
    if viewer.url is not None and getattr(args, "serve", False):
        _keep_serving(viewer, out)
    return stats


def _keep_serving(viewer, out) -> None:
    """The run is over but the web viewer is still being watched: serve until Ctrl-C (or SIGTERM)."""
    print(f"  still serving the recording at {viewer.url}; press Ctrl-C to stop", file=out, flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        print("  stopped serving", file=out)


def _progress(out, command, pipe, expected, wall) -> None:
    if out is None:
        return
    t = ((pipe.now_us or 0) - (pipe.first_us or 0)) / 1e6
    of = f"/{expected:g}" if expected else ""
    print(f"\r  {command}: {t:6.2f}{of} s sensor time · {pipe.events / 1e6:7.2f} M events · {pipe.frames} frames"
          f" · {wall:5.1f} s", end="", file=out, flush=True)


def _summary(out, stats: dict) -> None:
    if out is None:
        return
    print(f"  {stats['events']:,} events, {stats['frames']} frames over {stats['duration_s']:.2f} s "
          f"({stats['event_rate_mev_s']:.2f} Mev/s) in {stats['wall_s']:.1f} s wall", file=out)
    for name, s in stats["lanes"].items():
        print(f"  {name:8s} {s['frames']:4d} frames, {s['saturated_frames_50']:3d} saturated, {s['commands']:5d} "
              f"commands, latency p50 {_us(s['latency_p50_us'])} p99 {_us(s['latency_p99_us'])}", file=out)
    sk = stats.get("sink")
    if sk:
        print(f"  viewer: {sk['frames_logged']} frames, {sk['event_images']} event images; dropped "
              f"{sk['frames_dropped']} frames and {sk['event_batches_dropped']} event batches; "
              f"{sk['events_decimated']:,} of {sk['events_seen']:,} events not drawn (decimation)", file=out)


def write_json(path, data: dict) -> None:
    with open(path, "w", encoding="utf-8") as f:
        json.dump(data, f, indent=2)


def _us(v: float) -> str:
    return "—" if v != v else f"{v:.0f} µs"
