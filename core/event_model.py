"""The event generation model shared by EDI, TEDI and P-TEDI, and its segment integral.

Direct integral with TEDI compensation (our design decision for the paper's Eq. 6 terms, see
docs/method.md; ``u = |t - g|``, ``m±`` = number of ON/OFF events between ``g`` and ``t``,
``σ = sign(t - g)``)::

    D±(g,t)   = σ m±
    D_c±(g,t) = σ max(0, a± m± - b± u)
    c^T D     = c+ (D+ + D_c+) - c- (D- + D_c-)

With ``a = b = 0`` this is the plain EDI model ``c+ n+ - c- n-``. The compensation credits
log change for events a pixel misses when its event rate exceeds ``b±/a±``. The terms are per
pixel: EDI/TEDI apply them to each pixel's counts, and P-TEDI averages the per-pixel terms over
its region (Eq. 11; :mod:`necviz.core.ptedi`), never applies them to region-mean counts.
Units: ``c±`` natural-log units per event, ``a±`` dimensionless, ``b±`` events per pixel per
second, times in µs.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numba as nb

from necviz.core.errors import ParameterError


@dataclass(frozen=True)
class TediParams:
    """The six TEDI parameters ``p = {a+, b+, c+, a-, b-, c-}`` (Eq. 7)."""

    c_on: float = 0.26
    c_off: float = 0.24
    a_on: float = 0.0
    b_on: float = 0.0
    a_off: float = 0.0
    b_off: float = 0.0

    def __post_init__(self) -> None:
        for name, v in asdict(self).items():
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                raise ParameterError(f"TEDI parameter {name} must be a finite number, got {v!r}")
        for name in ("c_on", "c_off"):
            v = getattr(self, name)
            if not 0.005 <= v <= 5.0:
                raise ParameterError(f"contrast threshold {name} must lie in 0.005..5 (ln units), got {v}")
        for name in ("a_on", "b_on", "a_off", "b_off"):
            if getattr(self, name) < 0:
                raise ParameterError(f"TEDI compensation {name} must be >= 0, got {getattr(self, name)}")

    @property
    def plain(self) -> TediParams:
        """The same thresholds without compensation (the EDI model)."""
        return TediParams(self.c_on, self.c_off)

    def as_tuple(self) -> tuple[float, float, float, float, float, float]:
        """``(c_on, c_off, a_on, b_on_per_us, a_off, b_off_per_us)`` as the kernels take them."""
        return (self.c_on, self.c_off, self.a_on, self.b_on * 1e-6, self.a_off, self.b_off * 1e-6)


@nb.njit(cache=True, inline="always")
def exp_linear_integral(alpha, beta, length):
    """``∫_0^length exp(alpha + beta τ) dτ`` without cancellation for small ``beta·length``. O(1)."""
    z = beta * length
    if abs(z) < 1e-8:
        return math.exp(alpha) * length * (1.0 + 0.5 * z)
    return math.exp(alpha) * length * (math.expm1(z) / z)


@nb.njit(cache=True)
def segment_integral(u0, u1, sigma, m_on, m_off, c_on, c_off, a_on, b_on, a_off, b_off):
    """``∫ exp(c^T D(g,t)) dt`` over a stretch with no events, ``u = |t - g|`` from ``u0`` to ``u1``.

    The event counts ``m±`` are constant on the stretch, so the exponent is piecewise linear in
    ``u`` with a kink where each compensation term reaches zero (at ``u = a± m± / b±``); each
    piece is integrated in closed form (Eq. 5/14 integrand with the Eq. 6 terms). ``b±`` in
    events per µs. O(1): at most three pieces.
    """
    if u1 <= u0:
        return 0.0
    k_on = math.inf if b_on <= 0.0 else a_on * m_on / b_on
    k_off = math.inf if b_off <= 0.0 else a_off * m_off / b_off
    if a_on * m_on <= 0.0:
        k_on = -1.0
    if a_off * m_off <= 0.0:
        k_off = -1.0
    total = 0.0
    lo = u0
    while lo < u1:
        hi = u1
        if lo < k_on < hi:
            hi = k_on
        if lo < k_off < hi:
            hi = k_off
        alpha = c_on * m_on - c_off * m_off
        beta = 0.0
        if lo < k_on:  # ON compensation active on [lo, hi]
            alpha += c_on * a_on * m_on
            beta -= c_on * b_on
        if lo < k_off:
            alpha -= c_off * a_off * m_off
            beta += c_off * b_off
        alpha *= sigma
        beta *= sigma
        total += exp_linear_integral(alpha + beta * lo, beta, hi - lo)
        lo = hi
    return total


@nb.njit(cache=True, inline="always")
def direct_integral(sigma, u, m_on, m_off, c_on, c_off, a_on, b_on, a_off, b_off):
    """``c^T D(g, t)`` for ``m±`` events and ``u = |t - g|`` (Eq. 6 with the compensation). O(1)."""
    comp_on = a_on * m_on - b_on * u
    comp_off = a_off * m_off - b_off * u
    if comp_on < 0.0:
        comp_on = 0.0
    if comp_off < 0.0:
        comp_off = 0.0
    return sigma * (c_on * (m_on + comp_on) - c_off * (m_off + comp_off))
