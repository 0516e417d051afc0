"""Shared pieces of every recording reader: the error type, the :class:`Recording` base class and
:class:`StreamAssembler`, which turns a file's separately stored streams into stream order.

Stream order (the contract of :class:`~necviz.drivers.source.Source`): time-sorted event batches,
``ExposureMarker("start")`` before events at/after an exposure start, ``ExposureMarker("end")``
after the events before the exposure end, then the :class:`~necviz.core.frames.Frame` right after
its end marker; IMU and trigger batches interleaved by time. Event batches are bounded (at most
``batch_us`` = 1 ms of sensor time and at most 65,536 events) so a controller can act between
frames. All times are integer microseconds (µs).

One error path: whatever a reader or its library (NumPy, h5py, struct, zlib, json, the ``aedat``
decoder, including its Rust panics) raises on damaged input reaches the caller as one
:class:`RecordingError` — a one-line message naming the file and the byte offset or key where
reading stopped — after every packet decoded before the damage has been delivered
(:meth:`Recording.__iter__`; ``open_recording`` does the same for a reader's constructor).
"""

from __future__ import annotations

import os
import struct
import sys
import tempfile
import threading
import zlib
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from itertools import pairwise
from pathlib import Path

import numpy as np

from necviz.core.errors import NecvizError, StreamError
from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import IMU_DTYPE, TRIGGER_DTYPE, ImuBatch, TriggerBatch
from necviz.core.sensor import DAVIS240, DAVIS346, SensorGeometry, known_event_rate_max
from necviz.drivers.source import CAMERA, CameraInfo, Source, route

#: Batch bounds of every reader (sensor time per event batch, events per batch).
BATCH_US = 1000
MAX_BATCH_EVENTS = 65536

#: Sensor sizes a reader rounds up to when a file stores no size (smallest that holds every event).
KNOWN_SENSORS = (
    SensorGeometry(128, 128, "DVS128"),
    DAVIS240,
    DAVIS346,
    SensorGeometry(640, 480, "640x480"),
    SensorGeometry(1280, 720, "1280x720"),
)

#: Chip names (as in AEDAT headers) -> geometry.
CHIP_SENSORS = {
    "DAVIS346": DAVIS346,
    "DAVIS240": DAVIS240,
    "DAVIS128": SensorGeometry(128, 128, "DAVIS128"),
    "DVS128": SensorGeometry(128, 128, "DVS128"),
    "DAVIS640": SensorGeometry(640, 480, "DAVIS640"),
    "DVXPLORER": SensorGeometry(640, 480, "DVXplorer"),
}

NO_EXPOSURE_FRAMES = "none (frames skipped: no exposure stored, pass --exposure-us)"

#: Most events a :class:`StreamAssembler` holds back: past this, timestamps that do not advance
#: (a run of zeros, a stuck clock) are damage, not data (a real stream releases them within 50 ms).
MAX_HELD_EVENTS = 1 << 23
#: Most frame bytes a :class:`StreamAssembler` holds back (frames whose exposure never ends).
MAX_HELD_FRAME_BYTES = 256 << 20


class RecordingError(NecvizError):
    """A recording is missing, empty, of an unknown format, damaged or uses an unsupported feature.

    The message is one line naming the file and, where relevant, the byte offset of the damage.
    """


#: What the readers' libraries raise on damaged input: NumPy (ValueError, IndexError, MemoryError
#: for absurd sizes), h5py (OSError, KeyError, RuntimeError, ValueError, TypeError), struct, zlib,
#: json (ValueError), the ``aedat`` decoder (RuntimeError, OSError). Rust panics are matched by
#: :func:`is_rust_panic` (they derive from BaseException). Bugs such as NameError/AttributeError
#: are not in the list: they stay tracebacks.
DAMAGE_ERRORS = (
    OSError,
    EOFError,
    ValueError,
    LookupError,
    TypeError,
    RuntimeError,
    ArithmeticError,
    MemoryError,
    struct.error,
    zlib.error,
)


