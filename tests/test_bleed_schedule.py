"""The variable-bleed-valve schedule (engine_model.bleed_schedule): shut at the design point and
at high core speed, open at flight idle, limited on the ground, monotone, smooth, and the same
on floats, numpy arrays and CasADi symbols."""

import casadi as ca
import numpy as np

from engine_model.bleed_schedule import BleedValveSchedule

S = BleedValveSchedule()


def test_shut_at_the_design_point_and_above_the_core_closing_speed():
    assert S.fraction(1.0, 1.0, 0.0) == 0.0 and S.fraction(1.0, 1.0, 1.0) == 0.0
    n_fan = np.linspace(0.2, 1.1, 50)
    assert np.all(np.asarray(S.fraction(S.core_close[1], n_fan, 1.0), float) == 0.0)


def test_open_at_flight_idle_and_limited_on_the_ground():
    # flight idle at altitude and high Mach: corrected core speed 0.75, fan 0.59 (audit)
    f_flight = float(S.fraction(0.75, 0.59, 1.0))
    assert 0.25 < f_flight <= max(k[1] for k in S.knots)
    f_ground = float(S.fraction(0.75, 0.59, 0.0))
    assert abs(f_ground - S.f_ground_max) < 1e-12
    # below the limit the ground opening is the flight opening (exact outside the band)
    n = 0.85
    assert float(S.flight_opening(n, 0.6)) < S.f_ground_max - S.ground_band
    assert float(S.fraction(n, 0.6, 0.0)) == float(S.fraction(n, 0.6, 1.0))


def test_opening_falls_with_core_speed_and_rises_with_fan_speed():
    n = np.linspace(0.6, 1.0, 401)
    for nf in (0.3, 0.5, 0.7, 0.9):
        f = np.asarray(S.flight_opening(n, nf), float).ravel()
        assert np.all(np.diff(f) <= 1e-15) and f[0] > 0.0 and f[-1] == 0.0
    nf = np.linspace(0.2, 1.0, 401)
    f = np.asarray(S.flight_opening(0.88, nf), float).ravel()
    assert np.all(np.diff(f) >= -1e-15)


def test_casadi_matches_numpy_and_the_jacobian_is_continuous():
    n, nf, fl = ca.SX.sym("n"), ca.SX.sym("nf"), ca.SX.sym("fl")
    expr = S.fraction(n, nf, fl)
    fun = ca.Function("f", [n, nf, fl], [expr, ca.jacobian(expr, ca.vertcat(n, nf, fl))])
    rng = np.random.default_rng(3)
    for a, b, c in zip(rng.uniform(0.6, 1.0, 40), rng.uniform(0.2, 1.0, 40),
                       rng.uniform(0.0, 1.0, 40), strict=True):
        val, _ = fun(a, b, c)
        assert abs(float(val) - float(S.fraction(a, b, c))) < 1e-12
    # across every knot of F the derivative in core speed has no jump (C1 Hermite)
    for v_k, _ in S.knots:
        jumps = []
        for side in (-1e-9, 1e-9):
            _, jac = fun(v_k + S.fan_bias * 0.5 + side, 0.5, 1.0)
            jumps.append(float(jac[0]))
        assert abs(jumps[1] - jumps[0]) < 1e-4 * max(1.0, abs(jumps[0])), v_k
