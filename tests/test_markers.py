"""Fiducial markers as the downstream detector (issue 20, item 5): drawn where the truth says, lost when
over-exposed, and the per-run figures from hand-made sequences."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from necviz.core.crf import default_davis346
from necviz.core.errors import ParameterError
from necviz.core.markers import (
    MARGIN_PX,
    MIN_SIDE_PX,
    MarkerTruth,
    frame_scores,
    ids_mask,
    mask_ids,
    summarise_markers,
    visibility,
)
from necviz.drivers.sim.scenes import SCENARIOS, make_scenario
from necviz.marker_detection import MarkerDetector

DET = MarkerDetector()
#: (preset, parameters, times as fractions of the duration): times where markers are in view
CASES = [
    ("static_lab", {}, (0.1, 0.5)),
    ("flicker", {}, (0.1, 0.45, 0.9)),
    ("handheld_scan", {"shadow_db": 10.0}, (0.05, 0.4, 0.8)),  # soft shadows: the test is about geometry
    ("indoor_outdoor", {}, (0.1, 0.3, 0.9)),  # the wall beside the door, then the outdoor plane
    ("tunnel_exit", {}, (0.5, 0.6, 0.8)),  # the signs after the exit
]


def log_encoded(img: np.ndarray) -> np.ndarray:
    """A noiseless 8-bit view of ln L that clips nothing that matters: 0.5 .. 99.5 % percentiles to 0 .. 255."""
    lo, hi = np.percentile(img, (0.5, 99.5))
    return np.clip(np.rint((img - lo) / (hi - lo) * 255), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("name,params,fracs", CASES)
def test_the_detector_finds_every_visible_marker_where_the_truth_says(name, params, fracs):
    s = make_scenario(name, seed=1, change_jitter_ms=0, **params)
    assert len(s.markers) >= 3
    H, W = s.sensor.shape
    seen = set()
    for f in fracs:
        t = f * s.duration_us
        truth = s.marker_truth(t)
        visible = [int(i) for i, v in zip(truth.ids, truth.visible, strict=True) if v]
        assert visible, (name, f)
        found = DET.detect(log_encoded(s.log_irradiance(t)))
        for i in visible:
            assert i in found, (name, f, i)
            err = np.linalg.norm(found[i] - truth.corners_of(i), axis=1)
            assert err.max() < 1.0, (name, f, i, err)
        seen.update(visible)
    assert len(seen) >= 2


def test_markers_move_with_the_scene():
    s = make_scenario("handheld_scan", seed=1, change_jitter_ms=0)
    a, b = s.marker_truth(0.2e6), s.marker_truth(0.7e6)
    i = int(a.ids[a.visible][0])
    shift = b.corners_of(i) - a.corners_of(i)
    assert 30 < -shift[:, 0].mean() < 50  # the facade pans left at 80 px/s (plus shake)
    t = make_scenario("tunnel_exit", seed=1, change_jitter_ms=0)
    t0, t1 = 0.9e6, 1.3e6
    side = lambda tr: np.linalg.norm(tr.corners[0, 1] - tr.corners[0, 0])  # noqa: E731
    z0 = 14.0 + t.v * (t.t_exit - t0)  # the first sign's distance (m)
    z1 = 14.0 + t.v * (t.t_exit - t1)
    assert side(t.marker_truth(t1)) / side(t.marker_truth(t0)) == pytest.approx(z0 / z1, rel=1e-9)  # grows as 1/z


def test_a_frame_formed_at_the_goal_shows_them_and_an_over_exposed_one_loses_them():
    from necviz.drivers.sim.aps import ApsParams, expose

    s = make_scenario("static_lab", seed=2, change_jitter_ms=0)
    crf, aps = default_davis346(), ApsParams(noise=False)
    lbar = np.exp(s.log_irradiance(0.5e6))
    goal_us = math.exp(crf.goal_log_exposure - float(s.log_irradiance(0.5e6).mean())) * 1e6
    truth = s.marker_truth(0.5e6)
    rng = np.random.default_rng(0)
    good = expose(lbar, goal_us, 1.0, crf, aps, rng)
    vis, det, rate, err = DET.score(good, truth)
    assert rate == 1.0 and vis == det == ids_mask(truth.ids) and err < 1.0
    for factor in (60.0, 1 / 60.0):  # +-4.1 ln: most of the frame clipped
        bad = expose(lbar, goal_us * factor, 1.0, crf, aps, rng)
        assert DET.score(bad, truth)[1:3] == (0, 0.0)


def test_markers_off_leaves_the_rest_of_the_scene_and_its_seed():
    on, off = (
        make_scenario("static_lab", seed=3, change_jitter_ms=0),
        make_scenario("static_lab", seed=3, change_jitter_ms=0, markers=False),
    )
    assert off.marker_truth(0) is None and len(on.markers) == 4
    diff = on.log_irradiance(0.3e6) != off.log_irradiance(0.3e6)
    inside = np.zeros_like(diff)
    for m in on.markers:  # the patches: the black border plus one cell of quiet zone on every side
        (x0, y0), (x1, y1) = m.corners[0] + 0.5, m.corners[2] + 0.5
        c = (x1 - x0) / 6
        inside[int(y0 - c) : int(y1 + c), int(x0 - c) : int(x1 + c)] = True
    # only the patches differ, and the level (the scene is re-centred on base_log) by a near-constant
    d = on.log_irradiance(0.3e6) - off.log_irradiance(0.3e6)
    assert np.ptp(d[~inside]) < 1e-4 and abs(float(np.median(d[~inside]))) < 0.05
    with pytest.raises(ParameterError, match="markers must be true or false"):
        make_scenario("static_lab", markers="yes")


def test_every_preset_documents_and_draws_its_markers():
    for name, cls in SCENARIOS.items():
        assert "markers" in cls.PARAMS and "Markers (``markers``)" in cls.__doc__, name
        s = make_scenario(name, seed=0, duration_us=500_000)
        assert s.markers and len({m.marker_id for m in s.markers}) == len(s.markers)


# -- pure parts -------------------------------------------------------------------------------------
def square(x, y, side):
    return np.array([[x, y], [x + side, y], [x + side, y + side], [x, y + side]], float)


def test_visibility_rules():
    W, H = 100, 80
    c = np.stack(
        [
            square(10, 10, 30),  # fine
            square(MARGIN_PX - 0.1, 10, 30),  # too close to the left edge
            square(70, 50, 29.5),  # bottom-right corner at (99.5, 79.5): outside
            square(40, 40, MIN_SIDE_PX - 0.5),  # too small
            square(40, 10, 20),  # fine, but its view has only 80 % weight below
        ]
    )
    np.testing.assert_array_equal(visibility(c, W, H), [True, False, False, False, True])
    np.testing.assert_array_equal(visibility(c, W, H, [1, 1, 1, 1, 0.8]), [True, False, False, False, False])


def test_frame_scores_and_masks():
    truth = MarkerTruth(np.array([0, 3, 5]), np.stack([square(0, 0, 20)] * 3), np.array([True, True, False]))
    assert truth.visible_mask == 0b1001 and mask_ids(0b101001) == [0, 3, 5]
    det = {0: square(0, 0, 20) + [0.3, 0.4], 5: square(0, 0, 20), 7: square(1, 1, 2)}
    vis, dm, rate, err = frame_scores(truth, det)
    assert (vis, dm, rate) == (0b1001, ids_mask([0, 5, 7]), 0.5) and err == pytest.approx(0.5)
    nothing = MarkerTruth(np.array([1]), square(0, 0, 20)[None], np.array([False]))
    vis, dm, rate, err = frame_scores(nothing, {})
    assert (vis, dm) == (0, 0) and math.isnan(rate) and math.isnan(err)
    assert DET.score(np.zeros((40, 40), np.uint8), nothing)[0:2] == (0, 0)  # nothing visible: not searched
    with pytest.raises(ParameterError):
        MarkerTruth(np.array([0, 0]), np.zeros((2, 4, 2)), np.array([True, True]))


def test_summarise_markers_on_a_hand_made_sequence():
    # frames every 20 ms from t = 0; markers 0 and 1; a change at 100 ms and one at 200 ms, end at 300 ms
    starts = np.arange(0, 300_000, 20_000)
    A, B = 1 << 0, 1 << 1
    vis = [A] * 5 + [A | B] * 5 + [B] * 3 + [0, 0]
    det = [A] * 5 + [0, 0, A, A | B, A | B] + [0, 0, 0] + [A, 0]  # frame 13: A detected but not visible
    err = [0.2] * 5 + [math.nan, math.nan, 0.4, 0.6, 0.6] + [math.nan] * 3 + [0.9, math.nan]
    out = summarise_markers(starts, vis, det, err, [200_000, 100_000], end_us=300_000)
    # rate: visible 5 + 10 + 3 = 18 marker-frames; detected visible 5 + (1 + 2 + 2) = 10
    assert out["marker_detection_rate"] == pytest.approx(10 / 18)
    # corner error: weighted by detected visible markers: 5 x 0.2, 1 x 0.4, 2 x 0.6, 2 x 0.6
    assert out["marker_corner_error_px"] == pytest.approx((5 * 0.2 + 0.4 + 4 * 0.6) / 10)
    first, second = out["marker_changes"]
    assert first["t_us"] == 100_000 and first["window_ms"] == 100.0
    assert first["markers"] == {
        0: {"visible_ms": 0.0, "detected_ms": 40.0},
        1: {"visible_ms": 0.0, "detected_ms": 60.0},
    }
    assert second["markers"] == {1: {"visible_ms": 0.0, "detected_ms": None}}  # B never found after 200 ms
    assert (out["marker_pairs"], out["marker_missed"]) == (3, 1)
    assert out["marker_latency_ms"] == pytest.approx((40 + 60 + 100) / 3)  # the miss counts its 100 ms window
    none = summarise_markers(starts, [0] * 15, [0] * 15, [math.nan] * 15, [100_000])
    assert none["marker_detection_rate"] is None and none["marker_latency_ms"] is None and none["marker_pairs"] == 0
    with pytest.raises(ParameterError):
        summarise_markers(starts, vis[:-1], det, err, [])


# -- in a run ---------------------------------------------------------------------------------------
@pytest.mark.slow
def test_compare_reports_marker_figures_that_follow_from_its_frames(tmp_path):
    from necviz.commands.compare import run
    from necviz.options import CompareOptions, SceneOptions

    out = tmp_path / "m.json"
    sc = SceneOptions("static_lab", seed=1, duration_s=0.4, params={"steps": [[0.1, 40.0], [0.25, 0.0]]})
    run(CompareOptions(sc, ("nec", "fixed"), sift=False, json=out, markers=True), out=None)
    data = json.loads(out.read_text())
    assert data["markers"] is True
    for _name, r in data["controllers"].items():
        rows = r["frames_detail"]
        vis = [d["marker_visible_mask"] for d in rows]
        hit = [d["marker_visible_mask"] & d["marker_detected_mask"] for d in rows]
        n_vis, n_hit = sum(bin(v).count("1") for v in vis), sum(bin(h).count("1") for h in hit)
        assert n_vis == 4 * len(rows)  # static: all four always visible
        assert r["marker_detection_rate"] == pytest.approx(n_hit / n_vis)
        assert len(r["marker_changes"]) == 2
        for ch in r["marker_changes"]:
            for mid, m in ch["markers"].items():
                later = [d for d in rows if d["exposure_start_us"] >= ch["t_us"]]
                first = next((d for d in later if d["marker_detected_mask"] >> int(mid) & 1), None)
                want = None if first is None else (first["exposure_start_us"] - ch["t_us"]) / 1e3
                if first is not None and first["exposure_start_us"] >= ch["t_us"] + ch["window_ms"] * 1e3:
                    want = None
                assert m["detected_ms"] == want
    # a fixed exposure set for 0 dB is blinded by the +40 dB step; NEC re-exposes and finds them again
    assert data["controllers"]["fixed"]["marker_missed"] >= 4
    assert data["controllers"]["nec"]["marker_missed"] == 0
    plain = run(CompareOptions(sc, ("fixed",), sift=False), out=None)["controllers"]["fixed"]
    assert plain["marker_detection_rate"] is None and plain["marker_latency_ms"] is None


def test_run_specs_and_sweep_files_take_markers(tmp_path):
    from necviz.runs import run_spec
    from necviz.sweeps.spec import SweepFileError, load_plan

    res = run_spec({"scenario": "flicker", "seed": 0, "duration_s": 0.1, "controllers": ["fixed"], "markers": True})[
        "results"
    ]["fixed"]
    assert res["marker_detection_rate"] is not None and res["marker_corner_error_px"] < 1.0
    base = 'seeds = "0"\ncontrollers = ["fixed"]\nscenarios = ["flicker"]\n'
    f0, f1, bad = tmp_path / "a.toml", tmp_path / "b.toml", tmp_path / "c.toml"
    f0.write_text(base)
    f1.write_text("markers = true\n" + base)
    bad.write_text("markers = 1\n" + base)
    p0, p1 = load_plan(f0), load_plan(f1)
    assert "markers" not in p0.runs[0].spec and p1.runs[0].spec["markers"] is True
    assert p0.runs[0].hash != p1.runs[0].hash and p1.runs[0].columns["markers"] is True
    with pytest.raises(SweepFileError, match="markers must be true or false"):
        load_plan(bad)
