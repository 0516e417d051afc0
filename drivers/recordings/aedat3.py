"""AEDAT 3.1 (cAER / libcaer packet files), decoded with NumPy from the documented layout.

Header: ASCII lines beginning with ``#`` from ``#!AER-DAT3.1\\r\\n`` to ``#!END-HEADER\\r\\n``;
``#Source <id>: <chip>`` names the sensor (DAVIS346B -> 346x260 ...). Then packets, little-endian:
a 28-byte header ``int16 type, int16 source, int32 eventSize, int32 tsOffset, int32 tsOverflow,
int32 capacity, int32 number, int32 valid`` and ``capacity * eventSize`` bytes of events. An event's
64-bit time is ``(tsOverflow << 31) | ts32`` (µs); bit 0 of its first word marks it valid
(invalid events are skipped).

What is read:

* POLARITY (type 1, 8 B): ``uint32 data`` (bit 1 polarity, y bits 2-16, x bits 17-31), ``int32 ts``.
* FRAME (type 2): ``uint32 info`` (channels bits 1-3), ``int32 ts_startframe, ts_endframe,
  ts_startexposure, ts_endexposure, lengthX, lengthY, positionX, positionY``, then
  ``uint16 pixels[lengthX*lengthY*channels]`` (10-bit value << 6, row-major, (0,0) top-left).
  Exposure ``[ts_startexposure, ts_endexposure]`` is stored. 8-bit grey = the 8 most significant
  bits (``>> 8``); colour frames become luma (:func:`~.base.to_gray8`); partial/ROI frames are dropped.
* IMU6 (type 3, 36 B): ``uint32 info, int32 ts, float accel x,y,z (g), gyro x,y,z (°/s), temp (°C)``.
* SPECIAL (type 0, 8 B): ``uint32 data`` (type bits 1-7), ``int32 ts``: TS_RESET, EXT_RISING/
  FALLING/PULSE, APS_FRAME_START/END, APS_EXPOSURE_START/END become triggers; others are ignored.

Other packet types (IMU9, spikes ...) are skipped and counted in a warning. Packets are read one at
a time (bounded memory); frames are held back as for AEDAT 4 (:class:`~.base.StreamAssembler`).
Seeking: polarity packets whose last timestamp precedes ``start_us`` by more than 2 s are skipped
with a ``seek`` over their payload (reading 4 bytes); reading stops past ``end_us``.
"""

from __future__ import annotations

import os
import struct
from collections import Counter
from collections.abc import Iterator

import numpy as np

from necviz.core.events import EVENT_DTYPE
from necviz.core.frames import Frame
from necviz.core.imu import IMU_DTYPE, TRIGGER_DTYPE
from necviz.drivers.recordings.reader import Recording, StreamAssembler, sensor_from_chip, sensor_from_extent, to_gray8

MAGICS = (b"#!AER-DAT3.1", b"#!AER-DAT3.0")
END_HEADER = b"#!END-HEADER\r\n"
PACKET_HEAD = struct.Struct("<hhiiiiii")
SPECIAL, POLARITY, FRAME, IMU6 = 0, 1, 2, 3
FRAME_HEAD = np.dtype(
    [
        ("info", "<u4"),
        ("ts_sf", "<i4"),
        ("ts_ef", "<i4"),
        ("ts_se", "<i4"),
        ("ts_ee", "<i4"),
        ("lx", "<i4"),
        ("ly", "<i4"),
        ("px", "<i4"),
        ("py", "<i4"),
    ]
)
IMU6_REC = np.dtype(
    [
        ("info", "<u4"),
        ("ts", "<i4"),
        ("ax", "<f4"),
        ("ay", "<f4"),
        ("az", "<f4"),
        ("gx", "<f4"),
        ("gy", "<f4"),
        ("gz", "<f4"),
        ("temp", "<f4"),
    ]
)
#: libcaer special event type -> index in TRIGGER_KINDS
SPECIAL_TO_TRIGGER = {1: 0, 2: 1, 3: 2, 4: 3, 14: 6, 15: 7, 16: 8, 17: 9}
_LUT = np.full(128, -1, np.int8)
for _k, _v in SPECIAL_TO_TRIGGER.items():
    _LUT[_k] = _v


def _plausible(typ: int, esize: int, cap: int, num: int, valid: int, overflow: int) -> bool:
    """Whether a packet header's fields are possible (type, event size, capacity >= number >= valid)."""
    return (
        0 <= typ < 64 and 0 < esize < (1 << 26) and 0 <= num <= cap < (1 << 26) and 0 <= valid <= num and overflow >= 0
    )


