"""NumPy ``.npz``: events as one structured array, frames with their exposures, IMU and triggers.

``np.load(path)`` gives (every array is plain data: no pickles)::

    events                  structured (N,): t int64 µs, x uint16, y uint16, p int8 (+1 ON, -1 OFF)
    frames                  uint8 (F, H, W), row-major, (0,0) top-left
    frame_exposure_start_us int64 (F,)      frame_exposure_end_us int64 (F,)
    frame_gain              float64 (F,) (linear, >= 1)
    imu                     structured (M,): t int64 µs, ax ay az (g), gx gy gz (°/s), temp (°C) float32
    triggers                structured (K,): t int64 µs, kind int8 (index into necviz.core.imu.TRIGGER_KINDS)
    sensor_size             int64 (2,): width, height

Times are the recording's own clock. :func:`necviz.io.to_tonic` / :func:`necviz.io.to_faery` convert
``events`` to the layouts of those libraries. Events and frames are spooled to temporary files while
the stream is read and copied into the (deflate-compressed, ZIP64) archive at the end, so memory stays
bounded however long the export.
"""

from __future__ import annotations

import shutil
import tempfile
import zipfile

import numpy as np

from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import IMU_DTYPE, TRIGGER_DTYPE, ImuBatch, TriggerBatch


class NpzWriter:
    """Write stream packets to a ``.npz`` archive (layout in the module docstring).

    Parameters
    ----------
    path : the file to create.
    sensor : :class:`~necviz.core.sensor.SensorGeometry`.
    """

    def __init__(self, path, sensor, *, properties: dict | None = None):
        self.path = path
        self.sensor = sensor
        self._events = tempfile.TemporaryFile()
        self._images = tempfile.TemporaryFile()
        self._shape: tuple[int, int] | None = None
        self._starts: list[int] = []
        self._ends: list[int] = []
        self._gains: list[float] = []
        self._imu: list[np.ndarray] = []
        self._trg: list[np.ndarray] = []
        self.counts = {"events": 0, "frames": 0, "imu": 0, "triggers": 0}
        self._closed = False

    def write(self, packet) -> None:
        """Append one stream packet (events, frame, IMU or trigger batch; markers are implied by frames)."""
        if isinstance(packet, EventBatch):
            packet = packet.events
        if isinstance(packet, np.ndarray):
            self._events.write(np.ascontiguousarray(packet, EVENT_DTYPE).tobytes())
            self.counts["events"] += len(packet)
        elif isinstance(packet, ExposureMarker):
            return
        elif isinstance(packet, Frame):
            if self._shape is None:
                self._shape = packet.image.shape
            if packet.image.shape != self._shape:  # one array holds every frame: a reader delivers one size
                raise ValueError(f"frame of size {packet.image.shape} after frames of size {self._shape}")
            self._images.write(np.ascontiguousarray(packet.image).tobytes())
            self._starts.append(int(packet.exposure_start_us))
            self._ends.append(int(packet.exposure_end_us))
            self._gains.append(float(packet.gain))
            self.counts["frames"] += 1
        elif isinstance(packet, ImuBatch):
            self._imu.append(np.asarray(packet.samples, IMU_DTYPE))
            self.counts["imu"] += len(packet)
        elif isinstance(packet, TriggerBatch):
            self._trg.append(np.asarray(packet.triggers, TRIGGER_DTYPE))
            self.counts["triggers"] += len(packet)

    @staticmethod
    def _spooled(zf: zipfile.ZipFile, name: str, spool, dtype: np.dtype, shape: tuple) -> None:
        with zf.open(name + ".npy", "w", force_zip64=True) as out:
            header = {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)), "fortran_order": False, "shape": shape}
            np.lib.format.write_array_header_2_0(out, header)
            spool.seek(0)
            shutil.copyfileobj(spool, out, 1 << 20)

    @staticmethod
    def _array(zf: zipfile.ZipFile, name: str, arr: np.ndarray) -> None:
        with zf.open(name + ".npy", "w", force_zip64=True) as out:
            np.lib.format.write_array(out, np.ascontiguousarray(arr), allow_pickle=False)

    def close(self) -> None:
        """Write the archive and drop the spool files."""
        if self._closed:
            return
        self._closed = True
        try:
            h, w = self._shape or (self.sensor.height, self.sensor.width)
            with zipfile.ZipFile(self.path, "w", zipfile.ZIP_DEFLATED, allowZip64=True) as zf:
                self._spooled(zf, "events", self._events, EVENT_DTYPE, (self.counts["events"],))
                self._spooled(zf, "frames", self._images, np.uint8, (self.counts["frames"], h, w))
                self._array(zf, "frame_exposure_start_us", np.array(self._starts, np.int64))
                self._array(zf, "frame_exposure_end_us", np.array(self._ends, np.int64))
                self._array(zf, "frame_gain", np.array(self._gains, np.float64))
                self._array(zf, "imu", np.concatenate(self._imu) if self._imu else np.zeros(0, IMU_DTYPE))
                self._array(zf, "triggers", np.concatenate(self._trg) if self._trg else np.zeros(0, TRIGGER_DTYPE))
                self._array(zf, "sensor_size", np.array([self.sensor.width, self.sensor.height], np.int64))
        finally:
            self._events.close()
            self._images.close()


__all__ = ["NpzWriter"]
