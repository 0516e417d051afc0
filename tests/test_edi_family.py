"""EDI, Fast-EDI, TEDI and mEDI against closed-form scenes, and against each other where theory says so.

Truth: ``scene.log_irradiance(g)`` of :mod:`analytic` (ideal events at exact crossing times,
exact 8-bit exposure averages). With ideal events the model ``c^T D`` differs from the true
log change by less than one threshold, so ``|error| < max(c)`` up to the 8-bit rounding of
the frame; averaged over the random per-pixel threshold phases the mean error is at most
``c/2`` (reached only by a step with its change half-way between two multiples of ``c``).
A wrong orientation of ``D`` or a wrong sign in ``ln L = ln Lbar - ln E`` is off by whole
ln units on these scenes.
"""

import math

import numpy as np
import pytest
from analytic import AnalyticScene, Trajectory

from necviz.core.edi import edi_reconstruct, fast_edi_reconstruct, medi_reconstruct, valid_mask
from necviz.core.errors import EventFormatError, FrameFormatError, ParameterError
from necviz.core.event_model import TediParams
from necviz.core.events import EVENT_DTYPE, make_events
from necviz.core.frames import Frame
from necviz.core.tedi import tedi_reconstruct

C_ON, C_OFF = 0.26, 0.24
PARAMS = TediParams(C_ON, C_OFF)
C_MAX = max(C_ON, C_OFF)
W, H = 48, 32
S, E = 10_000, 14_000  # the exposure
G_TIMES = {"before": 4_000, "inside": 12_345, "after": 21_000}

TRAJECTORIES = {
    "step +2 inside the exposure": Trajectory("step", 11_500, 2.0),
    "step -2.5 before the exposure": Trajectory("step", 7_000, -2.5),
    "ramp +3 across everything": Trajectory("ramp", 6_000, 3.0, 14_000),
    "exp -2.5": Trajectory("exp", 9_000, -2.5, 3_000),
    "exp +4 inside the exposure": Trajectory("exp", 10_500, 4.0, 1_500),
}

METHODS = {
    "EDI": lambda ev, fr, g, crf: edi_reconstruct(ev, fr, g, PARAMS, crf),
    "Fast-EDI": lambda ev, fr, g, crf: fast_edi_reconstruct(ev, fr, g, PARAMS, crf),
    "TEDI": lambda ev, fr, g, crf: tedi_reconstruct(ev, fr, g, PARAMS, crf),
    "mEDI": lambda ev, fr, g, crf: medi_reconstruct(ev, [fr], g, PARAMS, crf),
}


def quantisation_allowance(crf):
    """Largest change of ``g(Z)`` from rounding the exact intensity to the nearest digit (0.5 DN)."""
    return 0.5 * float(np.max(np.diff(crf.g[crf.valid_min - 1 : crf.valid_max + 2])))


_SCENES = {}


def scene_data(name, crf):
    """Scene (its level puts the exposure average at the goal exposure), its events and frame."""
    if name not in _SCENES:
        tr = TRAJECTORIES[name]
        level = crf.goal_log_exposure - math.log((E - S) / 1e6) - math.log(tr.integral(S, E) / (E - S))
        scene = AnalyticScene(W, H, [tr], log_level=level)
        _SCENES[name] = (scene, scene.events(C_ON, C_OFF, seed=1), scene.frame(crf, S, E))
    return _SCENES[name]


@pytest.mark.parametrize("where", list(G_TIMES))
@pytest.mark.parametrize("name", list(TRAJECTORIES))
@pytest.mark.parametrize("method", list(METHODS))
def test_latent_image_matches_the_analytic_truth(method, name, where, crf):
    scene, ev, frame = scene_data(name, crf)
    g = G_TIMES[where]
    ok = valid_mask(frame, crf)
    assert ok.mean() > 0.9  # the test is not vacuous
    est = METHODS[method](ev, frame, g, crf)
    assert est.shape == (H, W) and est.dtype == np.float64
    err = (est - scene.log_irradiance(g))[ok]
    assert np.max(np.abs(err)) <= C_MAX + quantisation_allowance(crf), f"worst {np.max(np.abs(err)):.3f}"
    assert np.mean(np.abs(err)) <= C_MAX / 2, f"mean {np.mean(np.abs(err)):.3f}"


def test_frame_alone_is_far_from_the_truth(crf):
    """Control: without events (E = 1) the same scenes are off by far more than the tolerance."""
    scene, ev, frame = scene_data("ramp +3 across everything", crf)
    ok = valid_mask(frame, crf)
    from necviz.core.edi import log_mean_irradiance

    for g in (G_TIMES["before"], G_TIMES["after"]):
        err = (log_mean_irradiance(frame, crf) - scene.log_irradiance(g))[ok]
        assert np.mean(np.abs(err)) > 4 * C_MAX
    # the sign convention matters: flipping ln E gives errors of whole ln units
    g = G_TIMES["before"]
    est = fast_edi_reconstruct(ev, frame, g, PARAMS, crf)
    flipped = 2 * log_mean_irradiance(frame, crf) - est  # ln Lbar + ln E
    assert np.mean(np.abs((flipped - scene.log_irradiance(g))[ok])) > 4 * C_MAX