def read_text_header(path, fh, magics, end_line: bytes | None, limit: int = 1 << 20) -> tuple[list[str], int]:
    """Header lines (decoded, without '#' and line end) and the byte offset where data start.

    With ``end_line`` the header ends after that line; otherwise at the first line not starting with '#'.
    """
    lines, off = [], 0
    fh.seek(0)
    while True:
        line = fh.readline(limit)
        if not line:
            break
        if end_line is not None:
            off += len(line)
            if line.rstrip(b"\r\n") == end_line.rstrip(b"\r\n"):
                return lines, off
            if not line.startswith(b"#"):
                return lines, -1
        else:
            if not line.startswith(b"#"):
                break
            off += len(line)
        lines.append(line.rstrip(b"\r\n").decode("latin-1")[1:])
        if off > limit:
            return lines, -1
    return lines, (off if end_line is None else -1)


class Aedat3Recording(Recording):
    """Replay an AEDAT 3.1 file (see the module docstring)."""

    format = "aedat3"

    def __init__(self, path, **kwargs):
        kwargs.pop("exposure_us", None)  # AEDAT 3.1 stores exposures
        super().__init__(path, **kwargs)
        self.size = os.path.getsize(self.path)
        with open(self.path, "rb") as fh:
            head = fh.read(12)
            if head not in MAGICS:
                raise self.error(f"wrong magic (expected '#!AER-DAT3.1', found {head!r})", 0)
            lines, self._data_start = read_text_header(self.path, fh, MAGICS, END_HEADER)
            if self._data_start < 0:
                raise self.error("truncated or damaged text header (no '#!END-HEADER' line)", 0)
            self.header_lines = lines
            chip = next((ln.partition(":")[2].strip() for ln in lines if ln.startswith("Source")), "")
            self.properties = {"source": chip} if chip else {}
            self.camera_name = chip or None
            if self.sensor is None:
                self.sensor = sensor_from_chip(chip) if chip else None
            if self.sensor is None:
                self.sensor = self._sensor_from_data(fh)
        self.exposure_source = "stored"

    def _sensor_from_data(self, fh):
        """Largest frame size / event coordinate in the first 64 packets (no chip name in the header)."""
        mx = my = -1
        off = self._data_start
        for _ in range(64):
            fh.seek(off)
            h = fh.read(PACKET_HEAD.size)
            if len(h) < PACKET_HEAD.size:
                break
            typ, _, esize, _, _, cap, num, _ = PACKET_HEAD.unpack(h)
            if not _plausible(typ, esize, cap, num, 0, 0) or off + PACKET_HEAD.size + esize * cap > self.size:
                break
            body = fh.read(esize * cap)
            if typ == POLARITY and esize == 8 and num:
                d = np.frombuffer(body, "<u4", count=2 * num)[0::2]
                mx, my = max(mx, int((d >> 17).max())), max(my, int(((d >> 2) & 0x7FFF).max()))
            elif typ == FRAME and num and esize >= FRAME_HEAD.itemsize:
                fr = np.frombuffer(body, FRAME_HEAD, count=1)[0]
                mx, my = max(mx, int(fr["lx"]) - 1), max(my, int(fr["ly"]) - 1)
            off += PACKET_HEAD.size + esize * cap
        if mx < 0:
            raise self.error("cannot tell the sensor size (no chip name, no events); pass a sensor geometry")
        return sensor_from_extent(mx, my)

    def _packets(self) -> Iterator:
        asm = StreamAssembler(self.sensor, start_us=self.start_us, end_us=self.end_us)
        lag, seq = 0, 0
        skipped: Counter = Counter()
        self._asm = asm
        fh = open(self.path, "rb")
        off = self._data_start
        try:
            while off < self.size:
                self._where = off
                fh.seek(off)
                h = fh.read(PACKET_HEAD.size)
                if len(h) < PACKET_HEAD.size:
                    yield from asm.drain(None)
                    raise self.error(f"truncated packet header ({len(h)} of {PACKET_HEAD.size} bytes)", off)
                typ, _src, esize, _tsoff, overflow, cap, num, valid = PACKET_HEAD.unpack(h)
                if not _plausible(typ, esize, cap, num, valid, overflow):
                    yield from asm.drain(None)
                    raise self.error(
                        f"implausible packet header (type {typ}, size {esize}, capacity {cap}, "
                        f"number {num}): garbage or damaged data",
                        off,
                    )
                end = off + PACKET_HEAD.size + esize * cap
                if end > self.size:
                    yield from asm.drain(None)
                    raise self.error(
                        f"truncated packet (type {typ}: {esize * cap} bytes declared, "
                        f"{self.size - off - PACKET_HEAD.size} present)",
                        off,
                    )
                base = overflow << 31
                if typ in (SPECIAL, POLARITY) and esize != 8 or typ == FRAME and esize < FRAME_HEAD.itemsize:
                    yield from asm.drain(None)
                    raise self.error(f"packet of type {typ} with {esize}-byte events (garbage or damaged data)", off)
                if typ not in (SPECIAL, POLARITY, FRAME, IMU6):
                    skipped[typ] += 1
                    off = end
                    continue
                if typ == POLARITY and num and self.start_us is not None:
                    fh.seek(off + PACKET_HEAD.size + (num - 1) * esize + 4)  # last event's ts32
                    last = base | struct.unpack("<i", fh.read(4))[0]
                    if last < self.start_us - 2_000_000:  # well before the range (beyond any hold-back)
                        off = end
                        continue
                    fh.seek(off + PACKET_HEAD.size)
                body = fh.read(esize * cap)
                off = end
                if typ == POLARITY:
                    rec = np.frombuffer(body, "<u4", count=2 * num).reshape(-1, 2)
                    d = rec[:, 0]
                    ok = (d & 1).astype(bool)
                    d = d[ok]
                    ev = np.empty(d.size, EVENT_DTYPE)
                    ev["t"] = base | rec[ok, 1].view("<i4").astype(np.int64)
                    ev["x"] = d >> 17
                    ev["y"] = (d >> 2) & 0x7FFF
                    ev["p"] = ((d >> 1) & 1).astype(np.int8) * 2 - 1
                    asm.push_events(ev)
                elif typ == SPECIAL:
                    rec = np.frombuffer(body, "<u4", count=2 * num).reshape(-1, 2)
                    d = rec[:, 0]
                    kind = _LUT[(d >> 1) & 0x7F]
                    ok = (d & 1).astype(bool) & (kind >= 0)
                    trg = np.empty(int(ok.sum()), TRIGGER_DTYPE)
                    trg["t"] = base | rec[ok, 1].view("<i4").astype(np.int64)
                    trg["kind"] = kind[ok]
                    asm.push_triggers(trg)
                elif typ == IMU6:
                    rec = np.frombuffer(body, IMU6_REC, count=num) if esize == IMU6_REC.itemsize else None
                    if rec is None:
                        skipped[typ] += 1
                        continue
                    rec = rec[(rec["info"] & 1).astype(bool)]
                    imu = np.empty(rec.size, IMU_DTYPE)
                    imu["t"] = base | rec["ts"].astype(np.int64)
                    for name in ("ax", "ay", "az", "gx", "gy", "gz", "temp"):
                        imu[name] = rec[name]
                    asm.push_imu(imu)
                else:  # FRAME
                    for i in range(num):
                        fr = np.frombuffer(body, FRAME_HEAD, count=1, offset=i * esize)[0]
                        if not int(fr["info"]) & 1:
                            continue
                        ch = (int(fr["info"]) >> 1) & 7
                        lx, ly = int(fr["lx"]), int(fr["ly"])
                        npx = lx * ly * max(ch, 1)
                        if 36 + 2 * npx > esize or lx <= 0 or ly <= 0:
                            yield from asm.drain(None)
                            raise self.error(
                                f"frame of {lx}x{ly}x{ch} does not fit its {esize}-byte event",
                                off - esize * cap + i * esize,
                            )
                        px = np.frombuffer(body, "<u2", count=npx, offset=i * esize + 36)
                        img = px.reshape(ly, lx) if ch <= 1 else px.reshape(ly, lx, ch)
                        s, e = base | int(fr["ts_se"]), base | int(fr["ts_ee"])
                        lag = max(lag, asm.lag_of(s))
                        if e <= s:
                            skipped["odd_exposure"] += 1
                            continue
                        asm.push_frame(Frame(to_gray8(img, 16), s, e, 1.0, seq))
                        seq += 1
                watermark = asm.holdback_watermark(lag)
                if watermark is None:
                    continue
                if self.start_us is None or watermark > self.start_us:
                    yield from asm.drain(watermark)
                if self.end_us is not None and watermark > self.end_us:
                    break
            yield from asm.drain(None)
        finally:
            fh.close()
            odd = skipped.pop("odd_exposure", 0)
            if odd:
                self.warn(f"{odd} frames dropped: exposure end not after exposure start")
            if skipped:
                kinds = ", ".join(f"type {k} x{v}" for k, v in sorted(skipped.items()))
                self.warn(f"packets of unsupported event types skipped ({kinds})")
            if asm.frames_out == 0 and self.start_us is None and self.end_us is None:
                self.exposure_source = "none (no frames)"
