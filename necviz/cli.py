"""The ``necviz`` command."""

from __future__ import annotations

import argparse
import sys

from . import __version__


def _cmd_info(args: argparse.Namespace) -> int:
    if args.file:
        return _info_file(args)
    import platform

    from .info import collect_info

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


def _info_file(args: argparse.Namespace) -> int:
    import json

    from .dashboard import check_output_path
    from .drivers.replay import describe

    if args.json:
        check_output_path(args.json, "--json")

    def progress(events, frames, seconds):
        print(f"\r  reading: {events:,} events, {frames} frames, {seconds:.1f} s", end="", file=sys.stderr, flush=True)

    live = sys.stderr.isatty()
    info = describe(args.file, progress=progress if live else None, exposure_us=args.exposure_us)
    if live:
        print("\r" + " " * 72 + "\r", end="", file=sys.stderr, flush=True)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(info.to_dict(), f, indent=2)
    print(info.to_text())
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    from .replay import run

    run(args)
    return 0


def _cmd_live(args: argparse.Namespace) -> int:
    from .live import run

    run(args)
    return 0


def _cmd_devices(args: argparse.Namespace) -> int:
    from .devices import run

    return run(include_emulated=not args.no_emulated)


def _cmd_bench_decode(args: argparse.Namespace) -> int:
    from .bench.decode import run

    run(seconds=args.seconds, repeats=args.repeats, seed=args.seed, json_path=args.json)
    return 0


def _cmd_bench_pipeline(args: argparse.Namespace) -> int:
    from .bench.pipeline import run

    run(duration_s=args.duration, rate_mev_s=args.rate, fps=args.fps, batch_us=args.batch_us, seed=args.seed,
        repeats=args.repeats, json_path=args.json)
    return 0


def _cmd_bench_estimators(args: argparse.Namespace) -> int:
    from .bench.estimators import run

    run(events=args.events, duration_s=args.duration, fps=args.fps, exposure_us=args.exposure_us,
        repeats=args.repeats, edi_samples=args.edi_samples, seed=args.seed, json_path=args.json)
    return 0


def _cmd_bench_sim(args: argparse.Namespace) -> int:
    from .bench.sim import run

    run(duration_s=args.duration, cameras=args.cameras, scenario=args.scenario, seed=args.seed, json_path=args.json)
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    from .compare import run

    run(scenario=args.scenario, controllers=args.controllers, seed=args.seed, seeds=args.seeds,
        duration_s=args.duration, sift=not args.no_sift, json_path=args.json, save=args.save)
    return 0


LAYOUT_NAMES = ("live", "inspect", "compare")  # necviz.layouts.LAYOUTS, without importing Rerun for --help


def _run_args(parser: argparse.ArgumentParser, tuning: bool = True) -> None:
    from .dashboard import add_run_args

    add_run_args(parser, LAYOUT_NAMES, tuning=tuning)


