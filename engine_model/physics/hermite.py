"""Piecewise-cubic Hermite schedules that work on floats, numpy arrays and CasADi symbols.

Controller schedules (TRA -> fan speed, core speed -> bleed-valve opening) are tables joined by
cubic Hermite segments. With the slopes of Fritsch & Butland (SIAM J. Sci. Stat. Comput. 5, 1984:
the weighted harmonic mean of the neighbouring secants, zero where they change sign; the PCHIP
slopes) the curve meets Fritsch & Carlson's monotonicity conditions (SIAM J. Numer. Anal. 17, 1980),
so it is monotone wherever the table is, cannot overshoot a knot, and is C1 - so the model built on
it keeps exact, continuous Jacobians.
"""

from __future__ import annotations

import casadi as ca
import numpy as np


def is_casadi(x) -> bool:
    """True for a CasADi matrix or symbol (SX, MX, DM)."""
    return isinstance(x, (ca.SX, ca.MX, ca.DM))


def where(cond, a, b):
    """``cond ? a : b`` elementwise, for numpy values or CasADi expressions."""
    if is_casadi(cond) or is_casadi(a) or is_casadi(b):
        return ca.if_else(cond, a, b)
    return np.where(cond, a, b)


def fritsch_carlson_slopes(t, y, first=0.0):
    """Knot slopes of the monotone interpolant through ``(t, y)`` (``t`` increasing).

    Interior slopes: Fritsch & Butland's weighted harmonic mean of the two secants (zero where
    they differ in sign or one is zero); the first slope ``first``, the last the last secant
    (a caller may change the end slopes)."""
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    d = np.diff(y) / np.diff(t)
    m = np.zeros_like(y)
    for i in range(1, len(y) - 1):
        if d[i - 1] * d[i] <= 0.0:
            continue
        w1 = 2 * (t[i + 1] - t[i]) + (t[i] - t[i - 1])
        w2 = (t[i + 1] - t[i]) + 2 * (t[i] - t[i - 1])
        m[i] = (w1 + w2) / (w1 / d[i - 1] + w2 / d[i])
    m[0] = first
    m[-1] = d[-1]
    return m


def hermite(x, t, y, m):
    """The cubic Hermite interpolant through knots ``(t, y)`` with slopes ``m`` at ``x``;
    constant ``y[0]`` below ``t[0]``, linear with slope ``m[-1]`` above ``t[-1]``."""
    out = y[-1] + m[-1] * (x - t[-1])
    for i in range(len(t) - 2, -1, -1):
        h = t[i + 1] - t[i]
        s = (x - t[i]) / h
        h00 = (1 + 2 * s) * (1 - s) ** 2
        h10 = s * (1 - s) ** 2
        h01 = s**2 * (3 - 2 * s)
        h11 = s**2 * (s - 1)
        seg = h00 * y[i] + h10 * h * m[i] + h01 * y[i + 1] + h11 * h * m[i + 1]
        out = where(x < t[i + 1], seg, out)
    return where(x < t[0], y[0] + 0.0 * x, out)
