"""HDF5 event layouts: DSEC-style ``/events/{t,x,y,p}`` and MVSEC ``davis/left``.

* **DSEC** (``events.h5``): ``/events/t`` (µs, relative), ``/events/x``, ``/events/y``, ``/events/p``
  (0/1 -> -1/+1), optional ``/t_offset`` (µs, added to t) and ``/ms_to_idx`` (index of the first
  event at/after each millisecond, used for seeking; otherwise bisection on ``/events/t``). DSEC's own
  files hold no frames; files written by ``necviz export`` add ``/frames/{images, exposure_start_us,
  exposure_end_us, gain}``, ``/imu/{t, accel, gyro, temp}`` and ``/triggers/{t, kind}`` (times relative
  to ``/t_offset`` too; :mod:`necviz.writers.hdf5_writer`), which are replayed with their stored exposures.
  DSEC's own files use Blosc (HDF5 filter 32001): they are read when ``hdf5plugin`` is installed
  (imported if present); otherwise a one-line error names the missing filter.
* **MVSEC** (``<seq>_data.hdf5``): ``davis/left/events`` (N x 4 float64: x, y, t s, p ±1),
  ``davis/left/image_raw`` (N x H x W uint8) with ``image_raw_ts`` (s, mid-exposure stamps), and
  ``davis/left/imu`` / ``imu_ts`` when present (m/s², rad/s -> g, °/s). No exposure times: with
  ``exposure_us`` a frame's exposure is ``[stamp - exposure/2, stamp + exposure/2]``, otherwise frames
  are skipped with a warning. Seeking: bisection on the time column.

Streaming: slices of 2^18 events (bounded memory); times rounded to integer µs.

Bounded by what the file holds, not by what it declares (:meth:`_Hdf5Recording._dataset`): a
dataset without compression must have its declared bytes stored in the file (HDF5 reads
unallocated chunks as zeros, so a 3 kB file could declare 2^38 events); a compressed one may
expand at most :data:`MAX_RATIO` times (gzip's limit is about 1032) beyond 64 MiB, in chunks of at
most :data:`MAX_CHUNK_BYTES`; a dataset read whole (time stamps) holds at most :data:`MAX_WHOLE_BYTES`.
Anything else is a one-line :class:`RecordingError` naming the dataset, before any of it is read.
"""

from __future__ import annotations

import os
from collections.abc import Iterator

import numpy as np

from necviz.core.events import EVENT_DTYPE
from necviz.core.frames import Frame
from necviz.core.imu import IMU_DTYPE, TRIGGER_DTYPE, TRIGGER_KINDS
from necviz.core.sensor import DAVIS346, SensorGeometry
from necviz.drivers.recordings.reader import (
    NO_EXPOSURE_FRAMES,
    Recording,
    RecordingError,
    StreamAssembler,
    first_line,
    imu_from_si,
    is_damage,
    reason,
    sensor_from_extent,
    to_gray8,
)

try:  # registers Blosc/Zstd/LZ4 HDF5 filters when installed (DSEC files need Blosc)
    import hdf5plugin  # noqa: F401
except ImportError:  # pragma: no cover - optional
    hdf5plugin = None

CHUNK = 1 << 18
#: Largest expansion of a compressed dataset above 64 MiB (gzip/deflate cannot exceed ~1032:1).
MAX_RATIO = 1100
#: Largest HDF5 chunk decompressed at once (HDF5 decompresses whole chunks).
MAX_CHUNK_BYTES = 64 << 20
#: Largest dataset read in one piece (frame and IMU time stamps).
MAX_WHOLE_BYTES = 256 << 20


def _show(sl) -> str:
    """A dataset index as text: ``a:b`` for slices, else the index."""
    if isinstance(sl, slice):
        return f"{'' if sl.start is None else sl.start}:{'' if sl.stop is None else sl.stop}"
    return str(sl)


