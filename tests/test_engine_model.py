"""Physics and numerics of the two-spool turbofan model (engine_model.EngineModel).

Conservation at converged off-design points, exact Jacobians against finite differences,
the health-parameter signature table, the design point against C-MAPSS, convergence over
the civil envelope, input errors, compiled versus interpreted, warm start, thrust, effects.
"""

import functools

import numpy as np
import pandas as pd
import pytest
from scipy.optimize import brentq

from engine_model import OUTPUT_NAMES, THETA_NAMES, W_NAMES, EngineModel, InputError
from engine_model.physics import atmosphere, components, gas, turbofan
from engine_model.physics.effects import Effect, Param

from .conftest import isa_t2_R, reference_csv, w_rows

OUT = list(OUTPUT_NAMES)
N_TH = len(THETA_NAMES)


def theta_vec(**kw):
    th = np.zeros(N_TH)
    for k, v in kw.items():
        th[THETA_NAMES.index(k)] = v
    return th


def stations(model, w, theta, x):
    """Station values (SI, floats) of the cycle at unknowns ``x``, and its residuals."""
    res, st = turbofan.cycle(model.design, [float(v) for v in w], [float(v) for v in theta],
                             [float(v) for v in x])
    return np.asarray(res, float).ravel(), {k: float(v) for k, v in st.items()}


# ------------------------------------------------------------------ conservation
# off-design points (alt ft, Mach, TRA %, dT_isa K) with nominal and degraded health
BALANCE_CASES = [
    ((0.0, 0.0, 100.0, 0.0), theta_vec()),
    ((0.0, 0.25, 30.0, 15.0), theta_vec(HPT_eff_mod=-0.03, HPT_flow_mod=-0.01)),
    ((10000.0, 0.4, 80.0, 0.0), theta_vec(fan_eff_mod=-0.02, LPC_flow_mod=-0.01,
                                          HPC_eff_mod=-0.015)),
    ((35000.0, 0.8, 100.0, 0.0), theta_vec(HPT_eff_mod=-0.03, LPT_eff_mod=-0.02,
                                           LPT_flow_mod=-0.01)),
    ((42000.0, 0.8, 40.0, -10.0), np.linspace(-0.05, 0.0, N_TH)),
    ((20000.0, 0.6, 60.0, 10.0), np.linspace(0.0, -0.04, N_TH)),
]


def _rel(a, b):
    return abs(a - b) / max(abs(a), abs(b))


@pytest.fixture(scope="module")
def balance_solutions(model):
    w = w_rows([c[0] for c in BALANCE_CASES])
    th = np.array([c[1] for c in BALANCE_CASES])
    res = model.solve(w, th)
    assert res.converged.all()
    return w, th, res


@pytest.mark.parametrize("case", range(len(BALANCE_CASES)))
def test_spool_energy_balances(model, balance_solutions, case):
    w, th, res = balance_solutions
    r, st = stations(model, w[case], th[case], res.x[case])
    assert np.max(np.abs(r)) < 1e-10
    eta_mech = model.design.spec.eta_mech
    # HP spool: eta_mech * P_HPT = P_HPC + power off-take
    assert _rel(eta_mech * st["P_hpt"], st["P_hpc"] + st["P_offtake"]) < 1e-8
    # LP spool: eta_mech * P_LPT = fan + LPC
    assert _rel(eta_mech * st["P_lpt"], st["P_lp"]) < 1e-8

    # the same balances recomputed from station temperatures with gas.h (not from the
    # component functions' own specific works)
    far41 = st["Wf"] / (st["W41"] - st["Wf"])
    far48 = st["Wf"] / (st["W48"] - st["Wf"])
    T25 = st["T24"]  # adiabatic LPC-HPC duct
    p_hpc = (st["W25"] * (gas.h(st["T_int"]) - gas.h(T25))
             + (st["W25"] - st["W32"]) * (gas.h(st["T30"]) - gas.h(st["T_int"])))
    # the HPT rotor expands W41 from T41 to T43 (its coolant mixes in after the rotor)
    p_hpt = st["W41"] * (gas.h(st["T41"], far41) - gas.h(st["T43"], far41))
    p_lp = (st["W2"] * (gas.h(st["T21"]) - gas.h(st["T2"]))
            + st["W22"] * (gas.h(st["T24"]) - gas.h(st["T21"])))
    p_lpt = st["W49"] * (gas.h(st["T49"], st["far50"]) - gas.h(st["T50"], st["far50"]))
    assert _rel(eta_mech * p_hpt, p_hpc + st["P_offtake"]) < 1e-8
    assert _rel(eta_mech * p_lpt, p_lp) < 1e-8
    # coolant mixing at 41 (vanes), 45 (rotor) and 49 (LPT) conserves energy
    f_vane = model.design.spec.f_hpt_vane
    h30 = gas.h(st["T30"])
    assert _rel(st["W41"] * gas.h(st["T41"], far41),
                st["W4"] * gas.h(st["T40"], st["far4"]) + f_vane * st["W31"] * h30) < 1e-8
    assert _rel(st["W48"] * gas.h(st["T48"], far48),
                st["W41"] * gas.h(st["T43"], far41) + (1 - f_vane) * st["W31"] * h30) < 1e-8
    assert _rel(st["W49"] * gas.h(st["T49"], st["far50"]),
                st["W48"] * gas.h(st["T48"], far48) + st["W32"] * gas.h(st["T_int"])) < 1e-8


@pytest.mark.parametrize("case", range(len(BALANCE_CASES)))
def test_burner_energy_balance(model, balance_solutions, case):
    w, th, res = balance_solutions
    _, st = stations(model, w[case], th[case], res.x[case])
    # W3 h_air(T30) + Wf eta_b LHV = W4 h(T40, far4), enthalpies on the fuel's 288.15 K datum
    lhs = st["W3"] * gas.h(st["T30"]) + st["Wf"] * st["eta_b"] * gas.LHV_KEROSENE
    rhs = st["W4"] * gas.h(st["T40"], st["far4"])
    assert _rel(lhs, rhs) < 1e-8
    assert 0.98 < st["eta_b"] <= 1.0
    assert _rel(st["far4"], st["Wf"] / st["W3"]) < 1e-12


