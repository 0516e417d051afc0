"""AEDAT 4.0 files that iniVation's DV software (``dv-processing``) and the ``aedat`` reader open.

The container, as iniVation documents it (AEDAT 4.0 format description; schemas as published with DV):

* ``#!AER-DAT4.0\\r\\n``, a ``uint32`` length, then the **IOHeader** FlatBuffer (identifier ``IOHE``):
  ``compression`` (int32: 0 none, 1 LZ4, 2 LZ4 high, 3 Zstd, 4 Zstd high), ``dataTablePosition``
  (int64 byte offset of the data table, -1 if none) and ``infoNode``, an XML text naming every stream:
  its id, ``typeIdentifier`` (``EVTS``, ``FRME``, ``IMUS``, ``TRIG``), compression and ``info`` (sensor
  ``sizeX``/``sizeY``, ``source`` camera name, ``tsOffset``);
* packets: ``int32 streamID``, ``int32 size``, then ``size`` bytes: a size-prefixed FlatBuffer with the
  stream's identifier, compressed whole (LZ4 frame format, or a Zstandard frame);
* the **FileDataTable** (identifier ``FTAB``, compressed like a packet, no packet header) at
  ``dataTablePosition``: for every packet its byte offset (of the payload, after the 8-byte header),
  stream id and size, element count and first/last timestamp, so a reader can seek.

Schemas (slot order is what counts):

* ``EVTS`` EventPacket { elements: [Event] }, struct Event { timestamp: int64; x: int16; y: int16;
  polarity: bool } (16 bytes with padding);
* ``FRME`` Frame { timestamp (mid-exposure), timestampStartOfFrame, timestampEndOfFrame,
  timestampStartOfExposure, timestampEndOfExposure: int64; format: int8 (0 = 8-bit grey);
  sizeX, sizeY, positionX, positionY: int16; pixels: [uint8] } — one frame per packet;
* ``IMUS`` IMUPacket { elements: [IMU] }, IMU { timestamp: int64; temperature (°C), accelerometerX/Y/Z
  (g), gyroscopeX/Y/Z (°/s), magnetometerX/Y/Z: float };
* ``TRIG`` TriggerPacket { elements: [Trigger] }, Trigger { timestamp: int64; type: int8 } (0 timestamp
  reset ... 8 exposure begin, 9 exposure end: :data:`necviz.core.imu.TRIGGER_KINDS`).

What necviz cannot store here: the frames' digital gain (AEDAT 4 has no field for it; the pixels are
as recorded) and a native recording's commands and annotations. Frames carry no readout times, so
start/end of frame are written as the exposure's.
"""

from __future__ import annotations

import struct

import numpy as np

from necviz.core.errors import ParameterError
from necviz.core.events import EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import ImuBatch, TriggerBatch
from necviz.writers.flatbuf import Buffer

MAGIC = b"#!AER-DAT4.0\r\n"
#: ``--compression`` names -> (IOHeader enum, XML name).
COMPRESSIONS = {"none": (0, "NONE"), "lz4": (1, "LZ4"), "zstd": (3, "ZSTD")}
#: Events per EVTS packet (DV's own recorder writes packets of a few thousand to tens of thousands).
EVENTS_PER_PACKET = 1 << 15

_EVENT = np.dtype(
    {"names": ["t", "x", "y", "on"], "formats": ["<i8", "<i2", "<i2", "u1"], "offsets": [0, 8, 10, 12], "itemsize": 16}
)
_IMU = np.dtype(
    {
        "names": ["so", "t", "temp", "ax", "ay", "az", "gx", "gy", "gz"],
        "formats": ["<i4", "<i8"] + ["<f4"] * 7,
        "offsets": [0, 4, 12, 16, 20, 24, 28, 32, 36],
        "itemsize": 40,
    }
)
_TRIGGER = np.dtype(
    {"names": ["so", "t", "kind"], "formats": ["<i4", "<i8", "i1"], "offsets": [0, 4, 12], "itemsize": 16}
)
_TABLE_ROW = np.dtype(
    {
        "names": ["so", "offset", "n", "t0", "t1", "stream", "size"],
        "formats": ["<i4", "<i8", "<i8", "<i8", "<i8", "<i4", "<i4"],
        "offsets": [0, 4, 12, 20, 28, 36, 40],
        "itemsize": 48,
    }
)
STREAMS = (  # id, name, identifier, description, has a size
    (0, "events", "EVTS", "Array of events (polarity ON/OFF).", True),
    (1, "frames", "FRME", "Standard frame (8-bit image).", True),
    (2, "imu", "IMUS", "Inertial Measurement Unit data samples.", False),
    (3, "triggers", "TRIG", "External triggers and special signals.", False),
)


def _compressor(name: str):
    if name == "none":
        return lambda b: b
    if name == "lz4":
        import lz4.frame  # LZ4 frame format, as DV writes it

        return lambda b: lz4.frame.compress(b)
    try:  # Zstandard: the standard library from Python 3.14, its backport before
        from compression import zstd
    except ImportError:
        from backports import zstd
    return lambda b: zstd.compress(b)


