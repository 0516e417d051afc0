"""P-TEDI's per-pixel compensation state in the cases its fast paths do not cover.

The estimator keeps each pixel's counts since the anchor and since the latest exposure start; re-anchoring
on the latest exposure is a swap of the two, an exposure start zeroes the window's counts, and counts are
uint16 until one could overflow. These tests drive the other paths against the brute force of
``test_ptedi_compensation`` (written from the model alone): frames that arrive after the next exposure
started (pending windows), zones that do not all re-anchor (a saturated quadrant), and a pixel whose
count passes what uint16 holds.
"""

import numpy as np
import pytest
from test_ptedi_compensation import EXPOSURES, PARAMS, SENSOR, H, W, brute_log_e, per_pixel_d, random_stream, zone_means

from necviz.core.events import EventBatch, make_events
from necviz.core.frames import Frame
from necviz.core.ptedi import PeripheralEstimator, PeripheralOptions
from necviz.core.stream import interleave


def _frames(saturated_quadrant: bool):
    out = []
    for i, (s, e) in enumerate(EXPOSURES):
        img = np.full((H, W), 128, np.uint8)
        if saturated_quadrant and i % 2 == 1:
            img[: H // 2, : W // 2] = 255  # zone (0, 0) of a 2x2 grid: too few valid pixels, not re-anchored
        out.append(Frame(img, s, e, 1.0, i))
    return out


@pytest.mark.parametrize("grid, saturated", [((1, 1), False), ((2, 2), False), ((2, 2), True)])
@pytest.mark.parametrize("seed", [0, 1])
def test_frames_arriving_after_the_next_exposure_started(seed, grid, saturated):
    """Every frame is delivered 8 ms after its exposure ends, after the next exposure started: the
    estimator keeps the counts since each pending exposure's start, and still matches the brute force."""
    ev = random_stream(seed)
    est = PeripheralEstimator(SENSOR, PARAMS, options=PeripheralOptions(grid=grid, min_valid_fraction=0.5))
    zflat = est.zmap.ravel().astype(np.int64)
    k = est.num_zones
    fes, checks, n_done, most_live = [], 0, 0, 0
    for pk in interleave(ev, _frames(saturated), frame_delay_us=8_000, batch_us=500):
        most_live = max(most_live, est.event_side.live_slots())
        if isinstance(pk, EventBatch):
            est.update(pk.events)
            n_done += len(pk)
            if est.ready:
                seen = ev[:n_done]
                t = int(seen["t"][-1])
                g = est.anchor_t
                if t >= g.max():
                    want = [
                        est.anchor_log[z] + zone_means(per_pixel_d(seen, g[z], t, t - g[z]), zflat, k)[z]
                        for z in range(k)
                    ]
                    assert np.allclose(est.predict_zones(t), want, rtol=0, atol=1e-9)
                    checks += 1
            continue
        fe = est.feed(pk)
        if fe is not None:
            fes.append(fe)
    assert len(fes) == len(EXPOSURES) and checks > 20
    assert most_live >= 3  # the pending path ran: the anchor, an exposure awaiting its frame and the next one
    for f in fes:
        want = brute_log_e(ev, f.exposure_start_us, f.exposure_end_us, zflat, k)
        assert np.allclose(f.log_e, want, rtol=0, atol=1e-9)
    if saturated:
        assert any(not f.anchored.all() and f.anchored.any() for f in fes)  # zones re-anchored apart


def test_a_count_beyond_uint16_widens_the_per_pixel_counts():
    """One pixel firing 70,000 times since the anchor: the counts become int32 and stay exact."""
    n = 70_000
    t = np.arange(n, dtype=np.int64) * 3 + 2_000
    hot = make_events(t, np.full(n, 3), np.full(n, 2), np.ones(n, np.int8))
    est = PeripheralEstimator(SENSOR, PARAMS)
    img = np.full((H, W), 128, np.uint8)
    est.begin_exposure(0)
    est.end_exposure(1_000)
    est.add_frame(Frame(img, 0, 1_000))
    assert est.event_side.count_dtype == np.uint16
    for part in np.array_split(hot, 7):
        est.update(part)
    assert est.event_side.count_dtype == np.int32 and est.event_side.histogram_size > n
    end = int(t[-1]) + 1
    want = est.anchor_log[0] + per_pixel_d(hot, 0, end, end).mean()
    assert est.predict(end) == pytest.approx(want, abs=1e-9)
