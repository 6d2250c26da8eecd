"""Family-wise control over all candidates: the null distribution of the smallest p-value.

Under the null every efficient score is Gaussian with the covariance the null fit already
gives, ``s_T ~ N(0, S_TT)`` (:mod:`.score_statistics`), jointly over all candidates. Drawing from
it (no model runs) gives, for every draw, every candidate's statistic and its chi-bar-squared
p-value; the ``alpha`` quantile of the smallest p-value over the candidates is the
family-wise critical value of the *min-P* (equivalently, max-statistic after calibration to a
common scale) single-step procedure of Westfall & Young (1993), as used for correlated tests
by Hothorn, Bretz & Westfall (2008): the correlation between candidates (a bias on T48 and a
customer bleed both move T48) is taken into account exactly, so the procedure is less
conservative than Bonferroni while keeping ``P(any false discovery) <= alpha``.

The same draws estimate each candidate's chi-bar-squared weights (the distribution of the
number of free coordinates of its projected one-step estimate).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .score_statistics import Scores, chibar_pvalue, cone_signs, cone_statistic


@dataclass
class ScreenResult:
    """Per candidate (same order as ``candidates``): statistic ``T``, degrees of freedom,
    chi-bar weights, p-value, one-step estimate ``phi1`` of its parameters; the family-wise
    critical p-value ``p_crit`` and the draws used."""

    candidates: list
    T: np.ndarray
    df: np.ndarray
    weights: list
    p: np.ndarray
    phi1: list
    p_crit: float
    alpha: float
    n_draws: int

    def order(self) -> np.ndarray:
        """Candidates from the most to the least significant."""
        return np.lexsort((-self.T, self.p))


def _draws(S: np.ndarray, n: int, rng) -> np.ndarray:
    vals, vecs = np.linalg.eigh(0.5 * (S + S.T))
    vals = np.clip(vals, 0.0, None)
    return (rng.standard_normal((n, len(S))) * np.sqrt(vals)) @ vecs.T


def screen(scores: Scores, candidates: list, alpha: float = 0.01, n_draws: int = 20000,
           seed: int = 0) -> ScreenResult:
    """Statistics, p-values and the family-wise critical p-value of ``candidates`` (those
    whose parameters are all in ``scores.tested``)."""
    rng = np.random.default_rng(seed)
    pos = {int(t): i for i, t in enumerate(scores.tested)}
    sim = _draws(scores.S, n_draws, rng)
    T, dfs, wts, ps, phis, p_sim = [], [], [], [], [], []
    for c in candidates:
        b = np.array([pos[int(i)] for i in c.index], int)
        Sb = scores.S[np.ix_(b, b)]
        sg = cone_signs(c)
        t_obs, _, ph = cone_statistic(scores.s[b][None, :], Sb, sg)
        t_sim, dim_sim, _ = cone_statistic(sim[:, b], Sb, sg)
        w = np.bincount(dim_sim, minlength=len(b) + 1) / n_draws
        if not np.any(sg):  # two-sided: exactly chi2(k)
            w = np.zeros(len(b) + 1)
            w[len(b)] = 1.0
        T.append(float(t_obs[0]))
        dfs.append(len(b))
        wts.append(w)
        ps.append(float(chibar_pvalue(t_obs, w)[0]))
        phis.append(ph[0])
        p_sim.append(chibar_pvalue(t_sim, w))
    pmin = np.min(np.vstack(p_sim), axis=0) if p_sim else np.ones(n_draws)
    p_crit = float(np.quantile(pmin, alpha))
    return ScreenResult(list(candidates), np.array(T), np.array(dfs), wts, np.array(ps), phis,
                        p_crit, alpha, n_draws)
