"""Corrupted recordings for the robustness tests (``tests/test_fuzz_files.py``) and ``benchmarks/fuzz.py``.

:func:`build_seeds` writes one small, valid recording of every supported format with the project's own
writers (:mod:`format_writers`, the native :class:`~necviz.drivers.recordings.native.Recorder`, rosbags'
writer for ROS 2) plus the real DAVIS346 AEDAT 4 sample when it is present. :func:`variants` derives
corrupted copies from them, deterministically from a seed: truncation at a random offset, bit flips,
random bytes, huge values written into length fields (located from each format's documented layout),
a damaged magic, another format's header spliced in front, deleted/duplicated/zeroed spans, and for
text files changed column counts and non-numeric tokens. :func:`read_variant` reads one file the way
``necviz info`` and ``replay`` do and classifies the outcome: ``clean`` (read to the end), ``error``
(a one-line :class:`~necviz.core.errors.NecvizError` naming the file) or ``traceback`` (anything else,
including a multi-line or anonymous error message).
"""

from __future__ import annotations

import shutil
import struct
import time
import traceback
import tracemalloc
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from format_writers import (
    aedat2_bytes,
    aedat2_frame_words,
    aedat3_frame,
    aedat3_header,
    aedat3_imu6,
    aedat3_polarity,
    aedat3_special,
    jaer_dvs,
    jaer_imu,
    write_dsec,
    write_mvsec,
    write_ros1_bag,
    write_rpg_text,
)

#: the real recording the AEDAT 4 seed is taken from (tests read ../shared/data)
SAMPLE_AEDAT4 = Path(__file__).resolve().parents[2] / "shared" / "data" / "davis346_sample.aedat4"

MUTATIONS = (
    "truncate",
    "bit_flips",
    "random_bytes",
    "huge_length",
    "wrong_magic",
    "splice_header",
    "delete_span",
    "duplicate_span",
    "zero_span",
    "text_columns",
    "text_token",
)


@dataclass(frozen=True)
class Seed:
    """A valid recording: ``path`` (file or folder) and, for folders, the member files that may be damaged."""

    format: str
    path: Path
    members: tuple[str, ...] = ()

    @property
    def is_dir(self) -> bool:
        return self.path.is_dir()


# ----------------------------------------------------------------------------------- seeds


def _events(rng, n, t0, t1, w, h):
    t = np.sort(rng.integers(t0, t1, n))
    return t, rng.integers(0, w, n), rng.integers(0, h, n), rng.integers(0, 2, n)


def _native(path: Path, rng) -> None:
    from necviz.core.events import EVENT_DTYPE, EventBatch
    from necviz.core.frames import ExposureMarker, Frame
    from necviz.core.imu import IMU_DTYPE, TRIGGER_DTYPE, ImuBatch, TriggerBatch
    from necviz.core.sensor import SensorGeometry
    from necviz.drivers.recordings import Recorder
    from necviz.drivers.source import CommandRecord

    sensor = SensorGeometry(32, 24, "small")
    with Recorder(path, sensor=sensor, properties={"source": "fuzz seed"}) as rec:
        t = 0
        for k in range(4):
            ev = np.zeros(300, EVENT_DTYPE)
            ev["t"] = np.sort(rng.integers(t, t + 10_000, 300))
            ev["x"] = rng.integers(0, 32, 300)
            ev["y"] = rng.integers(0, 24, 300)
            ev["p"] = rng.choice([-1, 1], 300)
            rec.write(EventBatch(ev[:150]))
            s, e = int(ev["t"][149]), int(ev["t"][149]) + 2000
            rec.write(ExposureMarker(s, "start"))
            rec.write(EventBatch(ev[150:]))
            rec.write(ExposureMarker(max(e, int(ev["t"][-1])), "end"))
            rec.write(Frame(rng.integers(0, 256, sensor.shape, dtype=np.uint8), s, max(e, int(ev["t"][-1])), 1.0, k))
            imu = np.zeros(3, IMU_DTYPE)
            imu["t"] = int(ev["t"][-1])
            rec.write(ImuBatch(imu))
            trg = np.zeros(1, TRIGGER_DTYPE)
            trg["t"] = int(ev["t"][-1])
            rec.write(TriggerBatch(trg))
            rec.command(CommandRecord(int(ev["t"][-1]), 3000.0, 1.0, None))
            rec.annotate(int(ev["t"][-1]), {"k": k})
            t = int(ev["t"][-1]) + 1


