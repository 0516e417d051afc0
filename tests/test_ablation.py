"""The ablation lanes: ``nec-frames`` (NEC without events), ``nec-paper`` (the paper's controller exactly),
the switches between them and ``nec``, the tuned controllers, and the event bus ceiling read from the source."""

from __future__ import annotations

import math

import numpy as np
import pytest

from necviz.core.control import (
    CONTROLLERS,
    PAPER_OPTIONS,
    CameraLimits,
    NavidController,
    NECController,
    NECFramesController,
    make_controller,
    make_options,
    register_controller,
)
from necviz.core.errors import ParameterError
from necviz.core.event_model import TediParams
from necviz.core.sensor import SensorGeometry
from necviz.drivers.sim.aps import ApsParams
from necviz.drivers.sim.dvs import DvsParams
from necviz.drivers.sim.rig import SimRig
from necviz.drivers.sim.scene import FunctionScene, LightingChange
from necviz.options import BASELINES, COMPARE_CONTROLLERS, DEFAULT_CONTROLLERS, SceneOptions
from necviz.pipeline import Lane, Pipeline

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

SENSOR = SensorGeometry(64, 48)
YY, XX = np.mgrid[0:48, 0:64].astype(np.float32)
TEXTURE = 0.5 * np.sin(XX / 3.0) * np.cos(YY / 4.0)
TEDI = TediParams(0.26, 0.24, 0.5, 25.0, 0.4, 20.0)  # with compensation, to see it switched off


def step_scene(t_step_us=30_000, level=5.0, step=3.0, ramp_us=0.0, duration_us=120_000):
    def fn(t_us, sensor):
        a = 0.0 if t_us < t_step_us else (1.0 if ramp_us <= 0 else min(1.0, (t_us - t_step_us) / ramp_us))
        return level + TEXTURE + np.float32(step * a)

    return FunctionScene(fn, SENSOR, duration_us, changes=[LightingChange(int(t_step_us), "step", step)])


def closed_loop(scene, names, dvs=None, **kw):
    """Every controller in ``names`` drives its own camera of one rig; returns the controllers and the rig."""
    aps = ApsParams()
    rig = SimRig(scene, list(names), dvs=dvs, aps=aps, seed=3)
    limits = CameraLimits(aps.exposure_min_us, aps.exposure_max_us, aps.gain_max)
    rate = rig.camera_info.event_rate_max
    ctrls = {
        n: make_controller(
            n, sensor=SENSOR, limits=limits, exposure_us=rig.cams[n].exposure_us, event_rate_max=rate, **kw
        )
        for n in names
    }
    Pipeline(rig, [Lane(n, c) for n, c in ctrls.items()]).run().finish()
    return ctrls, rig


# -- nec-frames -----------------------------------------------------------------------------------
def test_nec_frames_estimator_receives_zero_events_and_keeps_nec_s_rules():
    ctrls, rig = closed_loop(step_scene(), ["nec", "nec-frames"])
    nec, frames = ctrls["nec"], ctrls["nec-frames"]
    assert isinstance(frames, NECFramesController) and not frames.uses_events and nec.uses_events
    assert nec.estimator.event_totals()[0] > 1_000  # the step's events reached NEC ...
    assert frames.estimator.event_totals() == (0, 0)  # ... and not one reached nec-frames
    assert frames.estimator.last_event_us == np.iinfo(np.int64).min
    assert frames.estimator.frames_seen == nec.estimator.frames_seen >= 5  # both anchored on every frame
    assert frames.options == nec.options  # the same metering, goal, law and escape rule
    assert frames.saturated_windows == 0  # the escape rule's event case cannot arise without events


def test_nec_frames_commands_only_at_frames_and_jumps_once_through_the_response():
    """Between frames the prediction is the last frame's level, so nec-frames commands only on frames;
    after the frame that shows the 3 ln step it jumps by the whole step in one command (Eq. 2-4)."""
    scene = step_scene(t_step_us=30_000, step=3.0)
    aps = ApsParams()
    rig = SimRig(scene, ["cam"], aps=aps, seed=1)
    limits = CameraLimits(aps.exposure_min_us, aps.exposure_max_us, aps.gain_max)
    ctrl = make_controller("nec-frames", sensor=SENSOR, limits=limits, exposure_us=rig.cams["cam"].exposure_us)
    from necviz.core.frames import Frame

    issued = []
    for _cam, packet in rig.packets():
        cmd = ctrl.feed(packet)
        if cmd is not None:
            issued.append((isinstance(packet, Frame), cmd))
            rig.set_exposure("cam", cmd.exposure_us, cmd.gain)
    assert issued and all(on_frame for on_frame, _ in issued)
    before = [c for _, c in issued if c.issue_time_us < 30_000]
    after = [c for _, c in issued if c.issue_time_us > 30_000]
    h0 = before[-1].exposure_us * before[-1].gain if before else rig.cams["cam"].exposure_us
    jump = math.log(h0 / (after[0].exposure_us * after[0].gain))
    assert jump == pytest.approx(3.0, abs=0.35)  # the whole step at once (the step leaves the frame saturated)


