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
  interpolant (:mod:`.hermite`: Fritsch & Butland's weighted-harmonic-mean slopes, monotone by
  Fritsch & Carlson's conditions, so the curve cannot overshoot), continued linearly above TRA 100
  with its end slope.

Limiters (a full-authority controller's min/max selection; Jaw & Mattingly, *Aircraft Engine
Controls*, AIAA 2009, ch. 4 and 6; Walsh & Fletcher ch. 7.2 and 8):

* N1 red line: the commanded corrected speed is ``min(schedule, 100 N1_max / sqrt(T2/T_std))``
  (explicit in the inputs; with 106 % N1 it binds only on hot days at TRA > 100);
* N2 red line and T48 (EGT) limit: the fan speed is lowered until the physical core speed or
  T48 is at its limit;
* minimum core speed: on the ground the engine idles on the fan schedule (ground idle); in
  flight the controller holds at least ``n2_min_flight`` physical core speed (flight idle;
  on the ground a lower floor, ``n2_min_ground``, below ground idle),
  which keeps the burner lit, the bleed pressure up and the fan from windmilling at altitude.
  The ground/flight switch (weight on wheels in a real FADEC) is a smooth (tanh) step
  centred between Mach 0.05 and 0.15 and between 500 and 2,000 ft: each step is 0.018 at
  the lower edge and 0.982 at the upper, so the flight weight is 0.036 at Mach 0.05 and
  500 ft (ground idle 1.8 % of the way to flight idle) and 0.982 at Mach 0.15 or 2,000 ft;
  it reaches 0.99 (:mod:`.bleed_schedule`'s "in flight") a little beyond those edges.

The selection ``n = max(min(n_cmd, n_N2max, n_T48max), n_N2min)`` is written as a residual in
the unknown fan speed (:meth:`ThrottleSchedule.controller_residual`): each limit contributes an
error that rises with fan speed and is zero on its limit; ``min`` of speeds is ``max`` of errors
and vice versa. The minima and maxima are blended over a band of ``CONTROL_BAND`` (in error
units, fan-speed fractions) monotonically and C3-smoothly (:func:`band_max`) and are
exact outside it: away from every limit the controller holds exactly the schedule, so the fan
speed does not depend on the health parameters at all (as in C-MAPSS).

Every function works on floats, numpy arrays and CasADi symbols.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from engine_model.units import T_STD_K

from .hermite import fritsch_carlson_slopes, hermite, is_casadi

LIMIT_SHARPNESS = 5.0  # 1 / % of corrected speed, N1 red line on the schedule
CONTROL_BAND = 0.002  # half-width of the limiter blending, in controller-error units


def _sqrt(x):
    return ca.sqrt(x) if is_casadi(x) else np.sqrt(x)


def smooth_min(a, b, k=LIMIT_SHARPNESS):
    """C-infinity minimum: ``-log(exp(-k a) + exp(-k b)) / k``, written without overflow."""
    d = a - b
    if is_casadi(d):
        return ca.fmin(a, b) - ca.log1p(ca.exp(-k * ca.fabs(d))) / k
    return np.minimum(a, b) - np.log1p(np.exp(-k * np.abs(d))) / k


def band_max(a, b, band=CONTROL_BAND):
    """Smooth maximum, exact outside ``|a - b| < band`` and non-decreasing in ``a`` and in
    ``b`` (a min/max selection must be: a rising input never lowers the selected value)::

        band_max(a, b) = b + G(a - b),   G(d) = int_{-band}^{d} S((u + band) / (2 band)) du
                       = 2 band P(t) + max(d - band, 0),   t = clip((d + band)/(2 band), 0, 1)

    with ``S(t) = 6t^5 - 15t^4 + 10t^3`` the C2 smootherstep and ``P(t) = t^6 - 3t^5 +
    5/2 t^4`` its integral: ``dG/dd = S`` lies in [0, 1], so both partial derivatives
    (``S`` and ``1 - S``) are non-negative; ``G`` is C3. (The blend ``b + d step(d)`` is
    smooth too but its slope in ``a`` turns negative inside the band.)"""
    d = a - b
    if is_casadi(d):
        t = ca.fmin(ca.fmax((d + band) / (2.0 * band), 0.0), 1.0)
        beyond = ca.fmax(d - band, 0.0)
    else:
        t = np.clip((d + band) / (2.0 * band), 0.0, 1.0)
        beyond = np.maximum(d - band, 0.0)
    return b + 2.0 * band * t**4 * (t * (t - 3.0) + 2.5) + beyond


def band_min(a, b, band=CONTROL_BAND):
    """C3 minimum (:func:`band_max` mirrored), exact outside ``|a - b| < band``."""
    return -band_max(-a, -b, band)


def _tanh(x):
    return ca.tanh(x) if is_casadi(x) else np.tanh(x)


@dataclass(frozen=True)
class ThrottleSchedule:
    tra_idle: float = 20.0  # TRA at and below which the engine is at ground idle [%]
    pct_idle: float = 25.0  # corrected fan speed at ground idle [%]
    knots: tuple = ((60.0, 84.93), (100.0, 100.0))  # C-MAPSS points (TRA, %)
    n1_max_pct: float = 106.0  # physical fan-speed red line [% of design]
    n2_max: float = 1.05  # physical core-speed red line [fraction of design]
    t48_max: float = 1.12  # T48 limit [fraction of the SLS take-off design T48]
    n2_min_ground: float = 0.50  # minimum physical core speed on the ground (below idle)
    n2_min_flight: float = 0.70  # minimum physical core speed in flight (flight idle)
    mach_flight: tuple = (0.05, 0.15)  # Mach band of the ground -> flight idle switch
    alt_flight: tuple = (500.0, 2000.0)  # altitude band [ft] of the same switch
    # fan-speed fraction per unit of each limited quantity near its limit (makes the errors
    # comparable): the core speed moves about half as much as the fan speed, T48 by about
    # 0.7 of the design value per unit of fan speed
    gain_n2: float = 2.0
    gain_t48: float = 1.5

    def _points(self):
        pts = ((self.tra_idle, self.pct_idle),) + tuple(self.knots)
        t = np.array([p[0] for p in pts], float)
        y = np.array([p[1] for p in pts], float)
        # zero slope at idle (joins the flat idle segment smoothly); toward maximum speed the
        # schedule flattens, as real schedules do: 0.75 of the last secant
        m = fritsch_carlson_slopes(t, y, first=0.0)
        m[-1] = m[-1] * 0.75
        return t, y, m

    def demand_pct(self, tra):
        """Scheduled corrected fan speed [%] for throttle-resolver angle ``tra`` [%]."""
        return hermite(tra, *self._points())

    def command_pct(self, tra, T2_K):
        """Commanded corrected fan speed [%]: the schedule, limited by the N1 red line."""
        n1_limit = self.n1_max_pct / _sqrt(T2_K / T_STD_K)
        return smooth_min(self.demand_pct(tra), n1_limit)

    def alt_flight_weight(self, alt):
        """The altitude step [ft]: ``(1 + tanh((alt - mid) / (quarter band))) / 2``, 0.018
        at ``alt_flight[0]`` and 0.982 at ``alt_flight[1]``, tending to 0 and 1 beyond."""
        lo, hi = self.alt_flight
        return 0.5 * (1.0 + _tanh((alt - 0.5 * (lo + hi)) / (0.25 * (hi - lo))))

    def flight_weight(self, mach, alt):
        """The ground/flight switch (weight on wheels): tends to 0 on the ground and to 1
        in flight, ``1 - (1 - s_Mach)(1 - s_alt)`` with the two tanh steps (0.018 / 0.982 at
        the edges of ``mach_flight`` and ``alt_flight``)."""
        lo, hi = self.mach_flight
        s_m = 0.5 * (1.0 + _tanh((mach - 0.5 * (lo + hi)) / (0.25 * (hi - lo))))
        return 1.0 - (1.0 - s_m) * (1.0 - self.alt_flight_weight(alt))

    def n2_min(self, mach, alt):
        """Minimum physical core speed [fraction of design]: ground idle value on the ground,
        flight idle value in flight, joined by :meth:`flight_weight`."""
        s = self.flight_weight(mach, alt)
        return self.n2_min_ground + (self.n2_min_flight - self.n2_min_ground) * s

    def controller_residual(self, n_fan, n_cmd, n2, t48, mach, alt):
        """Residual of the controller's speed selection (module doc) in the fan speed
        ``n_fan`` [fraction of design corrected speed]; ``n_cmd`` the commanded corrected
        speed, ``n2`` the physical core speed and ``t48`` the T48, both relative to design;
        ``mach`` and ``alt`` [ft] select ground or flight idle."""
        e_cmd = n_fan - n_cmd
        e_n2max = self.gain_n2 * (n2 - self.n2_max)
        e_t48 = self.gain_t48 * (t48 - self.t48_max)
        e_n2min = self.gain_n2 * (n2 - self.n2_min(mach, alt))
        return band_min(band_max(band_max(e_cmd, e_n2max), e_t48), e_n2min)

    def tra_from_pct(self, pct):
        """The TRA [%] whose scheduled speed is ``pct`` (inverse of :meth:`demand_pct` above
        idle; numpy only). Speeds at or below idle map to ``tra_idle``."""
        grid = np.linspace(self.tra_idle, 110.0, 9001)
        return np.interp(pct, self.demand_pct(grid), grid)
