"""RPG Event Camera Dataset text format: ``events.txt``, ``images.txt``, ``imu.txt``.

* ``events.txt``: one event per line ``t x y p`` (t seconds, float; p 0/1). Times are rounded to
  integer µs; polarity 0/1 becomes -1/+1.
* ``images.txt``: ``t images/frame_XXXXXXXX.png`` (t seconds: the frame's mid-exposure stamp, as
  rpg_dvs_ros stamps images). 16-bit PNGs keep their 8 most significant bits, colour becomes luma.
* ``imu.txt``: ``t ax ay az gx gy gz`` (m/s², rad/s), converted to g and °/s.

No exposure times are stored: with ``exposure_us`` (``--exposure-us``) a frame's exposure is
``[stamp - exposure/2, stamp + exposure/2]``; without it frames are skipped (with a warning).
Sensor size: the ``sensor`` hint, else the first image's size, else the smallest known sensor
holding the events of the first block (the RPG dataset is DAVIS240C, 240x180).

Streaming: lines are parsed in ~8 MiB blocks with NumPy's C text parser (no Python per event).
Seeking: bisection on byte offsets (one line read per step) finds the first event at ``start_us``.
Damage: an unparsable line raises :class:`RecordingError` with its byte offset after everything
before it was yielded.
"""

from __future__ import annotations

import io
import os
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from necviz.core.frames import Frame
from necviz.core.sensor import SensorGeometry
from necviz.drivers.recordings.reader import (
    NO_EXPOSURE_FRAMES,
    Recording,
    RecordingError,
    StderrTrap,
    StreamAssembler,
    events_from_seconds,
    imu_from_si,
    sensor_from_extent,
    to_gray8,
)

BLOCK_BYTES = 8 << 20
#: Longest line read (a line of this project's text formats is under 100 bytes): more is damage,
#: e.g. a run of zero bytes where a crash or a preallocation left the file's tail.
MAX_LINE_BYTES = 1 << 20


def _parse(block: bytes, ncols: int) -> np.ndarray:
    with warnings.catch_warnings():  # a block of comments only is not worth a warning
        warnings.simplefilter("ignore", UserWarning)
        arr = np.loadtxt(io.BytesIO(block), dtype=np.float64, comments="#", ndmin=2)
    if arr.size and arr.shape[1] < ncols:
        raise ValueError(f"expected {ncols} columns, found {arr.shape[1]}")
    return arr[:, :ncols] if arr.size else np.zeros((0, ncols))


def _data_lines(block: bytes) -> Iterator[tuple[int, bytes]]:
    """(offset in the block, content before any '#') of every line NumPy's parser reads as data."""
    pos = 0
    for line in block.split(b"\n"):
        s = line.split(b"#", 1)[0].strip()
        if s:
            yield pos, s
        pos += len(line) + 1


def _bad_line(block: bytes, ncols: int) -> tuple[int, str]:
    """Offset (within the block) and text of the first line that does not parse: not numbers,
    fewer than ``ncols`` columns, or a column count different from the first line's."""
    count = None
    for pos, s in _data_lines(block):
        try:
            vals = [float(v) for v in s.split()]
        except ValueError:
            return pos, s[:40].decode("latin-1")
        if count is None:
            count = len(vals)
        if len(vals) < ncols or len(vals) != count:
            return pos, s[:40].decode("latin-1")
    return len(block), ""


def _nth_line(block: bytes, k: int) -> tuple[int, str]:
    """Offset and text of the ``k``-th data line of ``block``."""
    for i, (pos, s) in enumerate(_data_lines(block)):
        if i == k:
            return pos, s[:40].decode("latin-1")
    return len(block), ""


