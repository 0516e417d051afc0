"""necviz's own recording format (``.necrec``): a crash-safe, append-only log of what a source produced.

Written by :class:`Recorder` (``necviz live/demo --record FILE``), read by :class:`NativeRecording`.

Layout (all integers little-endian)::

    file    := magic chunk*
    magic   := b"NECVIZ-REC\\x00" (11 bytes)  version:u8 (2; version 1 files are read too)
    chunk   := type:u8  length:u32  crc32:u32  payload[length]      (crc32 = zlib.crc32(payload))

The first chunk is the header; then chunks follow in the order the source yielded the packets
(stream order), so a reader replays them as they are:

    type 1 HEADER      UTF-8 JSON object: {"format": "necviz-recording", "version": 2,
                       "sensor": {"width", "height", "name"}, "properties": {...run metadata...},
                       "compression": "zstd" | "lz4" | "none", "created_utc": ISO-8601 string}
    type 2 EVENTS      t_first:i64 (µs), n:u32, codec:u8, dt_bytes:u8, then ``codec`` applied to the
                       columns (each byte-shuffled: byte k of every value, then byte k+1 ...):
                       dt (t[i] - t[i-1], dt[0] = 0, as unsigned ints of dt_bytes bytes), x:u16,
                       y:u16, p:i8
                       (at most 1,048,576 events per chunk, time-sorted)
                       [version 1: n packed records of 13 bytes: t:i64, x:u16, y:u16, p:i8]
    type 3 MARKER      t:i64 (µs), kind:u8 (0 exposure start, 1 exposure end)
    type 4 FRAME       exposure_start:i64 (µs), exposure_end:i64 (µs), gain:f64 (linear, >= 1),
                       sequence:i64, height:u16, width:u16, codec:u8, then ``codec`` applied to the
                       height*width uint8 pixels as differences along each row (p[y, x] - p[y, x-1]
                       modulo 256, the first of a row as is), row-major, (0,0) top-left
                       [version 1: no codec byte, the pixels as they are]
    type 5 IMU         n records of 36 bytes: t:i64 (µs), ax, ay, az (g), gx, gy, gz (°/s), temp (°C): f32
    type 6 TRIGGERS    n records of 9 bytes: t:i64 (µs), kind:i8 (index into core.imu.TRIGGER_KINDS)
    type 7 COMMAND     issue_time:i64 (µs), exposure:f64 (µs), gain:f64 (linear), has_applied:u8,
                       applied_start:i64 (µs; meaningful when has_applied = 1)
    type 8 ANNOTATION  t:i64 (µs), then a UTF-8 JSON object (e.g. a live parameter change)
    type 9 END         empty; written by a clean close

Codecs: 0 none, 1 LZ4 (block format, the uncompressed size first as a u32), 2 Zstandard (one frame)
— the compressors AEDAT 4 uses for its packets. Every chunk is compressed on its own, so the file
stays an append-only sequence of self-contained chunks. Default zstd (level 1): on the emulated
live stream (2.7 Mev/s, 50 fps) events take 2.6 bytes each instead of 13 and frames ~60 % of their
pixels (``benchmarks/recording_size.py``).

Crash safety: chunks are only ever appended. The writer keeps chunks in memory, a background thread
encodes them (the compression stays off the control path) and hands whole 64 KiB blocks to the OS as
they fill and everything at least every 0.25 s of wall time; ``close`` writes the END chunk and calls
``os.fsync``. After a crash (process killed, cable pulled) the file is a valid prefix up to the last
flush, possibly ending inside a chunk; the reader replays every complete chunk and reports the
incomplete tail as a warning. A file without END (killed exactly between chunks) is also replayed
completely, with a warning. A CRC mismatch, an unknown chunk type or a chunk that does not decode
before the last chunk is damage: the reader yields everything before it and raises
:class:`RecordingError`. A full disk stops the writer: the error is kept and raised by the next
call, and what was written before stays readable.

Seeking (``start_us``/``end_us``): a forward scan of the chunk headers (reading only the first
9-17 bytes of each chunk and seeking over payloads) builds an index of chunk offsets and times.
"""

