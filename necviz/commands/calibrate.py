"""The ``necviz calibrate`` command: its argument parser, the argument parsing helpers and :func:`run`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

# light imports only: the parser is built for every command line (`necviz --help` must not load NumPy)
from necviz.calibration.settings import DEFAULT_LOSS, DEFAULT_SLOW_RATE, DEFAULTS
from necviz.commands import Command
from necviz.core.errors import ParameterError

if TYPE_CHECKING:
    from necviz.core.event_model import TediParams
    from necviz.core.sensor import SensorGeometry


def parse_seeds(text: str) -> list[int]:
    """``"3"`` -> [3]; ``"0..4"`` -> [0, 1, 2, 3, 4] (inclusive); ``"1,5,9"`` -> [1, 5, 9]."""
    s = str(text).strip()
    try:
        if ".." in s:
            a, b = s.split("..", 1)
            lo, hi = int(a), int(b)
            if hi < lo:
                raise ValueError
            out = list(range(lo, hi + 1))
        else:
            out = [int(v) for v in s.split(",") if v.strip() != ""]
    except ValueError:
        raise ParameterError(f"--seeds expects N, a..b or a,b,c (non-negative integers), got {text!r}") from None
    if not out or any(v < 0 for v in out) or len(out) > 1000:
        raise ParameterError(f"--seeds expects N, a..b or a,b,c (non-negative integers, at most 1000), got {text!r}")
    return out


def _parse_init(text: str, base: TediParams) -> TediParams:
    from necviz.core.event_model import TediParams

    parts = [p.strip() for p in str(text).split(",")]
    try:
        if len(parts) != 2:
            raise ValueError
        c_on, c_off = float(parts[0]), float(parts[1])
    except ValueError:
        raise ParameterError(
            f"--init expects c_on,c_off (two numbers in ln units, e.g. 0.26,0.24), got {text!r}"
        ) from None
    return TediParams(c_on, c_off, base.a_on, base.b_on, base.a_off, base.b_off)


def _parse_sensor(text: str) -> SensorGeometry:
    from necviz.core.sensor import DAVIS346, SensorGeometry

    if text.upper() == "DAVIS346":
        return DAVIS346
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ParameterError(f"--sensor expects WIDTHxHEIGHT (e.g. 346x260), got {text!r}") from None
    if not (8 <= w <= 2048 and 8 <= h <= 2048):
        raise ParameterError(f"--sensor {text}: width and height must lie in 8..2048")
    return SensorGeometry(w, h, f"{w}x{h}")


def add_arguments(p) -> None:
    from necviz.flags import number

    p.add_argument(
        "files", nargs="*", metavar="FILE", help="recordings (necviz, AEDAT 4/3.1/2.0, ROS bag, HDF5, RPG text)"
    )
    p.add_argument(
        "--sim",
        metavar="SCENARIO[,..]",
        default=None,
        help="calibrate on simulator runs instead: 'calibration' (the held-out calibration scene) and/or presets",
    )
    p.add_argument("--seeds", default="0", metavar="a..b", help="with --sim: seeds (N, a..b or a,b,c; default 0)")
    p.add_argument(
        "--duration",
        type=number("--duration", "calibrate"),
        default=None,
        metavar="S",
        help="with --sim: simulated seconds per run",
    )
    p.add_argument("--sensor", default="DAVIS346", metavar="WxH", help="with --sim: sensor size (default DAVIS346)")
    p.add_argument("--out", required=True, metavar="PROFILE.json", help="the camera profile to write")
    p.add_argument("--force", action="store_true", help="replace --out / --json if they exist")
    p.add_argument(
        "--json",
        metavar="REPORT.json",
        default=None,
        help="also write a report: fitted values, the thresholds' 95 %% bootstrap intervals, standard errors, "
        "residuals, per-pair statistics",
    )
    p.add_argument(
        "--profile",
        metavar="FILE",
        default=None,
        help="starting profile (response, limits, initial parameters; default: DAVIS346 defaults)",
    )
    p.add_argument(
        "--init",
        metavar="c_on,c_off",
        default=None,
        help="initial contrast thresholds in ln units (default: the starting profile's, 0.26,0.24)",
    )
    p.add_argument(
        "--fit",
        default="all",
        metavar="WHICH",
        help="parameters to fit: all (default), c (thresholds only) or names, e.g. c_on,c_off,a_on,b_on",
    )
    p.add_argument(
        "--crf",
        choices=("auto", "keep"),
        default="auto",
        help="auto: fit the response when the data hold exposure brackets of a static scene (default)",
    )
    p.add_argument(
        "--exposure-us", type=number("--exposure-us"), default=None, help="exposure for formats that do not store it"
    )
    p.add_argument(
        "--min-change",
        type=number("--min-change"),
        default=DEFAULTS["min_change"],
        metavar="LN",
        help=f"use pixels whose frame-measured change is at least this (ln units; default {DEFAULTS['min_change']})",
    )
    p.add_argument(
        "--min-pixels",
        type=number("--min-pixels"),
        default=DEFAULTS["min_pixels"],
        metavar="N",
        help=f"use a frame pair when at least N pixels qualify (default {DEFAULTS['min_pixels']})",
    )
    p.add_argument(
        "--max-pixels",
        type=number("--max-pixels"),
        default=DEFAULTS["max_pixels"],
        metavar="N",
        help=f"pixels per pair at most, an even subsample (default {DEFAULTS['max_pixels']})",
    )
    p.add_argument(
        "--max-pairs",
        type=number("--max-pairs"),
        default=DEFAULTS["max_pairs"],
        metavar="N",
        help=f"pairs kept at most, spread evenly over the data (default {DEFAULTS['max_pairs']})",
    )
    p.add_argument(
        "--max-lag",
        type=number("--max-lag"),
        default=DEFAULTS["max_lag"],
        metavar="K",
        help=f"pair a frame with up to K frames back when consecutive frames changed too little "
        f"(default {DEFAULTS['max_lag']}; 1 = consecutive frames only)",
    )
    p.add_argument(
        "--no-continuation",
        action="store_true",
        help="also use pixels whose change reverses the direction of their previous event "
        "(biases the thresholds up; for recordings with too few events)",
    )
    p.add_argument(
        "--max-event-rate",
        type=number("--max-event-rate"),
        default=None,
        metavar="MEV_S",
        help="the sensor's bus ceiling in Mev/s: pairs that reached 90 %% of it are left out of the "
        "threshold fit (default: 12 for DAVIS346/DAVIS240 recordings, the simulator's own with "
        "--sim; 0 = unknown)",
    )
    p.add_argument(
        "--slow-rate",
        type=number("--slow-rate"),
        default=DEFAULT_SLOW_RATE,
        metavar="EV_S",
        help=f"lower bound of the compensation knee b/a, events per pixel per second (default {DEFAULT_SLOW_RATE:g})",
    )
    p.add_argument(
        "--loss",
        choices=("linear", "soft_l1", "huber", "cauchy"),
        default=DEFAULT_LOSS,
        help=f"least-squares loss (default {DEFAULT_LOSS}: squared residuals)",
    )
    p.add_argument(
        "--bias-setting",
        default=None,
        metavar="N|all",
        help="fit DVS bias setting N of the data's bias timeline (a .necrec's recorded bias changes, or --dvs-at; "
        "0 = the biases the data start with), or each one (all: a profile per setting, OUT.settingN.json); frames "
        "never pair across a change",
    )
    p.add_argument(
        "--dvs-at",
        action="append",
        default=[],
        metavar="S:KEY=VALUE",
        help="with --sim: set a DVS control at S seconds of each run, as --dvs does (c_on, c_off, refractory_us, "
        "bandwidth_hz; repeatable)",
    )
    p.add_argument("--name", default=None, help="profile name (default: derived from the inputs)")


def run(args: argparse.Namespace) -> int:
    from necviz.calibration.fit import CalibrationOptions
    from necviz.calibration.from_recordings import calibrate_from_recordings
    from necviz.calibration.from_simulation import CalibrationSimulation, calibrate_from_simulation
    from necviz.calibration.pairs import CollectorOptions
    from necviz.core.camera_profile import CameraProfile
    from necviz.core.tedi import PairSelection
    from necviz.outputs import check_distinct, check_output, write_json
    from necviz.profiles import load_profile

    files = list(args.files or [])
    if files and args.sim:
        raise ParameterError("give recordings (FILE...) or --sim, not both")
    if not files and not args.sim:
        raise ParameterError("nothing to calibrate on: give recordings (FILE...) or --sim SCENARIO")
    from necviz.calibration.bias_settings import parse_change, parse_setting

    which = None if args.bias_setting is None else parse_setting(args.bias_setting)
    changes = tuple(parse_change(c) for c in args.dvs_at or ())
    if changes and not args.sim:
        raise ParameterError("--dvs-at schedules bias changes in simulator runs (--sim); a recording holds its own")
    inputs = files + ([args.profile] if args.profile else [])
    out = check_output(args.out, "--out", inputs=inputs, force=args.force, suffixes=(".json",))
    rep = None
    if args.json:
        rep = check_output(args.json, "--json", inputs=inputs, force=args.force, suffixes=(".json",))
        check_distinct({"--out": args.out, "--json": args.json})
    for f in files:
        if not Path(f).exists():
            raise ParameterError(f"{f}: no such file or directory")
    base = load_profile(args.profile) if args.profile else None
    init = _parse_init(args.init, (base or CameraProfile()).tedi) if args.init else None
    sim = None
    if files:
        name = args.name or f"calibrated from {', '.join(Path(f).name for f in files)}"[:120]
    else:
        sensor = _parse_sensor(args.sensor)
        scenarios = tuple(s.strip() for s in args.sim.split(",") if s.strip())
        sim = CalibrationSimulation(
            scenarios, tuple(parse_seeds(args.seeds)), args.duration, sensor=sensor, dvs_changes=changes
        )
        name = args.name or f"simulated {sensor.width}x{sensor.height} ({','.join(scenarios)}, seeds {args.seeds})"
        if base is not None and (base.sensor.width, base.sensor.height) != (sensor.width, sensor.height):
            base = CameraProfile(base.name, sensor, base.crf, base.tedi, base.limits)
    options = CalibrationOptions(
        profile=base,
        init=init,
        fit=args.fit,
        crf_mode=args.crf,
        name=name,
        max_event_rate="auto" if args.max_event_rate is None else (args.max_event_rate * 1e6 or None),
        slow_rate=args.slow_rate,
        loss=args.loss,
        selection=PairSelection(min_change=args.min_change, min_pixels=args.min_pixels, max_pixels=args.max_pixels),
        collection=CollectorOptions(
            max_pairs=args.max_pairs, max_lag=args.max_lag, continuation=not args.no_continuation
        ),
    )
    if which is None:
        for f in files:  # data across bias changes holds several thresholds: say so before one fit mixes them
            n = _bias_changes(f, args.exposure_us) if Path(f).is_file() else 0  # a pipe is read once, by the fit
            if n:
                print(
                    f"note: {Path(f).name} holds {n} DVS bias change(s), so more than one set of thresholds; this fit "
                    "mixes them (--bias-setting all fits each setting on its own)"
                )
    live = sys.stderr.isatty()

    def progress(text):
        if live:
            print("\r  " + text[:100].ljust(100), end="", file=sys.stderr, flush=True)

    try:
        if which is not None:
            if sim is None:
                fits = calibrate_from_recordings(
                    files, options, exposure_us=args.exposure_us, progress=progress, bias_setting=which
                )
            else:
                fits = calibrate_from_simulation(sim, options, progress=progress, bias_setting=which)
        elif sim is None:
            result = calibrate_from_recordings(files, options, exposure_us=args.exposure_us, progress=progress)
        else:
            result = calibrate_from_simulation(sim, options, progress=progress)
    finally:
        if live:
            print("\r" + " " * 104 + "\r", end="", file=sys.stderr, flush=True)
    if which is not None:
        return _write_settings(fits, which, out, rep, args, inputs)
    write_json(out, result.profile.to_dict(), indent=1)
    if rep is not None:
        write_json(rep, result.to_dict())
    print(result.summary())
    print(f"wrote {out}" + (f" and {rep}" if rep is not None else ""))
    return 0


def _bias_changes(path, exposure_us) -> int:
    """How many bias changes a recording's timeline holds (0 for formats that record none)."""
    from necviz.calibration.bias_settings import BiasTimeline
    from necviz.drivers.recordings import open_recording

    rec = open_recording(path, exposure_us=exposure_us)
    try:
        notes = rec.annotations
        return len(BiasTimeline.from_annotations(notes).changes) if notes else 0
    finally:
        rec.close()


