"""Live tuning: commands parse, apply between packets, are logged, and bad values are refused."""

from __future__ import annotations

import io
import math
import os
import time

import pytest
import rerun as rr

from necviz import schema as S
from necviz.core.control import NECController, make_controller
from necviz.core.errors import ParameterError
from necviz.drivers.replay import Recorder, open_recording
from necviz.pipeline import Lane, Pipeline
from necviz.sink import RerunSink
from necviz.tuning import TuningConsole, TuningFile, parse, status
from rrd_read import Rrd
from test_pipeline import SENSOR, ListSource, nec_lane, stream


def apply(pipe, line):
    msg, data = parse(line)(pipe)
    return msg, data


def two_lane_pipe():
    class Rig(ListSource):  # the multi-camera shape: packets() and cams
        cams = {}

        def packets(self):
            return iter(())

    nav = Lane.build("navid", make_controller("navid", sensor=SENSOR, limits=nec_lane().controller.limits), SENSOR)
    return Pipeline(Rig([]), [nec_lane(name="nec"), nav])


def test_goal_dead_band_and_thresholds_change_the_controller():
    pipe = two_lane_pipe()
    nec = pipe.lanes["nec"].controller
    crf = nec.estimator.crf
    apply(pipe, "goal = 100")
    assert nec.goal_log_exposure == pytest.approx(float(crf.log_exposure(100.0)))
    assert float(crf.intensity(nec.goal_log_exposure)) == pytest.approx(100.0, abs=0.5)
    apply(pipe, "set nec.dead_band 0.05")
    assert nec.dead_band == 0.05
    msg, data = apply(pipe, "c = 0.3")  # both lanes have an estimator (navid's is passive)
    assert "nec" in msg and "navid" in msg and data["tuning"]["key"] == "c"
    for lane in pipe.lanes.values():
        assert lane.estimator.params.c_on == lane.estimator.params.c_off == 0.3
    apply(pipe, "navid.exposure_max = 4000")
    assert pipe.lanes["navid"].controller.limits.exposure_max_us == 4000
    assert pipe.lanes["nec"].controller.limits.exposure_max_us == 8000
    assert "goal=100 DN" in status(pipe)


@pytest.mark.parametrize("line, fragment", [
    ("goal = 300", "valid range"),
    ("full_band = 0.01", "dead_band < full_band"),
    ("exposure_min = -5", "exposure_min_us"),
    ("c = 9", "contrast threshold"),
    ("nope.goal = 100", "no lane"),
    ("navid.goal = 100", "NEC parameter"),
])
def test_bad_values_are_refused_with_a_reason(line, fragment):
    pipe = two_lane_pipe()
    with pytest.raises(ParameterError, match=fragment):
        apply(pipe, line)


@pytest.mark.parametrize("line", ["goal 1x0", "speed = 3", "drive nobody", "hello world"])
def test_unreadable_lines(line):
    with pytest.raises(ParameterError):
        parse(line)


def test_drive_switches_the_controller_only_where_a_factory_exists():
    pipe = Pipeline(ListSource([]), [nec_lane()])
    with pytest.raises(ParameterError, match="every controller drives"):
        apply(pipe, "drive navid")
    pipe.controller_factory = lambda name, old: make_controller(name, sensor=SENSOR, limits=old.limits,
                                                                exposure_us=old.exposure_us)
    apply(pipe, "drive navid")
    lane = pipe.lanes["camera"]
    assert lane.controller.name == "navid" and lane.passive_estimator
    apply(pipe, "drive nec")
    assert isinstance(lane.controller, NECController) and not lane.passive_estimator


def test_console_changes_are_applied_between_packets_and_logged(tmp_path):
    """A change typed while streaming lands in the .rrd (tuning entity) and the native recording."""
    rec = rr.RecordingStream("necviz-test")
    rec.save(str(tmp_path / "t.rrd"))
    sink = RerunSink(rec, ["camera"], SENSOR.height, SENSOR.width, lossless=True)
    recorder = Recorder(tmp_path / "t.necrec", sensor=SENSOR, properties={})
    replies = []
    pipe = Pipeline(ListSource(stream(n_frames=6)), [nec_lane()], sink, recorder)
    change = parse("goal = 90", reply=replies.append)
    pipe.submit(change)
    pipe.submit(parse("goal = 999", reply=replies.append))
    pipe.run().finish()
    rr.disconnect(rec)
    assert replies[0].startswith("goal = 90") and replies[1].startswith("rejected:")
    texts = Rrd(tmp_path / "t.rrd").texts(S.TUNING)
    assert any("goal = 90" in t for t in texts) and any("rejected" in t for t in texts)
    notes = open_recording(tmp_path / "t.necrec").annotations
    assert [n for _, n in notes] == [{"tuning": {"key": "goal", "value": 90.0, "lanes": ["camera"]}}]


def test_console_reads_lines_and_reports_errors():
    pipe = Pipeline(ListSource([]), [nec_lane()])
    out = io.StringIO()
    console = TuningConsole(pipe, io.StringIO("dead_band = 0.2\n# comment\nnonsense\n"), out=out).start()
    console._thread.join(5)
    assert len(pipe._pending) == 1 and "error" in out.getvalue()


def test_tune_file_applies_only_changed_lines(tmp_path):
    f = tmp_path / "tune.txt"
    f.write_text("goal = 80\ndead_band = 0.2\n")
    pipe = Pipeline(ListSource([]), [nec_lane()])
    tf = TuningFile(pipe, f, out=io.StringIO())
    assert tf.check() == 2
    assert tf.check() == 0  # unchanged file
    f.write_text("goal = 80\ndead_band = 0.3\n")
    os.utime(f, ns=(time.time_ns(), time.time_ns() + 1_000_000))
    assert tf.check() == 1
    pipe._apply_changes()
    assert pipe.lanes["camera"].controller.dead_band == 0.3
    assert math.isclose(float(pipe.lanes["camera"].controller.estimator.crf.intensity(
        pipe.lanes["camera"].controller.goal_log_exposure)), 80.0, abs_tol=0.5)
    with pytest.raises(ParameterError, match="not a file"):
        TuningFile(pipe, tmp_path / "missing.txt")
