"""AEDAT 3.1 and AEDAT 2.0 readers on byte-exact synthetic files (tests/format_writers.py)."""

import numpy as np
import pytest
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
)

from necviz.core.events import EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import ImuBatch, TriggerBatch
from necviz.drivers.recordings import RecordingError, describe, open_recording

W, H = 346, 260


def _events(seed, n, t0, t1):
    rng = np.random.default_rng(seed)
    return (np.sort(rng.integers(t0, t1, n)), rng.integers(0, W, n), rng.integers(0, H, n), rng.choice([-1, 1], n))


def _split(packets):
    ev = [p.events for p in packets if isinstance(p, EventBatch)]
    return np.concatenate(ev) if ev else np.zeros(0), [p for p in packets if isinstance(p, Frame)]


# ------------------------------------------------------------------------------------- AEDAT 3.1


@pytest.fixture
def aedat3_file(tmp_path):
    t, x, y, p = _events(1, 4000, 1000, 300_000)
    rng = np.random.default_rng(2)
    img = rng.integers(0, 1024, (H, W))
    ov = 1  # timestamps beyond 2^31 µs use the packet's overflow counter
    base = 1 << 31
    parts = [
        aedat3_header(),
        aedat3_polarity(base + t[:1500], x[:1500], y[:1500], p[:1500], ov),
        aedat3_special(base + np.array([100_000, 101_000]), [16, 17], ov),
        aedat3_frame(img, base + 90_000, base + 120_000, base + 100_000, base + 101_000, ov),
        aedat3_polarity(base + t[1500:], x[1500:], y[1500:], p[1500:], ov),
        aedat3_imu6(base + np.array([200_000, 201_000]), [[0, 0, 1, 1, 2, 3, 30]] * 2, ov),
    ]
    path = tmp_path / "synthetic.aedat"
    path.write_bytes(b"".join(parts))
    return path, (base + t, x, y, p), img, parts


def test_aedat3_decodes_every_stream(aedat3_file):
    path, (t, x, y, p), img, _ = aedat3_file
    r = open_recording(path)
    assert r.format == "aedat3" and (r.sensor.width, r.sensor.height) == (W, H)
    packets = list(r)
    ev, frames = _split(packets)
    assert np.array_equal(ev["t"], t) and np.array_equal(ev["x"], x) and np.array_equal(ev["y"], y)
    assert np.array_equal(ev["p"], p)
    assert len(frames) == 1
    f = frames[0]
    assert (f.exposure_start_us, f.exposure_end_us) == ((1 << 31) + 100_000, (1 << 31) + 101_000)
    assert np.array_equal(f.image, (img >> 2).astype(np.uint8))  # 10-bit -> 8 most significant bits
    i = next(k for k, q in enumerate(packets) if q is f)
    assert packets[i - 1] == ExposureMarker(f.exposure_end_us, "end")
    imu = np.concatenate([q.samples for q in packets if isinstance(q, ImuBatch)])
    assert imu.size == 2 and imu["az"][0] == 1.0 and imu["gz"][0] == 3.0 and imu["temp"][0] == 30.0
    trg = np.concatenate([q.triggers for q in packets if isinstance(q, TriggerBatch)])
    assert trg["kind"].tolist() == [8, 9]  # exposure begin / end
    assert r.exposure_source == "stored" and r.warnings == []


def test_aedat3_truncated_and_garbage(aedat3_file, tmp_path):
    path, (t, *_), _, parts = aedat3_file
    data = path.read_bytes()
    head = len(parts[0]) + len(parts[1]) + len(parts[2]) + len(parts[3])
    cut = tmp_path / "cut.aedat"
    cut.write_bytes(data[: head + 28 + 100])  # inside the second polarity packet
    got = []
    with pytest.raises(RecordingError, match=rf"cut\.aedat: truncated packet .* at byte {head}$"):
        for q in open_recording(cut):
            got.append(q)
    ev, frames = _split(got)
    assert np.array_equal(ev["t"], t[:1500]) and len(frames) == 1
    bad = tmp_path / "garbage.aedat"
    bad.write_bytes(data[:head] + b"\xff" * 28 + data[head + 28 :])
    got = []
    with pytest.raises(RecordingError, match=rf"garbage\.aedat: implausible packet header.* at byte {head}$"):
        for q in open_recording(bad):
            got.append(q)
    assert _split(got)[0].size == 1500
    wrong = tmp_path / "wrong.aedat"
    wrong.write_bytes(b"#!AER-DAT3.7\r\n" + data[14:])
    with pytest.raises(RecordingError, match="wrong magic"):
        open_recording(wrong)
    empty = tmp_path / "empty.aedat"
    empty.write_bytes(b"")
    with pytest.raises(RecordingError, match="empty file"):
        open_recording(empty)


