"""``necviz calibrate --bias-setting``: a fit per DVS bias setting (necviz/calibration/bias_settings.py).

Truths used: the simulated pixel's thresholds at each bias setting (the simulator's own, after the biases a
``--dvs-at`` change writes), and the times a recorded change showed in the stream (the pipeline's ``ptedi`` note).
"""

import json

import numpy as np
import pytest

from necviz.calibration.bias_settings import BiasTimeline, SplitCollector, parse_change, parse_setting
from necviz.core.errors import ParameterError
from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.sensor import SensorGeometry

SMALL = SensorGeometry(48, 36)


def test_the_timeline_of_a_recording_takes_each_change_where_it_showed():
    """A change set before the stream (noted at the first packet, P-TEDI took it at once), two written mid-run
    together (c_on, then c_off) whose ``ptedi`` note says when they showed (one setting), one that moved no threshold
    (no ``ptedi`` note: from when it was written), and a return to the first setting (the same setting number)."""
    low = {"c_on": 0.15, "c_off": 0.15, "refractory_us": 100.0, "bandwidth_hz": 300.0}
    half = {**low, "c_on": 0.4}
    high = {**low, "c_on": 0.4, "c_off": 0.4}
    slow = {**high, "refractory_us": 400.0}
    moved = {"ratio": {"c_on": 1.5, "c_off": 1.6}, "ptedi": {"camera": {"c_on": 0.4, "c_off": 0.4}}}
    notes = [
        (10, {"dvs": {"key": "c_on", **low}, "ptedi": {"camera": {"c_on": 0.15, "c_off": 0.15}}}),
        (1_000, {"dvs": {"key": "c_on", **half, **moved}}),
        (1_000, {"dvs": {"key": "c_off", **high, **moved}}),
        (1_500, {"ptedi": {"camera": {"c_on": 0.4, "c_off": 0.4, "from_us": 1_200}}, "ratio": {}}),
        (2_000, {"dvs": {"key": "refractory_us", **slow}}),
        (3_000, {"dvs": {"key": "c_on", **low, **moved}}),
        (3_100, {"ptedi": {"camera": {"c_on": 0.15, "c_off": 0.15, "from_us": 3_050}}}),
        (3_200, "not a note"),
    ]
    tl = BiasTimeline.from_annotations(notes)
    assert tl.changes == [(10, 1), (1_200, 2), (2_000, 3), (3_050, 1)]
    assert tl.settings[0] is None and tl.settings[1]["c_on"] == 0.15 and tl.settings[3]["refractory_us"] == 400.0
    assert tl.settings[2]["c_off"] == 0.4 and len(tl.settings) == 4  # c_on and c_off written together: one setting
    assert [tl.at(t) for t in (0, 10, 1_199, 1_200, 2_500, 9_999)] == [0, 1, 1, 2, 3, 1]
    assert BiasTimeline.from_annotations([]).changes == []  # no change: everything is setting 0


def _events(t):
    ev = np.zeros(len(t), dtype=EVENT_DTYPE)
    ev["t"] = t
    return EventBatch(ev)


def _frame(start, end, seq):
    return Frame(np.zeros((4, 4), np.uint8), start, end, 1.0, seq)


def test_the_split_routes_events_and_frames_and_never_pairs_across_a_change():
    """Events are cut at the change; a frame whose exposure spans it is dropped; each stretch starts its setting's
    collector over (``begin``), also when the stream returns to a setting."""

    class Fake:
        def __init__(self):
            self.log = []
            self.frames = 0

        def begin(self, source):
            self.log.append(("begin", source))

        def feed(self, packet):
            match packet:
                case EventBatch(events=ev):
                    self.log.append(("events", ev["t"].tolist()))
                case Frame():
                    self.log.append(("frame", packet.sequence))
                case ExposureMarker():
                    self.log.append(("marker", packet.t_us))

        def finish(self):
            self.log.append(("finish",))

    tl = BiasTimeline()
    split = SplitCollector(tl, Fake)
    split.begin("run")
    tl.add(100, {"c_on": 0.15, "c_off": 0.15})
    tl.add(300, {"c_on": 0.26, "c_off": 0.24, "refractory_us": 1.0})
    tl.add(500, {"c_on": 0.15, "c_off": 0.15})  # back to setting 1
    split.feed(_events([10, 50]))
    split.feed(_frame(20, 60, 1))
    split.feed(_events([99, 100, 150]))
    split.feed(_frame(90, 120, 2))  # spans the change at 100: dropped
    split.feed(_frame(130, 160, 3))
    split.feed(_events([320, 600]))
    split.feed(_frame(610, 620, 4))
    split.finish()
    zero, one, two = split.collectors[0].log, split.collectors[1].log, split.collectors[2].log
    assert zero == [
        ("begin", "run (bias setting 0)"),
        ("events", [10, 50]),
        ("frame", 1),
        ("events", [99]),
        ("finish",),
    ]
    assert one[:3] == [("begin", "run (bias setting 1)"), ("events", [100, 150]), ("frame", 3)]
    assert one[3:] == [("begin", "run (bias setting 1)"), ("events", [600]), ("frame", 4), ("finish",)]
    assert two == [("begin", "run (bias setting 2)"), ("events", [320]), ("finish",)]
    assert split.frames_dropped == 1