# -- nec-paper and the switches --------------------------------------------------------------------
def test_nec_paper_is_nec_with_every_addition_off():
    nec = make_controller("nec-paper", sensor=SENSOR, limits=CameraLimits(), tedi=TEDI)
    assert {k: getattr(nec.options, k) for k in PAPER_OPTIONS} == PAPER_OPTIONS
    assert not nec.estimator.saturation_bound  # the paper's rule for a saturated anchor alone
    assert nec.estimator.params == TEDI  # the paper's TEDI applies its compensation (Eq. 6)
    default = make_controller("nec", sensor=SENSOR, limits=CameraLimits(), tedi=TEDI)
    assert default.estimator.saturation_bound and default.estimator.params == TEDI
    # every switch alone, on the default
    for switch in ("saturation_bound", "compensation", "escape"):
        one = make_controller("nec", sensor=SENSOR, limits=CameraLimits(), tedi=TEDI, **{switch: False})
        assert getattr(one.options, switch) is False
    assert not make_controller(
        "nec", sensor=SENSOR, limits=CameraLimits(), saturation_bound=False
    ).estimator.saturation_bound
    raw = make_controller("nec", sensor=SENSOR, limits=CameraLimits(), tedi=TEDI, compensation=False)
    assert raw.estimator.params.a_on == 0.0 and raw.estimator.params.c_on == TEDI.c_on
    # a parameter given by name overrides the registered defaults
    assert make_options("nec-paper", {"escape": True}).escape is True
    with pytest.raises(ParameterError, match="saturation_bound must be true or false"):
        make_controller("nec", sensor=SENSOR, limits=CameraLimits(), saturation_bound="yes")


def test_nec_paper_skips_saturated_anchors_where_nec_re_anchors_at_the_bound():
    """A 9.2 ln step over 2 ms beyond the event ceiling: most events are lost, the frames after it are
    saturated. The paper's rule skips them and keeps propagating from the last good anchor (which the
    lost events leave far too low); NEC re-anchors at the bound they prove and recovers."""
    dvs = DvsParams.ideal(max_event_rate=3e5)
    ctrls, _ = closed_loop(
        step_scene(37_500, 3.6, 9.2, ramp_us=2_000, duration_us=200_000), ["nec", "nec-paper"], dvs=dvs
    )
    nec, paper = ctrls["nec"], ctrls["nec-paper"]
    assert paper.estimator.frames_bounded == 0 and paper.estimator.frames_skipped >= 3
    assert nec.estimator.frames_bounded >= 1
    assert paper.estimator.anchor_t[0] < 37_500 < nec.estimator.anchor_t[0]  # still anchored before the step
    end = 199_000
    assert paper.estimator.predict(end) < nec.estimator.predict(end) - 2.0  # and propagating from there


# -- the registry: defaults, tuned controllers --------------------------------------------------------
def test_registered_defaults_are_checked_when_registered():
    with pytest.raises(ParameterError, match="no option 'bogus'"):
        register_controller("navid-bad", NavidController, defaults={"bogus": 1})
    with pytest.raises(ParameterError):
        register_controller("navid-bad", NavidController, defaults={"ev_per_unit": 5.0})  # beyond 0.1
    assert "navid-bad" not in CONTROLLERS
    register_controller("navid-test", NavidController, defaults={"ev_per_unit": 0.02}, doc="test")
    try:
        c = make_controller("navid-test", sensor=SENSOR, limits=CameraLimits())
        assert c.name == "navid-test" and c.options.ev_per_unit == 0.02
        assert (
            make_controller("navid-test", sensor=SENSOR, limits=CameraLimits(), ev_per_unit=0.03).options.ev_per_unit
            == 0.03
        )
    finally:
        del CONTROLLERS["navid-test"]