def _cmd_demo(args: argparse.Namespace) -> int:
    from .demo import run

    run(args)
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="necviz", description="Neuromorphic exposure control: estimators, controllers, dashboard.")
    p.add_argument("--version", action="version", version=f"necviz {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    info = sub.add_parser("info", help="versions and capabilities; with FILE, what a recording holds")
    info.add_argument("file", nargs="?", metavar="FILE", help="a recording (any supported format)")
    info.add_argument("--exposure-us", type=float, default=None,
                      help="exposure for formats that do not store it (AEDAT 2.0, text, HDF5, bags)")
    info.add_argument("--json", metavar="OUT", help="with FILE: also write the summary as JSON")
    info.set_defaults(func=_cmd_info)

    cmp_ = sub.add_parser("compare", help="NEC versus the baselines in closed loop on one simulated scene")
    cmp_.add_argument("--scenario", default="tunnel_exit", help="simulator scenario (default tunnel_exit)")
    cmp_.add_argument("--controllers", default="nec,navid,shim,begin,builtin,fixed",
                      help="comma-separated controllers (default: all six)")
    cmp_.add_argument("--duration", type=float, default=None, help="simulated seconds (default: the scenario's)")
    cmp_.add_argument("--seed", type=int, default=0)
    cmp_.add_argument("--seeds", type=int, default=1, help="repeat over this many seeds and report mean ± std")
    cmp_.add_argument("--json", metavar="FILE", help="write the results as JSON")
    cmp_.add_argument("--save", metavar="FILE.rrd", help="write a Rerun recording (per-controller entity paths)")
    cmp_.add_argument("--no-sift", action="store_true", help="skip the SIFT inlier metric (the slowest part)")
    cmp_.set_defaults(func=_cmd_compare)

    demo = sub.add_parser("demo", help="the dashboard on the simulator: tunnel_exit, NEC versus the baselines side by side",
                          description="Simulated tunnel_exit (or another scenario), every controller driving its own "
                                      "camera, shown in the compare layout. No hardware or files needed.")
    demo.add_argument("--scenario", default="tunnel_exit", help="simulator scenario (default tunnel_exit)")
    demo.add_argument("--controllers", default="nec,navid,shim,begin,builtin,fixed",
                      help="comma-separated controllers (default: all six)")
    demo.add_argument("--duration", type=float, default=None, help="simulated seconds (default: the scenario's)")
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--record", metavar="FILE", help="also record the first controller's camera (events, frames, "
                                                      "commands) to a crash-safe native file for necviz replay")
    _run_args(demo)
    demo.set_defaults(func=_cmd_demo)

    rep = sub.add_parser("replay", help="a recording in open loop: frames, events, P-TEDI vs frames, what NEC would do",
                         description="Replays FILE (necviz, AEDAT 4/3.1/2.0, ROS bag, RPG text, HDF5) through P-TEDI and "
                                     "a controller in open loop, in the inspect layout, and reports the per-frame "
                                     "prediction error and saturated frames.")
    rep.add_argument("file", metavar="FILE", help="the recording")
    rep.add_argument("--start", type=float, default=None, metavar="S", help="start S seconds into the recording")
    rep.add_argument("--end", type=float, default=None, metavar="S", help="stop S seconds into the recording")
    rep.add_argument("--exposure-us", type=float, default=None,
                     help="exposure for formats that do not store it (AEDAT 2.0 estimates it from frame timing)")
    rep.add_argument("--format", default=None, help="skip detection (necviz, aedat4, aedat3, aedat2, rosbag1, "
                                                    "rosbag2, hdf5, rpg-text)")
    rep.add_argument("--controller", default="nec", help="the controller shown in open loop (default nec)")
    rep.add_argument("--json", metavar="OUT", help="write the summary (per-frame detail included) as JSON")
    _run_args(rep, tuning=False)
    rep.set_defaults(func=_cmd_replay)

    live = sub.add_parser("live", help="a DAVIS camera (USB or emulated) with NEC closing the loop",
                          description="Runs a controller (NEC by default) in closed loop on a DAVIS346/DAVIS240 over "
                                      "USB, or on a virtual DAVIS346 (--device emulated), in the live layout.")
    live.add_argument("--device", choices=("usb", "emulated"), default="usb",
                      help="usb (a real camera) or emulated (the same driver on a virtual DAVIS346)")
    live.add_argument("--serial", default=None, help="which camera when several are attached")
    live.add_argument("--reconnect", action="store_true", help="if the camera is unplugged, wait for it to return")
    live.add_argument("--controller", default="nec", help="the controller that drives the camera (default nec)")
    live.add_argument("--duration", type=float, default=None, metavar="S",
                      help="stop after S seconds of sensor time (emulated: the scene's length)")
    live.add_argument("--scenario", default="tunnel_exit", help="emulated device: simulator scenario")
    live.add_argument("--seed", type=int, default=0, help="emulated device: simulator seed")
    live.add_argument("--emulate-unplug", type=float, default=None, metavar="S",
                      help="emulated device: unplug it after S seconds (shows what an unplug does)")
    live.add_argument("--record", metavar="FILE", help="record events, frames and commands to a crash-safe file")
    _run_args(live)
    live.set_defaults(func=_cmd_live)

    dev = sub.add_parser("devices", help="attached (and emulated) DAVIS cameras: serial, firmware, logic version")
    dev.add_argument("--no-emulated", action="store_true", help="list real cameras only")
    dev.set_defaults(func=_cmd_devices)

    bench = sub.add_parser("bench", help="speed benchmarks (print a table, optionally write JSON)")
    bsub = bench.add_subparsers(dest="bench", metavar="BENCH", required=True)
    est = bsub.add_parser("estimators", help="Table 1 of the paper: EDI, mEDI, Fast-EDI, TEDI, P-TEDI and a read-only floor")
    est.add_argument("--json", metavar="FILE", help="write the results as JSON")
    est.add_argument("--events", type=int, default=10_000_000, help="events in the synthetic 346x260 stream (default 10M)")
    est.add_argument("--duration", type=float, default=2.0, help="stream length in seconds (default 2.0)")
    est.add_argument("--fps", type=float, default=50.0, help="APS frame rate, 25-100 (default 50)")
    est.add_argument("--exposure-us", type=int, default=5_000, help="APS exposure (default 5000 µs)")
    est.add_argument("--repeats", type=int, default=3, help="timed runs per method after a warm-up (default 3)")
    est.add_argument("--edi-samples", type=int, default=64, help="samples per exposure for EDI and mEDI (default 64)")
    est.add_argument("--seed", type=int, default=0)
    est.set_defaults(func=_cmd_bench_estimators)
    sim = bsub.add_parser("sim", help="closed-loop simulator speed: tunnel_exit with several cameras")
    sim.add_argument("--json", metavar="FILE", help="write the results as JSON")
    sim.add_argument("--duration", type=float, default=5.0, help="simulated seconds (default 5)")
    sim.add_argument("--cameras", type=int, default=6, help="cameras sharing the scene (default 6)")
    sim.add_argument("--scenario", default="tunnel_exit", help="scenario preset (default tunnel_exit)")
    sim.add_argument("--seed", type=int, default=0)
    sim.set_defaults(func=_cmd_bench_sim)
    dec = bsub.add_parser("decode", help="DAVIS stream decoder throughput on a 12 Mev/s-style stream")
    dec.add_argument("--json", metavar="FILE", help="write the results as JSON")
    dec.add_argument("--seconds", type=float, default=1.0, help="stream length in seconds (default 1)")
    dec.add_argument("--repeats", type=int, default=5, help="timed runs (default 5)")
    dec.add_argument("--seed", type=int, default=0)
    dec.set_defaults(func=_cmd_bench_decode)
    pipe = bsub.add_parser("pipeline", help="the whole dashboard path at 12 Mev/s: real-time factor and control latency")
    pipe.add_argument("--json", metavar="FILE", help="write the results as JSON")
    pipe.add_argument("--duration", type=float, default=10.0, help="stream length in seconds (default 10)")
    pipe.add_argument("--rate", type=float, default=12.0, help="event rate in Mev/s (default 12)")
    pipe.add_argument("--fps", type=float, default=50.0, help="frame rate (default 50)")
    pipe.add_argument("--batch-us", type=int, default=1_000, help="event batch period (default 1000 µs)")
    pipe.add_argument("--repeats", type=int, default=3, help="runs per configuration; the median is reported")
    pipe.add_argument("--seed", type=int, default=0)
    pipe.set_defaults(func=_cmd_bench_pipeline)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    from .core.errors import NecvizError

    _terminate_as_interrupt()
    try:
        return int(args.func(args) or 0)
    except NecvizError as e:
        print(f"necviz: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("necviz: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into `head` and the like: not an error
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


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
