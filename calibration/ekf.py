"""Extended Kalman filter of the health parameters with exact model sensitivities.

Same state space as the UKF (:mod:`calibration.estimation_setup`, paper eq. 5-6). Per sample ``n``
and lane (unit)::

    predict   P <- P + q^2 dtau_n I                                  (m unchanged)
    linearise x_n solves r(x, w_n, m) = 0 (compiled Newton, warm-started from the previous
              sample); y_bar = F(w_n, m) / sigma_n;
              H = dF/dtheta (w_n, m) / sigma_n   exact, by the implicit function theorem
              on the residual system (CasADi AD: dy/dtheta - dy/dx (dr/dx)^-1 dr/dtheta)
    update    nu = y_n / sigma_n - y_bar,   S = H P H^T + I
              P <- (P^-1 + H^T H)^-1,       m <- m + P H^T nu        (information form)

The information form is algebraically the Kalman update (``K = P H^T S^-1``) and keeps ``P``
symmetric positive definite by construction; it is symmetrised and checked like the UKF's
(:func:`lockstep.make_pd`) and the mean is projected onto the bounds. One model point per lane
and step: all lanes' points in one batched Newton call and one call of the compiled
sensitivity function.
"""

from __future__ import annotations

import numpy as np

from .kalman import KalmanEstimator
from .lockstep import LockstepFilter


class ExtendedFilter(LockstepFilter):
    """Lockstep EKF over ``n_lanes`` units (equations in the module docstring)."""

    n_points = 1

    def update(self, w, y, sigma, rows):
        A = len(w)
        m = self.m[:A]
        x, Yall, conv = self.solve_points(w, m[:, None, :], A)
        x = x[:, 0]
        th = np.broadcast_to(self.theta_base, (A, len(self.theta_base))).copy()
        th[:, self.pidx] = m
        H = self.sensitivities(x, w, th)[:, rows][:, :, self.pidx] / sigma[:, :, None]
        ybar = Yall[:, 0, rows] / sigma
        ok = conv[:, 0] & np.all(np.isfinite(ybar), axis=1) & np.all(np.isfinite(H),
                                                                      axis=(1, 2))
        H = np.where(ok[:, None, None], H, 0.0)
        nu = np.where(ok[:, None], y / sigma - ybar, 0.0)
        P = self.P[:A]
        info = np.linalg.inv(P) + np.einsum("ami,amj->aij", H, H)
        P_new = np.linalg.inv(info)
        dm = np.einsum("aij,amj,am->ai", P_new, H, nu)
        S = np.einsum("ami,aij,anj->amn", H, P, H) + np.eye(H.shape[1])
        nis = np.einsum("am,am->a", nu, np.linalg.solve(S, nu[:, :, None])[:, :, 0])
        self.m[:A] = np.where(ok[:, None], m + dm, m)
        self.P[:A] = np.where(ok[:, None, None], P_new, P)
        self._finish_update(A)
        self.innovation = np.where(ok[:, None], nu, np.nan)
        self.nis = np.where(ok, nis, np.nan)
        self.ok = ok
        self.x_center = x


class EKF(KalmanEstimator):
    """Extended Kalman filter estimator (module docstring); options ``tol`` / ``max_iter`` of
    the Newton solver, ``max_lanes`` units run in lockstep per group."""

    name = "ekf"
    filter_class = ExtendedFilter

    def __init__(self, model=None, tol: float = 1e-10, max_iter: int = 30,
                 max_lanes: int = 64):
        super().__init__(model, tol=tol, max_iter=max_iter, max_lanes=max_lanes)
