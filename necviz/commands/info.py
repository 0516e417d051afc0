"""What ``necviz info`` reports: versions, Numba's threading layer, registered sources and controllers."""

from __future__ import annotations

import os
import sys
from importlib.metadata import PackageNotFoundError, version

from necviz import __version__
from necviz.commands import Command

PACKAGES = ("numpy", "numba", "llvmlite", "scipy", "opencv-python-headless", "pyusb", "rerun-sdk")


def threading_layer() -> str:
    """The layer Numba actually uses (it is only chosen once a parallel function has run)."""
    import numba as nb
    import numpy as np

    @nb.njit(parallel=True, cache=True)
    def _touch_threads(n):
        acc = np.zeros(n)
        for i in nb.prange(n):
            acc[i] = i
        return acc.sum()

    try:
        _touch_threads(4)
        return f"{nb.threading_layer()} ({nb.config.NUMBA_NUM_THREADS} threads)"
    except Exception as e:  # no usable layer: report it rather than fail
        return f"unavailable ({e})"


def _scenarios() -> list[str]:
    from necviz.drivers.sim.scenes import SCENARIOS

    return sorted(SCENARIOS)


def collect_info() -> dict:
    import necviz.tuned  # noqa: F401 - registers the tuned controllers (navid-tuned, ...), which every command accepts
    from necviz.core.control import CONTROLLERS
    from necviz.drivers import SOURCES

    pkgs = {}
    for name in PACKAGES:
        try:
            pkgs[name] = version(name)
        except PackageNotFoundError:
            pkgs[name] = "not installed"
    return {
        "necviz": __version__,
        "cpu_count": os.cpu_count(),
        "packages": pkgs,
        "numba_threading_layer": threading_layer(),
        "controllers": sorted(CONTROLLERS),
        "sources": sorted(SOURCES),
        "scenarios": _scenarios(),
    }


def _command(args) -> int:
    if args.file:
        return _info_file(args)
    import platform

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


def add_arguments(p) -> None:
    from necviz.flags import number

    p.add_argument("file", nargs="?", metavar="FILE", help="a recording (any supported format)")
    p.add_argument(
        "--exposure-us",
        type=number("--exposure-us"),
        default=None,
        help="exposure for formats that do not store it (AEDAT 2.0, text, HDF5, bags)",
    )
    p.add_argument("--json", metavar="OUT", help="with FILE: also write the summary as JSON")
    p.add_argument(
        "--pipe-timeout",
        type=number("--pipe-timeout"),
        default=None,
        metavar="S",
        help="accept FILE as a named pipe: copy what it delivers, waiting at most S seconds for data",
    )
    p.add_argument("--force", action="store_true", help="replace an existing --json file")


COMMAND = Command(
    name="info",
    help="versions and capabilities; with FILE, what a recording holds",
    add_arguments=add_arguments,
    run=_command,
)
