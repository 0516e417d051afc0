"""AEDAT 4.0 (iniVation DV) replay through the ``aedat`` package.

Why ``aedat``: maintained (neuromorphicsystems), a 0.5 MB Rust wheel depending only on NumPy,
a streaming packet iterator (bounded memory), and it exposes every frame's exposure begin/end,
IMU and trigger streams. ``dv-processing`` (56 MB, requires the ``.aedat4`` name) and ``faery``
(21 MB) offer the same data at many times the size.

What is read: events (``EVTS``), frames (``FRME``: exposure ``[exposure_begin_t,
exposure_end_t]`` as stored, 8-bit grey; 16-bit and colour frames converted with
:func:`~.base.to_gray8`; partial/ROI frames dropped with a warning), IMU (``IMUS``: g, °/s, °C;
the magnetometer is dropped) and triggers (``TRIG``, source codes 0..9 = ``TRIGGER_KINDS``).
Times are the file's µs timestamps (DV: Unix time in µs).

DV writes a frame after its readout, i.e. after events that follow its exposure start, so packets
are held back (:class:`~.base.StreamAssembler`) by ``max(1 s, 2 x the largest lag seen between a
frame's exposure start and the newest timestamp when it was stored)``; at most 4 M events are
buffered. Seeking: the ``aedat`` decoder has no random access, so packets before ``start_us`` are
decoded and dropped (cheap: no per-event Python), and decoding stops once past ``end_us``.

Damage: the packet headers (``uint32 stream_id, uint32 size``) are walked in step with the
decoder, so a truncated packet, an unknown stream id or a packet the decoder rejects (an error or
a Rust panic of the decoder) is reported with its byte offset after everything before it has been
yielded.
"""

from __future__ import annotations

import html
import os
import re
import struct
import warnings
from collections.abc import Iterator

import numpy as np

from necviz.core.events import EVENT_DTYPE
from necviz.core.frames import Frame
from necviz.core.imu import IMU_DTYPE, TRIGGER_DTYPE, TRIGGER_KINDS
from necviz.core.sensor import SensorGeometry
from necviz.drivers.recordings.reader import (
    Recording,
    StderrTrap,
    StreamAssembler,
    first_line,
    is_rust_panic,
    openable_path,
    sensor_from_chip,
    to_gray8,
)

MAGIC = b"#!AER-DAT4.0\r\n"
COMPRESSION = ("none", "LZ4", "LZ4 high", "Zstd", "Zstd high")


