"""NEC control law (Eq. 2-4 with the sign fix): exact targets, gain rule, dead band, limits, closed loop."""

import math

import numpy as np
import pytest
from analytic import AnalyticScene, Trajectory
from hypothesis import given
from hypothesis import strategies as st

from necviz.core.control import CONTROLLERS, CameraLimits, ExposureCommand, NECController, NECOptions, error_weight
from necviz.core.errors import ParameterError
from necviz.core.event_model import TediParams
from necviz.core.events import EventBatch
from necviz.core.frames import Frame
from necviz.core.ptedi import PeripheralEstimator
from necviz.core.sensor import SensorGeometry
from necviz.core.stream import interleave

SENSOR = SensorGeometry(64, 48)


def _nec(crf, limits=CameraLimits(10, 20_000, 8.0), exposure_us=1_000, **kw):
    """The paper's controller (Eq. 2-4 on P-TEDI's mean, goal at the log mid-point): the law under test."""
    kw = {"metering": "paper", "goal_mode": "paper", "escape": False, **kw}
    est = PeripheralEstimator(SENSOR, TediParams(0.26, 0.24), crf)
    return NECController(est, limits, exposure_us, options=NECOptions(**kw))


def _log_exposure_product(cmd):
    return math.log(cmd.exposure_us / 1e6) + math.log(cmd.gain)


@pytest.mark.parametrize("log_l", [9.0, 4.0, 2.5, 10.5])
def test_one_command_puts_the_mean_log_intensity_at_the_goal(log_l, crf):
    """Changes beyond f_w's full band (|ln(T_opt / 1 ms)| > 0.5): one full jump."""
    nec = _nec(crf)
    cmd = nec.command_for(log_l, 0)
    # Eq. 1 for the next frame: mean g(Z) = mean ln L + ln T + ln K must equal g(I_opt)
    assert log_l + _log_exposure_product(cmd) == pytest.approx(crf.goal_log_exposure, abs=1e-9)


def test_next_frame_lands_on_the_goal_intensity(crf):
    """Through the camera response: the frame taken with the command has mean g(Z) at the goal."""
    scene = AnalyticScene(64, 48, [Trajectory("flat")], log_level=8.3)
    nec = _nec(crf)
    cmd = nec.command_for(scene.mean_log_irradiance(0), 0)
    frame = scene.frame(crf, 0, round(cmd.exposure_us), cmd.gain)
    z = frame.image
    assert ((z >= 9) & (z <= 250)).mean() == 1.0
    assert crf.g[z].mean() == pytest.approx(crf.goal_log_exposure, abs=0.01)


def test_gain_rises_only_when_exposure_would_pass_its_maximum(crf):
    lim = CameraLimits(10, 20_000, 8.0)
    for log_l in np.linspace(1.0, 12.0, 200):
        nec = _nec(crf, lim, exposure_us=1.0e4, full_band=0.01, dead_band=0.0)
        cmd = nec.command_for(float(log_l), 0)
        if cmd is None:
            continue
        h_opt = math.exp(crf.goal_log_exposure - log_l) * 1e6
        if h_opt <= lim.exposure_max_us:
            assert cmd.gain == 1.0
            assert cmd.exposure_us == pytest.approx(max(h_opt, lim.exposure_min_us))
        else:
            assert cmd.exposure_us == lim.exposure_max_us
            assert cmd.gain == pytest.approx(min(h_opt / lim.exposure_max_us, lim.gain_max))


def test_no_command_inside_the_dead_band(crf):
    nec = _nec(crf, exposure_us=1_000, dead_band=0.1)
    log_l_now = crf.goal_log_exposure - math.log(1_000 / 1e6)  # exactly right for 1 ms
    assert nec.command_for(log_l_now, 0) is None
    assert nec.command_for(log_l_now + 0.09, 0) is None
    assert nec.command_for(log_l_now - 0.09, 0) is None
    assert nec.command_for(log_l_now + 0.2, 0) is not None


def test_partial_step_moves_towards_the_target(crf):
    """Between the corners of f_w, Eq. 3 moves part of the way (sign fixed: towards T_opt)."""
    nec = _nec(crf, exposure_us=1_000, dead_band=0.1, full_band=0.5)
    log_l = crf.goal_log_exposure - math.log(1_000 / 1e6) + 0.3  # brighter: wants a shorter exposure
    cmd = nec.command_for(log_l, 0)
    h_opt = math.exp(crf.goal_log_exposure - log_l) * 1e6
    assert h_opt < cmd.exposure_us < 1_000
    w = error_weight(math.log(h_opt / 1_000), 0.1, 0.5)
    assert cmd.exposure_us == pytest.approx(1_000 + w * (h_opt - 1_000))