def info_node(width: int, height: int, source: str, compression: str, streams=None) -> str:
    """The IOHeader's XML stream description (the layout DV writes), for the stream ids ``streams``
    (default: all four)."""
    root = "/mainloop/Recorder/outInfo/"
    lines = ['<dv version="2.0">', f'    <node name="outInfo" path="{root}">']
    for sid, name, ident, desc, sized in STREAMS:
        if streams is not None and sid not in streams:
            continue
        lines += [
            f'        <node name="{sid}" path="{root}{sid}/">',
            f'            <attr key="compression" type="string">{compression}</attr>',
            '            <attr key="originalModuleName" type="string">necviz</attr>',
            f'            <attr key="originalOutputName" type="string">{name}</attr>',
            f'            <attr key="typeDescription" type="string">{desc}</attr>',
            f'            <attr key="typeIdentifier" type="string">{ident}</attr>',
            f'            <node name="info" path="{root}{sid}/info/">',
        ]
        if sized:
            lines += [
                f'                <attr key="sizeX" type="int">{int(width)}</attr>',
                f'                <attr key="sizeY" type="int">{int(height)}</attr>',
            ]
        lines += [
            f'                <attr key="source" type="string">{_xml(source)}</attr>',
            '                <attr key="tsOffset" type="long">0</attr>',
            "            </node>",
            "        </node>",
        ]
    lines += ["    </node>", "</dv>", ""]
    return "\n".join(lines)


