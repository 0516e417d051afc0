"""Estimators sharing their event side (:mod:`necviz.core.ptedi_shared`) give exactly what stand-alone ones give.

Truth: the stand-alone :class:`~necviz.core.ptedi.PeripheralEstimator` (itself checked against the per-pixel
brute force in ``test_ptedi_compensation``). Every lane of a rig has a stand-alone estimator and a shared
one, fed the same packets; every frame estimate and prediction must be equal to the last bit (``repr``).
"""

from dataclasses import replace

import numpy as np
import pytest
from test_ptedi_compensation import PARAMS, SENSOR, H, W, random_stream

from necviz.core.errors import ParameterError, StreamError
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.ptedi import PeripheralEstimator, PeripheralOptions
from necviz.core.ptedi_shared import share_event_side
from necviz.core.stream import interleave


def _lanes_stream(seed: int, delay_us: int):
    """Three cameras on one event stream, exposures starting together every 10 ms with different lengths;
    camera 2's frames are over-exposed every other time (not re-anchored), frames come ``delay_us`` late."""
    ev = random_stream(seed)
    lengths = (700, 3_000, 7_000)
    packets = []
    for cam, length in enumerate(lengths):
        frames = []
        for i, s in enumerate(range(1_000, 55_000, 10_000)):
            img = np.full((H, W), 128, np.uint8)
            if cam == 2 and i % 2:
                img[:] = 255
            elif cam == 1 and i % 3 == 1:
                img[: H // 2, : W // 2] = 0  # one quadrant under-exposed: zones re-anchor apart
            frames.append(Frame(img, s, s + length, 1.0, i))
        for pk in interleave(ev[:0], frames, frame_delay_us=delay_us):
            t = pk.t_us if isinstance(pk, ExposureMarker) else pk.exposure_end_us + delay_us
            order = 0 if isinstance(pk, ExposureMarker) and pk.kind == "end" else (2 if isinstance(pk, Frame) else 1)
            packets.append((t, order, cam, pk))
    packets.sort(key=lambda r: (r[0], r[1], r[2]))
    # events cut at every marker / frame time and every 700 µs, in stream order
    times = sorted({r[0] for r in packets} | set(range(700, 60_000, 700)))
    out, pos = [], 0
    cuts = np.searchsorted(ev["t"], times, side="left")
    k = 0
    for tc, cut in zip(times, cuts, strict=True):
        if cut > pos:
            out.append((None, ev[pos:cut]))
            pos = cut
        while k < len(packets) and packets[k][0] == tc:
            out.append((packets[k][2], packets[k][3]))
            k += 1
    if pos < ev.size:
        out.append((None, ev[pos:]))
    return out


@pytest.mark.parametrize("grid", [(1, 1), (2, 2)])
@pytest.mark.parametrize("delay_us", [0, 12_000])
def test_shared_estimators_equal_stand_alone_ones_bit_for_bit(grid, delay_us):
    stream = _lanes_stream(7, delay_us)
    alone = [PeripheralEstimator(SENSOR, PARAMS, options=PeripheralOptions(grid=grid)) for _ in range(3)]
    shared = [PeripheralEstimator(SENSOR, PARAMS, options=PeripheralOptions(grid=grid)) for _ in range(3)]
    (side,) = share_event_side(shared)
    got, want, most_live = [], [], 0
    for cam, pk in stream:
        most_live = max(most_live, side.live_slots())
        for ests, out in ((alone, want), (shared, got)):
            for i, est in enumerate(ests):
                if cam is None:
                    est.update(pk)
                    if est.ready:
                        out.append(repr(est.predict_zones()))
                elif cam == i:
                    if isinstance(pk, ExposureMarker) and pk.kind == "start" and est.ready:
                        out.append(repr(est.predict_zones(pk.t_us)))
                    fe = est.feed(pk)
                    if fe is not None:
                        out.append(repr(fe))
    assert len(want) > 100 and got == want
    assert all(est.frames_seen == 6 for est in shared)
    # anchors and exposure starts in separate slots (and, with late frames, the starts awaiting them)
    assert most_live >= (3 if delay_us else 2)


def _tuned_mid_stream(tune):
    """Three lanes alone and three sharing a side, fed the same packets; mid-stream (mid-exposure, frames
    pending) ``tune(alone, shared)`` is called once. Returns every estimate of each group (``repr``)."""
    stream = _lanes_stream(3, 12_000)
    alone = [PeripheralEstimator(SENSOR, PARAMS) for _ in range(3)]
    shared = [PeripheralEstimator(SENSOR, PARAMS) for _ in range(3)]
    share_event_side(shared)
    got, want, done = [], [], False
    for n, (cam, pk) in enumerate(stream):
        if not done and n > len(stream) // 2 and shared[1]._open >= 0:
            tune(alone, shared)
            done = True
        for ests, out in ((alone, want), (shared, got)):
            for i, est in enumerate(ests):
                if cam is None:
                    est.update(pk)
                    if est.ready:
                        out.append(repr(est.predict_zones()))
                elif cam == i:
                    fe = est.feed(pk)
                    if fe is not None:
                        out.append(repr(fe))
    assert done
    return got, want


def test_a_member_whose_thresholds_change_continues_on_its_own_exactly():
    """Live tuning of one lane: the shared member leaves the side mid-stream and goes on as a stand-alone
    estimator tuned at the same moment does."""
    tuned = PARAMS.__class__(0.3, 0.2, PARAMS.a_on, PARAMS.b_on, PARAMS.a_off, PARAMS.b_off)

    def tune(alone, shared):
        alone[1].set_params(tuned)
        shared[1].set_params(tuned)
        # the tuned lane alone has the new parameters: the others go on with theirs
        assert shared[1].params == tuned and shared[0].params == shared[2].params == PARAMS

    got, want = _tuned_mid_stream(tune)
    assert got == want


def test_contrast_thresholds_change_on_the_side_for_every_member():
    """set_contrast_thresholds on one lane changes the thresholds of every estimator on its event side, from
    that moment on exactly as for a lone estimator given the same call; a+-, b+- stay; the next estimates
    follow the new thresholds."""

    def tune(alone, shared):
        before = shared[0].predict()
        for est in alone:
            est.set_contrast_thresholds(0.3, 0.2)
        shared[2].set_contrast_thresholds(0.3, 0.2)  # one call: every member
        assert all(est.params == replace(PARAMS, c_on=0.3, c_off=0.2) for est in shared)
        assert shared[0].predict() != before  # the counts since the anchor are weighed anew

    got, want = _tuned_mid_stream(tune)
    assert got == want


def test_members_must_be_fed_in_lock_step():
    shared = [PeripheralEstimator(SENSOR, PARAMS) for _ in range(2)]
    share_event_side(shared)
    ev = random_stream(1)
    shared[0].update(ev[:10])
    with pytest.raises(StreamError, match="every event batch"):
        shared[1].update(ev[10:20])  # not the batch the other member received


def test_contrast_thresholds_without_compensation_and_bad_values():
    plain = PeripheralEstimator(SENSOR, PARAMS.plain)
    plain.set_contrast_thresholds(0.3, 0.25)
    assert plain.params == replace(PARAMS.plain, c_on=0.3, c_off=0.25) and plain.event_side is None
    for bad in (0.0, -0.1, float("nan"), float("inf"), True, "0.2"):
        with pytest.raises(ParameterError, match="c_on"):
            plain.set_contrast_thresholds(bad, 0.2)
    assert plain.params.c_on == 0.3