def test_tedi_without_compensation_equals_fast_edi(crf):
    for name in ("exp +4 inside the exposure", "ramp +3 across everything"):
        _, ev, frame = scene_data(name, crf)
        for g in G_TIMES.values():
            a = tedi_reconstruct(ev, frame, g, PARAMS, crf)
            b = fast_edi_reconstruct(ev, frame, g, PARAMS, crf)
            assert np.max(np.abs(a - b)) < 1e-9


def test_edi_converges_to_fast_edi(crf):
    _, ev, frame = scene_data("exp +4 inside the exposure", crf)
    g = G_TIMES["inside"]
    exact = fast_edi_reconstruct(ev, frame, g, PARAMS, crf)
    err = {
        n: float(np.max(np.abs(edi_reconstruct(ev, frame, g, PARAMS, crf, n_samples=n) - exact))) for n in (8, 64, 4096)
    }
    # midpoint rule on a piecewise-constant integrand: the error falls like 1/n
    assert err[8] > 0.02  # coarse sampling really is inaccurate here (measured 0.050)
    assert err[64] < err[8] and err[4096] < err[64]
    assert err[4096] < err[8] / 100
    assert err[4096] < 2e-3


def test_edi_samples_the_exposure_midpoints(crf):
    """With n samples EDI evaluates exp(c^T D) at s + (k + 1/2) T / n: check n = 1 and 2 by counting."""
    _, ev, frame = scene_data("exp +4 inside the exposure", crf)
    lbar = crf.log_irradiance(frame.image, frame.exposure_us, frame.gain)
    pix = ev["y"].astype(np.int64) * W + ev["x"]
    for g in G_TIMES.values():
        for n in (1, 2):
            mids = [S + (k + 0.5) * (E - S) / n for k in range(n)]
            e_sum = np.zeros(H * W)
            for t in mids:  # signed counts of events between g and t (an event at τ counts for t > τ)
                between = (ev["t"] >= min(g, t)) & (ev["t"] < max(g, t))
                sgn = 1.0 if t > g else -1.0
                on = np.bincount(pix[between & (ev["p"] > 0)], minlength=H * W) * sgn
                off = np.bincount(pix[between & (ev["p"] < 0)], minlength=H * W) * sgn
                e_sum += np.exp(C_ON * on - C_OFF * off)
            expected = lbar - np.log(e_sum / n).reshape(H, W)
            assert np.allclose(edi_reconstruct(ev, frame, g, PARAMS, crf, n_samples=n), expected, atol=1e-12)


def test_tedi_compensation_integral_matches_brute_force_quadrature(crf):
    """The exact TEDI integral against a direct midpoint quadrature of Eq. 5-6 on a fine grid.

    ``b_on`` is chosen so the ON compensation switches on and off during the exposure (the
    ramp's event rate is close to ``b/a``), which exercises every branch of the segment integral.
    """
    scene, ev, frame = scene_data("ramp +3 across everything", crf)
    params = TediParams(C_ON, C_OFF, 0.5, 380.0, 0.7, 100.0)
    n_grid = 200_000
    ts = S + (np.arange(n_grid) + 0.5) * (E - S) / n_grid
    pixels = [(0, 0), (5, 7), (17, 3), (30, 21), (47, 31)]
    for g in (*G_TIMES.values(), S, E):
        est = tedi_reconstruct(ev, frame, g, params, crf)
        for x, y in pixels:
            sel = (ev["x"] == x) & (ev["y"] == y)
            ref = np.log(_brute_force_e(ev["t"][sel], ev["p"][sel], g, ts, params))
            lbar = crf.log_irradiance(frame.image[y, x], frame.exposure_us, frame.gain)
            assert est[y, x] == pytest.approx(lbar - ref, abs=1e-4)


def _brute_force_e(tau, pol, g, ts, p):
    """``E(g) = mean_t exp(c^T D(g,t))`` straight from the definition (events at τ count for t > τ)."""
    u = np.abs(ts - g)
    sigma = np.sign(ts - g)
    expo = np.zeros_like(ts)
    for sign, c, a, b in ((1, p.c_on, p.a_on, p.b_on * 1e-6), (-1, p.c_off, p.a_off, p.b_off * 1e-6)):
        t_pol = np.sort(tau[pol == sign])
        n = np.searchsorted(t_pol, ts, side="left") - np.searchsorted(t_pol, g, side="left")
        comp = sigma * np.maximum(0.0, a * np.abs(n) - b * u)
        expo += sign * c * (n + comp)
    return float(np.mean(np.exp(expo)))


def test_medi_with_one_frame_equals_edi(crf):
    _, ev, frame = scene_data("exp -2.5", crf)
    # make part of the frame saturated so "valid pixels only" matters
    img = frame.image.copy()
    img[:4] = 255
    img[4:6] = 0
    frame = Frame(img, frame.exposure_start_us, frame.exposure_end_us)
    ok = valid_mask(frame, crf)
    for g in G_TIMES.values():
        m = medi_reconstruct(ev, [frame], g, PARAMS, crf, n_samples=32)
        e = edi_reconstruct(ev, frame, g, PARAMS, crf, n_samples=32)
        assert np.max(np.abs(m[ok] - e[ok])) < 1e-12
        assert np.all(np.isnan(m[~ok]))


