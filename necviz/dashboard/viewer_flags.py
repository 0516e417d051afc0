"""The viewer flags of the command line (``--spawn``, ``--serve``, ``--save`` …), without Rerun.

Kept apart from :mod:`necviz.dashboard.viewer` (which imports the Rerun SDK) so building the
parser — ``necviz --help``, a mistyped flag — loads nothing heavy.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from necviz.names import DEFAULT_CONNECT, DEFAULT_GRPC_PORT, DEFAULT_WEB_PORT, LAYOUT_NAMES


def add_viewer_args(parser: argparse.ArgumentParser, layouts: tuple[str, ...] = LAYOUT_NAMES) -> None:
    """Add the viewer flags (an argument group) to ``parser``."""
    g = parser.add_argument_group("viewer (combine freely; headless default: save to a file)")
    g.add_argument("--spawn", action="store_true", help="spawn a native Rerun viewer (default when a display exists)")
    g.add_argument(
        "--serve",
        action="store_true",
        help=f"serve the web viewer (:{DEFAULT_WEB_PORT}) and its data (:{DEFAULT_GRPC_PORT}) on 127.0.0.1",
    )
    g.add_argument(
        "--bind",
        metavar="ADDR",
        default="127.0.0.1",
        help="with --serve: the address to listen on (default 127.0.0.1; anything else exposes the "
        "recording to the network)",
    )
    g.add_argument(
        "--connect",
        metavar="URL",
        nargs="?",
        const=DEFAULT_CONNECT,
        help=f"stream to a running viewer (default URL {DEFAULT_CONNECT})",
    )
    g.add_argument("--save", metavar="FILE.rrd", type=Path, help="write the recording to FILE.rrd")
    g.add_argument("--layout", choices=layouts, help="override the command's layout")
    from necviz.flags import number

    g.add_argument("--grpc-port", type=number("--grpc-port"), default=DEFAULT_GRPC_PORT, help=argparse.SUPPRESS)
    g.add_argument("--web-port", type=number("--web-port"), default=DEFAULT_WEB_PORT, help=argparse.SUPPRESS)
    g.add_argument("--memory-limit", default="1GB", help="viewer / server memory limit (default 1GB)")


def viewer_options(args: argparse.Namespace):
    """The viewer flags of a parsed command line, as :class:`~necviz.options.ViewerOptions`."""
    from necviz.options import ViewerOptions

    return ViewerOptions(
        spawn=args.spawn,
        serve=args.serve,
        connect=args.connect,
        save=args.save,
        force=getattr(args, "force", False),
        layout=args.layout,
        memory_limit=args.memory_limit,
        bind=args.bind,
        grpc_port=args.grpc_port,
        web_port=args.web_port,
    )


__all__ = [
    "DEFAULT_CONNECT",
    "DEFAULT_GRPC_PORT",
    "DEFAULT_WEB_PORT",
    "LAYOUT_NAMES",
    "add_viewer_args",
    "viewer_options",
]
