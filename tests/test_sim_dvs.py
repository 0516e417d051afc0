"""The DVS event model (ESIM crossings + v2e non-idealities) against closed-form truths.

Truths used: the ESIM invariant (the reference tracks ln L within one threshold, so
``c_on n_on - c_off n_off`` equals the change of ln L to within ``(-c_off, c_on)``);
analytic crossing instants of a linear ramp and of a first-order low-pass step response;
the exact count of a refractory-thinned regular crossing train; Poisson/leak rates.
"""

import math
import time

import numpy as np
import pytest

from necviz.core.errors import ParameterError
from necviz.core.events import EVENT_DTYPE, validate_events
from necviz.core.sensor import DAVIS346, SensorGeometry
from necviz.drivers.sim.dvs import DvsParams, EventSimulator

C_ON, C_OFF = 0.26, 0.24
SMALL = SensorGeometry(40, 30)


def counts(ev, sensor):
    """Per-pixel (n_on, n_off) images of an event batch."""
    on = np.zeros(sensor.shape, np.int64)
    off = np.zeros(sensor.shape, np.int64)
    m = ev["p"] > 0
    np.add.at(on, (ev["y"][m], ev["x"][m]), 1)
    np.add.at(off, (ev["y"][~m], ev["x"][~m]), 1)
    return on, off


def smooth_field(rng, sensor, amp):
    yy, xx = np.mgrid[0 : sensor.height, 0 : sensor.width]
    fx, fy, ph = rng.uniform(0.05, 0.4), rng.uniform(0.05, 0.4), rng.uniform(0, 2 * np.pi)
    return amp * np.sin(fx * xx + ph) * np.cos(fy * yy)


def check_batch(ev, t0, t1, sensor):
    assert ev.dtype == EVENT_DTYPE
    validate_events(ev, sensor)  # sorted, polarity ±1, on the sensor
    if ev.size:
        assert ev["t"].min() > t0 and ev["t"].max() <= t1


# -- fidelity ------------------------------------------------------------------------------------
def test_ideal_tracks_log_intensity_within_one_threshold():
    rng = np.random.default_rng(3)
    sim = EventSimulator(SMALL, DvsParams.ideal(C_ON, C_OFF), seed=1)
    l0 = (5.0 + smooth_field(rng, SMALL, 1.0)).astype(np.float32)
    sim.reset(l0, 1_000)
    n_on = np.zeros(SMALL.shape, np.int64)
    n_off = np.zeros(SMALL.shape, np.int64)
    t = 1_000
    total = 0
    for k in range(120):
        dt = [1, 37, 250, 1_000, 200_000][k % 5]  # includes a long interval (argsort path)
        if k % 7 == 3:  # a stepped image: jumps of several thresholds, both signs
            img = l0 + rng.choice([-2.0, -0.7, 0.0, 0.5, 3.1], size=SMALL.shape)
        else:
            img = l0 + smooth_field(rng, SMALL, 2.0) + rng.normal(0, 0.05, SMALL.shape)
        img = img.astype(np.float32)
        ev = sim.step(img, t + dt)
        check_batch(ev, t, t + dt, SMALL)
        on, off = counts(ev, SMALL)
        n_on += on
        n_off += off
        total += ev.size
        err = (img.astype(np.float64) - l0) - (C_ON * n_on - C_OFF * n_off)
        assert err.max() < C_ON + 1e-6 and err.min() > -C_OFF - 1e-6, f"step {k}: error {err.min()}..{err.max()}"
        t += dt
    assert total > 10_000
    assert sim.events_emitted == total == sim.events_generated
    assert sim.dropped_by_ceiling == 0 and sim.dropped_by_refractory == 0


