"""Where a command's Rerun data goes: the viewer options every dashboard command shares.

As in Rerun's own examples: ``spawn`` starts a native viewer (the default when a display exists),
``serve`` runs the web viewer and its gRPC data port and prints the URL, ``connect URL`` streams
to a running viewer, ``save FILE.rrd`` writes a file; they combine (``--serve --save run.rrd``).
Headless with nothing set, the run is saved to ``necviz-<command>-<time>.rrd`` and the command
says how to open it.

``serve`` listens on 127.0.0.1 only, for the web page and for the data: it runs the ``rerun``
program that ships with the SDK (``rerun --serve-web --bind ADDR``), because the SDK's own web
server has no bind address and listens on every interface. Another address takes an explicit
``bind`` (``--bind 0.0.0.0``), and the command warns that the recording is then visible to the
network.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import rerun as rr

from necviz.core.errors import ParameterError
from necviz.dashboard.viewer_flags import (  # noqa: F401 - re-exported: the flags live in a module without Rerun
    DEFAULT_CONNECT,
    DEFAULT_GRPC_PORT,
    DEFAULT_WEB_PORT,
    add_viewer_args,
    viewer_options,
)
from necviz.options import ViewerOptions
from necviz.outputs import check_output, commit_recording, recording_target

LOOPBACK = ("127.0.0.1", "::1", "localhost")


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def resolve(options: ViewerOptions, command: str, inputs=()) -> ViewerOptions:
    """Fill in the headless default (a file) and check the save path before anything starts."""
    from dataclasses import replace

    if not (options.spawn or options.serve or options.connect or options.save or options.notebook):
        if has_display():
            options = replace(options, spawn=True)
        else:
            options = replace(options, save=Path(f"necviz-{command}-{time.strftime('%Y%m%d-%H%M%S')}.rrd"))
    if options.save is not None:
        check_output(options.save, "--save", inputs=inputs, force=options.force, suffixes=(".rrd",))
    return options


@dataclass
class Viewer:
    """An open recording stream and what the user was told about it."""

    rec: rr.RecordingStream
    messages: list[str] = field(default_factory=list)
    save_path: Path | None = None
    url: str | None = None
    server: subprocess.Popen | None = None
    target: Path | None = None  # where the file is written until it is complete (see necviz.outputs)
    notebook: object = None  # the rerun.notebook.Viewer shown in the cell (it keeps what was streamed)

    def close(self) -> None:
        """Flush what was logged. A served recording stays available until :meth:`stop_serving`;
        a notebook's viewer keeps everything it was sent."""
        self.rec.flush()
        if self.server is None and self.notebook is None:
            rr.disconnect(self.rec)
        if self.target is not None and self.save_path is not None:
            commit_recording(self.target, self.save_path)

    def stop_serving(self) -> None:
        if self.server is not None:
            rr.disconnect(self.rec)
            stop_process_group(self.server)
            self.server = None


def stop_process_group(proc: subprocess.Popen, timeout_s: float = 5.0) -> None:
    """Stop a server started in its own session, and everything it started (the ``rerun`` wrapper
    script runs the viewer binary as a child)."""
    import signal

    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout_s)
            return
        except subprocess.TimeoutExpired:
            continue


def open_viewer(options: ViewerOptions, command: str, blueprint, name: str) -> Viewer:
    """Create the recording and attach the sinks ``options`` (already :func:`resolve` d) ask for."""
    messages: list[str] = []
    if options.save is not None and not options.watched and not has_display():
        messages.append(f"saving to {options.save} (open it with: rerun {options.save})")
    try:
        return _open(options, blueprint, name, messages)
    except RuntimeError as e:  # Rerun reports bad URLs, ports and memory limits this way
        raise ParameterError(f"viewer: {e}") from None


def _rerun_program() -> list[str]:
    exe = Path(sys.executable).with_name("rerun")
    if exe.exists():
        return [str(exe)]
    found = shutil.which("rerun")
    return [found] if found else [sys.executable, "-m", "rerun"]


def _wait_listening(host: str, port: int, proc: subprocess.Popen, timeout_s: float = 15.0) -> None:
    deadline = time.monotonic() + timeout_s
    target = "127.0.0.1" if host in ("0.0.0.0", "localhost") else ("::1" if host == "::" else host)
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            err = (proc.stderr.read() or b"").decode(errors="replace").strip().splitlines()
            stop_process_group(proc)
            raise ParameterError(f"viewer: the web viewer server did not start ({err[-1] if err else 'no message'})")
        try:
            with socket.create_connection((target, port), timeout=0.2):
                return
        except OSError:
            time.sleep(0.05)
    stop_process_group(proc)
    raise ParameterError(f"viewer: the web viewer server did not listen on {host}:{port} within {timeout_s:g} s")


