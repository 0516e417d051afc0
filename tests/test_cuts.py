"""``--start``/``--end`` cut exactly ``[first + start, first + end)``, in every input format.

The truth is counted from the arrays each file was written from (or, for the real AEDAT 4 sample,
read with the independent ``aedat`` decoder), never with necviz's readers: ``first`` is the earliest
timestamp of anything the file holds, events, IMU samples and triggers are kept when stamped in the
half-open interval, frames when their whole exposure lies in it. The files start with a burst of
events inside the first millisecond and an IMU sample before the first event, where a cut counted
from the wrong zero (the last timestamp of the first batch) loses data.
"""

from __future__ import annotations

import math
import struct

import format_writers as fw
import numpy as np
import pytest
from fuzz_corpus import SAMPLE_AEDAT4

from necviz.commands.cli import main
from necviz.core.events import EVENT_DTYPE
from necviz.core.imu import IMU_DTYPE
from necviz.io import load_npz

T0 = 5_000_037
EXPOSURE_US = 2000
W, H = 346, 260
#: (start_s, end_s) cuts: everything, from 0, the first microsecond only, a middle span, ragged bounds
CUTS = [(None, None), (0.0, None), (None, 1e-7), (0.05, 0.1), (0.0123456, 0.1500001)]


def _truth(rng):
    t = T0 + np.sort(np.concatenate([rng.integers(0, 46, 40), rng.integers(46, 200_000, 3960)]))
    ev = np.zeros(t.size, EVENT_DTYPE)
    ev["t"], ev["x"], ev["y"], ev["p"] = t, rng.integers(0, W, t.size), rng.integers(0, H, t.size), 1
    ev["p"][rng.random(t.size) < 0.5] = -1
    imu = np.zeros(200, IMU_DTYPE)
    imu["t"] = T0 - 5 + np.arange(200) * 1000  # the first sample precedes the first event
    imu["az"] = 1.0
    frames = [(T0 + 20_000 + k * 40_000, T0 + 20_000 + k * 40_000 + EXPOSURE_US) for k in range(5)]
    images = [np.full((H, W), 40 + 30 * k, np.uint8) for k in range(5)]
    return ev, imu, frames, images


