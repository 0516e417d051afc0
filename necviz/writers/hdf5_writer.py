"""HDF5 in the DSEC event layout, with frames, their exposures, IMU and triggers beside the events.

Layout (all times integer µs, relative to ``/t_offset``; ``necviz replay``/``export`` read it back)::

    /events/t  int64    /events/x  uint16    /events/y  uint16    /events/p  uint8 (1 ON, 0 OFF)
    /ms_to_idx uint64   index of the first event at or after each millisecond (DSEC's seek table)
    /t_offset  int64    added to every time below to give the recording's own clock
    /frames/images               uint8 N x H x W (row-major, (0,0) top-left)
    /frames/exposure_start_us    int64 N        /frames/exposure_end_us  int64 N
    /frames/gain                 float64 N (linear, >= 1)
    /imu/t int64, /imu/accel float32 N x 3 (g), /imu/gyro float32 N x 3 (°/s), /imu/temp float32 (°C)
    /triggers/t int64, /triggers/kind int8 (index into necviz.core.imu.TRIGGER_KINDS)

Root attributes ``width``, ``height`` (the sensor) and ``producer``. The event columns are separate
datasets as in DSEC (https://dsec.ifi.uzh.ch/data-format/), chunked (2^16 events) and compressed
with gzip + shuffle, which every HDF5 build reads (DSEC's own files use Blosc, which needs
``hdf5plugin``); frames are one chunk each. Datasets grow as packets arrive: memory stays bounded.

The HDF5 library writes through :class:`DiskFile`, a Python file object: a write the OS refuses (a
full disk) is kept and raised by the writer's next call, while the library itself is told it
succeeded. The HDF5 library cannot recover from a failed write of its own (its close then crashes the
process); the file is deleted by the caller anyway, so what it held after the failure does not matter.
"""

from __future__ import annotations

import os

import numpy as np

from necviz.core.events import EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import ImuBatch, TriggerBatch

EVENT_CHUNK = 1 << 16
COMPRESSION = {"compression": "gzip", "compression_opts": 4, "shuffle": True}


class DiskFile:
    """A file h5py writes through (``h5py.File(DiskFile(path), "w")``) that never fails a write.

    The first OS error (``ENOSPC``, ``EFBIG``, ``EIO``) is kept in :attr:`error`; from then on writes
    are dropped and reported as done, reads return what the file holds (zeros past its end)."""

    def __init__(self, path):
        self._f = open(path, "w+b", buffering=0)  # noqa: SIM115 - closed by close()
        self.error: OSError | None = None

    def _failed(self, exc: OSError) -> None:
        if self.error is None:
            self.error = exc

    def write(self, data) -> int:
        n = len(memoryview(data).cast("B"))
        if self.error is not None:
            self._f.seek(n, os.SEEK_CUR)
            return n
        try:
            with memoryview(data).cast("B") as view:
                while view:
                    view = view[self._f.write(view) :]
        except OSError as exc:
            self._failed(exc)
        return n

    def read(self, n: int = -1) -> bytes:
        data = self._f.read(n)
        return data + bytes(max(0, n - len(data))) if n is not None and n >= 0 else data

    def readinto(self, buf) -> int:
        data = self.read(len(memoryview(buf).cast("B")))
        memoryview(buf).cast("B")[: len(data)] = data
        return len(data)

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        return self._f.seek(offset, whence)

    def tell(self) -> int:
        return self._f.tell()

    def truncate(self, size: int | None = None) -> int:
        if self.error is None:
            try:
                return self._f.truncate(size)
            except OSError as exc:
                self._failed(exc)
        return self._f.tell() if size is None else size

    def flush(self) -> None:
        pass

    def seekable(self) -> bool:
        return True

    def readable(self) -> bool:
        return True

    def writable(self) -> bool:
        return True

    def close(self) -> None:
        self._f.close()


