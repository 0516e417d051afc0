"""A full disk during any write ends in one line (exit 2) and leaves nothing partial behind.

The disk is a small tmpfs mounted for the test (the tests run as root in CI); where mounting is not
allowed the tests are skipped with the reason.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.sensor import SensorGeometry
from necviz.drivers.recordings.native import Recorder

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out


@pytest.fixture
def small_disk(tmp_path):
    """A folder on a 1 MB tmpfs (unmounted afterwards, whatever happens)."""
    folder = tmp_path / "disk"
    folder.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(folder)], capture_output=True)
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here (needs root): {proc.stderr.decode().strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """A 6 MB native recording: events and frames that do not compress to 1 MB."""
    rng = np.random.default_rng(0)
    path = tmp_path_factory.mktemp("src") / "src.necrec"
    with Recorder(path, sensor=SensorGeometry(346, 260, "DAVIS346"), compression="none") as rec:
        for k in range(20):
            ev = np.zeros(20_000, EVENT_DTYPE)
            ev["t"] = k * 10_000 + np.sort(rng.integers(0, 10_000, ev.size))
            ev["x"], ev["y"], ev["p"] = rng.integers(0, 346, ev.size), rng.integers(0, 260, ev.size), 1
            rec.write(EventBatch(ev))
            s = k * 10_000 + 9_000
            rec.write(ExposureMarker(s, "start"))
            rec.write(ExposureMarker(s + 500, "end"))
            rec.write(Frame(rng.integers(0, 256, (260, 346), dtype=np.uint8), s, s + 500, 1.0, k))
    return path


def _necviz(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "necviz", *map(str, args)], capture_output=True, text=True, cwd=cwd)


@pytest.mark.parametrize("suffix", [".aedat4", ".h5", ".npz", ".necrec"])
def test_export_to_a_full_disk_is_one_line_and_leaves_nothing(small_disk, recording, suffix):
    out = small_disk / f"out{suffix}"
    proc = _necviz("export", recording, out)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "No space left on device" in lines[0] and str(out) in lines[0], proc.stderr
    assert ".partial" not in lines[0]  # the file the user named, not the temporary one
    assert os.listdir(small_disk) == []


def test_export_replacing_a_file_on_a_full_disk_keeps_the_old_one(small_disk, recording):
    out = small_disk / "out.npz"
    out.write_bytes(b"old")
    proc = _necviz("export", recording, out, "--force")
    assert proc.returncode == 2 and "unchanged" in proc.stderr
    assert out.read_bytes() == b"old" and os.listdir(small_disk) == ["out.npz"]


def _one_line_exit_2(proc, *words):
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("necviz: error:"), proc.stderr
    for w in words:
        assert w in lines[0], lines[0]
    assert ".partial" not in lines[0] and "Traceback" not in proc.stderr
    return lines[0]


DEMO = ["demo", "--duration", "1.0", "--controllers", "nec,fixed", "--no-prompt"]


@pytest.fixture
def no_reserve(monkeypatch):
    """Let the writes reach the full disk (the run's free-space guard would stop it first)."""
    monkeypatch.setenv("NECVIZ_DISK_RESERVE_MB", "0")


def test_record_on_a_full_disk(small_disk, tmp_path, no_reserve):
    proc = _necviz(*DEMO, "--record", small_disk / "r.necrec", "--save", tmp_path / "x.rrd", cwd=tmp_path)
    _one_line_exit_2(proc, "No space left on device")
    assert os.listdir(small_disk) == [] and not (tmp_path / "x.rrd").exists()


def test_save_on_a_full_disk(small_disk, tmp_path, no_reserve):
    proc = _necviz(*DEMO, "--save", small_disk / "x.rrd", cwd=tmp_path)
    _one_line_exit_2(proc, "x.rrd")
    assert os.listdir(small_disk) == []


def test_a_clip_on_a_full_disk_stops_the_run_and_leaves_no_part_of_it(small_disk, tmp_path, no_reserve):
    args = ["--clips", small_disk, "--clip-before", "0.3", "--clip-after", "0.2", "--save", tmp_path / "x.rrd"]
    proc = _necviz(*DEMO, *args, cwd=tmp_path)
    _one_line_exit_2(proc, "--clips", "No space left on device")
    assert os.listdir(small_disk) == []


def test_a_video_on_a_full_disk(small_disk, tmp_path, no_reserve):
    pytest.importorskip("av", reason="PyAV is not installed (pip install 'necviz[video]')")
    filler = small_disk / "filler"
    filler.write_bytes(bytes(os.statvfs(small_disk).f_bavail * os.statvfs(small_disk).f_frsize - 60_000))
    proc = _necviz(*DEMO, "--video", small_disk / "v.mp4", "--save", tmp_path / "x.rrd", cwd=tmp_path)
    _one_line_exit_2(proc, "v.mp4", "No space left on device")
    assert os.listdir(small_disk) == ["filler"]
