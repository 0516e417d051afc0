"""Recorded files: readers for AEDAT 4/3.1/2.0, ROS bags, text and HDF5, and the crash-safe native recorder.

``open_recording(path)`` detects the format by content and returns a :class:`Recording` (a
:class:`~necviz.drivers.source.Source`); ``describe(path)`` summarises a file for ``necviz info``;
:class:`Recorder` writes the native format.
"""

from __future__ import annotations

import os
import select
import stat
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

from necviz.core.errors import NecvizError
from necviz.core.sensor import SensorGeometry
from necviz.drivers.recordings.detect import FORMATS, SUPPORTED, detect_format
from necviz.drivers.recordings.native import NativeRecording, Recorder
from necviz.drivers.recordings.reader import Recording, RecordingError, StreamAssembler, first_line, is_damage, reason
from necviz.drivers.recordings.summary import RecordingInfo, describe

__all__ = [
    "FORMATS",
    "SUPPORTED",
    "Recorder",
    "Recording",
    "RecordingError",
    "RecordingInfo",
    "StreamAssembler",
    "check_source",
    "describe",
    "detect_format",
    "open_recording",
    "readable_copy",
    "spool_pipe",
]


def _reader(fmt: str):
    if fmt == "necviz":
        return NativeRecording
    if fmt == "aedat4":
        from necviz.drivers.recordings.aedat4 import Aedat4Recording

        return Aedat4Recording
    if fmt == "aedat3":
        from necviz.drivers.recordings.aedat3 import Aedat3Recording

        return Aedat3Recording
    if fmt == "aedat2":
        from necviz.drivers.recordings.aedat2 import Aedat2Recording

        return Aedat2Recording
    if fmt in ("rosbag1", "rosbag2"):
        from necviz.drivers.recordings.rosbag import RosbagRecording

        return RosbagRecording
    if fmt == "hdf5":
        from necviz.drivers.recordings.hdf5 import open_hdf5

        return open_hdf5
    if fmt == "rpg-text":
        from necviz.drivers.recordings.text import RpgTextRecording

        return RpgTextRecording
    raise RecordingError(f"unknown format name {fmt!r}; choose one of {', '.join(FORMATS)}")


def check_source(path) -> str:
    """What ``path`` is, checked before anything opens it: ``"file"``, ``"folder"`` or ``"pipe"``.

    Raises :class:`RecordingError` (one line) for a missing path, a symbolic link loop, a device or
    a socket. A named pipe is returned as ``"pipe"``: readers refuse it unless asked (opening one
    waits for a writer for ever), see :func:`open_recording`.
    """
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise RecordingError(f"{p}: no such file or directory") from None
    except OSError as exc:  # a symbolic link loop, a path through a file, a name too long
        raise RecordingError(f"{p}: cannot open ({exc.strerror or exc})") from None
    if stat.S_ISREG(st.st_mode):
        return "file"
    if stat.S_ISDIR(st.st_mode):
        return "folder"
    if stat.S_ISFIFO(st.st_mode):
        return "pipe"
    kind = "a character device" if stat.S_ISCHR(st.st_mode) else "a block device"
    kind = "a socket" if stat.S_ISSOCK(st.st_mode) else kind
    raise RecordingError(f"{p}: {kind}, not a recording file")


#: Largest recording copied from a named pipe (``pipe_timeout_s``).
MAX_PIPE_BYTES = 64 << 30


def spool_pipe(path, timeout_s: float, folder=None) -> Path:
    """Copy what a named pipe delivers into a temporary file (deleted by the caller) and return it.

    Waits at most ``timeout_s`` seconds for a writer and then between two reads; the copy ends when
    the writer closes the pipe. Raises :class:`RecordingError` when nothing arrives in time, when
    more than :data:`MAX_PIPE_BYTES` arrive, or when the copy cannot be written.
    """
    p = Path(path)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as exc:
        raise RecordingError(f"{p}: cannot open the pipe ({exc.strerror or exc})") from None
    out = tempfile.NamedTemporaryFile(prefix="necviz-pipe-", suffix=p.suffix, dir=folder, delete=False)
    total, started, deadline = 0, False, time.monotonic() + timeout_s
    try:
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                what = "no data" if not total else f"no more data after {total:,} bytes"
                raise RecordingError(f"{p}: {what} from the named pipe within {timeout_s:g} s")
            ready, _, _ = select.select([fd], [], [], min(left, 0.5))
            if not ready:
                continue
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                if started or total:
                    break  # the writer closed the pipe
                time.sleep(0.05)  # no writer yet (a FIFO without writer reads as end of file)
                continue
            started = True
            total += len(chunk)
            if total > MAX_PIPE_BYTES:
                raise RecordingError(f"{p}: more than {MAX_PIPE_BYTES >> 30} GiB from the named pipe")
            out.write(chunk)
            deadline = time.monotonic() + timeout_s
        out.close()
        return Path(out.name)
    except BaseException as exc:
        out.close()
        os.unlink(out.name)
        if isinstance(exc, OSError):
            raise RecordingError(f"{p}: cannot copy the named pipe ({exc.strerror or exc})") from None
        raise
    finally:
        os.close(fd)