def _valid_rows(t, x, y, p, n: int, t_scale: float):
    """Event columns checked for damage: ``(t µs int64, x, y, p, first bad row or None)``.

    A row is bad if a value is not numeric or finite, a coordinate is negative or above 65535, or
    the time (``t * t_scale`` µs) does not fit in int64; only the rows before the first bad one are
    returned. Columns of the wrong shape make row 0 bad."""
    cols = [np.asarray(c) for c in (t, x, y, p)]
    if any(c.ndim != 1 or c.shape[0] != n or c.dtype.kind not in "biuf" for c in cols):
        z = np.zeros(0, np.int64)
        return z, z, z, z, 0
    t, x, y, p = (c.astype(np.float64) if c.dtype.kind == "f" else c for c in cols)
    with np.errstate(over="ignore", invalid="ignore"):  # damaged values overflow here: they are refused
        return _check_rows(t, x, y, p, n, t_scale)


def _check_rows(t, x, y, p, n: int, t_scale: float):
    ok = np.ones(n, bool)
    for c in (t, x, y, p):
        if c.dtype.kind == "f":
            ok &= np.isfinite(c)
    for c in (x, y):
        ok &= (c >= 0) & (c <= 65535)
    if t.dtype.kind == "u" and t.dtype.itemsize == 8:
        ok &= t < (1 << 62)
    elif t.dtype.kind == "f" or t_scale != 1.0:
        ok &= np.abs(t.astype(np.float64)) * t_scale < 9e18
    bad = None
    if not ok.all():
        bad = int(np.argmin(ok))
        t, x, y, p = t[:bad], x[:bad], y[:bad], p[:bad]
    tt = np.rint(t * t_scale).astype(np.int64) if t.dtype.kind == "f" or t_scale != 1.0 else t.astype(np.int64)
    return tt, x, y, p, bad


def _mb(n: int) -> str:
    return f"{n / (1 << 20):,.1f} MB" if n >= 1 << 20 else f"{n:,} bytes"


def open_hdf5(path, **kwargs) -> Recording:
    """Open an HDF5 recording, choosing the layout by its groups.

    Every h5py call of this module runs inside :meth:`_Hdf5Recording._at` (or, here, an equivalent
    guard), so what h5py raises on a damaged file (OSError, KeyError, RuntimeError, ValueError,
    TypeError ...) becomes a one-line :class:`RecordingError` naming the file and the group or
    dataset being read."""
    import h5py

    where = "the root group"
    try:
        with h5py.File(path, "r") as f:
            keys = sorted(f.keys())
            where = "group /events"
            dsec = "events" in f and isinstance(f["events"], h5py.Group) and "t" in f["events"]
            where = "group /davis"
            mvsec = "davis" in f
    except BaseException as exc:
        if not is_damage(exc):
            raise
        raise RecordingError(f"{path}: unreadable HDF5 file ({reason(exc)}) at {where}") from None
    if dsec:
        return DsecRecording(path, **kwargs)
    if mvsec:
        return MvsecRecording(path, **kwargs)
    raise RecordingError(
        f"{path}: HDF5 file with an unknown layout (top-level groups {keys}); "
        "supported: DSEC /events/{t,x,y,p}, MVSEC davis/left/events"
    )


