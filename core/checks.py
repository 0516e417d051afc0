"""Checks of numeric parameters, shared by every part of necviz.

:func:`check_number` accepts a real number (Python ``int``/``float``, NumPy integer or floating
scalar, ``fractions.Fraction``) that is finite and lies in an interval, and returns it as a
``float`` (an ``int`` with ``integer=True``). Everything else raises
:class:`~necviz.core.errors.ParameterError` with one line that names the parameter, shows the
value and states what is accepted, e.g.::

    tunnel_exit: step_db = 30 is out of range [40, 140]
    DvsParams.c_on must be a number, got '0.2'
    lam = 0 is out of range (must be > 0)

Booleans are refused although Python counts them as integers (``True`` is not a threshold), and
so are NaN and infinities. :func:`parse_number` does the same for text a user typed (a command
line flag, a prompt).
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from necviz.core.errors import ParameterError

__all__ = ["check_number", "parse_number", "format_number", "format_range"]


def format_number(v) -> str:
    """Short text for a number: ``%.15g`` when that is exact (``30``, ``0.5``, ``1000000``), else ``repr``."""
    try:
        short = f"{v:.15g}"
        return short if float(short) == v else repr(v)
    except (TypeError, ValueError, OverflowError):
        return repr(v)


def format_range(
    lo: float | None = None, hi: float | None = None, *, lo_open: bool = False, hi_open: bool = False
) -> str:
    """The accepted interval as text: ``[40, 140]``, ``(0, 1]``, ``must be > 0``, ``must be <= 5``."""
    if lo is not None and hi is not None:
        return f"{'(' if lo_open else '['}{format_number(lo)}, {format_number(hi)}{')' if hi_open else ']'}"
    if lo is not None:
        return f"(must be {'>' if lo_open else '>='} {format_number(lo)})"
    if hi is not None:
        return f"(must be {'<' if hi_open else '<='} {format_number(hi)})"
    return "(any finite number)"


def _is_real(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def check_number(
    name: str,
    value,
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
    integer: bool = False,
    where: str = "",
):
    """``value`` as a finite ``float`` inside ``[lo, hi]``, else a one-line :class:`ParameterError`.

    ``lo``/``hi`` ``None`` leave that side unbounded; ``lo_open``/``hi_open`` exclude the bound
    itself (``lo=0, lo_open=True`` is "> 0"). With ``integer=True`` the value must be a whole
    number (``3`` or ``3.0``) and is returned as an ``int``. ``where`` prefixes the message
    (``"tunnel_exit"`` gives ``"tunnel_exit: step_db = 30 is out of range [40, 140]"``).

    Refused: ``bool`` (also NumPy's), anything that is not a real number (strings, ``None``,
    arrays, complex), NaN, infinities and integers too large for a float.
    """
    pre = f"{where}: " if where else ""
    if not _is_real(value):
        kind = "a whole number" if integer else "a number"
        raise ParameterError(f"{pre}{name} must be {kind}, got {value!r}")
    try:
        v = float(value)
    except OverflowError:
        v = math.inf
    if not math.isfinite(v):
        raise ParameterError(f"{pre}{name} must be finite, got {value!r}")
    if integer:
        if not v.is_integer():
            raise ParameterError(f"{pre}{name} must be a whole number, got {value!r}")
        out = int(value) if isinstance(value, numbers.Integral) else int(v)
    if (lo is not None and (v < lo or (lo_open and v == lo))) or (hi is not None and (v > hi or (hi_open and v == hi))):
        shown = format_number(out if integer else v)
        raise ParameterError(
            f"{pre}{name} = {shown} is out of range {format_range(lo, hi, lo_open=lo_open, hi_open=hi_open)}"
        )
    return out if integer else v


def parse_number(
    name: str,
    text: str,
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
    integer: bool = False,
    where: str = "",
):
    """A number typed by a user (``" 2.5 "``, ``"1e-3"``, ``"40"``), then :func:`check_number`.

    Text that is not a number (``"fast"``, ``""``), ``"nan"`` and ``"inf"`` give a one-line
    :class:`ParameterError`; so do non-string inputs other than real numbers (which are checked
    as they are).
    """
    if not isinstance(text, str):
        return check_number(name, text, lo, hi, lo_open=lo_open, hi_open=hi_open, integer=integer, where=where)
    s = text.strip()
    pre = f"{where}: " if where else ""
    try:
        value = int(s) if integer and s.lstrip("+-").isdigit() else float(s)
    except ValueError:
        kind = "a whole number" if integer else "a number"
        raise ParameterError(f"{pre}{name} must be {kind}, got {text!r}") from None
    return check_number(name, value, lo, hi, lo_open=lo_open, hi_open=hi_open, integer=integer, where=where)
