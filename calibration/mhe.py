"""Windowed MAP / moving-horizon estimation (MHE) of the health parameters, with IPOPT.

Model (paper eq. 5-6, with the steady state as equality constraints)::

    theta(t) = theta(t-1) + xi,   xi ~ N(0, q^2 dtau)         random walk, q per sqrt(hour)
    y(t)     = h(x(t), w(t), theta(t)) + eps,  eps ~ N(0, R(t))  R from the sensor-noise table
    0        = r(x(t), w(t), theta(t))                          steady state, 7 unknowns x

``dtau`` is recorded operating time: the time between consecutive samples of the same flight
(``t`` column), one sample period across a flight boundary.

Windows of ``window`` samples slide along a unit's series by ``stride`` samples (default: the
window length, i.e. non-overlapping windows). In each window :class:`mhe_nlp.WindowNLP` solves
the MAP problem: theta for the window (``mode="constant"``) or one theta per sample
(``mode="random_walk"``, the drift prior between samples), plus the seven unknowns at every
sample, the steady-state residuals as equality constraints, bounds on theta, and the
**arrival cost** ``1/2 |C (theta_first - mu)|^2``.

Arrival cost. After a window is solved, the samples that leave it (the first ``stride``) are
folded into the arrival cost by one Gauss-Newton information update linearised at the window's
solution, with exact sensitivities ``S_k = de_k/dtheta`` (implicit function theorem on the
residual system, :func:`mhe_nlp.reduced_sensitivity`)::

    I    = C^T C + sum_k S_k^T S_k                      (Fisher information + propagated prior)
    mu'  = theta_hat - I^-1 (C^T C (theta_hat - mu) + sum_k S_k^T e_k)
    P'   = I^-1 + q^2 dtau                                 inflated by the drift over the gap
    C'   = chol(P'^-1)

In random-walk mode the same update runs sample by sample (a linearised information filter
through the leaving samples, inflating by ``q^2 dtau`` between them). With non-overlapping
windows this is the exact filtering arrival cost of a linear-Gaussian problem: ``mu'`` is the
window's estimate at its last sample and ``I`` its posterior information. The first window's
arrival cost is the setup's prior ``N(prior_mean, prior_std^2)``.

Per-sample outputs. Sample ``k`` gets the estimate of the window that starts at the window
start ``s`` with ``s <= k < s + stride`` (the last window: all its remaining samples); in
constant mode that is the window's theta, in random-walk mode the window's ``theta_k`` (a
fixed-interval smoothed value within the window). Its covariance is the inverse of the window's
Fisher information with the arrival cost (and the drift prior in random-walk mode), i.e. the
inverse of the Gauss-Newton reduced Hessian; ``x_hat`` are the model's outputs at the window's
solution ``(x_k, theta_k)``.

Observability: :func:`base.check_observability` (Fisher-information rank over the unit at the
prior mean, the setup's policy): an unobservable parameter is held at its prior mean, reported
as NaN and listed in ``diagnostics["unobservable"]``; only the observable ones become decision
variables. ``diagnostics["window_data_rank"]`` is the rank of each window's data-only Fisher
information (a window flown at one operating point may see less than the unit; the arrival
cost then carries the rest).

Default window: 60 samples (10 min at 0.1 Hz), non-overlapping, constant theta. Measured on
this project's 2-core machine: the ds02 fleet at 0.1 Hz (749,561 samples) in 241 s on two
worker processes, 3,107 samples/s, with the Gauss-Newton Hessian
(``benchmarks/calibration.py``; table in the README).

``map_cycle`` is the simple reference: one constant theta per flight cycle from all that cycle's
samples, with the same NLP, the prior only as regularisation (no arrival cost between cycles).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from engine_model.channels import XS_NAMES
from engine_model.validation import InputError

from .base import (
    CalibrationResult,
    CalibrationSetup,
    Estimator,
    UnitSeries,
    check_observability,
    make_result,
    prepare_unit,
    timed,
)
from .mhe_nlp import HESSIANS, MODES, N_TH, N_Y, StageKernels, WindowNLP, reduced_sensitivity

_PAD = 16  # a window's length is padded up to a multiple of this (one NLP per padded length)


@dataclass
class MHEOptions:
    """Settings of the windowed MAP estimator itself (the noise, drift, prior, bounds and
    observability settings are the :class:`base.CalibrationSetup`'s)."""

    window: int = 60  # samples per window [60: 10 min at 0.1 Hz]
    stride: int | None = None  # samples the window moves [None: = window, no overlap]
    mode: str = "constant"  # "constant" theta per window or "random_walk" theta per sample
    hessian: str = "gauss-newton"  # or "exact"
    ipopt_options: dict = field(default_factory=dict)  # override mhe_nlp.IPOPT_DEFAULTS
    compiled: bool = True  # per-sample kernels as compiled C (else CasADi's VM)
    threads: int = 1  # threads of the per-sample map inside one NLP
    arrival_cost: bool = True  # False: every window starts from the prior (for comparison)

    def __post_init__(self):
        if self.mode not in MODES:
            raise InputError(f"mhe mode {self.mode!r}: one of {', '.join(MODES)}")
        if self.hessian not in HESSIANS:
            raise InputError(f"mhe hessian {self.hessian!r}: one of {', '.join(HESSIANS)}")
        stride = self.stride or self.window
        if self.window < 2 or not 1 <= stride <= self.window:
            raise InputError(f"mhe window {self.window}, stride {stride}: need window >= 2 "
                             "and 1 <= stride <= window")


# --------------------------------------------------------------------- caches
_KERNELS: dict = {}


def kernels_for(model, compiled=True) -> StageKernels:
    """The per-sample kernels of ``model`` (built, or loaded from the disk cache, once per
    process)."""
    key = (id(model), compiled)
    if key not in _KERNELS:
        _KERNELS[key] = StageKernels(model, compiled=compiled)
    return _KERNELS[key]


class _NLPCache:
    def __init__(self, kernels, est, mode, hessian, ipopt, threads):
        self.args = (kernels, est, mode, hessian, ipopt, threads)
        self.nlps: dict[int, WindowNLP] = {}

    def get(self, n) -> WindowNLP:
        if n not in self.nlps:
            k, est, mode, hess, ipopt, threads = self.args
            self.nlps[n] = WindowNLP(k, n, est, mode, hess, ipopt, threads)
        return self.nlps[n]


@dataclass
class _Series:
    """A unit in the kernels' layout: all 16 measured channels, ``s = 1/sigma`` (0 where a
    channel is not used), cumulative drift variance per unit q^2."""

    w: np.ndarray
    y: np.ndarray
    s: np.ndarray
    tau_h: np.ndarray
    cycle: np.ndarray | None
    p: np.ndarray | None


def _kernel_series(series: UnitSeries, p) -> _Series:
    n = len(series)
    y = np.zeros((n, N_Y))
    s = np.zeros((n, N_Y))
    for jj, c in enumerate(series.sensors):
        j = XS_NAMES.index(c)
        y[:, j] = series.y[:, jj]
        s[:, j] = 1.0 / series.sigma[:, jj]
    pm = None
    if p is not None:
        pm = np.asarray(p, float)
        pm = np.tile(pm, (n, 1)) if pm.ndim == 1 else pm
    return _Series(w=series.w, y=y, s=s, tau_h=np.cumsum(series.dt_h), cycle=series.cycle,
                   p=pm)


def _full_theta(theta_est, est, theta_base):
    th = np.broadcast_to(np.asarray(theta_base, float),
                         (*np.shape(theta_est)[:-1], N_TH)).copy()
    th[..., est] = theta_est
    return th


def _solve_x(model, w, th_full, p, x_fallback):
    r = model.solve(w, th_full, p, check=False)
    ok = r.converged
    return np.where(ok[:, None], r.x, x_fallback), int((~ok).sum())


def _window_info(kernels, sol_x, th_full_k, ser, sl, est):
    """Reduced sensitivities S (n, 16, nt) and normalised residuals e (n, 16) at a solution."""
    pm = None if ser.p is None else ser.p[sl]
    jr, je = kernels.jacobians(sol_x, th_full_k, ser.w[sl], ser.y[sl], ser.s[sl], pm)
    _, e = kernels.residuals(sol_x, th_full_k, ser.w[sl], ser.y[sl], ser.s[sl], pm)
    return reduced_sensitivity(jr, je, est), e


def _chol_info(cov):
    """C with C^T C = cov^-1."""
    info = np.linalg.inv(0.5 * (cov + cov.T))
    return np.linalg.cholesky(0.5 * (info + info.T)).T


def _pad(a, n):
    if len(a) == n:
        return a
    return np.concatenate([a, np.repeat(a[-1:], n - len(a), axis=0)], axis=0)


def run_windows(model, series: UnitSeries, setup: CalibrationSetup, options: MHEOptions,
                per_cycle: bool = False, p=None) -> CalibrationResult:
    """Windowed MAP / MHE (``per_cycle=False``) or batch MAP per flight cycle
    (``per_cycle=True``) of ``setup.params`` along one checked unit series."""
    o = options
    t_start = time.perf_counter()
    ser = _kernel_series(series, p)
    n = len(ser.w)
    if per_cycle and ser.cycle is None:
        raise InputError("map_cycle: the data have no 'cycle' column")
    theta_base = setup.theta_base()  # fixed values + prior mean of the estimated ones
    kern = kernels_for(model, o.compiled)
    params = setup.params
    k_all = len(params)

    # starting unknowns at the prior mean; observability of the requested parameters
    r0 = model.solve_series(ser.w, np.tile(theta_base, (n, 1)), ser.p)
    x_prior = r0.x
    obs = check_observability(model, series, setup, x=x_prior if r0.converged.all() else None,
                              p=ser.p)
    keep = [params.index(q) for q in obs.observable]
    est = setup.param_index[keep]
    nt = len(est)

    theta_hat = np.tile(setup.prior_mean_vec(), (n, 1))
    theta_cov = np.full((n, k_all, k_all), np.nan)
    x_sol = x_prior.copy()
    th_sol_full = np.tile(theta_base, (n, 1))
    stride = int(o.stride or o.window)
    diag = {"method": "map_cycle" if per_cycle else "mhe",
            "mode": "constant" if per_cycle else o.mode, "hessian": o.hessian,
            "window": None if per_cycle else int(o.window),
            "stride": None if per_cycle else stride,
            "fisher_rank": obs.rank, "fisher_unit": obs.fisher.tolist(),
            "windows": 0, "iterations": [], "status": [], "window_starts": [],
            "window_data_rank": [], "non_converged_windows": 0, "seconds_nlp": 0.0,
            "x_warm_start_failures": int((~r0.converged).sum())}

    mode = "constant" if per_cycle else o.mode
    cache = _NLPCache(kern, est, mode, o.hessian, o.ipopt_options, o.threads)
    lb = np.full(nt, setup.bounds[0])
    ub = np.full(nt, setup.bounds[1])
    prior_mu = setup.prior_mean_vec()[keep]
    prior_cov = np.diag(setup.prior_std_vec()[keep] ** 2)
    C0 = _chol_info(prior_cov) if nt else np.zeros((0, 0))
    mu, C = prior_mu.copy(), C0.copy()
    q2 = setup.drift_std_per_sqrt_h ** 2
    if per_cycle:
        cyc = ser.cycle
        edges = np.flatnonzero(np.diff(cyc, prepend=cyc[0] - 1) != 0).tolist() + [n]
        segments = [(a, b, b) for a, b in zip(edges[:-1], edges[1:], strict=True)]
    else:
        win = int(o.window)
        starts = list(range(0, max(n - win, 0) + 1, stride))
        if starts[-1] + win < n:
            starts.append(starts[-1] + stride)
        segments = []
        for i, a in enumerate(starts):
            b = min(a + win, n)
            segments.append((a, b, b if i == len(starts) - 1 else min(a + stride, n)))
    th_prev = mu.copy()
    for a, b, assign_end in segments if nt else []:
        m_len = b - a
        n_pad = int(np.ceil(m_len / _PAD) * _PAD)
        nlp = cache.get(n_pad)
        sl = slice(a, b)
        p_sl = None if ser.p is None else ser.p[sl]
        s_win = _pad(ser.s[sl], n_pad)
        s_win[m_len:] = 0.0  # padding samples carry no data
        if per_cycle:  # each cycle on its own: the prior, no arrival cost
            mu, C, th_prev = prior_mu, C0, prior_mu
        # warm start: theta of the last window, x by the compiled solve at that theta
        x0, nfail = _solve_x(model, ser.w[sl], _full_theta(th_prev, est, theta_base), p_sl,
                             x_prior[sl])
        diag["x_warm_start_failures"] += nfail
        d = None
        if mode == "random_walk":
            dtau = np.diff(_pad(ser.tau_h[sl], n_pad))
            d = np.tile(1.0 / np.sqrt(np.maximum(q2 * dtau, 1e-30)), (nt, 1))
            d[:, m_len - 1:] = 1e3  # padding samples: tied to the last real one
        pv = nlp.params(_pad(ser.w[sl], n_pad), _pad(ser.y[sl], n_pad), s_win, theta_base, mu,
                        C, d, None if p_sl is None else _pad(p_sl, n_pad))
        sol = nlp.solve(pv, _pad(x0, n_pad), th_prev, lb, ub)
        diag["windows"] += 1
        diag["iterations"].append(sol.iterations)
        diag["status"].append(sol.status)
        diag["window_starts"].append(int(a))
        diag["seconds_nlp"] += sol.seconds
        if not sol.success:
            diag["non_converged_windows"] += 1
        xk, thk = sol.x[:m_len], sol.theta[:m_len]
        th_full_k = _full_theta(thk, est, theta_base)
        S, e = _window_info(kern, xk, th_full_k, ser, sl, est)
        info_k = np.einsum("nki,nkj->nij", S, S)
        diag["window_data_rank"].append(int(np.linalg.matrix_rank(info_k.sum(0))))
        CtC = C.T @ C
        # posterior covariance: inverse of the window's Fisher information with the prior
        if mode == "constant":
            cov_k = np.broadcast_to(np.linalg.inv(CtC + info_k.sum(0)), (m_len, nt, nt))
        else:
            cov_k = _rw_marginals(info_k, CtC, d[:, :m_len - 1] ** 2)
        rows = np.arange(a, assign_end)
        loc = rows - a
        theta_hat[np.ix_(rows, keep)] = thk[loc]
        theta_cov[np.ix_(rows, keep, keep)] = cov_k[loc]
        x_sol[rows] = xk[loc]
        th_sol_full[rows] = th_full_k[loc]
        if per_cycle:
            continue
        # arrival cost of the next window: fold in the samples that leave this one
        n_leave = assign_end - a
        if mode == "constant":
            th_hat = thk[0]
            info = CtC + info_k[:n_leave].sum(0)
            g_d = np.einsum("nki,nk->i", S[:n_leave], e[:n_leave])
            mu_new = th_hat - np.linalg.solve(info, CtC @ (th_hat - mu) + g_d)
            cov_new = np.linalg.inv(info)
            gap = ser.tau_h[min(assign_end, n - 1)] - ser.tau_h[a]
        else:
            m_f, cov_f = mu, np.linalg.inv(CtC)
            for k in range(n_leave):
                if k > 0:
                    cov_f = cov_f + np.eye(nt) * q2 * (ser.tau_h[a + k] - ser.tau_h[a + k - 1])
                p_inv = np.linalg.inv(cov_f)
                info = p_inv + info_k[k]
                m_f = thk[k] - np.linalg.solve(info, p_inv @ (thk[k] - m_f) + S[k].T @ e[k])
                cov_f = np.linalg.inv(info)
            mu_new, cov_new = m_f, cov_f
            gap = ser.tau_h[min(assign_end, n - 1)] - ser.tau_h[assign_end - 1]
        cov_new = cov_new + np.eye(nt) * q2 * max(float(gap), 0.0)
        mu, C = np.clip(mu_new, lb, ub), _chol_info(cov_new)
        if not o.arrival_cost:
            mu, C = prior_mu, C0
        th_prev = thk[n_leave - 1] if mode == "random_walk" else thk[0]

    # outputs at the estimate, normalised residuals of the used sensors
    y_hat = model.outputs_at(x_sol, ser.w, th_sol_full, ser.p)
    from engine_model.channels import OUTPUT_NAMES

    cols = [OUTPUT_NAMES.index(c) for c in series.sensors]
    resid = (series.y - y_hat[:, cols]) / series.sigma
    its = diag["iterations"]
    diag["mean_iterations"] = float(np.mean(its)) if its else 0.0
    diag["n_nonconverged"] = diag["non_converged_windows"]
    diag["observable"] = list(obs.observable)
    timed(diag, t_start, n)
    diag["samples_per_second_nlp"] = n / diag["seconds_nlp"] if diag["seconds_nlp"] else None
    return make_result(series, setup, theta_hat, theta_cov, y_hat, resid, diag,
                       obs.unobservable)


def _rw_marginals(info_k, CtC, dd):
    """Marginal covariances of theta_k (m, nt, nt) from the block-tridiagonal information
    of a random-walk window: data blocks ``info_k``, arrival ``CtC`` on the first sample,
    drift precisions ``dd`` (nt, m - 1) between samples."""
    m, nt = info_k.shape[0], info_k.shape[1]
    big = np.zeros((m * nt, m * nt))
    for k in range(m):
        big[k * nt:(k + 1) * nt, k * nt:(k + 1) * nt] += info_k[k]
    big[:nt, :nt] += CtC
    for k in range(m - 1):
        i0, i1 = k * nt, (k + 1) * nt
        dk = np.diag(dd[:, k])
        big[i0:i1, i0:i1] += dk
        big[i1:i1 + nt, i1:i1 + nt] += dk
        big[i0:i1, i1:i1 + nt] -= dk
        big[i1:i1 + nt, i0:i1] -= dk
    cov = np.linalg.inv(big)
    return np.stack([cov[k * nt:(k + 1) * nt, k * nt:(k + 1) * nt] for k in range(m)])


class MHEEstimator(Estimator):
    """Windowed MAP / moving-horizon estimation with IPOPT (module docstring).

    ``MHEEstimator(model=None, window=60, stride=None, mode="constant",
    hessian="gauss-newton", ipopt_options=None, compiled=True, threads=1,
    arrival_cost=True)`` (:class:`MHEOptions`).
    """

    name = "mhe"
    per_cycle = False

    def __init__(self, model=None, **options):
        super().__init__(model)
        self.options = MHEOptions(**options)

    def estimate(self, df_unit: pd.DataFrame, setup: CalibrationSetup | None = None,
                 source=None, p=None) -> CalibrationResult:
        setup = setup or CalibrationSetup()
        series = prepare_unit(df_unit, setup, source)
        return run_windows(self.model, series, setup, self.options, self.per_cycle, p)


class MAPCycleEstimator(MHEEstimator):
    """Batch MAP per flight cycle: one constant theta per ``cycle`` from all that cycle's
    samples, with the same NLP, the setup's prior as the only regularisation."""

    name = "map_cycle"
    per_cycle = True
