"""Engine components, one function each, station by station (SAE ARP755 numbering).

Every function takes and returns SI quantities (K, Pa, kg/s, J/kg, W) and works on floats or
CasADi symbols alike. The assembly into a two-spool turbofan is in :mod:`turbofan`.
"""

from dataclasses import dataclass

import casadi as ca

from engine_model.units import P_STD_PA, T_STD_K

from . import gas


def corrected_flow(W, T, P):
    """W sqrt(T/T_std) / (P/P_std) [kg/s]."""
    return W * ca.sqrt(T / T_STD_K) / (P / P_STD_PA)


def physical_flow(Wc, T, P):
    return Wc * (P / P_STD_PA) / ca.sqrt(T / T_STD_K)


def duct_loss(P_in, Wc, Wc_des, dp_des):
    """Total-pressure loss of a duct, dP/P proportional to corrected flow squared.

    Walsh & Fletcher ch. 5: the loss of a duct scales with its inlet dynamic head, i.e. with
    the square of the corrected flow; ``dp_des`` is dP/P at the design corrected flow.
    """
    return P_in * (1.0 - dp_des * (Wc / Wc_des) ** 2)


def compressor(cmap, T_in, P_in, n, beta, eff_mod=0.0, flow_mod=0.0, far=0.0, slope_mod=0.0,
               pr_mod=0.0):
    """Compressor on its map: corrected flow, exit state, specific work and stall margin.

    The map (:class:`maps.CompressorMap`) gives the isentropic head, hence the pressure
    ratio, at ``(n, beta)``; the specific work is the map's Euler work divided by
    ``1 + eff_mod`` (``dh = head / eta`` with the efficiency scaled by ``1 + eff_mod``; written
    without the division by ``eta``, which passes through 0 where the choke line continues
    below PR = 1). The stall margin is taken at constant corrected speed (SAE
    ARP1420; Walsh & Fletcher ch. 5), ``SM = 100 (PR_surge(N) / PR - 1)``, against the surge
    line of the compressor's own flow capacity (:meth:`maps.CompressorMap.beta_surge`).
    ``slope_mod`` scales the slope of the map's work line, hence of its speed lines
    (:meth:`maps.CompressorMap.work`; 0 for the map as designed).

    ``pr_mod`` is the map's pressure-ratio scaler, the third of the classic scalers of a
    component map beside flow and efficiency (Kurzke, ASME 96-GT-164; Li & Pilidis, ASME
    J. Eng. Gas Turbines Power 132, 2010; C-MAPSS's ``<c>_PR_mod``, Saxena et al. 2008,
    Table 1): the isentropic head of every map point, the surge line's included, is
    ``(1 + pr_mod)`` times the map's, and the work with it at the map's efficiency
    (``dh = (1 + pr_mod) work / (1 + eff_mod)``). Written on the head rather than on
    ``PR - 1`` (GasTurb's form), to which it is equal to first order in ``PR - 1``, so that
    the efficiency of a map point stays the map's and the surge line scales with the map
    (the stall margin at a map point moves only through the curvature of ``PR`` in the
    head). 0 (the default) leaves the expression graph as it is.
    """
    def scaled(x):
        return x if isinstance(pr_mod, (int, float)) and pr_mod == 0 else x * (1.0 + pr_mod)

    wc = cmap.flow(n, beta, flow_mod)
    W = physical_flow(wc, T_in, P_in)
    head = scaled(cmap.head(n, beta, slope_mod) * T_in)  # isentropic specific work [J/kg]
    eta = cmap.efficiency(n, beta, eff_mod)
    h_in = gas.h(T_in, far)
    cp_in = gas.cp(T_in, far)
    T_is = gas.t_from_h(h_in + head, far, T_in + head / cp_in)
    pr = gas.pressure_ratio_isentropic(T_in, T_is, far)
    dh = scaled(cmap.work(n, beta, slope_mod) * T_in) / (1.0 + eff_mod)  # = head / eta
    T_out = gas.t_from_h(h_in + dh, far, T_in + dh / cp_in)
    # surge line at the same corrected speed
    head_s = scaled(cmap.head(n, cmap.beta_surge(n, flow_mod), slope_mod) * T_in)
    T_is_s = gas.t_from_h(h_in + head_s, far, T_in + head_s / cp_in)
    pr_s = gas.pressure_ratio_isentropic(T_in, T_is_s, far)
    return {
        "Wc": wc, "W": W, "T_out": T_out, "P_out": P_in * pr, "PR": pr, "eta": eta,
        "dh": dh, "SM": 100.0 * (pr_s / pr - 1.0), "PR_surge": pr_s,
    }


