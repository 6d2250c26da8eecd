"""The two-spool, separate-flow, high-bypass turbofan assembled from its components.

Stations (SAE ARP755): 0 free stream, 2 fan face, 21 fan exit (both streams), 15 bypass duct,
18 bypass nozzle throat, 24 LPC exit, 25 HPC inlet, 30 HPC exit, 40 burner exit, 41 HPT rotor
inlet (after the vane share of the HPT coolant W31 joins), 43 HPT rotor exit, 45/48 HPT exit
after the rotor share of W31 mixes in (``P45``, ``T48``), 49 LPT rotor inlet (after the LPT
coolant W32 joins), 50 LPT exit, 8 core nozzle throat.

Turbine cooling air is accounted as performance codes do (Walsh & Fletcher, *Gas Turbine
Performance*, 2nd ed., ch. 5, turbine cooling; Kurzke's GasTurb): nozzle-guide-vane coolant
mixes into the gas upstream of the rotor, so it expands through the rotor and does work;
rotor coolant leaves the blades and mixes downstream, doing no work in that stage
(``DesignSpec.f_hpt_vane`` splits W31). The work the rotor spends pumping its coolant
outward is not modelled separately: at the design point it is part of the HPT efficiency.

Off-design the cycle is a residual system ``r(x; w, theta, p) = 0`` in eight unknowns ``x``::

    x = [beta_fan, beta_LPC, beta_HPC, n_HPC, T40/T40_des, PR_HPT/PR_HPT_des, PR_LPT/PR_LPT_des,
         n_fan]

and eight residuals, each scaled by its design value::

    r0 bypass nozzle flow      = bypass flow (fan flow - LPC flow) + VBV bleed
    r1 HPC map flow            = LPC map flow - VBV bleed (- any bleed an effect adds)
    r2 HPT flow capacity       = W41
    r3 HPT power * eta_mech    = HPC power (+ power off-take)
    r4 LPT flow capacity       = W49
    r5 LPT power * eta_mech    = fan + LPC power
    r6 core nozzle flow        = W50
    r7 controller              : the fan speed the full-authority controller selects

The controller (:mod:`schedule`) holds the corrected fan speed ``n_fan`` on its TRA schedule
(C-MAPSS; idle to maximum, with the N1 red line), unless a limiter takes over: the maximum
core speed and the maximum T48 lower it, the minimum core speed (flight idle) raises it.
``Nf = Nf_des * n_fan * sqrt(T2/T_std)``; the fuel flow ``Wf`` is an output (through T40).
``PCNfR_dmd`` is the schedule's demand before the limiters; ``NRf`` the speed it holds.

Extension point. Every quantity that an optional physical effect may change passes through
``hook(name, value, **station)`` (see :mod:`engine_model.physics.effects`, which lists the hooks and
their station context), with the effect's own symbolic parameters in ``p``. The station
keywords (e.g. a component's inlet ``T_in``, ``P_in`` and their design values) only inform
the effects; with no effects the hooks return their input unchanged and ignore them, so the
expression graph is the same as without the context.
"""

import math

import casadi as ca

from engine_model.units import LBF_TO_N, LBM_TO_KG, PSIA_TO_PA, R_PER_K, T_STD_K

from . import atmosphere, components, gas
from .design import EngineDesign

UNKNOWN_NAMES = ("beta_fan", "beta_LPC", "beta_HPC", "n_HPC", "T40_rel", "PR_HPT_rel",
                 "PR_LPT_rel", "n_fan")
N_UNKNOWNS = len(UNKNOWN_NAMES)
X_DESIGN = (0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0)


def _no_hook(name, value, **station):
    return value


def _inlet(T_in, P_in, T_in_des, P_in_des, eta_des, n_corr):
    """Station context of a component's modifier hooks: its inlet total state here and at
    the design point, its design efficiency (used e.g. by Reynolds-number effects) and its
    corrected speed relative to the design point, ``n_corr = (N/sqrt(T_in)) / (N/sqrt(T_in))_des``
    (the speed coordinate of its map; used e.g. by map-adaptation effects)."""
    return dict(T_in=T_in, P_in=P_in, T_in_des=float(T_in_des), P_in_des=float(P_in_des),
                eta_des=float(eta_des), n_corr=n_corr)


