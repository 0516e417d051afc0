"""Camera response: the documented default curve, its inverse, Debevec-Malik recovery, profiles."""

import json
import math

import numpy as np
import pytest

from necviz.core.camera_profile import CameraProfile
from necviz.core.crf import CameraResponse, debevec_malik, default_davis346
from necviz.core.errors import ParameterError, ProfileError
from necviz.profiles import load_profile, save_profile


def test_default_curve_matches_its_documented_anchors(crf):
    assert crf.g[128] == 0.0
    assert crf.g[9] == pytest.approx(-2.20, abs=0.01)
    assert crf.g[250] == pytest.approx(1.11, abs=0.01)
    assert np.all(np.diff(crf.g) > 0)
    assert (crf.valid_min, crf.valid_max) == (9, 250)


def test_default_curve_is_linear_in_exposure_from_16_to_230_with_a_knee_above_236(crf):
    z = np.arange(16, 231)
    exposure = np.exp(crf.g[z])
    slope, icpt = np.polyfit(z, exposure, 1)
    assert np.max(np.abs(exposure - (slope * z + icpt))) < 1e-9  # exactly affine (black-level offset)
    # above the knee each digit costs more exposure than the linear part predicts
    lin_250 = slope * 250 + icpt
    assert math.exp(crf.g[250]) > 1.4 * lin_250
    assert math.exp(crf.g[236]) == pytest.approx(slope * 236 + icpt, rel=1e-9)


def test_goal_is_the_log_midpoint(crf):
    assert crf.goal_log_exposure == pytest.approx((crf.g[9] + crf.g[250]) / 2)
    assert 65 < crf.goal_intensity < 80
    assert crf.log_exposure(crf.goal_intensity) == pytest.approx(crf.goal_log_exposure, abs=1e-9)


def test_inverse_round_trip(crf):
    z = np.linspace(0, 255, 1021)
    assert np.allclose(crf.intensity(crf.log_exposure(z)), z, atol=1e-9)
    assert crf.intensity(crf.g[0] - 5) == 0.0 and crf.intensity(crf.g[255] + 5) == 255.0


def test_log_irradiance_is_equation_1(crf):
    # Z = 128 means T K L = 1 (T in seconds): at 10 ms and gain 2, L = 50
    assert crf.log_irradiance(128, 10_000, 2.0) == pytest.approx(math.log(50.0))


@pytest.mark.parametrize(
    "g, match",
    [
        (np.arange(255.0), "256 values"),
        (np.r_[np.arange(255.0), 254.0], "increase strictly"),
        (np.r_[np.nan, np.arange(1, 256.0)], "NaN"),
    ],
)
def test_bad_curves_rejected(g, match):
    with pytest.raises(ParameterError, match=match):
        CameraResponse(g)


def _gamma_response():
    """A known non-linear response unlike the default: Z = 255 (H / H_sat)^(1/2.2)."""
    z = np.arange(256.0)
    return CameraResponse(2.2 * np.log(np.maximum(z, 0.5) / 255.0))


@pytest.mark.parametrize("truth", [default_davis346(), _gamma_response()], ids=["davis346", "gamma2.2"])
def test_debevec_malik_recovers_a_known_response(truth):
    rng = np.random.default_rng(1)
    h, w = 40, 60
    log_l = rng.uniform(-4.0, 4.0, size=(h, w))  # static scene spanning a wide range
    exposures = 10_000 * 2.0 ** np.arange(-5, 4)  # 9 brackets, one stop apart
    stack = np.stack(
        [np.clip(np.rint(truth.intensity(log_l + math.log(t / 1e6))), 0, 255).astype(np.uint8) for t in exposures]
    )
    est = debevec_malik(stack, exposures)
    z = np.arange(20, 236)
    assert np.max(np.abs(est.g[z] - truth.g[z])) < 0.05
    assert np.all(np.diff(est.g) > 0)


def test_debevec_malik_bad_input():
    stack = np.zeros((3, 4, 4), np.uint8)
    with pytest.raises(ParameterError, match="one exposure per image"):
        debevec_malik(stack, [1, 2])
    with pytest.raises(ParameterError, match="positive"):
        debevec_malik(stack, [1, -2, 3])
    with pytest.raises(ParameterError, match="uint8"):
        debevec_malik(stack.astype(float), [1, 2, 3])


def test_profile_round_trip(tmp_path):
    prof = CameraProfile()
    path = tmp_path / "cam.json"
    save_profile(prof, path)
    back = load_profile(path)
    assert back == prof
    assert back.crf.g[250] == pytest.approx(1.11, abs=0.01)


def test_profile_errors_name_the_problem(tmp_path):
    with pytest.raises(ProfileError, match="does not exist"):
        load_profile(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text('{\n  "format": ')
    with pytest.raises(ProfileError, match="invalid JSON at line 2"):
        load_profile(bad)
    d = CameraProfile().to_dict()
    d["tedi"]["c_on"] = -1
    bad.write_text(json.dumps(d))
    with pytest.raises(ProfileError, match="c_on"):
        load_profile(bad)
    d = CameraProfile().to_dict()
    d["limits"]["exposure_max_us"] = float("nan")
    bad.write_text(json.dumps(d).replace("NaN", '"nan"'))
    with pytest.raises(ProfileError, match="exposure_max_us"):
        load_profile(bad)
    d = CameraProfile().to_dict()
    del d["crf"]
    bad.write_text(json.dumps(d))
    with pytest.raises(ProfileError, match="crf"):
        load_profile(bad)
    bad.write_text(json.dumps({"hello": 1}))
    with pytest.raises(ProfileError, match="not a necviz camera profile"):
        load_profile(bad)
