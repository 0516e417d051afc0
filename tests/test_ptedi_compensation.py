"""P-TEDI with the TEDI compensation applied per pixel and averaged over the zone (Eq. 11).

Truth: a brute force written here from the model alone. For a reference ``g`` and ``u = t - g``,
pixel ``x`` with ``n±`` events since ``g`` (an event at ``τ`` has happened for ``t > τ``) has

    D(g,t,x) = c+ (n+ + max(0, a+ n+ - b+ u)) - c- (n- + max(0, a- n- - b- u))

and the zone's direct integral is the mean of ``D`` over its pixels. Between two events and two
multiples of ``a±/b±`` every per-pixel term is linear in ``t``, so ``E_p = (1/T) ∫ exp(mean D) dt``
is a sum of exp-of-linear pieces, integrated exactly here piece by piece (endpoints only, no
shared code with the estimator). With one pixel per zone P-TEDI is per-pixel TEDI, so the
exposure integral of :func:`necviz.core.tedi.tedi_exposure_integral` is a second reference.
"""

import numpy as np
import pytest

from necviz.core.event_model import TediParams
from necviz.core.events import EventBatch, make_events
from necviz.core.frames import Frame
from necviz.core.ptedi import PeripheralEstimator, PeripheralOptions
from necviz.core.sensor import SensorGeometry
from necviz.core.stream import interleave
from necviz.core.tedi_kernels import tedi_exposure_integral

W, H = 8, 6
SENSOR = SensorGeometry(W, H)
# knees: ON pixels compensated while faster than 1 event per 300 µs, OFF per 400 µs
PARAMS = TediParams(0.26, 0.24, a_on=0.6, b_on=2_000.0, a_off=0.4, b_off=1_000.0)
EXPOSURES = [(1_000, 5_000), (11_000, 14_000), (21_000, 26_000), (31_000, 33_000), (41_000, 47_000)]