def _aedat3(rng) -> bytes:
    w, h = 32, 24
    parts = [aedat3_header("DAVIS32")]  # unknown chip: the size comes from the data
    t = 0
    for _k in range(4):
        tt, x, y, p = _events(rng, 200, t, t + 10_000, w, h)
        parts.append(aedat3_polarity(tt, x, y, p))
        img = rng.integers(0, 1024, (h, w))
        parts.append(aedat3_frame(img, tt[0], tt[-1], tt[0] + 10, tt[0] + 2000))
        parts.append(aedat3_imu6([int(tt[-1])], [[0, 0, 1, 0, 0, 0, 30]]))
        parts.append(aedat3_special([int(tt[-1])], [3]))
        t = int(tt[-1]) + 1
    return b"".join(parts)


def _aedat2(rng) -> bytes:
    w = h = 128
    t, x, y, p = _events(rng, 3000, 0, 60_000, w, h)
    reset = rng.integers(600, 1000, (h, w))
    sig = reset - rng.integers(0, 600, (h, w))
    fa, ft = aedat2_frame_words(reset, sig, 20_000, 22_000, w, h, step_us=1000)
    imu = jaer_imu([8192, -8192, 4096, 340, 655, -131, 0])
    ext = np.array([(3 << 0) | (1 << 10)], np.int64)  # external input, rising edge
    addr = np.concatenate([jaer_dvs(x, y, p, w, h), fa, imu, ext])
    ts = np.concatenate([t, ft, [40_000] * 7, [41_000]])
    order = np.argsort(ts, kind="stable")
    return aedat2_bytes(addr[order], ts[order], chip="eu.seebetter.ini.chips.davis.DAVIS128")


