"""P-TEDI against closed-form scenes: anchor, forward prediction, anchor rule, zones, streaming.

Truths: for the paper's image form (Eq. 15, ``g(mean Z)``) the estimate is the log of the
*spatial mean* irradiance (exact for an affine response); for the mean-log form it is the
mean log irradiance (Eq. 8). Either way a wrong sign, a wrong orientation of the direct
integral or a wrong exposure integral is off by far more than the ``c/2`` tolerance.
"""

import math

import numpy as np
import pytest
from analytic import AnalyticScene, Trajectory
from hypothesis import given, settings
from hypothesis import strategies as st

from necviz.core.crf import default_davis346
from necviz.core.errors import EventFormatError, FrameFormatError, NotAnchoredError, ParameterError, StreamError
from necviz.core.event_model import TediParams
from necviz.core.events import EventBatch, make_events
from necviz.core.frames import Frame
from necviz.core.ptedi import PeripheralEstimator, PeripheralOptions
from necviz.core.sensor import SensorGeometry
from necviz.core.stream import interleave

C_ON, C_OFF = 0.26, 0.24
TOL = max(C_ON, C_OFF) / 2  # the tolerance: half a contrast threshold
SENSOR = SensorGeometry(64, 48)
PARAMS = TediParams(C_ON, C_OFF)


def _truth(scene, t, form, mask=None):
    return scene.log_mean_irradiance(t, mask) if form == "paper" else scene.mean_log_irradiance(t, mask)


def _frames(scene, crf, starts, exposure_us=4_000, adapt=False):
    """Frames at ``starts``; with ``adapt`` each exposure puts the true mean log irradiance at the goal."""
    out = []
    for i, s in enumerate(starts):
        t_exp = exposure_us
        if adapt:
            t_exp = int(np.clip(math.exp(crf.goal_log_exposure - scene.mean_log_irradiance(s)) * 1e6, 20, 18_000))
        out.append(scene.frame(crf, s, s + t_exp, seq=i))
    return out


def _packet_time(pk):
    if isinstance(pk, EventBatch):
        return int(pk.events["t"][0])
    return int(pk.t_us) if hasattr(pk, "t_us") else int(pk.exposure_end_us)