def smooth_step(t):
    """C-infinity step from 0 (t <= 0) to 1 (t >= 1), exactly flat outside [0, 1]:
    ``e^(-1/t) / (e^(-1/t) + e^(-1/(1-t)))`` on the argument clipped to [1e-6, 1 - 1e-6]."""
    tc = ca.fmin(ca.fmax(t, 1e-6), 1.0 - 1e-6)
    a = ca.exp(-1.0 / tc)
    return a / (a + ca.exp(-1.0 / (1.0 - tc)))


def burner(T_in, P_in, W_air, T_out, dp, eta_b, lhv=gas.LHV_KEROSENE):
    """Burner: fuel-air ratio and fuel flow needed to reach ``T_out`` from air at ``T_in``.

    Energy balance with the 288.15 K datum of :mod:`gas`, fuel supplied at the datum:
    ``h_air(T_in) + far eta_b LHV = (1 + far) h(T_out, far)``, which is linear in ``far``
    because ``(1+far) h(T, far) = (1+far) h_air(T) + far h_B(T)``.
    """
    h_air_out = gas.h(T_out, 0.0)
    h_b_out = 2.0 * (gas.h(T_out, 1.0) - h_air_out)  # far/(1+far) = 1/2 at far = 1
    far = (h_air_out - gas.h(T_in, 0.0)) / (eta_b * lhv - h_air_out - h_b_out)
    return {"far": far, "Wf": far * W_air, "P_out": P_in * (1.0 - dp), "W_out": W_air * (1 + far)}


def burner_loading(P_in, T_in, W_in):
    """Lefebvre's burner loading parameter without the geometry terms, P^1.75 e^(T/300) / W."""
    return (P_in / P_STD_PA) ** 1.75 * ca.exp(T_in / 300.0) / W_in


def burner_efficiency(theta_rel, eta_des):
    """Combustion efficiency versus relative loading ``theta_rel = theta/theta_des``.

    Efficiency falls as the loading parameter drops (low pressure, low inlet temperature:
    altitude idle), the trend of Lefebvre & Ballal, *Gas Turbine Combustion*, 3rd ed., ch. 5
    (efficiency against the loading parameter). The form ``1 - eta = (1 - eta_des)
    (theta_des/theta)^0.5`` and its exponent 0.5 are **assumed** (a class-typical shape, not
    read from a figure and not fitted). It has no floor: the loss is ``theta_rel^-0.5`` times
    the design loss (4.5 times at 5 % of the design loading), and the efficiency would reach
    zero only at ``theta_rel = (1 - eta_des)^2``.
    """
    return 1.0 - (1.0 - eta_des) / ca.sqrt(theta_rel)


def turbine(tmap, T_in, P_in, far, pr, n_rpm, eff_mod=0.0, flow_mod=0.0):
    """Turbine on its map: flow capacity, exit state, specific work."""
    phi = tmap.capacity(pr, flow_mod)
    W_cap = phi * P_in / ca.sqrt(T_in)
    T_is = gas.t_isentropic(T_in, far, 1.0 / pr)
    h_in = gas.h(T_in, far)
    dh_is = h_in - gas.h(T_is, far)
    eta = tmap.efficiency(n_rpm, dh_is, eff_mod)
    dh = eta * dh_is
    T_out = gas.t_from_h(h_in - dh, far, T_in - dh / gas.cp(T_in, far))
    return {"W_cap": W_cap, "T_out": T_out, "P_out": P_in / pr, "dh": dh, "eta": eta}


def mixer(W1, T1, far1, W2, T2, far2):
    """Adiabatic mixing of two streams at equal total pressure: mass, fuel and energy balance."""
    W = W1 + W2
    fuel = W1 * far1 / (1.0 + far1) + W2 * far2 / (1.0 + far2)
    far = fuel / (W - fuel)
    H = W1 * gas.h(T1, far1) + W2 * gas.h(T2, far2)
    T_guess = (W1 * T1 + W2 * T2) / W
    T = gas.t_from_h(H / W, far, T_guess)
    return {"W": W, "T": T, "far": far}


def smooth_max(a, b, eps):
    """C-infinity approximation of max(a, b); the error is at most eps/2."""
    return 0.5 * (a + b + ca.sqrt((a - b) ** 2 + eps**2))