class _Hdf5Recording(Recording):
    def _at(self, where: str):
        """Guard for h5py calls: damage inside becomes a RecordingError "... at <where>"."""
        self._where = where
        return self.converting(where)

    def _open(self):
        import h5py

        try:
            return h5py.File(self.path, "r")
        except BaseException as exc:
            if not is_damage(exc):
                raise
            raise self.error(f"unreadable HDF5 file ({reason(exc)})") from None

    def _get(self, group, key: str):
        """``group[key]`` (a dataset or group), a RecordingError naming the key if that fails."""
        with self._at(f"key {key}"):
            name = f"{group.name.rstrip('/')}/{key}"
        with self._at(f"key {name}"):
            return group[key]

    def _dataset(self, group, key: str, *, whole: bool = False):
        """``group[key]``, checked: a dataset (not a group), whose declared size the file can hold (see
        the module docstring); ``whole``: it will be read in one piece."""
        import h5py

        ds = self._get(group, key)
        with self._at(f"key {key}"):
            name = f"{group.name.rstrip('/')}/{key}"
            if not isinstance(ds, h5py.Dataset):
                raise self.error(f"{name} is a {type(ds).__name__.lower()}, not a dataset")
        with self._at(f"dataset {name}"):
            n = int(ds.size or 0)
            declared = n * int(ds.dtype.itemsize)
            stored = int(ds.id.get_storage_size())
            compressed = bool(getattr(ds, "_filters", None))
            chunk = ds.chunks
        size = os.path.getsize(self.path)
        if stored > size:
            raise self.error(f"dataset {name} claims {stored:,} bytes of storage in a file of {size:,} bytes")
        if not compressed and declared > stored:
            raise self.error(
                f"dataset {name} declares {n:,} entries ({_mb(declared)}) but the file holds {stored:,} bytes "
                "of them (damaged, truncated or sparse file)"
            )
        if compressed and chunk is not None:
            chunk_bytes = int(np.prod(chunk, dtype=np.float64)) * int(ds.dtype.itemsize)
            if chunk_bytes > MAX_CHUNK_BYTES:
                raise self.error(
                    f"dataset {name} is compressed in chunks of {_mb(chunk_bytes)} (at most "
                    f"{_mb(MAX_CHUNK_BYTES)} are decompressed at once)"
                )
        if compressed and declared > 64 << 20 and declared > MAX_RATIO * max(stored, 1):
            raise self.error(
                f"dataset {name} would decompress to {_mb(declared)} from {stored:,} bytes (more than "
                f"{MAX_RATIO}:1): a decompression bomb or a damaged file"
            )
        if whole and declared > MAX_WHOLE_BYTES:
            raise self.error(f"dataset {name} holds {_mb(declared)}, more than necviz reads at once")
        return ds

    def _read(self, ds, sl):
        """``ds[sl]``; a missing compression filter or damage becomes a RecordingError naming the dataset."""
        with self._at("a dataset"):
            name = ds.name
        where = f"dataset {name}" + ("" if isinstance(sl, tuple) and not sl or sl == slice(None) else f" [{_show(sl)}]")
        self._where = where
        try:
            return ds[sl]
        except BaseException as exc:
            if not is_damage(exc):
                raise
            if isinstance(exc, OSError) and "filter" in first_line(exc).lower():
                filters = ", ".join(str(k) for k in getattr(ds, "_filters", {})) or "unknown"
                raise self.error(
                    f"dataset {name} uses an HDF5 compression filter that is not available "
                    f"({filters}; DSEC uses Blosc: pip install hdf5plugin)"
                ) from None
            raise self.damage(exc, where) from None

    @staticmethod
    def _bisect(get, n: int, target: float) -> int:
        lo, hi = 0, n
        while lo < hi:
            mid = (lo + hi) // 2
            if get(mid) < target:
                lo = mid + 1
            else:
                hi = mid
        return lo