@pytest.mark.parametrize("case", range(len(BALANCE_CASES)))
def test_mass_balance_every_station(model, balance_solutions, case):
    w, th, res = balance_solutions
    _, st = stations(model, w[case], th[case], res.x[case])
    d = model.design
    tol = 1e-8
    assert st["W_bleed_24"] == 0.0 and st["W_cust"] == 0.0  # no effects: no extra bleeds
    assert _rel(st["W2"], st["W13"] + st["W22"]) < tol  # fan splits into bypass + core
    # the booster's variable bleed valves dump W_vbv into the bypass duct (zero at high power)
    assert _rel(st["W25"], st["W22"] - st["W_vbv"]) < tol
    assert _rel(st["W3"], st["W25"] - st["W31"] - st["W32"]) < tol  # coolant extraction
    assert _rel(st["W4"], st["W3"] + st["Wf"]) < tol  # fuel added in the burner
    f_vane = model.design.spec.f_hpt_vane
    # HPT coolant: the vane share returns at 41 (before the rotor), the rest after the rotor
    assert _rel(st["W41"], st["W4"] + f_vane * st["W31"]) < tol
    assert _rel(st["W48"], st["W41"] + (1.0 - f_vane) * st["W31"]) < tol
    assert _rel(st["W49"], st["W48"] + st["W32"]) < tol  # LPT coolant returns at 49
    assert _rel(st["W50"], st["W49"]) < tol
    assert _rel(st["W50"], st["W22"] - st["W_vbv"] + st["Wf"]) < tol  # core in + fuel = out
    assert _rel(st["far50"], st["Wf"] / (st["W50"] - st["Wf"])) < tol
    # the VBV air mixes into the bypass stream adiabatically (T15 from the energy balance)
    assert _rel((st["W13"] + st["W_vbv"]) * gas.h(st["T15"]),
                st["W13"] * gas.h(st["T21"]) + st["W_vbv"] * gas.h(st["T24"])) < tol
    # flow-passing elements pass exactly the flow that reaches them
    s = d.spec
    byp = components.convergent_nozzle(st["P15"], st["T15"], 0.0, st["P_amb"], d.A18,
                                       s.nozzle_cd, s.nozzle_cv)
    core = components.convergent_nozzle(st["P50"], st["T50"], st["far50"], st["P_amb"], d.A8,
                                        s.nozzle_cd, s.nozzle_cv)
    assert _rel(st["W13"] + st["W_vbv"], float(byp["W"])) < tol
    assert _rel(st["W50"], float(core["W"])) < tol
    th_ = dict(zip(THETA_NAMES, th[case], strict=True))
    w41_cap = (float(d.hpt.capacity(st["pr_hpt"], th_["HPT_flow_mod"])) * st["P40"]
               / np.sqrt(st["T41"]))
    w49_cap = (float(d.lpt.capacity(st["pr_lpt"], th_["LPT_flow_mod"])) * st["P45"]
               / np.sqrt(st["T49"]))
    assert _rel(st["W41"], w41_cap) < tol
    assert _rel(st["W49"], w49_cap) < tol


def test_outputs_are_the_stations_in_imperial_units(model, balance_solutions):
    w, th, res = balance_solutions
    y = pd.DataFrame(model.outputs_at(res.x, w, th), columns=OUT)
    for k in range(len(w)):
        _, st = stations(model, w[k], th[k], res.x[k])
        assert y.T48[k] == pytest.approx(st["T48"] * 1.8, rel=1e-12)
        assert y.P30[k] == pytest.approx(st["P30"] / 6894.757293168, rel=1e-12)
        assert y.W50[k] == pytest.approx(st["W50"] / 0.45359237, rel=1e-12)
        assert y.Wf[k] == pytest.approx(st["Wf"] / 0.45359237, rel=1e-12)
        assert y.Nc[k] == pytest.approx(st["Nc"], rel=1e-12)
        # N-CMAPSS definitions of the derived channels
        assert y.phi[k] == pytest.approx(y.Wf[k] / y.Ps30[k], rel=1e-12)
        assert y.epr[k] == pytest.approx(y.P50[k] / y.P2[k], rel=1e-12)
        assert y.BPR[k] == pytest.approx((y.W21[k] - y.W22[k]) / y.W22[k], rel=1e-10)
        assert y.TSFC[k] == pytest.approx(y.Wf[k] * 3600.0 / y.Fn[k], rel=1e-12)
    # the residual function of the public API agrees with cycle()
    r = model.residuals_at(res.x, w, th)
    assert np.max(np.abs(r)) < 1e-10


# ------------------------------------------------------------------ exact Jacobian vs FD
# Criterion (per point, per output y_i): derivatives are first scaled to "change of y_i for
# a typical change of the input" (theta: 0.01; w: 1000 ft, 0.01 Mach, 1 % TRA, 1 degR).
# Each scaled entry must satisfy |exact - fd| <= 1e-5 * max(|fd|, 1e-2 * max_j |fd_ij|,
# 1e-10 |y_i|): a 1e-5 relative error on every entry that is at least 1 % of the largest
# entry of its row; smaller entries (and rows that are ~0, e.g. Nf versus theta) are held
# to 1e-7 of the row's largest entry (or 1e-15 of |y_i|) in absolute terms. The floor is
# there because the finite differences carry the solver's noise. The perturbed steady states
# are solved to max|r| < 1e-12 (FD_TOL): at the default 1e-10 the noise of x over a 2e-5
# step reaches 3e-5 of an output whose sensitivity is a difference of large terms (P50 versus
# HPC flow capacity at 2,000 ft, TRA 45: the HPC map line moves 4 units per unit of theta);
# 1e-13 in x over a 2e-5 step is ~1e-8 of a typical sensitivity, which
# would dominate entries far smaller than their row. (Measured: worst entry error ~4e-6 on
# entries of 0.04 % of their row, worst row-norm error 1e-8 for theta and 4e-8 for w.)
FD_POINTS = [(10000.0, 0.4, 80.0, 0.0), (30000.0, 0.78, 95.0, 10.0), (2000.0, 0.2, 45.0, -10.0)]
FD_THETA = np.array([
    theta_vec(HPT_eff_mod=-0.02, LPT_eff_mod=-0.01),
    np.linspace(-0.03, 0.0, N_TH),
    theta_vec(fan_eff_mod=-0.01, fan_flow_mod=-0.02, HPC_flow_mod=-0.015),
])
THETA_STEP = 1e-5
W_STEPS = np.array([5.0, 1e-4, 1e-3, 1e-2])  # ft, -, %, degR
W_SCALE = np.array([1000.0, 0.01, 1.0, 1.0])
FD_TOL = 1e-12


