"""NEC's metering statistics, their event-driven propagation, the escape rule and the measured defaults.

Independent truths: quantiles of continuous digits whose distribution is known in closed form; the
order-statistics fact that clipping cannot move a quantile whose rank lies among unclipped pixels
and only bounds it otherwise; a global lighting step that moves every pixel (hence every statistic)
by the same known amount; and a closed loop on a two-level scene where the answer is known.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from necviz.core.control import CameraLimits, NECController, NECOptions, make_controller
from necviz.core.control.nec import METERING, censored_quantiles, update_offset, update_offsets, weighted_median
from necviz.core.errors import ParameterError
from necviz.core.event_model import TediParams
from necviz.core.events import EventBatch, make_events
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.ptedi import PeripheralEstimator
from necviz.core.sensor import SensorGeometry

SENSOR = SensorGeometry(48, 32)
C_ON, C_OFF = 0.26, 0.24


def _hist(z):
    return np.bincount(np.asarray(z, np.int64).ravel(), minlength=256)


# -- the censored statistics -------------------------------------------------------------------------
def test_median_of_evenly_spread_digits_is_exact(crf):
    """Continuous digits spread evenly over [20.5, 120.5) and rounded: every bin holds the same count,
    the in-bin interpolation is exact, and the median digit is 70.5."""
    u = np.linspace(20.5, 120.5, 100_000, endpoint=False)
    v, side = censored_quantiles(_hist(np.floor(u + 0.5)), 0.5, crf.g, 9, 250)
    assert side[0] == 0
    assert v[0] == pytest.approx(crf.log_exposure(70.5), abs=1e-9)
    v, side = censored_quantiles(_hist(np.floor(u + 0.5)), 0.9, crf.g, 9, 250)
    assert side[0] == 0 and v[0] == pytest.approx(crf.log_exposure(110.5), abs=1e-9)


def test_two_level_image_gives_the_level_of_the_majority(crf):
    """70 % shadow at 40 DN, 30 % sun clipped at 255: the median is a shadow value, the 95th percentile
    is only bounded below by the top of the valid range."""
    z = np.r_[np.full(7000, 40), np.full(3000, 255)]
    v, side = censored_quantiles(_hist(z), 0.5, crf.g, 9, 250)
    assert side[0] == 0 and crf.log_exposure(39.5) <= v[0] <= crf.log_exposure(40.5)
    v, side = censored_quantiles(_hist(z), 0.95, crf.g, 9, 250)
    assert side[0] == 1 and v[0] == pytest.approx(crf.log_exposure(249.5))
    # the paper's g(mean Z) is pulled 0.88 ln above the shadows by the clipped minority (mean 104.5 DN)
    assert crf.log_exposure(z.mean()) - crf.log_exposure(40) > 0.8


def test_sixty_percent_clipped_bounds_the_median_from_the_right_side(crf):
    over = np.r_[np.full(6000, 255), np.full(4000, 100)]
    v, side = censored_quantiles(_hist(over), 0.5, crf.g, 9, 250)
    assert side[0] == 1 and v[0] == pytest.approx(crf.log_exposure(249.5))
    under = np.r_[np.full(6000, 0), np.full(4000, 100)]
    v, side = censored_quantiles(_hist(under), 0.5, crf.g, 9, 250)
    assert side[0] == -1 and v[0] == pytest.approx(crf.log_exposure(9.5))
    v, side = censored_quantiles(np.zeros(256), 0.5, crf.g, 9, 250)
    assert side[0] == 2 and math.isnan(v[0])


@settings(max_examples=60, deadline=None)
@given(st.floats(-1.5, 1.5), st.floats(0.2, 2.5), st.floats(0.05, 0.95), st.integers(0, 2**31))
def test_clipping_never_moves_a_determined_quantile_and_bounds_the_others(shift, spread, q, seed):
    """The same continuous digits seen by a camera that clips at 9/250 and by one that does not:
    where the clipped histogram says "determined" the two quantiles agree; where it says "bound",
    the unclipped quantile lies on the stated side."""
    rng = np.random.default_rng(seed)
    from necviz.core.crf import default_davis346

    crf = default_davis346()
    # a two-population scene in log exposure (a sun/shadow frame), mapped to continuous digits
    h = np.where(rng.random(20_000) < 0.3, 1.5, -1.0) + shift + spread * rng.standard_normal(20_000) * 0.5
    u = np.asarray(crf.intensity(h))  # continuous digit (0..255)
    z_raw = np.floor(u + 0.5).clip(0, 255)
    ext_g = crf.g
    wide, _ = censored_quantiles(_hist(z_raw), q, ext_g, 0, 255)  # nothing censored inside 1..254
    raw_ok = (z_raw > 0).all() and (z_raw < 255).all()
    v, side = censored_quantiles(_hist(z_raw), q, crf.g, 9, 250)
    if side[0] == 0:
        assert v[0] == pytest.approx(wide[0], abs=1e-12)
    elif side[0] == 1 and raw_ok:
        assert wide[0] >= v[0] - 1e-12
    elif side[0] == -1 and raw_ok:
        assert wide[0] <= v[0] + 1e-12


def test_weighted_median():
    assert weighted_median(np.array([1.0, 5.0, 2.0]), np.ones(3)) == 2.0
    assert weighted_median(np.array([1.0, 5.0, 2.0]), np.array([1.0, 5.0, 1.0])) == 5.0
    assert weighted_median(np.array([np.nan, 3.0]), np.ones(2)) == 3.0
    assert math.isnan(weighted_median(np.array([np.nan]), np.ones(1)))


# -- propagation between frames -----------------------------------------------------------------------
def _two_level_log_exposure(rng):
    """Log exposure: 70 % shadow around -1.2, 30 % sun 2.5 ln brighter (clipped), texture 0.3 ln."""
    hgt, wd = SENSOR.height, SENSOR.width
    xx = np.arange(wd)[None, :].repeat(hgt, 0)
    return np.where(xx < 0.3 * wd, 1.3, -1.2) + 0.3 * rng.standard_normal((hgt, wd))


def _two_level_image(crf, exposure_us, rng, h=None):
    h = _two_level_log_exposure(rng) if h is None else h
    return np.clip(np.rint(np.asarray(crf.intensity(h))), 0, 255).astype(np.uint8)


def _feed_frame(nec, image, s, e):
    nec.feed(ExposureMarker(s, "start"))
    nec.feed(ExposureMarker(e, "end"))
    return nec.feed(Frame(image, s, e, 1.0, s // 1000))


def _controller(metering, crf, **kw):
    return make_controller(
        "nec",
        sensor=SENSOR,
        limits=CameraLimits(1, 20_000, 8.0),
        exposure_us=1_000,
        crf=crf,
        tedi=TediParams(C_ON, C_OFF),
        metering=metering,
        **kw,
    )


@pytest.mark.parametrize("metering", METERING)
def test_a_global_step_moves_every_statistic_by_the_event_measured_change(metering, crf):
    """k ON events on every pixel (a global step of k c_on) move M by exactly k c_on in every mode; a
    frame then taken at the new level with the exposure cut by the same factor re-measures the
    same M (the propagated value was right)."""
    rng = np.random.default_rng(3)
    nec = _controller(metering, crf)
    img = _two_level_image(crf, 1_000, rng)
    _feed_frame(nec, img, 0, 1_000)
    before = nec.metered(2_000)
    k = 4
    npix = SENSOR.width * SENSOR.height
    pix = np.tile(np.arange(npix), k)
    t = 2_000 + (np.arange(pix.size) * 1_000) // pix.size
    nec.feed(EventBatch(make_events(t, pix % SENSOR.width, pix // SENSOR.width, np.ones(pix.size, np.int8))))
    after = nec.metered(3_100)
    assert after - before == pytest.approx(k * C_ON, abs=1e-9)
    # the same image at an exposure shortened by exp(k c_on): the light rose by exactly that much
    e2 = 4_000 + round(1_000 * math.exp(-k * C_ON))
    _feed_frame(nec, img, 4_000, e2)
    remeasured = nec.metered(e2)
    assert remeasured == pytest.approx(after, abs=0.02)  # up to the exposure's rounding to whole µs


def test_paper_metering_is_p_tedi_itself(crf):
    nec = _controller("paper", crf)
    _feed_frame(nec, _two_level_image(crf, 1_000, np.random.default_rng(1)), 0, 1_000)
    assert nec.metered(1_500) == nec.estimator.predict(1_500)


def test_median_meters_the_majority_where_paper_meters_the_mean_exposure(crf):
    """Same two-level frame: the median puts the shadows (70 %) at the goal; the paper's g(mean Z) is
    dragged up by the clipped sun and would under-expose the shadows."""
    h = _two_level_log_exposure(np.random.default_rng(2))
    img = _two_level_image(crf, 1_000, None, h)
    m = {}
    for metering in ("paper", "median"):
        nec = _controller(metering, crf, goal_mode="paper")
        _feed_frame(nec, img, 0, 1_000)
        m[metering] = nec.metered(1_000)
    median = float(np.median(h)) - math.log(1e-3)  # ln L of the median pixel: a shadow pixel
    assert abs(m["median"] - median) < 0.03  # up to the 8-bit quantisation
    assert m["paper"] - median > 0.5


def test_censored_median_keeps_its_offset_inside_the_bound(crf):
    """A frame 60 % over-exposed proves only 'median >= top of the range': the metered value rises to
    that bound when it lay below, and stays where it was when it lay above."""
    nec = _controller("median", crf)
    img = _two_level_image(crf, 1_000, np.random.default_rng(4))
    _feed_frame(nec, img, 0, 1_000)
    top = float(crf.log_exposure(249.5)) - math.log(1e-3)
    assert nec.metered(1_000) < top
    over = np.where(np.arange(SENSOR.width)[None, :] < 0.6 * SENSOR.width, 255, 100).repeat(SENSOR.height, 0)
    _feed_frame(nec, over.astype(np.uint8), 2_000, 3_000)
    assert nec.metered(3_000) >= top - 1e-9
    assert nec.escape_direction in (0, 1)


def test_metering_options_are_checked(crf):
    with pytest.raises(ParameterError, match="metering"):
        _controller("mean", crf)
    with pytest.raises(ParameterError, match="zone grid"):
        NECController(
            PeripheralEstimator(SENSOR, TediParams(C_ON, C_OFF), crf),
            CameraLimits(),
            options=NECOptions(metering="zones"),
        )
    with pytest.raises(ParameterError, match="goal_mode"):
        _controller("median", crf, goal_mode="bright")
    nec = _controller("percentile", crf)
    with pytest.raises(ParameterError, match="floor < goal < highlight"):
        nec.set_param("goal", 240)


def test_nec_raw_keeps_the_metering_and_goal_of_nec(crf):
    tedi = TediParams(C_ON, C_OFF, 0.5, 25.0, 0.4, 20.0)
    kw = dict(sensor=SENSOR, limits=CameraLimits(1, 20_000, 8.0), crf=crf, tedi=tedi)
    nec, raw = make_controller("nec", **kw), make_controller("nec-raw", **kw)
    assert (nec.options.metering, nec.goal_log_exposure, nec.options.escape, nec.options.edge_margin) == (
        raw.options.metering,
        raw.goal_log_exposure,
        raw.options.escape,
        raw.options.edge_margin,
    )
    assert raw.estimator.params.a_on == 0.0 and nec.estimator.params.a_on == tedi.a_on


# -- closed loop ---------------------------------------------------------------------------------------
def test_the_default_beats_paper_metering_on_a_two_level_scene(crf):
    """A shadowed facade with a sunlit band over 30 % of the view, 50 dB apart (more than any exposure
    records): the paper's g(mean Z) exposes for the mean exposure, which the sun dominates, and leaves
    the shadows (70 %) under-exposed in every frame; the default metering records the majority."""
    from necviz.drivers.sim.aps import ApsParams
    from necviz.drivers.sim.rig import SimRig
    from necviz.drivers.sim.scene import FunctionScene, db_to_log

    sensor = SensorGeometry(64, 48)
    yy, xx = np.mgrid[0:48, 0:64]
    tex = 0.3 * np.sin(xx / 3.0) * np.cos(yy / 4.0)

    def facade(t_us, sensor):
        band = xx < 0.3 * 64 + 4 * math.sin(t_us / 1e5)  # the shadow edge sways a little
        return 5.0 + tex + np.where(band, db_to_log(50.0), 0.0)

    scene = FunctionScene(facade, sensor=sensor, duration_us=400_000)
    aps = ApsParams()
    rig = SimRig(scene, ["paper", "default"], aps=aps, crf=crf, seed=2)
    limits = CameraLimits(aps.exposure_min_us, aps.exposure_max_us, aps.gain_max)
    tedi = TediParams(C_ON, C_OFF)
    ctrls = {
        "paper": make_controller(
            "nec",
            sensor=sensor,
            limits=limits,
            exposure_us=rig.cams["paper"].exposure_us,
            crf=crf,
            tedi=tedi,
            metering="paper",
            goal_mode="paper",
            escape=False,
        ),
        "default": make_controller(
            "nec", sensor=sensor, limits=limits, exposure_us=rig.cams["default"].exposure_us, crf=crf, tedi=tedi
        ),
    }
    saturated = {n: 0 for n in ctrls}
    frames = {n: 0 for n in ctrls}
    for name, packet in rig.packets():
        for n in ctrls if name is None else (name,):
            cmd = ctrls[n].feed(packet)
            if cmd is not None:
                rig.set_exposure(n, cmd.exposure_us, cmd.gain)
        if isinstance(packet, Frame) and packet.sequence >= 3:  # after the first frames have been metered
            frames[name] += 1
            z = packet.image
            saturated[name] += int((z <= 9).mean() > 0.5 or (z >= 250).mean() > 0.5)
    assert frames["paper"] >= 12 and frames["default"] == frames["paper"]
    assert saturated["paper"] >= 0.8 * frames["paper"]  # the shadows under-exposed, frame after frame
    assert saturated["default"] == 0


_OFFSET_VALUES = st.one_of(
    st.floats(-20, 20, allow_nan=False), st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.5, 0.5])
)


@settings(max_examples=400, deadline=None)
@given(old=_OFFSET_VALUES, cand=_OFFSET_VALUES, side=st.sampled_from([-1, 0, 1, 2]))
def test_the_single_zone_offset_update_is_the_array_rule_bit_for_bit(old, cand, side):
    """Whole-sensor metering updates its offset on floats (every frame, no array round trips); it must
    give exactly what the per-zone rule gives for one zone, NaN and infinities included."""
    want = update_offsets(np.array([old]), np.array([cand]), np.array([side], np.int8))[0]
    got = update_offset(old, cand, side)
    assert (math.isnan(got) and math.isnan(want)) or got == want
    if not math.isfinite(cand):
        assert got == old or (math.isnan(got) and math.isnan(old))  # a non-finite candidate never moves it
    elif side == 1 and math.isfinite(old):
        assert got >= old  # a lower bound only raises it
    elif side == -1 and math.isfinite(old):
        assert got <= old  # an upper bound only lowers it


def test_whole_sensor_metering_keeps_its_offset_array_and_scalar_in_step():
    """The offset the hot path reads (a float) and the per-zone array the flicker path reads agree after
    every frame of a closed loop."""
    from necviz.core.sensor import DAVIS346
    from necviz.dashboard import pipeline_speed as bench

    events = bench.make_events(0.3, 2.0)
    src = bench.SyntheticStream(events, 0.3)
    ctrl = make_controller("nec", sensor=DAVIS346, limits=CameraLimits(10.0, 19_000, 8.0), exposure_us=2_000.0)
    checked = 0
    for packet in src:
        ctrl.feed(packet)
        if isinstance(packet, Frame):
            assert ctrl._offset.shape == (1,)
            assert ctrl._offset[0] == ctrl._offset0 or (math.isnan(ctrl._offset[0]) and math.isnan(ctrl._offset0))
            checked += math.isfinite(ctrl._offset0)
    assert checked >= 10  # the offset was measured on most of the 15 frames
