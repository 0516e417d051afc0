"""Event, frame, marker and sensor constructors reject bad input with a clear message."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from necviz.core.errors import EventFormatError, FrameFormatError, NecvizError, ParameterError
from necviz.core.events import EVENT_DTYPE, empty_events, make_events, validate_events
from necviz.core.frames import ExposureMarker, Frame
from necviz.core.sensor import DAVIS346, SensorGeometry


def test_event_dtype_is_the_documented_layout():
    assert EVENT_DTYPE.names == ("t", "x", "y", "p")
    assert [EVENT_DTYPE[n] for n in "txyp"] == [np.dtype("<i8"), np.dtype("<u2"), np.dtype("<u2"), np.dtype("i1")]


def test_make_events_round_trips_values():
    ev = make_events([1, 2, 2, 5], [0, 345, 3, 4], [0, 259, 1, 2], [1, -1, 1, -1], DAVIS346)
    assert ev.dtype == EVENT_DTYPE
    assert ev["t"].tolist() == [1, 2, 2, 5] and ev["x"].tolist() == [0, 345, 3, 4]
    assert ev["p"].tolist() == [1, -1, 1, -1]


def test_empty_batch_is_valid():
    assert validate_events(empty_events(), DAVIS346).size == 0
    assert make_events([], [], [], []).size == 0


@pytest.mark.parametrize(
    "args, match",
    [
        (([2, 1], [0, 0], [0, 0], [1, 1]), "must not decrease"),
        (([1, 2], [0, 346], [0, 0], [1, 1]), "outside the 346x260 sensor"),
        (([1, 2], [0, 0], [0, 260], [1, 1]), "outside the 346x260 sensor"),
        (([1, 2], [0, 0], [0, 0], [1, 0]), "polarity must be \\+1 or -1"),
        (([1.5, 2], [0, 0], [0, 0], [1, 1]), "whole microseconds"),
        (([1, 2], [0, -1], [0, 0], [1, 1]), "0..65535"),
        (([1, 2, 3], [0, 0], [0, 0], [1, 1]), "different lengths"),
    ],
)
def test_make_events_rejects(args, match):
    with pytest.raises(EventFormatError, match=match):
        make_events(*args, sensor=DAVIS346)


def test_validate_rejects_wrong_dtype():
    wrong = np.zeros(3, dtype=[("t", "<f8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])
    with pytest.raises(EventFormatError, match="expected"):
        validate_events(wrong)
    with pytest.raises(EventFormatError, match="structured array"):
        validate_events([1, 2, 3])


@given(
    st.lists(
        st.tuples(st.integers(0, 10**12), st.integers(0, 345), st.integers(0, 259), st.sampled_from([-1, 1])),
        max_size=50,
    )
)
def test_sorted_on_sensor_events_always_validate(rows):
    rows.sort(key=lambda r: r[0])
    t, x, y, p = (list(c) for c in zip(*rows, strict=True)) if rows else ([], [], [], [])
    ev = make_events(t, x, y, p, DAVIS346)
    assert ev.size == len(rows)


def test_frame_validation():
    img = np.zeros((4, 5), np.uint8)
    f = Frame(img, 100, 350, 2.0, 7)
    assert f.exposure_us == 250 and f.shape == (4, 5)
    with pytest.raises(FrameFormatError, match="exposure must be positive"):
        Frame(img, 100, 100)
    with pytest.raises(FrameFormatError, match="gain"):
        Frame(img, 0, 10, 0.5)
    with pytest.raises(FrameFormatError, match="gain"):
        Frame(img, 0, 10, float("nan"))
    with pytest.raises(FrameFormatError, match="uint8"):
        Frame(img.astype(np.float32), 0, 10)
    with pytest.raises(FrameFormatError, match="integer"):
        Frame(img, 0.5, 10)
    with pytest.raises(FrameFormatError, match="kind"):
        ExposureMarker(5, "middle")


def test_sensor_geometry_checks_and_errors_are_value_errors():
    assert DAVIS346.shape == (260, 346)
    with pytest.raises(ParameterError):
        SensorGeometry(0, 10)
    assert issubclass(EventFormatError, NecvizError) and issubclass(NecvizError, ValueError)