def numeric_blocks(
    rec: Recording, path: Path, ncols: int, start_offset: int = 0, valid=None
) -> Iterator[tuple[int, np.ndarray]]:
    """Yield (byte offset, float64 rows) blocks of a whitespace-separated numeric text file.

    ``valid(rows) -> bool mask`` marks rows whose values are possible. The first line that does not
    parse (or is not valid) raises :class:`RecordingError` with its byte offset, after the rows
    before it were yielded.
    """
    size = os.path.getsize(path)
    with open(path, "rb") as f:
        off = start_offset
        f.seek(off)
        carry = b""
        while off + len(carry) < size or carry:
            data = f.read(BLOCK_BYTES)
            block = carry + data
            if not data:
                carry = b""
            else:
                cut = block.rfind(b"\n") + 1
                if cut == 0:
                    if len(block) > MAX_LINE_BYTES:  # no line end in sight: damage, not a line
                        zeros = len(block) - len(block.lstrip(b"\x00"))
                        if zeros:
                            raise rec.error(f"a run of zero bytes in {path.name} (damaged or preallocated file)", off)
                        raise rec.error(f"a line longer than {MAX_LINE_BYTES:,} bytes in {path.name}", off)
                    carry = block
                    continue
                block, carry = block[:cut], block[cut:]
            rec._where = off
            try:
                rows = _parse(block, ncols)
                at, text = len(block), ""
            except ValueError:
                at, text = _bad_line(block, ncols)
                try:
                    rows = _parse(block[:at], ncols)
                except ValueError:  # cannot happen after _bad_line; report the block start
                    rows, at, text = np.zeros((0, ncols)), 0, ""
            if valid is not None and rows.size:
                ok = np.asarray(valid(rows), bool)
                if not ok.all():
                    k = int(np.argmin(ok))
                    rows = rows[:k]
                    at, text = _nth_line(block, k)
            if at < len(block):
                if rows.size:
                    yield off, rows  # everything before the damaged line
                raise rec.error(f"unparsable line {text!r} in {path.name}", off + at)
            yield off, rows
            off += len(block)
            if not data:
                break


def _valid_events(rows: np.ndarray) -> np.ndarray:
    """Events ``t x y p`` that can be: finite, time within int64 µs, coordinates 0..65535."""
    t, x, y, p = rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3]
    return (
        np.isfinite(rows).all(axis=1)
        & (np.abs(t) < 9e12)
        & (x >= 0)
        & (x <= 65535)
        & (y >= 0)
        & (y <= 65535)
        & np.isfinite(p)
    )


def _valid_imu(rows: np.ndarray) -> np.ndarray:
    return np.isfinite(rows).all(axis=1) & (np.abs(rows[:, 0]) < 9e12)


#: Largest image file read (a frame of the largest sensor, uncompressed, is 4 MB; 16-bit colour 24 MB).
MAX_IMAGE_BYTES = 64 << 20


def _imread(file: Path):
    """The image at ``file`` (OpenCV, unchanged depth), or None if it cannot be read.

    The bytes are read here and decoded from memory: OpenCV's own file opening takes a UTF-8 name
    (a file name in another encoding crashed it), and a file over :data:`MAX_IMAGE_BYTES` is not an
    event camera's frame. OpenCV refuses images over ``OPENCV_IO_MAX_IMAGE_PIXELS`` (set by necviz
    to the largest sensor), so a small compressed file cannot expand into gigabytes."""
    import cv2

    try:
        if os.path.getsize(file) > MAX_IMAGE_BYTES:
            return None
        if not os.path.isfile(file):  # a named pipe would block
            return None
        with open(file, "rb") as f:
            data = np.frombuffer(f.read(), np.uint8)
        if not data.size:
            return None
        global _TRAP
        if _TRAP is None:
            _TRAP = StderrTrap()
        with _TRAP(discard=True):  # libpng/libjpeg complain about damaged images on stderr; we report it
            return cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    except (OSError, ValueError, cv2.error):
        return None


_TRAP = None