def is_rust_panic(exc: BaseException) -> bool:
    """True for a panic of a Rust extension (PyO3's ``pyo3_runtime.PanicException``, a BaseException).

    Matched by the type's module and name, so KeyboardInterrupt/SystemExit are never caught with it."""
    t = type(exc)
    return t.__name__ == "PanicException" and t.__module__ == "pyo3_runtime"


def is_damage(exc: BaseException) -> bool:
    """Whether ``exc`` is what a reader's library raises on damaged input (see :data:`DAMAGE_ERRORS`)."""
    return isinstance(exc, DAMAGE_ERRORS) or is_rust_panic(exc)


def first_line(exc: BaseException, limit: int = 160) -> str:
    """The first non-empty line of ``str(exc)``, at most ``limit`` characters ("" if none)."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    text = lines[0] if lines else ""
    return text if len(text) <= limit else text[: limit - 3] + "..."


def reason(exc: BaseException, limit: int = 160) -> str:
    """``Type: first line of the message``, for one-line errors."""
    text = first_line(exc, limit)
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


class StderrTrap:
    """Keep what a native library writes to the process's standard error (file descriptor 2) during
    a call, and throw it away if the call ended in a Rust panic.

    A panic of a Rust extension prints its message (and, with ``RUST_BACKTRACE=1``, a backtrace) on
    fd 2 before Python sees the exception; necviz reports the damage in its own line instead.
    Whatever the call wrote without panicking (or another thread wrote meanwhile) is passed on to
    the real fd 2 afterwards. One trap per reader; calls are serialised by a lock.
    """

    _lock = threading.Lock()

    def __init__(self):
        self._file = None  # the temporary file where memfd_create is missing
        try:
            self._fd = os.memfd_create("necviz-stderr", 0)
        except (AttributeError, OSError):
            self._fd = None
            tmp = tempfile.TemporaryFile()
            self._file = tmp  # kept open for the trap's lifetime
            self._fd = tmp.fileno()

    @contextmanager
    def __call__(self, discard: bool = False):
        """Trap fd 2 for the block; ``discard``: drop what was written even without a panic (a
        library that prints its own complaints about damaged data, e.g. libpng inside OpenCV)."""
        if self._fd is None:
            yield
            return
        with self._lock:
            try:
                sys.stderr.flush()
            except (OSError, ValueError, AttributeError):
                pass
            saved = os.dup(2)
            os.dup2(self._fd, 2)
            panicked = False
            try:
                yield
            except BaseException as exc:
                panicked = is_rust_panic(exc)
                raise
            finally:
                os.dup2(saved, 2)
                os.close(saved)
                n = os.lseek(self._fd, 0, os.SEEK_CUR)
                if n:
                    if not (panicked or discard):
                        data = os.pread(self._fd, n, 0)
                        try:
                            os.write(2, data)
                        except OSError:
                            pass
                    os.ftruncate(self._fd, 0)
                    os.lseek(self._fd, 0, os.SEEK_SET)

    def close(self) -> None:
        """Release the trap's file (idempotent); later calls run untrapped."""
        if self._fd is None:
            return
        if self._file is not None:
            self._file.close()
        else:
            os.close(self._fd)
        self._fd = None

    def __del__(self):
        try:
            self.close()
        except (OSError, AttributeError):
            pass


@contextmanager
def openable_path(path):
    """A name of ``path`` that libraries taking UTF-8 text paths (the Rust ``aedat`` decoder, SQLite,
    rosbags) can open: the path itself, or — when it is not UTF-8 (a file name in another encoding,
    which Python keeps as surrogate escapes) — a symbolic link to it with a UTF-8 name and the same
    extension, in a temporary folder that lasts as long as the block."""
    text = str(path)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        folder = tempfile.mkdtemp(prefix="necviz-name-")
        name = os.path.basename(text).encode("utf-8", "surrogateescape").decode("utf-8", "replace")
        link = os.path.join(folder, name.replace("\ufffd", "_") or "recording")
        try:
            os.symlink(os.fsencode(os.path.abspath(path)), link)
            yield link
        finally:
            try:
                os.unlink(link)
            finally:
                os.rmdir(folder)
        return
    yield text


