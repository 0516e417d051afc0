"""AEDAT 4.0 replay on the real DAVIS346 sample (shared/data), plus damaged copies of it."""

import shutil
import struct

import numpy as np
import pytest
from conftest import SHARED_DATA

from necviz.core.events import EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import ImuBatch, TriggerBatch
from necviz.drivers.recordings import RecordingError, describe, detect_format, open_recording

SAMPLE = SHARED_DATA / "davis346_sample.aedat4"
pytestmark = pytest.mark.skipif(
    not SAMPLE.is_file(),
    reason=f"real sample not found at {SAMPLE} (the shared data folder exists only in the project workspace)",
)


def _split(packets):
    ev = [p.events for p in packets if isinstance(p, EventBatch)]
    return (
        np.concatenate(ev) if ev else None,
        [p for p in packets if isinstance(p, Frame)],
        [p for p in packets if isinstance(p, ExposureMarker)],
    )


def test_real_sample_decodes_with_the_right_counts():
    r = open_recording(SAMPLE)
    assert r.format == "aedat4" and (r.sensor.width, r.sensor.height) == (346, 260)
    packets = list(r)
    ev, frames, markers = _split(packets)
    assert ev.size == 6676
    assert np.all(np.diff(ev["t"]) >= 0)
    assert set(np.unique(ev["p"])) == {-1, 1}
    assert ev["x"].max() < 346 and ev["y"].max() < 260
    assert len(frames) == 4
    for f in frames:
        assert f.image.shape == (260, 346) and f.image.dtype == np.uint8
        assert abs(f.exposure_us - 500) <= 1
    starts = [f.exposure_start_us for f in frames]
    assert starts == sorted(starts) and np.all(np.diff(starts) > 0)
    assert sum(len(p) for p in packets if isinstance(p, ImuBatch)) == 160
    assert sum(len(p) for p in packets if isinstance(p, TriggerBatch)) == 17
    assert r.exposure_source == "stored" and r.warnings == []
    assert r.commands == [] and r.annotations == []


def test_stream_order_contract():
    """start marker before events at/after it, end marker after events before it, frame after its end."""
    last_t = None
    open_start = None
    pending_end = None
    batches = 0
    for p in open_recording(SAMPLE):
        if isinstance(p, EventBatch):
            batches += 1
            p = p.events
            assert p.size <= 65536 and int(p["t"][-1]) - int(p["t"][0]) < 1000
            if last_t is not None:
                assert p["t"][0] >= last_t
            last_t = int(p["t"][-1])
            if open_start is not None:
                assert p["t"][0] >= open_start
        elif isinstance(p, ExposureMarker):
            if p.kind == "start":
                assert last_t is None or last_t < p.t_us
                open_start = p.t_us
            else:
                assert last_t is None or last_t < p.t_us
                pending_end, open_start = p.t_us, None
        elif isinstance(p, Frame):
            assert pending_end == p.exposure_end_us
            pending_end = None
    assert batches > 0 and last_t is not None


def test_seek_by_time():
    full = _split(list(open_recording(SAMPLE)))
    t0 = int(full[1][1].exposure_start_us) - 100
    t1 = int(full[1][2].exposure_end_us) + 100
    ev, frames, _ = _split(list(open_recording(SAMPLE, start_us=t0, end_us=t1)))
    want = full[0][(full[0]["t"] >= t0) & (full[0]["t"] < t1)]  # [start, end): the end excluded
    assert np.array_equal(ev, want)
    assert [f.exposure_start_us for f in frames] == [full[1][1].exposure_start_us, full[1][2].exposure_start_us]


def test_describe_real_sample():
    info = describe(SAMPLE)
    assert (info.events, info.frames, info.width, info.height) == (6676, 4, 346, 260)
    assert info.exposure_source == "stored" and abs(info.exposure_min_us - 500) <= 1
    assert 0.15 < info.duration_s < 0.2
    text = info.to_text()
    assert "6,676" in text and "346 x 260" in text and "500 µs (stored)" in text
    assert info.to_dict()["events"] == 6676


def _packet_offsets(data):
    off = 18 + struct.unpack_from("<I", data, 14)[0]
    out = []
    while off + 8 <= len(data):
        sid, size = struct.unpack_from("<II", data, off)
        if sid > 10:
            break
        out.append((off, sid, size))
        off += 8 + size
    return out


def test_truncated_copy_yields_what_precedes_the_damage(tmp_path):
    data = SAMPLE.read_bytes()
    pk = _packet_offsets(data)
    off, sid, size = pk[20]
    path = tmp_path / "trunc.aedat4"
    path.write_bytes(data[: off + 8 + size // 2])
    got = []
    with pytest.raises(RecordingError) as err:
        for p in open_recording(path):
            got.append(p)
    assert str(path) in str(err.value) and f"at byte {off}" in str(err.value)
    ev, frames, _ = _split(got)
    assert 0 < ev.size < 6676 and len(frames) >= 1


def test_garbage_packet_header(tmp_path):
    data = bytearray(SAMPLE.read_bytes())
    off = _packet_offsets(bytes(data))[10][0]
    data[off : off + 8] = b"\xde\xad\xbe\xef" * 2
    path = tmp_path / "garbage.aedat4"
    path.write_bytes(bytes(data))
    got = []
    with pytest.raises(RecordingError, match=rf"unknown stream id .* at byte {off}$"):
        for p in open_recording(path):
            got.append(p)
    assert _split(got)[0].size > 0


def test_wrong_magic_zero_length_and_detection_by_content(tmp_path):
    bad = tmp_path / "bad.aedat4"
    bad.write_bytes(b"#!AER-DAT9.9\r\n" + b"\0" * 100)
    with pytest.raises(RecordingError, match="wrong magic"):
        open_recording(bad)
    empty = tmp_path / "empty.aedat4"
    empty.write_bytes(b"")
    with pytest.raises(RecordingError, match=r"empty\.aedat4: empty file \(0 bytes\)"):
        open_recording(empty)
    renamed = tmp_path / "recording.dat"  # detection uses the magic, not the name
    shutil.copy(SAMPLE, renamed)
    assert detect_format(renamed) == "aedat4"
    with pytest.raises(RecordingError, match="aedat4"):
        open_recording(tmp_path / "missing.aedat4")
