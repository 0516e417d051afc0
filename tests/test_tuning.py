"""Live tuning: declared parameters, commands applied between packets and logged, bad values refused."""

from __future__ import annotations

import io
import math
import os
import threading
import time

import pytest
import rerun as rr
from hypothesis import given, settings
from hypothesis import strategies as st
from rrd_read import Rrd
from test_pipeline import SENSOR, ListSource, nec_lane, stream

from necviz import schema as S
from necviz.core.control import CONTROLLERS, CameraLimits, NECController, make_controller
from necviz.core.errors import ParameterError
from necviz.dashboard.sink import RerunSink, SinkOptions
from necviz.dashboard.tuning import TuningConsole, TuningFile, execute, parse
from necviz.drivers.recordings import Recorder, open_recording
from necviz.pipeline import Lane, Pipeline, RecorderObserver

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out


class TwoCameras(ListSource):
    cameras = ("nec", "navid")

    def packets(self):
        return iter(())


def apply(pipe, line):
    """Submit a typed line and apply it as the streaming thread would between two packets."""
    cmd = parse(line)
    if cmd.kind in ("help", "status"):
        return execute(pipe, cmd)
    fut = pipe.tune(cmd.key, cmd.value, cmd.lane) if cmd.kind == "set" else pipe.drive(cmd.key, cmd.lane)
    pipe._apply_changes()
    return fut.result(0)


def two_lane_pipe():
    nav = Lane("navid", make_controller("navid", sensor=SENSOR, limits=nec_lane().controller.limits))
    return Pipeline(TwoCameras([]), [nec_lane(name="nec"), nav])


def test_goal_dead_band_and_thresholds_change_the_controller():
    pipe = two_lane_pipe()
    nec = pipe.lanes["nec"].controller
    crf = nec.estimator.crf
    apply(pipe, "goal = 100")
    assert nec.goal_log_exposure == pytest.approx(float(crf.log_exposure(100.0)))
    assert nec.get_param("goal") == pytest.approx(100.0, abs=1e-6)
    apply(pipe, "set nec.dead_band 0.05")
    assert nec.options.dead_band == 0.05
    msg = apply(pipe, "c = 0.3")  # both lanes have an estimator (navid's is passive)
    assert "nec" in msg and "navid" in msg
    for lane in pipe.lanes.values():
        assert lane.estimator.params.c_on == lane.estimator.params.c_off == 0.3
    apply(pipe, "navid.exposure_max = 4000")
    assert pipe.lanes["navid"].controller.limits.exposure_max_us == 4000
    assert pipe.lanes["nec"].controller.limits.exposure_max_us == 8000
    apply(pipe, "target_msv = 3")  # only navid has it: applied there
    assert pipe.lanes["navid"].controller.options.target_msv == 3.0
    assert "goal=100" in apply(pipe, "status") and "target_msv=3" in apply(pipe, "status")


@pytest.mark.parametrize(
    "line, fragment",
    [
        ("goal = 300", "goal = 300 is out of range"),
        ("goal = 252", "valid range"),
        ("full_band = 0.01", "dead_band < full_band"),
        ("exposure_min = -5", "exposure_min"),
        ("exposure_min = 9000", r"exposure_max_us \(8000"),
        ("c = 9", "c = 9 is out of range"),
        ("nope.goal = 100", "no lane"),
        ("navid.goal = 100", "no lane has a parameter 'goal'"),
        ("drive navid", "every controller drives its own camera"),
    ],
)
def test_bad_values_are_refused_with_a_reason_and_change_nothing(line, fragment):
    pipe = two_lane_pipe()
    before = {n: (ln.controller.params(), ln.controller.limits, ln.estimator.params) for n, ln in pipe.lanes.items()}
    with pytest.raises(ParameterError, match=fragment):
        apply(pipe, line)
    after = {n: (ln.controller.params(), ln.controller.limits, ln.estimator.params) for n, ln in pipe.lanes.items()}
    assert after == before


@pytest.mark.parametrize("line", ["goal 1x0", "goal = nan", "drive nobody", "hello world", "= 3"])
def test_unreadable_lines(line):
    with pytest.raises(ParameterError):
        parse(line)


def test_every_controller_declares_its_tunables_with_unit_and_meaning():
    for name in CONTROLLERS:
        ctrl = make_controller(name, sensor=SENSOR, limits=CameraLimits(10, 8_000, 4.0))
        tun = ctrl.tunables()
        assert {"exposure_min", "exposure_max", "gain_max"} <= set(tun)
        for t in tun.values():
            assert t.unit and len(t.doc) > 10
        for k, v in ctrl.params().items():  # the current value is accepted as it is
            assert ctrl.check_param(k, v) == pytest.approx(v)


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(sorted(CONTROLLERS)), st.data())
def test_a_value_inside_a_declared_range_is_set_and_read_back(name, data):
    ctrl = make_controller(name, sensor=SENSOR, limits=CameraLimits(10, 8_000, 4.0))
    key, t = data.draw(st.sampled_from(sorted(ctrl.params().items(), key=str))) if ctrl.params() else (None, None)
    if key is None:
        return
    spec = ctrl.tunables()[key]
    lo = spec.lo if spec.lo is not None else 0.0
    hi = spec.hi if spec.hi is not None else lo + 100.0
    if key == "goal":  # further bounded by the camera response's valid range
        lo, hi = 10.0, 249.0
    v = data.draw(st.floats(lo, hi, exclude_min=spec.lo_open, exclude_max=spec.hi_open))
    try:
        ctrl.set_param(key, v)
    except ParameterError as e:  # only a rule between parameters (or the camera limits) may refuse it
        assert "<" in str(e) or "limits" in str(e) or "gain_max" in str(e)
        return
    assert ctrl.get_param(key) == pytest.approx(v, rel=1e-9, abs=1e-9)


