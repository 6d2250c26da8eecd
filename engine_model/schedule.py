"""The throttle schedule: throttle-resolver angle TRA [%] -> corrected fan speed [%].

Convention (C-MAPSS; Frederick, DeCastro & Litt, NASA/TM-2007-215026, "User's guide for the
Commercial Modular Aero-Propulsion System Simulation"): the controller holds the corrected fan
speed ``PCNfR = 100 N_f / sqrt(T2/T_std) / N_f,des`` on a schedule of TRA, and the two points
that the C-MAPSS data show are kept exactly: TRA 100 -> 100 %, TRA 60 -> 84.93 %, at every
altitude. Below them the schedule falls to ground idle:

* ground idle: TRA <= ``tra_idle`` holds ``pct_idle`` (flat), joined with zero slope. A high-
  bypass engine idles at about a quarter of its take-off fan speed and gives a few per cent of
  its take-off thrust (Walsh & Fletcher, *Gas Turbine Performance*, 2nd ed., ch. 7.2 and 8.6:
  ground idle thrust 3-7 % of take-off; N1 at idle 20-25 % on CFM56/CF6-class engines).
* between the knots (tra_idle, pct_idle), (60, 84.93), (100, 100) a monotone cubic Hermite
  interpolant (Fritsch & Carlson, SIAM J. Numer. Anal. 17, 1980: slopes by the weighted
  harmonic mean, so the curve cannot overshoot), continued linearly above TRA 100 with its
  end slope.

Limiter: a full-authority controller never lets the physical fan speed exceed its red line
``N1_max``: the commanded corrected speed is ``min(schedule, 100 N1_max / sqrt(T2/T_std))``,
taken with a smooth minimum (log-sum-exp over ``LIMIT_SHARPNESS`` per % of speed: it departs
from the exact minimum by less than 1e-8 % when the two are 4 % apart). With the default red
line of 106 % N1 it binds only on hot days at TRA > 100.

Every function works on floats, numpy arrays and CasADi symbols.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from .units import T_STD_K

LIMIT_SHARPNESS = 5.0  # 1 / % of corrected speed


def _is_casadi(x) -> bool:
    return isinstance(x, (ca.SX, ca.MX, ca.DM))


def _where(cond, a, b):
    if _is_casadi(cond) or _is_casadi(a) or _is_casadi(b):
        return ca.if_else(cond, a, b)
    return np.where(cond, a, b)


def _sqrt(x):
    return ca.sqrt(x) if _is_casadi(x) else np.sqrt(x)


def smooth_min(a, b, k=LIMIT_SHARPNESS):
    """C-infinity minimum: ``-log(exp(-k a) + exp(-k b)) / k``, written without overflow."""
    d = a - b
    if _is_casadi(d):
        return ca.fmin(a, b) - ca.log1p(ca.exp(-k * ca.fabs(d))) / k
    return np.minimum(a, b) - np.log1p(np.exp(-k * np.abs(d))) / k


@dataclass(frozen=True)
class ThrottleSchedule:
    tra_idle: float = 20.0  # TRA at and below which the engine is at ground idle [%]
    pct_idle: float = 25.0  # corrected fan speed at ground idle [%]
    knots: tuple = ((60.0, 84.93), (100.0, 100.0))  # C-MAPSS points (TRA, %)
    n1_max_pct: float = 106.0  # physical fan-speed red line [% of design]

    def _points(self):
        pts = ((self.tra_idle, self.pct_idle),) + tuple(self.knots)
        t = np.array([p[0] for p in pts], float)
        y = np.array([p[1] for p in pts], float)
        d = np.diff(y) / np.diff(t)
        m = np.zeros_like(y)  # zero slope at idle: joins the flat idle segment smoothly
        for i in range(1, len(y) - 1):
            w1 = 2 * (t[i + 1] - t[i]) + (t[i] - t[i - 1])
            w2 = (t[i + 1] - t[i]) + 2 * (t[i] - t[i - 1])
            m[i] = (w1 + w2) / (w1 / d[i - 1] + w2 / d[i])
        m[-1] = d[-1] * 0.75  # flattening toward maximum speed, as real schedules do
        return t, y, m

    def demand_pct(self, tra):
        """Scheduled corrected fan speed [%] for throttle-resolver angle ``tra`` [%]."""
        t, y, m = self._points()
        out = y[-1] + m[-1] * (tra - t[-1])  # above the last knot: linear
        for i in range(len(t) - 2, -1, -1):
            h = t[i + 1] - t[i]
            s = (tra - t[i]) / h
            h00 = (1 + 2 * s) * (1 - s) ** 2
            h10 = s * (1 - s) ** 2
            h01 = s**2 * (3 - 2 * s)
            h11 = s**2 * (s - 1)
            seg = h00 * y[i] + h10 * h * m[i] + h01 * y[i + 1] + h11 * h * m[i + 1]
            out = _where(tra < t[i + 1], seg, out)
        return _where(tra < t[0], y[0] + 0.0 * tra, out)

    def command_pct(self, tra, T2_K):
        """Commanded corrected fan speed [%]: the schedule, limited by the N1 red line."""
        n1_limit = self.n1_max_pct / _sqrt(T2_K / T_STD_K)
        return smooth_min(self.demand_pct(tra), n1_limit)

    def tra_from_pct(self, pct):
        """The TRA [%] whose scheduled speed is ``pct`` (inverse of :meth:`demand_pct` above
        idle; numpy only). Speeds at or below idle map to ``tra_idle``."""
        grid = np.linspace(self.tra_idle, 110.0, 9001)
        return np.interp(pct, self.demand_pct(grid), grid)