from __future__ import annotations

import datetime as _dt
import functools
import json
import os
import struct
import threading
import time
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from necviz.core.errors import NecvizError
from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import IMU_DTYPE, TRIGGER_DTYPE, ImuBatch, TriggerBatch
from necviz.core.sensor import SensorGeometry
from necviz.drivers.recordings.reader import Recording, RecordingError, first_line
from necviz.drivers.source import CommandRecord

MAGIC = b"NECVIZ-REC\x00"
VERSION = 2
READS = (1, 2)
PREAMBLE = len(MAGIC) + 1
CHUNK_HEAD = struct.Struct("<BII")
HEADER, EVENTS, MARKER, FRAME, IMU, TRIGGERS, COMMAND, ANNOTATION, END = range(1, 10)
_NAMES = {
    HEADER: "header",
    EVENTS: "events",
    MARKER: "marker",
    FRAME: "frame",
    IMU: "IMU",
    TRIGGERS: "triggers",
    COMMAND: "command",
    ANNOTATION: "annotation",
    END: "end",
}
MARKER_S = struct.Struct("<qB")
FRAME_S = struct.Struct("<qqdqHH")
COMMAND_S = struct.Struct("<qddBq")
T_S = struct.Struct("<q")
EVENTS_S = struct.Struct("<qIBB")
MAX_EVENTS_PER_CHUNK = 1 << 20
BLOCK = 1 << 16
FLUSH_S = 0.25
#: Bytes of chunks waiting for the encoding thread before :meth:`Recorder.write` waits for it.
MAX_QUEUED = 64 << 20
#: ``--compression`` names -> codec ids.
CODECS = {"none": 0, "lz4": 1, "zstd": 2}
#: How far before ``start_us`` a ranged read starts (see ``NativeRecording._first_offset``).
SEEK_MARGIN_US = 1_000_000
#: Longest run of zero bytes accepted as the lost tail of a crash (see ``NativeRecording._zeros_to_end``).
ZERO_TAIL = 16 << 20
_PACKED_EVENTS = np.dtype(
    {"names": ["t", "x", "y", "p"], "formats": ["<i8", "<u2", "<u2", "i1"], "offsets": [0, 8, 10, 12], "itemsize": 13}
)
assert EVENT_DTYPE.itemsize == 13 and _PACKED_EVENTS == EVENT_DTYPE


class WriteError(RecordingError):
    """The recording could not be written (a full disk, a file too large); ``cause`` is the OS error."""

    def __init__(self, message: str, cause: OSError | None = None):
        super().__init__(message)
        self.cause = cause
        self.strerror = cause.strerror if cause is not None else None


def _chunk(kind: int, payload: bytes) -> bytes:
    return CHUNK_HEAD.pack(kind, len(payload), zlib.crc32(payload)) + payload


@functools.cache
def _zstd():
    """The Zstandard module (looked up once: a failed import is not cached by Python and costs ~0.2 ms)."""
    try:  # the standard library from Python 3.14, its backport before
        from compression import zstd
    except ImportError:
        from backports import zstd
    return zstd


def compress(codec: int, data: bytes) -> bytes:
    """``data`` compressed with ``codec`` (:data:`CODECS`)."""
    if codec == 0:
        return bytes(data)
    if codec == 1:
        import lz4.block

        return lz4.block.compress(data, store_size=True)
    return _zstd().compress(data, 1)


def decompress(codec: int, data, size: int) -> bytes:
    """The ``size`` bytes ``data`` holds in ``codec``; ValueError when it does not decode to that."""
    if codec == 0:
        out = bytes(data)
    elif codec == 1:
        import lz4.block

        try:
            out = lz4.block.decompress(bytes(data))
        except lz4.block.LZ4BlockError as exc:
            raise ValueError(f"LZ4 data do not decode ({exc})") from None
    elif codec == 2:
        zstd = _zstd()
        try:
            out = zstd.decompress(bytes(data))
        except zstd.ZstdError as exc:
            raise ValueError(f"zstd data do not decode ({exc})") from None
    else:
        raise ValueError(f"unknown codec {codec}")
    if len(out) != size:
        raise ValueError(f"decoded {len(out)} bytes where {size} were stored")
    return out