class DsecRecording(_Hdf5Recording):
    """DSEC-style ``/events/{t,x,y,p}`` HDF5 (see the module docstring)."""

    format = "hdf5-dsec"

    def __init__(self, path, **kwargs):
        kwargs.pop("exposure_us", None)
        super().__init__(path, **kwargs)
        with self._open() as f:
            g = self._get(f, "events")
            with self._at("group /events"):
                missing = [k for k in "txyp" if k not in g]
            if missing:
                raise self.error(f"/events lacks dataset(s) {', '.join(missing)}")
            ds = {k: self._dataset(g, k) for k in "txyp"}
            with self._at("dataset /events/t"):
                self.n = int(ds["t"].shape[0]) if ds["t"].ndim == 1 else -1
            if self.n < 0:
                raise self.error("/events/t is not a 1-D dataset")
            with self._at("datasets /events/{x,y,p}"):
                if any(ds[k].ndim != 1 or int(ds[k].shape[0]) != self.n for k in "xyp"):
                    raise self.error("/events/{t,x,y,p} have different lengths")
            with self._at("key /t_offset"):
                has_offset = "t_offset" in f
            self.t_offset = 0
            if has_offset:
                v = np.asarray(self._read(self._dataset(f, "t_offset", whole=True), ())).reshape(-1)
                if v.size != 1 or v.dtype.kind not in "iuf" or not abs(float(v[0])) < 2.0**62:
                    raise self.error("t_offset is not one integer number of µs", "dataset /t_offset")
                self.t_offset = int(v[0])
            if self.sensor is None:
                with self._at("width/height attributes"):
                    w = f.attrs.get("width") or g.attrs.get("width")
                    h = f.attrs.get("height") or g.attrs.get("height")
                if w and h:
                    self.sensor = SensorGeometry(int(w), int(h))
                else:
                    k = min(self.n, 1 << 22)
                    if k == 0:
                        raise self.error("no events and no width/height attributes; pass a sensor geometry")
                    self.sensor = sensor_from_extent(
                        int(self._read(ds["x"], slice(0, k)).max()), int(self._read(ds["y"], slice(0, k)).max())
                    )
            else:
                self._read(ds["t"], slice(0, 1))
            with self._at("groups /frames, /imu, /triggers"):
                self.n_frames = int(f["frames/exposure_start_us"].shape[0]) if "frames/exposure_start_us" in f else 0
                self.has_imu = "imu/t" in f
                self.has_triggers = "triggers/t" in f
        self.exposure_source = "stored" if self.n_frames else "none (no frames)"

    def _side_streams(self, f):
        """The frames' exposures and the IMU / trigger columns of a file written by ``necviz export``."""
        out = {}
        if self.n_frames:
            g = self._get(f, "frames")
            s = np.asarray(self._read(self._dataset(g, "exposure_start_us"), slice(None)), np.int64) + self.t_offset
            e = np.asarray(self._read(self._dataset(g, "exposure_end_us"), slice(None)), np.int64) + self.t_offset
            gain = np.asarray(self._read(self._dataset(g, "gain"), slice(None)), np.float64) if "gain" in g else None
            out["frames"] = (s, e, gain, self._dataset(g, "images"))
        if self.has_imu:
            g = self._get(f, "imu")
            t = np.asarray(self._read(self._dataset(g, "t"), slice(None)), np.int64)
            imu = np.empty(t.size, IMU_DTYPE)
            imu["t"] = t + self.t_offset
            acc = np.asarray(self._read(self._dataset(g, "accel"), slice(None)), np.float32).reshape(-1, 3)
            gyr = np.asarray(self._read(self._dataset(g, "gyro"), slice(None)), np.float32).reshape(-1, 3)
            for k, axis in enumerate("xyz"):
                imu[f"a{axis}"], imu[f"g{axis}"] = acc[:, k], gyr[:, k]
            imu["temp"] = self._read(self._dataset(g, "temp"), slice(None)) if "temp" in g else np.nan
            out["imu"] = imu
        if self.has_triggers:
            g = self._get(f, "triggers")
            t = np.asarray(self._read(self._dataset(g, "t"), slice(None)), np.int64)
            trg = np.empty(t.size, TRIGGER_DTYPE)
            trg["t"] = t + self.t_offset
            trg["kind"] = self._read(self._dataset(g, "kind"), slice(None))
            out["triggers"] = trg[(trg["kind"] >= 0) & (trg["kind"] < len(TRIGGER_KINDS))]
        return out

    def _push_side(self, asm: StreamAssembler, side: dict, cursor: dict, horizon: int | None) -> None:
        """Push the frames, IMU samples and triggers that start before ``horizon`` (None: all that remain)."""
        if "frames" in side:
            s, e, gain, images = side["frames"]
            i = cursor.get("frames", 0)
            while i < s.size and (horizon is None or s[i] < horizon):
                if self.exposure_in_range(int(s[i]), int(e[i])) and e[i] > s[i]:
                    img = to_gray8(np.asarray(self._read(images, i)))
                    g = float(gain[i]) if gain is not None and np.isfinite(gain[i]) and gain[i] >= 1 else 1.0
                    asm.push_frame(Frame(img, int(s[i]), int(e[i]), g, i))
                i += 1
            cursor["frames"] = i
        for key, push in (("imu", asm.push_imu), ("triggers", asm.push_triggers)):
            if key in side:
                arr, i = side[key], cursor.get(key, 0)
                j = arr.size if horizon is None else int(np.searchsorted(arr["t"], horizon, side="left"))
                if j > i:
                    push(arr[i:j])
                cursor[key] = max(i, j)

    def _first_index(self, f) -> int:
        if self.start_us is None:
            return 0
        rel = self.start_us - self.t_offset
        with self._at("key /ms_to_idx"):
            has_index = "ms_to_idx" in f
        if has_index and rel >= 0:
            m2i = self._dataset(f, "ms_to_idx")
            ms = rel // 1000
            if ms < m2i.shape[0]:
                return min(max(int(self._read(m2i, ms)), 0), self.n)
        t = self._get(self._get(f, "events"), "t")
        return self._bisect(lambda i: int(self._read(t, i)), self.n, rel)

    def _packets(self) -> Iterator:
        asm = StreamAssembler(self.sensor, start_us=self.start_us, end_us=self.end_us)
        return self._assembled(asm, self._feed(asm))

    def _feed(self, asm: StreamAssembler) -> Iterator:
        with self._open() as f:
            g = self._get(f, "events")
            ds = {k: self._dataset(g, k) for k in "txyp"}
            side = self._side_streams(f)
            cursor: dict = {}
            for i in range(self._first_index(f), self.n, CHUNK):
                sl = slice(i, min(i + CHUNK, self.n))
                cols = [self._read(ds[k], sl) for k in "txyp"]
                t, x, y, p, bad = _valid_rows(cols[0], cols[1], cols[2], cols[3], sl.stop - sl.start, 1.0)
                ev = np.empty(t.size, EVENT_DTYPE)
                ev["t"] = t + self.t_offset
                ev["x"] = x
                ev["y"] = y
                ev["p"] = np.where(p > 0, 1, -1)
                asm.push_events(ev)
                if bad is not None:
                    raise self.error(
                        "non-numeric, non-finite or negative values in /events/{t,x,y,p}",
                        f"dataset /events row {i + bad}",
                    )
                if ev.size:
                    self._push_side(asm, side, cursor, int(ev["t"][-1]))
                    yield from asm.drain(int(ev["t"][-1]))
                    if self.past_end(int(ev["t"][0])):
                        break
            self._push_side(asm, side, cursor, None if self.end_us is None else self.end_us)