def _run(scene, frames, crf, form="paper", batch_us=1_000, query_us=500, end_us=100_000, **kw):
    """Stream everything; return the predictions on a ``query_us`` grid once anchored, and the FrameEstimates.

    A query at time q is answered after every packet before q has been applied.
    """
    est = PeripheralEstimator(SENSOR, PARAMS, crf, options=PeripheralOptions(image_form=form, **kw))
    preds, fes = [], []
    queries = list(range(query_us // 2, end_us, query_us))  # never exactly at a step instant
    qi = 0

    def answer(until):
        nonlocal qi
        while qi < len(queries) and queries[qi] < until:
            if est.ready and queries[qi] >= max(est.last_event_us, int(est.anchor_t.max())):
                preds.append((queries[qi], est.predict(queries[qi])))
            qi += 1

    for pk in interleave(scene.events(C_ON, C_OFF, seed=3), frames, batch_us=batch_us):
        answer(_packet_time(pk))
        r = est.feed(pk)
        if r is not None:
            fes.append(r)
    answer(end_us)
    return est, preds, fes


TRAJECTORIES = {
    "step +2": Trajectory("step", 31_000, 2.0),
    "step -3": Trajectory("step", 31_000, -3.0),
    "ramp +3": Trajectory("ramp", 25_000, 3.0, 30_000),
    "exp -2.5": Trajectory("exp", 25_000, -2.5, 8_000),
    "exp +13.8 (120 dB)": Trajectory("exp", 25_000, 13.8, 5_000),
}


@pytest.mark.parametrize("form", ["paper", "mean_log"])
@pytest.mark.parametrize("name", list(TRAJECTORIES))
def test_anchor_and_forward_prediction_match_the_truth(name, form, crf):
    tr = TRAJECTORIES[name]
    # level 6.5: the goal exposure is ~0.9 ms before the change and within 20 µs..18 ms after it,
    # except for 120 dB, where (as at a real tunnel exit) no exposure of this camera fits afterwards
    scene = AnalyticScene(64, 48, [tr], log_level=6.5)
    frames = _frames(scene, crf, range(0, 100_000, 20_000), adapt=True)
    est, preds, fes = _run(scene, frames, crf, form)
    # every frame that anchored: ln P(s) equals the truth at the exposure start
    anchored = [f for f in fes if f.anchored[0]]
    assert len(anchored) >= (2 if abs(tr.delta) > 10 else 4)
    for f in anchored:
        assert abs(f.log_anchor[0] - _truth(scene, f.exposure_start_us, form)) < TOL
    # forward prediction between and across frames, through the whole change
    errs = np.array([p - _truth(scene, t, form) for t, p in preds])
    assert len(errs) > 50
    assert np.max(np.abs(errs)) < TOL, f"worst {np.max(np.abs(errs)):.3f}"
    # ... and far better than the tolerance on average (uniform threshold phases average out)
    assert np.mean(np.abs(errs)) < TOL / 4


def test_image_forms_estimate_different_things(crf):
    """The paper form is biased relative to the mean log by the texture's Jensen gap, as derived."""
    scene = AnalyticScene(64, 48, [Trajectory("flat")], log_level=5.0)
    frame = _frames(scene, crf, [0])
    _, _, (fe_paper,) = _run(scene, frame, crf, "paper")
    _, _, (fe_mlog,) = _run(scene, frame, crf, "mean_log")
    jensen = scene.log_mean_irradiance(0) - scene.mean_log_irradiance(0)
    assert jensen > 0.05
    assert fe_paper.log_anchor[0] - fe_mlog.log_anchor[0] == pytest.approx(jensen, abs=0.01)


def test_120_dB_inside_one_exposure_is_integrated_exactly(crf):
    """A 13.8 ln-unit step half-way through an exposure: E_p spans a factor of 1e6 without overflow."""
    tr = Trajectory("step", 2_000, 13.8)
    # dark level chosen so the exposure average (dominated by the bright half) is well exposed
    scene = AnalyticScene(64, 48, [tr], log_level=5.0 - 13.8 + math.log(2.0))
    frames = [scene.frame(crf, 0, 4_000)]
    for form in ("paper", "mean_log"):
        est, preds, (fe,) = _run(scene, frames, crf, form)
        assert fe.anchored[0] and fe.valid_fraction[0] > 0.9
        assert fe.log_e[0] == pytest.approx(math.log((1 + math.exp(13.8)) / 2), abs=TOL)
        assert abs(fe.log_anchor[0] - _truth(scene, 0, form)) < TOL
        assert abs(preds[-1][1] - _truth(scene, preds[-1][0], form)) < TOL


def test_saturated_frames_do_not_reanchor_and_prediction_continues(crf):
    """Fixed exposure through a +3 step: later frames over-expose, P-TEDI keeps its good anchor."""
    scene = AnalyticScene(64, 48, [Trajectory("step", 31_000, 3.0)], log_level=5.0)
    frames = _frames(scene, crf, range(0, 100_000, 20_000), exposure_us=4_000)
    est, preds, fes = _run(scene, frames, crf, "paper")
    assert [bool(f.anchored[0]) for f in fes] == [True, True, False, False, False]
    assert all(f.valid_fraction[0] < 0.5 for f in fes[2:])
    assert est.frames_skipped == 3 and est.anchor_t[0] == 20_000
    late = [(t, p) for t, p in preds if t > 40_000]
    assert late and max(abs(p - _truth(scene, t, "paper")) for t, p in late) < TOL
    # a frame-only estimate would be badly wrong on those frames: the anchor rule matters
    assert min(abs(f.log_anchor[0] - _truth(scene, f.exposure_start_us, "paper")) for f in fes[2:]) > 0.5


def test_zones_follow_their_own_lighting(crf):
    """Four quadrants lit differently; a 2x2 grid of zones estimates each one separately."""
    groups = np.zeros((48, 64), np.int64)
    groups[:24, 32:] = 1
    groups[24:, :32] = 2
    groups[24:, 32:] = 3
    trs = [
        Trajectory("step", 31_000, 1.5),
        Trajectory("ramp", 25_000, -2.0, 20_000),
        Trajectory("flat"),
        Trajectory("exp", 25_000, 2.5, 6_000),
    ]
    scene = AnalyticScene(64, 48, trs, groups=groups, log_level=5.0)
    frames = [scene.frame(crf, s, s + 3_000, seq=i) for i, s in enumerate(range(0, 100_000, 20_000))]
    est = PeripheralEstimator(
        SENSOR, PARAMS, crf, options=PeripheralOptions(grid=(2, 2), image_form="mean_log", min_valid_fraction=0.3)
    )
    assert est.num_zones == 4 and not est.whole
    for pk in interleave(scene.events(C_ON, C_OFF), frames[:1]):
        est.feed(pk)
    t = est.last_event_us
    z = est.predict_zones(t)
    for k in range(4):
        assert abs(z[k] - scene.mean_log_irradiance(t, groups == k)) < TOL
    # the whole-sensor mean is the pixel-weighted zone mean
    assert est.predict(t) == pytest.approx(z.mean())
    # zones really differ: a single whole-sensor zone would be wrong for every quadrant
    assert np.ptp(z) > 2.0


def test_rectangle_region_ignores_events_outside(crf):
    groups = np.zeros((48, 64), np.int64)
    groups[:, 32:] = 1
    scene = AnalyticScene(
        64,
        48,
        [Trajectory("ramp", 10_000, 2.0, 20_000), Trajectory("step", 12_000, -4.0)],
        groups=groups,
        log_level=5.0,
    )
    frames = [scene.frame(crf, 0, 4_000)]
    est = PeripheralEstimator(
        SENSOR, PARAMS, crf, options=PeripheralOptions(rectangle=(0, 0, 32, 48), image_form="mean_log")
    )
    for pk in interleave(scene.events(C_ON, C_OFF), frames):
        est.feed(pk)
    t = est.last_event_us
    assert abs(est.predict(t) - scene.mean_log_irradiance(t, groups == 0)) < TOL
    assert est.counts_off[0] == 0  # every OFF event was on the right half


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, 60_000), max_size=12))
def test_batch_boundaries_do_not_change_the_result(cuts):
    """Streaming is exact: any split of the event stream into batches gives the same estimate."""
    from necviz.core.crf import default_davis346

    crf = default_davis346()
    scene = AnalyticScene(32, 24, [Trajectory("ramp", 5_000, 2.0, 30_000)], log_level=5.0)
    ev = scene.events(C_ON, C_OFF)
    frames = [scene.frame(crf, s, s + 3_000, seq=i) for i, s in enumerate((1_000, 21_000, 41_000))]
    sensor = SensorGeometry(32, 24)
    params = TediParams(C_ON, C_OFF, 0.5, 50.0, 0.5, 50.0)
    results = []
    for extra in ([], sorted(cuts)):
        est = PeripheralEstimator(sensor, params, crf)
        for pk in interleave(ev, frames):
            if isinstance(pk, EventBatch):  # split further at the drawn times
                t = pk.events["t"]
                bounds = np.searchsorted(t, [c for c in extra if t[0] <= c <= t[-1]])
                for part in np.split(pk.events, bounds):
                    est.update(part)
            else:
                est.feed(pk)
        results.append((est.anchor_log.copy(), est.predict(60_000)))
    assert np.allclose(results[0][0], results[1][0], rtol=0, atol=1e-9)
    assert results[0][1] == pytest.approx(results[1][1], abs=1e-9)


