"""Efficient score tests of every candidate at once, from the null fit alone.

At the null fit (theta per cycle and the accepted effects: the nuisance ``N``; every other
candidate parameter at 0), with ``L`` the negative log posterior (:mod:`.null_fit`), its
gradient ``grad`` and Gauss-Newton matrix ``H`` over ``[N, phi]`` (exact, from the model's
sensitivities), the efficient score and information of the tested parameters ``T`` are
(Rao 1948; e.g. Boos & Stefanski 2013, sec. 6.4)::

    s_T = -(grad_T - H_TN H_NN^-1 grad_N)        (what theta cannot already explain)
    S_TT = H_TT - H_TN H_NN^-1 H_NT               (null covariance of s_T)

(``grad_N`` is ~0 at a converged fit; keeping it makes the statistic the one-step score at
the null even where the fit stopped short.) For candidate ``j`` with the block ``b`` of ``T``:
``Z = S_bb^-1 s_b`` (the one-step estimate), and the statistic is the drop of the quadratic
model of ``2 L`` when ``phi_b`` is set free within its cone ``K`` (``phi >= 0`` for a
one-sided parameter, free otherwise)::

    T_j = Z^T S_bb Z - min_{phi in K} (Z - phi)^T S_bb (Z - phi)

Two-sided: ``T_j = s_b^T S_bb^-1 s_b ~ chi2(k)``. With one-sided parameters the null is on the
boundary and ``T_j`` follows the chi-bar-squared distribution ``sum_i w_i chi2(i)`` (Silvapulle
& Sen 2005, ch. 3; Self & Liang 1987), e.g. ``1/2 chi2(0) + 1/2 chi2(1)`` for one parameter;
the weights ``w_i`` (the probability that the projection of ``Z ~ N(0, S^-1)`` onto ``K`` has
``i`` free coordinates) are estimated from the same draws of ``N(0, S_TT)`` that give the
family-wise critical value (:mod:`.max_stat`). The minimum over the cone is found exactly by
enumerating the active sets (a candidate has at most a few parameters).

Cost: one linearisation at the null fit; no re-solve per candidate.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from .null_fit import DENSE_MAX, FitState, Problem


@dataclass
class Scores:
    """Efficient scores of the tested parameters ``tested`` (indices into the global phi):
    ``s`` (n_T,), information ``S`` (n_T, n_T), raw information ``D`` (n_T,) = diag of
    J^T J (the signature's squared norm before projection), and ``shift`` (n_N, n_T) =
    H_NN^-1 H_NT, how the nuisance moves to absorb each parameter."""

    tested: np.ndarray
    s: np.ndarray
    S: np.ndarray
    D: np.ndarray
    shift: np.ndarray
    nuisance: np.ndarray


def efficient_scores(problem: Problem, null: FitState, accepted: np.ndarray) -> Scores:
    nt = problem.n_theta
    accepted = np.asarray(accepted, int)
    tested = np.setdiff1d(np.arange(problem.n_phi), accepted)
    N = np.concatenate([np.arange(nt), nt + accepted])
    T = nt + tested
    H, g = null.H, null.grad
    if len(N) <= DENSE_MAX:  # the dense solve, as before the block structure
        Hd = H.dense()
        HNN = Hd[np.ix_(N, N)]
        HNT = Hd[np.ix_(N, T)]
        d = np.sqrt(np.maximum(np.diag(HNN), 1e-300))
        M = np.linalg.solve(HNN / np.outer(d, d) + 1e-12 * np.eye(len(N)),
                            np.column_stack([HNT / d[:, None], g[N] / d]))
        M = M / d[:, None]
        HTT = Hd[np.ix_(T, T)]
    else:  # in the block structure (normal_matrix): linear in the number of units
        HNT = np.vstack([H.theta_columns(tested), H.D[np.ix_(accepted, tested)]])
        M = H.solve(accepted, np.column_stack([HNT, g[N]]))
        HTT = H.D[np.ix_(tested, tested)]
    shift, corr = M[:, :-1], M[:, -1]
    s = -(g[T] - HNT.T @ corr)
    S = HTT - HNT.T @ shift
    S = 0.5 * (S + S.T)
    return Scores(tested, s, S, np.diag(H.D)[tested].copy(), shift, N)


def cone_signs(candidate) -> np.ndarray:
    """+1 for phi >= 0, -1 for phi <= 0, 0 for a free parameter (relative to neutral)."""
    return np.where(np.isfinite(candidate.lower), 1, np.where(np.isfinite(candidate.upper),
                                                               -1, 0)).astype(int)


def _reg(S):
    k = len(S)
    return S + 1e-10 * max(np.trace(S) / max(k, 1), 1e-300) * np.eye(k)


def cone_statistic(s: np.ndarray, S: np.ndarray, signs: np.ndarray):
    """The statistic of the module docstring for scores ``s`` (M, k) (rows: draws or the
    observed one) with information ``S`` (k, k); returns ``(T (M,), dim (M,), phi (M, k))``:
    the statistic, the number of free coordinates of the projection and the projected
    one-step estimate."""
    s = np.atleast_2d(s)
    S = _reg(S)
    Sinv = np.linalg.inv(S)
    Z = s @ Sinv
    full = np.einsum("mi,ij,mj->m", Z, S, Z)
    k = len(signs)
    con = np.flatnonzero(signs != 0)
    if con.size == 0:
        return full, np.full(len(s), k), Z
    best = np.full(len(s), np.inf)
    dim = np.zeros(len(s), int)
    phi = np.zeros_like(Z)
    for r in range(con.size + 1):
        for act in itertools.combinations(con, r):
            act = np.array(act, int)
            fre = np.setdiff1d(np.arange(k), act)
            ph = np.zeros_like(Z)
            if fre.size:
                if act.size:
                    corr = np.linalg.solve(S[np.ix_(fre, fre)], S[np.ix_(fre, act)] @ Z[:, act].T).T
                    ph[:, fre] = Z[:, fre] + corr
                else:
                    ph[:, fre] = Z[:, fre]
            u = Z - ph
            q = np.einsum("mi,ij,mj->m", u, S, u)
            feas = np.all(ph[:, con] * signs[con] >= -1e-12, axis=1)
            # coordinates free in this face but constrained must be strictly inside
            better = feas & (q < best - 1e-14)
            best = np.where(better, q, best)
            dim = np.where(better, fre.size, dim)
            phi[better] = ph[better]
    return np.maximum(full - best, 0.0), dim, phi


def chibar_pvalue(T, weights: np.ndarray) -> np.ndarray:
    """``P(sum_i w_i chi2(i) >= T)`` (``weights[i]`` for ``i`` = 0..k free coordinates)."""
    T = np.asarray(T, float)
    p = np.zeros_like(T)
    for i, wi in enumerate(weights):
        if wi <= 0:
            continue
        p += wi * (np.where(T <= 0, 1.0, 0.0) if i == 0 else chi2.sf(T, i))
    return np.clip(p, 0.0, 1.0)
