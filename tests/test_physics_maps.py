"""Physics of the compressor maps, the surge line and the throttle schedule (issue 12).

Map properties on every speed line of every compressor (pressure ratio and specific work fall
strictly from surge to choke, corrected flow saturates at choke), the surge line moving with
flow-capacity loss, positive stall margins of a new engine over the envelope, component
efficiencies in a documented range, and a throttle response that is monotonic in TRA on a grid
of the envelope.
"""

import casadi as ca
import numpy as np
import pytest

from engine_model import THETA_NAMES, EngineModel
from engine_model.physics import atmosphere, gas, turbofan
from engine_model.physics.design import DesignSpec
from engine_model.physics.schedule import ThrottleSchedule, band_max, band_min

from .conftest import w_rows

N_TH = len(THETA_NAMES)
NRF_DES = DesignSpec().Nf_rpm  # design corrected fan speed [rpm]
SPEEDS = (0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.05)
T_IN = 288.15


def _line(cmap, n, flow_mod=0.0, n_pts=2000):
    """One speed line from the surge line to deep choke: beta, Wc, PR, specific work."""
    b = np.linspace(float(cmap.beta_surge(n, flow_mod)), cmap.beta_choke - 4.0, n_pts)
    wc = np.array([float(cmap.flow(n, x, flow_mod)) for x in b])
    head = np.array([float(cmap.head(n, x)) for x in b]) * T_IN
    work = np.array([float(cmap.work(n, x)) for x in b]) * T_IN
    T_is = gas.t_from_h(gas.h(T_IN) + head, 0.0, T_IN + head / 1004.0)
    pr = np.asarray(gas.pressure_ratio_isentropic(T_IN, T_is, 0.0), float).ravel()
    return b, wc, pr, work


@pytest.mark.parametrize("comp", ["fan", "lpc", "hpc"])
def test_every_speed_line_falls_from_surge_to_choke(model, comp):
    """From the surge line toward choke, pressure ratio and specific work fall strictly and the
    corrected flow rises, saturating at the choke flow. A fan's low-speed lines reach zero work
    (windmilling: the blades turn the flow less than the inflow angle) before their passages
    choke; the lines are checked down to that point, and choke saturation where it is reached
    with the blades still doing work. Past PR = 1 the choke line goes on down (maps.py, 2.);
    it is checked down to PR 0.5, below which the isentropic exit temperature leaves the gas
    model's range on the high-pressure-ratio lines."""
    cmap = getattr(model.design, comp)
    for n in SPEEDS:
        b, wc, pr, work = _line(cmap, n)
        # the flow rises toward choke and saturates at the choke flow, on every line
        wc_choke = cmap.wc_des * n * float(cmap.phi_choke(n))
        assert np.all(np.diff(wc) > 0.0) and wc_choke * (1.0 - 1e-4) < wc[-1] < wc_choke
        ok = (work > 0.0) & (pr > 0.5)
        keep = np.cumprod(ok).astype(bool)  # the stretch from the surge line down to there
        windmills = not keep.all() and work[keep.sum()] <= 0.0  # the stretch ends at work 0
        b, wc, pr, work = b[keep], wc[keep], pr[keep], work[keep]
        assert len(b) > 50, (comp, n)
        assert np.all(np.diff(pr) < 0.0), (comp, n)  # pressure ratio falls toward choke
        assert np.all(np.diff(work) < 0.0), (comp, n)  # Euler: specific work falls too
        assert pr[0] > 1.0
        if not windmills:  # a line still doing work in deep choke has gone below PR 1
            assert pr[-1] < 1.0, (comp, n)
    # the core compressors, and the fan at and above 90 % speed, reach choke doing work
    for n in SPEEDS:
        if comp != "fan" or n >= 0.9:
            assert np.all(_line(cmap, n)[3] > 0.0), (comp, n)