def test_tuned_controllers_come_from_the_committed_file(tmp_path):
    import json

    from necviz.tuned import load_tuned, register_tuned

    data = load_tuned()
    for base, entry in data.get("controllers", {}).items():
        name = f"{base}-tuned"
        assert name in CONTROLLERS
        c = make_controller(name, sensor=SENSOR, limits=CameraLimits())
        for k, v in entry["params"].items():
            assert getattr(c.options, k) == v
    f = tmp_path / "tuned.json"
    f.write_text(json.dumps({"controllers": {"shim": {"params": {"kp": 3.2}}}}))
    try:
        assert register_tuned(f) == ["shim-tuned"]
        assert make_controller("shim-tuned", sensor=SENSOR, limits=CameraLimits()).options.kp == 3.2
    finally:
        register_tuned()  # back to the committed choice
    f.write_text(json.dumps({"controllers": {"nope": {"params": {}}}}))
    with pytest.raises(ParameterError, match="not a registered controller"):
        register_tuned(f)


# -- lanes of the commands ----------------------------------------------------------------------------
def test_the_demo_shows_nec_frames_beside_nec_and_compare_runs_the_ladder_s_ends():
    from necviz.commands.cli import build_parser

    # the demo's baselines are the tuned ones, in the published ones' order (the fair comparison)
    assert DEFAULT_CONTROLLERS[:2] == ("nec", "nec-frames")
    assert [c.removesuffix("-tuned") for c in DEFAULT_CONTROLLERS[2:]] == list(BASELINES)
    assert {"navid-tuned", "shim-tuned", "begin-tuned"} <= set(DEFAULT_CONTROLLERS)
    assert {"nec-frames", "nec-paper"} <= set(COMPARE_CONTROLLERS)
    p = build_parser()
    assert p.parse_args(["demo"]).controllers == DEFAULT_CONTROLLERS
    assert p.parse_args(["compare"]).controllers == COMPARE_CONTROLLERS


# -- the bus ceiling comes from the source ----------------------------------------------------------
def test_lanes_read_the_event_ceiling_from_the_simulator_configuration():
    from necviz.runs import build_rig

    for sim, want in (({"dvs.max_event_rate": 6e6}, 6e6), ({}, 12e6), ({"dvs.max_event_rate": None}, None)):
        _, _, lanes, _ = build_rig(SceneOptions("tunnel_exit", duration_s=0.05).build(), ["nec", "nec-frames"], sim=sim)
        assert [ln.controller.bus_event_rate for ln in lanes] == [want, want]
    # an explicit option still wins over the source
    _, _, lanes, _ = build_rig(
        SceneOptions("tunnel_exit", duration_s=0.05).build(),
        ["nec"],
        controller_params={"nec": {"bus_event_rate": 1e7}},
        sim={"dvs.max_event_rate": 6e6},
    )
    assert lanes[0].controller.bus_event_rate == 1e7


def test_the_escape_rule_uses_the_source_s_ceiling_not_a_literal():
    """A 64x48 sensor whose bus carries 3e5 events/s: the 9.2 ln step saturates it. NEC built with the
    source's ceiling flags those windows and escapes; with the DAVIS346's 12 Mev/s literal it would
    never see the bus as saturated on this sensor."""
    dvs = DvsParams.ideal(max_event_rate=3e5)
    scene = step_scene(37_500, 3.6, 9.2, ramp_us=2_000, duration_us=100_000)
    ctrls, rig = closed_loop(scene, ["nec"], dvs=dvs)
    assert rig.camera_info.event_rate_max == 3e5 and ctrls["nec"].bus_event_rate == 3e5
    assert ctrls["nec"].saturated_windows >= 1
    literal, _ = closed_loop(scene, ["nec"], dvs=dvs, bus_event_rate=12e6)
    assert literal["nec"].saturated_windows == 0
    unknown, _ = closed_loop(scene, ["nec"], dvs=DvsParams.ideal())  # no ceiling at the source: none assumed
    assert unknown["nec"].bus_event_rate is None and unknown["nec"].saturated_windows == 0


def test_a_controller_switched_to_on_the_dashboard_gets_the_source_s_ceiling():
    from necviz.runs import build_rig

    _, rig, lanes, _ = build_rig(
        SceneOptions("tunnel_exit", duration_s=0.05).build(), ["navid"], sim={"dvs.max_event_rate": 6e6}
    )
    pipe = Pipeline(rig, lanes)
    pipe._drive("nec", "navid")
    assert isinstance(pipe.lanes["navid"].controller, NECController)
    assert pipe.lanes["navid"].controller.bus_event_rate == 6e6