def random_stream(seed, t_end=60_000):
    """Sparse background events plus bursts (one pixel, one polarity, 4-25 events within ~250 µs)."""
    rng = np.random.default_rng(seed)
    n_bg = 400
    t = list(rng.integers(0, t_end, n_bg))
    pix = list(rng.integers(0, W * H, n_bg))
    pol = list(rng.choice([-1, 1], n_bg))
    for _ in range(40):
        t0 = int(rng.integers(0, t_end - 300))
        k = int(rng.integers(4, 26))
        t += list(t0 + np.sort(rng.integers(0, 250, k)))
        pix += [int(rng.integers(0, W * H))] * k
        pol += [int(rng.choice([-1, 1]))] * k
    t = np.array(t)
    order = np.argsort(t, kind="stable")
    pix = np.array(pix)[order]
    return make_events(t[order], pix % W, pix // W, np.array(pol)[order])


def frames():
    img = np.full((H, W), 128, np.uint8)  # valid everywhere: every frame anchors every zone
    return [Frame(img, s, e, 1.0, i) for i, (s, e) in enumerate(EXPOSURES)]


def zone_means(values, zflat, k):
    sel = zflat >= 0
    return np.bincount(zflat[sel], weights=values[sel], minlength=k) / np.bincount(zflat[sel], minlength=k)


def per_pixel_d(ev, g, t, u, p=PARAMS):
    """Brute-force D(g, t, x) for every pixel from the events ``g <= τ`` in ``ev`` (already cut at ``t``)."""
    sel = ev["t"] >= g
    pix = ev["y"][sel].astype(np.int64) * W + ev["x"][sel]
    on = ev["p"][sel] > 0
    n_on = np.bincount(pix[on], minlength=W * H).astype(np.float64)
    n_off = np.bincount(pix[~on], minlength=W * H).astype(np.float64)
    b_on, b_off = p.b_on * 1e-6, p.b_off * 1e-6
    return p.c_on * (n_on + np.maximum(0.0, p.a_on * n_on - b_on * u)) - p.c_off * (
        n_off + np.maximum(0.0, p.a_off * n_off - b_off * u)
    )


def brute_log_e(ev, s, e, zflat, k, p=PARAMS):
    """ln E_p(s) per zone, exactly: pieces between events and the kinks at multiples of a/b."""
    t = ev["t"]
    inside = t[(t > s) & (t < e)].astype(np.float64)
    rates = [bb * 1e-6 / aa for aa, bb in ((p.a_on, p.b_on), (p.a_off, p.b_off)) if aa > 0 and bb > 0]
    kinks = [s + np.arange(1, int((e - s) * r) + 2) / r for r in rates]  # the per-pixel terms' kinks
    bps = np.unique(np.concatenate([[s, e], inside] + kinks))
    bps = bps[(bps >= s) & (bps <= e)]
    total = np.zeros(k)
    for t0, t1 in zip(bps[:-1], bps[1:], strict=True):
        ev0 = ev[(t >= s) & (t <= t0)]  # what has happened on (t0, t1)
        y0 = zone_means(per_pixel_d(ev0, s, t0, t0 - s, p), zflat, k)
        y1 = zone_means(per_pixel_d(ev0, s, t1, t1 - s, p), zflat, k)
        dy = y1 - y0
        with np.errstate(invalid="ignore", divide="ignore"):
            piece = np.where(np.abs(dy) < 1e-12, np.exp(y0) * (1 + dy / 2), (np.exp(y1) - np.exp(y0)) / dy)
        total += piece * (t1 - t0)
    return np.log(total / (e - s))


def mean_count_log_e(ev, s, e, zflat, k, p=PARAMS, n=4000):
    """The old (pre-fix) model for comparison: the compensation applied to the zone-mean counts."""
    ts = s + (np.arange(n) + 0.5) * (e - s) / n
    out = np.zeros(k)
    b_on, b_off = p.b_on * 1e-6, p.b_off * 1e-6
    for tt in ts:
        cur = ev[(ev["t"] >= s) & (ev["t"] < tt)]
        pix = cur["y"].astype(np.int64) * W + cur["x"]
        on = cur["p"] > 0
        m_on = zone_means(np.bincount(pix[on], minlength=W * H).astype(float), zflat, k)
        m_off = zone_means(np.bincount(pix[~on], minlength=W * H).astype(float), zflat, k)
        u = tt - s
        out += np.exp(
            p.c_on * (m_on + np.maximum(0, p.a_on * m_on - b_on * u))
            - p.c_off * (m_off + np.maximum(0, p.a_off * m_off - b_off * u))
        )
    return np.log(out / n)


REGIONS = {
    "whole": {},
    "grid 2x2": {"grid": (2, 2)},
    "grid 3x2": {"grid": (3, 2)},
    "rectangle": {"rectangle": (1, 1, 7, 5), "grid": (2, 1)},
    "pixel zones": {"grid": (W, H)},
}


def run_and_check(seed, region, batch_us, params=PARAMS):
    ev = random_stream(seed)
    est = PeripheralEstimator(SENSOR, params, options=PeripheralOptions(min_valid_fraction=0.5, **REGIONS[region]))
    zflat = est.zmap.ravel().astype(np.int64)
    k = est.num_zones
    n_done = 0
    fes, pred_checks = [], 0
    for i, pk in enumerate(interleave(ev, frames(), batch_us=batch_us)):
        if isinstance(pk, EventBatch):
            est.update(pk.events)
            n_done += len(pk)
            if est.ready and (batch_us is None or i % 3 == 0):
                seen = ev[:n_done]
                t_last = int(seen["t"][-1])
                g = est.anchor_t
                # at the last event, later (compensation fading), and earlier (but after the anchor)
                for t in (t_last, t_last + 150, t_last + 2_000, t_last + 30_000, max(int(g.max()), t_last - 700)):
                    if t < g.max():
                        continue
                    d = {int(gz): zone_means(per_pixel_d(seen, gz, t, t - gz, params), zflat, k) for gz in set(g)}
                    want = np.array([est.anchor_log[z] + d[int(g[z])][z] for z in range(k)])
                    assert np.allclose(est.predict_zones(t), want, rtol=0, atol=1e-9), (region, t)
                    pred_checks += 1
        else:
            fe = est.feed(pk)
            if fe is not None:
                fes.append(fe)
    assert len(fes) == len(EXPOSURES) and all(f.anchored.all() for f in fes)
    assert pred_checks > 20
    return ev, est, zflat, fes


@pytest.mark.parametrize("region", list(REGIONS))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compensated_ptedi_matches_a_per_pixel_brute_force(seed, region):
    """ln E_p (Eq. 13-14) and ln P(t) (Eq. 12) with per-pixel compensation, against the brute force."""
    batch_us = [None, 700, 97][seed]  # whole segments, and batches cut at arbitrary times
    ev, est, zflat, fes = run_and_check(seed, region, batch_us)
    k = est.num_zones
    gap = 0.0
    for f in fes:
        s, e = f.exposure_start_us, f.exposure_end_us
        want = brute_log_e(ev, s, e, zflat, k)
        assert np.allclose(f.log_e, want, rtol=0, atol=1e-9), (region, s, f.log_e - want)
        if region != "pixel zones":
            gap = max(gap, float(np.max(np.abs(want - mean_count_log_e(ev, s, e, zflat, k)))))
    if region != "pixel zones":
        # the bursts do trigger the compensation: per-pixel terms differ from terms of the mean counts
        assert gap > 0.02


@pytest.mark.parametrize(
    "params",
    [
        TediParams(0.26, 0.24, a_on=0.5, b_on=0.0, a_off=0.3, b_off=0.0),  # b = 0: the compensation never fades
        TediParams(0.26, 0.24, a_on=0.6, b_on=2_000.0),  # OFF uncompensated
        TediParams(0.26, 0.24, a_off=0.4, b_off=1_000.0),  # ON uncompensated
        TediParams(0.26, 0.24, a_on=0.05, b_on=5_000.0, a_off=0.05, b_off=8_000.0),  # a/b of 6-10 µs: many levels
    ],
    ids=["b=0", "ON only", "OFF only", "tiny a/b"],
)
def test_compensation_corner_cases_match_the_brute_force(params):
    ev, est, zflat, fes = run_and_check(6, "grid 2x2", 300, params)
    for f in fes:
        s, e = f.exposure_start_us, f.exposure_end_us
        assert np.allclose(f.log_e, brute_log_e(ev, s, e, zflat, est.num_zones, params), rtol=0, atol=1e-9)


def test_one_pixel_zones_are_per_pixel_tedi():
    """With one pixel per zone, P-TEDI's exposure integral is TEDI's (Eq. 5 with g = s), pixel by pixel."""
    ev, est, _, fes = run_and_check(3, "pixel zones", 500)
    pixmap = np.arange(W * H, dtype=np.int64)
    for f in fes:
        s, e = f.exposure_start_us, f.exposure_end_us
        tedi = tedi_exposure_integral(ev["t"], ev["x"], ev["y"], ev["p"], pixmap, W, W * H, s, e, s, *PARAMS.as_tuple())
        assert np.allclose(f.log_e, np.log(tedi / (e - s)), rtol=0, atol=1e-10)


def test_prediction_at_a_saturated_frames_start_uses_per_pixel_terms():
    """The saturation bound compares the frame with Eq. 12 at its exposure start: per pixel there too."""
    ev = random_stream(4)
    est = PeripheralEstimator(SENSOR, PARAMS, options=PeripheralOptions(grid=(2, 2)))
    zflat = est.zmap.ravel().astype(np.int64)
    fr = frames()
    for pk in interleave(ev[ev["t"] < 20_000], fr[:2]):
        est.feed(pk)
    s, e = 51_000, 52_000
    est.update(ev[(ev["t"] >= 20_000) & (ev["t"] < s)])
    est.begin_exposure(s)
    est.update(ev[(ev["t"] >= s) & (ev["t"] < e)])
    est.end_exposure(e)
    w = est._wstart.index(s)
    seen = ev[ev["t"] < s]
    g = est.anchor_t
    want = [est.anchor_log[z] + zone_means(per_pixel_d(seen, g[z], s, s - g[z]), zflat, 4)[z] for z in range(4)]
    assert np.allclose(est._predict_at_window(w), want, atol=1e-9)


def test_compensation_off_is_the_plain_model_and_can_be_switched():
    """a = 0: the fast kernels, identical to the per-pixel path with the compensation switched off;
    switching it on mid-stream counts from the switch and becomes exact at the next anchor."""
    ev = random_stream(5)
    plain = PARAMS.plain
    a = PeripheralEstimator(SENSOR, plain)
    b = PeripheralEstimator(SENSOR, PARAMS)
    b.set_params(plain)  # drops the per-pixel state: the fast path again
    assert b.event_side is None
    c = PeripheralEstimator(SENSOR, plain)
    for pk in interleave(ev, frames(), batch_us=1_000):
        for est in (a, b, c):
            est.feed(pk)
        if isinstance(pk, EventBatch) and pk.t_last_us >= 8_000 and c.event_side is None:
            c.set_params(PARAMS)
    assert c.event_side is not None  # the switch happened mid-stream
    assert a.predict(60_000) == pytest.approx(b.predict(60_000), abs=1e-12)
    # c has the compensation on since 8 ms; from the anchors after that it matches a fresh estimator
    ref = PeripheralEstimator(SENSOR, PARAMS)
    for pk in interleave(ev, frames(), batch_us=1_000):
        ref.feed(pk)
    assert c.anchor_t[0] == ref.anchor_t[0] == EXPOSURES[-1][0]
    assert c.predict(60_000) - c.anchor_log[0] == pytest.approx(ref.predict(60_000) - ref.anchor_log[0], abs=1e-9)


def test_hot_pixel_grows_the_count_histograms():
    """One pixel firing thousands of times (beyond the initial histogram size) stays exact."""
    n = 3_000
    t = np.arange(n) * 2 + 2_000
    hot = make_events(t, np.full(n, 3), np.full(n, 2), np.ones(n, np.int8))
    est = PeripheralEstimator(SENSOR, PARAMS)
    img = np.full((H, W), 128, np.uint8)
    est.begin_exposure(0)
    est.end_exposure(1_000)
    est.add_frame(Frame(img, 0, 1_000))
    est.begin_exposure(1_500)
    est.update(hot[: n // 2])
    est.update(hot[n // 2 :])
    est.end_exposure(9_000)
    fe = est.add_frame(Frame(img, 1_500, 9_000, 1.0, 1))
    zflat = np.zeros(W * H, np.int64)
    assert fe.log_e[0] == pytest.approx(brute_log_e(hot, 1_500, 9_000, zflat, 1)[0], abs=1e-9)
    u = 9_000 - 1_500
    want = est.anchor_log[0] + per_pixel_d(hot, 1_500, 9_000, u).mean()
    assert est.predict(9_000) == pytest.approx(want, abs=1e-9)
    assert est.event_side.histogram_size > n