@dataclass(frozen=True)
class NozzleDischarge:
    """Discharge (flow) coefficient of a convergent nozzle versus its pressure ratio
    ``NPR = Pt / P_amb``::

        Cd(NPR) = cd_inf - (cd_inf - cd_1) exp(-(NPR - 1) / npr_scale)

    The effective throat area of a convergent nozzle is smaller than its geometric area (the
    jet goes on contracting after the exit plane, and the boundary layer displaces flow); the
    contraction shrinks as the pressure ratio rises, and it goes on shrinking beyond the
    critical pressure ratio because the sonic line is curved: the mean velocity in the exit
    plane is still subsonic when the nozzle first chokes and rises with the downstream
    expansion (Grey & Wilsted, *Performance of conical jet nozzles in terms of flow and
    velocity coefficients*, NACA TR-933, 1949, pressure ratios 1-2.8; Bragg, *Effect of
    compressibility on the discharge coefficient of orifices and convergent nozzles*,
    J. Mech. Eng. Sci. 2, 1960). The exponential approach from ``cd_1`` (NPR -> 1) to
    ``cd_inf`` is a smooth monotone form of that behaviour; the values in
    :class:`design.DesignSpec` are class-typical for short conical nozzles (they depend on the
    cone angle), not read from one figure. Only the ratio to the design point's Cd acts on the
    cycle: the nozzle areas are sized at the design point with it.

    The velocity coefficient stays constant: Grey & Wilsted find it constant below the
    critical pressure ratio and falling slightly above it, by an amount that depends on the
    pressure ratio only and not on the geometry - the incomplete expansion of a convergent
    nozzle, which :func:`convergent_nozzle` computes explicitly through its pressure thrust.
    """

    cd_1: float = 0.93
    cd_inf: float = 0.985
    npr_scale: float = 0.7

    def __call__(self, npr):
        return self.cd_inf - (self.cd_inf - self.cd_1) * ca.exp(-(npr - 1.0) / self.npr_scale)


def convergent_nozzle(Pt, Tt, far, P_amb, area, cd, cv=0.99, eps=2e-3):
    """Convergent nozzle: mass flow it passes and gross thrust, choked or not.

    ``cd`` is a :class:`NozzleDischarge` (evaluated at ``Pt / P_amb``) or a fixed value. The
    throat static-to-total pressure ratio is ``max(P_amb/Pt, critical)`` with a smooth max,
    so the switch between unchoked and choked flow is C-infinity. Expansion to the throat uses
    the real-gas entropy function; the critical ratio uses gamma at the sonic temperature.
    ``Fg = Cv W V + A (Ps - P_amb)``: momentum with the velocity coefficient, plus the
    pressure thrust of an under-expanded (choked) jet on the geometric area.
    """
    if callable(cd):
        cd = cd(Pt / P_amb)
    g_t = gas.gamma(Tt, far)
    T_star = 2.0 * Tt / (g_t + 1.0)
    g = gas.gamma(T_star, far)
    x_crit = (2.0 / (g + 1.0)) ** (g / (g - 1.0))
    x = smooth_max(P_amb / Pt, x_crit, eps)
    Ts = gas.t_isentropic(Tt, far, x)
    dh = ca.fmax(gas.h(Tt, far) - gas.h(Ts, far), 1e-6)
    V = ca.sqrt(2.0 * dh)
    Ps = x * Pt
    rho = Ps / (gas.R_GAS * Ts)
    W = cd * area * rho * V
    Fg = W * cv * V + area * (Ps - P_amb)
    return {"W": W, "Fg": Fg, "Ps": Ps, "V": V, "x": x, "x_crit": x_crit, "Cd": cd}


def mach_from_flow(W, Tt, Pt, area, far=0.0, mach_guess=0.3, n_iter=5):
    """Subsonic Mach number at a station of given area and flow (perfect-gas flow function
    with gamma at the total temperature), Newton iterations in the graph."""
    g = gas.gamma(Tt, far)
    q_target = W * ca.sqrt(gas.R_GAS * Tt) / (area * Pt * ca.sqrt(g))
    M = mach_guess
    e = (g + 1.0) / (2.0 * (g - 1.0))
    for _ in range(n_iter):
        base = 1.0 + 0.5 * (g - 1.0) * M**2
        q = M * base**-e
        dq = base**-e - M * e * base ** (-e - 1.0) * (g - 1.0) * M
        M = M - (q - q_target) / dq
    return M


def static_pressure(Pt, Tt, mach, far=0.0):
    g = gas.gamma(Tt, far)
    return Pt * (1.0 + 0.5 * (g - 1.0) * mach**2) ** (-g / (g - 1.0))
