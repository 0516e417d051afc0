"""Byte-exact synthetic recordings written from the documented layouts (docs/file-formats.md).

Independent of the readers under test: only ``struct``/``numpy``/``zlib`` (plus h5py for HDF5 and
rosbags' own Writer for bags). Coordinates given here are image coordinates (top-left origin);
the writers apply each format's own convention (e.g. jAER's flipped axes).
"""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import numpy as np

# ----------------------------------------------------------------------------------- AEDAT 3.1


def aedat3_packet(
    event_type: int, event_size: int, ts_overflow: int, payload: bytes, number: int, source: int = 1
) -> bytes:
    """28-byte header ``int16 type, int16 source, int32 size, int32 tsOffset, int32 tsOverflow,
    int32 capacity, int32 number, int32 valid`` + payload (capacity == number)."""
    assert len(payload) == event_size * number
    ts_offset = 4  # every libcaer event type stores its 32-bit timestamp at byte 4
    return (
        struct.pack("<hhiiiiii", event_type, source, event_size, ts_offset, ts_overflow, number, number, number)
        + payload
    )


def aedat3_polarity(t, x, y, p, overflow: int = 0) -> bytes:
    """POLARITY packet: ``uint32 data`` (bit0 valid, bit1 polarity, y bits 2-16, x bits 17-31), ``int32 ts``."""
    t, x, y, p = (np.asarray(a, np.int64) for a in (t, x, y, p))
    data = 1 | ((p > 0).astype(np.int64) << 1) | (y << 2) | (x << 17)
    rec = np.empty(t.size, [("d", "<u4"), ("t", "<i4")])
    rec["d"] = data
    rec["t"] = t - (overflow << 31)
    return aedat3_packet(1, 8, overflow, rec.tobytes(), t.size)


def aedat3_special(t, types, overflow: int = 0) -> bytes:
    """SPECIAL packet: ``uint32 data`` (bit0 valid, type bits 1-7), ``int32 ts``."""
    t, types = np.asarray(t, np.int64), np.asarray(types, np.int64)
    rec = np.empty(t.size, [("d", "<u4"), ("t", "<i4")])
    rec["d"] = 1 | (types << 1)
    rec["t"] = t - (overflow << 31)
    return aedat3_packet(0, 8, overflow, rec.tobytes(), t.size)


def aedat3_frame(
    image10: np.ndarray, ts_start_frame, ts_end_frame, ts_start_exp, ts_end_exp, overflow: int = 0
) -> bytes:
    """FRAME packet with one frame: 36-byte header then ``uint16`` pixels (10-bit value << 6)."""
    h, w = image10.shape
    head = struct.pack(
        "<Iiiiiiiii",
        1 | (1 << 1),
        *(int(v) - (overflow << 31) for v in (ts_start_frame, ts_end_frame, ts_start_exp, ts_end_exp)),
        w,
        h,
        0,
        0,
    )
    px = (np.asarray(image10, np.uint16) << 6).astype("<u2").tobytes()
    return aedat3_packet(2, 36 + 2 * w * h, overflow, head + px, 1)


def aedat3_imu6(t, values, overflow: int = 0) -> bytes:
    """IMU6 packet: ``uint32 info, int32 ts, 7 x float`` (ax ay az g, gx gy gz °/s, temp °C)."""
    t = np.asarray(t, np.int64)
    rec = np.zeros(t.size, [("i", "<u4"), ("t", "<i4"), ("v", "<f4", 7)])
    rec["i"] = 1
    rec["t"] = t - (overflow << 31)
    rec["v"] = values
    return aedat3_packet(3, 36, overflow, rec.tobytes(), t.size)


def aedat3_header(source: str = "DAVIS346B") -> bytes:
    return (
        b"#!AER-DAT3.1\r\n#Format: RAW\r\n"
        + f"#Source 1: {source}\r\n".encode()
        + b"#Start-Time: 2024-01-01 00:00:00 (TZ+0000)\r\n#!END-HEADER\r\n"
    )


# ----------------------------------------------------------------------------------- AEDAT 2.0


def jaer_dvs(x, y, p, width, height) -> np.ndarray:
    """DVS address words: polarity bit 11, x' bits 12-21, y' bits 22-30, with jAER's flipped axes."""
    x, y, p = (np.asarray(a, np.int64) for a in (x, y, p))
    return ((height - 1 - y) << 22) | ((width - 1 - x) << 12) | ((p > 0).astype(np.int64) << 11)


