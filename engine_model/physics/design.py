"""Design point of the 90,000 lbf class two-spool high-bypass turbofan.

The design point is sea-level static, ISA, TRA 100, theta = 0. Its measured quantities are the
C-MAPSS early-life means of ``data_samples/cmapss-fd002-operating-points.csv`` (row alt 0,
Mach 0, TRA 100): T24, T30, T50, P2, P15, P30, epr = P50/P2, BPR, W31, W32, Nf, Nc. Quantities
that C-MAPSS does not publish are typical values of the engine class (Walsh & Fletcher ch. 5
and 6; Saravanamuttoo et al. ch. 3), each a named field of :class:`DesignSpec`.

The calculation (:func:`design_engine`) is a cycle "design mode": it runs the component
functions of :mod:`components` forward at the design point with the chosen efficiencies and
losses, and solves three unknowns - burner exit temperature T40, LPT efficiency and fan inlet
flow W2 - so that T50, P50 and the net thrust match their targets. Map scaling, nozzle areas,
turbine flow capacities and bleed fractions follow. No factor is tuned per operating point:
the five other reference points are off-design predictions (README, "Model versus C-MAPSS").
"""

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import brentq, fsolve

from engine_model.units import LBF_TO_N, LBM_TO_KG, P_STD_PA, PSIA_TO_PA, T_STD_K, r_to_k

from . import atmosphere, components, gas
from .bleed_schedule import BleedValveSchedule
from .components import NozzleDischarge
from .maps import CompressorMap, TurbineMap
from .schedule import ThrottleSchedule


