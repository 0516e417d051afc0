"""The shared number checks (core/checks.py)."""

import math
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from necviz.core.checks import check_number, format_number, format_range, parse_number
from necviz.core.errors import NecvizError, ParameterError

finite = st.floats(allow_nan=False, allow_infinity=False)


@st.composite
def interval(draw):
    """(lo, hi, lo_open, hi_open) with lo < hi, either side possibly unbounded."""
    a, b = sorted(draw(st.lists(finite, min_size=2, max_size=2, unique=True)))
    lo = draw(st.sampled_from([a, None]))
    hi = draw(st.sampled_from([b, None]))
    return lo, hi, draw(st.booleans()), draw(st.booleans())


def inside(v, lo, hi, lo_open, hi_open) -> bool:
    return (lo is None or v > lo or (v == lo and not lo_open)) and (hi is None or v < hi or (v == hi and not hi_open))


@given(interval(), finite)
def test_finite_float_inside_is_returned_unchanged_outside_raises(iv, v):
    lo, hi, lo_open, hi_open = iv
    if inside(v, lo, hi, lo_open, hi_open):
        out = check_number("x", v, lo, hi, lo_open=lo_open, hi_open=hi_open)
        assert type(out) is float and out == v and math.copysign(1, out) == math.copysign(1, v)
    else:
        with pytest.raises(ParameterError, match=r"^x = .* is out of range"):
            check_number("x", v, lo, hi, lo_open=lo_open, hi_open=hi_open)


@given(
    interval(),
    st.sampled_from(
        [math.nan, math.inf, -math.inf, True, False, np.bool_(True), "1", None, [1.0], np.array(1.0), 1j, 10**400]
    ),
)
def test_nan_inf_bool_and_non_numbers_always_raise(iv, v):
    lo, hi, lo_open, hi_open = iv
    with pytest.raises(ParameterError, match=r"^x must be (a number|finite), got "):
        check_number("x", v, lo, hi, lo_open=lo_open, hi_open=hi_open)


@given(st.integers(-(10**6), 10**6), st.integers(-(10**6), 10**6))
def test_integers_inside_and_outside(v, lo):
    if v >= lo:
        out = check_number("n", v, lo, integer=True)
        assert type(out) is int and out == v
        assert check_number("n", float(v), lo, integer=True) == v
        assert check_number("n", np.int32(v), lo) == float(v)
    else:
        with pytest.raises(ParameterError, match=f"n = {v} is out of range \\(must be >= {lo}\\)"):
            check_number("n", v, lo, integer=True)


@given(finite)
def test_parse_number_reads_what_repr_writes(v):
    assert parse_number("x", f"  {v!r} ") == v
    if not v.is_integer():
        with pytest.raises(ParameterError, match="whole number"):
            parse_number("x", repr(v), integer=True)
    else:
        assert parse_number("x", repr(v), integer=True) == int(v)


def test_messages_are_one_line_and_name_everything():
    cases = [
        (
            lambda: check_number("step_db", 30, 40.0, 140.0, where="tunnel_exit"),
            "tunnel_exit: step_db = 30 is out of range [40, 140]",
        ),
        (lambda: check_number("lam", 0.0, 0.0, lo_open=True), "lam = 0 is out of range (must be > 0)"),
        (lambda: check_number("kp", 10.0, 0.0, 10.0, lo_open=True, hi_open=True), "kp = 10 is out of range (0, 10)"),
        (lambda: check_number("d", 2, hi=1, hi_open=True), "d = 2 is out of range (must be < 1)"),
        (lambda: check_number("g", 0.1 + 0.2, 0, 0.3), "g = 0.30000000000000004 is out of range [0, 0.3]"),
        (lambda: check_number("DvsParams.c_on", "0.2", 0.01), "DvsParams.c_on must be a number, got '0.2'"),
        (lambda: check_number("rate", float("nan")), "rate must be finite, got nan"),
        (lambda: check_number("flag", True), "flag must be a number, got True"),
        (lambda: check_number("n", 2.5, integer=True, where="toml"), "toml: n must be a whole number, got 2.5"),
        (lambda: parse_number("--gain", "fast", 1.0), "--gain must be a number, got 'fast'"),
        (lambda: parse_number("--gain", "inf", 1.0), "--gain must be finite, got inf"),
        (lambda: parse_number("--gain", "0.5", 1.0), "--gain = 0.5 is out of range (must be >= 1)"),
        (lambda: parse_number("--seeds", "2.5", 1, integer=True), "--seeds must be a whole number, got 2.5"),
        (lambda: parse_number("--seeds", "", integer=True), "--seeds must be a whole number, got ''"),
    ]
    for call, message in cases:
        with pytest.raises(ParameterError) as e:
            call()
        assert str(e.value) == message and "\n" not in message
        assert isinstance(e.value, NecvizError) and isinstance(e.value, ValueError)


def test_accepted_number_types_and_text():
    assert check_number("x", np.float32(0.5), 0, 1) == 0.5
    assert check_number("x", np.int64(3), 0, 10, integer=True) == 3
    assert check_number("x", Fraction(1, 4), 0, 1) == 0.25
    assert parse_number("x", "+7", 0, 10, integer=True) == 7
    assert parse_number("x", "1e-3", 0, 1) == 0.001
    assert parse_number("x", 4, 0, 10) == 4.0  # a number passed through is checked as it is
    assert format_number(1e6) == "1000000" and format_number(0.1 + 0.2) == "0.30000000000000004"
    assert format_range(0, 1, hi_open=True) == "[0, 1)" and format_range() == "(any finite number)"