def test_medi_two_frames_recover_the_truth_over_a_wide_range(crf):
    """A scene wider than one exposure's valid range: a short and a long exposure cover it together."""
    yy, xx = np.mgrid[0:H, 0:W]
    log_tex = -3.0 + 6.0 * xx / (W - 1) + 0.2 * np.sin(yy)  # 6 ln units across the sensor
    tr = Trajectory("ramp", 6_000, -1.5, 20_000)
    scene = AnalyticScene(W, H, [tr], log_level=5.0, log_texture=log_tex)
    ev = scene.events(C_ON, C_OFF, seed=2)
    short = scene.frame(crf, 10_000, 10_500, seq=0)
    long_ = scene.frame(crf, 14_000, 22_000, seq=1)
    ok_s, ok_l = valid_mask(short, crf), valid_mask(long_, crf)
    either = ok_s | ok_l
    assert (ok_s & ~ok_l).sum() > 100 and (ok_l & ~ok_s).sum() > 100 and (ok_s & ok_l).sum() > 100
    assert either.sum() > 1.2 * max(ok_s.sum(), ok_l.sum())  # neither frame alone covers the range
    allow = C_MAX + quantisation_allowance(crf)
    for g in (2_000, 12_000, 30_000):
        est = medi_reconstruct(ev, [short, long_], g, PARAMS, crf)
        assert np.all(np.isfinite(est[either])) and np.all(np.isnan(est[~either]))
        err = (est - scene.log_irradiance(g))[either]
        assert np.max(np.abs(err)) <= allow
        assert np.mean(np.abs(err)) <= C_MAX / 2


def test_events_outside_the_needed_interval_are_ignored(crf):
    _, ev, frame = scene_data("ramp +3 across everything", crf)
    for g in G_TIMES.values():
        lo, hi = min(g, S), max(g, E)
        inner = ev[(ev["t"] >= lo) & (ev["t"] < hi)]
        for fn in (fast_edi_reconstruct, tedi_reconstruct):
            assert np.array_equal(fn(ev, frame, g, PARAMS, crf), fn(inner, frame, g, PARAMS, crf))
        assert np.array_equal(edi_reconstruct(ev, frame, g, PARAMS, crf), edi_reconstruct(inner, frame, g, PARAMS, crf))


def test_no_events_gives_the_frame(crf):
    frame = Frame(np.full((H, W), 100, np.uint8), 0, 1_000)
    expected = crf.log_irradiance(frame.image, 1_000)
    empty = np.zeros(0, EVENT_DTYPE)
    for fn in (edi_reconstruct, fast_edi_reconstruct, tedi_reconstruct):
        assert np.allclose(fn(empty, frame, 500, TediParams(0.2, 0.2, 0.5, 10.0, 0.5, 10.0), crf), expected)
    assert np.allclose(medi_reconstruct(empty, [frame], 500, PARAMS, crf), expected)


def test_bad_input_is_reported(crf):
    _, ev, frame = scene_data("exp -2.5", crf)
    with pytest.raises(ParameterError, match="n_samples"):
        edi_reconstruct(ev, frame, 0, PARAMS, crf, n_samples=0)
    with pytest.raises(ParameterError, match="n_samples"):
        medi_reconstruct(ev, [frame], 0, PARAMS, crf, n_samples=-3)
    with pytest.raises(FrameFormatError, match="no frames"):
        medi_reconstruct(ev, [], 0, PARAMS, crf)
    other = Frame(np.zeros((H, W + 1), np.uint8), 0, 100)
    with pytest.raises(FrameFormatError, match="different shapes"):
        medi_reconstruct(ev, [frame, other], 0, PARAMS, crf)
    outside = make_events([11_000, 12_000], [3, W + 5], [2, 2], [1, -1])
    for fn in (edi_reconstruct, fast_edi_reconstruct, tedi_reconstruct):
        with pytest.raises(EventFormatError, match="outside"):
            fn(outside, frame, 0, PARAMS, crf)
        with pytest.raises(ParameterError, match="integer"):
            fn(ev, frame, 1.5, PARAMS, crf)
        with pytest.raises(ParameterError, match="TediParams"):
            fn(ev, frame, 0, (0.2, 0.2), crf)
        with pytest.raises(EventFormatError, match="dtype"):
            fn(np.zeros(3), frame, 0, PARAMS, crf)
        with pytest.raises(FrameFormatError):
            fn(ev, frame.image, 0, PARAMS, crf)
    unsorted = make_events([11_000, 12_000], [3, 4], [2, 2], [1, -1])[::-1].copy()
    with pytest.raises(EventFormatError, match="decrease"):
        fast_edi_reconstruct(unsorted, frame, 0, PARAMS, crf)
    # events outside the frame but outside the needed interval are not an error
    far = make_events([90_000], [W + 5], [2], [1])
    assert np.all(np.isfinite(tedi_reconstruct(far, frame, 0, PARAMS, crf)))