@pytest.mark.parametrize("comp", ["fan", "lpc", "hpc"])
def test_choke_line_continues_below_unit_pressure_ratio(model, comp):
    """Deep in choke the isentropic head goes through zero and on to negative values (PR < 1,
    efficiency < 0) at the choke flow, falling strictly; above the choke line's centre the
    continuation changes the head by at most 2.5e-4 of itself, and above b_ch + 3.5 (where
    99 % of converged envelope points lie) by less than 1e-8. The fan's lines below 90 %
    speed windmill (Euler work < 0) before they choke and are not checked here."""
    cmap = getattr(model.design, comp)
    b_ch, b_d = cmap.beta_choke, cmap.beta_deep_choke
    assert b_d < b_ch
    for n in ((0.9, 1.0) if comp == "fan" else (0.3, 0.6, 1.0)):
        assert float(cmap.work(n, b_d - 0.3)) > 0.0
        b = np.linspace(b_ch, b_d - 0.3, 400)
        head = np.array([float(cmap.head(n, x)) for x in b])
        eta = np.array([float(cmap.eta_map(n, x)) for x in b])
        assert np.all(np.diff(head) < 0.0) and head[0] > 0.0 > head[-1], (comp, n)
        assert eta[-1] < 0.0
        wc_choke = cmap.wc_des * n * float(cmap.phi_choke(n))
        assert abs(float(cmap.flow(n, b_d)) / wc_choke - 1.0) < 5e-5
        for db, tol in ((0.0, 2.5e-4), (3.5, 1e-8)):
            x = b_ch + db
            # the head with the logistic choke factor alone, as the map was before
            island = float(cmap.eta_pk * ca.exp(-cmap.c_phi * (cmap.phi_work(n, x)
                                                                 / cmap.phi_opt1 - 1.0) ** 2
                                                - cmap.c_n * (n - cmap.n_pk) ** 2))
            first = island * float(cmap.work(n, x)) / (1.0 + np.exp(-cmap.mu * db))
            assert abs(float(cmap.head(n, x)) / first - 1.0) < tol, (comp, n, db)


def test_degraded_ground_idle_points_with_a_choked_booster_converge(model):
    """Two random envelope points (sampling.random_envelope(100000, seed=0), rows 34485 and
    92387: ground idle, booster flow capacity -4.6 %) that had no root while the booster's
    choke line stopped at PR 1: now a steady state with the booster choked below PR 1."""
    w = np.array([[780.8578825382144, 0.00911312727022797, 32.282717280016215,
                   499.6893937462079],
                  [4079.3039963502356, 0.054153134207127196, 29.012141432786656,
                   524.4368482914866]])
    th = np.array([[-0.029337901027302896, -0.00536807262401464, -0.033602747297819174,
                    -0.045535453667654185, -0.009970122058501, -0.01594109461542817,
                    -0.00040779193411007164, -0.005887732096762924, -0.01917377334282391,
                    -0.018466212006977144],
                   [-0.03593126954709459, -0.0036868594020069007, -0.005368541116850728,
                    -0.046377728377835416, -0.008711593890966832, -0.006691094394343636,
                    -0.00480769511436023, -0.015232971171494109, -0.045292488434312356,
                    -0.005072549728483269]])
    res = model.solve(w, th)
    assert res.converged.all()
    lpc = model.design.lpc
    assert np.all(res.x[:, 1] < lpc.beta_deep_choke)  # on the continuation
    for k in range(2):
        _, st = turbofan.cycle(model.design, list(w[k]), list(th[k]), list(res.x[k]))
        assert 0.9 < float(st["pr_lpc"]) < 1.0 and float(st["eta_lpc"]) < 0.0


@pytest.mark.parametrize("comp", ["fan", "lpc", "hpc"])
def test_efficiency_island_peaks_at_the_aero_design_point(model, comp):
    cmap = getattr(model.design, comp)
    n_grid = np.linspace(0.3, 1.05, 31)
    b_grid = np.linspace(float(cmap.beta_surge(1.0)) + 1.0, cmap.beta_choke, 121)
    eta = np.array([[float(cmap.eta_map(n, b)) for b in b_grid] for n in n_grid])
    i, j = np.unravel_index(np.argmax(eta), eta.shape)
    assert abs(n_grid[i] - cmap.n_pk) <= 0.03
    assert abs(float(cmap.phi_work(n_grid[i], b_grid[j])) - cmap.phi_opt1) <= 0.01
    assert eta.max() <= cmap.eta_pk + 1e-12 and eta.max() < 0.95