def _describe_setting(index: int, settings: dict | None) -> str:
    if not settings:
        return f"bias setting {index} (the biases the data start with)"
    model = ", ".join(
        f"{k} {settings[k]:.4g}" for k in ("c_on", "c_off", "refractory_us") if settings.get(k) is not None
    )
    truth = settings.get("truth")
    true = f"; simulated c_on {truth['c_on']:.4g}, c_off {truth['c_off']:.4g}" if isinstance(truth, dict) else ""
    return f"bias setting {index} ({model}{true})"


def _write_settings(fits, which, out: Path, rep, args, inputs) -> int:
    """``--bias-setting``: one profile per setting fitted (``N``: ``--out``; ``all``: ``OUT.settingN.json``)."""
    from necviz.outputs import check_output, write_json

    written = []
    for f in fits:
        print(_describe_setting(f.index, f.settings) + ":")
        if f.result is None:
            print(f"  not fitted: {f.error}")
            continue
        print("  " + f.result.summary().replace("\n", "\n  "))
        path = out
        if which == "all":
            path = check_output(
                out.with_name(f"{out.stem}.setting{f.index}{out.suffix}"),
                "--out",
                inputs=inputs,
                force=args.force,
                suffixes=(".json",),
            )
        write_json(path, f.result.profile.to_dict(), indent=1)
        written.append(str(path))
    if rep is not None:
        write_json(rep, {"bias_settings": [f.to_dict() for f in fits]})
        written.append(str(rep))
    print(f"wrote {', '.join(written)}")
    return 0


COMMAND = Command(
    name="calibrate",
    help="fit a camera profile (TEDI c±, a±, b± by Eq. 7; response from brackets) from recordings or the simulator",
    description="Fits the six TEDI parameters by frame-to-frame consistency (Eq. 7) on recordings (any "
    "supported format) or simulator runs, and the camera response (Debevec-Malik) where the data hold "
    "exposure brackets of a static scene; writes a camera profile (JSON) for --profile.",
    add_arguments=add_arguments,
    run=run,
)