def _outputs(model, w, th):
    """Outputs at steady states solved to FD_TOL (see the criterion above)."""
    r = model.solve(w, th, tol=FD_TOL)
    assert r.converged.all()
    return model.outputs_at(r.x, w, th)


def _check_jacobian(exact, fd, y, scale, rtol=1e-5):
    ex_s = exact * scale
    fd_s = fd * scale
    row = np.max(np.abs(fd_s), axis=2, keepdims=True)
    denom = np.maximum(np.maximum(np.abs(fd_s), 1e-2 * row), 1e-10 * np.abs(y)[:, :, None])
    err = np.abs(ex_s - fd_s) / denom
    worst = np.unravel_index(np.argmax(err), err.shape)
    assert err.max() <= rtol, (
        f"point {worst[0]}, output {OUT[worst[1]]}, input {worst[2]}: exact "
        f"{exact[worst]:.10g}, finite difference {fd[worst]:.10g}, error {err.max():.3g}")


@pytest.fixture(scope="module")
def fd_base(model):
    w = w_rows(FD_POINTS)
    y = _outputs(model, w, FD_THETA)
    dth, dw = model.sensitivities(w, FD_THETA)
    assert dth.shape == (len(w), len(OUT), N_TH) and dw.shape == (len(w), len(OUT), 4)
    return w, y, dth, dw


def test_dy_dtheta_matches_central_differences(model, fd_base):
    w, y, dth, _ = fd_base
    n = len(w)
    rows_w, rows_th = [], []
    for k in range(n):
        for j in range(N_TH):
            for sgn in (1.0, -1.0):
                t = FD_THETA[k].copy()
                t[j] += sgn * THETA_STEP
                rows_w.append(w[k])
                rows_th.append(t)
    yy = _outputs(model, np.array(rows_w), np.array(rows_th)).reshape(n, N_TH, 2, len(OUT))
    fd = ((yy[:, :, 0] - yy[:, :, 1]) / (2.0 * THETA_STEP)).transpose(0, 2, 1)
    _check_jacobian(dth, fd, y, np.full(N_TH, 0.01))
    # health parameters do not move the controller's fan-speed demand (exact zeros) nor,
    # away from the limiters (none is near at these points), the speed it holds: its selection
    # is exact there, so only the round-off of the implicit-function solve remains
    assert np.all(dth[:, OUT.index("PCNfR_dmd"), :] == 0.0)
    for name in ("Nf", "NRf"):
        i = OUT.index(name)
        assert np.all(np.abs(dth[:, i, :]) * 0.01 < 1e-12 * y[:, [i]])


def test_dy_dw_matches_central_differences(model, fd_base):
    w, y, _, dw = fd_base
    n = len(w)
    rows_w, rows_th = [], []
    for k in range(n):
        for j in range(4):
            for sgn in (1.0, -1.0):
                r = w[k].copy()
                r[j] += sgn * W_STEPS[j]
                rows_w.append(r)
                rows_th.append(FD_THETA[k])
    yy = _outputs(model, np.array(rows_w), np.array(rows_th)).reshape(n, 4, 2, len(OUT))
    fd = ((yy[:, :, 0] - yy[:, :, 1]) / (2.0 * W_STEPS[None, :, None])).transpose(0, 2, 1)
    _check_jacobian(dw, fd, y, W_SCALE)
    # the demanded corrected fan speed depends on TRA alone, through the throttle schedule
    i = OUT.index("PCNfR_dmd")
    sched = model.design.spec.throttle
    h = 1e-4
    slope = (sched.demand_pct(w[:, 2] + h) - sched.demand_pct(w[:, 2] - h)) / (2 * h)
    np.testing.assert_allclose(dw[:, i, [0, 1, 3]], 0.0, atol=1e-15)
    np.testing.assert_allclose(dw[:, i, 2], slope, rtol=1e-7)


# ------------------------------------------------------------------ signature table
# Expected sign of the change of an output when one health parameter is LOWERED by 0.01
# (1 % lost) at fixed TRA, i.e. at fixed corrected fan speed (the controller closes Nf on
# its TRA schedule, so Wf is an output). Every sign is derived below from the physics, and
# asserted at sea-level static TRA 100 and at cruise (35,000 ft, Mach 0.8, ISA, TRA 100).
#
# fan_eff_mod: the fan still has to deliver its pressure ratio at the held speed, but needs
#   more shaft work per kg (dh = dh_is / eta) -> the LPT must give more power -> more fuel
#   and hotter turbine gas: Wf, T48, T50 up; more fuel for the same thrust: TSFC up.
# fan_flow_mod: at the held fan speed the fan swallows less air -> W21 down and, with less
#   mass flow through both nozzles, net thrust Fn down.
# LPC_eff_mod: more work for the booster's pressure rise -> its exit temperature T24 up; more
#   LP power -> Wf up, TSFC up.
# LPC_flow_mod: the booster passes less air at the held LP speed -> core flow W22 down while
#   the fan's total flow hardly changes -> bypass ratio BPR up.
# HPC_eff_mod: more work for the HPC pressure rise -> T30 up; the HPT must deliver more power
#   -> hotter burner exit -> Wf, T48 up, TSFC up.
# HPC_flow_mod: the HPC's corrected flow is pinned by the choked HPT nozzle (working line
#   W25 sqrt(T25)/P25 ~ Phi_HPT PR_HPC sqrt(T25/T41)); a compressor that passes less flow
#   per rpm must turn faster to pass it -> Nc up.
# HPT_eff_mod: less work per unit expansion -> the HP spool needs hotter gas -> T40 up, the
#   HPT exit T48 up, T50 up, Wf up, TSFC up.
# HPT_flow_mod: a smaller HPT flow capacity back-pressures the HPC -> P30 up and the HPC
#   working line moves toward surge -> SmHPC down.
# LPT_eff_mod: less work per unit expansion in the LPT -> more fuel for the held fan speed
#   and hotter exhaust: T50 up, Wf up, TSFC up.
# LPT_flow_mod: a smaller LPT flow capacity raises the pressure between the turbines -> P45
#   up; the HPT expansion ratio falls, so the HP spool needs hotter gas -> T48 up.
#
# Not in the table: fan_eff_mod -> T24 (see test_fan_efficiency_heats_fan_exit below).
SIGNATURE = {
    "fan_eff_mod": {"Wf": +1, "T48": +1, "T50": +1, "TSFC": +1},
    "fan_flow_mod": {"W21": -1, "Fn": -1},
    "LPC_eff_mod": {"T24": +1, "Wf": +1, "TSFC": +1},
    "LPC_flow_mod": {"W22": -1, "BPR": +1},
    "HPC_eff_mod": {"T30": +1, "T48": +1, "Wf": +1, "TSFC": +1},
    "HPC_flow_mod": {"Nc": +1},
    "HPT_eff_mod": {"T40": +1, "T48": +1, "T50": +1, "Wf": +1, "TSFC": +1},
    "HPT_flow_mod": {"P30": +1, "SmHPC": -1},
    "LPT_eff_mod": {"T50": +1, "Wf": +1, "TSFC": +1},
    "LPT_flow_mod": {"P45": +1, "T48": +1},
}
SIGNATURE_POINTS = {"SLS TRA 100": (0.0, 0.0, 100.0), "35 kft M0.8 TRA 100": (35000.0, 0.8, 100.0)}
DELTA = -0.01