@pytest.mark.parametrize("comp", ["fan", "lpc", "hpc"])
def test_flow_capacity_loss_lowers_the_surge_line(model, comp):
    cmap = getattr(model.design, comp)
    for n in (0.5, 0.8, 1.0):
        pr_new = _line(cmap, n)[2][0]
        pr_fouled = _line(cmap, n, flow_mod=-0.02)[2][0]
        assert pr_fouled < pr_new, (comp, n)


def test_schedule_keeps_the_cmapss_points_and_idles():
    s = ThrottleSchedule()
    assert float(s.demand_pct(100.0)) == pytest.approx(100.0, abs=1e-12)
    assert float(s.demand_pct(60.0)) == pytest.approx(84.93, abs=1e-12)
    tra = np.linspace(15.0, 105.0, 901)
    pct = s.demand_pct(tra)
    assert np.all(np.diff(pct[tra >= s.tra_idle]) > 0.0)
    assert np.all(pct[tra <= s.tra_idle] == s.pct_idle)
    np.testing.assert_allclose(s.tra_from_pct(s.demand_pct(tra[tra > 21.0])),
                               tra[tra > 21.0], atol=1e-3)
    # the N1 red line limits the physical fan speed on a hot day only
    cmd = s.command_pct(np.array([100.0, 105.0]), np.array([288.15, 330.0]))
    assert cmd[0] == pytest.approx(100.0, abs=1e-8)
    assert cmd[1] * np.sqrt(330.0 / 288.15) <= s.n1_max_pct + 1e-9


def test_nozzle_discharge_coefficient_rises_with_pressure_ratio_past_choke(model):
    """Cd of the convergent nozzles rises with NPR, below and above the critical ratio, and
    stays between its low-NPR and high-NPR limits; in the engine both nozzles pass more per
    unit area at cruise (the bypass nozzle choked) than at sea-level take-off."""
    cd = model.design.spec.nozzle_cd
    npr = np.linspace(1.0, 6.0, 501)
    c = np.array([float(cd(v)) for v in npr])
    assert np.all(np.diff(c) > 0.0)
    assert c[0] == pytest.approx(cd.cd_1) and cd.cd_1 <= c.min() and c.max() < cd.cd_inf
    assert float(cd(3.0)) > float(cd(1.9))  # still rising once choked (NPR > ~1.85)
    w = w_rows([(0.0, 0.0, 100.0), (35000.0, 0.8, 80.0)])
    res = model.solve(w)
    st = [turbofan.cycle(model.design, [float(v) for v in w[k]], [0.0] * N_TH,
                         [float(v) for v in res.x[k]])[1] for k in range(2)]
    for key in ("Cd18", "Cd8"):
        assert float(st[1][key]) > float(st[0][key]), key
    assert float(st[1]["x18"]) == pytest.approx(float(st[1]["x18_crit"]), rel=0.01)  # choked


def test_limiter_selection_is_monotone_and_exact_outside_its_band():
    """The controller's smooth min/max never lets a rising input lower the selection (the
    flight-idle to schedule hand-over must not dip) and is the exact min/max outside the
    band."""
    band = 0.002
    a = np.linspace(-3 * band, 3 * band, 20001)
    for b in (-1e-3, 0.0, 0.5):
        a_ = a + b
        for f, exact in ((band_max, np.maximum), (band_min, np.minimum)):
            y = f(a_, b, band)
            assert np.all(np.diff(y) >= -1e-15)  # in a
            assert np.all(np.diff(f(b, a_, band)) >= -1e-15)  # in b
            out = np.abs(a_ - b) >= band
            np.testing.assert_allclose(y[out], exact(a_, b)[out], rtol=0, atol=1e-15)