@dataclass(frozen=True)
class DesignSpec:
    # --- C-MAPSS SLS TRA 100 early-life means (reference table) ---
    T24_R: float = 642.3067
    T30_R: float = 1586.3954
    T50_R: float = 1402.0268
    P2_psia: float = 14.62
    P15_psia: float = 21.6094
    P30_psia: float = 554.0603
    epr: float = 1.30
    BPR: float = 8.4154
    W31_lbms: float = 38.9468
    W32_lbms: float = 23.3666
    Nf_rpm: float = 2388.0523
    Nc_rpm: float = 9055.8111
    # --- class-typical choices (not published by C-MAPSS) ---
    Fn_lbf: float = 90000.0  # SLS take-off thrust, "90,000 lbf class"
    eta_fan: float = 0.90
    eta_lpc: float = 0.88
    eta_hpt: float = 0.89
    dp_bypass: float = 0.010  # bypass duct dP/P
    dp_icd: float = 0.015  # LPC-HPC transition duct dP/P
    dp_burner: float = 0.040  # burner dP/P at design, scaled with corrected flow squared
    #                           (the cold, friction loss; no hot Rayleigh loss is modelled)
    eta_burner: float = 0.9995
    eta_mech: float = 0.995  # both spools
    f_interstage: float = 0.5  # fraction of HPC enthalpy rise at the LPT-coolant port
    mach_hpc_exit: float = 0.25
    # both nozzles: discharge coefficient versus pressure ratio (components.NozzleDischarge),
    # constant velocity coefficient
    nozzle_cd: NozzleDischarge = field(default_factory=NozzleDischarge)
    nozzle_cv: float = 0.99
    # share of the HPT coolant W31 that cools the first nozzle guide vanes: it joins the gas
    # before the rotor and does work there; the rest cools the rotor and mixes after it
    # (turbofan.py). Class-typical: the first NGV row, in the combustor's exit temperature
    # traverse, takes the larger part of a single-stage HPT's cooling air.
    f_hpt_vane: float = 0.6
    # design stall margins at SLS take-off [%], at constant corrected speed (components.
    # compressor); class-typical (Walsh & Fletcher ch. 5.2.5: 15-25 % on core compressors,
    # 10-20 % on fans at take-off). The booster's pressure ratio is only 1.31, so its 14 % in
    # pressure ratio is a 50 % rise of its isentropic head.
    sm_fan: float = 12.0
    sm_lpc: float = 14.0
    sm_hpc: float = 25.0
    # variable bleed valves: opening on corrected core and fan speeds and Mach, limited at
    # ground-idle fan speeds (bleed_schedule.py; designed from benchmarks/vbv_schedule_audit.py)
    vbv: BleedValveSchedule = field(default_factory=BleedValveSchedule)
    # TRA -> corrected fan speed, idle to maximum, with the limiters (schedule.py)
    throttle: ThrottleSchedule = field(default_factory=ThrottleSchedule)
    # Compressor maps (maps.py). Class-typical shape parameters, none fitted to C-MAPSS data
    # (only the islands' peaks, (n_pk, phi_opt1) below, are made self-consistent with the
    # model's own cruise point):
    # - phi_ch1: choke flow / design flow at 100 % speed: 5-6 % for the booster and HPC; 12 %
    #   for the fan, whose working line at the same corrected speed lies nearer choke at
    #   cruise (choked bypass nozzle) than at sea-level take-off (unchoked nozzle).
    # - k_ch: choke flow ~ n^k_ch: 2.5 for a 9-10 stage HPC whose rear stages choke at part
    #   speed (Walsh & Fletcher ch. 5.2; Saravanamuttoo et al. ch. 9 on part-speed
    #   mismatch), 1 for the booster, 0.5 for a single fan stage whose throats choke at a
    #   corrected flow that falls more slowly than speed.
    # - k_work: 1 for the single-stage fan (physical flow coefficient); k_ch for the
    #   multistage booster and HPC (stage-averaged flow coefficient, maps.py item 1).
    # - k_s: the fan's stall flow coefficient ~ n^0.1 (transonic stall at high speed).
    # - kappa: relative slope of the specific-work line along a speed line. One repeating
    #   stage has kappa = phi_d (tan a1 + tan b2) / psi_d = 1.5 (Dixon & Hall's typical stage,
    #   phi_d 0.5, psi_d 0.4); stage matching steepens the overall characteristic of a
    #   multistage compressor at high speed (Cumpsty, Compressor Aerodynamics, ch. 4;
    #   Saravanamuttoo et al. ch. 5.6) and a transonic fan's high-speed lines are nearly
    #   vertical (unique incidence). Values 3-5.5 give 100 % speed lines that span 4-8 %
    #   of flow between the take-off point and stall, as class maps do.
    # - c_phi: incidence-loss curvature: 4-6 points of efficiency between peak and surge.
    # - (n_pk, phi_opt1): the island's peak, the aerodynamic design point: the cruise point
    #   (35 kft, Mach 0.8, ISA, the profiles' mid cruise TRA 70), where a civil engine spends
    #   most of its life and for which its compressors are designed (Walsh & Fletcher ch. 7.3;
    #   Cumpsty, Jet Propulsion, ch. 11): the (n, phi_work) of that point as printed by
    #   ``benchmarks/map_design_point.py``, iterated until they stop changing (0.001) with
    #   the present VBV schedule, nozzle discharge coefficients and cooling split.
    # - c_n: efficiency fall-off with speed: 5-10 points from the design speed to 50-60 %.
    # - lam (beta scale) is a parametrisation choice and does not change the map's shape in
    #   physical coordinates.
    fan_map: dict = field(default_factory=lambda: dict(
        phi_ch1=1.12, k_ch=0.5, k_work=1.0, k_s=0.1, lam=1.0, kappa=5.0, c_phi=4.0, c_n=0.6,
        n_pk=0.901, phi_opt1=1.039))
    lpc_map: dict = field(default_factory=lambda: dict(
        phi_ch1=1.06, k_ch=1.0, k_work=1.0, lam=1.0, kappa=5.5, c_phi=8.0, c_n=0.6, n_pk=0.920,
        phi_opt1=0.952))
    hpc_map: dict = field(default_factory=lambda: dict(
        phi_ch1=1.05, k_ch=2.5, k_work=2.5, lam=1.0, kappa=3.0, c_phi=8.0, c_n=0.6, n_pk=0.925,
        phi_opt1=0.992))
    c_eta_hpt: float = 0.5
    c_eta_lpt: float = 0.5