def test_multiple_thresholds_in_one_interval_and_back():
    s = SensorGeometry(3, 2)
    sim = EventSimulator(s, DvsParams.ideal(0.25, 0.25), seed=0)
    base = np.full(s.shape, 4.0, np.float32)
    sim.reset(base, 0)
    ev = sim.step(base + np.float32(1.1), 100)  # 4 ON per pixel, times at 0.25/1.1 ... of the interval
    assert ev.size == 4 * 6 and np.all(ev["p"] == 1)
    expect = np.round(100 * np.arange(1, 5) * 0.25 / 1.1).astype(int)
    for x in range(3):
        for y in range(2):
            tt = ev["t"][(ev["x"] == x) & (ev["y"] == y)]
            np.testing.assert_array_equal(tt, expect)
    ev = sim.step(base, 200)  # reference at +1.0: 4 OFF back down to +0.0
    assert ev.size == 4 * 6 and np.all(ev["p"] == -1)


def test_linear_ramp_gives_evenly_spaced_events_at_the_analytic_instants():
    s = SensorGeometry(5, 4)
    rate = 0.26 / 713.0  # one ON threshold every 713 µs
    sim = EventSimulator(s, DvsParams.ideal(0.26, 0.24), seed=0)
    base = np.linspace(2.0, 3.0, s.num_pixels).reshape(s.shape)  # ramp is the same at every pixel
    sim.reset(base.astype(np.float32), 0)
    evs = []
    for t in range(300, 40_001, 300):
        evs.append(sim.step((base + rate * t).astype(np.float32), t))
    ev = np.concatenate(evs)
    n_expect = int(39_900 // 713)  # last sample at 39,900 µs
    for x in range(5):
        for y in range(4):
            tt = ev["t"][(ev["x"] == x) & (ev["y"] == y)]
            assert tt.size == n_expect
            exact = 713.0 * np.arange(1, n_expect + 1)
            # float32 ln L carries ~2e-7 error at ln L ~ 3: under 1 µs of timing error here
            assert np.max(np.abs(tt - exact)) <= 1.0
    assert np.all(ev["p"] == 1)


# -- threshold mismatch -------------------------------------------------------------------------
def test_threshold_mismatch_statistics_and_own_threshold_tracking():
    s = SensorGeometry(100, 80)
    p = DvsParams.ideal(C_ON, C_OFF, sigma_threshold=0.03)
    sim = EventSimulator(s, p, seed=5)
    th_on, th_off = sim.threshold_on, sim.threshold_off
    assert abs(th_on.std() - 0.03) < 0.002 and abs(th_off.std() - 0.03) < 0.002
    assert abs(th_on.mean() - C_ON) < 0.002 and abs(th_off.mean() - C_OFF) < 0.002
    assert abs(np.corrcoef(th_on.ravel(), th_off.ravel())[0, 1]) < 0.05  # independent draws
    base = np.full(s.shape, 5.0, np.float32)
    sim.reset(base, 0)
    # a slow rise by 2.0 then a fall by 1.3: counts are exactly floor(change / own threshold)
    ev_up = np.concatenate([sim.step(base + np.float32(2.0 * k / 20), 100 * k) for k in range(1, 21)])
    on, off = counts(ev_up, s)
    assert off.sum() == 0
    np.testing.assert_array_equal(on, np.floor(2.0 / th_on))
    ref_up = on * th_on  # the reference after the rise
    ev_dn = sim.step(base + np.float32(0.7), 3_000)
    on2, off2 = counts(ev_dn, s)
    assert on2.sum() == 0
    err = (0.7 - ref_up) + off2 * th_off  # ln L change minus the reference's change
    assert err.max() < 1e-5 and err.min() > -th_off.max()
    np.testing.assert_array_equal(off2, np.floor((ref_up - 0.7) / th_off).clip(0))


def test_mismatch_is_clamped_at_a_hundredth():
    s = SensorGeometry(50, 50)
    sim = EventSimulator(s, DvsParams.ideal(0.1, 0.1, sigma_threshold=0.1), seed=0)
    assert sim.threshold_on.min() == pytest.approx(0.01) and sim.threshold_off.min() == pytest.approx(0.01)
    assert np.mean(sim.threshold_on == 0.01) > 0.1  # ~16 % of N(0.1, 0.1) falls below 0.01


# -- refractory period --------------------------------------------------------------------------
def test_refractory_drops_events_by_the_predicted_amount():
    s = SensorGeometry(6, 5)
    c, spacing, refr, dur = 0.25, 30.0, 100.0, 12_000
    rate = c / spacing  # one crossing every 30 µs
    base = np.full(s.shape, 3.0)

    def run(refractory):
        sim = EventSimulator(s, DvsParams.ideal(c, c, refractory_us=refractory), seed=0)
        sim.reset(base.astype(np.float32), 0)
        ev = np.concatenate([sim.step((base + rate * t).astype(np.float32), t) for t in range(250, dur + 1, 250)])
        return sim, ev

    free_sim, free = run(0.0)
    sim, ev = run(refr)
    n_cross = int(dur // spacing)
    assert free.size == n_cross * s.num_pixels
    # emitted: crossings k = 1, 5, 9, ... (ceil(100/30) = 4 crossings per emitted event)
    kept_k = np.arange(1, n_cross + 1, 4)
    assert ev.size == kept_k.size * s.num_pixels
    assert sim.dropped_by_refractory == (n_cross - kept_k.size) * s.num_pixels
    assert sim.crossings == free_sim.crossings == n_cross * s.num_pixels
    for x in range(s.width):
        for y in range(s.height):
            tt = ev["t"][(ev["x"] == x) & (ev["y"] == y)]
            assert np.diff(tt).min() >= refr
            assert np.max(np.abs(tt - spacing * kept_k)) <= 1
    # the reference still advanced: after the ramp stops, the pixel is quiet
    assert sim.step((base + rate * dur).astype(np.float32), dur + 1_000).size == 0


# -- bandwidth ceiling --------------------------------------------------------------------------
def test_rate_ceiling_keeps_a_uniform_random_subset():
    s = SensorGeometry(100, 100)
    sim = EventSimulator(s, DvsParams.ideal(0.25, 0.25, max_event_rate=1e6), seed=0)
    base = np.full(s.shape, 5.0, np.float32)
    sim.reset(base, 0)
    ev = ev_first = sim.step(base + np.float32(0.3), 1_000)  # 10,000 events, ceiling 1e6 * 1 ms = 1,000
    assert ev.size == 1_000
    assert sim.dropped_by_ceiling == 9_000 and sim.events_generated == 10_000 and sim.events_emitted == 1_000
    check_batch(ev, 0, 1_000, s)
    # uniform over the array, not the first pixels in memory order
    assert 40 < ev["y"].mean() < 60 and 40 < ev["x"].mean() < 60
    assert np.unique(ev["y"].astype(int) * 100 + ev["x"]).size == 1_000
    # references advanced for dropped events too: holding the level gives nothing
    assert sim.step(base + np.float32(0.3), 2_000).size == 0
    ev = sim.step(base, 2_010)  # 10 µs: at most 10 events
    assert ev.size == 10 and sim.dropped_by_ceiling == 9_000 + 9_990
    # a different seed keeps a different subset
    sim2 = EventSimulator(s, DvsParams.ideal(0.25, 0.25, max_event_rate=1e6), seed=1)
    sim2.reset(base, 0)
    ev2 = sim2.step(base + np.float32(0.3), 1_000)
    first = np.sort(sim_first := ev_first["y"].astype(int) * 100 + ev_first["x"])
    assert ev2.size == 1_000 and sim_first.size == 1_000
    assert not np.array_equal(np.sort(ev2["y"].astype(int) * 100 + ev2["x"]), first)


# -- photoreceptor low-pass ---------------------------------------------------------------------
def _lowpass_step_times(level, jump=2.5, cutoff=300.0, dt=10, dur=40_000, c=0.26):
    s = SensorGeometry(2, 2)
    sim = EventSimulator(s, DvsParams.ideal(c, c, cutoff_hz=cutoff), seed=0)
    l0 = np.full(s.shape, level, np.float32)
    l1 = l0 + np.float32(jump)
    sim.reset(l0, 0)
    ev = np.concatenate([sim.step(l1, t) for t in range(dt, dur + 1, dt)])
    return ev[(ev["x"] == 0) & (ev["y"] == 0)], float(l1[0, 0])


def _inten01(log_l, ref=5.5):
    u = min(1.0, math.exp(log_l - ref))
    return (u + 20 / 255) / (1 + 20 / 255)


@pytest.mark.parametrize("level", [6.0, -2.0])
def test_lowpass_spreads_a_step_like_a_first_order_filter(level):
    ev, l1 = _lowpass_step_times(level)
    tau = 1e6 / (2 * math.pi * 300.0) / _inten01(l1)
    j = np.arange(1, 10)
    expect = -tau * np.log(1 - j * 0.26 / 2.5)  # lp(t) = L1 - 2.5 exp(-t / tau), 9.6 thresholds
    assert ev.size == 9 and np.all(ev["p"] == 1)
    np.testing.assert_allclose(ev["t"], expect, rtol=2e-3, atol=2.0)


def test_lowpass_is_slower_in_the_dark_and_off_means_instant():
    bright, _ = _lowpass_step_times(6.0)
    dark, _ = _lowpass_step_times(-2.0)
    tau = 1e6 / (2 * math.pi * 300.0)
    assert 0.5 * tau < bright["t"][4] < 1.5 * tau  # ~ 1/(2 pi f) in the bright (0.69 tau for j = 5)
    assert dark["t"][4] > 10 * bright["t"][4]
    s = SensorGeometry(2, 2)
    sim = EventSimulator(s, DvsParams.ideal(0.26, 0.26), seed=0)
    l0 = np.full(s.shape, 6.0, np.float32)
    sim.reset(l0, 0)
    ev = sim.step(l0 + np.float32(2.6), 10)
    assert ev.size == 4 * 10 and ev["t"].max() <= 10  # unfiltered: all within the first sample


def test_lowpass_disabled_by_zero_cutoff():
    a = EventSimulator(SMALL, DvsParams.ideal(cutoff_hz=0.0), seed=0)
    b = EventSimulator(SMALL, DvsParams.ideal(cutoff_hz=None), seed=0)
    rng = np.random.default_rng(0)
    l0 = (5 + smooth_field(rng, SMALL, 1.0)).astype(np.float32)
    a.reset(l0, 0)
    b.reset(l0, 0)
    for t in (100, 200, 300):
        img = (l0 + smooth_field(rng, SMALL, 1.5)).astype(np.float32)
        np.testing.assert_array_equal(a.step(img, t), b.step(img, t))


# -- noise --------------------------------------------------------------------------------------
def test_leak_rate_static_scene():
    s = SensorGeometry(64, 64)
    sim = EventSimulator(s, DvsParams.ideal(leak_hz=2.0), seed=0)
    base = np.full(s.shape, 5.0, np.float32)
    sim.reset(base, 0)
    dur = 5_000_000
    ev = np.concatenate([sim.step(base, t) for t in range(5_000, dur + 1, 5_000)])
    assert np.all(ev["p"] == 1)  # leak makes ON events
    expected = s.num_pixels * 2.0 * dur / 1e6  # uniform random phase: exact in expectation
    assert abs(ev.size - expected) < 0.01 * expected
    # regular per pixel: interval = 1 / rate
    tt = ev["t"][(ev["x"] == 3) & (ev["y"] == 7)]
    np.testing.assert_allclose(np.diff(tt), 500_000, atol=2)
    # not synchronised across the array
    assert np.unique(ev["t"] // 5_000).size > 500


def test_leak_rate_with_per_pixel_spread():
    s = SensorGeometry(64, 64)
    p = DvsParams.ideal(leak_hz=2.0, leak_cov_decades=0.1)
    sim = EventSimulator(s, p, seed=0)
    rates = sim.leak_rate_hz
    assert abs(np.log10(rates / 2.0).std() - 0.1) < 0.01
    base = np.full(s.shape, 5.0, np.float32)
    sim.reset(base, 0)
    ev = np.concatenate([sim.step(base, t) for t in range(10_000, 5_000_001, 10_000)])
    on, _ = counts(ev, s)
    expected = rates * 5.0
    assert abs(on.sum() - expected.sum()) < 0.01 * expected.sum()
    assert np.all(np.abs(on - expected) <= 1.0)  # each pixel: floor(phase + rate T)


@pytest.mark.parametrize("level,factor", [(7.0, 0.25), (-5.0, 1 - 0.75 * _inten01(-5.0))])
def test_shot_noise_rate_depends_on_intensity(level, factor):
    s = SensorGeometry(64, 64)
    rate = 0.5
    sim = EventSimulator(s, DvsParams.ideal(shot_noise_hz=rate), seed=2)
    base = np.full(s.shape, level, np.float32)
    sim.reset(base, 0)
    dur = 10_000_000
    ev = np.concatenate([sim.step(base, t) for t in range(10_000, dur + 1, 10_000)])
    expected = s.num_pixels * rate * factor * dur / 1e6
    assert abs(ev.size - expected) < 4.5 * math.sqrt(expected)
    assert sim.shot_noise_events == ev.size
    n_on = int((ev["p"] > 0).sum())
    assert abs(n_on - ev.size / 2) < 4.5 * math.sqrt(ev.size / 4)
    # uniform in time and over the array
    assert abs(ev["t"].mean() - dur / 2) < 0.03 * dur
    assert abs(ev["x"].mean() - 31.5) < 2 and abs(ev["y"].mean() - 31.5) < 2


def test_default_noise_is_small_and_shot_events_do_not_break_tracking():
    # defaults: 0.001 Hz shot + 0.01 Hz leak -> ~0.01 ev/s/pixel on a static DAVIS346 array
    sim = EventSimulator(DAVIS346, DvsParams(), seed=0)
    base = np.full(DAVIS346.shape, 5.0, np.float32)
    sim.reset(base, 0)
    n = sum(sim.step(base, t).size for t in range(1_000, 2_000_001, 1_000))
    expected = DAVIS346.num_pixels * 2.0 * (0.01 * 1.027 + 0.001 * (1 - 0.75 * _inten01(5.0)))
    assert 0.75 * expected < n < 1.3 * expected


# -- determinism --------------------------------------------------------------------------------
def _noisy_run(seed):
    p = DvsParams(leak_hz=0.5, shot_noise_hz=2.0)
    sim = EventSimulator(SMALL, p, seed=seed)
    rng = np.random.default_rng(0)  # the same scene for every seed
    l0 = (5 + smooth_field(rng, SMALL, 1.0)).astype(np.float32)
    sim.reset(l0, 0)
    out = []
    for t in range(500, 400_001, 500):
        img = (l0 + 0.8 * math.sin(t / 30_000)).astype(np.float32)
        out.append(sim.step(img, t))
    return np.concatenate(out), sim


def test_same_seed_same_events_different_seed_different_noise():
    a, sa = _noisy_run(7)
    b, _ = _noisy_run(7)
    c, sc = _noisy_run(8)
    assert a.size > 1_000 and sa.shot_noise_events > 50
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert not np.array_equal(sa.threshold_on, sc.threshold_on)
    # noise events differ but the signal is the same scene: counts close
    assert abs(a.size - c.size) < 0.1 * a.size


# -- errors -------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kw,word",
    [
        (dict(c_on=float("nan")), "c_on"),
        (dict(c_on=-0.2), "c_on"),
        (dict(c_off=0.0), "c_off"),
        (dict(sigma_threshold=-0.01), "sigma_threshold"),
        (dict(sigma_threshold=1.0), "sigma_threshold"),
        (dict(refractory_us=-1), "refractory_us"),
        (dict(refractory_us=float("inf")), "refractory_us"),
        (dict(cutoff_hz=-300.0), "cutoff_hz"),
        (dict(cutoff_hz=float("nan")), "cutoff_hz"),
        (dict(leak_hz=-0.1), "leak_hz"),
        (dict(shot_noise_hz=float("nan")), "shot_noise_hz"),
        (dict(max_event_rate=0), "max_event_rate"),
        (dict(max_event_rate=-5.0), "max_event_rate"),
        (dict(c_on="0.2"), "c_on"),
        (dict(refractory_us=True), "refractory_us"),
        (dict(bandwidth_ref_log=float("nan")), "bandwidth_ref_log"),
    ],
)
def test_bad_parameters_raise_clear_errors(kw, word):
    with pytest.raises(ParameterError, match=word):
        DvsParams(**kw)


def test_ideal_preset_and_defaults():
    p = DvsParams.ideal()
    assert p.sigma_threshold == 0 and p.refractory_us == 0 and not p.cutoff_hz
    assert p.leak_hz == 0 and p.shot_noise_hz == 0 and p.max_event_rate is None
    d = DvsParams()
    assert (d.c_on, d.c_off, d.sigma_threshold, d.cutoff_hz) == (0.26, 0.24, 0.03, 300.0)
    assert d.max_event_rate == 12e6


def test_bad_steps_raise_clear_errors():
    sim = EventSimulator(SMALL, DvsParams.ideal(), seed=0)
    img = np.full(SMALL.shape, 5.0, np.float32)
    with pytest.raises(ParameterError, match="before reset"):
        sim.step(img, 10)
    sim.reset(img, 100)
    with pytest.raises(ParameterError, match="after the previous"):
        sim.step(img, 100)
    with pytest.raises(ParameterError, match="after the previous"):
        sim.step(img, 50)
    with pytest.raises(ParameterError, match="shape"):
        sim.step(np.full((SMALL.width, SMALL.height), 5.0, np.float32), 200)
    bad = img.copy()
    bad[3, 4] = np.nan
    with pytest.raises(ParameterError, match="NaN"):
        sim.step(bad, 200)
    with pytest.raises(ParameterError, match="whole"):
        sim.step(img, 200.5)
    with pytest.raises(ParameterError, match="NaN"):
        sim.reset(bad, 0)
    with pytest.raises(ParameterError, match="seed"):
        EventSimulator(SMALL, DvsParams(), seed=-1)
    # the failed calls left the simulator usable
    assert sim.step(img + np.float32(0.3), 200).size == SMALL.num_pixels


# -- scale and speed ----------------------------------------------------------------------------
def test_large_step_grows_buffers_and_keeps_every_event():
    sim = EventSimulator(DAVIS346, DvsParams.ideal(0.25, 0.25), seed=0)
    base = np.full(DAVIS346.shape, 5.0, np.float32)
    sim.reset(base, 0)
    ev = sim.step(base + np.float32(1.3), 1_000)  # 5 per pixel: 450k events
    assert ev.size == 5 * DAVIS346.num_pixels
    check_batch(ev, 0, 1_000, DAVIS346)
    on, off = counts(ev, DAVIS346)
    assert np.all(on == 5) and off.sum() == 0


def test_static_step_is_fast_on_a_davis346():
    sim = EventSimulator(DAVIS346, DvsParams(), seed=0)
    rng = np.random.default_rng(0)
    base = (5 + 0.5 * rng.standard_normal(DAVIS346.shape)).astype(np.float32)
    sim.reset(base, 0)
    for t in range(500, 20_001, 500):  # let the filter settle
        sim.step(base, t)
    times = []
    for t in range(20_500, 120_001, 500):
        a = time.perf_counter()
        sim.step(base, t)
        times.append(time.perf_counter() - a)
    assert np.median(times) < 1e-3, f"static step took {np.median(times) * 1e3:.2f} ms"


def test_a_bursts_scratch_buffers_are_let_go_once_it_is_over():
    """A lighting step's burst grows the event buffers; a few hundred quiet steps later they are back
    near their base size (a long live session must not hold every burst's memory). That the events
    do not depend on the buffers is pinned by tests/test_speed_invariance.py."""
    from necviz.drivers.sim.dvs import SHRINK_EVERY

    sim = EventSimulator(DAVIS346, DvsParams(shot_noise_hz=0.0, leak_hz=0.0), seed=1)
    base = np.zeros(DAVIS346.shape)
    sim.reset(base, 0)
    sim.step(base + 3.0, 1_000)  # every pixel crosses its threshold ~10 times (the bus ceiling keeps 12k)
    assert sim.events_generated > 4 * sim._base_cap and sim._buf_t.shape[0] >= sim.events_generated
    for k in range(2 * SHRINK_EVERY):  # the photoreceptor settles at the new level: few events a step
        sim.step(base + 3.0, 2_000 + 1_000 * k)
    assert sim._buf_t.shape[0] <= 4 * sim._base_cap
