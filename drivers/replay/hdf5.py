"""HDF5 event layouts: DSEC-style ``/events/{t,x,y,p}`` and MVSEC ``davis/left``.

* **DSEC** (``events.h5``): ``/events/t`` (µs, relative), ``/events/x``, ``/events/y``, ``/events/p``
  (0/1 -> -1/+1), optional ``/t_offset`` (µs, added to t) and ``/ms_to_idx`` (index of the first
  event at/after each millisecond, used for seeking; otherwise bisection on ``/events/t``). No frames.
  DSEC's own files use Blosc (HDF5 filter 32001): they are read when ``hdf5plugin`` is installed
  (imported if present); otherwise a one-line error names the missing filter.
* **MVSEC** (``<seq>_data.hdf5``): ``davis/left/events`` (N x 4 float64: x, y, t s, p ±1),
  ``davis/left/image_raw`` (N x H x W uint8) with ``image_raw_ts`` (s, mid-exposure stamps), and
  ``davis/left/imu`` / ``imu_ts`` when present (m/s², rad/s -> g, °/s). No exposure times: with
  ``exposure_us`` a frame's exposure is ``[stamp - exposure/2, stamp + exposure/2]``, otherwise frames
  are skipped with a warning. Seeking: bisection on the time column.

Streaming: slices of 2^18 events (bounded memory); times rounded to integer µs.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from ...core.events import EVENT_DTYPE
from ...core.frames import Frame
from ...core.sensor import DAVIS346, SensorGeometry
from .base import (NO_EXPOSURE_FRAMES, Recording, RecordingError, StreamAssembler, events_from_seconds,
                   imu_from_si, sensor_from_extent, to_gray8)

try:  # registers Blosc/Zstd/LZ4 HDF5 filters when installed (DSEC files need Blosc)
    import hdf5plugin  # noqa: F401
except ImportError:  # pragma: no cover - optional
    hdf5plugin = None

CHUNK = 1 << 18


def open_hdf5(path, **kwargs) -> Recording:
    """Open an HDF5 recording, choosing the layout by its groups."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            keys = sorted(f.keys())
            dsec = "events" in f and isinstance(f["events"], h5py.Group) and "t" in f["events"]
            mvsec = "davis" in f
    except OSError as exc:
        raise RecordingError(f"{path}: unreadable HDF5 file ({str(exc).splitlines()[0]})") from None
    if dsec:
        return DsecRecording(path, **kwargs)
    if mvsec:
        return MvsecRecording(path, **kwargs)
    raise RecordingError(f"{path}: HDF5 file with an unknown layout (top-level groups {keys}); "
                         "supported: DSEC /events/{t,x,y,p}, MVSEC davis/left/events")


class _Hdf5Recording(Recording):
    def _open(self):
        import h5py

        try:
            return h5py.File(self.path, "r")
        except OSError as exc:
            raise self.error(f"unreadable HDF5 file ({str(exc).splitlines()[0]})") from None

    def _read(self, ds, sl):
        try:
            return ds[sl]
        except OSError as exc:
            msg = str(exc).splitlines()[0]
            if "filter" in msg.lower():
                filters = ", ".join(str(k) for k in ds._filters) or "unknown"
                raise self.error(f"dataset {ds.name} uses an HDF5 compression filter that is not available "
                                 f"({filters}; DSEC uses Blosc: pip install hdf5plugin)") from None
            raise self.error(f"cannot read {ds.name} ({msg})") from None

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
            g = f["events"]
            missing = [k for k in "txyp" if k not in g]
            if missing:
                raise self.error(f"/events lacks dataset(s) {', '.join(missing)}")
            self.n = int(g["t"].shape[0])
            if any(int(g[k].shape[0]) != self.n for k in "xyp"):
                raise self.error("/events/{t,x,y,p} have different lengths")
            self.t_offset = int(self._read(f["t_offset"], ())) if "t_offset" in f else 0
            if self.sensor is None:
                w = f.attrs.get("width") or g.attrs.get("width")
                h = f.attrs.get("height") or g.attrs.get("height")
                if w and h:
                    self.sensor = SensorGeometry(int(w), int(h))
                else:
                    k = min(self.n, 1 << 22)
                    if k == 0:
                        raise self.error("no events and no width/height attributes; pass a sensor geometry")
                    self.sensor = sensor_from_extent(int(self._read(g["x"], slice(0, k)).max()),
                                                     int(self._read(g["y"], slice(0, k)).max()))
            else:
                self._read(g["t"], slice(0, 1))
        self.exposure_source = "none (no frames)"

    def _first_index(self, f) -> int:
        if self.start_us is None:
            return 0
        rel = self.start_us - self.t_offset
        if "ms_to_idx" in f and rel >= 0:
            m2i = f["ms_to_idx"]
            ms = rel // 1000
            if ms < m2i.shape[0]:
                return int(self._read(m2i, ms))
        t = f["events"]["t"]
        return self._bisect(lambda i: int(self._read(t, i)), self.n, rel)

    def _packets(self) -> Iterator:
        asm = StreamAssembler(self.sensor, start_us=self.start_us, end_us=self.end_us)
        return self._assembled(asm, self._feed(asm))

    def _feed(self, asm: StreamAssembler) -> Iterator:
        with self._open() as f:
            g = f["events"]
            for i in range(self._first_index(f), self.n, CHUNK):
                sl = slice(i, min(i + CHUNK, self.n))
                t = self._read(g["t"], sl).astype(np.int64) + self.t_offset
                ev = np.empty(t.size, EVENT_DTYPE)
                ev["t"] = t
                ev["x"] = self._read(g["x"], sl)
                ev["y"] = self._read(g["y"], sl)
                ev["p"] = np.where(self._read(g["p"], sl) > 0, 1, -1)
                asm.push_events(ev)
                yield from asm.drain(int(t[-1]))
                if self.past_end(int(t[0])):
                    break


