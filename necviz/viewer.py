"""Where a command's Rerun data goes: the viewer flags every dashboard command shares.

As in Rerun's own examples: ``--spawn`` starts a native viewer (the default when a display
exists), ``--serve`` runs a gRPC server and the web viewer on localhost and prints the URL,
``--connect URL`` streams to a running viewer, ``--save FILE.rrd`` writes a file. Flags combine
(``--serve --save run.rrd``). Headless with no flag, the run is saved to
``necviz-<command>-<time>.rrd`` and the command says how to open it.
"""

from __future__ import annotations

import argparse
import os
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import rerun as rr

from .core.errors import ParameterError

DEFAULT_GRPC_PORT = 9876
DEFAULT_WEB_PORT = 9090
DEFAULT_CONNECT = f"rerun+http://127.0.0.1:{DEFAULT_GRPC_PORT}/proxy"


def add_viewer_args(parser: argparse.ArgumentParser, layouts: tuple[str, ...]) -> None:
    g = parser.add_argument_group("viewer (combine freely; headless default: save to a file)")
    g.add_argument("--spawn", action="store_true", help="spawn a native Rerun viewer (default when a display exists)")
    g.add_argument("--serve", action="store_true",
                   help=f"serve gRPC (:{DEFAULT_GRPC_PORT}) and the web viewer (:{DEFAULT_WEB_PORT}) on localhost")
    g.add_argument("--connect", metavar="URL", nargs="?", const=DEFAULT_CONNECT,
                   help=f"stream to a running viewer (default URL {DEFAULT_CONNECT})")
    g.add_argument("--save", metavar="FILE.rrd", type=Path, help="write the recording to FILE.rrd")
    g.add_argument("--layout", choices=layouts, help="override the command's layout")
    g.add_argument("--grpc-port", type=int, default=DEFAULT_GRPC_PORT, help=argparse.SUPPRESS)
    g.add_argument("--web-port", type=int, default=DEFAULT_WEB_PORT, help=argparse.SUPPRESS)
    g.add_argument("--memory-limit", default="1GB", help="viewer / server memory limit (default 1GB)")


def check_save_path(save) -> Path:
    """``--save``: a ``.rrd`` name in a folder that exists and can be written."""
    save = Path(save)
    if save.suffix != ".rrd":
        raise ParameterError(f"--save expects a .rrd file name, got {str(save)!r}")
    if save.is_dir():
        raise ParameterError(f"--save: {str(save)!r} is a folder")
    parent = save.parent if str(save.parent) else Path(".")
    if not parent.is_dir():
        raise ParameterError(f"--save: folder {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK):
        raise ParameterError(f"--save: folder {str(parent)!r} is not writable")
    return save


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


@dataclass
class Viewer:
    """An open recording stream and what the user was told about it."""

    rec: rr.RecordingStream
    messages: list[str] = field(default_factory=list)
    save_path: Path | None = None
    url: str | None = None

    def close(self) -> None:
        """Flush what was logged. A served recording stays available until the process ends."""
        self.rec.flush()
        if self.url is None:
            rr.disconnect(self.rec)


def open_viewer(args: argparse.Namespace, command: str, blueprint, name: str) -> Viewer:
    """Create the recording and attach the sinks the flags ask for."""
    save = getattr(args, "save", None)
    if save is not None:
        save = check_save_path(save)
    spawn = getattr(args, "spawn", False)
    serve = getattr(args, "serve", False)
    connect = getattr(args, "connect", None)
    messages: list[str] = []
    if not (spawn or serve or connect or save):
        if has_display():
            spawn = True
        else:
            save = Path(f"necviz-{command}-{time.strftime('%Y%m%d-%H%M%S')}.rrd")
            messages.append(f"no display: saving to {save} (open it with: rerun {save})")
    try:
        return _open(args, blueprint, name, save, spawn, serve, connect, messages)
    except RuntimeError as e:  # Rerun reports bad URLs, ports and memory limits this way
        raise ParameterError(f"viewer: {e}") from None


def _open(args, blueprint, name, save, spawn, serve, connect, messages) -> Viewer:
    rec = rr.RecordingStream("necviz", recording_id=str(uuid.uuid4()))
    sinks = []
    url = None
    if spawn:
        rr.spawn(port=args.grpc_port + 1 if serve else args.grpc_port, connect=False,
                 memory_limit=args.memory_limit, hide_welcome_screen=True)
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{args.grpc_port + 1 if serve else args.grpc_port}/proxy"))
        messages.append("streaming to a native viewer")
    if serve:
        server = rr.GrpcServerSink(bind_ip="127.0.0.1", port=args.grpc_port, server_memory_limit=args.memory_limit)
        sinks.append(server)
    if connect:
        sinks.append(rr.GrpcSink(connect))
        messages.append(f"streaming to {connect}")
    if save:
        sinks.append(rr.FileSink(str(save)))
        if not any(m.startswith("no display") for m in messages):
            messages.append(f"saving to {save} (open it with: rerun {save})")
    rec.set_sinks(*sinks, default_blueprint=blueprint)
    if serve:
        rr.serve_web_viewer(web_port=args.web_port, open_browser=False, connect_to=server.uri)
        url = f"http://127.0.0.1:{args.web_port}/?url={server.uri.replace('+', '%2B')}"
        messages.append(f"web viewer: {url}  (gRPC {server.uri}; the web viewer listens on all interfaces)")
    rec.send_recording_name(name)
    return Viewer(rec, messages, save, url)