def test_setting_and_schedule_arguments():
    assert parse_setting("all") == "all" and parse_setting(" 2 ") == 2
    assert parse_change("3:c_on=0.15") == (3.0, "c_on", "0.15")
    for bad in ("-1", "x", "1.5"):
        with pytest.raises(ParameterError, match="--bias-setting takes"):
            parse_setting(bad)
    for bad, match in [
        ("c_on=0.15", "SECONDS:KEY=VALUE"),
        ("-1:c_on=0.15", "SECONDS:KEY=VALUE"),
        ("3:c_on=-3", "c_on"),
        ("3:ba_filter_us=500", "no raw biases or FPGA filters"),
        ("3:bias.DiffBn=4/39", "no raw biases or FPGA filters"),
    ]:
        with pytest.raises(ParameterError, match=match):
            parse_change(bad)


@pytest.mark.parametrize(
    "argv, match",
    [
        (["--sim", "calibration", "--bias-setting", "x"], "--bias-setting takes"),
        (["--sim", "calibration", "--dvs-at", "3:c_on"], "--dvs takes KEY=VALUE"),
        (["--sim", "calibration", "--dvs-at", "3:nonsense=1"], "nonsense"),
        (["x.necrec", "--dvs-at", "3:c_on=0.15"], "--dvs-at schedules bias changes in simulator runs"),
    ],
)
def test_bad_bias_arguments_give_one_line_errors(tmp_path, monkeypatch, capsys, argv, match):
    from necviz.commands.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["calibrate", *argv, "--out", "p.json"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("necviz: error:") and match in err and "\n" not in err, err
    assert not (tmp_path / "p.json").exists()


def test_a_recorded_change_gives_the_timeline_the_replay_follows(tmp_path):
    """A simulated run whose thresholds change mid-run, recorded: the calibration's timeline puts the change where
    P-TEDI followed it in the live run, and ``--bias-setting 5`` is refused naming the settings the file holds."""
    from dvs_recording import nec_pipeline, record_with_dvs_changes

    from necviz.calibration import calibrate_from_recordings
    from necviz.drivers.recordings import open_recording
    from necviz.drivers.sim.rig import RigOptions, SimRig
    from necviz.drivers.sim.scenes import make_scenario

    sc = make_scenario("static_lab", sensor=SMALL, duration_us=300_000, seed=0, ramp_ms=100.0, change_jitter_ms=0.0)
    rig = SimRig(sc, ["camera"], seed=0, options=RigOptions(threads=False))
    pipe = nec_pipeline(rig, SMALL)
    record_with_dvs_changes(pipe, tmp_path / "t.necrec", SMALL, [("c_on", 0.13)], lambda n, batch: n == 20)
    tl = BiasTimeline.from_annotations(open_recording(tmp_path / "t.necrec").annotations)
    assert tl.changes == [(pipe.dvs.followed_from_us, 1)]
    assert tl.settings[1]["c_on"] == pytest.approx(0.13, rel=0.01)
    with pytest.raises(ParameterError, match=r"--bias-setting 5: the data hold bias settings 0\.\.1"):
        calibrate_from_recordings([tmp_path / "t.necrec"], bias_setting=5)

    from necviz.commands.calibrate import _bias_changes

    assert _bias_changes(tmp_path / "t.necrec", None) == 1  # calibrate without --bias-setting says so before its fit


@pytest.mark.slow  # two 6 s calibration runs and two bootstraps (≈ 30 s)
def test_each_settings_fit_holds_its_true_thresholds(tmp_path, capsys):
    """``--sim calibration --dvs-at 3:c_on=0.15 --dvs-at 3:c_off=0.35 --bias-setting all``: the simulated pixel
    runs at 0.26/0.24 for 3 s, then at 0.15/0.35; each setting's profile is fitted on its own stretch, and its
    thresholds' 95 % intervals hold that setting's true thresholds (and not the other's)."""
    from necviz.commands.cli import main

    out, rep = tmp_path / "p.json", tmp_path / "r.json"
    argv = ["calibrate", "--sim", "calibration", "--seeds", "0..1", "--duration", "6", "--sensor", "48x36"]
    argv += ["--fit", "c", "--min-pixels", "50", "--dvs-at", "3:c_on=0.15", "--dvs-at", "3:c_off=0.35"]
    argv += ["--bias-setting", "all", "--out", str(out), "--json", str(rep)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "bias setting 1 (c_on 0.1503, c_off 0.3501" in text
    fits = json.loads(rep.read_text())["bias_settings"]
    assert [f["bias_setting"] for f in fits] == [0, 1] and all(f["error"] is None for f in fits)
    truths = [f["settings"]["truth"] for f in fits]
    assert truths[0]["c_on"] == 0.26 and truths[1]["c_on"] == pytest.approx(0.15, rel=0.01)
    for f, other in zip(fits, truths[::-1], strict=True):
        intervals = f["calibration"]["fit"]["bootstrap"]["intervals"]
        for name in ("c_on", "c_off"):
            lo, hi = intervals[name]
            assert lo <= f["settings"]["truth"][name] <= hi, (f["bias_setting"], name, lo, hi)
            assert not lo <= other[name] <= hi  # the other setting's threshold is not in it: the split matters
        profile = json.loads((tmp_path / f"p.setting{f['bias_setting']}.json").read_text())
        assert profile["calibration"]["bias_setting"]["index"] == f["bias_setting"]
    assert not out.exists()  # with all, one file per setting


def test_a_recording_across_a_bias_change_gives_each_setting_its_own_thresholds(tmp_path, capsys):
    """NEC on the simulated calibration scene (48x36, 12 s, mismatch 0.01), recorded; at 6 s the thresholds go
    from 0.26 / 0.24 to 0.15 / 0.35 (``c_on`` then ``c_off``, one setting). ``calibrate --bias-setting all`` on the
    ``.necrec``: two profiles, each setting's 95 % intervals holding its own simulated thresholds and not the
    other's; without ``--bias-setting`` the command says the file holds a change."""
    from dvs_recording import nec_pipeline, record_with_dvs_changes

    from necviz.commands.cli import main
    from necviz.drivers.sim.calibration_scene import CalibrationScene
    from necviz.drivers.sim.dvs import DvsParams
    from necviz.drivers.sim.rig import RigOptions, SimRig

    scene = CalibrationScene(sensor=SMALL, duration_us=12_000_000, seed=0)
    rig = SimRig(scene, ["camera"], seed=0, dvs=DvsParams(sigma_threshold=0.01), options=RigOptions(threads=False))
    rec = tmp_path / "t.necrec"
    changes = [("c_on", 0.15), ("c_off", 0.35)]  # one setting: both at the same batch
    record_with_dvs_changes(nec_pipeline(rig, SMALL), rec, SMALL, changes, lambda n, b: int(b["t"][-1]) > 6_000_000)
    truth = [(0.26, 0.24), (rig.dvs_params.c_on, rig.dvs_params.c_off)]  # the simulated pixel's, before and after
    assert truth[1] == pytest.approx((0.15, 0.35), rel=0.01)

    out, rep = tmp_path / "p.json", tmp_path / "r.json"
    argv = ["calibrate", str(rec), "--fit", "c", "--min-pixels", "50", "--bias-setting", "all"]
    assert main([*argv, "--out", str(out), "--json", str(rep)]) == 0
    fits = json.loads(rep.read_text())["bias_settings"]
    assert [f["bias_setting"] for f in fits] == [0, 1] and fits[1]["settings"]["c_off"] == pytest.approx(0.35, rel=0.01)
    for f, own, other in zip(fits, truth, truth[::-1], strict=True):
        intervals = f["calibration"]["fit"]["bootstrap"]["intervals"]
        for k, name in enumerate(("c_on", "c_off")):
            lo, hi = intervals[name]
            assert lo <= own[k] <= hi and not lo <= other[k] <= hi, (f["bias_setting"], name, lo, hi)
        assert (tmp_path / f"p.setting{f['bias_setting']}.json").exists()
    capsys.readouterr()
    assert main(["calibrate", str(rec), "--fit", "c", "--min-pixels", "50", "--out", str(tmp_path / "one.json")]) == 0
    assert "t.necrec holds 1 DVS bias change(s)" in capsys.readouterr().out