# ------------------------------------------------------------------------------------- AEDAT 2.0


@pytest.fixture
def aedat2_file(tmp_path):
    t, x, y, p = _events(3, 3000, 0, 60_000)
    rng = np.random.default_rng(4)
    reset = rng.integers(600, 1000, (H, W))
    sig = reset - rng.integers(0, 600, (H, W))
    fa, ft = aedat2_frame_words(reset, sig, 20_000, 22_000, W, H, step_us=1000)
    dvs = jaer_dvs(x, y, p, W, H)
    k = np.searchsorted(t, 20_000)
    k2 = np.searchsorted(t, 40_000)
    imu = jaer_imu([8192, -8192, 4096, 340, 655, -131, 0])
    addr = np.concatenate([dvs[:k], fa, dvs[k:k2], imu, dvs[k2:]])
    ts = np.concatenate([t[:k], ft, t[k:k2], [40_000] * 7, t[k2:]])
    order = np.argsort(ts, kind="stable")
    path = tmp_path / "synthetic_davis346.aedat"
    data = aedat2_bytes(addr[order], ts[order])
    path.write_bytes(data)
    return path, (t, x, y, p), np.clip(reset - sig, 0, 1023), data


def test_aedat2_events_frames_imu(aedat2_file):
    path, (t, x, y, p), cds, _ = aedat2_file
    r = open_recording(path)
    assert r.format == "aedat2" and (r.sensor.width, r.sensor.height) == (W, H)
    packets = list(r)
    ev, frames = _split(packets)
    assert np.array_equal(ev["t"], t) and np.array_equal(ev["x"], x) and np.array_equal(ev["y"], y)
    assert np.array_equal(ev["p"], p)
    assert len(frames) == 1
    assert np.array_equal(frames[0].image, (cds >> 2).astype(np.uint8))  # CDS, flipped back to top-left
    assert (frames[0].exposure_start_us, frames[0].exposure_end_us) == (20_000, 22_000)
    assert r.exposure_source == "estimated from frame timing"
    imu = np.concatenate([q.samples for q in packets if isinstance(q, ImuBatch)])
    assert imu.size == 1 and imu["ax"][0] == 1.0 and imu["ay"][0] == -1.0 and imu["az"][0] == 0.5
    assert imu["temp"][0] == pytest.approx(36.0) and imu["gx"][0] == pytest.approx(10.0)


def test_aedat2_user_exposure(aedat2_file):
    path = aedat2_file[0]
    r = open_recording(path, exposure_us=800)
    frames = [q for q in r if isinstance(q, Frame)]
    assert [(f.exposure_start_us, f.exposure_end_us) for f in frames] == [(21_200, 22_000)]
    assert r.exposure_source == "user (--exposure-us)"
    assert describe(path, exposure_us=800).exposure_source == "user (--exposure-us)"


def test_aedat2_truncated_and_garbage(aedat2_file, tmp_path):
    path, (t, *_), _, data = aedat2_file
    header = data.index(b"\n", data.index(b"# HardwareInterface")) + 1
    cut = tmp_path / "cut.aedat"
    cut.write_bytes(data[:-3])
    got = []
    with pytest.raises(RecordingError, match=rf"cut\.aedat: truncated record .* at byte {len(data) - 8}$"):
        for q in open_recording(cut):
            got.append(q)
    assert _split(got)[0].size == t.size - 1  # all complete records replayed
    at = header + 8 * 1500
    bad = tmp_path / "garbage.aedat"
    bad.write_bytes(data[:at] + b"\xff" * 64 + data[at + 64 :])
    got = []
    with pytest.raises(RecordingError, match=rf"garbage\.aedat: timestamp jumps .* at byte {at}$"):
        for q in open_recording(bad):
            got.append(q)
    words = np.frombuffer(data[header:at], ">u4").reshape(-1, 2)[:, 0].astype(np.int64)
    assert _split(got)[0].size == int(np.count_nonzero(((words >> 31) == 0) & ((words >> 10) & 1 == 0)))
    wrong = tmp_path / "wrong.aedat"
    wrong.write_bytes(b"#!AER-DAT2.1" + data[12:])
    with pytest.raises(RecordingError, match="wrong magic"):
        open_recording(wrong)