@given(st.floats(-50, 50), st.floats(0, 1), st.floats(0.01, 3))
def test_error_weight_is_a_monotone_weight(r, dead, width):
    full = dead + width
    w = error_weight(r, dead, full)
    assert 0.0 <= w <= 1.0
    assert error_weight(abs(r) + 0.01, dead, full) >= w - 1e-12
    if abs(r) <= dead:
        assert w == 0.0
    if abs(r) >= full:
        assert w == 1.0


@given(st.one_of(st.floats(-60, 60), st.just(float("nan"))))
def test_commands_are_always_within_limits(log_l):
    lim = CameraLimits(15, 25_000, 4.0)
    nec = NECController(PeripheralEstimator(SENSOR), lim, 2_000)
    cmd = nec.command_for(log_l, 0)
    if math.isnan(log_l):
        assert cmd is None
        return
    if cmd is not None:
        assert lim.exposure_min_us <= cmd.exposure_us <= lim.exposure_max_us
        assert 1.0 <= cmd.gain <= lim.gain_max
        assert math.isfinite(cmd.exposure_us) and math.isfinite(cmd.gain)


@pytest.mark.slow
def test_closed_loop_exposes_the_first_frame_after_a_step_correctly(crf):
    """A miniature tunnel exit: +3 ln (26 dB) step between two frames; NEC, fed by events, commands the
    right exposure before the next frame starts, so that frame is well exposed (no saturated frame)."""
    step_t = 45_000
    scene = AnalyticScene(64, 48, [Trajectory("step", step_t, 3.0)], log_level=5.0)
    events = scene.events(0.26, 0.24)
    limits = CameraLimits(10, 15_000, 1.0)
    nec = _nec(crf, limits, exposure_us=math.exp(crf.goal_log_exposure - 5.0) * 1e6)
    exposure, gain = nec.exposure_us, nec.gain
    period, latency = 20_000, 500
    applied = []
    t_fed = 0
    for i in range(6):
        s = i * period + 1_000
        # events up to the exposure start, in 1 ms batches; commands issued before s - latency apply
        while t_fed < s:
            nxt = min(s, t_fed + 1_000)
            batch = events[(events["t"] >= t_fed) & (events["t"] < nxt)]
            cmd = nec.feed(EventBatch(batch))
            if cmd is not None and cmd.issue_time_us <= s - latency:
                exposure, gain = cmd.exposure_us, cmd.gain
            t_fed = nxt
        frame = scene.frame(crf, s, s + round(exposure), gain, seq=i)
        applied.append(frame)
        for pk in interleave(events[(events["t"] >= s) & (events["t"] < frame.exposure_end_us)], [frame]):
            cmd = nec.feed(pk)
        t_fed = frame.exposure_end_us
        if cmd is not None:
            exposure, gain = cmd.exposure_us, cmd.gain
    over = [float((f.image >= 250).mean()) for f in applied]
    first_after = next(i for i, f in enumerate(applied) if f.exposure_start_us > step_t)
    assert over[first_after] < 0.1, over
    assert applied[first_after].exposure_us < applied[0].exposure_us * math.exp(-2.5)
    # the same frame with the pre-step exposure (what a frame-only controller would still use) saturates
    stale = scene.frame(
        crf, applied[first_after].exposure_start_us, applied[first_after].exposure_start_us + applied[0].exposure_us
    )
    assert (stale.image >= 250).mean() > 0.5


def test_controller_interface_and_bad_parameters(crf):
    assert CONTROLLERS["nec"].cls is NECController
    nec = _nec(crf)
    assert nec.initial_command(5) == ExposureCommand(nec.exposure_us, 1.0, 5, "nec")
    f = Frame(np.full((48, 64), 90, np.uint8), 0, 1_000, 1.0)
    nec.on_exposure_start(0)
    nec.on_exposure_end(1_000)
    nec.on_frame(f)
    assert nec.exposure_us == 1_000 and nec.estimator.ready
    with pytest.raises(ParameterError, match="full_band"):
        _nec(crf, dead_band=0.5, full_band=0.4)
    with pytest.raises(ParameterError, match="dead_band"):
        _nec(crf, dead_band=float("nan"))
    with pytest.raises(ParameterError, match="exposure_max_us"):
        CameraLimits(100, 10)
    with pytest.raises(ParameterError, match="gain_max"):
        CameraLimits(10, 100, 0.5)
    with pytest.raises(ParameterError, match="exposure_us"):
        ExposureCommand(float("nan"), 1.0, 0)
    with pytest.raises(ParameterError, match="gain"):
        ExposureCommand(10.0, 0.5, 0)