def _rosbag2(folder: Path, rng) -> None:
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from necviz.drivers.recordings.rosbag import DVS_MSGS

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = {}
    for name, text in DVS_MSGS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    Time = store.types["builtin_interfaces/msg/Time"]
    Header = store.types["std_msgs/msg/Header"]
    Event = store.types["dvs_msgs/msg/Event"]
    EventArray = store.types["dvs_msgs/msg/EventArray"]
    with Writer(folder, version=8) as w:
        conn = w.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=store)
        t0 = 1_000_000
        for _k in range(3):
            tt, x, y, p = _events(rng, 40, t0, t0 + 10_000, 32, 24)
            evs = [
                Event(
                    x=int(a),
                    y=int(b),
                    ts=Time(sec=int(c) // 1_000_000, nanosec=int(c) % 1_000_000 * 1000),
                    polarity=bool(d),
                )
                for c, a, b, d in zip(tt, x, y, p, strict=True)
            ]
            stamp = Time(sec=int(tt[-1]) // 1_000_000, nanosec=int(tt[-1]) % 1_000_000 * 1000)
            msg = EventArray(header=Header(stamp=stamp, frame_id="cam"), height=24, width=32, events=evs)
            w.write(conn, int(tt[-1]) * 1000, store.serialize_cdr(msg, conn.msgtype))
            t0 = int(tt[-1]) + 1


def build_seeds(folder, *, sample: Path | None = SAMPLE_AEDAT4, seed: int = 0) -> list[Seed]:
    """Write one valid recording per format into ``folder``; returns them (AEDAT 4 only if ``sample`` exists)."""
    import cv2

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for old in ("seed.bag", "seed_ros2", "seed_rpg"):  # writers that refuse to overwrite
        remove(folder / old)
    rng = np.random.default_rng(seed)
    seeds = []
    p = folder / "seed.necrec"
    _native(p, rng)
    seeds.append(Seed("necviz", p))
    p = folder / "seed3.aedat"
    p.write_bytes(_aedat3(rng))
    seeds.append(Seed("aedat3", p))
    p = folder / "seed2.aedat"
    p.write_bytes(_aedat2(rng))
    seeds.append(Seed("aedat2", p))
    t, x, y, pol = _events(rng, 120, 1_000_000, 1_060_000, 32, 24)
    msgs = [(t[i : i + 40], x[i : i + 40], y[i : i + 40], pol[i : i + 40]) for i in range(0, 120, 40)]
    img = rng.integers(0, 256, (24, 32), dtype=np.uint8)
    p = folder / "seed.bag"
    write_ros1_bag(p, msgs, images=[(1_020_000, img)], exposures=[(1_000_000, 2000)], width=32, height=24)
    seeds.append(Seed("rosbag1", p))
    p = folder / "seed_ros2"
    _rosbag2(p, rng)
    seeds.append(Seed("rosbag2", p, tuple(sorted(f.name for f in p.iterdir()))))
    t, x, y, pol = _events(rng, 2000, 0, 200_000, 32, 24)
    p = folder / "seed_dsec.h5"
    write_dsec(p, t + 5_000_000, x, y, pol, t_offset=5_000_000)
    seeds.append(Seed("hdf5", p))
    p = folder / "seed_mvsec.hdf5"
    imgs = rng.integers(0, 256, (2, 24, 32), dtype=np.uint8)
    write_mvsec(p, t / 1e6, x, y, pol * 2 - 1, images=imgs, image_ts=[0.05, 0.15])
    seeds.append(Seed("hdf5", p))
    p = folder / "seed_rpg"
    write_rpg_text(
        p,
        t / 1e6,
        x,
        y,
        pol,
        frames=[(0.05, img), (0.15, img)],
        imu=[[0.1, 0, 0, 9.81, 0, 0, 0.1], [0.12, 0, 0, 9.81, 0, 0, 0.2]],
    )
    seeds.append(Seed("rpg-text", p, ("events.txt", "images.txt", "imu.txt", "images/frame_00000000.png")))
    p = folder / "seed_events.txt"
    shutil.copyfile(folder / "seed_rpg" / "events.txt", p)
    seeds.append(Seed("rpg-text", p))
    assert cv2 is not None
    if sample is not None and Path(sample).is_file():
        p = folder / "seed.aedat4"
        shutil.copyfile(sample, p)
        seeds.append(Seed("aedat4", p))
    return seeds


# ----------------------------------------------------------------------------------- length fields


def _length_fields(fmt: str, data: bytes) -> list[tuple[int, int]]:
    """(offset, size in bytes) of the length/count fields of ``data``, from each format's layout."""
    out: list[tuple[int, int]] = []
    try:
        if fmt == "necviz":  # chunk := type u8, length u32, crc u32, payload
            off = 12
            while off + 9 <= len(data):
                out.append((off + 1, 4))
                off += 9 + struct.unpack_from("<I", data, off + 1)[0]
        elif fmt == "aedat4":  # IOHeader length u32 at 14; packets: stream id u32, size u32
            out.append((14, 4))
            off = 18 + struct.unpack_from("<I", data, 14)[0]
            while off + 8 <= len(data) and len(out) < 200:
                out.append((off + 4, 4))
                off += 8 + struct.unpack_from("<I", data, off + 4)[0]
        elif fmt == "aedat3":  # 28-byte packet headers: size @4, capacity @20, number @24, valid @28-4
            off = data.index(b"#!END-HEADER\r\n") + 14
            while off + 28 <= len(data):
                out += [(off + 4, 4), (off + 16, 4), (off + 20, 4), (off + 24, 4)]
                esize, cap = struct.unpack_from("<i", data, off + 4)[0], struct.unpack_from("<i", data, off + 20)[0]
                off += 28 + esize * cap
        elif fmt == "rosbag1":  # record := header_len u32, header, data_len u32, data
            off = 13
            while off + 4 <= len(data) and len(out) < 200:
                hl = struct.unpack_from("<I", data, off)[0]
                out.append((off, 4))
                if off + 4 + hl + 4 > len(data):
                    break
                out.append((off + 4 + hl, 4))
                dl = struct.unpack_from("<I", data, off + 4 + hl)[0]
                off += 8 + hl + dl
    except (struct.error, ValueError):
        pass
    return out


HUGE = (0xFFFFFFFF, 0x7FFFFFFF, 0x80000000, 0x10000000, 0x00FFFFFF)


# ----------------------------------------------------------------------------------- mutations


def mutate(data: bytes, fmt: str, kind: str, rng, others: list[bytes]) -> bytes:
    """A damaged copy of ``data`` (a recording of format ``fmt``) made by mutation ``kind``."""
    n = len(data)
    b = bytearray(data)
    if n == 0:
        return bytes(rng.integers(0, 256, 64, dtype=np.uint8))
    if kind == "truncate":
        return data[: int(rng.integers(0, n))]
    if kind == "bit_flips":
        for _ in range(int(rng.integers(1, 9))):
            i = int(rng.integers(0, n))
            b[i] ^= 1 << int(rng.integers(0, 8))
        return bytes(b)
    if kind == "random_bytes":
        for _ in range(int(rng.integers(1, 17))):
            b[int(rng.integers(0, n))] = int(rng.integers(0, 256))
        return bytes(b)
    if kind == "huge_length":
        fields = _length_fields(fmt, data)
        v = int(HUGE[int(rng.integers(0, len(HUGE)))])
        if fields:
            off, size = fields[int(rng.integers(0, len(fields)))]
        else:  # no documented length fields (HDF5, text, PNG): any aligned word
            size = 8 if fmt == "hdf5" and rng.random() < 0.5 else 4
            off = int(rng.integers(0, max(1, n // size))) * size
            v = (1 << (8 * size)) - 1 if size == 8 else v
        if off + size <= n:
            b[off : off + size] = (v & ((1 << (8 * size)) - 1)).to_bytes(size, "little")
        return bytes(b)
    if kind == "wrong_magic":
        i = int(rng.integers(0, min(n, 16)))
        b[i] = (b[i] + int(rng.integers(1, 256))) & 0xFF
        return bytes(b)
    if kind == "splice_header":
        other = others[int(rng.integers(0, len(others)))] if others else data
        k = int(rng.integers(8, max(9, min(len(other), 4096))))
        j = int(rng.integers(0, n))
        return other[:k] + data[j:]
    if kind == "delete_span":
        i = int(rng.integers(0, n))
        return data[:i] + data[i + int(rng.integers(1, max(2, n // 4))) :]
    if kind == "duplicate_span":
        i = int(rng.integers(0, n))
        j = min(n, i + int(rng.integers(1, max(2, n // 4))))
        return data[:j] + data[i:j] + data[j:]
    if kind == "zero_span":
        i = int(rng.integers(0, n))
        j = min(n, i + int(rng.integers(1, 4096)))
        b[i:j] = bytes(j - i)
        return bytes(b)
    if kind in ("text_columns", "text_token"):
        lines = data.split(b"\n")
        k = int(rng.integers(0, len(lines)))
        parts = lines[k].split()
        if kind == "text_columns":
            if parts and rng.random() < 0.5:
                parts = parts[: int(rng.integers(0, len(parts)))]
            else:
                parts = parts + [b"%d" % int(rng.integers(0, 1000))] * int(rng.integers(1, 4))
        else:
            token = [b"nan", b"inf", b"-1e308", b"1e400", b"x", b"0x1f", b"--", b"\xff\xfe", b"99999999999999999999"]
            tok = token[int(rng.integers(0, len(token)))]
            if parts:
                parts[int(rng.integers(0, len(parts)))] = tok
            else:
                parts = [tok]
        lines[k] = b" ".join(parts)
        return b"\n".join(lines)
    raise ValueError(f"unknown mutation {kind!r}")


def _kinds_for(member: str) -> tuple[str, ...]:
    text = member.endswith(".txt") or member.endswith(".yaml")
    return MUTATIONS if text else MUTATIONS[:-2]


class VariantMaker:
    """Corrupted copies of ``seeds``: :meth:`make` writes variant ``i`` (a pure function of ``seed`` and
    ``i``, so variants can be made in any order, by any process)."""

    def __init__(self, seeds: list[Seed], seed: int, folder):
        self.seeds, self.seed = list(seeds), int(seed)
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.blobs = {s.path: (s.path.read_bytes() if not s.is_dir else None) for s in self.seeds}
        self.headers = [v[:4096] for v in self.blobs.values() if v is not None]

    def make(self, i: int) -> tuple[str, str, Path]:
        """Write variant ``i``; returns ``(format, mutation, path)``. Formats and mutations are taken
        in turn, so every format gets every mutation."""
        rng = np.random.default_rng([self.seed, i])
        s = self.seeds[i % len(self.seeds)]
        member = s.members[int(rng.integers(0, len(s.members)))] if s.is_dir else ""
        kinds = _kinds_for(member or s.path.name)
        kind = kinds[(i // len(self.seeds)) % len(kinds)]
        dst = self.folder / f"v{i:06d}_{s.path.name}"
        remove(dst)
        if s.is_dir:
            shutil.copytree(s.path, dst)
            target = dst / member
            data = target.read_bytes()
        else:
            target = dst
            data = self.blobs[s.path]
        others = [h for h in self.headers if h[:12] != data[:12]]
        target.write_bytes(mutate(data, s.format, kind, rng, others))
        return s.format, kind, dst


def variants(seeds: list[Seed], n: int, seed: int, folder):
    """Yield ``(format, mutation, path)`` for variants ``0 .. n-1`` (see :class:`VariantMaker`).

    The same arguments give the same files. The caller may delete each variant once read."""
    maker = VariantMaker(seeds, seed, folder)
    for i in range(n):
        yield maker.make(i)


def remove(path) -> None:
    p = Path(path)
    if p.is_dir():
        shutil.rmtree(p, ignore_errors=True)
    else:
        try:
            p.unlink()
        except FileNotFoundError:
            pass


# ----------------------------------------------------------------------------------- reading


def _reset_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _peak_rss() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    return 0


def _rss() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    return 0


def read_variant(path, *, describe_too: bool = True) -> dict:
    """Read ``path`` completely (``open_recording`` + iteration, then ``describe``) and classify.

    Returns ``{"outcome": "clean"|"error"|"traceback", "message", "seconds", "memory_bytes",
    "events", "frames"}``. ``memory_bytes`` is the growth of the peak resident set over the RSS
    before the read (Linux ``VmHWM``, reset per read through ``/proc/self/clear_refs``); elsewhere the
    tracemalloc peak of the read.
    """
    from necviz.core.errors import NecvizError
    from necviz.core.events import EventBatch
    from necviz.core.frames import Frame
    from necviz.drivers.recordings import describe, open_recording

    path = Path(path)
    measured = _reset_peak()
    base = _rss() if measured else 0
    traced = not measured and not tracemalloc.is_tracing()
    if traced:  # no /proc (not Linux): Python-level allocations only (NumPy reports its buffers)
        tracemalloc.start()
    t0 = time.perf_counter()
    events = frames = 0
    out = {"outcome": "clean", "message": ""}
    try:
        rec = open_recording(path)
        try:
            w, h = rec.sensor.width, rec.sensor.height
            for pk in rec:
                if isinstance(pk, EventBatch):
                    ev = pk.events
                    events += ev.size
                    if ev.size and (int(ev["x"].max()) >= w or int(ev["y"].max()) >= h):
                        raise AssertionError(f"event off the {w}x{h} sensor")
                elif isinstance(pk, Frame):
                    frames += 1
        finally:
            rec.close()
    except NecvizError as exc:
        out = {"outcome": "error", "message": str(exc)}
    except BaseException as exc:  # noqa: BLE001 - this is what the fuzzer counts
        if isinstance(exc, KeyboardInterrupt):
            raise
        out = {"outcome": "traceback", "message": "".join(traceback.format_exception(exc))[-3000:]}
    if out["outcome"] != "traceback" and describe_too:
        try:
            describe(path)
        except NecvizError as exc:
            if out["outcome"] == "clean":
                out = {"outcome": "error", "message": str(exc)}
        except BaseException as exc:  # noqa: BLE001
            if isinstance(exc, KeyboardInterrupt):
                raise
            out = {"outcome": "traceback", "message": "describe: " + "".join(traceback.format_exception(exc))[-3000:]}
    if out["outcome"] == "error":
        msg = out["message"]
        if "\n" in msg or path.name not in msg:
            out = {"outcome": "traceback", "message": f"not a one-line error naming the file: {msg!r}"}
    out["seconds"] = time.perf_counter() - t0
    if measured:
        out["memory_bytes"] = max(0, _peak_rss() - base)
    elif traced:
        out["memory_bytes"] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    else:
        out["memory_bytes"] = 0
    out["events"], out["frames"] = events, frames
    return out


__all__ = [
    "MUTATIONS",
    "SAMPLE_AEDAT4",
    "Seed",
    "VariantMaker",
    "build_seeds",
    "mutate",
    "read_variant",
    "remove",
    "variants",
]
