"""The variable-bleed-valve schedule (engine_model.physics.bleed_schedule): shut at the design
point and at high core speed, open at flight idle, limited at ground-idle fan speeds, monotone,
smooth, and the same on floats, numpy arrays and CasADi symbols."""

import casadi as ca
import numpy as np

from engine_model.physics.bleed_schedule import BleedValveSchedule

S = BleedValveSchedule()


def test_shut_at_the_design_point_and_above_the_core_closing_speed():
    assert S.fraction(1.0, 1.0, 0.0) == 0.0
    n_fan = np.linspace(0.2, 1.1, 50)
    for mach in (0.0, 0.4, 0.85):
        assert np.all(np.asarray(S.fraction(S.core_close[1], n_fan, mach), float) == 0.0)


def test_open_at_flight_idle_and_limited_at_ground_idle_speeds():
    # flight idle at altitude and high Mach: corrected core speed 0.75, fan 0.59 (audit)
    f_flight = float(S.fraction(0.75, 0.59, 0.8))
    assert 0.25 < f_flight <= max(k[1] for k in S.knots)
    # ground idle: corrected fan speed 0.25-0.33, where the booster chokes above 0.075
    for n_hpc, n_fan in ((0.64, 0.25), (0.66, 0.27), (0.71, 0.33)):
        assert abs(float(S.fraction(n_hpc, n_fan, 0.0)) - S.f_low) < 1e-12
        assert float(S.unlimited_opening(n_hpc, n_fan, 0.0)) > S.f_low + S.limit_band
    # ram raises the limit; above the band the limit is gone (exact outside the blend)
    assert float(S.low_speed_limit(0.3, 0.15)) > float(S.low_speed_limit(0.3, 0.0))
    assert float(S.low_speed_limit(S.low_speed_band[1], 0.0)) == 1.0
    assert float(S.fraction(0.75, 0.59, 0.8)) == float(S.unlimited_opening(0.75, 0.59, 0.8))


def test_opening_falls_with_core_speed_and_rises_with_fan_speed():
    n = np.linspace(0.6, 1.0, 401)
    for nf in (0.5, 0.7, 0.9):
        f = np.asarray(S.unlimited_opening(n, nf, 0.5), float).ravel()
        assert np.all(np.diff(f) <= 1e-15) and f[0] > 0.0 and f[-1] == 0.0
    nf = np.linspace(0.2, 1.0, 401)
    f = np.asarray(S.unlimited_opening(0.88, nf, 0.5), float).ravel()
    assert np.all(np.diff(f) >= -1e-15)


def test_casadi_matches_numpy_and_the_jacobian_is_continuous():
    n, nf, mach = ca.SX.sym("n"), ca.SX.sym("nf"), ca.SX.sym("mach")
    expr = S.fraction(n, nf, mach)
    fun = ca.Function("f", [n, nf, mach], [expr, ca.jacobian(expr, ca.vertcat(n, nf, mach))])
    rng = np.random.default_rng(3)
    for a, b, c in zip(rng.uniform(0.6, 1.0, 40), rng.uniform(0.2, 1.0, 40),
                       rng.uniform(0.0, 0.85, 40), strict=True):
        val, _ = fun(a, b, c)
        assert abs(float(val) - float(S.fraction(a, b, c))) < 1e-12
    # across every knot of F the derivative in core speed has no jump (C1 Hermite)
    nf0, m0 = 0.6, 0.3
    for v_k, _ in S.knots:
        n_k = v_k + S.fan_bias * nf0 + S.mach_bias * m0
        slopes = [float(fun(n_k + side, nf0, m0)[1][0]) for side in (-1e-9, 1e-9)]
        assert abs(slopes[1] - slopes[0]) < 1e-4 * max(1.0, abs(slopes[0])), v_k
