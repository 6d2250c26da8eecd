"""Can the data tell a candidate apart: from theta, from the other candidates, and how large
must it be to be seen.

All from the efficient information of the screen (:mod:`.score_statistics`), no model runs:

- **Projected signature.** ``S_ii`` is the squared norm of ``(I - P_N) J_i``, the part of the
  whitened signature of parameter ``i`` that theta (and the accepted effects) cannot explain;
  ``D_ii = |J_i|^2`` the whole. ``ratio = sqrt(S_ii / D_ii)``; below
  :data:`ABSORBED_RATIO` the candidate is *absorbed by theta*: it would bias the health
  estimate (by ``H_NN^-1 H_Ni`` per unit of ``phi_i``, reported as ``theta_shift``) but
  cannot be detected from residuals.
- **Ambiguity.** Two candidates whose projected signatures are nearly parallel cannot be told
  apart: the largest canonical correlation of their blocks of ``S_TT`` above
  :data:`AMBIGUOUS_CORR`. The operating points that separate them are those where their
  per-sample projected signatures (unit norm, leading canonical direction) differ most, binned
  by altitude, Mach and TRA (:func:`separating_points`).
- **Minimum detectable size** of each parameter at the family-wise level, with power
  :data:`POWER`: ``phi_min = sqrt(lambda / S_ii)`` where ``lambda`` is the noncentrality at
  which a noncentral chi-square with the candidate's degrees of freedom exceeds the critical
  value with that power (the local power of the score test, Rao 1948).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.optimize import brentq
from scipy.stats import chi2, ncx2

from .null_fit import FitState, Problem
from .score_statistics import Scores

ABSORBED_RATIO = 0.05
AMBIGUOUS_CORR = 0.95
POWER = 0.8


def _block(scores: Scores, c):
    pos = {int(t): i for i, t in enumerate(scores.tested)}
    return np.array([pos[int(i)] for i in c.index], int)


def noncentrality(df: int, p_crit: float, power: float = POWER) -> float:
    crit = chi2.isf(min(max(p_crit, 1e-300), 1.0), df)
    return float(brentq(lambda lam: ncx2.sf(crit, df, lam) - power, 1e-9, 1e6))


def candidate_report(scores: Scores, c, p_crit: float, df: int, theta_names=(),
                     n_theta: int = 0) -> dict:
    """Signature norms, ratio, absorbed flag, minimum detectable size per parameter and
    ``theta_shift``: how far theta (mean over cycles and units) moves to absorb one unit of
    each parameter, ``H_NN^-1 H_Nj`` (the bias an undeclared effect puts into the health
    estimate)."""
    b = _block(scores, c)
    S = scores.S[np.ix_(b, b)]
    D = scores.D[b]
    ratio = np.sqrt(np.clip(np.diag(S), 0, None) / np.maximum(D, 1e-300))
    # one-sided parameters: the test is at twice the level on the half line
    lam = noncentrality(df, p_crit * (2.0 if np.any(c.one_sided) and df == 1 else 1.0))
    mds = np.sqrt(lam / np.maximum(np.diag(S), 1e-300))
    k = len(theta_names)
    nt = int(np.sum(scores.nuisance < n_theta))
    shift = scores.shift[:nt, b].reshape(-1, k, len(b)).mean(axis=0)  # (k, n_params)
    return {"params": list(c.params), "signature_norm": np.sqrt(D).tolist(),
            "theta_shift": {q: {t: float(shift[i, j]) for i, t in enumerate(theta_names)}
                            for j, q in enumerate(c.params)},
            "projected_norm": np.sqrt(np.clip(np.diag(S), 0, None)).tolist(),
            "ratio": ratio.tolist(), "absorbed": bool(np.all(ratio < ABSORBED_RATIO)),
            "min_detectable": mds.tolist()}


def canonical_corr(scores: Scores, a, b) -> tuple[float, np.ndarray, np.ndarray]:
    """Largest canonical correlation of candidates ``a`` and ``b`` in ``S_TT``, with the
    leading directions (in parameter space) of each."""
    ia, ib = _block(scores, a), _block(scores, b)
    S = scores.S

    def isqrt(M):
        v, U = np.linalg.eigh(0.5 * (M + M.T))
        v = np.where(v > 1e-12 * max(v.max(), 1e-300), v, np.inf)
        return U @ np.diag(v ** -0.5) @ U.T

    Wa, Wb = isqrt(S[np.ix_(ia, ia)]), isqrt(S[np.ix_(ib, ib)])
    M = Wa @ S[np.ix_(ia, ib)] @ Wb
    U, sv, Vt = np.linalg.svd(M)
    return float(sv[0]) if sv.size else 0.0, Wa @ U[:, 0], Wb @ Vt[0]


def projected_signature(problem: Problem, null: FitState, scores: Scores, c,
                        direction: np.ndarray) -> list:
    """Per unit, the whitened signature (N, m) of ``direction`` of candidate ``c`` with the
    part theta (and the accepted effects) can explain removed."""
    b = _block(scores, c)
    shift = scores.shift[:, b] @ direction  # over the nuisance
    nt = problem.n_theta
    out = []
    acc = scores.nuisance[scores.nuisance >= nt] - nt
    for i, u in enumerate(problem.units):
        jp = null.lin.J_phi[i]
        jt = null.lin.J_th[i]
        sig = jp[:, :, c.index] @ direction
        sl = slice(problem.offsets[i], problem.offsets[i + 1])
        th_shift = shift[:nt][sl].reshape(u.n_cycles, problem.k)[u.cyc]  # (N, k)
        sig = sig - np.einsum("nmk,nk->nm", jt, th_shift)
        if acc.size:
            sig = sig - jp[:, :, acc] @ shift[nt:]
        out.append(sig)
    return out


def separating_points(problem: Problem, null: FitState, scores: Scores, a, b, top: int = 3
                      ) -> list[dict]:
    """Operating-point bins (altitude 5,000 ft, Mach 0.1, TRA 10 %) where the projected
    signatures of ``a`` and ``b`` (leading canonical directions, unit norm) differ most."""
    rho, da, db = canonical_corr(scores, a, b)
    pa = projected_signature(problem, null, scores, a, da)
    pb = projected_signature(problem, null, scores, b, db)
    na = np.sqrt(sum(float(np.sum(x * x)) for x in pa))
    nb = np.sqrt(sum(float(np.sum(x * x)) for x in pb))
    sgn = np.sign(sum(float(np.sum(x * y)) for x, y in zip(pa, pb, strict=True))) or 1.0
    rows = []
    for u, xa, xb in zip(problem.units, pa, pb, strict=True):
        d = np.sum((xa / max(na, 1e-300) - sgn * xb / max(nb, 1e-300)) ** 2, axis=1)
        w = u.series.w
        rows.append(pd.DataFrame({"alt": np.floor(w[:, 0] / 5000) * 5000,
                                  "Mach": np.floor(w[:, 1] / 0.1) * 0.1,
                                  "TRA": np.floor(w[:, 2] / 10) * 10, "d": d}))
    df = pd.concat(rows, ignore_index=True)
    g = df.groupby(["alt", "Mach", "TRA"])["d"].agg(["sum", "size"]).reset_index()
    g = g.sort_values("sum", ascending=False).head(top)
    total = float(df["d"].sum()) or 1.0
    return [{"alt_ft": [float(r.alt), float(r.alt) + 5000], "Mach": [round(r.Mach, 2),
             round(r.Mach + 0.1, 2)], "TRA": [float(r.TRA), float(r.TRA) + 10],
             "share": float(r["sum"]) / total, "samples": int(r["size"])}
            for _, r in g.iterrows()]
