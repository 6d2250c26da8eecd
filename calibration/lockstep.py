"""Lockstep random-walk filters: the state of ``U`` independent filters of the health
parameters, advanced one sample per unit at a time.

Per-step Python overhead, not the engine model, limits a filter that runs one sample at a time.
:class:`LockstepFilter` therefore holds ``U`` units (lanes) side by side as plain arrays, mean
``m`` (U, k) and covariance ``P`` (U, k, k): a step predicts and updates one sample of every
active lane with one batched call of the model for all lanes' points and numpy linear algebra
on stacked arrays. The units stay independent: a lane's numbers do not depend on which other
lanes run with it. The UKF (:mod:`calibration.ukf`) and the EKF (:mod:`calibration.ekf`)
subclass it with their measurement update; :mod:`calibration.kalman` drives whole series.

Warm start. Each lane keeps the unknowns ``x`` of its model points of the previous step and the
LU factors of their last Jacobian (``model.jacobian_store``); at 0.1 Hz a step moves ``w``
little and theta less, so the Newton-chord iteration converges in 1-3 residual evaluations
without a fresh Jacobian. A point that does not converge from there is retried by the model
(``solve_from(..., retry=True)``); if it still fails, the lane skips the update of that sample.

The model is any :class:`engine_model.solver.interface.SteadyStateModel`: the engine, or an analytic
model in the tests.
"""

from __future__ import annotations

from abc import abstractmethod

import numpy as np

from engine_model.solver.interface import SteadyStateModel

from .estimation_setup import CalibrationSetup


class LockstepFilter:
    """State of ``U`` random-walk filters of ``k`` parameters: plain arrays ``m`` (U, k) and
    ``P`` (U, k, k), plus the warm-start unknowns ``x`` (U, n_points, 7) of each lane's model
    points. Subclasses implement :meth:`update`.

    ``predict(q_var)`` adds the random-walk step ``q_var`` (U,) times the identity to ``P``;
    ``update(w, y, sigma, rows)`` assimilates one sample per lane (:meth:`KalmanEstimator.
    run_group` drives whole series). Both act on the first ``A`` lanes given by the arrays'
    length (the active prefix).
    """

    n_points: int = 1  # model points per lane and step

    def __init__(self, model: SteadyStateModel, setup: CalibrationSetup, n_lanes: int,
                 tol: float = 1e-10, max_iter: int = 30):
        self.model = model
        self.setup = setup
        self.k = setup.k
        self.tol = tol
        self.max_iter = max_iter
        self.lo, self.hi = setup.bounds
        self.pidx = setup.param_index
        self.theta_base = setup.theta_base()
        self.m = np.tile(setup.prior_mean_vec(), (n_lanes, 1))
        self.P = np.tile(np.diag(setup.prior_std_vec() ** 2), (n_lanes, 1, 1))
        self.x = None  # (U, n_points, n_x) after the first step
        self._lu = None  # Jacobian factors of every lane's points, carried between steps
        self.iterations = 0
        self.solves = 0
        self.retries = 0
        # per-step outputs of the last update, for the driver
        self.innovation = None  # (A, m) normalised (y - y_pred) / sigma
        self.nis = None  # (A,)
        self.ok = None  # (A,) update done
        self.x_center = None  # (A, n_x) unknowns at the prior mean

    # -- model evaluation
    def solve_points(self, w, theta_est, lanes: int):
        """Solve the steady state at ``theta_est`` (A, P, k) and ``w`` (A, 4) of the first
        ``lanes`` lanes, warm-started; returns unknowns (A, P, n_x), outputs (A, P, n_out) and
        a converged mask (A, P)."""
        A, npt, _ = theta_est.shape
        th = np.broadcast_to(self.theta_base, (A, npt, len(self.theta_base))).copy()
        th[:, :, self.pidx] = theta_est
        th = th.reshape(A * npt, -1)
        W = np.repeat(w, npt, axis=0)
        if self.x is None:
            x0 = self.model.initial_guess(W, th)
        else:
            x0 = self.x[:A].reshape(A * npt, -1)
        if self._lu is None:
            self._lu = self.model.jacobian_store(len(self.m) * npt)
        lu = None if self._lu is None else self._lu.head(A * npt)
        r = self.model.solve_from(W, th, x0, None, self.tol, self.max_iter, lu=lu, retry=True)
        self.iterations += int(r.iterations.sum())
        self.solves += len(W)
        self.retries += int(r.retried.sum())
        y = self.model.outputs_at(r.x, W, th)
        x = r.x.reshape(A, npt, -1)
        if self.x is None:
            self.x = np.zeros((len(self.m), npt, x.shape[-1]))
            self.x[:A] = x
        else:
            conv = r.converged.reshape(A, npt)
            self.x[:A] = np.where(conv[:, :, None], x, self.x[:A])
        return x, y.reshape(A, npt, -1), r.converged.reshape(A, npt)

    def sensitivities(self, x, w, th):
        """Exact ``dy/dtheta`` (N, n_out, 10) at the unknowns ``x`` (implicit function
        theorem on the residual system)."""
        return self.model.sensitivities_at(x, w, th).theta

    # -- filter steps
    def predict(self, q_var: np.ndarray):
        """Random walk: ``P += q_var I`` for the first ``len(q_var)`` lanes."""
        A = len(q_var)
        idx = np.arange(self.k)
        self.P[:A, idx, idx] += q_var[:, None]

    @abstractmethod
    def update(self, w: np.ndarray, y: np.ndarray, sigma: np.ndarray, rows: np.ndarray):
        """Assimilate one sample per active lane: ``w`` (A, 4), readings ``y`` (A, m) of the
        sensors at output rows ``rows``, their noise std ``sigma`` (A, m)."""

    def _finish_update(self, A):
        """Symmetrise, keep positive definite and project the mean onto the bounds."""
        P = self.P[:A]
        P = 0.5 * (P + np.swapaxes(P, 1, 2))
        self.P[:A] = make_pd(P)
        np.clip(self.m[:A], self.lo, self.hi, out=self.m[:A])


def make_pd(P: np.ndarray, floor: float = 1e-18) -> np.ndarray:
    """Symmetric positive definite version of stacked symmetric matrices (U, k, k): returned
    unchanged when the Cholesky factorisation of every matrix succeeds, else the failed ones'
    eigenvalues are floored at ``floor`` plus 1e-12 of their largest."""
    try:
        np.linalg.cholesky(P)
        return P
    except np.linalg.LinAlgError:
        pass
    lam, V = np.linalg.eigh(P)
    lam = np.maximum(lam, floor + 1e-12 * np.abs(lam).max(axis=1, keepdims=True))
    return np.einsum("uij,uj,ukj->uik", V, lam, V)