def test_whole_sensor_and_general_kernels_agree(crf):
    """The register-only whole-sensor kernel and the zone kernel implement the same equations (without
    compensation; with it both regions go through the per-pixel kernel, see test_ptedi_compensation.py)."""
    scene = AnalyticScene(64, 48, [Trajectory("exp", 3_000, 2.5, 4_000)], log_level=4.0)
    frames = [scene.frame(crf, 0, 8_000), scene.frame(crf, 20_000, 22_000, seq=1)]
    params = TediParams(C_ON, C_OFF)
    out = []
    for force_general in (False, True):
        est = PeripheralEstimator(SENSOR, params, crf)
        est.whole = not force_general
        fes = [r for pk in interleave(scene.events(C_ON, C_OFF), frames) if (r := est.feed(pk)) is not None]
        out.append(([f.log_e[0] for f in fes], est.predict(40_000)))
    assert np.allclose(out[0][0], out[1][0], atol=1e-9)
    assert out[0][1] == pytest.approx(out[1][1], abs=1e-9)


def test_compensation_adds_the_documented_term():
    """Forward prediction applies c (n + max(0, a n - b u)) per pixel and averages (Eq. 11; the term as in
    docs/method.md); with equal counts on every pixel that is the term of the mean count."""
    sensor = SensorGeometry(4, 1)
    params = TediParams(0.2, 0.3, a_on=0.5, b_on=1_000.0, a_off=0.0, b_off=0.0)
    est = PeripheralEstimator(sensor, params, options=PeripheralOptions(image_form="mean_log"))
    img = np.full((1, 4), 128, np.uint8)
    est.begin_exposure(0)
    est.end_exposure(1_000)
    est.add_frame(Frame(img, 0, 1_000))
    base = est.predict(1_000)
    # 8 ON events (2 per pixel) at t = 1500 µs: m = 2, u = 1500 µs -> comp = max(0, 1 - 1.5) = 0
    est.update(make_events([1_500] * 8, [0, 1, 2, 3] * 2, [0] * 8, [1] * 8))
    assert est.predict(1_500) - base == pytest.approx(0.2 * 2)
    # 40 more (m = 12) by 2000 µs: comp = 0.5 * 12 - 1000e-6 * 2000 = 4 -> 0.2 * (12 + 4)
    est.update(make_events([2_000] * 40, [0, 1, 2, 3] * 10, [0] * 40, [1] * 40))
    assert est.predict(2_000) - base == pytest.approx(0.2 * 16)
    # the compensation fades as time passes without events (u grows): back to 0.2 * 12 at u >= 6 ms
    assert est.predict(10_000) - base == pytest.approx(0.2 * 12)
    # unequal counts: 10 more on pixel 0 only (m = 22, 12, 12, 12; mean 14.5). Pixel 0 is still compensated
    # at u = 10 ms (0.5 * 22 - 10 = 1, mean 0.25) and 8 ms (3, mean 0.75), the mean count's term is 0 at both
    est.update(make_events([10_000] * 10, [0] * 10, [0] * 10, [1] * 10))
    assert est.predict(10_000) - base == pytest.approx(0.2 * (14.5 + 0.25))
    assert est.predict(8_000) - base == pytest.approx(0.2 * (14.5 + 0.75))


