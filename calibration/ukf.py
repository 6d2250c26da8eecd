"""Unscented Kalman filter of the health parameters on the exact engine model (paper eq. 5-6).

State ``theta`` (k,), a random walk; measurement the exact steady state ``F(w, theta)`` of the
chosen sensors (no surrogate). Per sample ``n`` and lane (unit)::

    predict   P  <- P + q^2 dtau_n I                                 (m unchanged)
    sigma     chi_0 = m,  chi_i = m + sqrt(c) L_i,  chi_{k+i} = m - sqrt(c) L_i,
              L L^T = P (Cholesky), c = k + lambda, lambda = alpha^2 (k + kappa) - k
    weights   Wm_0 = lambda / c,  Wc_0 = Wm_0 + 1 - alpha^2 + beta,  Wm_i = Wc_i = 1 / (2c)
    model     Y_i = F(w_n, chi_i) / sigma_n         all 2k+1 points of every lane in ONE batched
                                                   call of the compiled Newton solver
    moments   y_bar = sum Wm_i Y_i,  S = sum Wc_i (Y_i - y_bar)(Y_i - y_bar)^T + I,
              C = sum Wc_i (chi_i - m)(Y_i - y_bar)^T
    update    K = C S^-1,  nu = y_n / sigma_n - y_bar,  m <- m + K nu,  P <- P - K S K^T

Measurements are whitened by the sensor noise ``sigma_n`` (``R_n = diag(sigma_n^2)`` becomes
the identity). After every update ``P`` is symmetrised and, if a Cholesky factorisation fails,
its eigenvalues are floored (:func:`lockstep.make_pd`); the mean is projected onto the bounds.
The normalised innovation squared ``nu^T S^-1 nu`` (NIS, chi-square with ``m`` degrees of
freedom for a consistent filter) and the innovations ``nu`` are recorded.

Sigma-point defaults ``alpha = 1, beta = 2, kappa = 0``: points at ``+-sqrt(k)`` standard
deviations, all weights non-negative (``Wm_0 = 0``, ``Wc_0 = 2``). The measurement function is
smooth and close to linear over a few standard deviations of theta, so the wide spread costs
nothing, while a small ``alpha`` (e.g. 1e-3) puts the points so close together that the
solver's tolerance noise is amplified by ``1 / alpha^2`` in the weights.

Runs many units in lockstep (:class:`lockstep.LockstepFilter`); the estimator interface is
:class:`UKF` (``UKF().estimate(df, setup)``, ``estimate_many``).
"""

from __future__ import annotations

import numpy as np

from .kalman import KalmanEstimator
from .lockstep import LockstepFilter


class UnscentedFilter(LockstepFilter):
    """Lockstep UKF over ``n_lanes`` units (equations in the module docstring)."""

    def __init__(self, model, setup, n_lanes, tol=1e-10, max_iter=30, alpha: float = 1.0,
                 beta: float = 2.0, kappa: float = 0.0):
        super().__init__(model, setup, n_lanes, tol, max_iter)
        k = self.k
        lam = alpha ** 2 * (k + kappa) - k
        self.c = k + lam
        if self.c <= 0:
            raise ValueError(f"sigma points: k + lambda = {self.c} must be positive")
        self.n_points = 2 * k + 1
        wm = np.full(self.n_points, 0.5 / self.c)
        wc = wm.copy()
        wm[0] = lam / self.c
        wc[0] = lam / self.c + 1.0 - alpha ** 2 + beta
        self.wm, self.wc = wm, wc
        self.alpha, self.beta, self.kappa = alpha, beta, kappa

    def sigma_points(self, A: int) -> np.ndarray:
        """(A, 2k+1, k) sigma points of the first ``A`` lanes."""
        L = np.linalg.cholesky(self.P[:A]) * np.sqrt(self.c)
        m = self.m[:A, None, :]
        Lt = np.swapaxes(L, 1, 2)  # rows = columns of L
        return np.concatenate([m, m + Lt, m - Lt], axis=1)

    def update(self, w, y, sigma, rows):
        A = len(w)
        chi = self.sigma_points(A)
        x, Yall, conv = self.solve_points(w, chi, A)
        Y = Yall[:, :, rows] / sigma[:, None, :]
        ok = conv.all(axis=1) & np.all(np.isfinite(Y), axis=(1, 2))
        Y = np.where(ok[:, None, None], Y, 0.0)
        ybar = np.einsum("p,apm->am", self.wm, Y)
        dY = Y - ybar[:, None, :]
        dX = chi - self.m[:A, None, :]
        m_ = Y.shape[2]
        S = np.einsum("p,api,apj->aij", self.wc, dY, dY) + np.eye(m_)
        C = np.einsum("p,api,apj->aij", self.wc, dX, dY)
        nu = y / sigma - ybar
        Sinv_CT = np.linalg.solve(S, np.swapaxes(C, 1, 2))  # (A, m, k) = S^-1 C^T
        K = np.swapaxes(Sinv_CT, 1, 2)  # (A, k, m)
        Sinv_nu = np.linalg.solve(S, nu[:, :, None])[:, :, 0]
        dm = np.einsum("akm,am->ak", K, nu)
        dP = np.einsum("akm,amj->akj", C, Sinv_CT)  # K S K^T = C S^-1 C^T
        self.m[:A] += np.where(ok[:, None], dm, 0.0)
        self.P[:A] -= np.where(ok[:, None, None], dP, 0.0)
        self._finish_update(A)
        self.innovation = np.where(ok[:, None], nu, np.nan)
        self.nis = np.where(ok, np.einsum("am,am->a", nu, Sinv_nu), np.nan)
        self.ok = ok
        self.x_center = x[:, 0]


class UKF(KalmanEstimator):
    """Unscented Kalman filter estimator (module docstring); options ``alpha``, ``beta``,
    ``kappa`` of the sigma points, ``tol`` / ``max_iter`` of the Newton solver, ``max_lanes``
    units run in lockstep per group."""

    name = "ukf"
    filter_class = UnscentedFilter

    def __init__(self, model=None, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0,
                 tol: float = 1e-10, max_iter: int = 30, max_lanes: int = 64):
        super().__init__(model, tol=tol, max_iter=max_iter, max_lanes=max_lanes, alpha=alpha,
                         beta=beta, kappa=kappa)

    def describe(self) -> dict:
        return {"sigma_points": dict(self.filter_options)}
