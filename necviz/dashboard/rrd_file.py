"""The ``--save`` file of a long session: written in segments, joined into one file when the run ends.

Rerun's file sink keeps an index entry in memory for every chunk it writes and puts that index (the
footer, which makes the file seekable) at the end of the file when it is closed. A session that
writes one file for an hour therefore grows by the whole index: measured 44 MB per hour for the file
sink alone (``benchmarks/rerun_footer.py``; rerun-io/rerun#12623), more with a viewer connected
(small chunks). Writing the same stream into a new file every :data:`SEGMENT_S` seconds keeps the
index of one segment only, so memory stays flat; when the run ends, the segments are joined by
``rerun rrd route`` (the ``rerun`` program that ships with the SDK), which copies the messages
without decoding them and writes one footer for the whole file. The user gets the one file they
asked for.

The layout's blueprint is kept apart from the segments, in a small ``.rbl`` beside them, and joined
in last: ``rerun rrd route`` 0.41 stops with an assertion on a file whose blueprint store it did not
write itself (the chunks of a blueprint sent through ``set_sinks(default_blueprint=...)`` are not in
the order of the file's index), while a blueprint written with ``Blueprint.save`` routes cleanly.

Layout while the run goes on: the first segment is the file itself (a crash leaves it readable up to
its last flush, without its blueprint; ``necviz repair`` makes it whole); later segments go to
``<file>.parts/0001.rrd``, ``0002.rrd``... and the blueprint to ``.<file>.blueprint.rbl``, beside it.
After a crash all are kept; ``necviz repair <file>`` joins them.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

#: Wall-clock seconds of one segment: the footer index a segment keeps in memory covers this long.
SEGMENT_S = 300.0
#: How fast a live session's ``--save`` file grows (bytes per hour of session): every frame (50 fps)
#: and event image (30 a second) of the emulated DAVIS346 (``benchmarks/results/soak.json``: the
#: one-hour soak's file, 3.0 GB) ...
LIVE_BYTES_PER_HOUR = 3.0e9
#: ... and with ``--image-rate 2`` (two frames and two event images a second; every scalar series kept):
#: 0.76 MB for 10 s of emulated live against 9.2 MB for the full file.
LIGHT_BYTES_PER_HOUR = 0.3e9
#: Runs longer than this (or without ``--duration``) are told how big their file gets.
LONG_RUN_S = 600.0


def size_warning(path, duration_s: float | None, image_rate_hz: float | None) -> str | None:
    """The line a live session with ``--save`` prints before it starts when it may run long: how fast the
    file grows, how long the disk lasts, and the bounded ways to keep a long run. None for a short run."""
    from necviz.outputs import free_bytes

    if duration_s is not None and duration_s <= LONG_RUN_S:
        return None
    light = image_rate_hz is not None
    rate = LIGHT_BYTES_PER_HOUR * max(1.0, image_rate_hz / 2) if light else LIVE_BYTES_PER_HOUR
    free = free_bytes(path)
    room = "" if free is None else f"; {free / 1e9:.1f} GB free on its disk: about {free / rate:.1f} h"
    hours = "" if duration_s is None else f" ({duration_s / 3600:.1f} h: {rate * duration_s / 3600 / 1e9:.1f} GB)"
    tip = (
        ""
        if light
        else "; to keep a long run in bounded space, --image-rate 2 keeps every series with 2 frames and "
        f"2 event images a second (~{LIGHT_BYTES_PER_HOUR / 1e9:.1f} GB an hour), and --clips DIR keeps "
        "the seconds around every failure in full"
    )
    return f"  note: --save grows about {rate / 1e9:.1f} GB an hour of live session{hours}{room}{tip}"


def parts_folder(path) -> Path:
    """Where the later segments of ``path`` go: ``<path>.parts`` beside it."""
    p = Path(path)
    return p.with_name(p.name + ".parts")


def blueprint_file(path) -> Path:
    """Where the blueprint of ``path`` waits to be joined in: ``.<name>.blueprint.rbl`` beside it."""
    p = Path(path)
    return p.with_name(f".{p.name}.blueprint.rbl")


def segment_files(path) -> list[Path]:
    """``path``, its later segments (in order) and its blueprint, as they are on disk."""
    folder = parts_folder(path)
    parts = sorted(folder.glob("*.rrd")) if folder.is_dir() else []
    bp = blueprint_file(path)
    return [Path(path), *parts, *([bp] if bp.is_file() else [])]


def rerun_program() -> list[str]:
    """The ``rerun`` command that ships with the SDK (a Python script that runs the binary)."""
    exe = Path(sys.executable).with_name("rerun")
    if exe.exists():
        return [str(exe)]
    found = shutil.which("rerun")
    return [found] if found else [sys.executable, "-m", "rerun"]


def rerun_binary() -> list[str]:
    """The ``rerun`` executable itself (``RERUN_CLI_PATH``, else the one in the ``rerun_cli`` package), else
    :func:`rerun_program`: a signal to the script would not reach the binary it runs as a child."""
    override = os.environ.get("RERUN_CLI_PATH")
    if override and os.access(override, os.X_OK):
        return [override]
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).with_name("rerun.exe" if sys.platform.startswith("win") else "rerun")
        if exe.is_file() and os.access(exe, os.X_OK):
            return [str(exe)]
    except ImportError:
        pass
    return rerun_program()


def _rerun() -> list[str]:
    return rerun_binary()


def join_segments(files: list[Path], out: Path) -> None:
    """Join the recordings ``files`` (one recording in segments, each with its footer) into ``out``
    with ``rerun rrd route``: messages copied as they are, one footer for the whole file.

    Raises
    ------
    OutputError
        ``rerun rrd route`` failed (a full disk included); ``out`` is not left behind.
    """
    from necviz.outputs import OutputError

    proc = subprocess.run(
        [*_rerun(), "rrd", "route", "-o", str(out), *map(str, files)],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    if proc.returncode != 0:
        Path(out).unlink(missing_ok=True)
        lines = [ln for ln in proc.stderr.decode(errors="replace").splitlines() if ln.strip()]
        why = lines[-1].strip() if lines else f"rerun rrd route exited with {proc.returncode}"
        raise OutputError(f"cannot join the segments of {str(files[0])!r} ({why})")


class SegmentedFile:
    """A Rerun ``--save`` file written in segments of :data:`SEGMENT_S` wall seconds (module docstring).

    Parameters
    ----------
    target : path
        Where the file is written (the first segment; later ones in :func:`parts_folder`).
    blueprint : rerun.blueprint.Blueprint, optional
        The layout, written to :func:`blueprint_file` now and joined in at the end.
    application_id : str
        The recording's application id (the blueprint applies to it).
    segment_s : float, optional
        Seconds per segment (default :data:`SEGMENT_S`).
    """

    def __init__(self, target, blueprint=None, application_id: str = "necviz", segment_s: float | None = None):
        self.target = Path(target)
        self.segment_s = float(SEGMENT_S if segment_s is None else segment_s)
        self.blueprint = None
        if blueprint is not None:
            self.blueprint = blueprint_file(self.target)
            blueprint.save(application_id, str(self.blueprint))
        self.segments: list[Path] = [self.target]
        self.files: list[Path] = [self.target]  # the segment being written (a live list: flush bounds read it)
        self._since = time.monotonic()

    @property
    def parts(self) -> Path:
        return parts_folder(self.target)

    def sink(self):
        """A Rerun file sink writing the current segment."""
        import rerun as rr

        return rr.FileSink(str(self.segments[-1]))

    def due(self) -> bool:
        return time.monotonic() - self._since >= self.segment_s

    def next(self):
        """Start the next segment; returns its file sink (the caller swaps it in)."""
        self.parts.mkdir(exist_ok=True)
        path = self.parts / f"{len(self.segments):04d}.rrd"
        self.segments.append(path)
        self.files[:] = [path]
        self._since = time.monotonic()
        return self.sink()

    def size(self) -> int:
        """Bytes written so far (every segment)."""
        total = 0
        for p in self.segments:
            try:
                total += os.path.getsize(p)
            except OSError:
                pass
        return total

    def join(self) -> None:
        """Join the segments and the blueprint into :attr:`target` (a file of one segment and no blueprint
        is left as it is); the parts are removed.

        Raises
        ------
        OutputError
            Not enough space to write the joined file, or ``rerun rrd route`` failed: the segments
            are kept and the message says where.
        """
        from necviz.outputs import OutputError, free_bytes

        files = self.segments + ([self.blueprint] if self.blueprint is not None else [])
        if len(files) == 1:
            return
        need = self.size()
        free = free_bytes(self.target)
        if free is not None and free < need + (1 << 16):
            raise OutputError(
                f"not enough space to join the {len(self.segments)} segments of {str(self.target)!r} into one file "
                f"({need >> 20} MB needed, {free >> 20} MB free): they are kept beside it; "
                f"`necviz repair {self.target}` joins them"
            )
        out = self.target.with_name(f".{self.target.name}.joining")
        try:
            join_segments(files, out)
        except OutputError as e:
            raise OutputError(
                f"{e}: the segments are kept beside it; `necviz repair {self.target}` joins them"
            ) from None
        os.replace(out, self.target)
        self.discard()
        self.segments = [self.target]
        self.files[:] = [self.target]

    def discard(self) -> None:
        """Remove the later segments and the blueprint (the first segment is the file, which its output handles)."""
        shutil.rmtree(self.parts, ignore_errors=True)
        if self.blueprint is not None:
            self.blueprint.unlink(missing_ok=True)
            self.blueprint = None


__all__ = [
    "LIGHT_BYTES_PER_HOUR",
    "LIVE_BYTES_PER_HOUR",
    "SEGMENT_S",
    "SegmentedFile",
    "blueprint_file",
    "join_segments",
    "parts_folder",
    "segment_files",
    "size_warning",
]