def _xml(text: str) -> str:
    return str(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace('"', "&quot;")


def ioheader(compression: int, data_table_position: int, info: str) -> tuple[bytes, int]:
    """The IOHeader FlatBuffer and the byte position (within it) of ``dataTablePosition``."""
    b = Buffer(b"IOHE", size_prefixed=False)
    pos = b.table({0: ("i", compression), 1: ("q", data_table_position), 2: ("O", "info")}, root=True)
    b.string("info", info)
    out = b.finish()
    # the int64 field is the table's first (largest) field: 4 bytes after the table start
    return out, pos + 4


def events_packet(ev: np.ndarray) -> bytes:
    rec = np.zeros(len(ev), _EVENT)
    rec["t"], rec["x"], rec["y"], rec["on"] = ev["t"], ev["x"], ev["y"], ev["p"] > 0
    b = Buffer(b"EVTS")
    b.table({0: ("O", "elements")}, root=True)
    b.vector("elements", rec, len(rec), align=8)
    return b.finish()


def frame_packet(frame: Frame) -> bytes:
    s, e = int(frame.exposure_start_us), int(frame.exposure_end_us)
    h, w = frame.image.shape
    b = Buffer(b"FRME")
    b.table(
        {
            0: ("q", (s + e) // 2),
            1: ("q", s),
            2: ("q", e),
            3: ("q", s),
            4: ("q", e),
            5: ("b", 0),
            6: ("h", w),
            7: ("h", h),
            8: ("h", 0),
            9: ("h", 0),
            10: ("O", "pixels"),
        },
        root=True,
    )
    b.vector("pixels", np.ascontiguousarray(frame.image).reshape(-1), h * w, align=1)
    return b.finish()


def imu_packet(samples: np.ndarray) -> bytes:
    rec = np.zeros(len(samples), _IMU)
    for k in ("t", "temp", "ax", "ay", "az", "gx", "gy", "gz"):
        rec[k] = samples[k]
    b = Buffer(b"IMUS")
    b.table({0: ("O", "elements")}, root=True)
    b.table_vector("elements", rec, {0: "t", 1: "temp", 2: "ax", 3: "ay", 4: "az", 5: "gx", 6: "gy", 7: "gz"})
    return b.finish()


def trigger_packet(triggers: np.ndarray) -> bytes:
    rec = np.zeros(len(triggers), _TRIGGER)
    rec["t"], rec["kind"] = triggers["t"], triggers["kind"]
    b = Buffer(b"TRIG")
    b.table({0: ("O", "elements")}, root=True)
    b.table_vector("elements", rec, {0: "t", 1: "kind"})
    return b.finish()


def data_table(rows: list[tuple[int, int, int, int, int, int]]) -> bytes:
    """FileDataTable: ``rows`` of (payload offset, stream id, size, elements, first t, last t)."""
    rec = np.zeros(len(rows), _TABLE_ROW)
    if rows:
        arr = np.array(rows, np.int64)
        rec["offset"], rec["stream"], rec["size"], rec["n"], rec["t0"], rec["t1"] = arr.T
    b = Buffer(b"FTAB")
    b.table({0: ("O", "table")}, root=True)
    # PacketHeader is a struct (two int32) inline in slot 1
    slots = {0: "offset", 2: "n", 3: "t0", 4: "t1"}
    vec = b.table_vector("table", rec, {**slots, 1: "stream"})
    del vec
    return b.finish()


class Aedat4Writer:
    """Write stream packets to an AEDAT 4.0 file (layout in the module docstring).

    Parameters
    ----------
    path : the file to create (it is truncated).
    sensor : :class:`~necviz.core.sensor.SensorGeometry` (``sizeX``/``sizeY`` of the event and frame streams).
    compression : ``"lz4"`` (DV's default), ``"zstd"`` or ``"none"``.
    source : the camera name DV shows (the XML ``source``, e.g. ``DAVIS346_00000104``: keep the input's);
        default the sensor's name.

    The header declares only the streams the file holds: it is written with all four at the start
    and rewritten at :meth:`close` with those that received packets, padded to the same length.

    Raises
    ------
    ParameterError
        For an unknown compression.
    """

    def __init__(self, path, sensor, *, compression: str = "lz4", source: str | None = None):
        if compression not in COMPRESSIONS:
            raise ParameterError(f"--compression must be one of {', '.join(COMPRESSIONS)}, got {compression!r}")
        self.sensor = sensor
        self._compress = _compressor(compression)
        self._enum, self._xml_name = COMPRESSIONS[compression]
        self._source = source or (sensor.name or "DAVIS").replace(" ", "_")
        head, _ = ioheader(self._enum, -1, info_node(sensor.width, sensor.height, self._source, self._xml_name))
        self._head_len = len(head)
        self._f = open(path, "w+b")  # noqa: SIM115 - closed by close()
        self._f.write(MAGIC + struct.pack("<I", len(head)) + head)
        self._rows: list[tuple[int, int, int, int, int, int]] = []
        self._events: list[np.ndarray] = []
        self._n_events = 0
        self.counts = {"events": 0, "frames": 0, "imu": 0, "triggers": 0}
        self._closed = False

    def _packet(self, stream: int, flatbuffer: bytes, n: int, t0: int, t1: int) -> None:
        data = self._compress(flatbuffer)
        self._f.write(struct.pack("<ii", stream, len(data)))
        self._rows.append((self._f.tell(), stream, len(data), n, t0, t1))
        self._f.write(data)

    def _flush_events(self) -> None:
        if not self._events:
            return
        ev = np.concatenate(self._events) if len(self._events) > 1 else self._events[0]
        self._events, self._n_events = [], 0
        for i in range(0, len(ev), EVENTS_PER_PACKET):
            part = ev[i : i + EVENTS_PER_PACKET]
            self._packet(0, events_packet(part), len(part), int(part["t"][0]), int(part["t"][-1]))

    def write(self, packet) -> None:
        """Append one stream packet (events, frame, IMU or trigger batch; exposure markers are implied by frames)."""
        if isinstance(packet, EventBatch):
            packet = packet.events
        if isinstance(packet, np.ndarray):
            if len(packet):
                self._events.append(packet)
                self._n_events += len(packet)
                self.counts["events"] += len(packet)
                if self._n_events >= EVENTS_PER_PACKET:
                    self._flush_events()
            return
        if isinstance(packet, ExposureMarker):
            return
        self._flush_events()  # keep the file in time order across streams
        if isinstance(packet, Frame):
            s, e = int(packet.exposure_start_us), int(packet.exposure_end_us)
            self._packet(1, frame_packet(packet), 1, (s + e) // 2, (s + e) // 2)
            self.counts["frames"] += 1
        elif isinstance(packet, ImuBatch) and len(packet):
            t = packet.samples["t"]
            self._packet(2, imu_packet(packet.samples), len(t), int(t[0]), int(t[-1]))
            self.counts["imu"] += len(t)
        elif isinstance(packet, TriggerBatch) and len(packet):
            t = packet.triggers["t"]
            self._packet(3, trigger_packet(packet.triggers), len(t), int(t[0]), int(t[-1]))
            self.counts["triggers"] += len(t)

    def close(self) -> None:
        """Write the last events, the data table and its position in the header; close the file."""
        if self._closed:
            return
        self._closed = True
        try:
            self._flush_events()
            pos = self._f.tell()
            self._f.write(self._compress(data_table(self._rows)))
            self._f.seek(len(MAGIC) + 4)
            self._f.write(self._final_header(pos))
        finally:
            self._f.close()

    def _final_header(self, data_table_position: int) -> bytes:
        """The IOHeader naming only the streams that received packets, as long as the one written first
        (the XML padded with spaces after its end)."""
        used = {row[1] for row in self._rows}
        xml = info_node(self.sensor.width, self.sensor.height, self._source, self._xml_name, used)
        for pad in range(0, 4096):
            head, _ = ioheader(self._enum, data_table_position, xml + " " * pad)
            if len(head) == self._head_len:
                return head
        raise AssertionError("the final AEDAT 4 header cannot be padded to the first one's length")


__all__ = ["Aedat4Writer", "COMPRESSIONS", "MAGIC", "info_node"]