def test_stream_errors_are_clear(crf):
    est = PeripheralEstimator(SENSOR, PARAMS, crf)
    with pytest.raises(NotAnchoredError, match="no anchor"):
        est.predict(0)
    est.update(make_events([10, 20], [1, 2], [1, 2], [1, -1]))
    with pytest.raises(EventFormatError, match="earlier than events already processed"):
        est.update(make_events([15], [1], [1], [1]))
    with pytest.raises(StreamError, match="after events up to 20"):
        est.begin_exposure(5)
    est.begin_exposure(30)
    with pytest.raises(StreamError, match="has not ended"):
        est.begin_exposure(40)
    est.end_exposure(50)
    img = np.full((48, 64), 100, np.uint8)
    with pytest.raises(StreamError, match="not announced"):
        est.add_frame(Frame(img, 31, 50))
    with pytest.raises(FrameFormatError, match="sensor is 64x48"):
        est.add_frame(Frame(np.zeros((10, 10), np.uint8), 30, 50))
    est.add_frame(Frame(img, 30, 50))
    with pytest.raises(ParameterError, match="precedes the anchor"):
        est.predict(10)
    with pytest.raises(StreamError, match="without a matching start"):
        est.end_exposure(60)
    zoned = PeripheralEstimator(SENSOR, PARAMS, crf, options=PeripheralOptions(grid=(2, 2)))
    bad = np.zeros(2, dtype=make_events([], [], [], []).dtype)
    bad["t"] = [1, 2]
    bad["x"] = [3, 70]
    bad["p"] = 1
    with pytest.raises(EventFormatError, match="outside the 64x48 sensor; the 1 events before it were applied"):
        zoned.update(bad)
    assert zoned.counts_on.sum() == 1
    with pytest.raises(ParameterError):
        TediParams(c_on=float("nan"))
    with pytest.raises(ParameterError, match="image_form"):
        PeripheralEstimator(SENSOR, PARAMS, crf, options=PeripheralOptions(image_form="median"))
    with pytest.raises(ParameterError, match="rectangle"):
        PeripheralEstimator(SENSOR, PARAMS, crf, options=PeripheralOptions(rectangle=(0, 0, 100, 10)))