def jaer_aps(x, y, readout, adc, width, height) -> np.ndarray:
    """APS sample words: bit31, readout bits 10-11 (0 reset, 1 signal), ADC bits 0-9."""
    x, y, adc = (np.asarray(a, np.int64) for a in (x, y, adc))
    return (1 << 31) | ((height - 1 - y) << 22) | ((width - 1 - x) << 12) | (int(readout) << 10) | adc


def jaer_imu(raw7) -> np.ndarray:
    """7 IMU words (codes 0..6 = ax ay az temp gx gy gz): ``0x80000C00 | code << 28 | raw16 << 12``."""
    raw = np.asarray(raw7, np.int64) & 0xFFFF
    return (1 << 31) | (np.arange(7, dtype=np.int64) << 28) | (raw << 12) | (3 << 10)


def aedat2_bytes(addr, ts, chip: str = "eu.seebetter.ini.chips.davis.Davis346B") -> bytes:
    header = (
        b"#!AER-DAT2.0\r\n# This is a raw AE data file - do not edit\r\n"
        + f"# AEChip: {chip}\r\n".encode()
        + b"# HardwareInterface: synthetic\r\n"
    )
    rec = np.empty(len(addr), [("a", ">u4"), ("t", ">i4")])
    rec["a"] = np.asarray(addr, np.int64).astype(np.uint32)
    rec["t"] = np.asarray(ts, np.int64).astype(np.int32)
    return header + rec.tobytes()


def aedat2_frame_words(
    image10_reset: np.ndarray,
    image10_signal: np.ndarray,
    t_reset0: int,
    t_signal0: int,
    width: int,
    height: int,
    step_us: int = 0,
):
    """Global-shutter readout: every pixel's reset read (column-major in jAER order), then every signal
    read. Returns (addr, ts); all resets stamped ``t_reset0 + k*step_us``, signals ``t_signal0 + ...``."""
    ys, xs = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    xs, ys = xs.ravel(), ys.ravel()
    r = jaer_aps(xs, ys, 0, image10_reset[ys, xs], width, height)
    s = jaer_aps(xs, ys, 1, image10_signal[ys, xs], width, height)
    k = np.arange(xs.size, dtype=np.int64) * step_us // xs.size
    return np.concatenate([r, s]), np.concatenate([t_reset0 + k, t_signal0 + k])


# ----------------------------------------------------------------------------------- native


def native_bytes(sensor=(346, 260, "DAVIS346"), properties=None, chunks=(), end=True) -> bytes:
    """A necviz recording from the layout in drivers/recordings/native.py's docstring.

    ``chunks``: (type, payload bytes) pairs after the header chunk.
    """

    def chunk(kind, payload):
        return struct.pack("<BII", kind, len(payload), zlib.crc32(payload)) + payload

    header = {
        "format": "necviz-recording",
        "version": 1,
        "sensor": {"width": sensor[0], "height": sensor[1], "name": sensor[2]},
        "properties": properties or {},
        "created_utc": "2024-01-01T00:00:00+00:00",
    }
    out = b"NECVIZ-REC\x00" + bytes([1]) + chunk(1, json.dumps(header).encode())
    for kind, payload in chunks:
        out += chunk(kind, payload)
    if end:
        out += chunk(9, b"")
    return out


def native_events(t, x, y, p) -> bytes:
    """13-byte records: t i64, x u16, y u16, p i8."""
    return b"".join(struct.pack("<qHHb", int(a), int(b), int(c), int(d)) for a, b, c, d in zip(t, x, y, p, strict=True))


# ----------------------------------------------------------------------------------- RPG text


def write_rpg_text(folder: Path, t_s, x, y, p01, frames=(), imu=None) -> Path:
    """``events.txt`` (``t x y p``, t in s, p 0/1) and ``images.txt`` (``t images/frame_XXXXXXXX.png``)."""
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "events.txt", "w") as f:
        for row in zip(t_s, x, y, p01, strict=True):
            f.write(f"{row[0]:.6f} {int(row[1])} {int(row[2])} {int(row[3])}\n")
    if frames:
        (folder / "images").mkdir(exist_ok=True)
        with open(folder / "images.txt", "w") as f:
            for i, (ts, img) in enumerate(frames):
                name = f"images/frame_{i:08d}.png"
                cv2.imwrite(str(folder / name), img)
                f.write(f"{ts:.6f} {name}\n")
    if imu is not None:
        with open(folder / "imu.txt", "w") as f:
            for row in imu:
                f.write(" ".join(f"{v:.6f}" for v in row) + "\n")
    return folder


# ----------------------------------------------------------------------------------- HDF5


