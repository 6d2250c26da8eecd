"""Smooth analytic component maps, scaled at the design point.

No lookup tables: every map is an analytic expression, so outputs are differentiable
everywhere in ``w`` and ``theta``, exact Jacobians exist and the code compiles to C.

Compressor (fan, LPC, HPC)
--------------------------
Map coordinates: relative corrected speed ``n = N_c / N_c,des`` and a map line ``beta`` (an
R-line analogue defined for every real number: 0 at the SLS design point, growing toward
surge, ``beta -> -inf`` is the choke end of every speed line). The map is written in the
physical coordinates of the blading - flow coefficient (axial velocity over blade speed) and
work coefficient ``Dh / U^2`` - rather than in ``beta``::

    phi_hat(b)  = phi_ch1 / (1 + D exp(lam b)),   D = phi_ch1 - 1    (1 at the design point)
    Wc          = Wc_des n^k_ch phi_hat(b) (1 + flow_mod)              corrected flow
    phi_w(n, b) = Wc / (Wc_des n^k_work (1 + flow_mod)) = phi_hat n^(k_ch - k_work)
    Dh / T_in   = w_des n^2 (1 - kappa (phi_w - 1))                    specific work (Euler)
    eta_map     = eta_pk exp(-c_phi (phi_w/phi_opt1 - 1)^2 - c_n (n - n_pk)^2) chi(b)
    chi(b)      = 1 / (1 + exp(-mu (b - b_ch))) - softplus(mu (b_d - b))  choke (shock) loss
    Dh_is / T_in = eta_map Dh / T_in                                   isentropic head -> PR

1. *Euler work line.* The specific work of a stage is ``Dh = U^2 (1 - phi (tan a1 + tan b2))``
   (Euler's turbomachinery equation with fixed blade and vane exit angles; Dixon & Hall,
   *Fluid Mechanics and Thermodynamics of Turbomachinery*, 7th ed., ch. 5): linear and falling
   in the flow coefficient, proportional to ``U^2 ~ n^2 T_in`` at fixed flow coefficient.
   Relative to the design point this is ``1 - kappa (phi_w - 1)`` (values and their basis in
   :class:`design.DesignSpec`). ``phi_w`` is the flow coefficient that sets the blading's work,
   incidence and stall: the physical one (``k_work = 1``) for a single-stage fan; for a
   multistage compressor the stage-averaged one, which follows its speed line
   (``k_work = k_ch``): at part speed the front stages work harder and the rear stages less
   (stage mismatch; Cumpsty, *Compressor Aerodynamics*, ch. 4; Saravanamuttoo et al., *Gas
   Turbine Theory*, ch. 5.6).
2. *Choke.* Corrected flow saturates at the choke flow ``Wc_des phi_ch1 n^k_ch`` as
   ``beta -> -inf``: the blade-row throats are sonic. On multistage compressors the rear
   stages choke first at part speed, so the choke flow falls faster than speed (``k_ch > 1``,
   Walsh & Fletcher, *Gas Turbine Performance*, 2nd ed., ch. 5.2); a single fan stage chokes
   in its throats at a corrected flow that falls more slowly than speed (``k_ch < 1``). Once
   choked the pressure ratio falls at fixed flow because shock losses grow: ``chi`` takes the
   isentropic head to zero while the flow stays at choke - the vertical choke end of every
   speed line. ``b_ch`` is where the flow is 99.9 % of the choke flow. A fan's low-speed
   lines reach zero work (windmilling) before they choke.
   *Past PR = 1.* Deeper in choke the flow stays at the choke flow and the pressure ratio
   goes on falling below 1: the blading still does its Euler work but the shock and
   rear-stage losses exceed it, the rear stages acting as turbines or throttles (Cumpsty ch.
   4, the "turbining" of rear stages at low speed; Walsh & Fletcher on compressor maps
   extended below PR 1 for windmilling and starting). The first term of ``chi`` alone stops
   at PR = 1 (``chi -> 0+``), so an engine whose booster must pass more corrected flow than
   it can at PR >= 1 (ground idle with a heavily degraded booster) had no steady state. The
   second term continues the choke line: ``softplus(x) = ln(1 + e^x)`` with ``b_d = b_ch - 9
   / mu``. Above ``b_d`` it is ``e^(mu (b_d - b))``, negligible where the compressor is not
   choked, and it overtakes the first term (``e^(-mu (b_ch - b))`` in choke) at ``b_ch - 4.5
   / mu``, where the head passes zero (PR = 1); from there the isentropic head falls on, its
   slope rising to ``mu`` island heads per map unit well below ``b_d`` (0.5 ``mu`` at
   ``b_d``, 0.95 ``mu`` at ``b_d - 1``), to negative values (``PR < 1``, the efficiency
   ``Dh_is / Dh`` negative: the compressor dissipates more than its work). (These figures,
   and the ones that follow, are those of the present design's ``mu = 3`` and ``lam = 1``,
   the same for the three maps.) The flow is
   within 5e-5 of the choke flow from ``b_d`` down, so the continuation is the vertical
   choke end of the speed line extended downward; how ``b`` runs along a vertical line is a
   choice of parametrization, not a property of the map. Where the map was used before, the
   second term changes the head by ``softplus(mu (b_d - b)) / chi_1(b)`` of itself: 2.5e-4
   at ``b_ch``, 3e-7 at ``b_ch + 2``, below 1e-8 above ``b_ch + 3.5`` (99 % of converged
   random envelope points; of the 100,000 points that converged before the continuation the
   lowest booster point lies at ``b_ch - 0.81``, its head changed by 1.7 %).
3. *Efficiency island.* Profile loss is a bucket in incidence, i.e. in the flow coefficient
   relative to the optimum-incidence one (Cumpsty ch. 5; Dixon & Hall ch. 3): a Gaussian in
   ``phi_w/phi_opt1 - 1``, positive everywhere; the efficiency falls away from the
   aerodynamic design speed ``n_pk`` (Walsh & Fletcher fig. 5.6). The island's peak
   ``(n_pk, phi_opt1)`` is the compressors' aerodynamic design point, the cruise point (see
   :class:`design.DesignSpec` and ``benchmarks/map_design_point.py``): at sea-level take-off
   the compressors run off their peaks, as real ones do.

Along a speed line, from surge to choke, ``phi_w`` rises strictly, so the specific work falls
strictly (1.) and the isentropic head ``eta_map Dh`` falls strictly as long as the incidence
loss grows more slowly than the Euler work falls on the surge side of the island,
``2 c_phi (1 - phi_w/phi_opt1) / phi_opt1 < kappa / (1 - kappa (phi_w - 1))``, which holds
between the surge line and choke (or windmilling) for the values used (tested on every speed
line in ``tests/test_physics_maps.py``).

Surge line and stall margin. A blade row stalls at a critical incidence, i.e. at a critical
flow coefficient of its blading (Cumpsty ch. 8; Dixon & Hall ch. 5): the surge line is where
the *actual* flow coefficient ``(1 + flow_mod) phi_w`` falls to ``phi_s(n) = phi_s1 n^k_s``
(``k_s > 0``: a transonic fan stalls at a higher flow coefficient at design speed than its
subsonic part-speed lines do). In closed form that is the map line::

    b_s(n) = ln((phi_ch1 / phi_hat_s - 1) / D) / lam,
    phi_hat_s = phi_s1 n^k_s / ((1 + flow_mod) n^(k_ch - k_work))

A compressor that has lost flow capacity (fouling, erosion: ``flow_mod < 0``) reaches the
critical incidence earlier along each speed line, at a lower pressure ratio: the surge line
moves down and flow-capacity loss consumes stall margin, as fouling studies report
(Saravanamuttoo & Lakshminarasimha, ASME 85-GT-153, 1985; Kurz & Brun, J. Eng. Gas Turbines
Power 123, 2001). Whether the margin at a working point falls depends on where the
compressor's flow is set. For a booster behind the HPC it does not at sea level: the
booster runs down its speed line toward choke, and the core takes more corrected flow from
it. Stage stacking (:mod:`stage_stacking`), set behind the same exit flow, gives that sign
too, with a larger rise than this map's, whose surge line also drops. ``phi_s1`` is placed by the
design stall margin. The stall margin is taken
at constant corrected speed, ``SM = 100 (PR_surge / PR - 1)`` [%] (one of the two definitions
of SAE ARP1420 and Walsh & Fletcher ch. 5; the other is at constant corrected flow).

Turbine (HPT, LPT)
------------------
Flow capacity from Stodola's ellipse law (Cooke, ASME J. Eng. Gas Turbines Power 107, 1985),
a law for multistage turbines; for the single-stage HPT it is an approximation (a choked
nozzle-guide-vane row would hold its capacity nearly constant, where the ellipse lowers it by
about 1.6 % at expansion ratio 4 and 7 % at 2.5 against the design's 5.57),
efficiency from the blade-to-isentropic-velocity ratio ``nu = N / sqrt(dh_is)`` (Dixon & Hall,
ch. 4), a parabola near the design value::

    W sqrt(T_in)/P_in = Phi_des * sqrt(1 - PR^-2) / sqrt(1 - PR_des^-2)
    eta = eta_des * (1 - c_eta (nu/nu_des - 1)^2)

Health parameters scale the map: ``eta * (1 + eff_mod)`` and ``Wc * (1 + flow_mod)``
(``Phi * (1 + flow_mod)`` for turbines), the N-CMAPSS convention. For a compressor the map's
pressure ratio at a given map point is kept and the specific work is ``Dh_is / eta``.
"""