#: What a named pipe given without ``--pipe-timeout`` is told.
PIPE_REFUSED = (
    "a named pipe, not a regular file (reading one waits for a writer for ever); "
    "pass --pipe-timeout S to copy what it delivers"
)


@contextmanager
def readable_copy(path, pipe_timeout_s: float | None):
    """``path`` itself, or — a named pipe with ``pipe_timeout_s`` — a temporary copy of what it
    delivers (:func:`spool_pipe`), removed when the block ends; a pipe without a timeout is refused
    (readers that open a file twice, as a cut does, cannot read a pipe)."""
    p = Path(path)
    if check_source(p) != "pipe":
        yield p
        return
    if pipe_timeout_s is None:
        raise RecordingError(f"{p}: {PIPE_REFUSED}")
    copy = spool_pipe(p, pipe_timeout_s)
    try:
        yield copy
    finally:
        copy.unlink(missing_ok=True)


def open_recording(
    path,
    *,
    exposure_us: float | None = None,
    start_us: int | None = None,
    end_us: int | None = None,
    format: str | None = None,
    sensor: SensorGeometry | None = None,
    pipe_timeout_s: float | None = None,
) -> Recording:
    """Open a recording for replay (the format detected from its content).

    Parameters
    ----------
    path : path
        The file (or, for the RPG text format, its folder).
    exposure_us : float, optional
        Exposure (µs) for formats that do not store it (AEDAT 2.0, RPG text, HDF5, bags without an
        exposure topic); ignored where exposure is stored.
    start_us, end_us : int, optional
        Replay only that time range (sensor clock, µs).
    format : str, optional
        Skip detection (one of :data:`FORMATS`).
    sensor : SensorGeometry, optional
        Geometry hint for files that store none.
    pipe_timeout_s : float, optional
        Accept a named pipe (refused otherwise): its data are copied to a temporary file first
        (:func:`spool_pipe`), waiting at most that long for them.

    Returns
    -------
    Recording
        A :class:`~necviz.drivers.source.Source`; iterating it yields the packets in stream order.

    Raises
    ------
    RecordingError
        (and nothing else) a missing, unreadable or damaged file; iterating the recording does the
        same, after delivering everything before the damage.
    """
    p = Path(path)
    kind = check_source(p)
    spooled = None
    if kind == "pipe":
        if pipe_timeout_s is None:
            raise RecordingError(f"{p}: {PIPE_REFUSED}")
        spooled = spool_pipe(p, pipe_timeout_s)
        p = spooled
    try:
        rec = _open(p, exposure_us, start_us, end_us, format, sensor)
    except BaseException:
        if spooled is not None:
            spooled.unlink(missing_ok=True)
        raise
    if spooled is not None:
        rec.warn(f"read from the named pipe {path} through a temporary copy")
        _unlink_on_close(rec, spooled)
    return rec


def _unlink_on_close(rec: Recording, path: Path) -> None:
    close = rec.close

    def closing():
        try:
            close()
        finally:
            path.unlink(missing_ok=True)

    rec.close = closing


def _open(p: Path, exposure_us, start_us, end_us, format, sensor) -> Recording:
    if p.is_file() and p.stat().st_size == 0:
        raise RecordingError(f"{p}: empty file (0 bytes)")
    fmt = format or detect_format(p)
    cls = _reader(fmt)
    try:
        return cls(p, exposure_us=exposure_us, start_us=start_us, end_us=end_us, sensor=sensor)
    except RecordingError:
        raise
    except OSError as exc:
        if exc.strerror:  # the OS refused (permissions, a folder where a file was expected ...)
            raise RecordingError(f"{p}: cannot read ({exc.strerror})") from None
        raise RecordingError(f"{p}: unreadable {fmt} file ({reason(exc)})") from None
    except BaseException as exc:
        if isinstance(exc, NecvizError):  # e.g. an impossible sensor size read from the file
            raise RecordingError(f"{p}: unreadable {fmt} file ({first_line(exc) or type(exc).__name__})") from None
        if not is_damage(exc):
            raise
        raise RecordingError(f"{p}: unreadable {fmt} file ({reason(exc)})") from None
