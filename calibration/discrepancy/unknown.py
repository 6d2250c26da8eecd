"""Structure no candidate explains: tests on the final residual and a hint of what it
follows.

On the whitened residual ``e`` of the final fit (per channel; under a right model white,
zero-mean, unit variance and unrelated to the operating point):

- **dependence on the operating variables**: least squares of ``e_j`` on the documented basis
  :data:`BASIS_NAMES` (standardised), F-test against the intercept-only model;
- **bias**: the channel mean, t-test;
- **whiteness**: lag-1 autocorrelation within flights, ``z = r1 sqrt(n)``;
- **size**, only on channels whose noise level the noise check could not estimate (no two
  successive samples within a flight, e.g. a table of operating points, where it is the only
  test with power): ``sum e_j^2`` against chi-square with ``n (1 - n_fitted / (n m))``
  degrees of freedom. Where the noise check did estimate it (:mod:`.noise_check`), the
  documented level is accepted within its tolerance (10 % in std), so a white residual 5 %
  above the documented std is "the noise", not structure; testing its size against the
  documented level would contradict that (on 100 no-effect ``tiny`` fleets it called one of
  them an unknown effect: P21's white residual at 1.049 noise std, von Neumann's estimate the
  same), and any model error that is smooth within a flight, the only kind the size would
  see there, raises the lag-1 autocorrelation, which is tested;

each at ``alpha / n_tests`` (Bonferroni over channels and the tests run on them). A channel that
fails any carries structure. The hint is a sparse regression of its residual on the basis: forward
stepwise selection (up to :data:`MAX_TERMS` terms, each kept only if it lowers the BIC by more than
10, "very strong" evidence on Kass & Raftery's scale), reported as the terms it follows with their
coefficients (noise units per basis standard deviation) and the share of the residual's variance
they explain. The basis:

=================  ==========================================================
term               meaning
=================  ==========================================================
alt, Mach, TRA, T2 the operating point (alt in 10,000 ft, T2 in 100 degR)
alt^2, Mach^2,     curvature in each
TRA^2, T2^2
alt*Mach,          the usual interactions (Reynolds index ~ altitude and Mach,
alt*TRA, Mach*TRA  power setting at altitude)
dalt/dt, dTRA/dt   rates (ft/s, %/s) within a flight: transients
t_flight           time since the flight's first sample [h]: heat soak, drift
                   within a flight
cycle              the flight cycle: a trend with use
=================  ==========================================================
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2, norm
from scipy.stats import f as f_dist
from scipy.stats import t as t_dist

MAX_TERMS = 3
BASIS_NAMES = ("alt", "Mach", "TRA", "T2", "alt^2", "Mach^2", "TRA^2", "T2^2", "alt*Mach",
               "alt*TRA", "Mach*TRA", "dalt/dt", "dTRA/dt", "t_flight", "cycle")


def basis(w: np.ndarray, t: np.ndarray | None, flight: np.ndarray, cycle) -> np.ndarray:
    """The (N, len(BASIS_NAMES)) basis of the module docstring (not standardised)."""
    alt, mach, tra, t2 = w[:, 0] / 1e4, w[:, 1], w[:, 2], w[:, 3] / 100.0
    n = len(w)
    tt = np.arange(n, dtype=float) * 10.0 if t is None else np.asarray(t, float)
    new = np.r_[True, flight[1:] != flight[:-1]]
    dt = np.diff(tt, prepend=tt[0])
    dt = np.where(new | (dt <= 0), np.nan, dt)
    d_alt = np.nan_to_num(np.diff(w[:, 0], prepend=w[0, 0]) / dt)
    d_tra = np.nan_to_num(np.diff(w[:, 2], prepend=w[0, 2]) / dt)
    start = np.maximum.accumulate(np.where(new, np.arange(n), 0))
    t_flight = (tt - tt[start]) / 3600.0
    cyc = np.zeros(n) if cycle is None else np.asarray(cycle, float)
    return np.column_stack([alt, mach, tra, t2, alt ** 2, mach ** 2, tra ** 2, t2 ** 2,
                            alt * mach, alt * tra, mach * tra, d_alt, d_tra, t_flight, cyc])


def _standardise(X):
    mu, sd = X.mean(axis=0), X.std(axis=0)
    keep = sd > 1e-12 * np.maximum(1.0, np.abs(mu))
    return (X[:, keep] - mu[keep]) / sd[keep], np.flatnonzero(keep)


def forward_select(X: np.ndarray, y: np.ndarray, names, max_terms: int = MAX_TERMS) -> dict:
    """Forward stepwise least squares with a BIC stop; ``X`` standardised, intercept added."""
    n = len(y)
    chosen: list[int] = []
    resid = y - y.mean()
    sst = float(resid @ resid)
    sse = sst
    bic = n * np.log(sse / n)
    coef = np.zeros(0)
    for _ in range(max_terms):
        best = None
        for j in range(X.shape[1]):
            if j in chosen:
                continue
            A = np.column_stack([np.ones(n), X[:, chosen + [j]]])
            c, *_ = np.linalg.lstsq(A, y, rcond=None)
            r = y - A @ c
            s = float(r @ r)
            if best is None or s < best[1]:
                best = (j, s, c)
        if best is None:
            break
        new_bic = n * np.log(best[1] / n) + (len(chosen) + 2) * np.log(n)
        if new_bic >= bic - 10.0:  # a clear improvement only (BIC difference > 10)
            break
        chosen.append(best[0])
        sse, bic, coef = best[1], new_bic, best[2][1:]
    return {"terms": [names[j] for j in chosen],
            "coefficients": [float(c) for c in coef],
            "explained": float(1.0 - sse / sst) if sst > 0 else 0.0}


def structure(residuals: list, units: list, sensors, alpha: float = 0.01,
              n_fitted: int = 0, noise_checked=None) -> dict:
    """Per-channel tests and, for channels with structure, the hint (module docstring).
    ``noise_checked``: per channel, whether the noise check estimated its level (then no size
    test; default: none was)."""
    e = np.concatenate([r[ok] for r, ok in zip(residuals, (u[1] for u in units),
                                               strict=True)])
    Xs, flights = [], []
    for (ud, ok) in units:
        s = ud.series
        t = ud.frame["t"].to_numpy(float) if "t" in ud.frame.columns else None
        fl = ud.cyc
        Xs.append(basis(s.w, t, fl, ud.cycle)[ok])
        flights.append(np.asarray(fl)[ok] + 1_000_000 * len(flights))
    X, keep = _standardise(np.vstack(Xs))
    names = [BASIS_NAMES[j] for j in keep]
    flight = np.concatenate(flights)
    n, m = e.shape
    checked = np.zeros(m, bool) if noise_checked is None else np.asarray(noise_checked, bool)
    level = alpha / (3 * m + int(np.sum(~checked)))
    dof = max(n * (1.0 - n_fitted / max(n * m, 1)), 1.0)
    same = flight[1:] == flight[:-1]
    A = np.column_stack([np.ones(n), X])
    out = {"channels": {}, "alpha": alpha, "structure": [], "hint": {}}
    for j, ch in enumerate(sensors):
        y = e[:, j]
        mean = float(y.mean())
        sd = float(y.std(ddof=1)) if n > 1 else 0.0
        p_bias = float(2 * t_dist.sf(abs(mean) / max(sd / np.sqrt(n), 1e-300), n - 1))
        c, *_ = np.linalg.lstsq(A, y, rcond=None)
        r = y - A @ c
        sse1, sse0 = float(r @ r), float(((y - mean) ** 2).sum())
        p_f = 1.0
        df1, df2 = X.shape[1], n - X.shape[1] - 1
        if df1 > 0 and df2 > 0 and sse1 > 0:
            F = ((sse0 - sse1) / df1) / (sse1 / df2)
            p_f = float(f_dist.sf(F, df1, df2))
        yc = y - mean
        r1 = float(np.sum(yc[1:][same] * yc[:-1][same]) / max(float(yc @ yc), 1e-300))
        z1 = r1 * np.sqrt(max(int(same.sum()), 1))
        p_w = float(2 * norm.sf(abs(z1)))
        p_size = None if checked[j] else float(chi2.sf(float(y @ y), dof))
        flagged = min(p_bias, p_f, p_w, 1.0 if p_size is None else p_size) <= level
        out["channels"][ch] = {"rmse": float(np.sqrt(np.mean(y * y))), "bias": mean,
                               "p_bias": p_bias, "p_operating": p_f, "lag1": r1,
                               "p_white": p_w, "p_chi2": p_size,
                               "structure": bool(flagged)}
        if flagged:
            out["structure"].append(ch)
            out["hint"][ch] = {"rmse": out["channels"][ch]["rmse"],
                               **forward_select(X, y, names)}
    # the channels with structure, the most disturbed first
    out["structure"].sort(key=lambda c: -out["channels"][c]["rmse"])
    return out