@pytest.mark.parametrize("form", ["paper", "mean_log"])
def test_image_side_zone_path_agrees_with_whole_sensor_path(form, crf):
    scene = AnalyticScene(64, 48, [Trajectory("flat")], log_level=6.0)
    frame = scene.frame(crf, 0, 900)
    est = PeripheralEstimator(SENSOR, PARAMS, crf, options=PeripheralOptions(image_form=form))
    whole = est.frame_log_irradiance(frame)
    est.whole = False  # force the per-zone (bincount) path on the same single zone
    general = est.frame_log_irradiance(frame)
    assert np.allclose(whole[0], general[0], atol=1e-12) and np.allclose(whole[1], general[1])
    assert abs(whole[0][0] - _truth(scene, 0, form)) < 0.02


def test_saturated_frame_bounds_the_estimate_when_events_were_lost(crf):
    """Events lost (here: 80 % dropped, as at the sensor's rate ceiling) make the propagated estimate
    too low; an over-exposed frame proves a lower bound, and P-TEDI re-anchors there."""
    scene = AnalyticScene(64, 48, [Trajectory("step", 31_000, 4.0)], log_level=5.0)
    ev = scene.events(C_ON, C_OFF)
    kept = ev[np.random.default_rng(0).random(ev.size) < 0.2]
    frames = _frames(scene, crf, range(0, 100_000, 20_000), exposure_us=4_000)
    est = PeripheralEstimator(SENSOR, PARAMS, crf)
    fes = [r for pk in interleave(kept, frames) if (r := est.feed(pk)) is not None]
    assert [bool(f.anchored[0]) for f in fes] == [True, True, False, False, False]
    assert bool(fes[2].bounded[0]) and fes[2].over_fraction[0] > 0.5
    truth = scene.log_mean_irradiance(99_000)
    # the frame-only bound is below the truth (clipping) but far above the event-only estimate
    event_only = fes[1].log_anchor[0] + 0.2 * 4.0
    assert event_only < est.predict(99_000) <= truth + TOL
    assert est.frames_bounded >= 1


