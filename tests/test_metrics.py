"""Metrics on hand-made frames with known answers."""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from necviz.core.errors import ParameterError
from necviz.core.metrics import (
    exposure_rates_from_histogram,
    over_exposed_rate,
    recovery_times_ms,
    saturated_frames,
    summarise,
    under_exposed_rate,
)
from necviz.core.ptedi_kernels import digit_histogram
from necviz.image_quality import SiftMatcher


def test_rates_count_the_documented_thresholds():
    img = np.zeros((10, 10), np.uint8)
    img[0, :] = 250  # 10 over (>= 250)
    img[1, :5] = 249  # not over
    img[2, :] = 9  # 10 under (<= 9) ...
    img[3, :] = 10  # ... not under
    img[3, :3] = 255  # 3 more over
    assert over_exposed_rate(img) == pytest.approx(0.13)
    # rows 4..9 are 0 (60 px) + row 2 (10 px) + row 1's five zeros (5 px) = 75 under
    assert under_exposed_rate(img) == pytest.approx(0.75)


def test_saturated_frame_counts():
    over = np.array([0.0, 0.6, 0.2, 0.05, 0.0])
    under = np.array([0.55, 0.0, 0.0, 0.3, 0.11])
    assert saturated_frames(over, under, 0.5) == 2
    assert saturated_frames(over, under, 0.1) == 5 - 0  # every frame exceeds 10 % one way or the other


def test_recovery_time():
    starts = [0, 20_000, 40_000, 60_000, 80_000, 100_000, 120_000]
    rate = [0.0, 0.0, 0.9, 0.4, 0.05, 0.02, 0.0]
    # step at 35 ms: frames from 40 ms; last bad one at 60 ms; recovered from 80 ms -> 45 ms
    assert recovery_times_ms(starts, rate, [35_000]) == [45.0]
    # a step that is already fine at the first frame: recovery = delay to that frame
    assert recovery_times_ms(starts, rate, [90_000]) == [10.0]
    # never recovers before the next step -> None
    assert recovery_times_ms(starts, [0, 0, 0.9, 0.9, 0.9, 0.9, 0.9], [35_000]) == [None]
    with pytest.raises(ParameterError):
        recovery_times_ms([0, 1], [0.1], [0])


def test_summarise_reports_none_when_a_step_never_recovers():
    m = summarise([0, 20_000, 40_000], [0.0, 0.9, 0.9], [0.0, 0.0, 0.0], [10_000])
    assert m.recovery_ms is None and m.saturated_frames_50 == 2 and m.frames == 3
    m = summarise([0, 20_000, 40_000], [0.0, 0.9, 0.0], [0.0, 0.0, 0.0], [10_000])
    assert m.recovery_ms == 30.0 and m.mean_over_exposed_rate == pytest.approx(0.3)


def _textured(seed=0, shape=(130, 173)):
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 256, (shape[0] // 8 + 1, shape[1] // 8 + 1)).astype(np.uint8)
    img = np.kron(base, np.ones((8, 8), np.uint8))[: shape[0], : shape[1]]
    return np.clip(img.astype(int) + rng.integers(-20, 20, shape), 0, 255).astype(np.uint8)


def test_sift_inliers_high_for_a_shifted_copy_zero_for_a_blank_frame():
    img = _textured()
    shifted = np.roll(img, (3, 5), axis=(0, 1))
    m = SiftMatcher()
    assert m.next(img) is None
    good = m.next(shifted)
    assert good > 30
    assert m.next(np.full_like(img, 255)) == 0  # a saturated frame breaks the track
    other = SiftMatcher()
    other.next(img)
    assert other.next(_textured(seed=5)) < good / 3  # unrelated texture matches far less


def test_ssim_is_one_for_identical_images_and_falls_with_noise():
    from necviz.image_quality import ssim

    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur((rng.random((60, 80)) * 255).astype(np.uint8), (5, 5), 2)
    assert ssim(img, img) == pytest.approx(1.0)
    scores = [ssim(img, np.clip(img + rng.normal(0, s, img.shape), 0, 255).astype(np.uint8)) for s in (2, 8, 32)]
    assert 1.0 > scores[0] > scores[1] > scores[2]
    with pytest.raises(ParameterError):
        ssim(img, img[:-1])


@settings(max_examples=60, deadline=None)
@given(
    image=hnp.arrays(
        np.uint8,
        st.one_of(
            hnp.array_shapes(min_dims=2, max_dims=2, max_side=40),
            st.tuples(st.integers(1, 20), st.integers(1, 20), st.just(3)),
        ),
        elements=st.one_of(st.integers(0, 255), st.sampled_from([0, 9, 10, 249, 250, 255])),
    )
)
def test_exposure_rates_from_the_digit_histogram_are_the_image_rates(image):
    """Telemetry reads a frame's over/under-exposed rates from the digit histogram P-TEDI already counted:
    they must be the very numbers the image functions give (grey or colour, thresholds included)."""
    hist = digit_histogram(np.ascontiguousarray(image).ravel())
    assert exposure_rates_from_histogram(hist, image.size) == (over_exposed_rate(image), under_exposed_rate(image))