def write_dsec(path: Path, t_us, x, y, p01, t_offset: int = 0, compression=None) -> Path:
    """DSEC ``events.h5``: ``/events/{p,t,x,y}`` (t µs relative to ``/t_offset``), ``/ms_to_idx``."""
    import h5py

    t_us = np.asarray(t_us, np.int64)
    with h5py.File(path, "w") as f:
        g = f.create_group("events")
        g.create_dataset("t", data=(t_us - t_offset).astype(np.uint32), compression=compression)
        g.create_dataset("x", data=np.asarray(x, np.uint16), compression=compression)
        g.create_dataset("y", data=np.asarray(y, np.uint16), compression=compression)
        g.create_dataset("p", data=np.asarray(p01, np.uint8), compression=compression)
        f.create_dataset("t_offset", data=np.int64(t_offset))
        rel = t_us - t_offset
        ms = np.arange(0, int(rel.max()) // 1000 + 2) * 1000
        f.create_dataset("ms_to_idx", data=np.searchsorted(rel, ms, side="left").astype(np.uint64))
    return path


def write_mvsec(path: Path, t_s, x, y, pm1, images=None, image_ts=None) -> Path:
    """MVSEC ``<seq>_data.hdf5``: ``davis/left/events`` (N x 4 float64: x, y, t s, p ±1),
    ``davis/left/image_raw`` (N x 260 x 346 uint8), ``davis/left/image_raw_ts`` (s)."""
    import h5py

    with h5py.File(path, "w") as f:
        g = f.create_group("davis/left")
        g.create_dataset("events", data=np.stack([x, y, t_s, pm1], axis=1).astype(np.float64))
        if images is not None:
            g.create_dataset("image_raw", data=np.asarray(images, np.uint8))
            g.create_dataset("image_raw_ts", data=np.asarray(image_ts, np.float64))
    return path


# ----------------------------------------------------------------------------------- ROS bags

_DVS_MSGDEFS = {
    "dvs_msgs/msg/Event": "uint16 x\nuint16 y\ntime ts\nbool polarity\n",
    "dvs_msgs/msg/EventArray": "std_msgs/Header header\nuint32 height\nuint32 width\ndvs_msgs/Event[] events\n",
}


def write_ros1_bag(path: Path, event_msgs, images=(), exposures=(), width=346, height=260, ns="/dvs") -> Path:
    """A ROS1 bag written with rosbags' own Writer (independent of the reader's byte decoding).

    ``event_msgs``: list of (t, x, y, p) arrays per EventArray (t µs); ``images``: (stamp µs, uint8
    image); ``exposures``: (bag time µs, exposure µs) Int32 messages on ``<ns>/exposure``.
    """
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    types = {}
    for name, text in _DVS_MSGDEFS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    Time = store.types["builtin_interfaces/msg/Time"]
    Header = store.types["std_msgs/msg/Header"]
    Event = store.types["dvs_msgs/msg/Event"]
    EventArray = store.types["dvs_msgs/msg/EventArray"]
    Image = store.types["sensor_msgs/msg/Image"]
    Int32 = store.types["std_msgs/msg/Int32"]

    def tm(us):
        return Time(sec=int(us) // 1_000_000, nanosec=int(us) % 1_000_000 * 1000)

    msgs = []  # (bag time ns, kind, msg)
    for i, (t, x, y, p) in enumerate(event_msgs):
        evs = [Event(x=int(a), y=int(b), ts=tm(c), polarity=bool(d > 0)) for c, a, b, d in zip(t, x, y, p, strict=True)]
        m = EventArray(header=Header(seq=i, stamp=tm(t[-1]), frame_id="cam"), height=height, width=width, events=evs)
        msgs.append((int(t[-1]) * 1000 + 1, "events", m))
    for i, (stamp, img) in enumerate(images):
        m = Image(
            header=Header(seq=i, stamp=tm(stamp), frame_id="cam"),
            height=img.shape[0],
            width=img.shape[1],
            encoding="mono8",
            is_bigendian=0,
            step=img.shape[1],
            data=np.ascontiguousarray(img).ravel(),
        )
        msgs.append((int(stamp) * 1000 + 20_000_000, "image", m))  # received 20 ms after mid-exposure
    for t, e in exposures:
        msgs.append((int(t) * 1000, "exposure", Int32(data=int(e))))
    msgs.sort(key=lambda m: m[0])
    with Writer(path) as w:
        conns = {
            "events": w.add_connection(f"{ns}/events", "dvs_msgs/msg/EventArray", typestore=store),
            "image": w.add_connection(f"{ns}/image_raw", "sensor_msgs/msg/Image", typestore=store),
            "exposure": w.add_connection(f"{ns}/exposure", "std_msgs/msg/Int32", typestore=store),
        }
        for t, kind, m in msgs:
            w.write(conns[kind], t, store.serialize_ros1(m, conns[kind].msgtype))
    return path
