"""The variable-bleed-valve (VBV) schedule: the fraction of the booster exit flow that the valves
dump into the bypass duct, as the engine computer sets it.

Why. The booster (LPC) feeds the HPC. At part power a multistage HPC's flow capacity falls
faster than the booster's (its rear stages choke; ``Wc ~ n^k_ch`` with a larger exponent), so
the HPC throttles the booster toward surge; opening valves between them lowers the booster's
working line (Walsh & Fletcher, *Gas Turbine Performance*, 2nd ed., ch. 5.2.6 and 7.2, handling
bleed). On the CFM56 the VBVs are open at idle and shut at high power, scheduled on the corrected
core speed ``N2K25`` with a fan-speed term (Linke-Diesinger, *Systems of Commercial Turbofan
Engines*, Springer 2008, ch. 4 and 8).

Schedule variable. ``v = n_HPC - fan_bias n_fan - mach_bias Mach``: corrected core speed (on
T24, fraction of design) biased by the corrected fan speed (on T2) and the flight Mach number:
the valves close at a core speed that rises with fan speed and with ram. All three are
quantities a FADEC has (N1, N2, T2 and T25 are measured, Mach comes from the air-data
computer).

Opening. ``f = min(F(v) G(n_HPC), L(n_fan, Mach))``. ``F``: a monotone cubic Hermite table
(:mod:`hermite`) from ``knots``, flat at its first value below the first knot and exactly 0
from the last on (at or below the design point's ``v``, so take-off has no bleed).
``G = 1 - step((n_HPC - a) / (b - a))`` with ``(a, b) = core_close`` and the C-infinity step of
:func:`components.smooth_step`: the valves shut above a corrected core speed ``b`` whatever the
fan speed. ``L``: the low-speed limit, ``f_low + f_low_per_mach Mach`` below corrected fan speed
``low_speed_band[0]``, lifted (to 1, no limit) by ``low_speed_band[1]``; the minimum is
:func:`.schedule.band_min` (C3), exact outside ``limit_band``.

How the numbers were designed (as a real VBV schedule is: from a stability audit of the new
engine, not from data). ``benchmarks/vbv_schedule_audit.py`` holds the valves at fixed openings
over 3,009 envelope points (alt 0-42 kft; Mach 0, 0.1, 0.2, 0.25, the CAS limit and between;
ISA -15, 0, +15 K; TRA 20-100) and finds at each the opening ``need`` for a booster stall
margin of 3 % and the largest opening ``cap`` the booster passes before it chokes. Its
``--propose`` step prints:

* ``fan_bias``, ``mach_bias`` = 0.30, 0.075: over the 2,907 flight points (the throttle
  schedule's ground/flight weight above 0.99), of the pairs on a 0.05 x 0.025 grid with which
  a schedule on ``v`` alone has no conflict (no two points within 0.003 of ``v`` where one's
  ``1.05 need`` exceeds the other's ``cap``), the one with the smallest Mach term. Without a
  Mach term the best bias (0.35) leaves 9 conflicts, all at low Mach.
* knot values: the smallest non-increasing curve above ``1.05 need`` of every flight point,
  read half a knot spacing early (so the Hermite segment between two knots covers the points
  between them), rounded up to 0.005, ending at the first zero.
* ``core_close`` = (0.90, 0.94): the earliest closing band (0.01 steps, 0.04 wide) with which
  every flight point still gets its ``need``. The booster needs bleed at cruise part power:
  without it its margin at 35 kft Mach 0.8 is -1.2 % at TRA 60 and 1.1 % at TRA 70, so the
  valves modulate through cruise (12.7 % of the booster flow at TRA 60, 4.4 % at TRA 70, 1.5 %
  at TRA 75) and are shut from TRA 80; at sea-level take-off and at climb they are shut.
* the low-speed limit, chosen by hand from the table ``--propose`` prints of the points below
  corrected fan speed 0.46: at ground idle (corrected fan speed 0.25-0.33) the booster's speed
  line spans a pressure ratio of only about 1.02, no opening reaches the 3 % target (the best,
  2.4 %, at 0.075) and the booster chokes above 0.075, as it does up to ground TRA 35
  (corrected fan speed 0.42) and in static flight at 5,000 and 20,000 ft; with ram it passes
  more (smallest cap 0.10 at Mach 0.1, 0.125 at Mach 0.2). Hence ``f_low`` = 0.065 (0.01 under
  the static cap), ``f_low_per_mach`` = 0.22 (0.087 at Mach 0.1, 0.109 at Mach 0.2: under the
  caps, at or just under the needs: 0.081 and 0.115 at 5,000 ft) and the band (0.42, 0.46)
  just above ground TRA 35. Without the limit ``F`` opens up to 0.33 there (high-Mach flight
  idle has the same ``v``) and the booster chokes.

The numbers above are those of the audit the schedule was designed on, before the HPT cooling split
and the nozzle discharge coefficients; re-run after them, the audit still finds no conflict in
flight for ``(fan_bias, mach_bias) = (0.30, 0.075)``. Measured with the schedule (``--check``,
``benchmarks/results/vbv_schedule_audit.md``): all 3,009 points converge; the lowest booster stall
margin is 1.19 % (ground idle).

Every function works on floats, numpy arrays and CasADi symbols.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .components import smooth_step
from .effect_base import Effect, Param
from .hermite import fritsch_carlson_slopes, hermite
from .schedule import band_min

# (v, opening) - module doc; benchmarks/vbv_schedule_audit.py --propose
VBV_KNOTS = ((0.49, 0.335), (0.50, 0.335), (0.51, 0.335), (0.52, 0.330), (0.53, 0.325),
             (0.54, 0.295), (0.55, 0.265), (0.56, 0.240), (0.57, 0.235), (0.58, 0.210),
             (0.59, 0.180), (0.60, 0.145), (0.61, 0.135), (0.62, 0.115), (0.63, 0.095),
             (0.64, 0.075), (0.65, 0.060), (0.66, 0.040), (0.67, 0.025), (0.68, 0.005),
             (0.69, 0.0))


@dataclass(frozen=True)
class BleedValveSchedule:
    knots: tuple = VBV_KNOTS
    fan_bias: float = 0.30
    mach_bias: float = 0.075
    core_close: tuple = (0.90, 0.94)  # corrected core speed band over which the valves shut
    f_low: float = 0.065  # largest opening at ground-idle fan speeds, static
    f_low_per_mach: float = 0.22  # its rise with flight Mach (ram)
    low_speed_band: tuple = (0.42, 0.46)  # corrected fan speed over which that limit lifts
    limit_band: float = 0.005  # half-width of the smooth minimum with the limit

    def _points(self):
        t = np.array([k[0] for k in self.knots], float)
        y = np.array([k[1] for k in self.knots], float)
        m = fritsch_carlson_slopes(t, y, first=0.0)
        m[-1] = 0.0  # exactly shut above the last knot
        return t, y, m

    def variable(self, n_hpc, n_fan, mach):
        """The schedule variable ``v = n_HPC - fan_bias n_fan - mach_bias Mach`` (corrected
        speeds as fractions of design)."""
        return n_hpc - self.fan_bias * n_fan - self.mach_bias * mach

    def unlimited_opening(self, n_hpc, n_fan, mach):
        """``F(v) G(n_HPC)``: the opening before the low-speed limit (fraction of the booster
        exit flow)."""
        a, b = self.core_close
        g = 1.0 - smooth_step((n_hpc - a) / (b - a))
        return hermite(self.variable(n_hpc, n_fan, mach), *self._points()) * g

    def low_speed_limit(self, n_fan, mach):
        """The largest opening at corrected fan speed ``n_fan`` and flight Mach ``mach``:
        ``f_low + f_low_per_mach Mach`` below ``low_speed_band[0]`` (ram lets the booster pass
        more), rising (C-infinity) to 1, i.e. no limit, at ``low_speed_band[1]``."""
        a, b = self.low_speed_band
        f0 = self.f_low + self.f_low_per_mach * mach
        return f0 + (1.0 - f0) * smooth_step((n_fan - a) / (b - a))

    def fraction(self, n_hpc, n_fan, mach):
        """The opening (fraction of the booster exit flow): :meth:`unlimited_opening` limited at
        low fan speed (a C3 minimum, :func:`.schedule.band_min`, exact outside
        ``limit_band``)."""
        return band_min(self.unlimited_opening(n_hpc, n_fan, mach),
                        self.low_speed_limit(n_fan, mach), self.limit_band)


class FixedOpening(Effect):
    """An effect that holds the valves at the opening ``f`` (fraction of the booster exit
    flow) instead of the schedule's, through the model's ``W_vbv`` hook: for the stability
    audit (``benchmarks/vbv_schedule_audit.py``) and for what-if studies (valves rigged or
    stuck). Not registered in the effect library."""

    name = "vbv_fixed"
    params = (Param("f", "-", 0.0, "VBV opening, fraction of W22"),)

    def apply(self, hook, value, p, ctx):
        return p["f"] * ctx["W22"] if hook == "W_vbv" else value