def test_drive_is_a_pipeline_method_and_keeps_the_anchored_estimator():
    pipe = Pipeline(ListSource(stream(n_frames=3)), [nec_lane()])
    pipe.run()
    lane = pipe.lanes["camera"]
    est = lane.estimator
    assert est.ready
    apply(pipe, "drive navid")
    assert lane.controller.name == "navid" and lane.passive is est
    apply(pipe, "drive nec")
    assert isinstance(lane.controller, NECController) and lane.controller.estimator is est and lane.passive is None


def test_changes_are_applied_between_packets_and_logged(tmp_path):
    """A change made while streaming lands in the .rrd (tuning entity) and the native recording."""
    rec = rr.RecordingStream("necviz-test")
    rec.save(str(tmp_path / "t.rrd"))
    sink = RerunSink(rec, ["camera"], SENSOR.height, SENSOR.width, SinkOptions(lossless=True))
    recorder = Recorder(tmp_path / "t.necrec", sensor=SENSOR, properties={})
    pipe = Pipeline(
        ListSource(stream(n_frames=6)), [nec_lane()], observers=[sink, RecorderObserver(recorder, "camera")]
    )
    ok, bad = pipe.tune("goal", 90.0), pipe.tune("goal", 999.0)
    pipe.run().finish()
    rr.disconnect(rec)
    assert ok.result(0).startswith("goal = 90") and isinstance(bad.exception(0), ParameterError)
    texts = Rrd(tmp_path / "t.rrd").texts(S.TUNING)
    assert any("goal = 90" in t for t in texts) and any("rejected" in t for t in texts)
    notes = open_recording(tmp_path / "t.necrec").annotations
    assert [n for _, n in notes] == [{"tuning": {"key": "goal", "value": 90.0, "lanes": ["camera"]}}]
    assert pipe.tune("goal", 80.0).result(0).startswith("goal = 80")  # after the run: applied at once


def test_console_without_a_terminal_reads_lines_and_reports_errors():
    pipe = Pipeline(ListSource([]), [nec_lane()])
    out = io.StringIO()
    console = TuningConsole(pipe, io.StringIO("dead_band = 0.2\n# comment\nnonsense\n"), out=out, interactive=False)
    runner = threading.Thread(target=lambda: [time.sleep(0.05) or pipe._apply_changes() for _ in range(40)])
    runner.start()
    console.start()
    console._thread.join(5)
    runner.join()
    assert pipe.lanes["camera"].controller.options.dead_band == 0.2
    text = out.getvalue()
    assert "dead_band = 0.2 on camera" in text and "error: cannot read 'nonsense'" in text


def test_the_prompt_keeps_input_apart_completes_and_remembers():
    """The prompt_toolkit console on a pseudo-terminal: a typed line is applied; Tab completes keys and names."""
    from prompt_toolkit.document import Document
    from prompt_toolkit.input import create_pipe_input
    from prompt_toolkit.output import DummyOutput

    pipe = Pipeline(ListSource([]), [nec_lane()])
    with create_pipe_input() as inp:
        console = TuningConsole(pipe, status=lambda: "demo: 1.00 s", pt_input=inp, pt_output=DummyOutput())
        assert console.interactive
        words = lambda text: {c.text for c in console.completer().get_completions(Document(text), None)}  # noqa: E731
        assert "goal" in words("go") and "dead_band" in words("dead")
        assert "navid" in words("drive na") and "status" in words("sta")
        console.start()
        inp.send_text("goal = 95\n")
        deadline = time.time() + 5
        while time.time() < deadline and pipe.lanes["camera"].controller.get_param("goal") != pytest.approx(95):
            pipe._apply_changes()
            time.sleep(0.02)
        assert pipe.lanes["camera"].controller.get_param("goal") == pytest.approx(95)
        history = list(console._session.history.get_strings())
        console.close()
    assert history == ["goal = 95"]


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
    ctrl = pipe.lanes["camera"].controller
    assert ctrl.options.dead_band == 0.3 and math.isclose(ctrl.get_param("goal"), 80.0, abs_tol=1e-6)
    with pytest.raises(ParameterError, match="not a file"):
        TuningFile(pipe, tmp_path / "missing.txt")
