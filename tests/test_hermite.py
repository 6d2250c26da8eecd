"""engine_model.physics.hermite: the monotone cubic Hermite tables of the controller's schedules."""

import casadi as ca
import numpy as np

from engine_model.physics.hermite import fritsch_carlson_slopes, hermite


def test_keeps_knots_monotonicity_and_flat_stretches():
    t = np.array([0.0, 1.0, 1.5, 4.0, 5.0])
    y = np.array([0.0, 2.0, 2.1, 2.1, 7.0])  # a flat stretch between rising ones
    m = fritsch_carlson_slopes(t, y)
    np.testing.assert_allclose(hermite(t, t, y, m), y, atol=1e-12)
    x = np.linspace(-1.0, 6.0, 7001)
    v = hermite(x, t, y, m)
    assert np.all(np.diff(v) >= -1e-12)
    np.testing.assert_allclose(v[(x >= 1.5) & (x <= 4.0)], 2.1, atol=1e-12)  # no overshoot
    assert np.all(v[x < 0.0] == 0.0)  # constant below the table
    np.testing.assert_allclose(v[x > 5.0], 7.0 + m[-1] * (x[x > 5.0] - 5.0))  # linear above


def test_is_c1_and_the_same_in_casadi():
    t = np.array([0.7, 0.8, 0.9, 0.95])
    y = np.array([0.3, 0.2, 0.05, 0.0])
    m = fritsch_carlson_slopes(t, y)
    m[-1] = 0.0
    s = ca.SX.sym("s")
    fn = ca.Function("f", [s], [hermite(s, t, y, m), ca.jacobian(hermite(s, t, y, m), s)])
    x = np.linspace(0.6, 1.0, 4001)
    np.testing.assert_allclose(np.asarray(fn(x[None, :])[0]).ravel(), hermite(x, t, y, m),
                               atol=1e-14)
    for k in t:
        lo, hi = (np.asarray(fn(k + e)[1]).item() for e in (-1e-9, 1e-9))
        assert abs(lo - hi) < 1e-5, k