@pytest.fixture(scope="module")
def signature_runs(model):
    out = {}
    for label, pt in SIGNATURE_POINTS.items():
        w = w_rows([pt] * (N_TH + 1))
        th = np.zeros((N_TH + 1, N_TH))
        th[1:] = DELTA * np.eye(N_TH)
        ev = model.evaluate(w, th)
        assert ev.converged.all()
        out[label] = ev
    return out


@pytest.mark.parametrize("label", list(SIGNATURE_POINTS))
@pytest.mark.parametrize("param", list(SIGNATURE))
def test_signature_table(signature_runs, label, param):
    ev = signature_runs[label]
    base = ev.iloc[0]
    moved = ev.iloc[1 + THETA_NAMES.index(param)]
    for name, sign in SIGNATURE[param].items():
        rel = (moved[name] - base[name]) / abs(base[name])
        assert np.sign(rel) == sign and abs(rel) > 1e-5, (
            f"{label}: lowering {param} by 1 % moved {name} by {100 * rel:+.4f} %, "
            f"expected sign {sign:+d}")


def test_fan_efficiency_heats_fan_exit(model):
    """Lowering fan efficiency heats the fan exit (T21, both streams) at both points.

    T24 = T21 + booster temperature rise, and in this model T24 falls at both points (about
    -0.2 degR per 1 % at SLS take-off and at cruise): the extra fuel speeds up the HP spool,
    the HPC draws more core flow and pulls the booster toward choke (lower pressure ratio and
    temperature rise), which outweighs the hotter booster inlet. That is a matching effect,
    not a conservation error, so T24 is not asserted (the old maps gave +0.16 degR at SLS);
    the README's signature table reports it.
    """
    j = THETA_NAMES.index("fan_eff_mod")
    for label, pt in SIGNATURE_POINTS.items():
        w = w_rows([pt])[0]
        th1 = DELTA * np.eye(N_TH)[j]
        r = model.solve(np.array([w, w]), np.array([np.zeros(N_TH), th1]))
        _, st0 = stations(model, w, np.zeros(N_TH), r.x[0])
        _, st1 = stations(model, w, th1, r.x[1])
        assert st1["T21"] > st0["T21"], label


# ------------------------------------------------------------------ design point vs C-MAPSS
def test_sls_design_point_matches_cmapss_reference(model):
    ref = pd.read_csv(reference_csv()).iloc[0]
    assert (ref.alt_kft, ref.Mach, ref.TRA, ref.T2) == (0.0, 0.0, 100.0, 518.67)
    y = model.evaluate(pd.DataFrame({"alt": [0.0], "Mach": [0.0], "TRA": [100.0],
                                     "T2": [518.67]})).iloc[0]
    assert y.converged
    for ch in ("T24", "T30", "T50", "P15", "P30", "Nf", "Nc", "BPR", "W31", "W32", "epr"):
        assert y[ch] == pytest.approx(ref[ch], rel=1e-6), ch  # the design is built from them


# ------------------------------------------------------------------ convergence
def civil_envelope_sample(n, seed):
    """Random points of the civil envelope: alt 0-42,000 ft, Mach up to min(0.85, Mach of
    350 kt CAS), TRA 20-100, day temperature ISA -15..+15 K, theta in [-0.05, 0]."""
    rng = np.random.default_rng(seed)
    alt = rng.uniform(0.0, 42000.0, n)
    mmax = np.array([min(0.85, float(atmosphere.mach_from_cas(350.0 * 0.514444, a)))
                     for a in alt])
    mach = rng.uniform(0.0, 1.0, n) * mmax
    tra = rng.uniform(20.0, 100.0, n)
    dT = rng.uniform(-15.0, 15.0, n)
    w = w_rows(list(zip(alt, mach, tra, dT, strict=True)))
    theta = rng.uniform(-0.05, 0.0, (n, N_TH))
    return w, theta


@pytest.fixture(scope="module")
def envelope_run(model):
    w, th = civil_envelope_sample(500, seed=20240607)
    return w, th, model.evaluate(w, th)


def test_civil_envelope_converges(envelope_run):
    w, th, ev = envelope_run
    bad = ev.index[~ev.converged.to_numpy()]
    assert len(bad) == 0, f"not converged at rows {list(bad)[:10]}: w = {w[bad[:3]]}"
    assert (ev.residual_norm < 1e-10).all()
    assert np.isfinite(ev[OUT].to_numpy()).all()
    assert (ev.iterations <= 30).all()


def _below_unit_pr(model, x):
    """Compressors whose map line lies past the head's zero on the choke line, where a
    pressure ratio below 1 and a negative efficiency are the map's physics (maps.py, 2.)."""
    d = model.design
    return {name for j, name in enumerate(("fan", "lpc", "hpc"))
            if x[j] < getattr(d, name).beta_unit_pr}


