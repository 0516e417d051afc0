"""``necviz replay FILE``: a recording in open loop, in the ``inspect`` layout.

The file's packets go through P-TEDI and a controller (NEC by default) exactly as live, but the
commands only show what the controller *would* have done: the recorded exposures are what they
are. For every frame the replay reports what the frame measured (ln Pbar), what P-TEDI predicted
for that exposure from the events before it (``ln P(s) + ln E_p(s)``, the prediction at the
exposure start carried across the exposure by its events) and their difference, and flags
frames more than 50 % saturated.

``--json FILE`` writes ``{"frames", "events", "duration_s", "saturated_frames_50",
"prediction_error_rmse", "frames_detail": [...]}``.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

from .core.control import CONTROLLERS, CameraLimits, make_controller
from .core.errors import ParameterError
from .dashboard import check_run_args, run_dashboard, write_json
from .pipeline import Lane, packet_time_us

LANE = "camera"


def _first_time_us(path, open_kwargs) -> int | None:
    """The first packet time of a recording (opens it briefly; streams are lazy)."""
    from .drivers.replay import open_recording

    rec = open_recording(path, **open_kwargs)
    try:
        for packet in rec:
            t = packet_time_us(packet)
            if t is not None:
                return t
        return None
    finally:
        rec.close()


def open_for_replay(path, exposure_us=None, start_s=None, end_s=None, fmt=None):
    """Open ``path`` restricted to ``[start_s, end_s]`` seconds from its first timestamp.

    Returns ``(recording, origin_us)``.
    """
    from .drivers.replay import open_recording

    for label, v in (("--start", start_s), ("--end", end_s)):
        if v is not None and not (math.isfinite(v) and v >= 0):
            raise ParameterError(f"{label} must be a time in seconds >= 0, got {v}")
    if start_s is not None and end_s is not None and end_s <= start_s:
        raise ParameterError(f"--end ({end_s} s) must come after --start ({start_s} s)")
    kw = {"exposure_us": exposure_us, "format": fmt}
    origin = _first_time_us(path, kw)
    if origin is None:
        raise ParameterError(f"{path}: the recording holds no events or frames")
    start_us = None if start_s is None else origin + int(round(start_s * 1e6))
    end_us = None if end_s is None else origin + int(round(end_s * 1e6))
    return open_recording(path, start_us=start_us, end_us=end_us, **kw), origin


def summarise(stats: dict, lane: Lane) -> dict:
    errors = [d["prediction_error"] for d in lane.frames_detail if d["prediction_error"] is not None]
    rmse = math.sqrt(sum(e * e for e in errors) / len(errors)) if errors else None
    return {"frames": lane.frames, "events": stats["events"], "duration_s": stats["duration_s"],
            "saturated_frames_50": lane.saturated_frames, "prediction_error_rmse": rmse,
            "prediction_error_frames": len(errors), "frames_detail": lane.frames_detail}


def run(args, out=...) -> dict:
    out = sys.stdout if out is ... else out
    check_run_args(args)  # before anything is opened or truncated
    path = Path(args.file)
    if args.controller not in CONTROLLERS:
        raise ParameterError(f"unknown controller {args.controller!r}; available: {', '.join(sorted(CONTROLLERS))}")
    if args.exposure_us is not None and not (math.isfinite(args.exposure_us) and args.exposure_us > 0):
        raise ParameterError(f"--exposure-us must be a positive number of µs, got {args.exposure_us}")
    recording, origin = open_for_replay(path, args.exposure_us, args.start, args.end, args.format)
    sensor = recording.sensor
    limits = CameraLimits()
    ctrl = make_controller(args.controller, sensor=sensor, limits=limits)
    lane = Lane.build(LANE, ctrl, sensor, drives=False)
    props = {"command": "replay", "file": str(path), "format": recording.format,
             "exposure_source": recording.exposure_source, "controller": args.controller,
             "camera_limits": limits, "camera_profile": "default DAVIS346 response",
             **{f"recorded.{k}": v for k, v in getattr(recording, "properties", {}).items()}}
    print(f"  replay: {path} ({recording.format}, {sensor.width}x{sensor.height}, exposure "
          f"{recording.exposure_source}); {args.controller} in open loop", file=out)
    stats = run_dashboard(args, "replay", recording, [lane], "inspect", props, f"necviz replay: {path.name}", sensor,
                          sink_options={"origin_us": origin, "lossless_when_unpaced": True}, out=out)
    summary = summarise(stats, lane)
    if not summary["events"] and not summary["frames"] and (args.start is not None or args.end is not None):
        raise ParameterError(f"nothing in the selected range (--start {args.start} --end {args.end} s): it lies "
                             f"past the end of {path.name}; `necviz info {path}` shows its duration")
    for w in getattr(recording, "warnings", []):
        print(f"  warning: {w}", file=out)
    rmse = summary["prediction_error_rmse"]
    print(f"  prediction error (P-TEDI vs frame, ln): RMSE {rmse:.3f} over {summary['prediction_error_frames']} frames"
          if rmse is not None else "  prediction error: no frame pair to compare (need two usable frames)", file=out)
    sat = [d["sequence"] for d in lane.frames_detail if d["saturated"]]
    if sat:
        shown = ", ".join(map(str, sat[:12])) + (" …" if len(sat) > 12 else "")
        print(f"  saturated frames (>50 %): {len(sat)}: {shown}", file=out)
    if args.json:
        write_json(args.json, summary)
        print(f"  wrote {args.json}", file=out)
    return summary