class MvsecRecording(_Hdf5Recording):
    """MVSEC ``davis/<camera>`` HDF5 (see the module docstring)."""

    format = "hdf5-mvsec"

    def __init__(self, path, *, camera: str = "left", **kwargs):
        super().__init__(path, **kwargs)
        self.group = f"davis/{camera}"
        with self._open() as f:
            with self._at(f"group /{self.group}"):
                found = self.group in f and "events" in f[self.group]
            if not found:
                raise self.error(f"no {self.group}/events dataset")
            g = self._get(f, self.group)
            ev = self._dataset(g, "events")
            with self._at(f"dataset /{self.group}/events"):
                shape = tuple(int(v) for v in ev.shape) if ev.shape is not None else ()
            if len(shape) != 2 or shape[1] < 4:
                raise self.error(f"{self.group}/events must be N x 4 (x, y, t, p), got {shape}")
            self.n = shape[0]
            with self._at(f"group /{self.group}"):
                has_images = "image_raw" in g and "image_raw_ts" in g
                self.has_imu = "imu" in g and "imu_ts" in g
            self.n_frames = 0
            if has_images:
                img = self._dataset(g, "image_raw")
                with self._at(f"dataset /{self.group}/image_raw"):
                    ishape = tuple(int(v) for v in img.shape) if img.shape is not None else ()
                if len(ishape) not in (3, 4) or min(ishape) <= 0:
                    raise self.error(f"{self.group}/image_raw must be N x H x W, got {ishape}")
                self.n_frames = ishape[0]
            if self.sensor is None:
                if self.n_frames:
                    h, w = ishape[1:3]
                    self.sensor = DAVIS346 if (w, h) == (346, 260) else SensorGeometry(int(w), int(h))
                elif self.n:
                    head = self._read(ev, slice(0, min(self.n, 1 << 20)))
                    _, x, y, _, bad = _valid_rows(head[:, 2], head[:, 0], head[:, 1], head[:, 3], head.shape[0], 1e6)
                    if x.size == 0:
                        raise self.error(
                            "no readable events to tell the sensor size; pass a sensor geometry",
                            f"dataset /{self.group}/events row {bad or 0}",
                        )
                    self.sensor = sensor_from_extent(int(x.max()), int(y.max()))
                else:
                    raise self.error("no events or images; pass a sensor geometry")
        if not self.n_frames:
            self.exposure_source = "none (no frames)"
        elif self.exposure_us is not None:
            self.exposure_source = "user (--exposure-us)"
        else:
            self.exposure_source = NO_EXPOSURE_FRAMES

    def _packets(self) -> Iterator:
        asm = StreamAssembler(self.sensor, start_us=self.start_us, end_us=self.end_us)
        use_frames = self.n_frames and self.exposure_us is not None
        if self.n_frames and not use_frames:
            self.warn(f"{self.n_frames} frames skipped: MVSEC stores no exposure; pass --exposure-us")
        return self._assembled(asm, self._feed(asm, use_frames))

    def _times(self, g, key: str) -> np.ndarray:
        """A time column in seconds -> int64 µs (a RecordingError if it holds non-finite values)."""
        ds = self._dataset(g, key, whole=True)
        v = np.asarray(self._read(ds, slice(None)), np.float64).reshape(-1)
        ok = np.isfinite(v) & (np.abs(v) < 9e12)
        if not ok.all():
            raise self.error("non-finite or absurd time stamps", f"dataset {ds.name} row {int(np.argmin(ok))}")
        return np.rint(v * 1e6).astype(np.int64)

    def _feed(self, asm: StreamAssembler, use_frames) -> Iterator:
        with self._open() as f:
            g = self._get(f, self.group)
            ev_ds = self._dataset(g, "events")
            stamps = self._times(g, "image_raw_ts") if use_frames else np.zeros(0, np.int64)
            stamps = stamps[: self.n_frames]
            imu_t = self._times(g, "imu_ts") if self.has_imu else np.zeros(0, np.int64)
            img_ds = self._dataset(g, "image_raw") if use_frames else None
            imu_ds = self._dataset(g, "imu") if self.has_imu else None
            half = 0 if self.exposure_us is None else self.exposure_us / 2
            i0 = 0
            if self.start_us is not None:
                i0 = self._bisect(lambda i: float(self._read(ev_ds, (i, 2))), self.n, self.start_us / 1e6)
                fi = int(np.searchsorted(stamps, self.start_us))
                ii = int(np.searchsorted(imu_t, self.start_us))
            else:
                fi = ii = 0
            for i in range(i0, self.n, CHUNK):
                rows = np.asarray(self._read(ev_ds, slice(i, min(i + CHUNK, self.n))))
                if rows.ndim != 2 or rows.shape[1] < 4:
                    raise self.error("events are not N x 4", f"dataset {ev_ds.name} rows [{i}:]")
                t, x, y, p, bad = _valid_rows(rows[:, 2], rows[:, 0], rows[:, 1], rows[:, 3], rows.shape[0], 1e6)
                ev = np.empty(t.size, EVENT_DTYPE)
                ev["t"], ev["x"], ev["y"], ev["p"] = t, x, y, np.where(p > 0, 1, -1)
                if bad is not None:
                    asm.push_events(ev)
                    raise self.error(
                        "non-finite or negative values in the events (x, y, t, p)",
                        f"dataset {ev_ds.name} row {i + bad}",
                    )
                horizon = int(ev["t"][-1]) if ev.size else 0
                last = i + CHUNK >= self.n
                while fi < stamps.size and (last or stamps[fi] - half < horizon):
                    span = self.frame_exposure_from_stamp(int(stamps[fi]), None)
                    img = to_gray8(self._read(img_ds, fi))
                    if img.ndim == 2:
                        asm.push_frame(Frame(img, span[0], span[1], 1.0, fi))
                    fi += 1
                if ii < imu_t.size:
                    jj = imu_t.size if last else int(np.searchsorted(imu_t, horizon))
                    if jj > ii:
                        raw = np.asarray(self._read(imu_ds, slice(ii, jj)), np.float64)
                        if raw.ndim != 2 or raw.shape[1] < 6 or raw.shape[0] != jj - ii:
                            raise self.error("IMU samples are not N x 6", f"dataset {imu_ds.name} rows [{ii}:{jj}]")
                        asm.push_imu(imu_from_si(imu_t[ii:jj], raw[:, 0:3], raw[:, 3:6]))
                        ii = jj
                asm.push_events(ev)
                yield from asm.drain(horizon)
                if self.past_end(horizon):
                    break