def _implausible(st, choked=frozenset()):
    """Reasons why a converged state is not a physical engine state (empty if it is).
    ``choked``: the compressors running choked below PR 1 (:func:`_below_unit_pr`), whose
    pressure ratio and efficiency are then checked to lie in (0, 1] and below 0."""
    why = []
    for k in ("pr_fan", "pr_lpc", "pr_hpc", "pr_hpt", "pr_lpt"):
        ok = 0.0 < st[k] <= 1.0 if k[3:] in choked else st[k] > 1.0
        if not ok:
            why.append(f"{k} = {st[k]:.4g}")
    for k in ("eta_fan", "eta_lpc", "eta_hpc", "eta_hpt", "eta_lpt"):
        ok = st[k] <= 0.0 if k[4:] in choked else 0.0 < st[k] < 1.0
        if not ok:
            why.append(f"{k} = {st[k]:.4g}")
    # stall margins are not asked here: a degraded compressor (flow capacity down to -5 %)
    # may be predicted past its surge line, which is a physical prediction (surge), not a
    # broken state; a new engine's margins are tested in test_physics_maps.py
    chain = ("T2", "T21", "T24", "T30", "T40")
    for a, b in zip(chain, chain[1:], strict=False):
        if not st[b] > st[a]:
            why.append(f"{b} = {st[b]:.1f} K <= {a} = {st[a]:.1f} K")
    if not st["T40"] > st["T48"] > st["T50"]:
        why.append("turbine temperatures not falling")
    return why


def test_civil_envelope_states_are_physical(model, envelope_run):
    w, th, ev = envelope_run
    x = model.solve(w, th).x
    rng = np.random.default_rng(1)
    for k in rng.choice(len(w), 60, replace=False):
        _, st = stations(model, w[k], th[k], x[k])
        why = _implausible(st, _below_unit_pr(model, x[k]))
        assert not why, (w[k], why)
    # and thrust stays positive, fuel flow positive
    assert (ev.Fn > 0).all() and (ev.Wf > 0).all()


# regression: a root off the end of the LPC map (negative head) was once reported as converged
# at w = [-1500 ft, Mach 0.9, TRA 15, T2 620 degR] with every theta = -0.10
def test_no_unphysical_root_reported_as_converged(model):
    w = np.array([[-1500.0, 0.9, 15.0, 620.0]])
    th = np.full((1, N_TH), -0.10)
    r = model.solve(w, th)
    if r.converged[0]:
        _, st = stations(model, w[0], th[0], r.x[0])
        why = _implausible(st, _below_unit_pr(model, r.x[0]))
        assert not why, why


def test_non_converged_point_is_flagged_and_nan(model):
    good = w_rows([(10000.0, 0.4, 80.0)])[0]
    # a tolerance no point can meet: every point must come back flagged
    r = model.solve(np.array([good]), tol=0.0, max_iter=3)
    assert not r.converged.any()
    assert np.isfinite(r.residual_norm).all() and (r.residual_norm > 0).all()
    # a point with no physical steady state: everything 15 % degraded, idle at Mach 0.9 at sea
    # level on a 620 degR inlet (the corner of the envelope): the only root the solver finds
    # lies off the compressor maps (with the T48 and N1 limiters, a degraded engine at full
    # throttle on a hot day now has a steady state, so the old TRA 105 case converges)
    hopeless = np.array([0.0, 0.9, 15.0, 620.0])
    th = np.array([np.zeros(N_TH), np.full(N_TH, -0.15)])
    ev = model.evaluate(np.array([good, hopeless]), th)
    assert ev.converged.tolist() == [True, False]
    assert np.isfinite(ev.loc[0, OUT].to_numpy(float)).all()
    assert np.isnan(ev.loc[1, OUT].to_numpy(float)).all()
    # no root, or a root off the compressor maps (not a physical steady state)
    x = model.solve(np.array([good, hopeless]), th).x
    assert ev.residual_norm[1] > 1e-10 or not model.valid_on_maps(x[1:])[0]
    with pytest.raises(InputError, match="row 1"):
        model.sensitivities(np.array([good, hopeless]), th)


def test_evaluate_forwards_non_convergence(model, monkeypatch):
    # whatever evaluate's solver returns unconverged must surface as NaN + converged False
    monkeypatch.setattr(model, "solve", functools.partial(EngineModel.solve, model, tol=0.0,
                                                          max_iter=2))
    ev = model.evaluate(w_rows([(0.0, 0.0, 100.0), (30000.0, 0.7, 90.0)]))
    assert not ev.converged.any()
    assert ev[OUT].isna().all().all()


# ------------------------------------------------------------------ bad input
def _df(rows, index=None, columns=W_NAMES):
    return pd.DataFrame(rows, columns=list(columns), index=index)


GOOD = [0.0, 0.0, 100.0, 518.67]


@pytest.mark.parametrize(
    "rows, index, row_label, column",
    [
        ([GOOD, [10000.0, np.nan, 80.0, 500.0], GOOD], [10, 11, 12], "row 11", "Mach"),
        ([GOOD, GOOD, [0.0, -0.1, 80.0, 518.67]], None, "row 2", "Mach"),
        ([[60000.0, 0.8, 100.0, 440.0]], None, "row 0", "alt"),
        ([GOOD, [0.0, 0.0, np.inf, 518.67]], ["a", "b"], "row b", "TRA"),
        ([GOOD, [0.0, 0.0, 100.0, np.nan]], None, "row 1", "T2"),
    ],
)
def test_bad_operating_point_names_row_and_column(model, rows, index, row_label, column):
    with pytest.raises(InputError) as exc:
        model.evaluate(_df(rows, index))
    msg = str(exc.value)
    assert row_label in msg and f"column {column}" in msg, msg
    # the numpy path names the row (position) and the column too
    arr = np.array(rows, float)
    with pytest.raises(InputError) as exc:
        model.evaluate(arr)
    pos = int(np.flatnonzero(~np.isfinite(arr).all(axis=1) | (arr[:, 1] < 0)
                             | (arr[:, 0] > 45000))[0])
    assert f"row {pos}" in str(exc.value) and f"column {column}" in str(exc.value)


def test_missing_column_names_it(model):
    with pytest.raises(InputError, match="T2"):
        model.evaluate(_df([GOOD[:3]], columns=("alt", "Mach", "TRA")))
    with pytest.raises(InputError, match="4 columns"):
        model.evaluate(np.array([GOOD[:3]]))


def test_bad_theta_names_row_and_column(model):
    df = _df([GOOD, GOOD])
    df["HPT_eff_mod"] = [0.0, np.nan]
    with pytest.raises(InputError, match=r"row 1, column HPT_eff_mod"):
        model.evaluate(df)
    df["HPT_eff_mod"] = [0.0, -0.5]
    with pytest.raises(InputError, match=r"row 1, column HPT_eff_mod"):
        model.evaluate(df)
    with pytest.raises(InputError, match="HPT_eff"):
        model.point(0.0, 0.0, 100.0, theta={"HPT_eff": -0.01})