class Hdf5Writer:
    """Write stream packets to an HDF5 file in the layout of the module docstring.

    Parameters
    ----------
    path : the file to create.
    sensor : :class:`~necviz.core.sensor.SensorGeometry`.
    t_offset_us : the time subtracted from every stored time (default: the first packet's).
    """

    def __init__(self, path, sensor, *, t_offset_us: int | None = None, properties: dict | None = None):
        import h5py

        self.sensor = sensor
        self._disk = DiskFile(path)
        try:
            self._f = h5py.File(self._disk, "w")
        except BaseException:
            self._disk.close()
            raise
        self._f.attrs["width"] = sensor.width
        self._f.attrs["height"] = sensor.height
        self._f.attrs["producer"] = "necviz export"
        for k, v in (properties or {}).items():
            self._f.attrs[f"necviz.{k}"] = str(v)
        self.t_offset = t_offset_us
        g = self._f.create_group("events")
        self._ev = {
            k: g.create_dataset(k, (0,), dtype=dt, maxshape=(None,), chunks=(EVENT_CHUNK,), **COMPRESSION)
            for k, dt in (("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "u1"))
        }
        self._ms_to_idx: list[np.ndarray] = []
        self._next_ms = 0
        self._n = 0
        self._frames = None
        self._imu = None
        self._trg = None
        self.counts = {"events": 0, "frames": 0, "imu": 0, "triggers": 0}
        self._closed = False

    def _offset(self, t: int) -> int:
        if self.t_offset is None:
            self.t_offset = int(t)
        return self.t_offset

    @staticmethod
    def _append(ds, values) -> None:
        n = ds.shape[0]
        ds.resize((n + len(values),) + ds.shape[1:])
        ds[n:] = values

    def _group(self, name: str, spec: dict):
        g = self._f.create_group(name)
        out = {}
        for k, (dt, shape, chunks) in spec.items():
            kw = COMPRESSION if chunks is not None else {}
            out[k] = g.create_dataset(
                k, (0, *shape), dtype=dt, maxshape=(None, *shape), chunks=chunks or (1024, *shape), **kw
            )
        return out

    def write(self, packet) -> None:
        """Append one stream packet (events, frame, IMU or trigger batch; markers are implied by frames).

        Raises the OS error of a write the disk refused (a full disk), at the first call after it."""
        if self._disk.error is not None:
            raise self._disk.error
        self._write(packet)

    def _write(self, packet) -> None:
        if isinstance(packet, EventBatch):
            packet = packet.events
        if isinstance(packet, np.ndarray):
            if not len(packet):
                return
            rel = packet["t"] - self._offset(int(packet["t"][0]))
            for k, v in (("t", rel), ("x", packet["x"]), ("y", packet["y"]), ("p", packet["p"] > 0)):
                self._append(self._ev[k], v)
            last_ms = int(rel[-1]) // 1000
            if last_ms >= self._next_ms:  # the seek table: first event at or after each new millisecond
                ms = np.arange(self._next_ms, last_ms + 1, dtype=np.int64)
                self._ms_to_idx.append(self._n + np.searchsorted(rel, ms * 1000, side="left").astype(np.uint64))
                self._next_ms = last_ms + 1
            self._n += len(packet)
            self.counts["events"] += len(packet)
        elif isinstance(packet, ExposureMarker):
            return
        elif isinstance(packet, Frame):
            off = self._offset(int(packet.exposure_start_us))
            if self._frames is None:
                h, w = packet.image.shape
                self._frames = self._group(
                    "frames",
                    {
                        "images": ("u1", (h, w), (1, h, w)),
                        "exposure_start_us": ("<i8", (), None),
                        "exposure_end_us": ("<i8", (), None),
                        "gain": ("<f8", (), None),
                    },
                )
            fr = self._frames
            self._append(fr["images"], packet.image[None])
            self._append(fr["exposure_start_us"], [int(packet.exposure_start_us) - off])
            self._append(fr["exposure_end_us"], [int(packet.exposure_end_us) - off])
            self._append(fr["gain"], [float(packet.gain)])
            self.counts["frames"] += 1
        elif isinstance(packet, ImuBatch) and len(packet):
            s = packet.samples
            off = self._offset(int(s["t"][0]))
            if self._imu is None:
                self._imu = self._group(
                    "imu",
                    {
                        "t": ("<i8", (), None),
                        "accel": ("<f4", (3,), None),
                        "gyro": ("<f4", (3,), None),
                        "temp": ("<f4", (), None),
                    },
                )
            self._append(self._imu["t"], s["t"] - off)
            self._append(self._imu["accel"], np.stack([s["ax"], s["ay"], s["az"]], 1))
            self._append(self._imu["gyro"], np.stack([s["gx"], s["gy"], s["gz"]], 1))
            self._append(self._imu["temp"], s["temp"])
            self.counts["imu"] += len(s)
        elif isinstance(packet, TriggerBatch) and len(packet):
            tr = packet.triggers
            off = self._offset(int(tr["t"][0]))
            if self._trg is None:
                self._trg = self._group("triggers", {"t": ("<i8", (), None), "kind": ("i1", (), None)})
            self._append(self._trg["t"], tr["t"] - off)
            self._append(self._trg["kind"], tr["kind"])
            self.counts["triggers"] += len(tr)

    def close(self) -> None:
        """Write the seek table and the time offset; close the file. Raises the OS error of a write
        the disk refused (the file is then incomplete: the caller deletes it)."""
        if self._closed:
            return
        self._closed = True
        try:
            m2i = np.concatenate(self._ms_to_idx) if self._ms_to_idx else np.zeros(0, np.uint64)
            self._f.create_dataset("ms_to_idx", data=m2i, **({"chunks": True, **COMPRESSION} if len(m2i) else {}))
            self._f.create_dataset("t_offset", data=np.int64(self.t_offset or 0))
        finally:
            self._f.close()
            self._disk.close()
        if self._disk.error is not None:
            raise self._disk.error


__all__ = ["Hdf5Writer"]