def sensor_from_chip(name: str) -> SensorGeometry | None:
    """Geometry of a chip named in a file header (``'DAVIS346B'``, ``'Davis346redColor'`` ...), or None."""
    up = name.upper()
    for key, geo in CHIP_SENSORS.items():
        if key in up:
            return geo
    return None


def sensor_from_extent(max_x: int, max_y: int) -> SensorGeometry:
    """The smallest known sensor holding pixel (max_x, max_y), else exactly ``(max_x+1) x (max_y+1)``."""
    for geo in KNOWN_SENSORS:
        if max_x < geo.width and max_y < geo.height:
            return geo
    return SensorGeometry(int(max_x) + 1, int(max_y) + 1, "from event coordinates")


def to_gray8(image: np.ndarray, bits: int | None = None) -> np.ndarray:
    """Convert an image to 8-bit grey (H x W uint8).

    uint8 grey is returned as is; 16-bit (or ``bits``-bit values in a wider integer) keeps the 8
    most significant bits (``>> (bits - 8)``; no gamma, so linearity is preserved); colour
    (H x W x 3 BGR / x 4 BGRA, 8 or 16 bit) becomes luma ``0.114 B + 0.587 G + 0.299 R`` (ITU-R
    BT.601 weights, on linear values) before the bit reduction.
    """
    img = np.asarray(image)
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[:, :, 0]
        else:
            b, g, r = (img[:, :, i].astype(np.float32) for i in range(3))
            grey = 0.114 * b + 0.587 * g + 0.299 * r
            img = np.rint(grey).astype(img.dtype)
    if img.dtype == np.uint8:
        return np.ascontiguousarray(img)
    if bits is None:
        bits = 16 if img.dtype.itemsize >= 2 else 8
    return np.clip(img.astype(np.int64) >> max(bits - 8, 0), 0, 255).astype(np.uint8)


#: Standard gravity (m/s²): formats that store acceleration in SI units are converted to g.
G = 9.80665


def events_from_seconds(t_s, x, y, p) -> np.ndarray:
    """Events from columns with time in (float) seconds and polarity > 0 = ON: ``t`` rounded to
    integer µs, ``p`` -> ±1."""
    ev = np.empty(len(t_s), EVENT_DTYPE)
    ev["t"] = np.rint(np.asarray(t_s, np.float64) * 1e6).astype(np.int64)
    ev["x"] = x
    ev["y"] = y
    ev["p"] = np.where(np.asarray(p) > 0, 1, -1)
    return ev


def imu_from_si(t_us, accel_ms2, gyro_rad_s) -> np.ndarray:
    """IMU samples from SI columns (N x 3 m/s², N x 3 rad/s) in necviz's units (g, °/s); no temperature."""
    imu = np.empty(len(t_us), IMU_DTYPE)
    imu["t"] = t_us
    accel, gyro = np.asarray(accel_ms2, np.float64), np.degrees(np.asarray(gyro_rad_s, np.float64))
    for k, axis in enumerate("xyz"):
        imu[f"a{axis}"] = accel[:, k] / G
        imu[f"g{axis}"] = gyro[:, k]
    imu["temp"] = np.nan
    return imu


