"""The UKF and the EKF on a linear analytic model, where both must equal the Kalman filter.

For ``y = y0 + A theta`` with Gaussian noise and a random-walk theta, the Kalman filter is the
exact posterior; the unscented transform of a linear function is exact, and the EKF's
linearisation is the function itself, so the UKF, the EKF and the textbook Kalman filter
(Kalman 1960; Simon, *Optimal State Estimation*, Wiley 2006, ch. 5) agree to round-off. These
tests run the filters through the same :class:`engine_model.solver.interface.SteadyStateModel`
interface the engine implements, without building the engine (milliseconds).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from calibration import CalibrationSetup, get_estimator
from calibration.series import prepare_unit
from engine_model.channels import OUTPUT_NAMES, THETA_NAMES, W_NAMES, XS_NAMES
from engine_model.simulator.sensor_noise import sigma_abs
from engine_model.solver.interface import Sensitivities, SteadyStateModel
from engine_model.solver.newton_driver import SolveResult

SENSORS = ("Wf", "T30", "T48", "T50", "P30", "Nc")
PARAMS = ("HPT_eff_mod", "LPT_eff_mod", "LPT_flow_mod")


class LinearModel:
    """``y = y0 + A theta`` (every output in OUTPUT_NAMES order), one trivial unknown."""

    param_names: tuple = ()
    p_default = np.zeros(0)
    unknown_names = ("x",)
    output_names = OUTPUT_NAMES

    def __init__(self, seed: int = 0):
        rng = np.random.default_rng(seed)
        n_out = len(OUTPUT_NAMES)
        self.y0 = rng.uniform(100.0, 2000.0, n_out)
        # sensitivities of a few per cent of the reading per unit of theta
        self.A = self.y0[:, None] * rng.normal(0.0, 0.5, (n_out, len(THETA_NAMES)))
        self.n_solves = 0

    @property
    def n_unknowns(self) -> int:
        return 1

    @property
    def variant_key(self) -> str:
        return "linear"

    def p_matrix(self, p, n):
        return np.zeros((n, 0))

    def initial_guess(self, w, theta=None):
        return np.zeros((len(np.atleast_2d(w)), 1))

    def jacobian_store(self, n):
        return None

    def _result(self, n):
        self.n_solves += n
        return SolveResult(x=np.ones((n, 1)), converged=np.ones(n, bool),
                           residual_norm=np.zeros(n), iterations=np.ones(n, int))

    def solve_from(self, w, theta, x0, p=None, tol=1e-10, max_iter=30, lu=None, retry=True):
        return self._result(len(np.atleast_2d(w)))

    def solve(self, w, theta=None, p=None, x0=None, tol=1e-10, max_iter=30, check=True):
        return self._result(len(np.atleast_2d(w)))

    def solve_series(self, w, theta=None, p=None, tol=1e-10, max_iter=30, chunk=64,
                     starts=None):
        return self._result(len(np.atleast_2d(w)))

    def outputs_at(self, x, w, theta=None, p=None):
        n = len(np.atleast_2d(w))
        th = np.zeros((n, len(THETA_NAMES))) if theta is None else np.atleast_2d(theta)
        return self.y0[None, :] + th @ self.A.T

    def residuals_at(self, x, w, theta=None, p=None):
        return np.asarray(x, float) - 1.0

    def sensitivities_at(self, x, w, theta=None, p=None):
        n = len(np.atleast_2d(w))
        n_out = len(OUTPUT_NAMES)
        return Sensitivities(theta=np.broadcast_to(self.A, (n, *self.A.shape)).copy(),
                             w=np.zeros((n, n_out, len(W_NAMES))), p=np.zeros((n, n_out, 0)))


def unit_frame(model: LinearModel, n: int, seed: int, unit: int = 1) -> pd.DataFrame:
    """A unit drifting linearly in theta, measured with the noise of the sensor-noise table
    (the noise model the filters assume)."""
    rng = np.random.default_rng(seed)
    th = np.zeros((n, len(THETA_NAMES)))
    for j, q in enumerate(PARAMS):
        th[:, THETA_NAMES.index(q)] = -np.linspace(0.0, 0.01 * (j + 1), n)
    y = model.outputs_at(None, np.zeros((n, 4)), th)
    cols = [OUTPUT_NAMES.index(c) for c in XS_NAMES]
    y = y[:, cols]
    y = y + sigma_abs(y, XS_NAMES) * rng.standard_normal(y.shape)
    df = pd.DataFrame({"unit": unit, "t": np.arange(n) * 10.0, "alt": 30000.0, "Mach": 0.78,
                       "TRA": 80.0, "T2": 450.0})
    for j, c in enumerate(XS_NAMES):
        df[c] = y[:, j]
    return df


def kalman_reference(model: LinearModel, df: pd.DataFrame, setup: CalibrationSetup):
    """The textbook Kalman filter of the random walk, written out step by step."""
    s = prepare_unit(df, setup)
    rows = [OUTPUT_NAMES.index(c) for c in s.sensors]
    idx = setup.param_index
    H = model.A[np.ix_(rows, idx)]
    base = setup.theta_base()
    m = setup.prior_mean_vec().copy()
    P = np.diag(setup.prior_std_vec() ** 2)
    q2 = setup.drift ** 2
    ms, Ps, nis = [], [], []
    for k in range(len(s)):
        if k > 0:
            P = P + q2 * s.dtau_h[k] * np.eye(len(m))              # predict: P + Q
        th = base.copy()
        th[idx] = m
        nu = s.y[k] - (model.y0[rows] + model.A[rows] @ th)           # innovation
        R = np.diag(s.sigma[k] ** 2)
        S = H @ P @ H.T + R                                           # S = H P H' + R
        K = P @ H.T @ np.linalg.inv(S)                                # K = P H' S^-1
        m = m + K @ nu
        P = (np.eye(len(m)) - K @ H) @ P                              # P = (I - K H) P
        P = 0.5 * (P + P.T)
        ms.append(m.copy())
        Ps.append(P.copy())
        nis.append(float(nu @ np.linalg.solve(S, nu)))
    return np.array(ms), np.array(Ps), np.array(nis)


@pytest.fixture(scope="module")
def linear():
    return LinearModel(seed=4)


@pytest.fixture(scope="module")
def setup():
    return CalibrationSetup(params=PARAMS, sensors=SENSORS, drift=0.01)


def test_linear_model_satisfies_the_interface(linear):
    assert isinstance(linear, SteadyStateModel)


@pytest.mark.parametrize("method", ["ukf", "ekf"])
def test_filter_equals_kalman_on_a_linear_model(linear, setup, method):
    df = unit_frame(linear, 120, seed=1)
    res = get_estimator(method, model=linear).estimate(df, setup)
    m_ref, P_ref, nis_ref = kalman_reference(linear, df, setup)
    np.testing.assert_allclose(res.theta_hat.to_numpy(), m_ref, rtol=0, atol=1e-10)
    np.testing.assert_allclose(res.theta_cov, P_ref, rtol=1e-8, atol=1e-16)
    assert res.diagnostics["nis_mean"] == pytest.approx(nis_ref.mean(), rel=1e-8)
    # x_hat is the model at theta_hat
    th = np.zeros((len(df), len(THETA_NAMES)))
    th[:, setup.param_index] = m_ref
    y = linear.outputs_at(None, np.zeros((len(df), 4)), th)
    np.testing.assert_allclose(res.x_hat["T48_hat"], y[:, OUTPUT_NAMES.index("T48")],
                               rtol=1e-12)


def test_ukf_and_ekf_agree_and_track_the_truth(linear, setup):
    df = unit_frame(linear, 200, seed=2)
    u = get_estimator("ukf", model=linear).estimate(df, setup)
    e = get_estimator("ekf", model=linear).estimate(df, setup)
    np.testing.assert_allclose(u.theta_hat.to_numpy(), e.theta_hat.to_numpy(), atol=1e-10)
    truth = -0.01 * np.arange(1, 4)
    err = u.theta_hat.iloc[-1].to_numpy() - truth
    std = u.theta_std.iloc[-1].to_numpy()
    assert np.all(np.abs(err) < 4 * std)


def test_lanes_are_independent_on_a_linear_model(linear, setup):
    """Units of different lengths run in lockstep give each unit's solo result (to round-off:
    numpy's stacked linear algebra may round differently for a different stack size)."""
    a, b = unit_frame(linear, 80, seed=3, unit=1), unit_frame(linear, 50, seed=5, unit=2)
    est = get_estimator("ukf", model=linear)
    both = est.estimate_many([a, b], setup)
    for df, r in zip((a, b), both, strict=True):
        solo = est.estimate(df, setup)
        np.testing.assert_allclose(r.theta_hat.to_numpy(), solo.theta_hat.to_numpy(),
                                   rtol=0, atol=1e-14)