class RpgTextRecording(Recording):
    """Replay an RPG text recording (a folder with ``events.txt``, or that file)."""

    format = "rpg-text"

    def __init__(self, path, **kwargs):
        super().__init__(path, **kwargs)
        p = self.path
        self.events_path = p / "events.txt" if p.is_dir() else p
        folder = self.events_path.parent
        if not self.events_path.is_file():
            raise self.error("no events.txt")
        if os.path.getsize(self.events_path) == 0:
            raise RecordingError(f"{self.events_path}: empty file (0 bytes)")
        self.images_path = folder / "images.txt"
        self.imu_path = folder / "imu.txt"
        self._frames: list[tuple[int, Path]] = []
        if self.images_path.is_file():
            for _off, rows in self._image_lines():
                self._frames.append(rows)
        first_img = _imread(self._frames[0][1]) if self._frames else None
        if self.sensor is None and first_img is not None:
            self.sensor = SensorGeometry(int(first_img.shape[1]), int(first_img.shape[0]))
        if self.sensor is None:
            off, rows = next(numeric_blocks(self, self.events_path, 4, valid=_valid_events), (0, np.zeros((0, 4))))
            if rows.size == 0:
                raise self.error("no events in events.txt and no images to tell the sensor size")
            self.sensor = sensor_from_extent(int(rows[:, 1].max()), int(rows[:, 2].max()))
        if not self._frames:
            self.exposure_source = "none (no frames)"
        elif self.exposure_us is not None:
            self.exposure_source = "user (--exposure-us)"
        else:
            self.exposure_source = NO_EXPOSURE_FRAMES

    def _image_lines(self):
        folder = self.images_path.parent
        with open(self.images_path, "rb") as f:
            off = 0
            for line in f:
                s = line.strip()
                if s and not s.startswith(b"#"):
                    parts = s.split()
                    try:
                        t = int(round(float(parts[0]) * 1e6))
                        name = parts[1].decode()
                        if "\x00" in name:
                            raise ValueError("NUL in a file name")
                    except (ValueError, IndexError, OverflowError):
                        raise RecordingError(f"{self.images_path}: unparsable line {s[:40]!r} at byte {off}") from None
                    yield off, (t, folder / name)
                off += len(line)

    def _ts_at(self, f, off: int) -> tuple[int, float | None]:
        """(offset of the next line start at/after ``off``, its timestamp in s)."""
        f.seek(off)
        if off:
            f.readline()
        pos = f.tell()
        while True:
            line = f.readline()
            if not line:
                return pos, None
            s = line.strip()
            if s and not s.startswith(b"#"):
                try:
                    return pos, float(s.split()[0])
                except ValueError:
                    return pos, None
            pos = f.tell()

    def _seek(self) -> int:
        if self.start_us is None:
            return 0
        target = self.start_us / 1e6
        size = os.path.getsize(self.events_path)
        lo, hi = 0, size
        with open(self.events_path, "rb") as f:
            while hi - lo > 4096:
                mid = (lo + hi) // 2
                pos, t = self._ts_at(f, mid)
                if t is None or t >= target:
                    hi = mid
                else:
                    lo = mid
            return self._ts_at(f, lo)[0]

    def _load_frame(self, i: int, t: int, file: Path):
        img = _imread(file)
        if img is None:
            raise self.error(f"cannot read image {file}")
        span = self.frame_exposure_from_stamp(t, None)
        return Frame(to_gray8(img), span[0], span[1], 1.0, i)

    def _imu_blocks(self):
        if not self.imu_path.is_file():
            return
        for _, rows in numeric_blocks(self, self.imu_path, 7, valid=_valid_imu):
            if rows.shape[0] == 0:
                continue
            yield imu_from_si(np.rint(rows[:, 0] * 1e6).astype(np.int64), rows[:, 1:4], rows[:, 4:7])

    def _packets(self) -> Iterator:
        asm = StreamAssembler(self.sensor, start_us=self.start_us, end_us=self.end_us)
        use_frames = bool(self._frames) and self.exposure_us is not None
        if self._frames and not use_frames:
            self.warn(f"{len(self._frames)} frames skipped: images.txt stores no exposure; pass --exposure-us")
        return self._assembled(asm, self._feed(asm, use_frames))

    def _feed(self, asm: StreamAssembler, use_frames) -> Iterator:
        fi = 0
        imu_iter = self._imu_blocks()
        imu_next = next(imu_iter, None)
        for _off, rows in numeric_blocks(self, self.events_path, 4, self._seek(), valid=_valid_events):
            if rows.shape[0] == 0:
                continue
            ev = events_from_seconds(rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3])
            horizon = int(ev["t"][-1])
            while use_frames and fi < len(self._frames) and self._frames[fi][0] - self.exposure_us / 2 < horizon:
                t, file = self._frames[fi]
                if self.start_us is None or t >= self.start_us:  # (the assembler applies the exact range)
                    asm.push_frame(self._load_frame(fi, t, file))
                fi += 1
            while imu_next is not None and int(imu_next["t"][0]) < horizon:
                asm.push_imu(imu_next)
                imu_next = next(imu_iter, None)
            asm.push_events(ev)
            yield from asm.drain(horizon)
            if self.past_end(horizon):
                break
        else:
            while use_frames and fi < len(self._frames):
                asm.push_frame(self._load_frame(fi, *self._frames[fi]))
                fi += 1
            while imu_next is not None:
                asm.push_imu(imu_next)
                imu_next = next(imu_iter, None)