# ------------------------------------------------------------------ envelope grid
def _grid():
    """(alt, Mach) pairs inside the CAS limit, ISA -15/0/+15 K, TRA 20..100 by 10."""
    pairs = [(0.0, 0.0), (0.0, 0.3), (10000.0, 0.5), (25000.0, 0.62), (35000.0, 0.8),
             (42000.0, 0.84)]
    for alt, mach in pairs:
        assert mach <= max(0.25, float(atmosphere.mach_from_cas(350.0 * 0.514444, alt))) + 0.05
    rows = [(a, m, t, dT) for a, m in pairs for dT in (-15.0, 0.0, 15.0)
            for t in np.arange(20.0, 100.1, 10.0)]
    return rows


@pytest.fixture(scope="module")
def grid_run(model):
    rows = _grid()
    w = w_rows(rows)
    ev = model.evaluate(w)
    return rows, w, ev


def test_envelope_grid_converges(grid_run):
    _, _, ev = grid_run
    assert ev.converged.all(), ev.index[~ev.converged].tolist()


@pytest.mark.parametrize("channel", ["Wf", "Fn", "P30", "Nc", "T30", "T48"])
def test_throttle_response_is_monotonic(grid_run, channel):
    """Strictly increasing in TRA wherever the fan-speed schedule governs; where the flight-
    idle limiter holds the engine (minimum core speed, low TRA in flight) the response is
    flat, as a real engine's is below flight idle, and must not fall."""
    rows, _, ev = grid_run
    n_tra = len(np.arange(20.0, 100.1, 10.0))
    y = ev[channel].to_numpy().reshape(-1, n_tra)
    on_schedule = (np.abs(100.0 * ev.NRf.to_numpy() / NRF_DES - ev.PCNfR_dmd.to_numpy())
                   < 1e-3).reshape(-1, n_tra)
    for k in range(len(y)):
        d = np.diff(y[k])
        both = on_schedule[k, 1:] & on_schedule[k, :-1]
        where = (channel, rows[k * n_tra][:2], rows[k * n_tra][3], y[k])
        assert np.all(d[both] > 0.0), where
        assert np.all(d >= -1e-9 * np.abs(y[k, 1:])), where
    # the flat part is flight idle only: on the ground (Mach 0) every step is on schedule
    assert on_schedule[[k for k in range(len(y)) if rows[k * n_tra][1] == 0.0]].all()


def test_new_engine_fan_and_hpc_have_positive_stall_margins(grid_run):
    _, _, ev = grid_run
    for sm in ("SmFan", "SmHPC"):
        assert (ev[sm] > 0.0).all(), (sm, ev[sm].min())


def test_new_engine_booster_has_positive_stall_margin(grid_run):
    _, _, ev = grid_run
    assert (ev["SmLPC"] > 0.0).all(), ev["SmLPC"].min()


# Component efficiencies at converged envelope points. Range: the maps' island peaks are
# 0.91-0.93; 0.6 is the floor of a fan or booster at ground idle (25 % speed, far from
# the design speed and incidence; Walsh & Fletcher ch. 7: 0.6-0.75 at idle).
ETA_RANGE = {"eta_fan": (0.60, 0.93), "eta_lpc": (0.60, 0.93), "eta_hpc": (0.75, 0.93)}


def test_component_efficiencies_stay_in_range(model, grid_run):
    rows, w, _ = grid_run
    res = model.solve(w)
    vals = []
    for k in range(len(w)):
        _, st = turbofan.cycle(model.design, [float(v) for v in w[k]], [0.0] * N_TH,
                               [float(v) for v in res.x[k]])
        vals.append([float(st[name]) for name in ETA_RANGE])
    vals = np.array(vals)
    for j, (name, (lo, hi)) in enumerate(ETA_RANGE.items()):
        assert vals[:, j].min() >= lo and vals[:, j].max() <= hi, (
            name, vals[:, j].min(), vals[:, j].max())