def test_theta_columns_of_a_dataframe_are_used(model):
    df = _df([GOOD, [20000.0, 0.6, 80.0, 480.0]])
    df["HPT_eff_mod"] = [-0.02, -0.03]
    th = np.zeros((2, N_TH))
    th[:, THETA_NAMES.index("HPT_eff_mod")] = [-0.02, -0.03]
    a = model.evaluate(df)[OUT].to_numpy()
    b = model.evaluate(df[list(W_NAMES)].to_numpy(), th)[OUT].to_numpy()
    np.testing.assert_allclose(a, b, rtol=1e-12)
    s = model.point(20000.0, 0.6, 80.0, T2=480.0, theta={"HPT_eff_mod": -0.03})
    np.testing.assert_allclose(s[OUT].to_numpy(float), b[1], rtol=1e-12)


# ------------------------------------------------------------------ compiled vs interpreted
@pytest.mark.slow
def test_interpreted_equals_compiled(model, interpreted_model):
    w = w_rows([(0.0, 0.0, 100.0), (5000.0, 0.3, 45.0, 12.0), (25000.0, 0.62, 60.0),
                (35000.0, 0.84, 100.0), (41000.0, 0.8, 30.0, -8.0)])
    th = np.array([np.zeros(N_TH), np.linspace(-0.04, 0.0, N_TH),
                   theta_vec(HPT_eff_mod=-0.03), theta_vec(LPT_flow_mod=-0.02),
                   np.full(N_TH, -0.01)])
    a = model.evaluate(w, th)
    b = interpreted_model.evaluate(w, th)
    assert a.converged.all() and b.converged.all()
    np.testing.assert_allclose(b[OUT].to_numpy(), a[OUT].to_numpy(), rtol=1e-9, atol=0.0)
    x = model.solve(w, th).x
    np.testing.assert_allclose(interpreted_model.outputs_at(x, w, th),
                               model.outputs_at(x, w, th), rtol=1e-12, atol=0.0)
    np.testing.assert_allclose(interpreted_model.residuals_at(x, w, th),
                               model.residuals_at(x, w, th), rtol=0.0, atol=1e-13)


# ------------------------------------------------------------------ symbolic access
def test_residual_system_and_casadi_function(model):
    w = w_rows([(10000.0, 0.4, 80.0), (0.0, 0.2, 90.0, 5.0)])
    th = np.array([theta_vec(HPT_eff_mod=-0.01), np.zeros(N_TH)])
    res = model.solve(w, th)
    rs = model.residual_system()
    assert len(rs.unknown_names) == res.x.shape[1] and rs.output_names == OUTPUT_NAMES
    p = np.zeros(len(model.param_names))
    for k in range(len(w)):
        r = np.asarray(rs.residual(res.x[k], w[k], th[k], p)).ravel()
        assert np.max(np.abs(r)) < 1e-10
        y_sym = np.asarray(rs.outputs(res.x[k], w[k], th[k], p)).ravel()
        np.testing.assert_allclose(y_sym, model.outputs_at(res.x[k:k + 1], w[k:k + 1],
                                                           th[k:k + 1])[0], rtol=1e-12)
    F = model.casadi_function()
    y = model.evaluate(w, th)[OUT].to_numpy()
    for k in range(len(w)):
        yF = np.asarray(F(w[k], th[k], p)).ravel()
        np.testing.assert_allclose(yF, y[k], rtol=1e-8)


# ------------------------------------------------------------------ warm start
def test_solve_series_warm_start_matches_solve(model):
    n = 50
    s = 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, n))  # smooth 0 -> 1
    alt = 30000.0 * s
    mach = 0.3 + 0.48 * s
    tra = 100.0 - 8.0 * s
    w = w_rows(list(zip(alt, mach, tra, strict=True)))
    th = theta_vec(HPT_eff_mod=-0.02, LPT_flow_mod=-0.01)
    ref = model.solve(w, th)
    assert ref.converged.all()
    y_ref = model.outputs_at(ref.x, w, th)
    for chunk in (1, 7, 64):
        ser = model.solve_series(w, th, chunk=chunk)
        assert ser.converged.all() and (ser.residual_norm < 1e-10).all()
        np.testing.assert_allclose(ser.x, ref.x, rtol=0.0, atol=1e-8)
        np.testing.assert_allclose(model.outputs_at(ser.x, w, th), y_ref, rtol=1e-8)
        if chunk == 1:
            # warm-started from the previous sample: a few Newton iterations each
            assert ser.iterations[1:].max() <= 6
        if chunk == 7:
            # the carried offset saves iterations over the table's guess alone
            assert ser.iterations.mean() < ref.iterations.mean()


# ------------------------------------------------------------------ thrust and TSFC
def test_thrust_and_tsfc_plausible(model):
    sls = model.point(0.0, 0.0, 100.0)
    cruise = model.point(35000.0, 0.8, 100.0)
    assert sls.converged and cruise.converged
    assert sls.Fn == pytest.approx(90000.0, rel=1e-6)  # the design thrust
    assert cruise.TSFC > sls.TSFC
    # class-typical magnitudes [lbm/(lbf h)]: ~0.3 static take-off, ~0.55 cruise
    assert 0.25 < sls.TSFC < 0.40 and 0.45 < cruise.TSFC < 0.70
    # at sea level static, thrust and fuel flow rise with throttle
    tra = np.linspace(20.0, 100.0, 17)
    ev = model.evaluate(w_rows([(0.0, 0.0, t) for t in tra]))
    assert ev.converged.all()
    assert np.all(np.diff(ev.Fn) > 0) and np.all(np.diff(ev.Wf) > 0)
    assert np.all(np.diff(ev.T48) > 0) and np.all(np.diff(ev.Nc) > 0)


