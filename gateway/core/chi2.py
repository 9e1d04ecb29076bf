"""The χ² distribution's tail and quantile, without scipy (the daemon starts without it).

The daemon needs one χ² quantile at start (the standstill detector's variance threshold,
estimator_settings) and scipy.special's import alone was ~0.6 s of the start and scipy
143 MB of the install. These are the textbook forms: the regularized incomplete gamma
function by its power series where x < a + 1 and by its continued fraction (modified
Lentz) beyond, and the quantile by Newton's method on the upper tail from the
Wilson–Hilferty start. Agreement with scipy.stats.chi2 to ~1e-13 relative:
tests/core/test_chi2.py.
"""
from __future__ import annotations

import math
from statistics import NormalDist

_EPS = 1e-16
_TINY = 1e-300
_MAX_TERMS = 10_000


def _log_density_factor(a: float, x: float) -> float:
    """log(x^a e^−x / Γ(a))."""
    return a * math.log(x) - x - math.lgamma(a)


def upper_gamma_q(a: float, x: float) -> float:
    """The regularized upper incomplete gamma function Q(a, x) = Γ(a, x)/Γ(a)."""
    if a <= 0.0 or x < 0.0:
        raise ValueError(f"Q(a, x) needs a > 0 and x ≥ 0, got a={a}, x={x}")
    if x == 0.0:
        return 1.0
    if x < a + 1.0:  # the series of P converges fast here
        term = total = 1.0 / a
        n = a
        for _ in range(_MAX_TERMS):
            n += 1.0
            term *= x / n
            total += term
            if abs(term) < abs(total) * _EPS:
                break
        return 1.0 - total * math.exp(_log_density_factor(a, x))
    # the continued fraction of Q (modified Lentz)
    b = x + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, _MAX_TERMS):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = _TINY if abs(d) < _TINY else d
        c = b + an / c
        c = _TINY if abs(c) < _TINY else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return math.exp(_log_density_factor(a, x)) * h


def chi2_sf(x: float, dof: float) -> float:
    """P(χ²_dof > x)."""
    return upper_gamma_q(0.5 * dof, 0.5 * x) if x > 0.0 else 1.0


def chi2_isf(tail: float, dof: float) -> float:
    """The x with P(χ²_dof > x) = tail (0 < tail < 1): the quantile 1 − tail."""
    if not 0.0 < tail < 1.0 or not dof > 0.0:
        raise ValueError(f"chi2_isf needs 0 < tail < 1 and dof > 0, got tail={tail}, dof={dof}")
    a = 0.5 * dof
    z = NormalDist().inv_cdf(1.0 - tail)
    h = 2.0 / (9.0 * dof)
    x = max(dof * (1.0 - h + z * math.sqrt(h)) ** 3, 1e-3) * 0.5  # Wilson–Hilferty, in gamma units
    for _ in range(100):
        # Newton on Q(a, x) − tail: dQ/dx = −x^(a−1) e^−x / Γ(a)
        density = math.exp(_log_density_factor(a, x)) / x
        step = (upper_gamma_q(a, x) - tail) / density
        x_next = x + step
        if x_next <= 0.0:
            x_next = 0.5 * x
        if abs(x_next - x) <= 4 * _EPS * x_next:
            x = x_next
            break
        x = x_next
    return 2.0 * x