def _shuffle(a: np.ndarray) -> bytes:
    """Byte k of every value, then byte k+1 ...: the slowly changing high bytes become long runs."""
    b = np.ascontiguousarray(a).view(np.uint8).reshape(a.size, a.dtype.itemsize)
    return np.ascontiguousarray(b.T).tobytes()


def _unshuffle(data, n: int, dtype) -> np.ndarray:
    dtype = np.dtype(dtype)
    b = np.frombuffer(data, np.uint8, n * dtype.itemsize).reshape(dtype.itemsize, n)
    return np.ascontiguousarray(b.T).view(dtype).reshape(n)


def encode_events(ev: np.ndarray, codec: int) -> bytes:
    """An EVENTS chunk's payload (version 2; module docstring)."""
    t = ev["t"]
    dt = np.diff(t, prepend=t[:1])
    top = int(dt.max()) if dt.size else 0
    if dt.size and int(dt.min()) < 0:  # not time-sorted: full 64-bit steps (wrapping) keep it exact
        top = 1 << 62
    width = 1 if top < 1 << 8 else 2 if top < 1 << 16 else 4 if top < 1 << 32 else 8
    body = (
        _shuffle(dt.astype(f"<u{width}"))
        + _shuffle(ev["x"].astype("<u2"))
        + _shuffle(ev["y"].astype("<u2"))
        + ev["p"].astype(np.int8).tobytes()
    )
    return EVENTS_S.pack(int(t[0]), ev.size, codec, width) + compress(codec, body)


def decode_events(data) -> np.ndarray:
    """The events of a version 2 EVENTS payload (ValueError when it is malformed)."""
    t0, n, codec, width = EVENTS_S.unpack_from(data)
    if width not in (1, 2, 4, 8):
        raise ValueError(f"time step width {width}")
    size = n * (width + 5)
    body = decompress(codec, memoryview(data)[EVENTS_S.size :], size)
    ev = np.empty(n, EVENT_DTYPE)
    dt = _unshuffle(body, n, f"<u{width}").astype(np.int64)
    dt[0] = 0
    ev["t"] = t0 + np.cumsum(dt)
    o = n * width
    ev["x"] = _unshuffle(body[o:], n, "<u2")
    ev["y"] = _unshuffle(body[o + 2 * n :], n, "<u2")
    ev["p"] = np.frombuffer(body, np.int8, n, o + 4 * n)
    return ev


def encode_pixels(image: np.ndarray, codec: int) -> bytes:
    """A frame's pixels as row differences (modulo 256) compressed with ``codec`` (codec byte first)."""
    img = np.ascontiguousarray(image, np.uint8)
    diff = img.copy()
    diff[:, 1:] -= img[:, :-1]
    return bytes([codec]) + compress(codec, diff.tobytes())


def decode_pixels(data, h: int, w: int) -> np.ndarray:
    codec = data[0]
    diff = np.frombuffer(decompress(codec, memoryview(data)[1:], h * w), np.uint8).reshape(h, w)
    return np.cumsum(diff, axis=1, dtype=np.uint8)