def test_thrust_lapse_at_max_climb(model):
    """Thrust lapse from SLS take-off to max climb at 35 kft Mach 0.8.

    Mattingly, Heiser & Pratt (*Aircraft Engine Design*, 2nd ed., AIAA 2002, eq. 2.45a) give
    the full-throttle lapse of a high-bypass turbofan as ``alpha = delta0 (1 - 0.49 sqrt(M0))``
    with ``delta0 = Pt0 / P_std``: 0.2015 here; the class spread is 0.18-0.22. Max climb
    runs at about 100 % physical fan speed. With C-MAPSS's throttle convention (TRA 100 =
    100 % *corrected* fan speed at every altitude) that is 108 % corrected at 35 kft, TRA
    about 130, beyond the TRA range of the data (<= 105): the point is solved with the
    envelope check off. At TRA 100 (92.6 % physical fan speed) the lapse is 0.139, which is
    the convention's consequence, not a defect of the cycle (README, "Throttle schedule").
    """
    alt, mach = 35000.0, 0.8
    T2_K = isa_t2_R(alt, mach, 0.0) / 1.8
    pct = 100.0 / np.sqrt(T2_K / 288.15)  # corrected fan speed at 100 % physical
    tra = brentq(lambda t: float(model.design.nf_demand_pct(t)) - pct, 100.0, 200.0)
    w = np.array([[0.0, 0.0, 100.0, isa_t2_R(0.0, 0.0, 0.0)], [alt, mach, tra, T2_K * 1.8]])
    res = model.solve(w, check=False)
    assert res.converged.all()
    fn = [float(turbofan.cycle(model.design, list(w[k]), [0.0] * N_TH, list(res.x[k]))[1]["Fn"])
          for k in range(2)]
    nf_phys = 100.0 * res.x[1][7] * np.sqrt(T2_K / 288.15)  # x[7]: corrected fan speed
    assert nf_phys == pytest.approx(100.0, abs=1e-6)  # the controller holds the demand
    delta0 = atmosphere.isa_pressure(alt) * atmosphere.total_pressure_ratio(
        atmosphere.static_temperature(T2_K, mach), T2_K) / atmosphere.isa_pressure(0.0)
    mattingly = delta0 * (1.0 - 0.49 * np.sqrt(mach))
    assert mattingly == pytest.approx(0.2015, abs=1e-4)  # the docstring's four digits
    assert 0.18 <= fn[1] / fn[0] <= 0.22, (fn[1] / fn[0], mattingly)


# ------------------------------------------------------------------ effects extension point
class T48SensorOffset(Effect):
    """A constant offset on the T48 sensor reading."""

    name = "t48_offset"
    params = (Param("offset", "degR", 0.0, "added to the T48 reading"),)

    def apply(self, hook, value, p, ctx):
        return value + p["offset"] if hook == "sensor:T48" else value


@pytest.mark.slow
def test_effect_shifts_only_its_channel(model):
    m = EngineModel(design=model.design, effects=[T48SensorOffset(offset=0.0)], compiled=False)
    assert m.param_names == ("t48_offset.offset",)
    assert tuple(m.p_default) == (0.0,)
    w = w_rows([(0.0, 0.0, 100.0), (20000.0, 0.6, 70.0), (35000.0, 0.8, 95.0)])
    th = np.array([np.zeros(N_TH), theta_vec(HPT_eff_mod=-0.02), np.full(N_TH, -0.01)])
    base = model.evaluate(w, th)
    off0 = m.evaluate(w, th)
    offset = 7.5
    shifted = m.evaluate(w, th, p=[offset])
    assert off0.converged.all() and shifted.converged.all()
    np.testing.assert_allclose(off0[OUT].to_numpy(), base[OUT].to_numpy(), rtol=1e-9)
    np.testing.assert_allclose(shifted.T48 - off0.T48, offset, rtol=0.0, atol=1e-9)
    others = [c for c in OUT if c != "T48"]
    np.testing.assert_allclose(shifted[others].to_numpy(), off0[others].to_numpy(),
                               rtol=1e-12, atol=0.0)
    # the residual system (hence the steady state) does not see a sensor offset
    np.testing.assert_array_equal(m.solve(w, th, p=[offset]).x, m.solve(w, th).x)


def test_c_newton_driver_runs_the_numpy_iteration(model):
    """The batched Newton in C (newton_batch.c, threads) and the numpy reference
    implementation take the same steps: same iteration counts, same roots."""
    from engine_model.analysis.sampling import random_envelope

    w, th = random_envelope(400, seed=11)
    x0 = model.initial_guess(w, th)
    a = model.solve_from(w, th, x0, retry=False, backend="c")
    b = model.solve_from(w, th, x0, retry=False, backend="numpy")
    # one sampled point (ground idle at 26 kft, Mach 0.07: no flight goes there) needs the
    # retries of solve(); plain Newton from the table fails on it in both drivers
    both = a.converged & b.converged
    assert both.mean() >= 0.99 and np.array_equal(a.converged, b.converged)
    np.testing.assert_array_equal(a.iterations[both], b.iterations[both])
    np.testing.assert_allclose(a.x[both], b.x[both], rtol=0.0, atol=1e-9)
    assert (a.residual_norm[both] < 1e-10).all()
    # a point that cannot converge in the allowed iterations is reported, not hidden
    c = model.solve_from(w[:3], th[:3], x0[:3] + 0.5, max_iter=1, retry=False)
    assert not c.converged.any() and (c.iterations == 1).all()
    assert np.all(c.residual_norm > 1e-10)


def test_rescued_point_reports_the_iterations_it_used(model):
    """A point solved only by continuation reports the iterations actually spent
    (failed attempt + continuation + polish), not a placeholder."""
    w = w_rows([(35000.0, 0.8, 100.0)])
    res = model.solve(w, x0=np.array([[3.0, 3.0, 3.0, 0.6, 0.5, 0.5, 0.5, 0.5]]), max_iter=4)
    assert res.converged[0]
    assert res.iterations[0] > 4 + 20


