"""Confirmation of a screened candidate: joint bounded refit, likelihood ratio, held-out
flights.

1. Refit ``(Theta, phi_accepted, phi_j)`` jointly (:func:`null_fit.fit`: bounded
   Gauss-Newton with exact Jacobians), warm-started at the null fit with ``phi_j`` at its
   one-step estimate projected onto its cone (:mod:`.score_statistics`).
2. Likelihood ratio ``LR = 2 (L_null - L_alt)``; under the null it has the same
   chi-bar-squared distribution as the score statistic (Silvapulle & Sen 2005, sec. 4.3), so its
   p-value uses the candidate's weights, and it must pass the family-wise critical p-value of
   the screen (:mod:`.max_stat`).
3. Held-out whole flights: every third cycle of every unit with at least three cycles (cycles
   2, 5, 8, ... in row order) is left out of the estimate of ``phi`` (null and alternative
   alike); then, with ``phi`` fixed at that estimate, theta is fitted on every flight (theta
   is a per-flight nuisance: each held-out flight gets its own, from its own samples and the
   drift prior) and the residual of the held-out flights is compared. The candidate must
   lower it. Data with fewer than three cycles in every unit have no held-out flights and
   rely on the likelihood ratio alone (reported).
4. It must explain a material share of what is wrong: ``LR / max(X, LR) >=``
   :data:`MIN_SHARE`, with the excess ``X = sum e^2 - (n m - n_free)`` of the null fit's
   residual over its expectation under the noise model (the chi-square excess). A true
   effect explains nearly all of it (share ~ 1); a wrong candidate that only soaks up a
   corner of a large undeclared effect's signature explains a fraction (on the ``tiny``
   fleet with an undeclared customer bleed of f0 = 0.015: an inlet loss 28 %, a T24 bias
   32 %) and is not added; what remains is reported as an unknown effect (:mod:`.unknown`).
   Two effects of about equal size with unrelated signatures each explain about half, hence
   a threshold between the two (:data:`MIN_SHARE` = 0.4); with two equal effects the margin is
   10 points either way, so a share near 0.4 is reported as a rejection, never silently.
   The excess itself is noisy (its null std is ``sqrt(2 n m)``, about 350 on one ``tiny``
   unit): a candidate is rejected for its share only when the part it leaves unexplained,
   ``X - LR``, is itself significant (above :data:`REMAINDER_Z` null std), so that a small
   true effect near the detection limit is not refused because of the noise in ``X``.
5. Its estimate must lie within the effect's documented valid range (``Param.valid``): a
   bleed of 30 % or an efficiency scaler that changes by 40 % per percent of speed is not
   that effect but the fit bending a flexible shape to something else (seen on C-MAPSS's six
   operating points with the map-adaptation candidates).
6. ``phi_j`` with its standard error from the inverse Gauss-Newton matrix of the joint fit
   (the Cramer-Rao bound at the estimate, theta uncertainty included), and a 95 % interval
   (clipped at the boundary of a one-sided parameter).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .null_fit import DENSE_MAX, FitState, Problem, fit
from .score_statistics import chibar_pvalue

MIN_SHARE = 0.4
REMAINDER_Z = 3.0


def holdout_masks(problem: Problem, every: int = 3):
    """Per-unit sample masks ``(train, held_out)`` (1.0 / 0.0) of whole flights; None when no
    unit has at least ``every`` cycles."""
    train, held = [], []
    any_held = False
    for u in problem.units:
        if u.n_cycles >= every:
            h = (u.cyc % every) == 1
            any_held |= bool(h.any())
        else:
            h = np.zeros(u.n, bool)
        train.append((~h).astype(float))
        held.append(h.astype(float))
    return (train, held) if any_held else None


def held_out_sse(problem: Problem, start: FitState, phi: np.ndarray, held) -> float:
    """Residual sum of squares on the held-out flights of the model with ``phi`` fixed and
    theta fitted on every flight (warm-started at ``start``)."""
    st = fit(problem, start.Theta, phi, (), xs=start.lin.x)
    return problem.linearize(st.Theta, st.phi, st.lin.x, held, derivatives=False).sse


@dataclass
class Confirmation:
    """The refit of one candidate: ``fit`` (joint, all data), ``LR``, ``p_value``,
    ``share`` of the null fit's chi-square excess it explains,
    ``phi`` / ``std`` / ``ci`` of its parameters, held-out SSE with and without it
    (``sse_held_null``, ``sse_held_alt``; None without held-out flights), ``accepted``."""

    candidate: object
    fit: FitState
    LR: float
    p_value: float
    share: float
    phi: np.ndarray
    std: np.ndarray
    ci: np.ndarray
    sse_held_null: float | None
    sse_held_alt: float | None
    accepted: bool
    reason: str
    train_fit: FitState | None = None


def parameter_cov(problem: Problem, state: FitState) -> np.ndarray:
    """Covariance of the free phi of a fit: the phi block of the inverse Gauss-Newton
    matrix over (Theta, phi_free)."""
    nt = problem.n_theta
    sel = np.concatenate([np.arange(nt), nt + state.free])
    if len(sel) <= DENSE_MAX:
        Hs = state.H.dense()[np.ix_(sel, sel)]
        d = np.sqrt(np.maximum(np.diag(Hs), 1e-300))
        inv = np.linalg.pinv(Hs / np.outer(d, d)) / np.outer(d, d)
        return inv[nt:, nt:]
    S = state.H.schur(state.free)  # every theta marginalised out, in the block structure
    d = np.sqrt(np.maximum(np.diag(S), 1e-300))
    return np.linalg.pinv(S / np.outer(d, d)) / np.outer(d, d)


def confirm(problem: Problem, null: FitState, candidate, phi1: np.ndarray, weights,
            p_crit: float, accepted: np.ndarray, masks=None, null_train=None,
            excess: float | None = None, excess_sd: float = 0.0) -> Confirmation:
    """Refit with ``candidate`` added to the ``accepted`` parameters; ``masks`` from
    :func:`holdout_masks`; ``null_train`` a callable returning the null fit on the training
    flights (computed here when not given); ``excess`` the null fit's chi-square excess and
    ``excess_sd`` its null standard deviation."""
    free = np.concatenate([accepted, candidate.index]).astype(int)
    phi0 = null.phi.copy()
    phi0[candidate.index] = np.clip(phi1, candidate.lower, candidate.upper)
    alt = fit(problem, null.Theta, phi0, free, xs=null.lin.x)
    LR = max(2.0 * (null.L - alt.L), 0.0)
    p = float(chibar_pvalue(np.array([LR]), weights)[0])
    cov = parameter_cov(problem, alt)
    pos = [list(free).index(i) for i in candidate.index]
    std = np.sqrt(np.clip(np.diag(cov)[pos], 0, None))
    ph = alt.phi[candidate.index]
    ci = np.column_stack([np.maximum(ph - 1.96 * std, candidate.lower),
                          np.minimum(ph + 1.96 * std, candidate.upper)])
    share = 1.0 if excess is None else LR / max(excess, LR, 1e-300)
    if excess is not None and excess - LR <= REMAINDER_Z * excess_sd:
        share_ok = True  # what it leaves unexplained is within the noise of the excess
    else:
        share_ok = share >= MIN_SHARE
    s_null = s_alt = None
    ok_held = True
    outside = candidate.outside_valid(ph)
    if masks is not None and p <= p_crit and share_ok and not outside:
        train, held = masks
        nt_fit = (null_train() if null_train is not None else
                  fit(problem, null.Theta, null.phi, accepted, masks=train, xs=null.lin.x,
                      lin=null.lin))
        alt_train = fit(problem, alt.Theta, alt.phi, free, masks=train, xs=alt.lin.x,
                        lin=alt.lin)
        s_null = (problem.masked(null.lin, held).sse if accepted.size == 0 else
                  held_out_sse(problem, null, nt_fit.phi, held))
        s_alt = held_out_sse(problem, alt, alt_train.phi, held)
        ok_held = s_alt < s_null
    if p > p_crit:
        reason = f"likelihood ratio {LR:.3g}: p = {p:.3g} above the family-wise {p_crit:.3g}"
    elif outside:
        reason = ("estimate outside the effect's valid range: " + ", ".join(
            f"{q} = {v:.4g}" for q, v in zip(candidate.params, ph, strict=True)
            if q in outside))
    elif not share_ok:
        reason = (f"explains {100 * share:.0f} % of the residual's chi-square excess (below "
                  f"{100 * MIN_SHARE:.0f} %): a corner of something else")
    elif not ok_held:
        reason = (f"held-out flights: residual SSE {s_alt:.6g} with it vs {s_null:.6g} without"
                  " (no better)")
    else:
        reason = "significant likelihood ratio" + (", better on held-out flights"
                                                   if masks is not None else
                                                   " (no held-out flights: fewer than three "
                                                   "cycles per unit)")
    return Confirmation(candidate, alt, LR, p, share, ph, std, ci, s_null, s_alt,
                        p <= p_crit and share_ok and ok_held and not outside, reason,
                        alt_train if masks is not None and s_alt is not None else None)
