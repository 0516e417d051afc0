"""RPG text, HDF5 (DSEC, MVSEC), ROS1 bags and format detection, on synthetic files."""

import numpy as np
import pytest
from format_writers import write_dsec, write_mvsec, write_ros1_bag, write_rpg_text

from necviz.core.events import EventBatch
from necviz.core.frames import Frame
from necviz.core.imu import ImuBatch
from necviz.drivers.recordings import RecordingError, describe, detect_format, open_recording
from necviz.drivers.recordings.reader import NO_EXPOSURE_FRAMES

W, H = 240, 180


@pytest.fixture(scope="module")
def events():
    rng = np.random.default_rng(7)
    n = 6000
    return (np.sort(rng.integers(0, 600_000, n)), rng.integers(0, W, n), rng.integers(0, H, n), rng.integers(0, 2, n))


def _split(packets):
    ev = [p.events for p in packets if isinstance(p, EventBatch)]
    return np.concatenate(ev), [p for p in packets if isinstance(p, Frame)]


def _check_events(ev, t, x, y, p01):
    assert np.array_equal(ev["t"], t) and np.array_equal(ev["x"], x) and np.array_equal(ev["y"], y)
    assert np.array_equal(ev["p"], np.where(p01 > 0, 1, -1))


def test_rpg_text(tmp_path, events):
    t, x, y, p = events
    rng = np.random.default_rng(8)
    imgs = [(0.1, rng.integers(0, 256, (H, W), dtype=np.uint8)), (0.4, rng.integers(0, 256, (H, W), dtype=np.uint8))]
    folder = write_rpg_text(tmp_path / "rpg", t / 1e6, x, y, p, frames=imgs, imu=[[0.2, 0, 0, 9.80665, 0, 0, np.pi]])
    assert detect_format(folder) == "rpg-text" and detect_format(folder / "events.txt") == "rpg-text"
    r = open_recording(folder)
    ev, frames = _split(list(r))
    _check_events(ev, t, x, y, p)
    assert frames == [] and r.exposure_source == NO_EXPOSURE_FRAMES
    assert any("pass --exposure-us" in w for w in r.warnings)
    r = open_recording(folder, exposure_us=2000)
    packets = list(r)
    ev, frames = _split(packets)
    assert [(f.exposure_start_us, f.exposure_end_us) for f in frames] == [(99_000, 101_000), (399_000, 401_000)]
    assert np.array_equal(frames[0].image, imgs[0][1])
    imu = [q for q in packets if isinstance(q, ImuBatch)][0].samples
    assert imu["az"][0] == pytest.approx(1.0) and imu["gz"][0] == pytest.approx(180.0)
    ev, _ = _split(list(open_recording(folder, start_us=200_000, end_us=300_000)))
    sel = (t >= 200_000) & (t < 300_000)
    _check_events(ev, t[sel], x[sel], y[sel], p[sel])


