"""Export a recording (any format the readers accept) to the formats other tools read.

The output format is chosen by the file's suffix (:data:`WRITERS`):

* ``.aedat4`` — AEDAT 4.0 as iniVation's DV writes it: events, frames with exposure begin/end, IMU,
  triggers (:mod:`necviz.writers.aedat4_writer`);
* ``.h5`` / ``.hdf5`` — the DSEC event layout (``/events/t,x,y,p``) plus frames with their exposure
  intervals, IMU and triggers (:mod:`necviz.writers.hdf5_writer`);
* ``.npz`` — one structured event array, frames, exposures, IMU, triggers (:mod:`necviz.writers.npz_writer`);
* ``.necrec`` — a clip in necviz's native format (:class:`~necviz.drivers.recordings.native.Recorder`),
  with the commands and annotations of a native input kept.

:func:`export_recording` streams the packets of an open :class:`~necviz.drivers.recordings.Recording`
(already restricted to a time range) into a writer; memory does not grow with the recording.
Every file is written through :func:`written`: beside the target under a temporary name, renamed
into place only when complete, removed on any failure.
"""

from __future__ import annotations

import os
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

from necviz.core.errors import ParameterError
from necviz.core.events import EventBatch
from necviz.core.frames import Frame
from necviz.core.imu import ImuBatch, TriggerBatch
from necviz.outputs import write_failed
from necviz.pipeline import packet_time_us

#: Output suffix -> format name.
WRITERS = {".aedat4": "aedat4", ".h5": "hdf5", ".hdf5": "hdf5", ".npz": "npz", ".necrec": "necviz"}
SUFFIXES = tuple(WRITERS)


class Pending:
    """An output being written: a temporary file beside ``path`` (:attr:`tmp`) that :meth:`commit`
    renames over ``path`` and :meth:`abort` deletes, so nothing half-written is ever under the name.

    With :func:`written`, the one place export, clip and video output is created (the atomic-output
    helper of :mod:`necviz.outputs` can take its place without touching the writers)."""

    def __init__(self, path):
        self.path = Path(path)
        parent = self.path.parent if str(self.path.parent) else Path(".")
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.stem}.", suffix=f".partial{self.path.suffix}", dir=parent)
        os.close(fd)
        os.chmod(tmp, 0o644)  # as any new file (mkstemp makes it private)
        self.tmp = Path(tmp)

    def commit(self) -> None:
        os.replace(self.tmp, self.path)

    def abort(self) -> None:
        try:
            os.unlink(self.tmp)
        except OSError:
            pass


@contextmanager
def written(path):
    """Yield a temporary path beside ``path``; rename it over ``path`` when the block succeeds, delete it
    when it fails (:class:`Pending`)."""
    pending = Pending(path)
    try:
        yield pending.tmp
        pending.commit()
    except BaseException:
        pending.abort()
        raise


class _NativeWriter:
    """The native recorder with the writers' interface (``counts``)."""

    def __init__(self, path, sensor, *, properties: dict | None = None, compression: str = "zstd"):
        from necviz.drivers.recordings.native import Recorder

        props = {k: str(v) for k, v in (properties or {}).items()}
        self.recorder = Recorder(path, sensor=sensor, properties=props, compression=compression)
        self.counts = {"events": 0, "frames": 0, "imu": 0, "triggers": 0, "commands": 0, "annotations": 0}

    def write(self, packet) -> None:
        self.recorder.write(packet)
        match packet:
            case Frame():
                self.counts["frames"] += 1
            case ImuBatch():
                self.counts["imu"] += len(packet)
            case TriggerBatch():
                self.counts["triggers"] += len(packet)
            case EventBatch():
                self.counts["events"] += len(packet)

    def command(self, record) -> None:
        self.recorder.command(record)
        self.counts["commands"] += 1

    def annotate(self, t_us: int, data: dict) -> None:
        self.recorder.annotate(t_us, data)
        self.counts["annotations"] += 1

    def close(self) -> None:
        self.recorder.close()


#: Packet compression by format when none is asked for (the formats that take ``--compression``).
DEFAULT_COMPRESSION = {"aedat4": "lz4", "necviz": "zstd"}


def check_compression(fmt: str, compression: str | None) -> str | None:
    """The compression a writer of ``fmt`` uses: ``compression``, or the format's default.

    Raises
    ------
    ParameterError
        ``compression`` given for a format that has its own (``.h5``: gzip; ``.npz``: deflate).
    """
    if fmt not in DEFAULT_COMPRESSION:
        if compression is not None:
            suffix = {"hdf5": ".h5", "npz": ".npz"}.get(fmt, fmt)
            own = {"hdf5": "gzip with shuffle", "npz": "deflate"}.get(fmt, "its own")
            raise ParameterError(
                f"--compression applies to .aedat4 and .necrec; {suffix} is always compressed with {own}"
            )
        return None
    return compression or DEFAULT_COMPRESSION[fmt]