def _flatbuffer_table(buf: bytes, root: int):
    """(table position, vtable field offsets) of the flatbuffer table at ``root``."""
    vt = root - struct.unpack_from("<i", buf, root)[0]
    vsize = struct.unpack_from("<H", buf, vt)[0]
    fields = [struct.unpack_from("<H", buf, vt + 4 + 2 * i)[0] for i in range((vsize - 4) // 2)]
    return root, fields


class DescriptionNotText(ValueError):
    """The IOHeader description is not UTF-8; ``offset`` is the first bad byte within the IOHeader."""

    def __init__(self, offset: int):
        super().__init__(f"IOHeader description is not UTF-8 at byte {offset} of the header")
        self.offset = offset


def parse_ioheader(buf: bytes) -> tuple[int, int, str]:
    """(compression enum, file_data_position, description XML) from an IOHeader flatbuffer.

    Raises struct.error/IndexError for a malformed flatbuffer and :class:`DescriptionNotText` if
    the description is not UTF-8."""
    root = struct.unpack_from("<I", buf, 0)[0]
    pos, fields = _flatbuffer_table(buf, root)
    get = lambda i: fields[i] if i < len(fields) else 0  # noqa: E731
    compression = struct.unpack_from("<i", buf, pos + get(0))[0] if get(0) else 0
    data_pos = struct.unpack_from("<q", buf, pos + get(1))[0] if get(1) else -1
    desc = ""
    if get(2):
        at = pos + get(2)
        s = at + struct.unpack_from("<I", buf, at)[0]
        n = struct.unpack_from("<I", buf, s)[0]
        try:
            desc = buf[s + 4 : s + 4 + n].decode("utf-8")  # strict: see Aedat4Recording.__init__
        except UnicodeDecodeError as exc:
            raise DescriptionNotText(s + 4 + exc.start) from None
    return compression, data_pos, desc


class Aedat4Recording(Recording):
    """Replay an AEDAT 4.0 file (see the module docstring)."""

    format = "aedat4"

    def __init__(self, path, **kwargs):
        kwargs.pop("exposure_us", None)  # AEDAT 4 stores exposures
        super().__init__(path, **kwargs)
        self.size = os.path.getsize(self.path)
        with open(self.path, "rb") as f:
            head = f.read(len(MAGIC) + 4)
            if not head.startswith(MAGIC[:12]):
                raise self.error(f"wrong magic (expected '#!AER-DAT4.0', found {head[:12]!r})", 0)
            if len(head) < len(MAGIC) + 4:
                raise self.error("truncated file header", len(head))
            hlen = struct.unpack_from("<I", head, len(MAGIC))[0]
            hbuf = f.read(hlen)
        if len(hbuf) < hlen:
            raise self.error(f"truncated IOHeader ({hlen} bytes declared, {len(hbuf)} present)", len(MAGIC) + 4)
        try:
            compression, data_pos, desc = parse_ioheader(hbuf)
        except (struct.error, IndexError):
            raise self.error("unreadable IOHeader flatbuffer", len(MAGIC) + 4) from None
        except DescriptionNotText as exc:
            # checked here because aedat 2.3 aborts the process (a panic while reporting the error)
            # when the description it parses is not UTF-8
            raise self.error(
                "IOHeader description is not UTF-8 text (damaged header)", len(MAGIC) + 4 + exc.offset
            ) from None
        self.compression = COMPRESSION[compression] if 0 <= compression < len(COMPRESSION) else str(compression)
        self.description = desc
        self._packets_start = len(MAGIC) + 4 + hlen
        self._data_end = data_pos if 0 < data_pos <= self.size else self.size
        import aedat

        self._trap = StderrTrap()  # the decoder's panic messages: necviz reports the damage in one line
        try:
            with self._trap(), openable_path(self.path) as name:
                self._streams = aedat.Decoder(name).id_to_stream()
        except BaseException as exc:  # noqa: BLE001 - narrowed by _decoder_error
            err = self._decoder_error(exc, "unreadable AEDAT 4 header", len(MAGIC))
            if err is exc:
                raise
            raise err from None
        if self.sensor is None:
            for kind in ("events", "frame"):
                for s in self._streams.values():
                    if s.get("type") == kind and s.get("width"):
                        self.sensor = SensorGeometry(int(s["width"]), int(s["height"]), self._chip_name(s))
                        break
                if self.sensor is not None:
                    break
        if self.sensor is None:
            raise self.error("no stream declares a sensor size; pass a sensor geometry")
        has_frames = any(s.get("type") == "frame" for s in self._streams.values())
        self.exposure_source = "stored" if has_frames else "none (no frames)"
        self.properties = {}
        source = re.search(r'key="source"[^>]*>([^<]*)<', desc or "")  # the camera DV recorded (with its serial)
        self.camera_name = html.unescape(source.group(1)).strip() or None if source else None

    def close(self) -> None:
        self._trap.close()

    def _decoder_error(self, exc: BaseException, what: str, offset: int) -> BaseException:
        """What the ``aedat`` decoder raised, as a one-line RecordingError: its errors (RuntimeError,
        OSError ...) and its Rust panics (``pyo3_runtime.PanicException``, a BaseException matched
        by name, so KeyboardInterrupt and GeneratorExit pass through unchanged)."""
        if isinstance(exc, Exception) or is_rust_panic(exc):
            kind = "decoder panic: " if is_rust_panic(exc) else ""
            return self.error(f"{what} ({kind}{first_line(exc) or type(exc).__name__})", offset)
        return exc

    def _chip_name(self, stream: dict) -> str:
        geo = sensor_from_chip(self.description)
        if geo is not None and (geo.width, geo.height) == (int(stream["width"]), int(stream["height"])):
            return geo.name
        return "custom"

    def _packets(self) -> Iterator:
        import aedat

        asm = StreamAssembler(self.sensor, start_us=self.start_us, end_us=self.end_us)
        self._asm = asm
        lag = 0
        seq = 0
        odd_exposure = 0
        fh = open(self.path, "rb")
        off = self._packets_start
        try:
            try:
                with self._trap(), openable_path(self.path) as name:
                    decoder = aedat.Decoder(name)
            except BaseException as exc:  # noqa: BLE001 - narrowed by _decoder_error
                err = self._decoder_error(exc, "unreadable AEDAT 4 header", len(MAGIC))
                if err is exc:
                    raise
                raise err from None
            while True:
                # the header of the packet the decoder is about to read
                if off >= self._data_end:
                    break
                self._where = off
                fh.seek(off)
                head = fh.read(8)
                if len(head) < 8:
                    yield from asm.drain(None)
                    raise self.error(f"truncated packet header ({len(head)} of 8 bytes)", off)
                sid, size = struct.unpack("<II", head)
                if size == 0:
                    yield from asm.drain(None)
                    raise self.error(f"empty packet (stream {sid}, 0 bytes: garbage or damaged data)", off)
                if sid not in self._streams:
                    yield from asm.drain(None)
                    raise self.error(f"unknown stream id {sid} in packet header (garbage or damaged data)", off)
                if off + 8 + size > self._data_end:
                    yield from asm.drain(None)
                    raise self.error(
                        f"truncated packet (stream {sid}: {size} bytes declared, {self._data_end - off - 8} present)",
                        off,
                    )
                try:
                    with self._trap(), warnings.catch_warnings(record=True) as said:
                        warnings.simplefilter("always")
                        packet = next(decoder)
                    for w in said:  # e.g. "skipping unknown frame format": a recording warning, not stderr
                        self.warn(f"decoder: {first_line(w.message)} (packet at byte {off})")
                except StopIteration:
                    break
                except BaseException as exc:  # noqa: BLE001 - narrowed by _decoder_error
                    err = self._decoder_error(exc, "undecodable packet", off)
                    if err is exc:
                        raise
                    yield from asm.drain(None)
                    raise err from None
                off += 8 + size
                if "events" in packet:
                    e = packet["events"]
                    ev = np.empty(e.size, EVENT_DTYPE)
                    ev["t"] = e["t"]
                    ev["x"] = e["x"]
                    ev["y"] = e["y"]
                    ev["p"] = e["on"].view(np.int8) * 2 - 1
                    asm.push_events(ev)
                elif "frame" in packet:
                    fr = packet["frame"]
                    s, e = int(fr["exposure_begin_t"]), int(fr["exposure_end_t"])
                    lag = max(lag, asm.lag_of(s))
                    if e <= s:
                        odd_exposure += 1
                        continue
                    img = to_gray8(fr["pixels"], 16 if fr["format"].startswith("I;16") else None)
                    asm.push_frame(Frame(img, s, e, 1.0, seq))
                    seq += 1
                elif "imus" in packet:
                    m = packet["imus"]
                    imu = np.empty(m.size, IMU_DTYPE)
                    imu["t"] = m["t"]
                    for a, b in (
                        ("ax", "accelerometer_x"),
                        ("ay", "accelerometer_y"),
                        ("az", "accelerometer_z"),
                        ("gx", "gyroscope_x"),
                        ("gy", "gyroscope_y"),
                        ("gz", "gyroscope_z"),
                        ("temp", "temperature"),
                    ):
                        imu[a] = m[b]
                    asm.push_imu(imu)
                elif "triggers" in packet:
                    tr = packet["triggers"]
                    ok = tr["source"] < len(TRIGGER_KINDS)
                    trg = np.empty(int(ok.sum()), TRIGGER_DTYPE)
                    trg["t"] = tr["t"][ok]
                    trg["kind"] = tr["source"][ok]
                    asm.push_triggers(trg)
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
            if odd_exposure:
                self.warn(f"{odd_exposure} frames dropped: exposure end not after exposure begin")
            if (
                asm.frames_out == 0
                and self.exposure_source == "stored"
                and self.end_us is None
                and self.start_us is None
            ):
                self.exposure_source = "none (no frames)"