def cycle(d: EngineDesign, w, theta, x, hook=_no_hook):
    """Evaluate the cycle at unknowns ``x``: returns (residuals, stations).

    ``w = [alt ft, Mach, TRA %, T2 degR]``, ``theta`` the ten health deltas in
    :data:`channels.THETA_NAMES` order. Stations are SI.
    """
    s = d.spec
    alt, mach, tra, T2_R = w[0], w[1], w[2], w[3]
    (fan_eff, fan_flow, lpc_eff, lpc_flow, hpc_eff, hpc_flow, hpt_eff, hpt_flow, lpt_eff,
     lpt_flow) = (theta[i] for i in range(10))
    (beta_fan, beta_lpc, beta_hpc, n_hpc, t40_rel, prh_rel, prl_rel,
     n_fan) = (x[i] for i in range(8))

    # --- free stream and inlet ---
    T2 = T2_R / R_PER_K
    P_amb = hook("P_amb", atmosphere.isa_pressure(alt))
    Ts0 = atmosphere.static_temperature(T2, mach)
    Pt0 = P_amb * atmosphere.total_pressure_ratio(Ts0, T2)
    V0 = atmosphere.flight_speed(Ts0, mach)

    # --- controller: corrected fan speed (an unknown; residual r7 below) ---
    pct_dmd = d.nf_demand_pct(tra)
    Nf = s.Nf_rpm * n_fan * ca.sqrt(T2 / T_STD_K)

    # --- fan (its modifier hooks see the free-stream Pt0: they precede the intake loss) ---
    des = d.point  # design-point stations (SI)
    at2 = _inlet(T2, Pt0, des["T2"], des["P2"] / (1.0 - d.dp_inlet), d.fan.eta_des, n_fan)
    fan_eff = hook("fan_eff_mod", fan_eff, **at2)
    fan_flow = hook("fan_flow_mod", fan_flow, **at2)
    wc2 = d.fan.flow(n_fan, beta_fan, fan_flow)
    P2 = hook("P2", Pt0 * (1.0 - d.dp_inlet * (wc2 / d.wc2_des) ** 2), Pt0=Pt0)
    fan = components.compressor(d.fan, T2, P2, n_fan, beta_fan, fan_eff, fan_flow,
                                slope_mod=hook("fan_slope_mod", 0.0, **at2),
                                pr_mod=hook("fan_pr_mod", 0.0, **at2))
    W2, T21, P21 = fan["W"], fan["T_out"], fan["P_out"]

    # --- LPC (booster) on the core stream ---
    n_lpc = Nf / ca.sqrt(T21 / T_STD_K) / d.nrl_des
    at21 = _inlet(T21, P21, des["T21"], des["P21"], d.lpc.eta_des, n_lpc)
    lpc = components.compressor(d.lpc, T21, P21, n_lpc, beta_lpc,
                                hook("LPC_eff_mod", lpc_eff, **at21),
                                hook("LPC_flow_mod", lpc_flow, **at21),
                                slope_mod=hook("LPC_slope_mod", 0.0, **at21),
                                pr_mod=hook("LPC_pr_mod", 0.0, **at21))
    W22, T24, P24 = lpc["W"], lpc["T_out"], lpc["P_out"]

    # --- variable bleed valves: booster-exit air dumped into the bypass duct at part power ---
    W_vbv = hook("W_vbv", s.vbv.fraction(n_hpc, n_fan, mach) * W22, W22=W22, n_hpc=n_hpc,
                 n_fan=n_fan)

    # --- bypass duct and nozzle (the VBV air mixes into the bypass stream) ---
    W13 = W2 - W22
    wc13 = components.corrected_flow(W13, T21, P21)
    P15 = components.duct_loss(P21, wc13, d.wc13_des, hook("dp_bypass", s.dp_bypass))
    m15 = components.mixer(W13, T21, 0.0, W_vbv, T24, 0.0)
    byp = components.convergent_nozzle(P15, m15["T"], 0.0, P_amb, hook("A18", d.A18),
                                       s.nozzle_cd, s.nozzle_cv)

    # --- LPC-HPC duct, HPC with coolant extraction ---
    W_bleed_24 = hook("W_bleed_24", 0.0 * W22, W22=W22)  # handling / customer bleed at station 24
    W25_up = W22 - W_vbv - W_bleed_24
    wc24 = components.corrected_flow(W22, T24, P24)
    P25 = components.duct_loss(P24, wc24, d.wc24_des, hook("dp_icd", s.dp_icd))
    T25 = T24
    NRc = n_hpc * d.nrc_des  # C-MAPSS corrects core speed on T24
    Nc = NRc * ca.sqrt(T24 / T_STD_K)
    at25 = _inlet(T25, P25, des["T24"], des["P25"], d.hpc.eta_des, n_hpc)
    hpc = components.compressor(d.hpc, T25, P25, n_hpc, beta_hpc,
                                hook("HPC_eff_mod", hpc_eff, **at25),
                                hook("HPC_flow_mod", hpc_flow, **at25),
                                slope_mod=hook("HPC_slope_mod", 0.0, **at25),
                                pr_mod=hook("HPC_pr_mod", 0.0, **at25))
    W25, T30, P30 = hpc["W"], hpc["T_out"], hpc["P_out"]
    W31 = hook("f31", d.f31) * W25  # HPT coolant (W31) and LPT coolant (W32) fractions
    W32 = hook("f32", d.f32) * W25
    h25 = gas.h(T25)
    h30 = gas.h(T30)
    h_int = h25 + s.f_interstage * (h30 - h25)
    T_int = gas.t_from_h(h_int, 0.0, T25 + (h_int - h25) / gas.cp(T25))
    W_cust = hook("W_customer_bleed", 0.0 * W25, W25=W25, T30=T30,
                  P30=P30)  # customer bleed at HPC exit
    P_hpc = W25 * (h_int - h25) + (W25 - W32) * (h30 - h_int)

    # --- burner ---
    W3 = W25 - W31 - W32 - W_cust
    T40 = t40_rel * d.T40_des
    loading = components.burner_loading(P30, T30, W3) / d.loading_des
    eta_b = components.burner_efficiency(loading, s.eta_burner)
    wc3 = components.corrected_flow(W3, T30, P30)
    dp_b = hook("dp_burner", s.dp_burner) * (wc3 / d.wc3_des) ** 2
    brn = components.burner(T30, P30, W3, T40, dp_b, eta_b)
    far4, Wf, P40, W4 = brn["far"], brn["Wf"], brn["P_out"], brn["W_out"]

    # --- HPT: the vane share of the coolant W31 joins before the rotor (41) and does work
    # there, the rotor share mixes after the rotor (43 -> 45); Walsh & Fletcher ch. 5 ---
    m41 = components.mixer(W4, T40, far4, s.f_hpt_vane * W31, T30, 0.0)
    W41, T41, far41 = m41["W"], m41["T"], m41["far"]
    pr_hpt = prh_rel * d.pr_hpt_des
    n_hpt = n_hpc * ca.sqrt(T24 / T41) / math.sqrt(des["T24"] / des["T41"])
    at41 = _inlet(T41, P40, des["T41"], des["P40"], d.hpt.eta_des, n_hpt)
    hpt = components.turbine(d.hpt, T41, P40, far41, pr_hpt, Nc,
                             hook("HPT_eff_mod", hpt_eff, **at41),
                             hook("HPT_flow_mod", hpt_flow, **at41))
    T43, P45 = hpt["T_out"], hpt["P_out"]
    m45 = components.mixer(W41, T43, far41, (1.0 - s.f_hpt_vane) * W31, T30, 0.0)
    W48, T48, far48 = m45["W"], m45["T"], m45["far"]
    P_offtake = hook("P_offtake_HP", 0.0 * W25)  # W

    # --- LPT (coolant W32 joins at rotor inlet) ---
    m49 = components.mixer(W48, T48, far48, W32, T_int, 0.0)
    W49, T49, far49 = m49["W"], m49["T"], m49["far"]
    pr_lpt = prl_rel * d.pr_lpt_des
    n_lpt = n_fan * ca.sqrt(T2 / T49) / math.sqrt(des["T2"] / des["T49"])
    at49 = _inlet(T49, P45, des["T49"], des["P45"], d.lpt.eta_des, n_lpt)
    lpt = components.turbine(d.lpt, T49, P45, far49, pr_lpt, Nf,
                             hook("LPT_eff_mod", lpt_eff, **at49),
                             hook("LPT_flow_mod", lpt_flow, **at49))
    T50, P50, W50 = lpt["T_out"], lpt["P_out"], W49
    core = components.convergent_nozzle(P50, T50, far49, P_amb, hook("A8", d.A8), s.nozzle_cd,
                                        s.nozzle_cv)

    P_lp = W2 * fan["dh"] + W22 * lpc["dh"]
    res = ca.vertcat(
        (W13 + W_vbv - byp["W"]) / d.W13_des,
        (W25_up - W25) / d.W25_des,
        (W41 - hpt["W_cap"]) / d.W4_des,
        (s.eta_mech * W41 * hpt["dh"] - P_hpc - P_offtake) / d.P_hp_des,
        (W49 - lpt["W_cap"]) / d.W48_des,
        (s.eta_mech * W49 * lpt["dh"] - P_lp) / d.P_lp_des,
        (W50 - core["W"]) / d.W50_des,
        s.throttle.controller_residual(n_fan, d.nf_command_pct(tra, T2) / 100.0,
                                       Nc / s.Nc_rpm, T48 / des["T48"], mach, alt),
    )

    # --- derived outputs ---
    W30 = W25 - W32
    M30 = components.mach_from_flow(W30, T30, P30, d.A30, 0.0, s.mach_hpc_exit)
    Ps30 = components.static_pressure(P30, T30, M30)
    Fn = byp["Fg"] + core["Fg"] - W2 * V0
    st = dict(
        P_amb=P_amb, Ts0=Ts0, Pt0=Pt0, V0=V0, T2=T2, P2=P2, Nf=Nf, Nc=Nc, NRc=NRc,
        NRf=Nf / ca.sqrt(T2 / T_STD_K), PCNfR_dmd=pct_dmd, W2=W2, T21=T21, P21=P21, W22=W22,
        T24=T24, P24=P24, W13=W13, P15=P15, P25=P25, W25=W25, T30=T30, P30=P30, Ps30=Ps30,
        W31=W31, W32=W32, W3=W3, T40=T40, P40=P40, W4=W4, Wf=Wf, far4=far4, T41=T41, W41=W41,
        far41=far41, T43=T43, far48=far48, T48=T48, P45=P45, W48=W48, T49=T49, W49=W49,
        T50=T50, P50=P50, W50=W50, far50=far49,
        Fn=Fn, Fg_bypass=byp["Fg"], Fg_core=core["Fg"], P_hpc=P_hpc, P_lp=P_lp,
        P_hpt=W41 * hpt["dh"], P_lpt=W49 * lpt["dh"], P_offtake=P_offtake, W_cust=W_cust,
        W_bleed_24=W_bleed_24, W_vbv=W_vbv, T15=m15["T"], T_int=T_int, eta_fan=fan["eta"],
        eta_lpc=lpc["eta"], eta_hpc=hpc["eta"], eta_hpt=hpt["eta"], eta_lpt=lpt["eta"], eta_b=eta_b,
        SmFan=fan["SM"], SmLPC=lpc["SM"], SmHPC=hpc["SM"], n_fan=n_fan, n_lpc=n_lpc,
        pr_fan=fan["PR"], pr_lpc=lpc["PR"], pr_hpc=hpc["PR"], pr_surge_fan=fan["PR_surge"],
        pr_surge_lpc=lpc["PR_surge"], pr_surge_hpc=hpc["PR_surge"], wc_fan=fan["Wc"],
        wc_lpc=lpc["Wc"], wc_hpc=hpc["Wc"], pr_hpt=pr_hpt, pr_lpt=pr_lpt,
        x18=byp["x"], x8=core["x"], x18_crit=byp["x_crit"], x8_crit=core["x_crit"],
        Cd18=byp["Cd"], Cd8=core["Cd"],
    )
    return res, st


