"""Ground-truth metrics (simulated frames), brightness-normalised SIFT, and the causes in the JSON and the recording."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
from rrd_read import Rrd

from necviz.commands.cli import main
from necviz.commands.compare import run as run_compare
from necviz.core.control import CameraLimits
from necviz.core.crf import default_davis346
from necviz.core.diagnosis import CAUSES
from necviz.core.ground_truth import GroundTruth, true_valid_fraction
from necviz.core.metrics import rank_correlation, region_valid_fraction, summarise_details
from necviz.core.sensor import SensorGeometry
from necviz.drivers.sim.aps import ApsParams
from necviz.drivers.sim.rig import RigOptions, SimRig
from necviz.drivers.sim.scene import FunctionScene
from necviz.drivers.sim.scenes import TunnelExit
from necviz.image_quality import SiftMatcher, normalise_brightness
from necviz.options import CompareOptions, SceneOptions
from necviz.pipeline import Lane, Observer, Pipeline
from necviz.runs import build_controller
from necviz.telemetry import Telemetry

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

SENSOR = SensorGeometry(64, 48)
N = SENSOR.num_pixels
L0, L1 = 2.0, 8.0  # the raster ramp's ln L range


def ramp(t_us, sensor):
    """``ln L`` rising linearly in raster order over the pixels: every pixel distinct, uniform over [L0, L1]."""
    k = np.arange(sensor.num_pixels, dtype=np.float64).reshape(sensor.shape)
    return (L0 + (L1 - L0) * (k + 0.5) / sensor.num_pixels).astype(np.float32)


def frames_of(fn, exposure_us, noise, duration_us=90_000):
    rig = SimRig(
        FunctionScene(fn, SENSOR, duration_us), {"cam": (exposure_us, 1.0)}, aps=ApsParams(noise=noise), seed=2
    )
    limits = CameraLimits(1.0, 18_000.0, 16.0)
    lanes = [Lane("cam", build_controller("fixed", None, sensor=SENSOR, limits=limits, exposure_us=exposure_us))]
    tel = Telemetry(["cam"]).attach(lanes, rig)
    seen = []

    class Keep(Observer):
        def frame(self, lane, frame, record):
            seen.append((frame, record))

    Pipeline(rig, lanes, telemetry=tel, observers=[Keep()]).run().finish()
    return seen, tel["cam"]


def closed_form_valid(exposure_us: float) -> float:
    """Pixels k with g(9.5) <= ln T + L0 + (L1 - L0)(k + ½)/N < g(249.5), counted exactly."""
    crf = default_davis346()
    log_t = math.log(exposure_us / 1e6)
    lo = (crf.log_exposure(9.5) - log_t - L0) / (L1 - L0) * N - 0.5
    hi = (crf.log_exposure(249.5) - log_t - L0) / (L1 - L0) * N - 0.5
    k_lo, k_hi = max(math.ceil(lo), 0), min(math.ceil(hi), N)  # k in [lo, hi)
    return (k_hi - k_lo) / N


@pytest.mark.parametrize("exposure_us", [400, 4_000, 15_000])
def test_a_noiseless_frame_of_a_known_scene(exposure_us):
    seen, lane = frames_of(ramp, exposure_us, noise=False)
    frame, rec = seen[1]
    want = closed_form_valid(exposure_us)
    assert 0.1 < want < 0.9
    assert rec.true_valid_fraction == pytest.approx(want, abs=0.5 / N)
    # the noiseless camera records exactly those pixels in 10..249 (up to the digit table's rounding)
    z = frame.image
    assert np.count_nonzero((z > 9) & (z < 250)) / N == pytest.approx(want, abs=2.0 / N)
    # a monotone response of distinct irradiances: only the 8-bit quantisation breaks the ranks
    assert rec.rank_correlation > 0.999
    assert lane.summary()["true_valid_fraction_mean"] == pytest.approx(want, abs=0.5 / N)


def test_noise_lowers_the_rank_correlation_but_not_the_true_valid_fraction():
    quiet, _ = frames_of(ramp, 4_000, noise=False)
    noisy, _ = frames_of(ramp, 4_000, noise=True)
    assert noisy[1][1].true_valid_fraction == quiet[1][1].true_valid_fraction  # truth: the same light, same exposure
    assert quiet[1][1].rank_correlation > noisy[1][1].rank_correlation > 0.9


def test_rank_correlation_properties():
    rng = np.random.default_rng(0)
    lbar = rng.lognormal(0.0, 1.0, (120, 160)).astype(np.float32)
    z = np.clip(np.rint(40 * np.log(lbar) + 128), 0, 255).astype(np.uint8)
    assert rank_correlation(z, lbar) > 0.99
    assert rank_correlation(255 - z, lbar) < -0.99  # an inverted response is perfectly anti-ordered
    shuffled = rng.permutation(z.ravel()).reshape(z.shape)
    assert abs(rank_correlation(shuffled, lbar)) < 0.05
    assert math.isnan(rank_correlation(np.full_like(z, 255), lbar))  # nothing valid to rank


def test_ground_truth_is_attached_without_changing_the_simulation():
    a, _ = frames_of(ramp, 4_000, noise=True)
    rig = SimRig(
        FunctionScene(ramp, SENSOR, 90_000),
        {"cam": (4_000, 1.0)},
        aps=ApsParams(noise=True),
        seed=2,
        options=RigOptions(truth=False),
    )
    plain = [p for cam, p in rig.packets() if hasattr(p, "image")]
    assert len(plain) == len(a) and all(np.array_equal(f.image, p.image) for (f, _), p in zip(a, plain, strict=True))
    assert all(p.truth is None for p in plain)
    tr = a[3][0].truth
    assert isinstance(tr, GroundTruth) and tr.latency_us == 1_000 and tr.readout_us == 1_000
    # the lighting trace reaches from 2 frame intervals + latency before the exposure to its end
    s, e = a[3][0].exposure_start_us, a[3][0].exposure_end_us
    assert s - 41_000 - 2_000 <= tr.light_t_us[0] <= s - 41_000 and tr.light_t_us[-1] >= e
    assert tr.light_at(s) == pytest.approx(np.mean(ramp(0, SENSOR)[::4, ::4]), abs=1e-5)


def test_true_valid_fraction_against_the_bounds_directly():
    crf = default_davis346()
    lbar = np.exp(np.linspace(-2, 12, 1000, dtype=np.float32)).reshape(20, 50)
    tr = GroundTruth(lbar, crf, np.zeros(0, np.int64), np.zeros(0))
    for t_us, gain in ((1_000, 1.0), (200, 4.0)):
        h = np.log(t_us / 1e6) + np.log(gain) + np.log(lbar.astype(np.float64))
        want = np.mean((h >= crf.log_exposure(9.5)) & (h < crf.log_exposure(249.5)))
        assert true_valid_fraction(tr, t_us, gain) == pytest.approx(want, abs=1e-3)


def test_sift_normalisation_removes_the_brightness_bias():
    rng = np.random.default_rng(3)
    h, w = 260, 346
    base = np.zeros((h + 40, w + 40), np.float32)
    for _ in range(300):
        x, y, r, v = (
            int(rng.integers(0, w + 40)),
            int(rng.integers(0, h + 40)),
            int(rng.integers(3, 18)),
            float(rng.uniform(-1, 1)),
        )
        if rng.random() < 0.5:
            cv2.circle(base, (x, y), r, v, -1)
        else:
            cv2.rectangle(base, (x, y), (int(x + 1.5 * r), y + r), v, -1)
    base = cv2.GaussianBlur(base, (0, 0), 1.2)

    def frame(dx, scale):
        z = 128 * np.exp(0.5 * base[20 : 20 + h, 20 + dx : 20 + dx + w]) * scale + rng.normal(0, 1.0, (h, w))
        return np.clip(np.rint(z), 0, 255).astype(np.uint8)

    def inliers(a, b, normalise):
        m = SiftMatcher(normalise=normalise)
        m.next(a)
        return m.next(b)

    bright = frame(0, 1.0), frame(3, 1.0)
    dark = frame(0, 0.5), frame(3, 0.5)  # mean ~65 DN, below NEC's paper goal
    raw_b, raw_d = inliers(*bright, False), inliers(*dark, False)
    norm_b, norm_d = inliers(*bright, True), inliers(*dark, True)
    assert raw_d < 0.6 * raw_b  # the bias: the same structure, half the brightness, far fewer inliers
    assert norm_d == pytest.approx(norm_b, rel=0.1) and norm_b > 50
    n = normalise_brightness(dark[0])
    assert abs(float(n.mean()) - 128) < 2 and n.dtype == np.uint8
    assert normalise_brightness(np.zeros((4, 4), np.uint8)).max() == 0


def test_the_pedestrian_box_covers_the_pedestrian():
    sc = TunnelExit(SensorGeometry(173, 130), duration_us=1_000_000, seed=1)
    without = TunnelExit(SensorGeometry(173, 130), duration_us=1_000_000, seed=1, pedestrian_delay_ms=1e5)
    t_in = sc.annotations["pedestrian_enters_us"]
    assert sc.pedestrian_box(t_in - 1) is None and sc.pedestrian_box(t_in + 1_000) is None  # a sliver: not visible
    t = t_in + 0.25e6  # 15 px in at 60 px/s: more than half of the 19 px wide figure
    box = sc.pedestrian_box(t)
    assert box is not None
    diff = np.abs(sc.log_irradiance(t) - without.log_irradiance(t)) > 1e-3
    ys, xs = np.nonzero(diff)
    x0, y0, x1, y1 = box
    assert xs.size > 20
    # everything the pedestrian changed lies in its box (± the blend's one-pixel border)
    assert xs.min() >= x0 - 1 and xs.max() <= x1 and ys.min() >= y0 - 1 and ys.max() <= y1
    assert region_valid_fraction(np.full((130, 173), 128, np.uint8), box) == 1.0


def test_summarise_details():
    d = summarise_details(
        [3, 4, 5, 6],
        [np.nan, 10, 20, np.nan],
        [0.5, 0.7, np.nan, 0.9],
        [0.9, np.nan, 1.0, 1.0],
        [np.nan, np.nan, 0.95, 0.2],
        ["", "controller", "limit_reached", "controller"],
    )
    assert d["sift_inliers_normalised_mean"] == 15 and d["true_valid_fraction_mean"] == pytest.approx(0.7)
    assert d["rank_correlation_mean"] == pytest.approx(0.9666666)
    assert (d["pedestrian_frame"], d["pedestrian_valid_fraction"], d["pedestrian_well_exposed"]) == (5, 0.95, True)
    assert d["saturation_causes"] == {**dict.fromkeys(CAUSES, 0), "controller": 2, "limit_reached": 1}
    assert list(d["saturation_causes"]) == list(CAUSES)
    empty = summarise_details([1, 2])
    assert empty["true_valid_fraction_mean"] is None and empty["pedestrian_frame"] is None
    assert sum(empty["saturation_causes"].values()) == 0


def test_compare_reports_the_new_metrics_with_intervals_and_a_cause_per_saturated_frame(capsys, tmp_path):
    opts = CompareOptions(SceneOptions("tunnel_exit", seed=0, duration_s=0.6), ("nec", "fixed"), seeds=2, sift=False)
    res = run_compare(opts)
    out = capsys.readouterr().out
    assert "±" in out and "saturated frames by diagnosed cause (mean per run)" in out
    for name, row in res["controllers"].items():
        for key in ("true_valid_fraction_mean", "rank_correlation_mean", "pedestrian_valid_fraction"):
            assert row[key] is not None and row[key + "_ci95"] >= 0, (name, key)
        assert row["sift_inliers_normalised_mean"] is None  # --no-sift
        assert set(row["saturation_causes"]) <= set(CAUSES)
        # every saturated frame of every seed has a cause
        per_seed = [sum(c.values()) for c in row["saturation_causes_per_seed"]]
        assert per_seed == row["saturated_frames_50_per_seed"]
        assert sum(row["saturation_causes"].values()) == pytest.approx(row["saturated_frames_50"])
    fixed = res["controllers"]["fixed"]
    assert fixed["true_valid_fraction_mean"] < res["controllers"]["nec"]["true_valid_fraction_mean"]
    assert fixed["pedestrian_well_exposed"] == 0.0  # blind after the exit
    js = tmp_path / "c.json"
    assert (
        main(
            [
                "compare",
                "--scenario",
                "tunnel_exit",
                "--duration",
                "0.6",
                "--controllers",
                "fixed",
                "--no-sift",
                "--json",
                str(js),
            ]
        )
        == 0
    )
    one = json.loads(js.read_text())["controllers"]["fixed"]
    sat = [d for d in one["frames_detail"] if d["saturated"]]
    assert len(sat) == one["saturated_frames_50"] > 5
    assert all(d["saturation_cause"] in CAUSES and d["saturation_explanation"] for d in sat)
    assert all(d["saturation_cause"] == "" for d in one["frames_detail"] if not d["saturated"])


def test_the_recording_logs_each_cause_and_the_replay_json_carries_it(tmp_path):
    rrd, rec, js = tmp_path / "d.rrd", tmp_path / "d.necrec", tmp_path / "r.json"
    assert (
        main(
            [
                "demo",
                "--scenario",
                "tunnel_exit",
                "--duration",
                "0.6",
                "--controllers",
                "fixed",
                "--save",
                str(rrd),
                "--record",
                str(rec),
                "--no-prompt",
            ]
        )
        == 0
    )
    r = Rrd(rrd)
    texts = [t for t in r.texts("fixed/log") if "-exposed" in t]
    assert texts and all(any(f" — {c}: " in t for c in CAUSES) for t in texts)
    t, v = r.series("fixed/truth/valid_fraction")
    assert len(t) >= 25 and np.all((v >= 0) & (v <= 1))
    assert main(["replay", str(rec), "--json", str(js), "--save", str(tmp_path / "r.rrd")]) == 0
    s = json.loads(js.read_text())
    sat = [d for d in s["frames_detail"] if d["saturated"]]
    assert sat and all(d["saturation_cause"] in CAUSES for d in sat)
    assert sum(s["saturation_causes"].values()) == len(sat) == s["saturated_frames_50"]
    # a replayed file has no ground truth
    assert all(d["true_valid_fraction"] is None for d in s["frames_detail"])
