"""Recorded files: readers for AEDAT 4/3.1/2.0, ROS bags, text and HDF5, and the crash-safe native recorder.

``open_recording(path)`` detects the format by content and returns a :class:`Recording` (a
:class:`~necviz.drivers.source.Source`); ``describe(path)`` summarises a file for ``necviz info``;
:class:`Recorder` writes the native format.
"""

from __future__ import annotations

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
    "describe",
    "detect_format",
    "open_recording",
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


def open_recording(
    path,
    *,
    exposure_us: float | None = None,
    start_us: int | None = None,
    end_us: int | None = None,
    format: str | None = None,
    sensor: SensorGeometry | None = None,
) -> Recording:
    """Open a recording for replay.

    ``exposure_us``: exposure (µs) for formats that do not store it (AEDAT 2.0, RPG text, HDF5, bags
    without an exposure topic); ignored where exposure is stored. ``start_us``/``end_us``: replay
    only that time range (sensor clock, µs). ``format``: skip detection (one of :data:`FORMATS`).
    ``sensor``: geometry hint for files that store none. Raises :class:`RecordingError` (and
    nothing else) for a missing, unreadable or damaged file; iterating the recording does the same
    (see :mod:`.base`).
    """
    p = Path(path)
    if not p.exists():
        raise RecordingError(f"{p}: no such file or directory")
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