def test_flow_capacity_loss_consumes_stall_margin(model):
    """-2 % flow capacity of a compressor lowers that compressor's stall margin (at constant
    corrected speed) at SLS take-off, climb and cruise - except the booster at sea level.
    There the HPC behind it sets its flow: a booster that loses capacity runs down its speed
    line toward choke, the core takes 1.22 % more corrected flow from it, and its
    constant-speed margin rises (+0.07 points at SLS TRA 100). Stage stacking behind that
    exit flow gives the same sign, +0.54 to +1.32 points, in all 72 variants
    (engine_model.physics.stage_stacking, tests/test_stage_stacking.py,
    benchmarks/results/booster_stage_stacking.md). What consumes the booster's margin at sea
    level is the rematch: an HPC that loses flow capacity raises the booster's working line,
    asserted here at all three points."""
    pts = [(0.0, 0.0, 100.0), (20000.0, 0.7, 90.0), (35000.0, 0.8, 70.0)]
    for name, sm, where in (("fan_flow_mod", "SmFan", [0, 1, 2]),
                            ("LPC_flow_mod", "SmLPC", [1, 2]),
                            ("HPC_flow_mod", "SmHPC", [0, 1, 2])):
        th = np.zeros((2 * len(pts), N_TH))
        th[len(pts):, THETA_NAMES.index(name)] = -0.02
        ev = model.evaluate(w_rows(pts * 2), th)
        assert ev.converged.all()
        new = ev[sm].to_numpy()[:len(pts)][where]
        worn = ev[sm].to_numpy()[len(pts):][where]
        assert np.all(worn < new), (name, new, worn)
        if name == "HPC_flow_mod":
            lpc = ev.SmLPC.to_numpy()
            assert np.all(lpc[len(pts):] < lpc[:len(pts)]), lpc


def test_health_signatures_keep_their_sign(model):
    """Every theta at -2 % at SLS take-off, climb and cruise (engine_model.analysis.signatures): no
    channel of T24 T30 T48 T50 P30 Nc Wf changes sign between the points where the change
    exceeds the channel's noise sigma, except T24, whose flips are the bleed valves': at cruise
    (35 kft Mach 0.8 TRA 70) the booster needs bleed and the VBVs modulate (4.4 % of its flow,
    engine_model.physics.bleed_schedule), so a theta that moves the corrected core speed moves the
    opening, and the booster's exit temperature follows the valves. Held at the new engine's
    cruise opening (bleed_schedule.FixedOpening), T24 at cruise keeps its SLS and climb sign
    wherever the change exceeds noise."""
    from engine_model.analysis.signatures import DELTA, SIGNATURE_POINTS, signature_table
    from engine_model.physics.bleed_schedule import FixedOpening

    table, sigma, flips = signature_table(model)
    assert {c for _, c in flips} <= {"T24"}, flips
    alt, mach, tra = SIGNATURE_POINTS["cruise"]
    w = w_rows([(alt, mach, tra)] * (N_TH + 1))
    th = np.vstack([np.zeros(N_TH), DELTA * np.eye(N_TH)])
    new = model.evaluate(w[:1]).iloc[0]
    d = model.design
    f = float(d.spec.vbv.fraction(new.NRc / d.nrc_des, new.NRf / d.spec.Nf_rpm, mach))
    assert f > 0.01  # the valves are open at the cruise point
    held = EngineModel(design=d, effects=[FixedOpening()], compiled=False)
    ev = held.evaluate(w, th, np.full((N_TH + 1, 1), f))
    assert ev.converged.all()
    t24 = ev.T24.to_numpy()
    assert abs(t24[0] - new.T24) < 1e-6 * new.T24  # same state as the scheduled engine
    for j, name in enumerate(THETA_NAMES):
        dt = t24[1 + j] - t24[0]
        at_sls = table[name]["T24"]["SLS"]
        if abs(dt) > sigma["T24"]["cruise"] and abs(at_sls) > sigma["T24"]["SLS"]:
            assert np.sign(dt) == np.sign(at_sls), (name, dt, at_sls)