@pytest.mark.parametrize("zoned", [False, True])
@pytest.mark.parametrize("form", ["paper", "mean_log"])
def test_saturation_bounds_are_what_a_clipped_frame_proves(zoned, form, crf):
    """A frame clipped at both ends never pulls the anchor down to its own (invalid) g(mean Z); with the
    paper's form it may only raise it to its linear lower bound (under-exposed pixels counted as
    receiving nothing). Clipped at one end only, it bounds from that side."""
    sensor = SensorGeometry(20, 10)
    anchored_frame = np.full((10, 20), 128, np.uint8)

    def frame_with(fractions):  # {digit: fraction of the 200 pixels}
        z = np.concatenate([np.full(round(f * 200), d, np.uint8) for d, f in fractions.items()])
        return z.reshape(10, 20)

    paper = form == "paper"
    cases = [  # (image, expected bounded); no events, so the prediction at s is the first anchor
        # two-sided, reads brighter: paper form raises the anchor to the linear lower bound; mean_log: nothing
        (frame_with({255: 0.40, 0: 0.35, 200: 0.25}), paper),
        # two-sided, reads darker by g(mean Z), yet 35 % over-exposed proves it brighter on average: paper form
        # raises the anchor to the linear lower bound; it never lowers it (no upper bound with 35 % over-exposed)
        (frame_with({255: 0.35, 0: 0.40, 40: 0.25}), paper),
        (frame_with({255: 0.60, 200: 0.40}), True),  # over-exposed only: a lower bound above the prediction
        (frame_with({255: 0.60, 0: 0.04, 200: 0.36}), True),  # essentially one-sided (4 % at the other end)
        (frame_with({0: 0.60, 40: 0.40}), True),  # under-exposed only: an upper bound below the prediction
    ]
    for image, expect in cases:
        est = PeripheralEstimator(sensor, PARAMS, crf, options=PeripheralOptions(image_form=form))
        est.whole = not zoned  # zoned: the per-zone (bincount) image path on the same single zone
        est.begin_exposure(0)
        est.end_exposure(1_000)
        first = est.add_frame(Frame(anchored_frame, 0, 1_000))
        assert first.anchored[0]
        est.begin_exposure(10_000)
        est.end_exposure(11_000)
        fe = est.add_frame(Frame(image, 10_000, 11_000, 1.0, 1))
        assert not fe.anchored[0] and fe.valid_fraction[0] < 0.5
        assert bool(fe.bounded[0]) == expect
        if expect:
            assert est.anchor_t[0] == 10_000
            lo, hi = est.frame_bounds(Frame(image, 10_000, 11_000, 1.0, 1))
            moved = est.anchor_log[0] - first.log_anchor[0]
            if moved > 0:  # raised to a lower bound (at most the truth: see the property test below)
                assert est.anchor_log[0] == pytest.approx(lo[0] - fe.log_e[0])
            else:  # lowered to an upper bound
                assert est.anchor_log[0] == pytest.approx(hi[0] - fe.log_e[0]) and moved < 0
        else:
            assert est.anchor_t[0] == 0 and est.anchor_log[0] == first.log_anchor[0]
            assert abs(fe.log_anchor[0] - first.log_anchor[0]) > 0.1  # the frame disagrees, and is ignored


@settings(max_examples=80, deadline=None)
@given(st.lists(st.floats(-6.0, 6.0), min_size=20, max_size=200), st.floats(-4.0, 2.0))
def test_the_lower_bound_never_exceeds_the_truth(log_l, log_t):
    """For any scene and exposure, the paper-form lower bound is at most ln(mean irradiance) (noiseless frames)."""
    crf = default_davis346()
    sensor = SensorGeometry(len(log_l), 1)
    lin = np.exp(np.asarray(log_l))
    exposure_us = math.exp(log_t) * 1e6
    z = np.clip(np.rint(crf.intensity(np.asarray(log_l) + log_t)), 0, 255).astype(np.uint8).reshape(1, -1)
    est = PeripheralEstimator(sensor, PARAMS, crf)
    frame = Frame(z, 0, max(1, int(round(exposure_us))))
    lo, hi = est.frame_bounds(frame)
    truth = math.log(lin.mean())
    t_used = math.log(frame.exposure_us / 1e6)
    slack = 0.03 + abs(t_used - log_t)  # the digit rounding and the integer µs of the exposure
    if np.isfinite(lo[0]):
        assert lo[0] <= truth + slack
    if np.isfinite(hi[0]) and not (z > crf.valid_max).any():  # (a few hot pixels are tolerated, not bounded)
        assert hi[0] >= truth - slack

    with pytest.raises(ParameterError, match="one_sided_clip"):
        PeripheralEstimator(SensorGeometry(20, 10), PARAMS, crf, options=PeripheralOptions(one_sided_clip=1.5))