@dataclass(frozen=True)
class EngineDesign:
    spec: DesignSpec
    fan: CompressorMap
    lpc: CompressorMap
    hpc: CompressorMap
    hpt: TurbineMap
    lpt: TurbineMap
    dp_inlet: float
    wc2_des: float
    wc13_des: float
    wc24_des: float
    wc3_des: float
    nrl_des: float  # LPC corrected speed at design [rpm]
    nrc_des: float  # HPC corrected speed (on T24) at design [rpm]
    f31: float
    f32: float
    A18: float  # bypass nozzle throat area [m^2]
    A8: float  # core nozzle throat area [m^2]
    A30: float  # HPC exit annulus area [m^2]
    T40_des: float
    loading_des: float
    pr_hpt_des: float
    pr_lpt_des: float
    # scales of the residuals (design values)
    W13_des: float
    W25_des: float
    W4_des: float
    W48_des: float
    W50_des: float
    P_hp_des: float
    P_lp_des: float
    point: dict  # every design-point quantity, SI

    def nf_demand_pct(self, tra):
        """Scheduled corrected fan speed [%] for throttle-resolver angle ``tra`` [%]
        (:class:`schedule.ThrottleSchedule`, before the limiter)."""
        return self.spec.throttle.demand_pct(tra)

    def nf_command_pct(self, tra, T2_K):
        """Commanded corrected fan speed [%]: the schedule limited by the N1 red line."""
        return self.spec.throttle.command_pct(tra, T2_K)

    def tra_from_pct(self, pct):
        """The throttle-resolver angle [%] that demands corrected fan speed ``pct`` [%] (the
        inverse of :meth:`nf_demand_pct` above idle)."""
        return self.spec.throttle.tra_from_pct(pct)


def _compressor_map(kw, wc, T_in, head, dh, eta, pr, sm):
    """The map of one compressor scaled at the design point, its stall flow coefficient
    ``phi_s1`` placed so that the SLS design point has stall margin ``sm`` [%] at constant
    corrected speed (the definition of :func:`components.compressor`)."""
    base = CompressorMap(wc_des=wc, work_des=dh / T_in, eta_des=eta, phi_s1=0.5, **kw)
    pr_s = pr * (1.0 + sm / 100.0)
    T_is_s = gas.t_isentropic(T_in, 0.0, pr_s)
    head_s = float(gas.h(T_is_s) - gas.h(T_in)) / T_in

    def gap(b):
        return float(base.head(1.0, b)) - head_s

    grid = np.linspace(0.0, 15.0, 301)
    b_top = grid[int(np.argmax([gap(b) for b in grid]))]  # peak of the 100 % speed line
    if gap(b_top) <= 0.0:
        raise ValueError(f"stall margin {sm} % is beyond the peak of the 100 % speed line")
    b_s = brentq(gap, 0.0, b_top, xtol=1e-14)
    return replace(base, phi_s1=float(base.phi(1.0, b_s)))