def test_newton_with_carried_jacobians_reaches_the_same_roots(model):
    """Chord iteration from the previous call's LU factors (the filters' warm start) converges
    to the roots of a fresh-Jacobian solve, and stores factors for every converged point."""
    if not model.compiled:
        pytest.skip("LU carrying is a feature of the compiled driver")
    rng = np.random.default_rng(3)
    n = 40
    w = np.column_stack([rng.uniform(20000, 38000, n), rng.uniform(0.6, 0.8, n),
                         rng.uniform(60, 90, n), rng.uniform(420, 460, n)])
    th = np.zeros((n, 10))
    th[:, 6] = rng.uniform(-0.02, 0, n)
    first = model.solve(w, th)
    assert first.converged.all()
    store = model.jacobian_store(n)
    model.solve_from(w, th, first.x, lu=store, retry=False)
    assert store.HAVE.all()
    # the next sample: w and theta move a little; start from the last roots and factors
    w2 = w + np.array([50.0, 0.002, 0.5, 0.3])
    th2 = th.copy()
    th2[:, 6] -= 5e-4
    carried = model.solve_from(w2, th2, first.x, lu=store, retry=False)
    fresh = model.solve_from(w2, th2, first.x, retry=False)
    assert carried.converged.all() and fresh.converged.all()
    # both stop at max|r| < 1e-10 (scaled residuals): the roots agree to that tolerance times
    # the conditioning of J, a few units (a map coordinate near 0 differs by 2.5e-10)
    np.testing.assert_allclose(carried.x, fresh.x, rtol=1e-8, atol=1e-9)
    assert np.all(carried.residual_norm < 1e-10)


def assert_close_by_row(actual, desired, scale=1e-13):
    """``actual`` equals ``desired`` to ``scale`` times the largest magnitude of each row
    (last axis): derivatives of one output, whose small entries are remainders of
    cancellations that a change of evaluation order moves by more than their own 1e-11."""
    actual, desired = np.asarray(actual), np.asarray(desired)
    assert actual.shape == desired.shape
    tol = scale * np.abs(desired).max(axis=-1, keepdims=True, initial=0.0)
    worst = np.max(np.abs(actual - desired) - tol, initial=-np.inf)
    assert worst <= 0.0, f"off by {worst:.3g} beyond {scale:g} of a row's largest magnitude"


def test_a_model_for_some_outputs_sensitivities_gives_the_same_numbers(model):
    """``EngineModel(sens_outputs=...)`` (the adaptation's model: its fitted channels only)
    gives those rows of every output's sensitivities, in the order asked, NaN in the other
    rows of ``sensitivities_at``, and refuses an output it was not built for. The same
    expressions evaluated in another order: equal to 1e-13 of the largest magnitude in each
    output's row, not bit for bit (an entry that is a cancellation's remainder, -3.2e-8
    beside 2.5, differs by 1.3e-10 of itself). Uncompiled here (CasADi's virtual machine,
    no compile)."""
    from engine_model.validation import InputError

    some = EngineModel(design=model.design, compiled=False, sens_outputs=("T50", "Nc", "P15"))
    assert some.sens_outputs == ("Nc", "T50", "P15")  # in OUTPUT_NAMES order
    full = EngineModel(design=model.design, compiled=False)
    w = w_rows([(0.0, 0.0, 100.0), (35000.0, 0.8, 95.0)])
    th = np.array([np.zeros(N_TH), theta_vec(HPT_eff_mod=-0.02)])
    res = full.solve(w, th)
    a = full.sensitivities_of(res.x, w, th, None, ("P15", "T50"))
    b = some.sensitivities_of(res.x, w, th, None, ("P15", "T50"))
    for u, v in ((a.theta, b.theta), (a.w, b.w), (a.p, b.p)):
        assert u.shape == v.shape
        assert_close_by_row(v, u)
    at = some.sensitivities_at(res.x, w, th)
    rows = [OUTPUT_NAMES.index(c) for c in ("Nc", "T50", "P15")]
    whole = full.sensitivities_at(res.x, w, th)
    assert_close_by_row(at.theta[:, rows], whole.theta[:, rows])
    others = [i for i in range(len(OUTPUT_NAMES)) if i not in rows]
    assert np.isnan(at.theta[:, others]).all() and np.isnan(at.w[:, others]).all()
    with pytest.raises(InputError, match="no sensitivities of T30"):
        some.sensitivities_of(res.x, w, th, None, ("T30",))
    with pytest.raises(InputError, match="sens_outputs: T3O not outputs"):
        EngineModel(design=model.design, compiled=False, sens_outputs=("T3O",))
    with pytest.raises(InputError, match="distinct"):
        EngineModel(design=model.design, compiled=False, sens_outputs=("T50", "T50"))


def test_sensitivities_by_reverse_mode_are_forward_modes_numbers(model):
    """The sensitivities the model compiles (reverse-mode AD) equal those of forward mode
    (how they were built until 2026-11-29) to 1e-13 of each output's largest magnitude,
    with an effect's parameters among the inputs; so do the MHE's stage Jacobians. An
    unknown mode is refused. Uncompiled (CasADi's virtual machine)."""
    from calibration.mhe_nlp import StageKernels
    from engine_model.channels import XS_NAMES
    from engine_model.physics.effects import parse_effect_spec

    m = EngineModel(design=model.design, compiled=False,
                    effects=[parse_effect_spec("map_scaling:component=HPC")])
    w = w_rows([(0.0, 0.0, 100.0), (35000.0, 0.8, 95.0)])
    th = np.array([np.zeros(N_TH), theta_vec(HPC_eff_mod=-0.02)])
    x = m.solve(w, th).x
    p = np.tile(m.p_default, (2, 1))
    args = [x.T, w.T, th.T, p.T]
    fwd = m.sensitivity_function("forward").map(2)(*args)
    rev = m.sensitivity_function("reverse").map(2)(*args)
    assert len(fwd) == len(rev) == 3  # theta, w, p
    for f, r in zip(fwd, rev, strict=True):
        f, r = np.asarray(f), np.asarray(r)
        assert_close_by_row(r, f)
    assert np.abs(np.asarray(rev[2])).max() > 0  # the effect's parameters do move outputs
    y = m.outputs_at(x, w, th)[:, [OUTPUT_NAMES.index(c) for c in XS_NAMES]] * 1.001
    margs = [x.T, th.T, w.T, y.T, np.ones_like(y.T), p.T]
    kernels = {mode: StageKernels(m, compiled=False, mode=mode) for mode in ("forward",
                                                                             "reverse")}
    for name in ("jac", "hgn"):
        f = kernels["forward"].f[name].map(2)(*margs)
        r = kernels["reverse"].f[name].map(2)(*margs)
        for a, b in zip(f if isinstance(f, tuple) else [f], r if isinstance(r, tuple) else [r],
                        strict=True):
            a, b = np.asarray(a), np.asarray(b)
            assert_close_by_row(b, a)
    with pytest.raises(ValueError, match="sideways"):
        m.sensitivity_function("sideways")
    with pytest.raises(ValueError, match="sideways"):
        StageKernels(m, compiled=False, mode="sideways")
