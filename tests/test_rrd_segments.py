"""A ``--save`` file written in segments (bounded memory over hours) is one whole file when the run ends."""

from __future__ import annotations

import subprocess

import pytest
from rerun.chunk import RrdReader
from rrd_read import Rrd

import necviz.dashboard.rrd_file as rrd_file
from necviz.commands.cli import main
from necviz.dashboard.viewer import _rerun_binary
from necviz.outputs import OutputError

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

DEMO = ["demo", "--duration", "0.6", "--controllers", "nec,fixed", "--no-prompt"]


def _segments_written(monkeypatch) -> list:
    made = []
    original = rrd_file.SegmentedFile.next

    def spy(self):
        made.append(self.segments[-1])
        return original(self)

    monkeypatch.setattr(rrd_file.SegmentedFile, "next", spy)
    return made


def test_segments_are_joined_into_the_one_file_with_its_footer(tmp_path, monkeypatch):
    whole, joined = tmp_path / "whole.rrd", tmp_path / "joined.rrd"
    assert main([*DEMO, "--save", str(whole)]) == 0
    made = _segments_written(monkeypatch)
    monkeypatch.setattr(rrd_file, "SEGMENT_S", 0.05)  # a new segment at every send of the sink's worker
    assert main([*DEMO, "--save", str(joined)]) == 0
    assert len(made) >= 3  # the run was written in several segments ...
    assert sorted(p.name for p in tmp_path.iterdir()) == ["joined.rrd", "whole.rrd"]  # ... and is one file now
    RrdReader(str(joined)).store()  # with its footer: indexable
    assert RrdReader(str(joined)).blueprints() and RrdReader(str(whole)).blueprints()  # the layout joined in
    out = subprocess.run([*_rerun_binary(), "rrd", "verify", str(joined)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    a, b = Rrd(whole), Rrd(joined)
    assert dict(b.rows) == dict(a.rows)  # every entity holds what the unsegmented run holds
    assert b.property("run", "layout") == a.property("run", "layout")


def test_a_failed_join_keeps_the_segments_and_says_where(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(rrd_file, "SEGMENT_S", 0.05)

    def broken(files, out):
        raise OutputError("cannot join (disk full)")

    monkeypatch.setattr(rrd_file, "join_segments", broken)
    save = tmp_path / "run.rrd"
    assert main([*DEMO, "--save", str(save)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot join" in err[0]
    assert not save.exists() and not rrd_file.parts_folder(save).exists()  # a demo can be run again: nothing kept


def test_a_long_live_save_is_told_its_size_and_the_bounded_ways(tmp_path):
    from necviz.dashboard.rrd_file import size_warning

    assert size_warning(tmp_path / "x.rrd", 60.0, None) is None  # a short run: nothing to say
    note = size_warning(tmp_path / "x.rrd", None, None)
    assert "GB an hour of live session" in note and "free on its disk" in note
    assert "--image-rate 2" in note and "--clips DIR" in note
    assert "--image-rate" not in size_warning(tmp_path / "x.rrd", 7200.0, 2.0).split("session")[1].split(";")[0]


def test_image_rate_thins_the_images_by_sensor_time_and_keeps_every_series(tmp_path):
    full, light = tmp_path / "full.rrd", tmp_path / "light.rrd"
    argv = ["live", "--device", "emulated", "--scenario", "static_lab", "--duration", "1", "--no-prompt"]
    assert main([*argv, "--save", str(full)]) == 0
    assert main([*argv, "--image-rate", "4", "--save", str(light)]) == 0
    a, b = Rrd(full), Rrd(light)
    assert a.rows["camera/frame"] >= 40  # 50 fps
    assert 3 <= b.rows["camera/frame"] <= 5  # 4 a second of sensor time (+ the first)
    assert b.rows["events"] <= 5 < a.rows["events"]
    assert b.rows["camera/exposure/applied"] == a.rows["camera/exposure/applied"]  # the series stay whole
    assert light.stat().st_size < full.stat().st_size / 3