def design_engine(spec: DesignSpec | None = None) -> EngineDesign:
    s = spec or DesignSpec()
    T2 = T_STD_K
    P_amb = P_STD_PA
    P2 = s.P2_psia * PSIA_TO_PA
    dp_inlet = 1.0 - P2 / P_amb
    # fan: pressure ratio from the bypass-duct pressure and the duct loss
    P21 = s.P15_psia * PSIA_TO_PA / (1.0 - s.dp_bypass)
    pr_fan = P21 / P2
    T21_is = gas.t_isentropic(T2, 0.0, pr_fan)
    head_fan = gas.h(T21_is) - gas.h(T2)
    dh_fan = head_fan / s.eta_fan
    T21 = gas.t_from_h(gas.h(T2) + dh_fan, 0.0, T2)
    # LPC: efficiency chosen, pressure ratio from the measured T24
    T24 = r_to_k(s.T24_R)
    dh_lpc = gas.h(T24) - gas.h(T21)
    head_lpc = s.eta_lpc * dh_lpc
    T24_is = gas.t_from_h(gas.h(T21) + head_lpc, 0.0, T21)
    pr_lpc = float(gas.pressure_ratio_isentropic(T21, T24_is, 0.0))
    P24 = P21 * pr_lpc
    P25 = P24 * (1.0 - s.dp_icd)
    T25 = T24
    # HPC: pressure ratio and exit temperature measured -> efficiency
    T30 = r_to_k(s.T30_R)
    P30 = s.P30_psia * PSIA_TO_PA
    pr_hpc = P30 / P25
    T30_is = gas.t_isentropic(T25, 0.0, pr_hpc)
    head_hpc = gas.h(T30_is) - gas.h(T25)
    dh_hpc = gas.h(T30) - gas.h(T25)
    eta_hpc = head_hpc / dh_hpc
    h_int = gas.h(T25) + s.f_interstage * dh_hpc
    T_int = gas.t_from_h(h_int, 0.0, T25)
    P40 = P30 * (1.0 - s.dp_burner)
    P50_target = s.epr * P2
    T50_target = r_to_k(s.T50_R)
    W31 = s.W31_lbms * LBM_TO_KG
    W32 = s.W32_lbms * LBM_TO_KG
    Nc = s.Nc_rpm
    Nf = s.Nf_rpm

    def hot_section(T40, eta_lpt, W2):
        W25 = W2 / (1.0 + s.BPR)
        W13 = W2 - W25
        W3 = W25 - W31 - W32
        brn = components.burner(T30, P30, W3, T40, s.dp_burner, s.eta_burner)
        far4, W4 = brn["far"], brn["W_out"]
        P_hpc = W25 * (h_int - gas.h(T25)) + (W25 - W32) * (gas.h(T30) - h_int)
        # HPT coolant W31 (HPC exit air): the vane share joins before the rotor (station 41,
        # does work), the rotor share mixes after it (43 -> 45)
        m1 = components.mixer(W4, T40, far4, s.f_hpt_vane * W31, T30, 0.0)
        W41, T41, far41 = m1["W"], m1["T"], m1["far"]
        dh_hpt = P_hpc / (s.eta_mech * W41)
        h43 = gas.h(T41, far41) - dh_hpt
        T43 = gas.t_from_h(h43, far41, T41 - dh_hpt / gas.cp(T41, far41))
        T43_is = gas.t_from_h(gas.h(T41, far41) - dh_hpt / s.eta_hpt, far41, T43)
        pr_hpt = 1.0 / gas.pressure_ratio_isentropic(T41, T43_is, far41)
        P45 = P40 / pr_hpt
        m45 = components.mixer(W41, T43, far41, (1.0 - s.f_hpt_vane) * W31, T30, 0.0)
        W48, T48, far48 = m45["W"], m45["T"], m45["far"]
        # LPT coolant W32 (HPC interstage air) joins at the LPT rotor inlet, station 49
        m2 = components.mixer(W48, T48, far48, W32, T_int, 0.0)
        W49, T49, far49 = m2["W"], m2["T"], m2["far"]
        P_lp = W2 * dh_fan + W25 * dh_lpc
        dh_lpt = P_lp / (s.eta_mech * W49)
        T50 = gas.t_from_h(gas.h(T49, far49) - dh_lpt, far49, T49 - dh_lpt / gas.cp(T49, far49))
        T50_is = gas.t_from_h(gas.h(T49, far49) - dh_lpt / eta_lpt, far49, T50)
        pr_lpt = 1.0 / gas.pressure_ratio_isentropic(T49, T50_is, far49)
        P50 = P45 / pr_lpt
        W50, far50 = W49, far49
        byp = components.convergent_nozzle(P21 * (1 - s.dp_bypass), T21, 0.0, P_amb, 1.0,
                                           s.nozzle_cd, s.nozzle_cv)
        core = components.convergent_nozzle(P50, T50, far50, P_amb, 1.0, s.nozzle_cd,
                                            s.nozzle_cv)
        # thrust per unit area times the area that passes the flow
        A18 = W13 / byp["W"]
        A8 = W50 / core["W"]
        Fn = byp["Fg"] * A18 + core["Fg"] * A8  # static: no ram drag
        return dict(W2=W2, W25=W25, W13=W13, W3=W3, W4=W4, W41=W41, W48=W48, W49=W49,
                    W50=W50, far4=far4, far41=far41, Wf=brn["Wf"], T41=T41, T43=T43, T48=T48,
                    T49=T49, far48=far48,
                    T50=T50, P45=P45, P50=P50, pr_hpt=pr_hpt, pr_lpt=pr_lpt, far50=far50,
                    A18=A18, A8=A8,
                    Fn=Fn, P_hpc=P_hpc, P_lp=P_lp, dh_hpt=dh_hpt, dh_lpt=dh_lpt)

    Fn_target = s.Fn_lbf * LBF_TO_N

    def eqs(u):
        T40, eta_lpt, W2 = u[0] * 1000.0, u[1], u[2] * 1000.0
        r = hot_section(T40, eta_lpt, W2)
        return [float(r["T50"]) / T50_target - 1.0, float(r["P50"]) / P50_target - 1.0,
                float(r["Fn"]) / Fn_target - 1.0]

    sol, info, ier, msg = fsolve(eqs, [1.6, 0.9, 1.4], full_output=True, xtol=1e-13)
    if ier != 1 or max(abs(np.asarray(eqs(sol)))) > 1e-9:
        raise RuntimeError(f"design point did not converge: {msg}")
    T40, eta_lpt, W2 = sol[0] * 1000.0, float(sol[1]), sol[2] * 1000.0
    hs = {k: float(v) for k, v in hot_section(T40, eta_lpt, W2).items()}
    W25 = hs["W25"]

    wc2 = float(components.corrected_flow(W2, T2, P2))
    wc21 = float(components.corrected_flow(W25, T21, P21))
    wc25 = float(components.corrected_flow(W25, T25, P25))
    fan = _compressor_map(s.fan_map, wc2, T2, head_fan, dh_fan, s.eta_fan, pr_fan, s.sm_fan)
    lpc = _compressor_map(s.lpc_map, wc21, T21, head_lpc, dh_lpc, s.eta_lpc, pr_lpc, s.sm_lpc)
    hpc = _compressor_map(s.hpc_map, wc25, T25, head_hpc, dh_hpc, eta_hpc, pr_hpc, s.sm_hpc)
    dh_is_hpt = hs["dh_hpt"] / s.eta_hpt
    dh_is_lpt = hs["dh_lpt"] / eta_lpt
    hpt = TurbineMap(phi_des=hs["W41"] * np.sqrt(hs["T41"]) / P40, pr_des=hs["pr_hpt"],
                     eta_des=s.eta_hpt, nu_des=Nc / np.sqrt(dh_is_hpt), c_eta=s.c_eta_hpt)
    lpt = TurbineMap(phi_des=hs["W49"] * np.sqrt(hs["T49"]) / hs["P45"], pr_des=hs["pr_lpt"],
                     eta_des=eta_lpt, nu_des=Nf / np.sqrt(dh_is_lpt), c_eta=s.c_eta_lpt)
    W30 = W25 - W32
    m3 = s.mach_hpc_exit
    g30 = float(gas.gamma(T30))
    q = m3 * (1 + 0.5 * (g30 - 1) * m3**2) ** (-(g30 + 1) / (2 * (g30 - 1)))
    A30 = W30 * np.sqrt(gas.R_GAS * T30) / (q * P30 * np.sqrt(g30))
    W3 = hs["W3"]
    point = dict(T2=T2, P2=P2, T21=T21, P21=P21, T24=T24, P24=P24, P25=P25, T30=T30, P30=P30,
                 T40=T40, P40=P40, eta_hpc=eta_hpc, eta_lpt=eta_lpt, pr_fan=pr_fan,
                 pr_lpc=pr_lpc, pr_hpc=pr_hpc, T_int=T_int, **hs)
    return EngineDesign(
        spec=s, fan=fan, lpc=lpc, hpc=hpc, hpt=hpt, lpt=lpt, dp_inlet=dp_inlet,
        wc2_des=wc2, wc13_des=float(components.corrected_flow(hs["W13"], T21, P21)),
        wc24_des=float(components.corrected_flow(W25, T24, P24)),
        wc3_des=float(components.corrected_flow(W3, T30, P30)),
        nrl_des=Nf / np.sqrt(T21 / T_STD_K), nrc_des=Nc / np.sqrt(T24 / T_STD_K),
        f31=W31 / W25, f32=W32 / W25, A18=hs["A18"], A8=hs["A8"], A30=float(A30),
        T40_des=T40, loading_des=float(components.burner_loading(P30, T30, W3)),
        pr_hpt_des=hs["pr_hpt"], pr_lpt_des=hs["pr_lpt"], W13_des=hs["W13"], W25_des=W25,
        W4_des=hs["W4"], W48_des=hs["W48"], W50_des=hs["W50"], P_hp_des=hs["P_hpc"],
        P_lp_des=hs["P_lp"], point=point,
    )


def with_changes(spec: DesignSpec, **kw) -> DesignSpec:
    return replace(spec, **kw)


__all__ = ["DesignSpec", "EngineDesign", "design_engine", "atmosphere"]
