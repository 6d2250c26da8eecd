"""Mean-line stage stacking of a multistage axial compressor: a second model of how a loss of
flow capacity moves a compressor's working point and surge point.

The engine model's compressors are single maps (``maps.CompressorMap``) whose health
parameter ``flow_mod`` scales the corrected flow at a map point (the N-CMAPSS convention).
Whether such a loss consumes stall margin depends on where the compressor's flow is set.
This module builds the compressor stage by stage instead, fouls some of its stages and
compares the margins; ``benchmarks/booster_stage_stacking.py`` prints the table for the
booster (does the booster's margin at sea-level take-off fall when it loses flow capacity?).

Method
------
Stage stacking (Stone, ASME J. Basic Eng. 80, 1958; Howell & Calvert, ASME J. Eng. Power 100,
1978), with fouling as a change of the fouled stages' characteristics (Aker &
Saravanamuttoo, ASME J. Eng. Gas Turbines Power 111, 1989: flow, pressure-rise and
efficiency characteristics of the front stages degraded). Every stage has the same
non-dimensional characteristic in its own flow coefficient ``phi_k = c_x,k / U``; the blade
speed ``U = n U_d`` is the same for every stage (constant mean radius)::

    psi_k = Dh_k / U^2 = (1 - phi_k (tan a1 + tan b2)) (1 + k f_k)   Euler, fixed blade and
                                                                     vane exit angles
    eta_k = eta_pk exp(-c_eta (phi_k / phi_d - 1)^2) (1 + k f_k)     incidence-loss bucket
    T0_k+1 = T0_k + psi_k U^2 / cp
    P0_k+1 = P0_k (1 + eta_k psi_k U^2 / (cp T0_k))^(g / (g - 1))

(Dixon & Hall, *Fluid Mechanics and Thermodynamics of Turbomachinery*, 7th ed., ch. 5).
Continuity gives each stage's flow coefficient from the static density at its inlet::

    W = rho_k (1 + f_k) A_k c_x,k,    rho_k = rho0_k (1 - c_k^2 / (2 cp T0_k))^(1 / (g - 1)),
    c_k = c_x,k / cos a1   (the absolute velocity)

solved on the subsonic branch (``c_k`` below the sonic speed, where the mass flux per unit
area peaks); a flow above that peak chokes the stage and has no solution.

``f_k <= 0`` is the stage's blockage: the deposit on its blades and end walls, which reduces
the effective flow area at the same incidence. ``k >= 0`` (``fouling_loss``) lets the same
deposit lower the stage's work and efficiency as well (reduced turning, roughness); ``k = 0``
is pure blockage. The stage design follows Dixon & Hall's typical repeating stage:
``phi_d = 0.5``, ``psi_d = 0.4``, reaction 0.5, so ``tan a1 = (1 - R - psi_d / 2) / phi_d =
0.6`` and ``tan a1 + tan b2 = (1 - psi_d) / phi_d``. The reaction enters only through
``a1``, i.e. through the static density.

The annulus areas ``A_k`` are sized so that every stage runs at ``phi_d`` at the design point.
``U_d`` is set so that the stack gives the design pressure ratio. The compressor surges where
the first of its stages, whichever it is, reaches the stall flow coefficient ``phi_s`` as the
flow falls along a speed line. This is conservative beside the peak of the overall
characteristic. Cumpsty, *Compressor Aerodynamics*, ch. 8: in a multistage compressor the
rear stages stall first at high speed and the front stages at low speed;
``tests/test_stage_stacking.py`` checks both.

Stall. An isolated stage stalls near the peak of its pressure-rise characteristic, the
zero-slope point (Greitzer, ASME J. Fluids Eng. 103, 1981). By default ``phi_s`` is that
peak of the total-to-total head ``eta psi``. Greitzer's criterion is usually stated
total-to-static, which peaks at a lower flow coefficient. With ``c_eta = 2`` (efficiency 7
points below peak at 80 % of the design flow coefficient) the peak lies at ``0.73 phi_d``.
``c_eta`` and ``phi_s`` are class-typical choices, not measurements. The benchmark therefore
varies them (``c_eta`` 1-4, ``phi_s`` at the peak or fixed), together with the stage count,
the fouling distribution and ``k``.

Working point. A booster's flow is set by the core compressor behind it: at a given core
corrected speed the HPC swallows a nearly fixed corrected flow (Walsh & Fletcher, *Gas
Turbine Performance*, ch. 7, on the matching of an LP compressor to the HP compressor). The
booster's working point on a speed line is where its exit corrected flow ``W sqrt(T0_out) /
P0_out`` takes a given value (default: the design point's). The result hangs on that
value. Under uniform blockage with ``k = 0`` the speed line is the clean one scaled in flow,
so the margin is unchanged exactly when the exit flow falls by the same fraction, and it
rises when the exit flow falls less. ``benchmarks/booster_stage_stacking.py`` therefore also
runs the stack at the exit flow the engine model's own matching gives. The stall margin is
taken at constant speed, ``SM = 100 (PR_surge / PR - 1)``, the definition of ``maps`` and
``components``.

Gas: dry air with constant ``cp`` and ``g``. The booster's temperature rise is about 30 K, so
this is a small approximation, and the question here is a difference between two stacks.
The stage Mach numbers are low (absolute Mach about 0.25 at design, ``U_d`` about 160 m/s
for the engine's booster), so compressibility, and with it the mismatch between stages, is
weaker than in a real booster, which has a higher blade speed and a lower stage loading.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq

CP = 1004.5  # J/(kg K), dry air near 300 K
GAMMA = 1.4
R_AIR = CP * (GAMMA - 1.0) / GAMMA


@dataclass(frozen=True)
class StageStack:
    """A compressor of ``n_stages`` repeating stages, sized at its design point.

    ``pr_des``, ``w_des``, ``T_in`` and ``P_in`` are the design point, ``eta_pk`` the stages'
    peak efficiency, ``c_eta`` the curvature of their loss bucket, ``phi_s`` the stall flow
    coefficient relative to ``phi_d`` (``None``: the peak of the stage characteristic) and
    ``fouling_loss`` the ``k`` of the module docstring."""

    n_stages: int = 3
    pr_des: float = 1.31
    w_des: float = 100.0  # kg/s
    T_in: float = 320.0  # K
    P_in: float = 1.5e5  # Pa
    eta_pk: float = 0.88
    c_eta: float = 2.0
    phi_s: float | None = None
    fouling_loss: float = 0.0
    phi_d: float = 0.5
    psi_d: float = 0.4
    reaction: float = 0.5
    u_des: float = field(init=False)
    areas: np.ndarray = field(init=False, repr=False, compare=False)
    exit_flow_des: float = field(init=False)  # W sqrt(T0) / P0 at the stack's exit, design

    def __post_init__(self):
        if self.phi_s is None:
            object.__setattr__(self, "phi_s", self.peak_pressure_rise())
        u = brentq(lambda u: self._design_pr(u) - self.pr_des, 10.0, 1000.0, xtol=1e-12)
        object.__setattr__(self, "u_des", u)
        object.__setattr__(self, "areas", self._size(u))
        T0, P0, _ = self.run(self.w_des, 1.0)
        object.__setattr__(self, "exit_flow_des", self.w_des * np.sqrt(T0) / P0)

    # ------------------------------------------------------------------ stage geometry
    @property
    def tan_a1(self) -> float:
        return (1.0 - self.reaction - 0.5 * self.psi_d) / self.phi_d

    @property
    def tan_sum(self) -> float:
        """``tan a1 + tan b2`` of the Euler work line through (phi_d, psi_d)."""
        return (1.0 - self.psi_d) / self.phi_d

    def peak_pressure_rise(self) -> float:
        """``phi / phi_d`` at the peak of the stage's total-to-total isentropic head
        ``eta psi``: the zero-slope point of its pressure-rise characteristic, where an
        isolated stage stalls (Greitzer, ASME J. Fluids Eng. 103, 1981)."""

        def slope(x):  # d(eta psi)/d phi divided by the positive factor eta
            psi = 1.0 - self.tan_sum * x * self.phi_d
            return -self.tan_sum - psi * 2.0 * self.c_eta * (x - 1.0) / self.phi_d

        return float(brentq(slope, 0.05, 1.0, xtol=1e-14))

    def static_density(self, T0, P0, cx):
        """Static density [kg/m^3] of a flow of total state (T0, P0) whose axial velocity is
        ``cx`` at absolute flow angle ``a1``."""
        c2 = cx * cx * (1.0 + self.tan_a1**2)  # (c_x / cos a1)^2
        return P0 / (R_AIR * T0) * (1.0 - c2 / (2.0 * CP * T0)) ** (1.0 / (GAMMA - 1.0))

    def _axial_velocity(self, T0, P0, flux):
        """Axial velocity at which the mass flux per unit area is ``flux``, on the subsonic
        branch; ``None`` above the choking flux (the stage is choked)."""
        # the flux rho c_x peaks where the absolute velocity is sonic, c^2 = 2 cp T0 (g-1)/(g+1)
        cx_sonic = np.sqrt(2.0 * CP * T0 * (GAMMA - 1.0) / (GAMMA + 1.0) / (1.0 + self.tan_a1**2))
        if flux >= self.static_density(T0, P0, cx_sonic) * cx_sonic:
            return None
        return brentq(lambda cx: self.static_density(T0, P0, cx) * cx - flux, 0.0, cx_sonic,
                      xtol=1e-13, rtol=1e-15)

    def _stage(self, T0, P0, phi, u, f=0.0):
        scale = 1.0 + self.fouling_loss * f
        psi = (1.0 - self.tan_sum * phi) * scale
        eta = self.eta_pk * np.exp(-self.c_eta * (phi / self.phi_d - 1.0) ** 2) * scale
        dh = psi * u * u
        return T0 + dh / CP, P0 * (1.0 + eta * dh / (CP * T0)) ** (GAMMA / (GAMMA - 1.0))

    def _design_pr(self, u):
        T0, P0 = self.T_in, self.P_in
        for _ in range(self.n_stages):
            T0, P0 = self._stage(T0, P0, self.phi_d, u)
        return P0 / self.P_in

    def _size(self, u):
        T0, P0, areas = self.T_in, self.P_in, []
        for _ in range(self.n_stages):
            cx = self.phi_d * u
            areas.append(self.w_des / (self.static_density(T0, P0, cx) * cx))
            T0, P0 = self._stage(T0, P0, self.phi_d, u)
        return np.array(areas)

    # ------------------------------------------------------------------ off design
    def run(self, w, n, blockage=None):
        """Stack the stages at inlet flow ``w`` [kg/s] and relative speed ``n``: returns
        ``(T0_out, P0_out, phi)`` with ``phi`` the stages' flow coefficients / ``phi_d``, or
        ``None`` where a stage is choked at that flow."""
        f = np.zeros(self.n_stages) if blockage is None else np.asarray(blockage, float)
        u = n * self.u_des
        T0, P0, phis = self.T_in, self.P_in, []
        for k in range(self.n_stages):
            cx = self._axial_velocity(T0, P0, w / (self.areas[k] * (1.0 + f[k])))
            if cx is None:
                return None
            phis.append(cx / u)
            T0, P0 = self._stage(T0, P0, cx / u, u, f[k])
        return T0, P0, np.array(phis) / self.phi_d

    def _run(self, w, n, blockage):
        r = self.run(w, n, blockage)
        if r is None:
            raise ValueError(f"the stack is choked at flow {w:.4g} kg/s, speed {n:g}")
        return r

    def pressure_ratio(self, w, n, blockage=None) -> float:
        return self._run(w, n, blockage)[1] / self.P_in

    def exit_flow(self, w, n, blockage=None) -> float:
        """Exit corrected flow ``W sqrt(T0_out) / P0_out``."""
        T0, P0, _ = self._run(w, n, blockage)
        return w * np.sqrt(T0) / P0

    def _bracket(self, fun, lo, hi, n_grid=400):
        """First sign change of ``fun`` from ``hi`` down to ``lo`` (``None`` values, choked
        flows, skipped), then brentq."""
        grid = np.linspace(hi, lo, n_grid)
        vals = [fun(x) for x in grid]
        for a, b, fa, fb in zip(grid[:-1], grid[1:], vals[:-1], vals[1:], strict=True):
            if fa is not None and fb is not None and np.sign(fa) != np.sign(fb):
                return brentq(fun, b, a, xtol=1e-12)
        raise ValueError("no root on the speed line between "
                         f"{lo:.4g} and {hi:.4g} kg/s")

    def working_point(self, n, blockage=None, exit_flow=None):
        """Inlet flow and pressure ratio where the exit corrected flow equals ``exit_flow``
        (default: the design point's), i.e. behind a fixed downstream throttle."""
        target = self.exit_flow_des if exit_flow is None else exit_flow

        def gap(w):
            r = self.run(w, n, blockage)
            return None if r is None else w * np.sqrt(r[0]) / r[1] - target

        w = self._bracket(gap, 0.2 * self.w_des, 1.5 * self.w_des)
        return w, self.pressure_ratio(w, n, blockage)

    def surge_point(self, n, blockage=None):
        """Inlet flow, pressure ratio and stalling stage (0-based) where a stage's flow
        coefficient first falls to ``phi_s`` as the flow falls along the speed line."""

        def gap(w):
            r = self.run(w, n, blockage)
            return None if r is None else float(np.min(r[2]) - self.phi_s)

        w = self._bracket(gap, 0.2 * self.w_des, 1.5 * self.w_des)
        _, P0, phi = self._run(w, n, blockage)
        return w, P0 / self.P_in, int(np.argmin(phi))

    def stall_margin(self, n, blockage=None, exit_flow=None) -> float:
        """``100 (PR_surge / PR - 1)`` at speed ``n`` [%], working point behind the throttle."""
        _, pr = self.working_point(n, blockage, exit_flow)
        return 100.0 * (self.surge_point(n, blockage)[1] / pr - 1.0)

    def flow_at_pressure_ratio(self, pr, n, blockage=None) -> float:
        """Inlet flow [kg/s] where the speed line ``n`` passes pressure ratio ``pr`` on its
        choke side (the first root from high flow)."""

        def gap(w):
            r = self.run(w, n, blockage)
            return None if r is None else r[1] / self.P_in - pr

        return self._bracket(gap, 0.6 * self.w_des, 1.2 * self.w_des)

    def blockage_for_capacity(self, weights, capacity=-0.02):
        """Stage blockages ``-s * weights`` with ``s`` such that the inlet flow at design speed
        and design pressure ratio changes by ``capacity`` (the meaning of the N-CMAPSS
        ``flow_mod``: flow at a fixed map point). Raises ``ValueError`` where no blockage of
        up to 15 % does it (with a large ``fouling_loss`` the fouled 100 % line may no longer
        reach the design pressure ratio)."""
        wts = np.asarray(weights, float)

        def cap(s):
            try:
                w = self.flow_at_pressure_ratio(self.pr_des, 1.0, -s * wts)
            except ValueError:
                return -1.0 - capacity  # the line no longer reaches pr_des: no flow at all
            return w / self.w_des - 1.0 - capacity

        if cap(0.15) > 0.0:
            raise ValueError(f"no blockage of up to 15 % changes the flow capacity by "
                             f"{capacity:+.3g}")
        s = brentq(cap, 0.0, 0.15, xtol=1e-12)
        if abs(cap(s)) > 1e-6:  # brentq stopped at the jump where the line loses pr_des
            raise ValueError(f"the fouled 100 % line stops reaching the design pressure ratio "
                             f"before the flow capacity changes by {capacity:+.3g}")
        return -s * wts