class Recording(Source):
    """A recorded file replayed as a :class:`~necviz.drivers.source.Source`.

    Iterating yields packets in stream order, restricted to ``[start_us, end_us)`` (events, IMU
    samples and triggers stamped in that half-open range; frames whose whole exposure lies in it:
    exposure start >= ``start_us``, exposure end <= ``end_us``). Replay is open
    loop: :meth:`set_exposure` accepts commands and ignores them (the recorded exposures are what
    they are). Attributes: ``sensor``, ``format`` (short name), ``path``, ``properties`` (run
    metadata; native files only), ``camera_name`` (the camera the file names, e.g. AEDAT 4's
    ``DAVIS346_00000104``, else None), ``commands`` and ``annotations`` (stored in native files; empty for
    foreign formats), ``exposure_source`` (``"stored"``, ``"user (--exposure-us)"``, ``"estimated from
    frame timing"``, ``"none (no frames)"`` or :data:`NO_EXPOSURE_FRAMES`) and ``warnings`` (one-line
    strings about things fixed up or skipped; complete once iteration has finished).
    """

    format = ""

    def __init__(
        self,
        path,
        *,
        sensor: SensorGeometry | None = None,
        exposure_us: float | None = None,
        start_us: int | None = None,
        end_us: int | None = None,
    ):
        self.path = Path(path)
        self.sensor: SensorGeometry | None = sensor
        self.exposure_us = None if exposure_us is None else float(exposure_us)
        if self.exposure_us is not None and not (self.exposure_us > 0 and np.isfinite(self.exposure_us)):
            raise RecordingError(f"{self.path}: exposure must be a positive number of µs, got {exposure_us!r}")
        self.start_us = None if start_us is None else int(start_us)
        self.end_us = None if end_us is None else int(end_us)
        if self.start_us is not None and self.end_us is not None and self.end_us < self.start_us:
            raise RecordingError(f"{self.path}: end time {self.end_us} µs precedes start time {self.start_us} µs")
        self.properties: dict = {}
        self.camera_name: str | None = None  # the camera the file names (AEDAT: DAVIS346_00000104 ...)
        self.commands: list = []
        self.annotations: list = []
        self.exposure_source = "none (no frames)"
        self.warnings: list[str] = []
        self.ignored_commands = 0
        self._asm: StreamAssembler | None = None  # the assembler of the iteration under way
        self._where: int | str | None = None  # where the reader is (byte offset or key), for errors

    # -- Source protocol ----------------------------------------------------------------------
    cameras = (CAMERA,)

    def warm_up(self) -> None:
        """Nothing to ready: a reader's decoding is paid while reading, and a replay is open loop."""

    @property
    def camera_info(self) -> CameraInfo:
        """What a recording says about its camera: the event bus ceiling of a known sensor (replay is open loop)."""
        return CameraInfo(event_rate_max=known_event_rate_max(self.sensor))

    def packets(self) -> Iterator:
        """``(camera, packet)`` pairs (:class:`~necviz.drivers.source.Source`); iterate for bare packets."""
        return route(CAMERA, self)

    def __iter__(self) -> Iterator:
        """The packets in stream order (:meth:`_packets`), through the one error path.

        If reading stops at damage — a :class:`RecordingError` from the reader or anything
        :func:`is_damage` matches from its libraries — everything the reader's assembler
        (``self._asm``) still holds is delivered, then one :class:`RecordingError` is raised, naming
        the file and where reading stopped (``self._where``: a byte offset, or a key/message
        description, kept up to date by the reader).
        """
        self._asm = None
        self._where = None
        try:
            yield from self._packets()
        except BaseException as exc:
            err = self.as_recording_error(exc)
            if err is None:
                raise
            if self._asm is not None:
                yield from self._asm.drain(None)
            raise err from None
        finally:
            if self._asm is not None:
                for w in self._asm.warnings():
                    self.warn(w)

    def _packets(self) -> Iterator:  # pragma: no cover - abstract
        raise NotImplementedError

    def set_exposure(
        self, camera: str, exposure_us: float, gain: float = 1.0, *, issue_time_us: int | None = None
    ) -> None:
        """Accept and ignore an exposure command: a replay is open loop (counted in ``ignored_commands``)."""
        self.ignored_commands += 1

    def close(self) -> None:
        """Release file handles (idempotent)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- helpers --------------------------------------------------------------------------------
    def error(self, what: str, offset: int | str | None = None) -> RecordingError:
        """``RecordingError("<path>: <what> at byte <offset>")``; a string ``offset`` names a key instead
        (``"... at dataset /events/t"``)."""
        if offset is None:
            at = ""
        elif isinstance(offset, str):
            at = f" at {offset}"
        else:
            at = f" at byte {int(offset)}"
        return RecordingError(f"{self.path}: {what}{at}")

    def damage(self, exc: BaseException, where: int | str | None = None) -> RecordingError:
        """The one-line error for a library exception raised on damaged data, at ``where`` (default:
        the reader's current position ``self._where``)."""
        if where is None:
            where = getattr(self, "_where", None)
        return self.error(f"damaged or unreadable data ({reason(exc)})", where)

    def as_recording_error(self, exc: BaseException, where: int | str | None = None) -> RecordingError | None:
        """``exc`` as the recording's one-line error, or None if it is not about the data (a bug,
        KeyboardInterrupt, GeneratorExit ...): RecordingError as is; another NecvizError (e.g. a
        decoded frame or sensor size that is impossible) prefixed with the file and position;
        library exceptions (:func:`is_damage`) through :meth:`damage`."""
        if isinstance(exc, RecordingError):
            return exc
        if isinstance(exc, NecvizError):
            if where is None:
                where = getattr(self, "_where", None)
            return self.error(f"damaged data ({first_line(exc) or type(exc).__name__})", where)
        if is_damage(exc):
            return self.damage(exc, where)
        return None

    @contextmanager
    def converting(self, where: int | str | None = None):
        """Turn library exceptions raised inside the block into one-line :class:`RecordingError`."""
        try:
            yield
        except BaseException as exc:
            err = self.as_recording_error(exc, where)
            if err is None or err is exc:
                raise
            raise err from None

    def warn(self, text: str) -> None:
        if text not in self.warnings:
            self.warnings.append(text)

    def _assembled(self, asm: StreamAssembler, feed: Iterator) -> Iterator:
        """Run ``feed`` (a generator that pushes into ``asm`` and yields its drains), then the rest
        of ``asm``. ``asm`` becomes ``self._asm``: on damage :meth:`__iter__` delivers what it holds
        before the error, and its warnings become the recording's."""
        self._asm = asm
        yield from feed
        yield from asm.drain(None)

    def in_range(self, t_us: int) -> bool:
        """Whether ``t_us`` lies in ``[start_us, end_us)``."""
        return (self.start_us is None or t_us >= self.start_us) and (self.end_us is None or t_us < self.end_us)

    def exposure_in_range(self, start_us: int, end_us: int) -> bool:
        """Whether an exposure ``[start_us, end_us]`` lies wholly in the range."""
        return (self.start_us is None or start_us >= self.start_us) and (self.end_us is None or end_us <= self.end_us)

    def past_end(self, t_us: int) -> bool:
        """Whether ``t_us`` is at or after the (exclusive) end of the range."""
        return self.end_us is not None and t_us >= self.end_us

    def frame_exposure_from_stamp(self, stamp_us: int, stored_exposure_us: float | None) -> tuple[int, int] | None:
        """Exposure ``[start, end]`` of a frame stamped at mid-exposure: ``start = stamp - exp/2``.

        Uses the stored exposure when present, else the user's ``exposure_us``; ``None`` if neither.
        """
        exp = stored_exposure_us if stored_exposure_us is not None else self.exposure_us
        if exp is None or not exp > 0:
            return None
        start = int(round(stamp_us - exp / 2))
        return start, start + max(int(round(exp)), 1)


class StreamAssembler:
    """Merge separately stored streams into stream order with bounded batches and memory.

    Readers push what they decode in file order (``push_events``/``push_frame``/``push_imu``/
    ``push_triggers``) and call :meth:`drain` with a *watermark*: a time before which nothing more
    will be pushed. Everything earlier than the watermark is released in stream order. Frames
    whose exposure overlaps the previous frame's, frames that arrive after their exposure start was
    released, frames of the wrong size and events older than what was released are dropped and
    counted (see :meth:`warnings`). Memory: whatever lies after the watermark, at most
    :data:`MAX_HELD_EVENTS` events and :data:`MAX_HELD_FRAME_BYTES` of frames: more means the
    file's timestamps do not advance (damage), a one-line error.
    """

    def __init__(
        self,
        sensor: SensorGeometry,
        *,
        start_us: int | None = None,
        end_us: int | None = None,
        batch_us: int = BATCH_US,
        max_batch: int = MAX_BATCH_EVENTS,
    ):
        self.sensor = sensor
        self.start_us = start_us
        self.end_us = end_us
        self.batch_us = int(batch_us)
        self.max_batch = int(max_batch)
        self._ev: list[np.ndarray] = []
        self._ev_n = 0
        self._imu: list[np.ndarray] = []
        self._trg: list[np.ndarray] = []
        self._frames: list[Frame] = []
        self._open: Frame | None = None
        self._last_end = None  # exposure end of the last accepted frame
        self.released_us: int | None = None  # everything before this time has been released
        self.max_seen_us: int | None = None
        self.counts: Counter = Counter()
        self.frames_out = 0
        self._unsorted = False

    @property
    def buffered_events(self) -> int:
        return self._ev_n

    def _seen(self, t: int) -> None:
        if self.max_seen_us is None or t > self.max_seen_us:
            self.max_seen_us = int(t)

    def push_events(self, ev: np.ndarray) -> None:
        """Add an event batch (EVENT_DTYPE); off-sensor events are dropped and counted."""
        if ev.size == 0:
            return
        w, h = self.sensor.width, self.sensor.height
        off = (ev["x"] >= w) | (ev["y"] >= h)
        if off.any():
            self.counts["events_off_sensor"] += int(off.sum())
            ev = ev[~off]
            if ev.size == 0:
                return
        t = ev["t"]
        if ev.size > 1 and np.any(t[1:] < t[:-1]):
            self._unsorted = True
        if self._ev and int(t[0]) < int(self._ev[-1]["t"][-1]):
            self._unsorted = True
        self._ev.append(ev)
        self._ev_n += ev.size
        self._seen(int(t.max()))
        if self._ev_n > MAX_HELD_EVENTS:
            self._stuck()

    def _stuck(self) -> None:
        """Drop what is held (it cannot be released in order) and report the stuck timestamps."""
        t0 = min(int(a["t"].min()) for a in self._ev) if self._ev else self.max_seen_us
        n, self._ev, self._ev_n, self._frames = self._ev_n, [], 0, []
        raise StreamError(
            f"{n:,} events held between {t0} and {self.max_seen_us} µs without the stream's time advancing "
            "(timestamps stuck: a run of zeros or damaged data)"
        )

    @staticmethod
    def _sorted(arr: np.ndarray) -> np.ndarray:
        if arr.size > 1 and np.any(arr["t"][1:] < arr["t"][:-1]):
            return arr[np.argsort(arr["t"], kind="stable")]
        return arr

    def push_imu(self, samples: np.ndarray) -> None:
        samples = self._sorted(samples)
        if samples.size:
            self._imu.append(samples)
            self._seen(int(samples["t"].max()))

    def push_triggers(self, triggers: np.ndarray) -> None:
        triggers = self._sorted(triggers)
        if triggers.size:
            self._trg.append(triggers)
            self._seen(int(triggers["t"].max()))

    def push_frame(self, frame: Frame) -> None:
        if frame.image.shape != self.sensor.shape:
            self.counts["frames_wrong_size"] += 1
            return
        if self.released_us is not None and frame.exposure_start_us < self.released_us:
            self.counts["frames_late"] += 1
            return
        if (self.start_us is not None and frame.exposure_start_us < self.start_us) or (
            self.end_us is not None and frame.exposure_end_us > self.end_us
        ):
            return
        self._frames.append(frame)
        self._seen(int(frame.exposure_end_us))
        if sum(f.image.nbytes for f in self._frames) > MAX_HELD_FRAME_BYTES:
            self._stuck()

    def holdback_watermark(self, lag_us: int, holdback_us: int = 1_000_000, max_buffered: int = 1 << 22) -> int | None:
        """Watermark for files that store frames after their readout: ``max(holdback_us, 2*lag_us)``
        behind the newest timestamp seen (``lag_us``: the largest delay seen between a frame's
        exposure start and the newest timestamp when the frame was stored); shortened to
        ``max(2*lag_us, 50 ms)`` while more than ``max_buffered`` events are held (bounded memory)."""
        if self.max_seen_us is None:
            return None
        hold = max(holdback_us, 2 * lag_us)
        if self._ev_n > max_buffered:
            hold = max(2 * lag_us, 50_000)
        return self.max_seen_us - hold

    def lag_of(self, exposure_start_us: int) -> int:
        """How far the newest timestamp seen is past ``exposure_start_us`` (0 if nothing seen)."""
        return 0 if self.max_seen_us is None else max(0, self.max_seen_us - int(exposure_start_us))

    def warnings(self) -> list[str]:
        """One-line descriptions of everything dropped so far."""
        c = self.counts
        out = []
        if c["frames_overlap"]:
            out.append(f"{c['frames_overlap']} frames dropped: exposure overlaps the previous frame's")
        if c["frames_late"]:
            out.append(f"{c['frames_late']} frames dropped: stored after events past their exposure start")
        if c["frames_wrong_size"]:
            out.append(
                f"{c['frames_wrong_size']} frames dropped: size differs from the "
                f"{self.sensor.width}x{self.sensor.height} sensor (partial/ROI frames are not supported)"
            )
        if c["events_off_sensor"]:
            out.append(
                f"{c['events_off_sensor']} events dropped: coordinates outside the "
                f"{self.sensor.width}x{self.sensor.height} sensor"
            )
        if c["events_late"]:
            out.append(f"{c['events_late']} events dropped: older than events already replayed")
        if c["events_sorted"]:
            out.append(f"{c['events_sorted']} event batches were out of time order and were sorted")
        return out

    # -- release -------------------------------------------------------------------------------
    @staticmethod
    def _split(parts: list[np.ndarray], watermark: int | None, dtype) -> tuple[np.ndarray, list[np.ndarray]]:
        """(concatenation of everything before ``watermark``, remaining parts); parts are time-sorted.

        Only the released parts are copied, so a long hold-back costs no repeated copying."""
        if not parts:
            return np.zeros(0, dtype), []
        if watermark is None:
            return (parts[0] if len(parts) == 1 else np.concatenate(parts)), []
        out, i = [], 0
        while i < len(parts) and parts[i]["t"][-1] < watermark:
            out.append(parts[i])
            i += 1
        rest = parts[i:]
        if rest:
            k = int(np.searchsorted(rest[0]["t"], watermark, side="left"))
            if k:
                out.append(rest[0][:k])
                rest[0] = rest[0][k:]
        if not out:
            return np.zeros(0, dtype), rest
        return (out[0] if len(out) == 1 else np.concatenate(out)), rest

    def _range(self, arr: np.ndarray) -> np.ndarray:
        if arr.size == 0:
            return arr
        t = arr["t"]
        lo = 0 if self.start_us is None else int(np.searchsorted(t, self.start_us, side="left"))
        hi = arr.size if self.end_us is None else int(np.searchsorted(t, self.end_us, side="left"))  # end excluded
        return arr[lo:hi]

    def drain(self, watermark: int | None) -> Iterator:
        """Release (yield) everything before ``watermark`` µs; ``None`` releases everything."""
        if watermark is not None and self.released_us is not None and watermark <= self.released_us:
            return
        # events: sort if needed, drop the ones older than what was released
        if self._ev and self._unsorted:
            arr = np.concatenate(self._ev)
            order = np.argsort(arr["t"], kind="stable")
            if np.any(order != np.arange(arr.size)):
                self.counts["events_sorted"] += 1
            self._ev = [arr[order]]
            self._unsorted = False
        ev, self._ev = self._split(self._ev, watermark, EVENT_DTYPE)
        self._ev_n = sum(a.size for a in self._ev)
        for name, lst in (("_imu", self._imu), ("_trg", self._trg)):
            if len(lst) > 1 and any(b["t"][0] < a["t"][-1] for a, b in pairwise(lst)):
                arr = np.concatenate(lst)
                setattr(self, name, [arr[np.argsort(arr["t"], kind="stable")]])
        imu, self._imu = self._split(self._imu, watermark, IMU_DTYPE)
        trg, self._trg = self._split(self._trg, watermark, TRIGGER_DTYPE)
        if self.released_us is not None:
            for name in ("ev", "imu", "trg"):
                arr = locals()[name]
                if arr.size and arr["t"][0] < self.released_us:
                    k = int(np.searchsorted(arr["t"], self.released_us, side="left"))
                    if name == "ev":
                        self.counts["events_late"] += k
                        ev = ev[k:]
                    elif name == "imu":
                        imu = imu[k:]
                    else:
                        trg = trg[k:]
        ev, imu, trg = self._range(ev), self._range(imu), self._range(trg)

        # cuts: (time, order, packet); order 0 start marker, 1 end marker, 2 frame
        cuts: list[tuple[int, int, object]] = []
        self._frames.sort(key=lambda f: f.exposure_start_us)
        keep = []
        for f in self._frames:
            s, e = int(f.exposure_start_us), int(f.exposure_end_us)
            if watermark is not None and s >= watermark:
                keep.append(f)
                continue
            if (self._open is not None and s < self._open.exposure_end_us) or (
                self._last_end is not None and s < self._last_end
            ):
                self.counts["frames_overlap"] += 1
                continue
            if self.released_us is not None and s < self.released_us:
                self.counts["frames_late"] += 1
                continue
            cuts.append((s, 0, ExposureMarker(s, "start")))
            self._last_end = e
            if watermark is None or e < watermark:
                cuts.append((e, 1, ExposureMarker(e, "end")))
                cuts.append((e, 2, f))
            else:
                self._open = f
        self._frames = keep
        if (
            self._open is not None
            and (watermark is None or self._open.exposure_end_us < watermark)
            and not any(c[2] is self._open for c in cuts)
        ):
            e = int(self._open.exposure_end_us)
            cuts.append((e, 1, ExposureMarker(e, "end")))
            cuts.append((e, 2, self._open))
            self._open = None
        elif self._open is not None and any(c[2] is self._open for c in cuts):
            self._open = None

        items: list[tuple[int, int, object]] = list(cuts)
        if ev.size:
            t = ev["t"]
            bins = t // self.batch_us
            starts = np.flatnonzero(np.diff(bins)) + 1
            cut_t = np.array(sorted({c[0] for c in cuts}), dtype=np.int64)
            extra = np.searchsorted(t, cut_t, side="left")
            idx = np.unique(np.concatenate([[0], starts, extra, np.arange(0, ev.size, self.max_batch)]))
            idx = idx[(idx >= 0) & (idx < ev.size)]
            bounds = np.append(idx, ev.size)
            # refine bins that still exceed max_batch
            for a, b in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True):
                for c in range(a, b, self.max_batch):
                    chunk = ev[c : min(b, c + self.max_batch)]
                    items.append((int(chunk["t"][0]), 3, EventBatch(chunk)))
        for arr, order, cls in ((imu, 4, ImuBatch), (trg, 5, TriggerBatch)):
            if arr.size:
                b = arr["t"] // self.batch_us
                idx = np.concatenate([[0], np.flatnonzero(np.diff(b)) + 1, [arr.size]])
                for a, c in zip(idx[:-1].tolist(), idx[1:].tolist(), strict=True):
                    items.append((int(arr["t"][a]), order, cls(np.ascontiguousarray(arr[a:c]))))
        items.sort(key=lambda it: (it[0], it[1]))
        for _, _, pkt in items:
            if isinstance(pkt, Frame):
                self.frames_out += 1
            yield pkt
        if watermark is not None:
            self.released_us = int(watermark) if self.released_us is None else max(self.released_us, int(watermark))