def start_web_server(options: ViewerOptions) -> tuple[subprocess.Popen, str, str]:
    """``rerun --serve-web`` bound to ``options.bind``; returns the process, the data URI and the page URL."""
    cmd = [
        *_rerun_program(),
        "--serve-web",
        "--bind",
        options.bind,
        "--port",
        str(options.grpc_port),
        "--web-viewer-port",
        str(options.web_port),
        "--server-memory-limit",
        options.memory_limit,
    ]
    # its own session: a Ctrl-C at the terminal stops necviz, which then disconnects and stops the server
    # in that order (a server killed first makes the SDK's last flush fail loudly)
    proc = subprocess.Popen(
        cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True
    )
    _wait_listening(options.bind, options.grpc_port, proc)
    _wait_listening(options.bind, options.web_port, proc)
    host = "127.0.0.1" if options.bind in ("0.0.0.0", "::", "localhost") else options.bind
    uri = f"rerun+http://{host}:{options.grpc_port}/proxy"
    url = f"http://{host}:{options.web_port}/?url={uri.replace('+', '%2B')}"
    return proc, uri, url


#: Seconds between chunks of one entity in a recording that only goes to a file (the batcher's tick,
#: and how often a live sink that nobody watches sends its scalar series).
FILE_FLUSH_S = 2.0


def file_batching() -> "rr.ChunkBatcherConfig":
    """The chunk batcher for a recording that only goes to a file: a chunk per entity every 2 s (or 8 MiB).

    Rerun's file sink keeps an index entry for every chunk it writes (the .rrd footer), so with the
    default batcher (a flush every few ms) a process that records for hours grows by hundreds of MB per
    hour (measured: 440 → 640 MB over 850 s of ``live --save``; rerun-io/rerun#12623 reports the same).
    Nobody watches a file while it is written, so bigger chunks cost nothing: memory stays flat."""
    return rr.ChunkBatcherConfig(flush_tick=FILE_FLUSH_S, flush_num_bytes=8 << 20, flush_num_rows=100_000)


def _open_notebook(blueprint, name, messages) -> Viewer:
    """The viewer inline in the running Jupyter cell (``rerun-notebook``), fed as the run logs."""
    try:
        import rerun_notebook  # noqa: F401 - the widget itself (the optional extra)
        from rerun.notebook import Viewer as NotebookViewer
    except ImportError:
        raise ParameterError("notebook=True needs rerun-notebook: pip install 'necviz[notebook]'") from None
    rec = rr.RecordingStream("necviz", recording_id=str(uuid.uuid4()))
    widget = NotebookViewer(recording=rec, blueprint=blueprint, width="auto", height=720)
    widget.display()
    rec.send_recording_name(name)
    messages.append("showing the viewer in the notebook")
    return Viewer(rec, messages, notebook=widget)


def _open(options: ViewerOptions, blueprint, name, messages) -> Viewer:
    if options.notebook:
        return _open_notebook(blueprint, name, messages)
    viewer = bool(options.serve or options.spawn or options.connect)
    rec = rr.RecordingStream(
        "necviz", recording_id=str(uuid.uuid4()), batcher_config=None if viewer else file_batching()
    )
    sinks = []
    url = server = None
    port = options.grpc_port
    if options.serve:
        server, uri, url = start_web_server(options)
        sinks.append(rr.GrpcSink(uri))
        port = options.grpc_port + 1  # a spawned native viewer takes the next port
        if options.bind not in LOOPBACK:
            messages.append(f"warning: serving on {options.bind}: anyone who can reach this machine can watch")
        messages.append(f"web viewer: {url}")
    if options.spawn:
        rr.spawn(port=port, connect=False, memory_limit=options.memory_limit, hide_welcome_screen=True)
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy"))
        messages.append("streaming to a native viewer")
    if options.connect:
        sinks.append(rr.GrpcSink(options.connect))
        messages.append(f"streaming to {options.connect}")
    target = None
    if options.save:
        target = recording_target(options.save)
        sinks.append(rr.FileSink(str(target)))
        if not any(m.startswith("saving to") for m in messages):
            messages.append(f"saving to {options.save} (open it with: rerun {options.save})")
    rec.set_sinks(*sinks, default_blueprint=blueprint)
    rec.send_recording_name(name)
    return Viewer(rec, messages, Path(options.save) if options.save else None, url, server, target)
