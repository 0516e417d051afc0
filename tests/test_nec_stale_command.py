"""NEC control: a command issued for a transient must not outlive it.

The camera keeps the newest command it received and applies it at its next exposure start. When
the prediction swings out of the dead band (a command is issued) and back into the dead band of
the applied setting before the next exposure, the setting the camera applies must be the
applied one again, not the transient's.
"""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from necviz.core.control import CameraLimits, NECController, NECOptions
from necviz.core.event_model import TediParams
from necviz.core.events import EventBatch, make_events
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.ptedi import PeripheralEstimator
from necviz.core.sensor import SensorGeometry

SENSOR = SensorGeometry(32, 24)
DEAD, FULL = 0.1, 0.5


def _nec(crf, exposure_us=1_000.0):
    est = PeripheralEstimator(SENSOR, TediParams(0.26, 0.24), crf)
    # the paper's metering and goal: the mean-level arithmetic below is P-TEDI's own (the stale-command
    # rule in command_for is the same for every metering mode)
    return NECController(
        est,
        CameraLimits(10, 20_000, 8.0),
        exposure_us,
        options=NECOptions(dead_band=DEAD, full_band=FULL, metering="paper", goal_mode="paper", escape=False),
    )


def _every_pixel(n_per_pixel, t0, span_us, polarity):
    """``n_per_pixel`` events of one polarity on every pixel, spread evenly over ``[t0, t0 + span)``."""
    npix = SENSOR.width * SENSOR.height
    pix = np.tile(np.arange(npix), n_per_pixel)
    t = t0 + (np.arange(pix.size) * span_us) // pix.size
    return make_events(t, pix % SENSOR.width, pix // SENSOR.width, np.full(pix.size, polarity, np.int8))


def test_transient_inside_the_dead_band_leaves_no_stale_command(crf):
    nec = _nec(crf)
    setting = (nec.exposure_us, nec.gain)  # what the camera will apply at its next exposure start
    issued = []

    def feed(pk):
        nonlocal setting
        cmd = nec.feed(pk)
        if cmd is not None:
            setting = (cmd.exposure_us, cmd.gain)
            issued.append(cmd)

    # frame 0: 1 ms, every pixel at the digit nearest the goal: the applied setting is right
    z_goal = int(np.argmin(np.abs(crf.g - crf.goal_log_exposure)))
    feed(ExposureMarker(0, "start"))
    feed(ExposureMarker(1_000, "end"))
    feed(Frame(np.full((SENSOR.height, SENSOR.width), z_goal, np.uint8), 0, 1_000, 1.0, 0))
    assert not issued and abs(nec.last_log_irradiance + math.log(1e-3) - crf.goal_log_exposure) < 0.02
    # the transient: +3 ON per pixel (+0.78 ln, beyond the full band), then -3 OFF (-0.72): net +0.06
    on = _every_pixel(3, 2_000, 1_000, 1)
    off = _every_pixel(3, 4_000, 1_000, -1)
    for batch in np.array_split(on, 4):
        feed(EventBatch(batch))
    assert issued and math.log(setting[0] * setting[1] / 1_000) < -FULL  # the transient was commanded
    feed(EventBatch(off))  # one batch: no partial step on the way back
    # back inside the dead band of the applied 1 ms: the next exposure (starting at 6 ms) must use it
    assert abs(nec.last_log_irradiance - (crf.goal_log_exposure - math.log(1e-3)) - 0.06) < 0.05
    feed(ExposureMarker(6_000, "start"))
    assert setting == (1_000.0, 1.0)
    assert issued[-1].issue_time_us == int(off["t"][-1])  # re-commanded when the prediction came back


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-3.0, 3.0), max_size=8), st.floats(-0.095, 0.095))
def test_outstanding_setting_is_inside_the_dead_band_whenever_the_prediction_is(swings, final):
    """Any sequence of predictions ending inside the dead band of the applied setting leaves the camera
    a setting within the dead band of the target (up to the command hysteresis)."""
    from necviz.core.crf import default_davis346

    crf = default_davis346()
    nec = _nec(crf)
    base = crf.goal_log_exposure - math.log(1e-3)  # exactly right for the applied 1 ms
    pending = nec.exposure_us * nec.gain
    for k, d in enumerate(swings + [final]):
        cmd = nec.command_for(base + d, k)
        if cmd is not None:  # what Controller.feed does with a command
            nec.last_command = cmd
            pending = cmd.exposure_us * cmd.gain
    h_opt = 1_000.0 * math.exp(-final)
    assert abs(math.log(pending / h_opt)) <= DEAD + nec.options.min_command_change + 1e-9
