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

Layout while the run goes on: the first segment is the file itself (a run shorter than one segment
is never joined, and a crash leaves the file as it always did: readable up to its last flush,
``necviz repair`` makes it whole); later segments go to ``<file>.parts/0001.rrd``, ``0002.rrd``...
beside it. After a crash both are kept; ``necviz repair <file>`` joins them.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

#: Wall-clock seconds of one segment: the footer index a segment keeps in memory covers this long.
SEGMENT_S = 300.0


def parts_folder(path) -> Path:
    """Where the later segments of ``path`` go: ``<path>.parts`` beside it."""
    p = Path(path)
    return p.with_name(p.name + ".parts")


def segment_files(path) -> list[Path]:
    """``path`` followed by its later segments (in order), as they are on disk."""
    folder = parts_folder(path)
    parts = sorted(folder.glob("*.rrd")) if folder.is_dir() else []
    return [Path(path), *parts]


def _rerun() -> list[str]:
    from necviz.dashboard.viewer import _rerun_binary

    return _rerun_binary()


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
    segment_s : float, optional
        Seconds per segment (default :data:`SEGMENT_S`).
    """

    def __init__(self, target, segment_s: float | None = None):
        self.target = Path(target)
        self.segment_s = float(SEGMENT_S if segment_s is None else segment_s)
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
        """Join the segments into :attr:`target` (nothing to do for one segment); the parts are removed.

        Raises
        ------
        OutputError
            Not enough space to write the joined file, or ``rerun rrd route`` failed: the segments
            are kept and the message says where.
        """
        from necviz.outputs import OutputError, free_bytes

        if len(self.segments) == 1:
            return
        need = self.size()
        free = free_bytes(self.target)
        if free is not None and free < need + (16 << 20):
            raise OutputError(
                f"not enough space to join the {len(self.segments)} segments of {str(self.target)!r} into one file "
                f"({need >> 20} MB needed, {free >> 20} MB free): they are kept in {str(self.target)!r} and "
                f"{str(self.parts)!r}; `necviz repair {self.target}` joins them"
            )
        out = self.target.with_name(f".{self.target.name}.joining")
        try:
            join_segments(self.segments, out)
        except OutputError as e:
            raise OutputError(f"{e}: the segments are kept in {str(self.parts)!r}") from None
        os.replace(out, self.target)
        shutil.rmtree(self.parts, ignore_errors=True)
        self.segments = [self.target]
        self.files[:] = [self.target]

    def discard(self) -> None:
        """Remove the later segments (the first is the file, which its output handles)."""
        shutil.rmtree(self.parts, ignore_errors=True)


__all__ = ["SEGMENT_S", "SegmentedFile", "join_segments", "parts_folder", "segment_files"]
