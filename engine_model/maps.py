"""Smooth analytic component maps, scaled at the design point.

No lookup tables: every map is an analytic expression, so outputs are differentiable
everywhere in ``w`` and ``theta`` and exact Jacobians exist.

Compressor (fan, LPC, HPC) — map coordinates: relative corrected speed
``n = (N/sqrt(T_in/T_std)) / (N/sqrt(T_in/T_std))_des`` and a map line ``beta`` (an R-line
analogue: 0 at the design point, positive toward surge, negative toward choke)::

    Wc       = Wc_des * n^k_flow * (1 - s_flow * beta)           corrected flow
    dh_is/T  = (dh_is/T)_des * n^k_head * (1 + s_head * beta)    Euler: head ~ U^2
    eta      = eta_des * exp(-c_eta_n (n - 1)^2 - c_eta_b beta^2)

The isentropic head scales with blade speed squared (Euler's turbomachinery equation; Dixon &
Hall, *Fluid Mechanics and Thermodynamics of Turbomachinery*, ch. 1 and 5); the corrected flow
falls faster than speed on multistage high-pressure compressors because the front stages move
toward stall at part speed (Walsh & Fletcher, ch. 5; Saravanamuttoo et al., *Gas Turbine
Theory*, ch. 9) - hence ``k_flow`` > 1 growing with the number of stages. The surge line is the
map line ``beta = beta_surge``. The efficiency fall-off is second order about the peak ridge
and written as an exponential so it stays positive far from it. The stall margin is taken at
constant corrected speed, ``SM = 100 (PR_surge / PR - 1)`` [%] (one of the definitions that
SAE ARP1420 accepts).

Turbine (HPT, LPT) — flow capacity from Stodola's ellipse law (Cooke, ASME J. Eng. Gas
Turbines Power 107, 1985), efficiency from a parabola in the blade-to-isentropic-velocity ratio
``nu = N / sqrt(dh_is)`` (Dixon & Hall, ch. 4)::

    W sqrt(T_in)/P_in = Phi_des * sqrt(1 - PR^-2) / sqrt(1 - PR_des^-2)
    eta = eta_des * (1 - c_eta (nu/nu_des - 1)^2)

Health parameters scale the map: ``eta * (1 + eff_mod)`` and ``Wc * (1 + flow_mod)``
(``Phi * (1 + flow_mod)`` for turbines), the N-CMAPSS convention.
"""

from dataclasses import dataclass

import casadi as ca


@dataclass(frozen=True)
class CompressorMap:
    wc_des: float  # corrected flow at design [kg/s]
    head_des: float  # isentropic head / inlet total temperature at design [J/(kg K)]
    eta_des: float  # isentropic efficiency at design [-]
    k_flow: float  # corrected flow ~ n^k_flow on a constant map line
    k_head: float  # isentropic head / T_in ~ n^k_head (2 for an incompressible Euler head)
    s_flow: float  # relative flow change per unit beta
    s_head: float  # relative head change per unit beta
    c_eta_n: float  # efficiency fall-off with speed
    c_eta_b: float  # efficiency fall-off along a speed line
    beta_surge: float = 1.0  # map line of the surge line

    def flow(self, n, beta, flow_mod=0.0):
        return self.wc_des * n**self.k_flow * (1.0 - self.s_flow * beta) * (1.0 + flow_mod)

    def head(self, n, beta):
        return self.head_des * n**self.k_head * (1.0 + self.s_head * beta)

    def efficiency(self, n, beta, eff_mod=0.0):
        loss = self.c_eta_n * (n - 1.0) ** 2 + self.c_eta_b * beta**2
        return self.eta_des * ca.exp(-loss) * (1.0 + eff_mod)


@dataclass(frozen=True)
class TurbineMap:
    phi_des: float  # flow capacity W sqrt(T)/P at design [kg K^0.5 / (s Pa)]
    pr_des: float  # expansion ratio P_in/P_out at design
    eta_des: float  # isentropic efficiency at design
    nu_des: float  # N / sqrt(dh_is) at design [rpm / sqrt(J/kg)]
    c_eta: float = 0.5  # curvature of the velocity-ratio parabola

    def capacity(self, pr, flow_mod=0.0):
        ellipse = ca.sqrt(1.0 - pr**-2) / (1.0 - self.pr_des**-2) ** 0.5
        return self.phi_des * ellipse * (1.0 + flow_mod)

    def efficiency(self, n_rpm, dh_is, eff_mod=0.0):
        nu = n_rpm / ca.sqrt(dh_is)
        return self.eta_des * (1.0 - self.c_eta * (nu / self.nu_des - 1.0) ** 2) * (1.0 + eff_mod)