# -- events that lag behind a saturation bound --------------------------------------------------------
def _bounded_estimate(s, pred, bound):
    from necviz.core.ptedi import FrameEstimate

    one = lambda v: np.array([float(v)])  # noqa: E731
    return FrameEstimate(
        7,
        s,
        s + 500,
        one(bound),
        one(0.0),
        one(bound),
        one(0.0),
        np.array([False]),
        one(0.0),
        np.array([True]),
        one(bound),
        np.array([-1], np.int8),
        one(pred),
    )


def test_events_that_lag_behind_a_bound_are_not_counted_twice():
    """A frame proves the light fell to at most 5.5 while the events had only reached 6.5 (the
    photoreceptor still following the step): the next 1.0 ln of OFF events is the same fall."""
    nec = make_controller("nec", sensor=SENSOR, limits=CameraLimits())
    assert nec.options.bound_lag
    sizes = nec.estimator.sizes
    nec.lag.after_frame(_bounded_estimate(20_000, pred=6.5, bound=5.5), sizes, None)
    assert nec.bound_owed == pytest.approx(-1.0)
    for lp, absorbed in ((5.5, 0.0), (5.0, -0.5), (4.5, -1.0), (3.0, -1.0), (6.0, 0.0)):
        assert nec.lag.absorbed(lp) == pytest.approx(absorbed)  # M = lp - absorbed: events count beyond the gap
    # a normal anchor closes the gap
    from necviz.core.ptedi import FrameEstimate

    one = np.array([1.0])
    nec.lag.after_frame(FrameEstimate(8, 40_000, 40_500, one, one * 0, one, one, np.array([True])), sizes, None)
    assert nec.bound_owed == 0.0 and nec.lag.absorbed(3.0) == 0.0


def test_a_gap_after_a_window_at_the_bus_ceiling_is_lost_events_not_lag():
    from necviz.core.ptedi import FrameEstimate

    nec = make_controller("nec", sensor=SENSOR, limits=CameraLimits(), event_rate_max=1e6)
    one = np.array([1.0])
    nec.lag.after_frame(FrameEstimate(1, 0, 500, one, one * 0, one, one, np.array([True])), nec.estimator.sizes, None)
    # a window at the ceiling between the anchor and the frame: 600 OFF events in 600 µs at 1 Mev/s
    assert nec.bus.watch(1, 14_400, (0, 0), 1e6) is None
    assert nec.bus.watch(600, 15_000, (0, 600), 1e6) == (0, 600)
    assert nec.bus.saturated_t == 15_000 and nec.bus.saturated_dir == -1 and nec.saturated_windows == 1
    nec.lag.after_frame(_bounded_estimate(20_000, pred=6.5, bound=5.5), nec.estimator.sizes, nec.bus.saturated_t)
    assert nec.bound_owed == 0.0
    # a window before the anchor does not explain the gap
    nec.lag.after_frame(_bounded_estimate(30_000, pred=6.5, bound=5.5), nec.estimator.sizes, nec.bus.saturated_t)
    assert nec.bound_owed == pytest.approx(-1.0)
    # and the paper's controller has the switch off
    assert make_controller("nec-paper", sensor=SENSOR, limits=CameraLimits()).options.bound_lag is False


def test_absorbing_the_lag_keeps_the_frame_after_a_bounded_one_valid():
    """A 40 dB fall 1.5 ms before frame 2 starts (no bus ceiling): frame 2 cannot be helped (the
    command latency) and under-exposes; its bound lowers P-TEDI's anchor while the dark pixels' OFF
    events are still arriving. Counting those again left frame 3 over-exposed; absorbing them does not."""
    from necviz.telemetry import Telemetry

    scene = step_scene(39_500, 7.3, -4.6, duration_us=100_000)
    aps = ApsParams()
    worst = {}
    for lag in (True, False):
        rig = SimRig(scene, ["cam"], dvs=DvsParams(max_event_rate=None), aps=aps, seed=3)
        limits = CameraLimits(aps.exposure_min_us, aps.exposure_max_us, aps.gain_max)
        c = make_controller(
            "nec",
            sensor=SENSOR,
            limits=limits,
            exposure_us=rig.cams["cam"].exposure_us,
            bound_lag=lag,
            compensation=False,
        )
        tel = Telemetry(["cam"])
        Pipeline(rig, [Lane("cam", c)], telemetry=tel).run().finish()
        rows = {r["sequence"]: r for r in tel["cam"].table.rows()}
        assert rows[2]["under_exposed_rate"] > 0.5  # the frame no controller could have helped
        worst[lag] = max(rows[3]["over_exposed_rate"], rows[3]["under_exposed_rate"])
    assert worst[True] < 0.1 < 0.5 < worst[False]
