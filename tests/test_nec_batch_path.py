"""NEC's per-event-batch path (``NECController.on_events``) meters and aims exactly as its general methods do.

``on_events`` meters the whole-sensor modes directly and takes the escape rule's aims worked out when the
options are applied (issue 27 item 5: the per-batch cost); these tests pin that it decides on the same
numbers as :meth:`NECController.metered` and the escape rule's formula, so the two cannot drift apart.
"""

from __future__ import annotations

import math

import pytest

from necviz.core.control import CameraLimits, make_controller
from necviz.core.events import EventBatch
from necviz.core.sensor import DAVIS346, DAVIS_EVENT_RATE_MAX
from necviz.dashboard.pipeline_speed import SyntheticStream, make_events

DURATION_S = 0.3


@pytest.fixture(scope="module")
def events():
    return make_events(DURATION_S, 12.0, seed=3)  # at the bus ceiling, the light moving: every batch commands


def _same(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


@pytest.mark.parametrize(
    "kind, params",
    [
        ("nec", {}),
        ("nec", {"flicker_rule": False}),
        ("nec", {"metering": "percentile"}),
        ("nec", {"metering": "paper", "goal_mode": "paper"}),
        ("nec", {"escape": False}),
    ],
)
def test_batch_path_meters_as_metered(events, kind, params):
    src = SyntheticStream(events, DURATION_S)
    limits = CameraLimits(10.0, src.period_us - 1_000, 8.0)
    ctrl = make_controller(
        kind,
        sensor=DAVIS346,
        limits=limits,
        exposure_us=src.exposure_us,
        event_rate_max=DAVIS_EVENT_RATE_MAX,
        **params,
    )
    checked = commands = 0
    for packet in src:
        cmd = ctrl.feed(packet)
        if cmd is not None:
            commands += 1
            src.set_exposure("camera", cmd.exposure_us, cmd.gain)
        if type(packet) is EventBatch and ctrl.estimator.ready:
            lp = ctrl.last_log_irradiance
            assert _same(ctrl.last_metered, ctrl.metered(ctrl.now_us))
            assert _same(ctrl.last_log_irradiance, lp)  # metered() recomputed the same P-TEDI level
            checked += 1
    assert commands > 10
    assert checked > 200


@pytest.mark.parametrize("margin", [0.0, 0.4, 1.3])
def test_escape_aims_follow_the_options(margin):
    ctrl = make_controller("nec", sensor=DAVIS346, limits=CameraLimits(10.0, 19_000.0, 8.0), exposure_us=2_000.0)
    ctrl.set_param("edge_margin", margin)
    crf = ctrl.estimator.crf
    ctrl._determined_s = 0  # a frame determined M after every window at the bus ceiling: only the frame counts
    for d, expected in (
        (1, min(ctrl.goal_log_exposure, crf.g[crf.valid_min] + margin)),
        (-1, max(ctrl.goal_log_exposure, crf.g[crf.valid_max] - margin)),
        (0, None),
    ):
        ctrl._frame_dir = d
        assert ctrl._aim() == expected
        assert ctrl.escape_direction == d
