"""Native recordings: round trip, seeking, crash safety (SIGKILL mid-stream) and damaged files."""

import os
import signal
import struct
import subprocess
import sys
import time

import numpy as np
import pytest
from format_writers import native_bytes, native_events

from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.imu import IMU_DTYPE, TRIGGER_DTYPE, ImuBatch, TriggerBatch
from necviz.core.sensor import SensorGeometry
from necviz.core.stream import interleave
from necviz.drivers.recordings import Recorder, RecordingError, describe, open_recording
from necviz.drivers.source import CommandRecord

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

SMALL = SensorGeometry(32, 24, "small")


def _stream(seed=0, n=20000, frames=5, sensor=SMALL):
    rng = np.random.default_rng(seed)
    ev = np.zeros(n, EVENT_DTYPE)
    ev["t"] = np.sort(rng.integers(0, 500_000, n))
    ev["x"] = rng.integers(0, sensor.width, n)
    ev["y"] = rng.integers(0, sensor.height, n)
    ev["p"] = rng.choice([-1, 1], n)
    fr = [
        Frame(rng.integers(0, 256, sensor.shape, dtype=np.uint8), s, s + 3000, 1.5, i)
        for i, s in enumerate(range(20_000, 500_000, 500_000 // frames))
    ][:frames]
    return ev, fr, list(interleave(ev, fr, 0, 1000))


def _same(a, b):
    assert type(a) is type(b)
    if isinstance(a, EventBatch):
        assert np.array_equal(a.events, b.events)
    elif isinstance(a, Frame):
        assert np.array_equal(a.image, b.image)
        assert (a.exposure_start_us, a.exposure_end_us, a.gain, a.sequence) == (
            b.exposure_start_us,
            b.exposure_end_us,
            b.gain,
            b.sequence,
        )
    elif isinstance(a, (ImuBatch, TriggerBatch)):
        assert np.array_equal(
            a.samples if isinstance(a, ImuBatch) else a.triggers, b.samples if isinstance(b, ImuBatch) else b.triggers
        )
    else:
        assert a == b


def test_round_trip_every_packet_type(tmp_path):
    ev, fr, packets = _stream()
    imu = np.zeros(3, IMU_DTYPE)
    imu["t"] = [10, 20, 30]
    imu["az"] = 1.0
    trg = np.array([(15, 1), (25, 2)], TRIGGER_DTYPE)
    packets = [ImuBatch(imu), TriggerBatch(trg)] + packets
    path = tmp_path / "run.necrec"
    with Recorder(path, sensor=SMALL, properties={"scene": "step", "seed": 3}) as rec:
        for p in packets:
            rec.write(p)
        rec.command(CommandRecord(1000, 2500.0, 2.0, 21_000))
        rec.command(CommandRecord(2000, 3000.0, 1.0, None))
        rec.annotate(5000, {"param": "kp", "value": 0.5})
    r = open_recording(path)
    assert r.format == "necviz" and r.sensor == SMALL and r.exposure_source == "stored"
    assert r.properties == {"scene": "step", "seed": 3}
    out = list(r)
    assert len(out) == len(packets)
    for a, b in zip(out, packets, strict=True):
        _same(a, b)
    assert r.warnings == []
    assert r.commands == [CommandRecord(1000, 2500.0, 2.0, 21_000), CommandRecord(2000, 3000.0, 1.0, None)]
    assert r.annotations == [(5000, {"param": "kp", "value": 0.5})]
    r.set_exposure("camera", 1000.0)  # open loop: accepted and ignored
    info = describe(path)
    assert (info.events, info.frames, info.imu_samples, info.triggers, info.commands) == (ev.size, 5, 3, 2, 2)
    assert info.exposure_min_us == info.exposure_max_us == 3000


def test_reads_file_written_from_the_documented_layout(tmp_path):
    """A file built with struct/zlib only (tests/format_writers.py) is read by the reader."""
    img = np.arange(6 * 4, dtype=np.uint8).reshape(4, 6)
    chunks = [
        (2, native_events([5, 6, 9], [1, 2, 3], [0, 1, 2], [1, -1, 1])),
        (3, struct.pack("<qB", 10, 0)),
        (2, native_events([11], [5], [3], [-1])),
        (3, struct.pack("<qB", 20, 1)),
        (4, struct.pack("<qqdqHH", 10, 20, 1.0, 7, 4, 6) + img.tobytes()),
        (7, struct.pack("<qddBq", 3, 10.0, 1.0, 1, 10)),
        (8, struct.pack("<q", 4) + b'{"a": 1}'),
    ]
    path = tmp_path / "x.necrec"
    path.write_bytes(native_bytes((6, 4, "tiny"), {"k": "v"}, chunks))
    r = open_recording(path)
    out = list(r)
    assert [type(p).__name__ for p in out] == ["EventBatch", "ExposureMarker", "EventBatch", "ExposureMarker", "Frame"]
    assert out[0].events["t"].tolist() == [5, 6, 9] and out[0].events["p"].tolist() == [1, -1, 1]
    assert out[1] == ExposureMarker(10, "start") and out[3] == ExposureMarker(20, "end")
    assert np.array_equal(out[4].image, img) and out[4].sequence == 7
    assert r.commands == [CommandRecord(3, 10.0, 1.0, 10)] and r.annotations == [(4, {"a": 1})]
    assert r.sensor == SensorGeometry(6, 4) and r.properties == {"k": "v"}


def test_seek_by_time_keeps_whole_exposures_only(tmp_path):
    ev, fr, packets = _stream(n=30000, frames=5)
    path = tmp_path / "s.necrec"
    with Recorder(path, sensor=SMALL, properties={}) as rec:
        for p in packets:
            rec.write(p)
    lo, hi = 150_000, 330_000
    out = list(open_recording(path, start_us=lo, end_us=hi))
    got = np.concatenate([p.events for p in out if isinstance(p, EventBatch)])
    want = ev[(ev["t"] >= lo) & (ev["t"] < hi)]
    assert np.array_equal(got, want)
    frames = [p for p in out if isinstance(p, Frame)]
    assert [f.exposure_start_us for f in frames] == [
        f.exposure_start_us for f in fr if f.exposure_start_us >= lo and f.exposure_end_us <= hi
    ]
    markers = [p for p in out if isinstance(p, ExposureMarker)]
    assert [m.kind for m in markers] == ["start", "end"] * len(frames)


def _write(path, packets):
    with Recorder(path, sensor=SMALL, properties={}) as rec:
        for p in packets:
            rec.write(p)
    return path.read_bytes()


def test_incomplete_last_chunk_is_a_warning_not_an_error(tmp_path):
    ev, fr, packets = _stream()
    data = _write(tmp_path / "a.necrec", packets)
    cut = len(data) - 9 - 1000  # inside the last events chunk (END chunk is 9 bytes)
    path = tmp_path / "cut.necrec"
    path.write_bytes(data[:cut])
    r = open_recording(path)
    out = list(r)
    got = np.concatenate([p.events for p in out if isinstance(p, EventBatch)])
    assert 0 < got.size < ev.size and np.array_equal(got, ev[: got.size])
    assert len(r.warnings) == 1 and "incomplete chunk at byte" in r.warnings[0]
    assert "writer stopped mid-write" in r.warnings[0]


def test_damaged_middle_chunk_raises_after_the_good_part(tmp_path):
    ev, fr, packets = _stream()
    data = bytearray(_write(tmp_path / "a.necrec", packets))
    at = len(data) // 2
    data[at : at + 64] = os.urandom(64)
    path = tmp_path / "bad.necrec"
    path.write_bytes(bytes(data))
    out = []
    with pytest.raises(RecordingError) as err:
        for p in open_recording(path):
            out.append(p)
    msg = str(err.value)
    assert str(path) in msg and " at byte " in msg and "\n" not in msg
    offset = int(msg.rsplit(" at byte ", 1)[1])
    assert offset <= at < offset + 2_000_000
    got = np.concatenate([p.events for p in out if isinstance(p, EventBatch)])
    assert got.size > 0 and np.array_equal(got, ev[: got.size])


@pytest.mark.parametrize(
    "content,expect",
    [
        (b"", "empty file (0 bytes)"),
        (b"NECVIZ-REX\x00\x01" + b"\x00" * 40, "unknown recording format"),
        (b"NECVIZ-REC\x00\x01\x01\x50", "missing or incomplete header chunk at byte 12"),
    ],
)
def test_bad_files(tmp_path, content, expect):
    path = tmp_path / "f.bin"
    path.write_bytes(content)
    with pytest.raises(RecordingError) as err:
        open_recording(path)
    assert expect in str(err.value) and str(path) in str(err.value)


def test_wrong_magic_with_native_extension(tmp_path):
    path = tmp_path / "f.necrec"
    path.write_bytes(b"garbage garbage garbage")
    with pytest.raises(RecordingError, match=r"wrong magic .* at byte 0"):
        open_recording(path)


WRITER = r"""
import sys, time
import numpy as np
from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.sensor import DAVIS346
from necviz.drivers.recordings import Recorder
rec = Recorder(sys.argv[1], sensor=DAVIS346, properties={"run": "crash"})
img = np.full((260, 346), 7, np.uint8)
i = 0
while True:
    ev = np.zeros(997, EVENT_DTYPE)
    ev["t"] = i * 1000 + np.arange(997)
    ev["x"] = i % 346
    ev["p"] = 1
    if i % 20 == 5:
        rec.write(ExposureMarker(i * 1000, "start"))
    rec.write(EventBatch(ev))
    if i % 20 == 6:
        rec.write(ExposureMarker(i * 1000 + 997, "end"))
        rec.write(Frame(img, (i - 1) * 1000, i * 1000 + 997, 1.0, i // 20))
    if i == 100:
        print("ready", flush=True)
    i += 1
    time.sleep(0.0005)
"""


def test_writer_killed_mid_stream_leaves_a_readable_file(tmp_path):
    path = tmp_path / "crash.necrec"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE)
    try:
        assert proc.stdout.readline().strip() == b"ready"
        time.sleep(0.6)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    r = open_recording(path)
    assert r.properties == {"run": "crash"}
    out = list(r)
    assert any("incomplete chunk" in w or "no end chunk" in w for w in r.warnings), r.warnings
    ev = [p.events for p in out if isinstance(p, EventBatch)]
    assert len(ev) > 100
    # every complete chunk, in order, none missing
    assert [int(e["t"][0]) for e in ev] == [1000 * k for k in range(len(ev))]
    t = np.concatenate([e["t"] for e in ev])
    assert np.all(np.diff(t) >= 0)
    kinds = [
        ("S" if p.kind == "start" else "E") if isinstance(p, ExposureMarker) else "F"
        for p in out
        if isinstance(p, (ExposureMarker, Frame))
    ]
    assert "".join(kinds).startswith("SEF" * (len(ev) // 20 - 1))
    size = path.stat().st_size
    if any("incomplete chunk" in w for w in r.warnings):
        at = int(r.warnings[0].split("at byte ")[1].split()[0])
        assert 0 < size - at < 100_000


def test_flush_reaches_the_os_within_a_quarter_second(tmp_path):
    path = tmp_path / "f.necrec"
    rec = Recorder(path, sensor=SMALL, properties={})
    try:
        ev = np.zeros(10, EVENT_DTYPE)
        rec.write(EventBatch(ev))
        time.sleep(0.4)  # no further writes: the background flusher must hand the chunk over
        assert sum(len(p) for p in open_recording(path) if isinstance(p, EventBatch)) == 10
    finally:
        rec.close()
    rec.close()  # idempotent
    assert open_recording(path).warnings == []


def test_recorder_refuses_what_is_not_a_packet_and_writes_nothing_for_it(tmp_path):
    path = tmp_path / "r.necrec"
    ev = np.zeros(3, EVENT_DTYPE)
    ev["t"] = [1, 2, 3]
    with Recorder(path, sensor=SMALL, properties={}) as rec:
        with pytest.raises(RecordingError, match="cannot record a ndarray packet"):
            rec.write(ev)  # a bare array is not a packet (events travel as EventBatch)
        with pytest.raises(RecordingError, match="expected an EVENT_DTYPE event batch"):
            rec.write(EventBatch(np.zeros(3, np.int64)))
        rec.write(EventBatch(ev))
    out = list(open_recording(path))
    assert len(out) == 1 and np.array_equal(out[0].events, ev)
