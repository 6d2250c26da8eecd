"""Cramér-Rao bounds of the health-parameter estimates, with exact model sensitivities.

Notation: ``S_k = R_k^{-1/2} dF/dtheta (w_k, theta_k)`` (m, k) the whitened exact sensitivities
of the used sensors at the **true** theta (:func:`observability.scaled_sensitivities`), ``Q_k`` the
random-walk covariance before sample ``k`` and ``P_0`` the prior covariance.

Random-walk filters (UKF, EKF): the recursive posterior CRB of Tichavsky, Muravchik and
Nehorai (IEEE Trans. Signal Process. 46(5), 1998) for ``theta_{k+1} = theta_k + xi``,
``xi ~ N(0, Q)``, with the Fisher information ``J_k`` of ``theta_k``::

    J_{k+1} = Q^-1 - Q^-1 (J_k + Q^-1)^-1 Q^-1 + S_{k+1}^T S_{k+1}
            = (J_k^-1 + Q)^-1 + S_{k+1}^T S_{k+1}              (matrix inversion lemma)
    J_0     = P_0^-1 + S_0^T S_0,        bound: cov(theta_hat_k - theta_k) >= J_k^-1

The second form is used: it is the same number, and holds for ``Q = 0`` (no drift within a
flight when the drift enters per cycle), where ``J`` simply accumulates ``S^T S``. The bound
uses the exact sensitivities at the truth, i.e. the expectation over the measurement noise of
the information is replaced by its value at the true trajectory (exact for a measurement
model linear in theta around the truth; the usual practice for Gaussian additive noise, where
the Fisher information of one sample is ``S^T S`` whatever the noise draw).

Windowed MAP with one theta per window: the inverse Fisher information of the window,
``(P_a^-1 + sum_{k in window} S_k^T S_k)^-1``, with the prior / arrival-cost information
``P_a^-1`` where the data alone cannot determine theta (:func:`window_crb`).
"""

from __future__ import annotations

import numpy as np


def _as_q(q_var, n, k):
    q = np.asarray(q_var, float)
    if q.ndim == 0:
        q = np.full(n, float(q))
    if q.ndim == 1:
        if len(q) != n:
            raise ValueError(f"q_var: expected {n} values, got {len(q)}")
        return q[:, None, None] * np.eye(k)
    if q.shape != (n, k, k):
        raise ValueError(f"q_var: expected shape ({n}, {k}, {k}), got {q.shape}")
    return q


def posterior_crb(S: np.ndarray, q_var, prior_cov: np.ndarray) -> np.ndarray:
    """Recursive posterior CRB (module docstring) of a random walk observed through ``S``
    (N, m, k). ``q_var``: (N,) variance of the walk's step before each sample (times the
    identity; the first entry is ignored), or (N, k, k); ``prior_cov`` (k, k) or (k,) std^2.
    Returns the bound covariances (N, k, k)."""
    S = np.asarray(S, float)
    n, _, k = S.shape
    Q = _as_q(q_var, n, k)
    P0 = np.asarray(prior_cov, float)
    P0 = np.diag(P0) if P0.ndim == 1 else P0
    info = np.einsum("nmi,nmj->nij", S, S)
    out = np.empty((n, k, k))
    # where Q is zero the information simply accumulates: cumulative sums per segment
    jumps = np.flatnonzero(np.any(Q[1:] != 0, axis=(1, 2))) + 1
    starts = np.concatenate([[0], jumps])
    ends = np.concatenate([jumps, [n]])
    J = None
    for s0, s1 in zip(starts, ends, strict=True):
        if J is None:
            base = np.linalg.inv(P0)
        else:
            Pp = np.linalg.inv(J) + Q[s0]
            base = np.linalg.inv(0.5 * (Pp + Pp.T))
        Js = base + np.cumsum(info[s0:s1], axis=0)
        out[s0:s1] = np.linalg.inv(Js)
        J = Js[-1]
    return 0.5 * (out + np.swapaxes(out, 1, 2))


def window_crb(S: np.ndarray, prior_info: np.ndarray | None = None) -> np.ndarray:
    """Inverse Fisher information ``(prior_info + sum S_k^T S_k)^-1`` (k, k) of one constant
    theta observed through ``S`` (N, m, k) — the bound of a windowed MAP estimate."""
    S = np.asarray(S, float)
    info = np.einsum("nmi,nmj->ij", S, S)
    if prior_info is not None:
        info = info + np.asarray(prior_info, float)
    return np.linalg.inv(info)


def windowed_crb(S: np.ndarray, windows: np.ndarray, prior_cov: np.ndarray,
                 arrival: bool = True, q_var=None) -> np.ndarray:
    """Bound per sample (N, k, k) for an estimator with one theta per window: sample ``k``
    gets :func:`window_crb` of its window (``windows`` (N,) labels, e.g. window number or
    cycle). With ``arrival``, each window starts from the previous window's information
    propagated through the random walk over the gap (``q_var`` (N,) summed over the window's
    samples from the previous window's start to this one's, as the MHE inflates its arrival
    cost; an MHE with an exact arrival cost), else from the prior alone (``map_cycle``)."""
    S = np.asarray(S, float)
    n, _, k = S.shape
    P0 = np.asarray(prior_cov, float)
    P0 = np.diag(P0) if P0.ndim == 1 else P0
    q = np.zeros(n) if q_var is None else np.asarray(q_var, float)
    labels = np.asarray(windows)
    starts = np.flatnonzero(np.r_[True, labels[1:] != labels[:-1]])
    ends = np.r_[starts[1:], n]
    out = np.empty((n, k, k))
    cov_prev, s_prev = None, 0
    for s0, s1 in zip(starts, ends, strict=True):
        if arrival and cov_prev is not None:
            Pa = cov_prev + np.sum(q[s_prev + 1:s0 + 1]) * np.eye(k)
        else:
            Pa = P0
        cov = window_crb(S[s0:s1], np.linalg.inv(Pa))
        out[s0:s1] = cov
        cov_prev, s_prev = cov, s0
    return out


def unit_sensitivities(model, series, setup, theta_true_est: np.ndarray, p=None):
    """Whitened exact sensitivities (N, m, k) of ``series``' sensors to ``setup.params`` at the
    true values ``theta_true_est`` (N, k) of the estimated parameters (the others at
    ``setup.theta_fixed``: the model the estimators assume). Points whose steady state does
    not converge get zero information."""
    from .observability import scaled_sensitivities

    th = setup.full_theta(theta_true_est)
    r = model.solve_series(series.w, th, p)
    S = np.zeros((len(series), len(series.sensors), setup.k))
    ok = r.converged
    if ok.any():
        S[ok] = scaled_sensitivities(model, series.w[ok], r.x[ok], th[ok], series.sigma[ok],
                                     series.sensors, setup.param_index, p)
    return S


def unit_posterior_crb(model, series, setup, theta_true_est: np.ndarray) -> np.ndarray:
    """Posterior CRB (N, k, k) of the random-walk filters for one unit with known truth."""
    S = unit_sensitivities(model, series, setup, theta_true_est)
    return posterior_crb(S, series.q_diag(setup), np.diag(setup.prior_std_vec() ** 2))
