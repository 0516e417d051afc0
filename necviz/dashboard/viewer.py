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
network. Both ports are checked before the server starts: a port already taken (a server left
running by an earlier necviz, or another program) is refused in one line naming the process that
holds it, so the data never go to a stale server. The server runs in its own process group (a
Ctrl-C at the terminal reaches necviz, which disconnects first) and dies with necviz even when
necviz is killed outright (Linux: the kernel's parent-death signal; elsewhere a watchdog).

A file sink is flushed with a bound (:func:`flush_stream`): Rerun's file writer that hit a full
disk stops writing but leaves ``flush`` waiting for ever; necviz notices that the file stopped
growing and fails with one line instead.
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import rerun as rr

from necviz.core.errors import NecvizError, ParameterError
from necviz.dashboard.rrd_file import SegmentedFile, rerun_binary, rerun_program
from necviz.dashboard.viewer_flags import (  # noqa: F401 - re-exported: the flags live in a module without Rerun
    DEFAULT_CONNECT,
    DEFAULT_GRPC_PORT,
    DEFAULT_WEB_PORT,
    add_viewer_args,
    viewer_options,
)
from necviz.options import ViewerOptions
from necviz.outputs import OutputError, StreamedOutput, free_bytes

LOOPBACK = ("127.0.0.1", "::1", "localhost")


def text(value) -> str:
    """``str(value)`` that Rerun accepts: a file name that is not UTF-8 (kept by Python as surrogate
    escapes) shows its undecodable bytes as U+FFFD instead of failing to encode."""
    return str(value).encode("utf-8", "surrogateescape").decode("utf-8", "replace")


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def in_notebook() -> bool:
    """Whether this runs in a Jupyter kernel (where a widget can show), not a plain script or terminal."""
    ipython = sys.modules.get("IPython")
    shell = ipython.get_ipython() if ipython is not None and hasattr(ipython, "get_ipython") else None
    return shell is not None and getattr(shell, "kernel", None) is not None


def resolve(options: ViewerOptions, command: str) -> ViewerOptions:
    """Fill in the headless default (a file) before anything starts, and check that a notebook viewer is in a
    notebook and that the ports to serve on are free. The ``--save`` file is checked with the command's other
    outputs (:func:`necviz.outputs.check_run_files`)."""
    from dataclasses import replace

    if options.notebook and not in_notebook():
        raise ParameterError(
            "notebook=True shows the viewer in a Jupyter notebook's cell, and this is not a notebook (a plain "
            "script or terminal); use save='run.rrd' or spawn=True instead"
        )
    if not (options.spawn or options.serve or options.connect or options.save or options.notebook):
        if has_display():
            options = replace(options, spawn=True)
        else:
            options = replace(options, save=Path(f"necviz-{command}-{time.strftime('%Y%m%d-%H%M%S')}.rrd"))
    if options.serve:
        check_ports(options)  # before anything starts: a taken port is one line, not a stall
    return options


@dataclass
class Viewer:
    """An open recording stream and what the user was told about it.

    ``output``: the ``--save`` file being written (:class:`~necviz.outputs.StreamedOutput`); the
    command commits it when the run succeeded and discards it when it failed. With one, the viewer
    is one of the run's :class:`~necviz.outputs.Output` s (``path``, :meth:`commit`, :meth:`discard`)."""

    rec: rr.RecordingStream
    messages: list[str] = field(default_factory=list)
    save_path: Path | None = None
    url: str | None = None
    server: subprocess.Popen | None = None
    output: StreamedOutput | None = None
    notebook: object = None  # the rerun.notebook.Viewer shown in the cell (it keeps what was streamed)
    #: the ``--save`` file written in segments (:mod:`necviz.dashboard.rrd_file`), and the other sinks
    segments: SegmentedFile | None = None
    other_sinks: list = field(default_factory=list)

    @property
    def path(self) -> Path | None:
        """The ``--save`` file (an :class:`~necviz.outputs.Output`'s ``path``)."""
        return self.save_path

    def commit(self) -> None:
        """The run succeeded: the ``--save`` file becomes the file the user asked for."""
        self.output.commit()

    @property
    def target(self) -> Path | None:
        """Where the file is written until it is complete (see :mod:`necviz.outputs`)."""
        return self.output.target if self.output is not None else None

    @property
    def files(self) -> list:
        """The file being written now (a live list: a new segment replaces it)."""
        return self.segments.files if self.segments is not None else []

    def rotate(self) -> bool:
        """Start the ``--save`` file's next segment when the current one is due (called by the thread
        that logs, between its sends): the footer index Rerun keeps in memory covers one segment.
        True when a new segment was started."""
        if self.segments is not None and self.segments.due():
            self.rec.set_sinks(*self.other_sinks, self.segments.next())
            return True
        return False

    def close(self) -> None:
        """Flush what was logged (bounded: :func:`flush_stream`) and complete the ``--save`` file (its
        segments joined into one). A served recording stays available until :meth:`stop_serving`; a
        notebook's viewer keeps everything it was sent."""
        flush_stream(self.rec, self.files, label=self.save_path)
        keep_stream = self.server is not None or self.notebook is not None
        if self.segments is not None:
            if keep_stream:
                self.rec.set_sinks(*self.other_sinks)  # the file sink is closed: its footer is written
            else:
                rr.disconnect(self.rec)
                keep_stream = True  # already disconnected
            self.segments.join()
        if not keep_stream:
            rr.disconnect(self.rec)

    def discard(self) -> str:
        """The run failed: remove the ``--save`` file's later segments and discard the file
        (:meth:`~necviz.outputs.StreamedOutput.discard`, which may keep a camera session's)."""
        if self.segments is not None and self.output.keep_partial:
            try:
                self.segments.join()  # one readable file, if the disk allows
            except NecvizError:
                return f"{self.output.discard()} (and its later segments beside it: `necviz repair` joins them)"
        elif self.segments is not None:
            self.segments.discard()
        return self.output.discard()

    def stop_serving(self) -> None:
        if self.server is not None:
            rr.disconnect(self.rec)
            stop_process_group(self.server)
            self.server = None


#: Rerun streams whose file writer failed: flushing or dropping them would block for ever (rerun-sdk
#: 0.41), so they are kept here and the command line leaves with ``os._exit`` after its error line.
WEDGED: list = []


def _file_size_limit() -> float:
    """The process's file size limit (``ulimit -f``) in bytes, ``inf`` if none."""
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
        return float("inf") if soft == resource.RLIM_INFINITY else float(soft)
    except (ImportError, OSError, ValueError):
        return float("inf")


def flush_stream(rec: rr.RecordingStream, files=(), stall_s: float = 20.0, label=None) -> None:
    """``rec.flush()``, bounded when ``rec`` writes ``files``.

    Rerun's file sink that fails to write (a full disk) logs an error and stops, while ``flush`` (and
    dropping the stream) waits for ever. Here the flush is retried in 1 s steps while any of
    ``files`` still grows; once they have not grown for ``stall_s`` seconds, or the writer reports
    it stopped, the stream is set aside (:data:`WEDGED`) and :class:`~necviz.outputs.OutputError` is
    raised (the caller deletes the incomplete file); ``label`` is the file name it shows.
    """
    files = [Path(f) for f in files if f is not None]
    if not files:
        rec.flush()
        return

    def sizes():
        out = []
        for f in files:
            try:
                out.append(os.path.getsize(f))
            except OSError:
                out.append(-1)
        return out

    last, since = sizes(), time.monotonic()
    while True:
        try:
            rec.flush(timeout_sec=1.0)
            return
        except RuntimeError as e:
            timed_out = "timed out" in str(e).lower()
        now = sizes()
        if timed_out and now != last:
            last, since = now, time.monotonic()
            continue
        free = free_bytes(files[0])
        full = (free is not None and free < (1 << 20)) or max(now) >= _file_size_limit() - (1 << 16)
        if timed_out and time.monotonic() - since < (min(stall_s, 3.0) if full else stall_s):
            continue
        WEDGED.append(rec)
        why = "no space left (a full disk or the file size limit)" if full else "the file writer stopped"
        raise OutputError(f"cannot write {str(label or files[0])!r}: {why}")


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


def open_viewer(options: ViewerOptions, blueprint, name: str, *, output: StreamedOutput | None = None) -> Viewer:
    """Create the recording ``name`` and attach the sinks ``options`` (already :func:`resolve` d) ask for,
    the viewers laid out by ``blueprint``.

    ``output``: the ``--save`` file the caller made for ``options.save`` (a
    :class:`~necviz.outputs.StreamedOutput`, whose ``keep_partial`` says whether a failed run keeps what it
    holds); discarded here if the viewer cannot be opened."""
    assert (output is not None) == bool(options.save and not options.notebook), "open_viewer: output is options.save's"
    messages: list[str] = []
    if options.save is not None and not options.watched and not has_display():
        messages.append(f"saving to {options.save} (open it with: rerun {options.save})")
    try:
        return _open(options, blueprint, name, messages, output)
    except RuntimeError as e:  # Rerun reports bad URLs, ports and memory limits this way
        raise ParameterError(f"viewer: {e}") from None


_rerun_program = rerun_program  # the rerun command and its binary: necviz.dashboard.rrd_file
_rerun_binary = rerun_binary


def _listener(host: str, port: int) -> str | None:
    """Who listens on ``port`` (``"process 123 (rerun --serve-web ...)"``), or None if it is free."""
    probe_host = "127.0.0.1" if host in ("localhost",) else host
    family = socket.AF_INET6 if ":" in probe_host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server does: TIME_WAIT is no obstacle
        try:
            s.bind((probe_host, port))
            return None
        except OSError:
            pass
    try:
        import psutil

        for c in psutil.net_connections(kind="inet"):
            if c.status == psutil.CONN_LISTEN and c.laddr and c.laddr.port == port and c.pid:
                try:
                    cmd = " ".join(" ".join(psutil.Process(c.pid).cmdline()).split())
                except psutil.Error:
                    cmd = "?"
                return f"process {c.pid} ({cmd[:80]})"
    except (ImportError, OSError, RuntimeError):
        pass
    return "another program"


def check_ports(options: ViewerOptions) -> None:
    """Refuse, in one line, ports that are taken before a server is started on them."""
    for flag, port in (("--grpc-port", options.grpc_port), ("--web-port", options.web_port)):
        who = _listener(options.bind, port)
        if who is None:
            continue
        stale = "rerun" in who and "--serve" in who
        hint = f"a Rerun server left running by an earlier run; stop it (kill {who.split()[1]})" if stale else "stop it"
        raise ParameterError(
            f"--serve: port {port} on {options.bind} is already in use by {who}: {hint}, or choose "
            f"another port with {flag}"
        )


def _die_with_parent():
    """``preexec_fn`` of the server: its own session (Ctrl-C goes to necviz only) and, on Linux, SIGTERM
    when necviz dies (even by SIGKILL)."""
    os.setsid()
    if _PRCTL is not None:
        _PRCTL(1, 15)  # PR_SET_PDEATHSIG, SIGTERM


def _load_prctl():
    if not sys.platform.startswith("linux"):
        return None
    try:
        import ctypes

        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None


_PRCTL = _load_prctl()


def _watchdog(proc: subprocess.Popen) -> None:
    """Where the kernel cannot tie the server to necviz: a tiny shell that stops the server's process
    group once necviz is gone."""
    if _PRCTL is not None or os.name != "posix":
        return
    script = f"while kill -0 {os.getpid()} 2>/dev/null; do sleep 1; done; kill -TERM -{proc.pid} 2>/dev/null"
    subprocess.Popen(
        ["/bin/sh", "-c", script],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


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
    check_ports(options)
    cmd = [
        *_rerun_binary(),
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
    # in that order (a server killed first makes the SDK's last flush fail loudly); and it dies with necviz
    proc = subprocess.Popen(
        cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, preexec_fn=_die_with_parent
    )
    _watchdog(proc)
    _wait_listening(options.bind, options.grpc_port, proc)
    _wait_listening(options.bind, options.web_port, proc)
    host = "127.0.0.1" if options.bind in ("0.0.0.0", "::", "localhost") else options.bind
    uri = f"rerun+http://{host}:{options.grpc_port}/proxy"
    url = f"http://{host}:{options.web_port}/?url={uri.replace('+', '%2B')}"
    return proc, uri, url


#: Seconds between chunks of one entity in a recording that only goes to a file (the batcher's tick,
#: and how often a live sink that nobody watches sends its scalar series).
FILE_FLUSH_S = 2.0


def file_batching() -> rr.ChunkBatcherConfig:
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


def _open(options: ViewerOptions, blueprint, name, messages, output: StreamedOutput | None = None) -> Viewer:
    name = text(name)
    if options.notebook:
        return _open_notebook(blueprint, name, messages)
    viewer = bool(options.serve or options.spawn or options.connect)
    rec = rr.RecordingStream(
        "necviz", recording_id=str(uuid.uuid4()), batcher_config=None if viewer else file_batching()
    )
    sinks = []
    url = server = None
    port = options.grpc_port
    with contextlib.ExitStack() as undo:  # if the viewer cannot be opened: the server stopped, the file removed
        if output is not None:
            undo.callback(output.discard)
        if options.serve:
            server, uri, url = start_web_server(options)
            undo.callback(stop_process_group, server)
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
        segments = None
        others = list(sinks)
        if output is not None:
            segments = SegmentedFile(output.target, blueprint, "necviz")  # the blueprint beside, joined in at the end
            undo.callback(segments.discard)
            if others:  # the viewers get the blueprint; the file, never (rrd_file's docstring)
                rec.set_sinks(*others, default_blueprint=blueprint)
            sinks.append(segments.sink())
            if not any(m.startswith("saving to") for m in messages):
                messages.append(f"saving to {options.save} (open it with: rerun {options.save})")
        if segments is not None:
            rec.set_sinks(*sinks)
        else:
            rec.set_sinks(*sinks, default_blueprint=blueprint)
        rec.send_recording_name(name)
        undo.pop_all()  # opened: the run owns the server and the file from here
    return Viewer(
        rec, messages, Path(options.save) if options.save else None, url, server, output, None, segments, others
    )