def write_failure(exc: BaseException) -> BaseException | None:
    """The OS error behind a failed write (a full disk, a file too large, an I/O error), or None when
    ``exc`` is something else: a writer's own OSError, or the native recorder's error for one."""
    from necviz.drivers.recordings.native import WriteError

    if isinstance(exc, WriteError):
        return exc.cause or exc
    if isinstance(exc, OSError) and not isinstance(exc, (FileNotFoundError, PermissionError)):
        return exc
    return None


def open_writer(
    fmt: str,
    path,
    sensor,
    *,
    properties: dict | None = None,
    compression: str | None = None,
    camera_name: str | None = None,
):
    """A writer for format ``fmt`` (a :data:`WRITERS` value) creating ``path``: ``write(packet)``, ``close()``,
    ``counts``. ``camera_name``: the camera the input names (AEDAT 4's ``source``, kept in the output).

    Raises
    ------
    ParameterError
        For an unknown format or compression.
    """
    compression = check_compression(fmt, compression)
    if fmt == "aedat4":
        from necviz.writers.aedat4_writer import Aedat4Writer

        return Aedat4Writer(path, sensor, compression=compression, source=camera_name)
    if fmt == "hdf5":
        from necviz.writers.hdf5_writer import Hdf5Writer

        return Hdf5Writer(path, sensor, properties=properties)
    if fmt == "npz":
        from necviz.writers.npz_writer import NpzWriter

        return NpzWriter(path, sensor, properties=properties)
    if fmt == "necviz":
        return _NativeWriter(path, sensor, properties=properties, compression=compression)
    raise ParameterError(f"unknown export format {fmt!r}; choose one of {', '.join(sorted(set(WRITERS.values())))}")


def format_for(path) -> str:
    """The export format of an output path, by its suffix.

    Raises
    ------
    ParameterError
        When the suffix is not one of :data:`SUFFIXES`.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in WRITERS:
        raise ParameterError(
            f"OUT must end in {', '.join(SUFFIXES)} (the format is chosen by the suffix), got {str(path)!r}"
        )
    return WRITERS[suffix]


def export_recording(
    recording, out, *, compression: str | None = None, properties: dict | None = None, progress=None
) -> dict:
    """Write every packet of ``recording`` to ``out`` in the format its suffix names.

    Parameters
    ----------
    recording : an open :class:`~necviz.drivers.recordings.Recording` (restricted to the range to export).
    out : the output path (checked beforehand with :func:`necviz.outputs.check_output`).
    compression : packet compression of ``.aedat4`` (default ``"lz4"``) and ``.necrec`` (default
        ``"zstd"``): ``"lz4"``, ``"zstd"`` or ``"none"``; refused for the other formats.
    properties : run metadata stored where the format has room (native header, HDF5 attributes).
    progress : ``progress(events, frames, seconds)`` called now and then.

    Returns
    -------
    dict
        ``{"format", "path", "counts": {"events", "frames", "imu", "triggers", ...}, "first_us", "last_us",
        "wall_s"}``.

    Raises
    ------
    ParameterError
        When the range holds nothing (no file is left behind).
    RecordingError
        When the input is damaged (nothing is left behind either).
    """
    fmt = format_for(out)
    wall0 = time.perf_counter()
    first = last = None
    existed = os.path.lexists(out)
    with written(out) as tmp:
        camera = recording.camera_name
        props = {**(properties or {}), **({"camera_name": camera} if camera else {})}
        writer = open_writer(fmt, tmp, recording.sensor, properties=props, compression=compression, camera_name=camera)
        try:
            next_report = 0.0
            for packet in recording:
                t = packet_time_us(packet)
                if t is not None:
                    first = t if first is None else first
                    last = t
                writer.write(packet)
                if progress is not None and time.perf_counter() >= next_report:
                    next_report = time.perf_counter() + 0.5
                    c = writer.counts
                    progress(c["events"], c["frames"], 0.0 if first is None else (last - first) / 1e6)
            if fmt == "necviz":  # a native input's commands and annotations, within the range
                for rec in recording.commands:
                    if recording.in_range(int(rec.issue_time_us)):
                        writer.command(rec)
                for t_us, data in recording.annotations:
                    if recording.in_range(int(t_us)):
                        writer.annotate(int(t_us), data)
            writer.close()
        except BaseException as e:
            try:
                writer.close()  # whatever it raises now (the same full disk) is not the error to report
            except BaseException:  # noqa: BLE001
                pass
            cause = write_failure(e)
            if cause is not None:  # a full disk, a file too large: one line, and the partial file is removed
                raise write_failed(out, cause, existed) from None
            raise
        c = writer.counts
        if not (c["events"] or c["frames"] or c["imu"] or c["triggers"]):
            raise ParameterError(f"nothing to export from {recording.path.name} in the selected range")
    return {
        "format": fmt,
        "path": str(out),
        "counts": dict(writer.counts),
        "first_us": first,
        "last_us": last,
        "wall_s": time.perf_counter() - wall0,
    }


__all__ = ["Pending", "SUFFIXES", "WRITERS", "export_recording", "format_for", "open_writer", "written"]