class MvsecRecording(_Hdf5Recording):
    """MVSEC ``davis/<camera>`` HDF5 (see the module docstring)."""

    format = "hdf5-mvsec"

    def __init__(self, path, *, camera: str = "left", **kwargs):
        super().__init__(path, **kwargs)
        self.group = f"davis/{camera}"
        with self._open() as f:
            if self.group not in f or "events" not in f[self.group]:
                raise self.error(f"no {self.group}/events dataset")
            g = f[self.group]
            ev = g["events"]
            if ev.ndim != 2 or ev.shape[1] < 4:
                raise self.error(f"{self.group}/events must be N x 4 (x, y, t, p), got {ev.shape}")
            self.n = int(ev.shape[0])
            self.n_frames = int(g["image_raw"].shape[0]) if "image_raw" in g and "image_raw_ts" in g else 0
            if self.sensor is None:
                if self.n_frames:
                    h, w = g["image_raw"].shape[1:3]
                    self.sensor = DAVIS346 if (w, h) == (346, 260) else SensorGeometry(int(w), int(h))
                elif self.n:
                    head = self._read(ev, slice(0, min(self.n, 1 << 20)))
                    self.sensor = sensor_from_extent(int(head[:, 0].max()), int(head[:, 1].max()))
                else:
                    raise self.error("no events or images; pass a sensor geometry")
            self.has_imu = "imu" in g and "imu_ts" in g
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

    def _feed(self, asm: StreamAssembler, use_frames) -> Iterator:
        with self._open() as f:
            g = f[self.group]
            ev_ds = g["events"]
            stamps = np.rint(self._read(g["image_raw_ts"], slice(None)) * 1e6).astype(np.int64) \
                if use_frames else np.zeros(0, np.int64)
            imu_t = np.rint(self._read(g["imu_ts"], slice(None)) * 1e6).astype(np.int64) \
                if self.has_imu else np.zeros(0, np.int64)
            half = 0 if self.exposure_us is None else self.exposure_us / 2
            i0 = 0
            if self.start_us is not None:
                i0 = self._bisect(lambda i: float(self._read(ev_ds, (i, 2))), self.n, self.start_us / 1e6)
                fi = int(np.searchsorted(stamps, self.start_us))
                ii = int(np.searchsorted(imu_t, self.start_us))
            else:
                fi = ii = 0
            for i in range(i0, self.n, CHUNK):
                rows = self._read(ev_ds, slice(i, min(i + CHUNK, self.n)))
                ev = events_from_seconds(rows[:, 2], rows[:, 0], rows[:, 1], rows[:, 3])
                horizon = int(ev["t"][-1]) if ev.size else 0
                last = i + CHUNK >= self.n
                while fi < stamps.size and (last or stamps[fi] - half < horizon):
                    span = self.frame_exposure_from_stamp(int(stamps[fi]), None)
                    img = to_gray8(self._read(g["image_raw"], fi))
                    asm.push_frame(Frame(img, span[0], span[1], 1.0, fi))
                    fi += 1
                if ii < imu_t.size:
                    jj = imu_t.size if last else int(np.searchsorted(imu_t, horizon))
                    if jj > ii:
                        raw = self._read(g["imu"], slice(ii, jj))
                        asm.push_imu(imu_from_si(imu_t[ii:jj], raw[:, 0:3], raw[:, 3:6]))
                        ii = jj
                asm.push_events(ev)
                yield from asm.drain(horizon)
                if self.past_end(horizon):
                    break