def _batches(ev, cuts=()):
    """Event batches of at most 1 ms, also split at ``cuts`` (exposure starts and ends)."""
    t = ev["t"]
    edges = set(np.flatnonzero(np.diff(t // 1000)) + 1) | {int(np.searchsorted(t, c)) for c in cuts}
    bounds = sorted({0, t.size, *edges})
    return [ev[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True) if b > a]


def _write_native(path, ev, imu, frames, images):
    items = []  # (time, order, chunk type, payload): markers, then events at/after them, then samples
    for (s, e), img in zip(frames, images, strict=True):
        items.append((s, 0, 3, struct.pack("<qB", s, 0)))
        items.append((e, 1, 3, struct.pack("<qB", e, 1)))
        items.append((e, 2, 4, struct.pack("<qqdqHH", s, e, 1.0, 0, H, W) + img.tobytes()))
    for b in _batches(ev, [c for f in frames for c in f]):
        items.append((int(b["t"][0]), 3, 2, b.tobytes()))
    for s in imu:
        items.append((int(s["t"]), 4, 5, np.array([s], IMU_DTYPE).tobytes()))
    items.sort(key=lambda i: (i[0], i[1]))
    path.write_bytes(fw.native_bytes((W, H, "DAVIS346"), chunks=[(k, p) for _, _, k, p in items]))
    return path, {"imu": True, "frames": True}


def _write_aedat3(path, ev, imu, frames, images):
    items = []
    for b in _batches(ev):
        items.append((int(b["t"][0]), 1, fw.aedat3_polarity(b["t"], b["x"], b["y"], b["p"])))
    vals = np.zeros((len(imu), 7), np.float32)
    vals[:, 2] = 1.0
    for s, v in zip(imu, vals, strict=True):
        items.append((int(s["t"]), 2, fw.aedat3_imu6([s["t"]], v[None])))
    for (s, e), img in zip(frames, images, strict=True):  # stored once its readout ended
        items.append((e + 500, 0, fw.aedat3_frame(img.astype(np.uint16) << 2, s, e + 400, s, e)))
    items.sort(key=lambda i: (i[0], i[1]))
    path.write_bytes(fw.aedat3_header() + b"".join(p for _, _, p in items))
    return path, {"imu": True, "frames": True}


def _write_aedat2(path, ev, imu, frames, images):
    addr = [fw.jaer_dvs(ev["x"], ev["y"], ev["p"], W, H)]
    ts = [ev["t"]]
    for s in imu:
        addr.append(fw.jaer_imu([0, 0, 16384, 0, 0, 0, 0]))
        ts.append(np.full(7, int(s["t"])))
    addr, ts = np.concatenate(addr), np.concatenate(ts)
    order = np.argsort(ts, kind="stable")
    path.write_bytes(fw.aedat2_bytes(addr[order], ts[order]))
    return path, {"imu": True, "frames": False}


def _write_ros1(path, ev, imu, frames, images):
    msgs = [(b["t"], b["x"], b["y"], b["p"]) for b in _batches(ev)]
    imgs = [(s + EXPOSURE_US // 2, img) for (s, _), img in zip(frames, images, strict=True)]
    exps = [(s, EXPOSURE_US) for s, _ in frames]
    fw.write_ros1_bag(path, msgs, imgs, exps)
    return path, {"imu": False, "frames": True}


def _write_rpg(path, ev, imu, frames, images):
    si = np.zeros((len(imu), 7))
    si[:, 0] = imu["t"] / 1e6
    si[:, 3] = 9.80665
    stamps = [((s + EXPOSURE_US // 2) / 1e6, img) for (s, _), img in zip(frames, images, strict=True)]
    fw.write_rpg_text(path, ev["t"] / 1e6, ev["x"], ev["y"], (ev["p"] > 0).astype(int), stamps, si)
    return path, {"imu": True, "frames": True}


def _write_dsec(path, ev, imu, frames, images):
    fw.write_dsec(path, ev["t"], ev["x"], ev["y"], (ev["p"] > 0).astype(int), t_offset=T0 - 37)
    return path, {"imu": False, "frames": False}


def _write_mvsec(path, ev, imu, frames, images):
    stamps = np.array([(s + EXPOSURE_US // 2) / 1e6 for s, _ in frames])
    fw.write_mvsec(path, ev["t"] / 1e6, ev["x"], ev["y"], ev["p"], np.stack(images), stamps)
    return path, {"imu": False, "frames": True}


WRITERS = {
    "necviz": ("cut.necrec", _write_native),
    "aedat3": ("cut.aedat", _write_aedat3),
    "aedat2": ("cut2.aedat", _write_aedat2),
    "rosbag1": ("cut.bag", _write_ros1),
    "rpg-text": ("rpg", _write_rpg),
    "dsec": ("cut.h5", _write_dsec),
    "mvsec": ("cut_data.hdf5", _write_mvsec),
}


def _offset(seconds: float) -> int:
    """Seconds as the smallest whole µs not below them (t - first >= s  <=>  t - first >= ceil(s))."""
    return math.ceil(round(seconds * 1e6, 3))


def _select(ev, imu, frames, has, start_s, end_s):
    first = min([int(ev["t"][0])] + ([int(imu["t"][0])] if has["imu"] else []))
    lo = -(1 << 62) if start_s is None else first + _offset(start_s)
    hi = 1 << 62 if end_s is None else first + _offset(end_s)
    return (
        ev[(ev["t"] >= lo) & (ev["t"] < hi)],
        imu["t"][(imu["t"] >= lo) & (imu["t"] < hi)] if has["imu"] else np.zeros(0, np.int64),
        [f for f in frames if has["frames"] and f[0] >= lo and f[1] <= hi],
    )


def _export(src, out, start_s, end_s, fmt=None) -> int:
    args = ["export", str(src), str(out), "--exposure-us", str(EXPOSURE_US)]
    args += [] if start_s is None else ["--start", repr(start_s)]
    args += [] if end_s is None else ["--end", repr(end_s)]
    return main(args + ([] if fmt is None else ["--format", fmt]))


@pytest.mark.parametrize("fmt", sorted(WRITERS))
def test_every_cut_holds_exactly_the_half_open_interval(fmt, tmp_path):
    ev, imu, frames, images = _truth(np.random.default_rng(7))
    name, write = WRITERS[fmt]
    src, has = write(tmp_path / name, ev, imu, frames, images)
    for k, (start_s, end_s) in enumerate(CUTS):
        want_ev, want_imu, want_frames = _select(ev, imu, frames, has, start_s, end_s)
        out = tmp_path / f"cut{k}.npz"
        assert _export(src, out, start_s, end_s) == 0, (start_s, end_s)
        z = load_npz(out)
        got_ev = z["events"]
        assert len(got_ev) == len(want_ev), (fmt, start_s, end_s)
        np.testing.assert_array_equal(got_ev["t"], want_ev["t"])
        np.testing.assert_array_equal(got_ev["x"], want_ev["x"])
        np.testing.assert_array_equal(got_ev["p"], want_ev["p"])
        np.testing.assert_array_equal(z["imu"]["t"], want_imu)
        got_frames = list(zip(z["frame_exposure_start_us"].tolist(), z["frame_exposure_end_us"].tolist(), strict=True))
        assert got_frames == want_frames, (fmt, start_s, end_s)
    # the old zero (the last timestamp of the first 1 ms batch) dropped the burst: it is all there
    assert _select(ev, imu, frames, has, 0.0, None)[0].size == ev.size


def test_a_cut_of_a_ros2_bag_counts_from_its_first_event(tmp_path):
    from fuzz_corpus import _rosbag2

    folder = tmp_path / "ros2"
    _rosbag2(folder, np.random.default_rng(3))
    assert _export(folder, tmp_path / "all.npz", None, None) == 0
    ev = load_npz(tmp_path / "all.npz")["events"]  # the whole bag, written by rosbags' own Writer
    first = int(ev["t"][0])
    lo, hi = first + 2000, first + 15_000
    assert _export(folder, tmp_path / "cut.npz", 0.002, 0.015) == 0
    got = load_npz(tmp_path / "cut.npz")["events"]
    np.testing.assert_array_equal(got, ev[(ev["t"] >= lo) & (ev["t"] < hi)])


@pytest.mark.skipif(not SAMPLE_AEDAT4.is_file(), reason="the real DAVIS346 sample (../shared/data) is not here")
def test_cuts_of_the_real_davis_recording_match_the_aedat_decoder(tmp_path):
    import aedat

    ev, imu, frames, trg = [], [], [], []
    for packet in aedat.Decoder(str(SAMPLE_AEDAT4)):
        if "events" in packet:
            ev.append(packet["events"])
        elif "triggers" in packet:
            trg.append(packet["triggers"]["t"])
        elif "imus" in packet:
            imu.append(packet["imus"]["t"])
        elif "frame" in packet:
            frames.append((int(packet["frame"]["exposure_begin_t"]), int(packet["frame"]["exposure_end_t"])))
    ev = np.concatenate(ev)
    imu_t = np.concatenate(imu).astype(np.int64)
    t = ev["t"].astype(np.int64)
    trg_t = np.concatenate(trg).astype(np.int64)
    first = min(int(t.min()), int(imu_t.min()), int(trg_t.min()), min(s for s, _ in frames))
    for k, (start_s, end_s) in enumerate([(0.0, None), (None, 1e-7), (0.05, 0.1), (0.0123456, 0.1500001)]):
        lo = -(1 << 62) if start_s is None else first + _offset(start_s)
        hi = 1 << 62 if end_s is None else first + _offset(end_s)
        out = tmp_path / f"sample{k}.npz"
        inside = sum(int(np.sum((a >= lo) & (a < hi))) for a in (t, imu_t, trg_t))
        if not inside:  # nothing stamped in the interval: one line, exit 2, no file
            assert _export(SAMPLE_AEDAT4, out, start_s, end_s) == 2 and not out.exists()
            continue
        assert _export(SAMPLE_AEDAT4, out, start_s, end_s) == 0
        z = load_npz(out)
        np.testing.assert_array_equal(z["triggers"]["t"], trg_t[(trg_t >= lo) & (trg_t < hi)])
        np.testing.assert_array_equal(z["events"]["t"], t[(t >= lo) & (t < hi)])
        np.testing.assert_array_equal(z["imu"]["t"], imu_t[(imu_t >= lo) & (imu_t < hi)])
        got = list(zip(z["frame_exposure_start_us"].tolist(), z["frame_exposure_end_us"].tolist(), strict=True))
        assert got == [f for f in frames if f[0] >= lo and f[1] <= hi]
    assert len(load_npz(tmp_path / "sample0.npz")["events"]) == len(t)  # --start 0 keeps every event
