"""Failure diagnosis: one deliberately built case of each cause, each named by the rule that explains it.

The closed-loop cases run the simulator on a small sensor (64 x 48) for a few frames: a scene
function with a lighting step placed against the frame clock (exposures start at 1, 21, 41, … ms;
commands take effect 1 ms after they are issued). The data-only cases (no ground truth: a replayed
camera) build the evidence directly.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from necviz.core.control import CameraLimits
from necviz.core.crf import default_davis346
from necviz.core.diagnosis import CAUSES, Command, Evidence, best_valid_fraction, diagnose
from necviz.core.ground_truth import GroundTruth
from necviz.core.sensor import SensorGeometry
from necviz.drivers.sim.aps import ApsParams
from necviz.drivers.sim.dvs import DvsParams
from necviz.drivers.sim.rig import SimRig
from necviz.drivers.sim.scene import FunctionScene, LightingChange
from necviz.pipeline import Lane, Pipeline
from necviz.runs import build_controller
from necviz.telemetry import Telemetry

SENSOR = SensorGeometry(64, 48)
YY, XX = np.mgrid[0:48, 0:64].astype(np.float32)
TEXTURE = 0.5 * np.sin(XX / 3.0) * np.cos(YY / 4.0) + 0.2 * np.sin((XX + YY) / 7.0)


def step_scene(t_step_us: float, level: float, step: float, ramp_us: float = 0.0, duration_us: int = 100_000):
    """``ln L = level + texture`` stepping up by ``step`` at ``t_step_us`` (linear over ``ramp_us``)."""

    def fn(t_us, sensor):
        a = (
            0.0
            if t_us < t_step_us
            else (1.0 if ramp_us <= 0 or t_us >= t_step_us + ramp_us else (t_us - t_step_us) / ramp_us)
        )
        return level + TEXTURE + np.float32(step * a)

    return FunctionScene(
        fn, SENSOR, duration_us, changes=[LightingChange(int(t_step_us), "step", step)] if step else []
    )


def run(scene, controller: str, exposure_us: float | None = None, dvs: DvsParams | None = None, **params):
    """Run one controller in closed loop on ``scene``; returns its per-frame records (dicts) by sequence."""
    aps = ApsParams()
    rig = SimRig(scene, {"cam": None if exposure_us is None else (exposure_us, 1.0)}, dvs=dvs, aps=aps, seed=1)
    limits = CameraLimits(aps.exposure_min_us, aps.exposure_max_us, aps.gain_max)
    ctrl = build_controller(
        controller, params or None, sensor=SENSOR, limits=limits, exposure_us=rig.cams["cam"].exposure_us
    )
    lanes = [Lane("cam", ctrl)]
    tel = Telemetry(["cam"]).attach(lanes, rig)
    Pipeline(rig, lanes, telemetry=tel).run().finish()
    return {r["sequence"]: r for r in tel["cam"].table.rows()}, tel["cam"]


def test_causes_are_stable_strings_in_rule_order():
    assert CAUSES == (
        "change_during_exposure",
        "command_latency",
        "limit_reached",
        "prediction_undercount",
        "controller_lag",
        "controller",
    )


def test_a_step_inside_an_exposure_is_a_change_during_the_exposure():
    # frame 2 is exposed over [41 ms, ~45 ms] for ln L = 5; the light rises 3 ln (26 dB) at 43 ms
    rows, lane = run(step_scene(43_000, 5.0, 3.0), "fixed")
    f = rows[2]
    assert (f["exposure_start_us"], not rows[1]["saturated"]) == (41_000, True)
    assert f["exposure_start_us"] < 43_000 < f["exposure_end_us"] and f["saturated"]
    assert f["saturation_cause"] == "change_during_exposure"
    assert "during the" in f["saturation_explanation"] and "+3.00 ln" in f["saturation_explanation"]
    assert lane.summary()["saturation_causes"]["change_during_exposure"] == 1


def test_a_step_half_a_millisecond_before_an_exposure_is_command_latency():
    # NEC sees the step in the events at once and commands within a batch (1 ms); the command needs
    # 1 ms to take effect, so frame 2 (starting at 41 ms) still gets the old exposure
    rows, _ = run(step_scene(40_500, 5.0, 3.0), "nec")
    f = rows[2]
    assert f["saturated"] and f["saturation_cause"] == "command_latency"
    assert "0.5 ms before the exposure started" in f["saturation_explanation"]
    assert "commands take effect 1.0 ms after" in f["saturation_explanation"]
    assert not rows[3]["saturated"]  # and NEC's command holds from the next frame on


def test_a_40_db_step_beyond_the_event_rate_ceiling_is_a_prediction_undercount():
    # 9.2 ln (40 dB; 60 dB does not fit in the exposure range) over 2 ms between two exposures, on an
    # ideal sensor with a ceiling of 0.3 Mev/s (the DAVIS346's 12 Mev/s per pixel is 0.1 Mev/s on this
    # 3072-pixel sensor): most of the step's ~110 k events are lost, so P-TEDI's prediction, and NEC's
    # exposure, follow only part of the change
    dvs = DvsParams.ideal(max_event_rate=3e5)
    rows, _ = run(step_scene(37_500, 3.6, 9.2, ramp_us=2_000), "nec", dvs=dvs)
    f = rows[2]
    assert f["exposure_start_us"] == 41_000 and f["saturated"] and f["over_exposed_rate"] > 0.5
    assert f["saturation_cause"] == "prediction_undercount", f["saturation_explanation"]
    assert "P-TEDI predicted a change of" in f["saturation_explanation"]
    # the same step with every event delivered is followed (no saturated frame after it)
    rows_all, _ = run(step_scene(37_500, 3.6, 9.2, ramp_us=2_000), "nec", dvs=DvsParams.ideal())
    assert not rows_all[2]["saturated"]


def test_lost_events_in_the_ground_truth_carry_the_change_the_prediction_missed():
    """An ideal sensor (no refractory period, no noise) loses events only at its ceiling: what the
    lost events carried (simulator count, ground truth) plus what P-TEDI counted is the whole step."""
    dvs = DvsParams.ideal(max_event_rate=3e5)
    scene = step_scene(37_500, 3.6, 9.2, ramp_us=2_000)
    aps = ApsParams()
    rig = SimRig(scene, {"cam": None}, dvs=dvs, aps=aps, seed=1)
    limits = CameraLimits(aps.exposure_min_us, aps.exposure_max_us, aps.gain_max)
    ctrl = build_controller("nec", None, sensor=SENSOR, limits=limits, exposure_us=rig.cams["cam"].exposure_us)
    est = ctrl.estimator
    frames = {}
    for cam, packet in rig.packets():
        cmd = ctrl.feed(packet)
        if cmd is not None:
            rig.set_exposure("cam", cmd.exposure_us, cmd.gain)
        if cam is not None and hasattr(packet, "truth") and packet.sequence in (1, 2):
            frames[packet.sequence] = packet.truth
        if len(frames) == 2:
            break
    before, after = frames[1].lost_at(30_000), frames[2].lost_at(frames[2].lost_t_us[-1])
    assert before == (0, 0) and after[0] > 50_000 and after[1] < 0.01 * after[0]  # a rise: ON events lost
    lost = frames[2].lost_log_change(after[0] - before[0], after[1] - before[1])
    counted = 0.26 * est.event_totals()[0] / SENSOR.num_pixels  # P-TEDI's ON events, c_on 0.26
    assert counted + lost == pytest.approx(9.2, abs=0.1)  # every threshold crossing is one or the other


def test_a_lane_without_events_never_gets_prediction_undercount():
    # the step that NEC under-counts (above): nec-frames saturates on it too, but it never had events to lose
    dvs = DvsParams.ideal(max_event_rate=3e5)
    rows, lane = run(step_scene(37_500, 3.6, 9.2, ramp_us=2_000), "nec-frames", dvs=dvs)
    sat = [r for r in rows.values() if r["saturated"]]
    assert sat and not any(r["saturation_cause"] == "prediction_undercount" for r in sat)
    assert lane._lane.controller.estimator.event_totals() == (0, 0)
    assert lane.summary()["saturation_causes"]["prediction_undercount"] == 0


def test_prediction_undercount_comes_from_events_delivered_not_declared(monkeypatch):
    """A lane that declares events (``uses_events``) but whose estimator received none is a frame-only
    lane for the diagnosis: the step NEC under-counts is not an undercount there."""
    from necviz.core.control.nec import NECFramesController

    monkeypatch.setattr(NECFramesController, "uses_events", True)  # declares events, is fed none
    dvs = DvsParams.ideal(max_event_rate=3e5)
    rows, lane = run(step_scene(37_500, 3.6, 9.2, ramp_us=2_000), "nec-frames", dvs=dvs)
    assert lane._lane.controller.uses_events and lane._lane.controller.estimator.event_totals() == (0, 0)
    sat = [r for r in rows.values() if r["saturated"]]
    assert sat and not any(r["saturation_cause"] == "prediction_undercount" for r in sat)


def test_a_miss_that_lost_events_do_not_explain_is_not_prediction_undercount():
    """The sensor's thresholds are 2.3x P-TEDI's (0.6 against 0.26), no event is lost: P-TEDI
    under-counts the step by more than half, but not because of the bus; the residual says so."""
    dvs = DvsParams.ideal(c_on=0.6, c_off=0.6)
    rows, _ = run(step_scene(37_500, 3.6, 9.2, ramp_us=2_000), "nec", dvs=dvs)
    sat = [r for r in rows.values() if r["saturated"]]
    assert sat, "the mismatched thresholds must leave a frame saturated"
    assert not any(r["saturation_cause"] == "prediction_undercount" for r in sat)
    # frame 1 was exposed across the step; frame 2 at the setting NEC chose from its too few events
    assert [r["sequence"] for r in sat] == [1, 2] and rows[2]["exposure_us"] < 0.01 * rows[1]["exposure_us"]
    assert rows[2]["saturation_cause"] == "controller"
    assert "events lost at the bus ceiling since then carried +0.00 ln" in rows[2]["saturation_explanation"]


def test_a_fixed_exposure_at_its_minimum_in_a_too_bright_scene_is_the_limit():
    # ln L = 16 needs ~0.04 µs; the camera's shortest exposure is 1 µs
    rows, lane = run(step_scene(0, 16.0, 0.0), "fixed", exposure_us=1.0)
    assert len(rows) >= 4 and all(r["saturated"] and r["exposure_us"] == 1 for r in rows.values())
    assert {r["saturation_cause"] for r in rows.values()} == {"limit_reached"}
    assert "at its minimum (1 µs" in rows[1]["saturation_explanation"]
    assert lane.summary()["saturation_causes"] == {**dict.fromkeys(CAUSES, 0), "limit_reached": len(rows)}


def test_an_image_only_controller_one_frame_behind_is_controller_lag():
    # the light rises 3 ln at 30 ms, after frame 1 ([21, ~25] ms) was read out: no frame showing the
    # change exists before frame 2 starts (41 ms), so an image-only controller cannot have reacted
    rows, _ = run(step_scene(30_000, 5.0, 3.0), "navid")
    f = rows[2]
    assert not rows[1]["saturated"] and f["saturated"]
    assert f["saturation_cause"] == "controller_lag"
    assert "11.0 ms before the exposure started" in f["saturation_explanation"]
    assert "its first correcting command came 16.4 ms after the change, once a frame" in f["saturation_explanation"]
    # NEC on the same step sees it in its events and is not saturated at all
    rows_nec, _ = run(step_scene(30_000, 5.0, 3.0), "nec")
    assert not any(r["saturated"] for r in rows_nec.values())
    # NEC with its events withheld waits for the frame like any image-only controller: the same cause
    rows_frames, _ = run(step_scene(30_000, 5.0, 3.0), "nec-frames")
    assert rows_frames[2]["saturated"] and rows_frames[2]["saturation_cause"] == "controller_lag"
    assert not rows_frames[3]["saturated"]  # one jump through the response once the frame shows it


def test_a_controller_that_never_reacts_is_the_controller():
    # the fixed exposure sees frame 2 show the change and still does nothing: frame 3 on is its choice
    rows, _ = run(step_scene(30_000, 5.0, 3.0), "fixed")
    assert rows[2]["saturation_cause"] == "controller_lag"
    assert {rows[k]["saturation_cause"] for k in (3, 4)} == {"controller"}
    assert "no command from the controller" in rows[3]["saturation_explanation"]


def test_unsaturated_frames_carry_no_cause():
    rows, lane = run(step_scene(0, 5.0, 0.0), "nec")
    assert all(
        not r["saturated"] and r["saturation_cause"] == "" and r["saturation_explanation"] == "" for r in rows.values()
    )
    assert sum(lane.summary()["saturation_causes"].values()) == 0


# --- without ground truth (a camera, a file): the evidence the data gives ----------------------
BASE = dict(
    sequence=7,
    start_us=100_000,
    end_us=104_000,
    exposure_us=4_000.0,
    gain=1.0,
    over=0.8,
    under=0.0,
    exposure_min_us=10.0,
    exposure_max_us=30_000.0,
    gain_max=1.0,
    latency_us=1_000.0,
    drives=True,
)


#: the lane's previous frame: exposed over [80, 84] ms at 4 ms
PREVIOUS = ((80_000, 84_000, 4_000.0),)


@pytest.mark.parametrize(
    "extra, cause",
    [
        ({"sees_events": True, "exposure_log_change": 1.2}, "change_during_exposure"),
        (
            {"sees_events": True, "commands": (Command(98_000, 4_000.0, 1.0), Command(99_400, 600.0, 1.0))},
            "command_latency",
        ),
        ({"sees_events": False, "exposure_us": 10.0, "end_us": 100_010}, "limit_reached"),
        (
            {"sees_events": True, "predicted_change": 0.4, "frame_change": 2.5, "lost_change": 1.5},
            "prediction_undercount",
        ),
        ({"sees_events": True, "predicted_change": 0.4, "frame_change": 2.5}, "controller"),  # losses unknown
        ({"sees_events": True, "predicted_change": 0.4, "frame_change": 2.5, "lost_change": 0.5}, "controller"),
        ({"sees_events": False, "predicted_change": 0.4, "frame_change": 2.5, "lost_change": 1.5}, "controller"),
        ({"sees_events": False, "previous_saturated": False, "recent_frames": PREVIOUS}, "controller_lag"),
        ({"sees_events": True, "previous_saturated": False, "recent_frames": PREVIOUS}, "controller_lag"),
        ({"sees_events": False, "previous_saturated": True, "recent_frames": PREVIOUS}, "controller"),
        ({"sees_events": True, "predicted_change": 2.4, "frame_change": 2.5}, "controller"),
    ],
)
def test_data_only_evidence_names_each_cause(extra, cause):
    name, why = diagnose(Evidence(**{**BASE, **extra}))
    assert name == cause and why


def test_data_only_rules_need_what_they_claim():
    # an under-exposed frame: the change and the correction go the other way
    under = {**BASE, "over": 0.0, "under": 0.9}
    assert diagnose(Evidence(**under, sees_events=True, exposure_log_change=1.2))[0] == "controller"
    assert diagnose(Evidence(**under, sees_events=True, exposure_log_change=-1.2))[0] == "change_during_exposure"
    # a late command that would make it worse is not a correction
    late = (Command(99_400, 9_000.0, 1.0),)
    assert diagnose(Evidence(**BASE, sees_events=True, commands=late))[0] == "controller"
    # in open loop (a replay) the lane's commands and prediction did not set the exposure
    replay = {**BASE, "drives": False}
    assert diagnose(Evidence(**replay, sees_events=True, predicted_change=0.0, frame_change=3.0))[0] == "controller"
    name, why = diagnose(Evidence(**replay, sees_events=True))
    assert name == "controller" and "open loop" in why
    # unknown limits are not reached
    assert diagnose(Evidence(**{**BASE, "exposure_min_us": None, "exposure_us": 10.0}))[0] == "controller"
    assert math.isnan(Evidence(**BASE).predicted_change)


def test_controller_lag_is_measured_from_command_timing_not_from_the_controller_type():
    # an image-only controller that did correct between its last look and the deadline (99 ms) is not
    # lagging, whatever its type; one that uses events but waited is
    fix = (Command(90_000, 1_000.0, 1.0),)
    for sees in (False, True):
        ev = Evidence(**BASE, sees_events=sees, previous_saturated=False, recent_frames=PREVIOUS, commands=fix)
        assert diagnose(ev)[0] == "controller"
        ev = Evidence(**BASE, sees_events=sees, previous_saturated=False, recent_frames=PREVIOUS)
        name, why = diagnose(ev)
        assert name == "controller_lag" and "no correcting command" in why
    # a correction issued before the previous frame ended is not one made after it: still a lag
    early = (Command(70_000, 1_000.0, 1.0),)
    ev = Evidence(**BASE, sees_events=False, previous_saturated=False, recent_frames=PREVIOUS, commands=early)
    assert diagnose(ev)[0] == "controller_lag"


def test_a_frame_clipped_at_both_ends_proves_no_undercount():
    # the same shortfall as the prediction_undercount case, but 30 % of the frame is also black:
    # its mean is pulled down at one end and up at the other, so it bounds nothing
    two_sided = {**BASE, "over": 0.6, "under": 0.3}
    name, why = diagnose(
        Evidence(**two_sided, sees_events=True, predicted_change=0.4, frame_change=2.5, lost_change=2.0)
    )
    assert name == "controller" and "clipped at both ends (60% over, 30% under)" in why


def test_best_valid_fraction_of_a_uniform_log_ramp():
    # ln L uniform over 8 ln: a window as wide as the sensor's valid range, g(249.5) - g(9.5), holds that share
    crf = default_davis346()
    width = crf.log_exposure(249.5) - crf.log_exposure(9.5)
    lbar = np.tile(
        np.exp(np.linspace(0.0, 8.0, 4000)).astype(np.float32), (8, 1)
    )  # along x: the grid samples it evenly
    tr = GroundTruth(lbar, crf, np.zeros(0, np.int64), np.zeros(0))
    assert best_valid_fraction(tr) == pytest.approx(width / 8.0, abs=0.002)
    flat = GroundTruth(np.full((40, 40), 3.0, np.float32), crf, np.zeros(0, np.int64), np.zeros(0))
    assert best_valid_fraction(flat) == 1.0