def imperial_outputs(st, hook=_no_hook):
    """The user-facing outputs in N-CMAPSS units, keyed by channel name (order of
    :data:`channels.OUTPUT_NAMES`)."""
    R = R_PER_K
    psia = 1.0 / PSIA_TO_PA
    lbm = 1.0 / LBM_TO_KG
    Fn_lbf = st["Fn"] / LBF_TO_N
    Wf_pps = st["Wf"] * lbm
    out = {
        "Wf": Wf_pps, "Nf": st["Nf"], "Nc": st["Nc"],
        "T24": st["T24"] * R, "T30": st["T30"] * R, "T40": st["T40"] * R,
        "T48": st["T48"] * R, "T50": st["T50"] * R,
        "P15": st["P15"] * psia, "P2": st["P2"] * psia, "P21": st["P21"] * psia,
        "P24": st["P24"] * psia, "Ps30": st["Ps30"] * psia, "P30": st["P30"] * psia,
        "P40": st["P40"] * psia, "P50": st["P50"] * psia,
        "P45": st["P45"] * psia, "W21": st["W2"] * lbm, "W22": st["W22"] * lbm,
        "W25": st["W25"] * lbm, "W31": st["W31"] * lbm, "W32": st["W32"] * lbm,
        "W48": st["W48"] * lbm, "W50": st["W50"] * lbm,
        "SmFan": st["SmFan"], "SmLPC": st["SmLPC"], "SmHPC": st["SmHPC"],
        "phi": Wf_pps / (st["Ps30"] * psia),
        "Fn": Fn_lbf, "TSFC": Wf_pps * 3600.0 / Fn_lbf,
        "BPR": st["W13"] / st["W22"], "epr": st["P50"] / st["P2"],
        "NRf": st["NRf"], "NRc": st["NRc"], "PCNfR_dmd": st["PCNfR_dmd"], "FAR": st["far4"],
    }
    return {k: hook("sensor:" + k, v) for k, v in out.items()}