class Recorder:
    """Append what a source produced to a crash-safe native recording (layout in the module docstring).

    ``Recorder(path, sensor=..., properties={...}, compression="zstd")``; :meth:`write` takes any
    stream packet (event batch, ExposureMarker, Frame, ImuBatch, TriggerBatch), :meth:`command` an
    issued exposure command, :meth:`annotate` a timestamped JSON-able dict. The calls only queue the
    chunk: a background thread compresses and writes, and data reach the OS at least every 0.25 s of
    wall time; :meth:`close` (idempotent; also on leaving a ``with`` block) ends the file and fsyncs it.

    Raises
    ------
    RecordingError
        An unknown compression, properties that are not JSON, a file that cannot be created or
        written (a full disk: raised by the call after the failed write, and by every later one).
    """

    def __init__(self, path, *, sensor: SensorGeometry, properties: dict | None = None, compression: str = "zstd"):
        self.path = Path(path)
        self.sensor = sensor
        if compression not in CODECS:
            raise RecordingError(f"compression must be one of {', '.join(CODECS)}, got {compression!r}")
        self.codec = CODECS[compression]
        header = {
            "format": "necviz-recording",
            "version": VERSION,
            "sensor": {"width": sensor.width, "height": sensor.height, "name": sensor.name},
            "properties": dict(properties or {}),
            "compression": compression,
            "created_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        }
        try:
            payload = json.dumps(header, default=str).encode()
        except (TypeError, ValueError) as exc:
            raise RecordingError(f"{self.path}: recording properties are not JSON-serialisable ({exc})") from None
        try:
            self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        except OSError as exc:
            raise RecordingError(f"{self.path}: cannot create recording ({exc.strerror})") from None
        self._queue: list = []  # (type, encode, args): chunks waiting for the encoding thread
        self._queued = 0  # their raw bytes
        self._cond = threading.Condition()
        self._io = threading.Lock()  # one writer of the file at a time
        self._buf = bytearray()  # encoded chunks not yet handed to the OS (the encoding thread's)
        self._closed = False
        self._error: WriteError | None = None  # a failed write (full disk): raised by every later call
        self.bytes_written = 0
        self.raw_bytes = 0  # what the chunks would take uncompressed (version 1)
        try:
            self._write_all(MAGIC + bytes([VERSION]) + _chunk(HEADER, payload))
        except RecordingError:
            os.close(self._fd)
            raise
        self._thread = threading.Thread(target=self._encoder, name="necviz-recorder", daemon=True)
        self._thread.start()

    # -- low level -----------------------------------------------------------------------------
    def _write_all(self, data) -> None:
        """Write ``data`` to the file; an OS error (a full disk) becomes the recorder's
        :class:`RecordingError`, raised now and by every later call."""
        if self._error is not None:
            raise self._error
        try:
            with memoryview(data) as view:
                while view:
                    n = os.write(self._fd, view)
                    view = view[n:]
                    self.bytes_written += n
        except OSError as exc:
            self._error = WriteError(f"{self.path}: cannot write the recording ({exc.strerror or exc})", exc)
            raise self._error from None

    def _append(self, kind: int, encode, *args, raw: int = 0) -> None:
        """Queue a chunk: ``encode(*args)`` gives its payload (called on the encoding thread)."""
        with self._cond:
            if self._closed:
                raise RecordingError(f"{self.path}: recorder is closed")
            if self._error is not None:
                raise self._error
            while self._queued > MAX_QUEUED and self._error is None and self._thread.is_alive():
                self._cond.wait(0.05)  # the encoder is behind: wait for it (bounded memory)
            self._queue.append((kind, encode, args))
            self._queued += raw
            self.raw_bytes += raw
            if self._queued >= BLOCK:
                self._cond.notify()

    def _encode_pending(self) -> None:
        """Encode what is queued and write the whole blocks (the encoding thread, or close)."""
        with self._io:  # held while taking the queue too: chunks are written in the order they came
            with self._cond:
                items, self._queue = self._queue, []
                self._queued = 0
                self._cond.notify_all()
            for kind, encode, args in items:
                self._buf += _chunk(kind, encode(*args) if encode is not None else args[0])
                if len(self._buf) >= BLOCK:
                    self._flush_buf(whole_blocks=True)

    def _flush_buf(self, whole_blocks: bool = False) -> None:
        n = len(self._buf) // BLOCK * BLOCK if whole_blocks else len(self._buf)
        if n:
            self._write_all(bytes(self._buf[:n]))  # a copy: no view of the buffer outlives a failed write
            del self._buf[:n]

    def _encoder(self) -> None:
        last_flush = time.monotonic()
        while True:
            with self._cond:
                if not self._closed and self._queued < BLOCK:
                    self._cond.wait(FLUSH_S / 2)
                if self._closed:
                    return
            try:
                self._encode_pending()
                if time.monotonic() - last_flush >= FLUSH_S / 2:
                    with self._io:
                        self._flush_buf()
                    last_flush = time.monotonic()
            except RecordingError:  # kept in self._error: the writer's next call raises it
                with self._cond:
                    self._queue.clear()
                    self._queued = 0
                    self._cond.notify_all()
                return

    # -- public --------------------------------------------------------------------------------
    def write(self, packet) -> None:
        """Append one stream packet (an :class:`~necviz.core.events.EventBatch`, marker, frame, IMU or triggers)."""
        match packet:
            case EventBatch(events=ev):
                if ev.dtype != EVENT_DTYPE or ev.ndim != 1:
                    raise RecordingError(
                        f"{self.path}: cannot record an array of dtype {ev.dtype} (expected an EVENT_DTYPE event batch)"
                    )
                for i in range(0, ev.size, MAX_EVENTS_PER_CHUNK):
                    part = ev[i : i + MAX_EVENTS_PER_CHUNK]
                    if part.size:
                        self._append(EVENTS, encode_events, part, self.codec, raw=part.nbytes)
            case ExposureMarker():
                self._append(MARKER, None, MARKER_S.pack(int(packet.t_us), 0 if packet.kind == "start" else 1))
            case Frame():
                h, w = packet.image.shape
                head = FRAME_S.pack(
                    int(packet.exposure_start_us),
                    int(packet.exposure_end_us),
                    float(packet.gain),
                    int(packet.sequence),
                    h,
                    w,
                )
                self._append(
                    FRAME, lambda hd, img, c: hd + encode_pixels(img, c), head, packet.image, self.codec, raw=h * w
                )
            case ImuBatch():
                self._append(IMU, None, np.ascontiguousarray(packet.samples, dtype=IMU_DTYPE).tobytes())
            case TriggerBatch():
                self._append(TRIGGERS, None, np.ascontiguousarray(packet.triggers, dtype=TRIGGER_DTYPE).tobytes())
            case _:
                raise RecordingError(f"{self.path}: cannot record a {type(packet).__name__} packet")

    def command(self, record: CommandRecord) -> None:
        """Append an exposure command (issue time µs, exposure µs, linear gain, applied start µs)."""
        applied = record.applied_start_us
        self._append(
            COMMAND,
            None,
            COMMAND_S.pack(
                int(record.issue_time_us),
                float(record.exposure_us),
                float(record.gain),
                applied is not None,
                0 if applied is None else int(applied),
            ),
        )

    def annotate(self, t_us: int, data: dict) -> None:
        """Append a timestamped note (a JSON-serialisable dict), e.g. a live parameter change."""
        try:
            text = json.dumps(data, default=str).encode()
        except (TypeError, ValueError) as exc:
            raise RecordingError(f"{self.path}: annotation is not JSON-serialisable ({exc})") from None
        self._append(ANNOTATION, None, T_S.pack(int(t_us)) + text)

    def flush(self) -> None:
        """Encode everything queued and hand it to the OS (no fsync)."""
        with self._cond:
            if self._closed:
                return
            if self._error is not None:
                raise self._error
        self._encode_pending()
        with self._io:
            self._flush_buf()

    def close(self) -> None:
        """Write what is queued and the END chunk, flush, fsync and close (idempotent).

        Raises the recorder's :class:`RecordingError` when the file could not be written (a full
        disk): what was written before stays readable."""
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._cond.notify_all()
        self._thread.join()
        try:
            if self._error is None:
                self._queue.append((END, None, (b"",)))
                self._encode_pending()
                with self._io:
                    self._flush_buf()
                try:
                    os.fsync(self._fd)
                except OSError as exc:
                    self._error = WriteError(f"{self.path}: cannot write the recording ({exc.strerror or exc})", exc)
            if self._error is not None:
                raise self._error
        finally:
            self._buf = bytearray()
            os.close(self._fd)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def is_native(head: bytes) -> bool:
    return head.startswith(MAGIC)


class NativeRecording(Recording):
    """Replay a native recording (see the module docstring for the layout)."""

    format = "necviz"

    def __init__(self, path, **kwargs):
        kwargs.pop("exposure_us", None)  # exposures are stored
        super().__init__(path, **kwargs)
        self._fh = open(self.path, "rb")
        self.size = os.fstat(self._fh.fileno()).st_size
        head = self._fh.read(PREAMBLE)
        if not head.startswith(MAGIC):
            raise self.error("not a necviz recording (wrong magic)", 0)
        if len(head) < PREAMBLE:
            raise self.error("truncated file header", len(head))
        if head[-1] not in READS:
            raise self.error(
                f"unsupported necviz recording version {head[-1]} (this reader reads {' and '.join(map(str, READS))})",
                PREAMBLE - 1,
            )
        self.version = head[-1]
        kind, length, crc, payload, status = self._read_chunk(PREAMBLE)
        if status != "ok" or kind != HEADER:
            raise self.error("missing or incomplete header chunk", PREAMBLE)
        try:
            header = json.loads(payload)
            s = header["sensor"] if isinstance(header, dict) else None
            if not isinstance(s, dict):
                raise ValueError("no sensor object")
            stored = SensorGeometry(int(s["width"]), int(s["height"]), str(s.get("name", "custom")))
            props = header.get("properties") or {}
            if not isinstance(props, dict):
                raise ValueError("properties is not an object")
        except (ValueError, KeyError, TypeError, OverflowError, NecvizError) as exc:
            raise self.error(f"unreadable header chunk ({first_line(exc)})", PREAMBLE) from None
        self.header = header
        self.sensor = self.sensor or stored
        self.properties = dict(props)
        self.camera_name = str(props["camera_name"]) if props.get("camera_name") else None
        self.created_utc = header.get("created_utc")
        self._data_start = PREAMBLE + CHUNK_HEAD.size + length
        self._index: list[tuple[int, int, int, int]] | None = None  # (offset, type, length, t_us)
        self._commands: list[CommandRecord] | None = None
        self._annotations: list | None = None
        self._pairs: dict[int, int] = {}
        self.exposure_source = "stored"

    # -- chunk access ---------------------------------------------------------------------------
    def _read_chunk(self, offset: int, payload: bool = True, peek: int = 0):
        """Read the chunk at ``offset``: (type, length, crc, payload-or-peek, status).

        status: "ok", "eof" (clean end), "tail" (incomplete last chunk), "unknown" (bad type) or "zeros"
        (a run of zero bytes longer than a crash leaves: damage).
        """
        f = self._fh
        f.seek(offset)
        head = f.read(CHUNK_HEAD.size)
        if not head:
            return 0, 0, 0, b"", "eof"
        if len(head) < CHUNK_HEAD.size:
            return 0, 0, 0, b"", "tail"
        kind, length, crc = CHUNK_HEAD.unpack(head)
        if kind not in _NAMES:
            if kind == 0:
                zeros = self._zeros_to_end(offset)
                if zeros is not None:
                    return kind, length, crc, b"", zeros
            return kind, length, crc, b"", "unknown"
        end = offset + CHUNK_HEAD.size + length
        if end > self.size:
            return kind, length, crc, b"", "tail"
        if payload:
            data = bytearray(length)  # writable, so replayed arrays are ordinary writable arrays
            got = f.readinto(data)
            if got < length:
                return kind, length, crc, b"", "tail"
            if zlib.crc32(data) != crc:
                return kind, length, crc, data, ("tail" if end == self.size else "crc")
            return kind, length, crc, data, "ok"
        return kind, length, crc, f.read(min(peek, length)), "ok"

    def _zeros_to_end(self, offset: int) -> str | None:
        """What a run of zero bytes at ``offset`` is: ``"tail"`` if it reaches the end of the file within
        :data:`ZERO_TAIL` bytes (a file system that lost the last writes of a crash fills them with
        zeros), ``"zeros"`` if it goes on longer (damage), ``None`` if it is not a run of zeros."""
        self._fh.seek(offset)
        seen = 0
        while True:
            block = self._fh.read(1 << 20)
            if not block:
                return "tail"
            if block.count(0) != len(block):
                return None
            seen += len(block)
            if seen > ZERO_TAIL:
                return "zeros"

    def _tail_warning(self, offset: int) -> None:
        self.warn(
            f"recording ends in an incomplete chunk at byte {offset} (writer stopped mid-write); "
            f"{self.size - offset} bytes ignored"
        )

    def _damage(self, status: str, kind: int, offset: int) -> RecordingError:
        if status == "zeros":
            return self.error(f"a run of more than {ZERO_TAIL >> 20} MiB of zero bytes (damaged data)", offset)
        if status == "unknown":
            return self.error(f"unknown chunk type {kind} (garbage or damaged data)", offset)
        return self.error(f"{_NAMES.get(kind, kind)} chunk fails its CRC check (damaged data)", offset)

    @staticmethod
    def _chunk_time(kind: int, peek: bytes) -> int | None:
        if kind in (EVENTS, MARKER, FRAME, IMU, TRIGGERS, COMMAND, ANNOTATION) and len(peek) >= 8:
            return T_S.unpack_from(peek)[0]
        return None

    def scan(self) -> list[tuple[int, int, int, int]]:
        """Index the chunks by a forward scan of their headers: ``[(offset, type, length, t_us)]``.

        Reads 9 header bytes per chunk plus the small payloads of markers, commands and annotations
        (which it collects); seeks over everything else. Stops at the first damaged or incomplete
        chunk (iteration reports it).
        """
        if self._index is not None:
            return self._index
        index, commands, notes, pairs = [], [], [], {}
        open_start = None
        off = self._data_start
        while True:
            kind, length, _, data, status = self._read_chunk(off, payload=False, peek=17)
            if status != "ok":
                break
            t = self._chunk_time(kind, data)
            if kind in (MARKER, COMMAND, ANNOTATION):
                kind2, _, _, full, status = self._read_chunk(off)
                if status != "ok":
                    break
                if len(full) < {MARKER: MARKER_S.size, COMMAND: COMMAND_S.size, ANNOTATION: T_S.size}[kind]:
                    break  # malformed: iteration reports it
                if kind == MARKER:
                    tm, mk = MARKER_S.unpack_from(full)
                    if mk == 0:
                        open_start = tm
                    elif open_start is not None:
                        pairs[open_start] = tm
                        open_start = None
                elif kind == COMMAND:
                    commands.append(self._command(full))
                else:
                    notes.append(self._annotation(full, off))
            index.append((off, kind, length, -1 if t is None else t))
            off += CHUNK_HEAD.size + length
        self._index, self._commands, self._annotations, self._pairs = index, commands, notes, pairs
        return index

    @staticmethod
    def _command(data: bytes) -> CommandRecord:
        issue, exp, gain, has, applied = COMMAND_S.unpack_from(data)
        return CommandRecord(int(issue), float(exp), float(gain), int(applied) if has else None)

    def _annotation(self, data: bytes, offset: int):
        try:
            return (T_S.unpack_from(data)[0], json.loads(data[8:]))
        except ValueError:
            raise self.error("unreadable annotation chunk", offset) from None

    @property
    def commands(self) -> list[CommandRecord]:
        """Exposure commands stored in the file (indexes the file on first use)."""
        if self._commands is None:
            self.scan()
        return self._commands

    @commands.setter
    def commands(self, value) -> None:  # the base class initialises it
        self._commands = None if not value else list(value)

    @property
    def annotations(self) -> list:
        """``(t_us, dict)`` notes stored in the file (indexes the file on first use)."""
        if self._annotations is None:
            self.scan()
        return self._annotations

    @annotations.setter
    def annotations(self, value) -> None:
        self._annotations = None if not value else list(value)

    # -- iteration ------------------------------------------------------------------------------
    def _first_offset(self) -> int:
        if self.start_us is None:
            return self._data_start
        index = self.scan()
        # the last chunk stamped a second before start_us: whatever precedes it in stream order ended
        # before start_us (a batch spans 1 ms, an exposure less than a second), so nothing is skipped
        best = 0
        for i, (_off, kind, _length, t) in enumerate(index):
            if t < 0 or kind in (COMMAND, ANNOTATION):  # commands and notes are stamped when issued
                continue
            if t < self.start_us - SEEK_MARGIN_US:
                best = i
            else:
                break
        return index[best][0] if index else self._data_start

    def _packets(self) -> Iterator:
        ranged = self.start_us is not None or self.end_us is not None
        if ranged:
            self.scan()
        lo = -(1 << 62) if self.start_us is None else self.start_us
        hi = (1 << 62) if self.end_us is None else self.end_us  # excluded: [lo, hi)
        allowed_open = False  # the current exposure is replayed (its start marker was yielded)
        awaiting_frame = False
        off = self._first_offset()
        commands: list[CommandRecord] = []
        notes: list = []
        complete = False
        w, h = self.sensor.width, self.sensor.height
        off_sensor = 0
        while True:
            self._where = off
            kind, length, _, data, status = self._read_chunk(off)
            if status == "eof":
                self.warn("recording has no end chunk (the writer was not closed); everything written was read")
                complete = True
                break
            if status == "tail":
                self._tail_warning(off)
                complete = True
                break
            if status != "ok":
                raise self._damage(status, kind, off)
            next_off = off + CHUNK_HEAD.size + length
            try:
                if kind == EVENTS:
                    ev = decode_events(data) if self.version >= 2 else np.frombuffer(data, dtype=EVENT_DTYPE)
                    if ev.size and (int(ev["x"].max()) >= w or int(ev["y"].max()) >= h):
                        keep = (ev["x"] < w) & (ev["y"] < h)
                        off_sensor += ev.size - int(keep.sum())
                        ev = ev[keep]
                    if ev.size:
                        t = ev["t"]
                        if t[0] >= hi and not awaiting_frame:
                            break
                        if t[0] < lo or t[-1] >= hi:
                            ev = ev[(t >= lo) & (t < hi)]
                        if ev.size:
                            yield EventBatch(ev)
                elif kind == MARKER:
                    t, mk = MARKER_S.unpack(data)
                    if mk == 0:
                        allowed_open = not ranged or (t >= lo and self._pairs.get(t, hi + 1) <= hi)
                        if allowed_open:
                            yield ExposureMarker(int(t), "start")
                    elif allowed_open:
                        allowed_open = False
                        awaiting_frame = True
                        yield ExposureMarker(int(t), "end")
                elif kind == FRAME:
                    s, e, gain, seq, h, w = FRAME_S.unpack_from(data)
                    if awaiting_frame or not ranged:
                        awaiting_frame = False
                        if self.version >= 2:
                            img = decode_pixels(memoryview(data)[FRAME_S.size :], h, w)
                        else:
                            img = np.frombuffer(data, np.uint8, h * w, FRAME_S.size).reshape(h, w)
                        yield Frame(img, int(s), int(e), float(gain), int(seq))
                elif kind in (IMU, TRIGGERS):
                    arr = np.frombuffer(data, dtype=IMU_DTYPE if kind == IMU else TRIGGER_DTYPE)
                    if ranged and arr.size:
                        arr = arr[(arr["t"] >= lo) & (arr["t"] < hi)]
                    if arr.size:
                        yield ImuBatch(arr) if kind == IMU else TriggerBatch(arr)
                elif kind == COMMAND:
                    commands.append(self._command(data))
                elif kind == ANNOTATION:
                    notes.append(self._annotation(data, off))
                elif kind == END:
                    complete = True
                    break
                elif kind == HEADER:
                    raise self.error("second header chunk (two recordings concatenated?)", off)
            except (ValueError, struct.error) as exc:
                if isinstance(exc, RecordingError):
                    raise
                raise self.error(f"malformed {_NAMES[kind]} chunk ({exc})", off) from None
            off = next_off
        if off_sensor:
            self.warn(f"{off_sensor} events dropped: coordinates outside the {w}x{h} sensor")
        if complete and not ranged and self._index is None:
            self._commands, self._annotations = commands, notes