from dataclasses import dataclass

import casadi as ca
import numpy as np

CHOKE_FLOW_FRACTION = 0.999  # chi is centred where phi is this fraction of the choke flow
DEEP_CHOKE = 9.0  # mu (b_ch - b_d): chi's continuation below PR 1 (PR = 1 at b_ch - 4.5 / mu)
SURGE_FLOOR = 1e-4  # smooth floor of phi_ch1 / phi_stall - 1 in the surge-line formula


@dataclass(frozen=True)
class CompressorMap:
    wc_des: float  # corrected flow at the SLS design point [kg/s]
    work_des: float  # specific work / inlet total temperature at design [J/(kg K)]
    eta_des: float  # isentropic efficiency at the SLS design point [-]
    phi_ch1: float  # choke flow coefficient at n = 1, relative to the design point
    k_ch: float  # choke flow ~ n^k_ch
    lam: float  # steepness of the flow coefficient along beta
    kappa: float  # relative slope of the Euler work line
    c_phi: float  # incidence-loss curvature
    c_n: float  # efficiency fall-off with speed
    n_pk: float  # relative corrected speed of the efficiency peak (aero design point)
    phi_opt1: float  # optimum-incidence flow coefficient at n = 1 (relative)
    phi_s1: float  # stall flow coefficient at n = 1 (relative)
    k_work: float = 1.0  # flow coefficient of the work line: Wc / (Wc_des n^k_work)
    k_s: float = 0.0  # stall flow coefficient ~ n^k_s
    mu: float = 3.0  # steepness of the choke loss along beta

    # ---------------------------------------------------------------- derived constants
    @property
    def d_choke(self) -> float:
        return self.phi_ch1 - 1.0

    @property
    def beta_choke(self) -> float:
        """Map line where the flow is CHOKE_FLOW_FRACTION of the choke flow (centre of chi)."""
        return float(np.log((1.0 / CHOKE_FLOW_FRACTION - 1.0) / self.d_choke) / self.lam)

    @property
    def eta_pk(self) -> float:
        """Peak island efficiency, so that the map gives ``eta_des`` at (n, beta) = (1, 0)."""
        return self.eta_des / float(self._eta_shape(1.0, 0.0))

    # ---------------------------------------------------------------- map functions
    def phi_choke(self, n):
        return self.phi_ch1 * n ** (self.k_ch - 1.0)

    def phi(self, n, beta):
        """Flow coefficient relative to the design point (flow_mod not included)."""
        return self.phi_choke(n) / (1.0 + self.d_choke * ca.exp(self.lam * beta))

    def flow(self, n, beta, flow_mod=0.0):
        return self.wc_des * n * self.phi(n, beta) * (1.0 + flow_mod)

    def phi_hat(self, beta):
        """Flow coefficient relative to the speed line's own choke, ``phi / n^(k_ch - 1)``
        (a function of beta alone)."""
        return self.phi_ch1 / (1.0 + self.d_choke * ca.exp(self.lam * beta))

    def phi_work(self, n, beta):
        """Flow coefficient of the blading that sets work, incidence and stall,
        ``Wc / (Wc_des n^k_work) = phi_hat n^(k_ch - k_work)``."""
        return self.phi_hat(beta) * n ** (self.k_ch - self.k_work)

    def work(self, n, beta, slope_mod=0.0):
        """Euler specific work of the map / inlet total temperature [J/(kg K)]; ``slope_mod``
        scales the work line's slope ``kappa`` by ``1 + slope_mod`` (the speed lines' slope:
        :class:`~engine_model.physics.effect_library.MapSlope`)."""
        kappa = self.kappa * (1.0 + slope_mod)
        return self.work_des * n**2 * (1.0 - kappa * (self.phi_work(n, beta) - 1.0))

    @property
    def beta_deep_choke(self) -> float:
        """Map line ``b_d`` from which the choke line continues below PR = 1."""
        return self.beta_choke - DEEP_CHOKE / self.mu

    @property
    def beta_unit_pr(self) -> float:
        """Map line where the continued choke line passes PR = 1 (``b_ch - 4.5 / mu``)."""
        return self.beta_choke - 0.5 * DEEP_CHOKE / self.mu

    def _chi(self, beta):
        """Choke factor of the isentropic head: the shock loss of the logistic first term,
        continued below PR = 1 by ``softplus(mu (b_d - b))`` (module docstring, 2.)."""
        x = self.mu * (self.beta_deep_choke - beta)
        softplus = ca.fmax(x, 0.0) + ca.log1p(ca.exp(-ca.fabs(x)))  # ln(1 + e^x), no overflow
        return 1.0 / (1.0 + ca.exp(-self.mu * (beta - self.beta_choke))) - softplus

    def _eta_shape(self, n, beta):
        x = self.phi_work(n, beta) / self.phi_opt1 - 1.0
        return ca.exp(-self.c_phi * x**2 - self.c_n * (n - self.n_pk) ** 2) * self._chi(beta)

    def eta_map(self, n, beta):
        return self.eta_pk * self._eta_shape(n, beta)

    def efficiency(self, n, beta, eff_mod=0.0):
        return self.eta_map(n, beta) * (1.0 + eff_mod)

    def head(self, n, beta, slope_mod=0.0):
        """Isentropic head / inlet total temperature [J/(kg K)] (sets the pressure ratio)."""
        return self.eta_map(n, beta) * self.work(n, beta, slope_mod)

    def beta_surge(self, n=1.0, flow_mod=0.0):
        """Map line of the surge line at speed ``n``: where the actual flow coefficient of
        the blading, ``(1 + flow_mod) phi_work``, falls to the stall value
        ``phi_s1 n^k_s``."""
        target = self.phi_s1 * n**self.k_s / ((1.0 + flow_mod) * n ** (self.k_ch - self.k_work))
        # a compressor that has lost so much flow capacity that its stall flow coefficient lies
        # beyond choke is stalled along the whole speed line: the smooth floor puts its surge
        # line deep in choke (b_ch - 2.1 to - 2.3, PR_surge at or below 1, negative margin)
        # instead of taking log(<= 0)
        g = self.phi_ch1 / target - 1.0
        g = 0.5 * (g + SURGE_FLOOR + ca.sqrt((g - SURGE_FLOOR) ** 2 + SURGE_FLOOR**2))
        return ca.log(g / self.d_choke) / self.lam

    def on_map(self, beta) -> np.ndarray:
        """Where a root is meaningful (figures for the design's ``mu = 3``, ``lam = 1``):
        from deep choke (``b_ch - 4``, one map unit below the
        start of the continuation past PR = 1, where the isentropic head is -3 times the
        island's: a total-pressure loss no compressor runs at) to at most one map unit
        beyond the new-engine surge line at 20 % speed (the highest surge line). On the
        high-pressure-ratio lines (HPC, fan near design speed) the lowest part of that range
        lies below PR 0.2, where the isentropic exit temperature leaves the gas model's range;
        no root goes there (of 100,000 random envelope points the HPC and fan stay above
        ``b_ch + 3.7``; the booster, choked at ground idle, reaches ``b_ch - 4.0``)."""
        b = np.asarray(beta, float)
        return (b > self.beta_choke - 4.0) & (b < float(self.beta_surge(0.2)) + 1.0)


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