def test_rpg_text_bad_line(tmp_path, events):
    t, x, y, p = events
    folder = write_rpg_text(tmp_path / "rpg", t / 1e6, x, y, p)
    data = (folder / "events.txt").read_bytes()
    at = data.index(b"\n", len(data) // 2) + 1
    (folder / "events.txt").write_bytes(data[:at] + b"0.5 1 oops 1\n" + data[at:])
    got = []
    with pytest.raises(RecordingError, match=rf"events\.txt.* at byte {at}$"):
        for q in open_recording(folder):
            got.append(q)
    assert sum(len(q) for q in got if isinstance(q, EventBatch)) == data[:at].count(b"\n")


def test_dsec_hdf5(tmp_path, events):
    t, x, y, p = events
    path = write_dsec(tmp_path / "events.h5", t + 10**9, x, y, p, t_offset=10**9, compression="gzip")
    assert detect_format(path) == "hdf5"
    r = open_recording(path)
    assert r.format == "hdf5-dsec" and (r.sensor.width, r.sensor.height) == (W, H)
    ev, _ = _split(list(r))
    _check_events(ev, t + 10**9, x, y, p)
    lo, hi = 10**9 + 250_000, 10**9 + 260_000
    ev, _ = _split(list(open_recording(path, start_us=lo, end_us=hi)))
    sel = (t + 10**9 >= lo) & (t + 10**9 < hi)
    _check_events(ev, t[sel] + 10**9, x[sel], y[sel], p[sel])
    info = describe(path)
    assert info.events == t.size and info.frames == 0 and info.exposure_source == "none (no frames)"


def test_mvsec_hdf5(tmp_path, events):
    t, x, y, p = events
    imgs = np.random.default_rng(9).integers(0, 256, (2, 260, 346), dtype=np.uint8)
    path = write_mvsec(tmp_path / "seq_data.hdf5", t / 1e6, x, y, np.where(p > 0, 1, -1), imgs, [0.1, 0.3])
    r = open_recording(path, exposure_us=1000)
    assert r.format == "hdf5-mvsec" and (r.sensor.width, r.sensor.height) == (346, 260)
    ev, frames = _split(list(r))
    _check_events(ev, t, x, y, p)
    assert [(f.exposure_start_us, f.exposure_end_us) for f in frames] == [(99_500, 100_500), (299_500, 300_500)]
    assert np.array_equal(frames[1].image, imgs[1])


def test_hdf5_unknown_layout_and_truncation(tmp_path, events):
    import h5py

    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("stuff", data=np.arange(3))
    with pytest.raises(RecordingError, match=r"other\.h5: HDF5 file with an unknown layout"):
        open_recording(path)
    t, x, y, p = events
    good = write_dsec(tmp_path / "e.h5", t, x, y, p).read_bytes()
    cut = tmp_path / "cut.h5"
    cut.write_bytes(good[: len(good) // 2])
    with pytest.raises(RecordingError, match=r"cut\.h5"):
        list(open_recording(cut))


def test_ros1_bag(tmp_path, events):
    t, x, y, p = events
    msgs = [(t[i : i + 500], x[i : i + 500], y[i : i + 500], p[i : i + 500]) for i in range(0, t.size, 500)]
    img = np.random.default_rng(10).integers(0, 256, (H, W), dtype=np.uint8)
    path = write_ros1_bag(
        tmp_path / "dvs.bag",
        msgs,
        images=[(100_000, img), (300_000, img)],
        exposures=[(50_000, 1000), (250_000, 3000)],
        width=W,
        height=H,
    )
    assert detect_format(path) == "rosbag1"
    r = open_recording(path)
    assert r.format == "rosbag1" and (r.sensor.width, r.sensor.height) == (W, H)
    ev, frames = _split(list(r))
    _check_events(ev, t, x, y, p)
    assert [(f.exposure_start_us, f.exposure_end_us) for f in frames] == [(99_500, 100_500), (298_500, 301_500)]
    assert r.exposure_source == "stored"
    cut = tmp_path / "cut.bag"
    cut.write_bytes(path.read_bytes()[:200])
    with pytest.raises(RecordingError, match=r"cut\.bag"):
        list(open_recording(cut))


def test_detection_errors(tmp_path):
    unknown = tmp_path / "mystery.bin"
    unknown.write_bytes(b"\x00\x01garbage" * 10)
    with pytest.raises(RecordingError) as err:
        open_recording(unknown)
    msg = str(err.value)
    assert "mystery.bin: unknown recording format" in msg and "AEDAT 4.0" in msg and "HDF5" in msg
    assert "\n" not in msg
    with pytest.raises(RecordingError, match="no such file"):
        open_recording(tmp_path / "nope.aedat4")
    (tmp_path / "emptydir").mkdir()
    with pytest.raises(RecordingError, match="neither a ROS2 bag"):
        open_recording(tmp_path / "emptydir")
