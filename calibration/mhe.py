"""Windowed MAP / moving-horizon estimation (MHE) of the health parameters, with IPOPT.

Model (paper eq. 5-6, with the steady state as equality constraints)::

    theta(t) = theta(t-1) + xi,   xi ~ N(0, q^2 dtau)         random walk, q per sqrt(hour)
    y(t)     = h(x(t), w(t), theta(t)) + eps,  eps ~ N(0, R(t))  R from the sensor-noise table
    0        = r(x(t), w(t), theta(t))                          steady state, 7 unknowns x

``dtau`` follows the setup's drift model (``setup.drift_per``, :mod:`calibration.estimation_setup`)
in constant mode: per cycle (the default with a ``cycle`` column: theta constant within a flight,
the flight's wear entering at the next cycle's first sample) or per recorded operating time.
The random-walk mode, one theta per sample, always walks in operating time: the time between
consecutive samples of the same flight (``t`` column), one sample period across a flight
boundary.

Windows of ``window`` samples slide along a unit's series by ``stride`` samples (default: the
window length, i.e. non-overlapping windows). A constant-theta window must not hold a step of
the drift model, so with the drift per cycle the windows restart at every cycle's first
sample: each cycle is cut into windows on its own (its last window may be shorter). Without
this a window that straddles a flight boundary fits one theta to two flights' values and
reports each sample a std that ignores the step: with the information of the present engine
(the fan speed free at flight idle, where the minimum-N2 limiter holds the core) one flight
pins theta to ~4e-4, below a flight's wear in the tests' unit (7e-4 of HPT efficiency), and
the 95 % interval held the truth on only 72 % of the samples. In each window
:class:`mhe_nlp.WindowNLP` solves
the MAP problem: theta for the window (``mode="constant"``) or one theta per sample
(``mode="random_walk"``, the drift prior between samples), plus the eight unknowns at every
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

A window whose NLP did not converge (IPOPT's status neither solved nor acceptable) is no
evidence: its samples keep its solution and count in ``diagnostics["n_nonconverged"]``, but
they are not folded in; the arrival cost passes over the window with the drift inflation
alone (``P' = P + q^2 dtau``), and the next window is warm-started from the last converged one.

In random-walk mode the same update runs sample by sample (a linearised information filter
through the leaving samples, inflating by ``q^2 dtau`` between them). With non-overlapping
windows that hold no drift step this is the exact filtering arrival cost of a linear-Gaussian
problem: ``mu'`` is the window's estimate at its last sample and ``I`` its posterior
information (the reported std then equals the windowed Cramér-Rao bound at the truth with the
arrival information carried forward, :func:`crb.windowed_crb`: within 0.4 % on the tests'
unit). The first window's arrival cost is the setup's prior ``N(prior_mean, prior_std^2)``.

Per-sample outputs. Sample ``k`` gets the estimate of the window that starts at the window
start ``s`` with ``s <= k < s + stride`` (the last window of the series or of a cycle: all
its remaining samples; ``diagnostics["window_starts"]`` and ``["window_ends"]``); in
constant mode that is the window's theta, in random-walk mode the window's ``theta_k`` (a
fixed-interval smoothed value within the window). Its covariance is the inverse of the window's
Fisher information with the arrival cost (and the drift prior in random-walk mode), i.e. the
inverse of the Gauss-Newton reduced Hessian; ``x_hat`` are the model's outputs at the window's
solution ``(x_k, theta_k)``.

Observability: :func:`observability.check_observability` (Fisher-information rank over the unit at
the prior mean, the setup's policy): an unobservable parameter is held at its prior mean, reported
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
from engine_model.solver.batch_eval import pad_rows
from engine_model.solver.interface import SymbolicSteadyStateModel
from engine_model.validation import InputError

from .base import Estimator, timed
from .estimation_setup import CalibrationSetup
from .mhe_nlp import HESSIANS, MODES, N_Y, StageKernels, WindowNLP, reduced_sensitivity
from .observability import check_observability
from .result import CalibrationResult, make_result
from .series import UnitSeries, prepare_unit

_PAD = 16  # a window's length is padded up to a multiple of this (one NLP per padded length)


@dataclass
class MHEOptions:
    """Settings of the windowed MAP estimator itself (the noise, drift, prior, bounds and
    observability settings are the :class:`estimation_setup.CalibrationSetup`'s)."""

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
        stride = self.window if self.stride is None else self.stride
        if self.window < 2 or not 1 <= stride <= self.window:
            raise InputError(f"mhe window {self.window}, stride {stride}: need window >= 2 "
                             "and 1 <= stride <= window")


# --------------------------------------------------------------------- caches
_KERNELS: dict = {}


def kernels_for(model, compiled=True) -> StageKernels:
    """The per-sample kernels of ``model`` (built, or loaded from the disk cache, once per
    process). The cache holds the model with its kernels: an ``id`` is unique only among
    live objects, and a model freed and another built at its address would otherwise be
    served the first one's kernels."""
    key = (id(model), compiled)
    if key not in _KERNELS:
        _KERNELS[key] = (model, StageKernels(model, compiled=compiled))
    return _KERNELS[key][1]


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
    channel is not used); cumulative operating time ``tau_h`` (the random-walk mode's steps)
    and cumulative drift time ``drift_h`` of the setup's drift model (``setup.drift_per``:
    per cycle, all of a flight's wear at the next cycle's first sample, or per time), both
    per unit q^2 [h]."""

    w: np.ndarray
    y: np.ndarray
    s: np.ndarray
    tau_h: np.ndarray
    drift_h: np.ndarray
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
    return _Series(w=series.w, y=y, s=s, tau_h=np.cumsum(series.dt_h),
                   drift_h=np.cumsum(series.dtau_h), cycle=series.cycle, p=pm)


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


@dataclass(frozen=True)
class Segment:
    """Samples ``start:stop`` form one window (or cycle); its estimates are assigned to the
    samples ``start:assign_end`` (the ones that leave before the next window starts)."""

    start: int
    stop: int
    assign_end: int


def _cycle_starts(cycle: np.ndarray) -> list[int]:
    return np.flatnonzero(np.diff(cycle, prepend=cycle[0] - 1) != 0).tolist()


def segments(n: int, window: int, stride: int, cycle: np.ndarray | None = None,
             per_cycle: bool = False) -> list[Segment]:
    """The windows of a series of ``n`` samples, ``stride`` apart (the last one may be
    shorter and gets all its samples). With ``cycle`` the windows restart at every cycle's
    first sample, so that no window holds a cycle boundary (each cycle is cut the same way
    on its own); with ``per_cycle`` there is one segment per flight cycle."""
    edges = ([*_cycle_starts(cycle), n] if cycle is not None else [0, n])
    if per_cycle:
        return [Segment(a, b, b) for a, b in zip(edges[:-1], edges[1:], strict=True)]
    out = []
    for p0, p1 in zip(edges[:-1], edges[1:], strict=True):
        m = p1 - p0
        starts = list(range(0, max(m - window, 0) + 1, stride))
        if starts[-1] + window < m:
            starts.append(starts[-1] + stride)
        for i, a in enumerate(starts):
            b = min(a + window, m)
            end = b if i == len(starts) - 1 else min(a + stride, m)
            out.append(Segment(p0 + a, p0 + b, p0 + end))
    return out


@dataclass
class ArrivalCost:
    """``1/2 |C (theta_first - mu)|^2``: what the samples before a window say about it."""

    mu: np.ndarray
    C: np.ndarray

    @classmethod
    def prior(cls, mean: np.ndarray, std: np.ndarray) -> ArrivalCost:
        C = _chol_info(np.diag(std ** 2)) if len(mean) else np.zeros((0, 0))
        return cls(mean.copy(), C)

    @property
    def information(self) -> np.ndarray:
        return self.C.T @ self.C

    def inflated(self, drift_var: float) -> ArrivalCost:
        """The same arrival cost a drift variance later, with no data in between (the
        prediction step alone: what a window that failed to converge passes on)."""
        cov = np.linalg.inv(self.information) + np.eye(len(self.mu)) * drift_var
        return ArrivalCost(self.mu.copy(), _chol_info(cov))

    def fold_constant(self, theta: np.ndarray, S: np.ndarray, e: np.ndarray, drift_var: float
                      ) -> ArrivalCost:
        """Fold leaving samples (sensitivities ``S`` (n, 16, nt), residuals ``e`` (n, 16)) of a
        constant-theta window solved at ``theta`` into the next arrival cost (module
        docstring), inflated by the drift variance over the gap."""
        CtC = self.information
        info = CtC + np.einsum("nki,nkj->ij", S, S)
        g_d = np.einsum("nki,nk->i", S, e)
        mu = theta - np.linalg.solve(info, CtC @ (theta - self.mu) + g_d)
        cov = np.linalg.inv(info) + np.eye(len(mu)) * drift_var
        return ArrivalCost(mu, _chol_info(cov))

    def fold_random_walk(self, theta: np.ndarray, S: np.ndarray, e: np.ndarray,
                         step_var: np.ndarray, drift_var: float) -> ArrivalCost:
        """The same for a random-walk window: a linearised information filter through the
        leaving samples (``theta`` (n, nt), ``step_var`` (n - 1,) drift variances between
        them), then the drift over the gap."""
        nt = len(self.mu)
        m_f, cov_f = self.mu, np.linalg.inv(self.information)
        for k in range(len(theta)):
            if k > 0:
                cov_f = cov_f + np.eye(nt) * step_var[k - 1]
            p_inv = np.linalg.inv(cov_f)
            info = p_inv + S[k].T @ S[k]
            m_f = theta[k] - np.linalg.solve(info, p_inv @ (theta[k] - m_f) + S[k].T @ e[k])
            cov_f = np.linalg.inv(info)
        return ArrivalCost(m_f, _chol_info(cov_f + np.eye(nt) * drift_var))


def _new_diagnostics(per_cycle: bool, o: MHEOptions, mode: str, obs, n_fail: int) -> dict:
    return {"method": "map_cycle" if per_cycle else "mhe",
            "mode": mode, "hessian": o.hessian,
            "window": None if per_cycle else int(o.window),
            "stride": None if per_cycle else int(o.stride or o.window),
            "fisher_rank": obs.rank, "fisher_unit": obs.fisher.tolist(),
            "windows": 0, "iterations": [], "status": [], "window_starts": [],
            "window_ends": [],
            "window_data_rank": [], "non_converged_windows": 0, "n_nonconverged": 0,
            "seconds_nlp": 0.0,
            "x_warm_start_failures": n_fail}


def _record_window(diag: dict, seg: Segment, sol, info_k: np.ndarray) -> None:
    diag["windows"] += 1
    diag["iterations"].append(sol.iterations)
    diag["status"].append(sol.status)
    diag["window_starts"].append(int(seg.start))
    diag["window_ends"].append(int(seg.assign_end))
    diag["seconds_nlp"] += sol.seconds
    diag["window_data_rank"].append(int(np.linalg.matrix_rank(info_k.sum(0))))
    if not sol.success:  # its samples (those it assigns) count as not converged
        diag["non_converged_windows"] += 1
        diag["n_nonconverged"] += int(seg.assign_end - seg.start)


def _window_covariance(mode: str, info_k: np.ndarray, CtC: np.ndarray, d) -> np.ndarray:
    """Posterior covariance of each sample's theta (m, nt, nt): the inverse of the window's
    Fisher information with the arrival cost (and the drift prior in random-walk mode)."""
    m_len, nt = info_k.shape[0], info_k.shape[1]
    if mode == "constant":
        return np.broadcast_to(np.linalg.inv(CtC + info_k.sum(0)), (m_len, nt, nt))
    return _rw_marginals(info_k, CtC, d[:, :m_len - 1] ** 2)


def run_windows(model: SymbolicSteadyStateModel, series: UnitSeries, setup: CalibrationSetup,
                options: MHEOptions, per_cycle: bool = False, p=None,
                warn_unobservable: bool = True) -> CalibrationResult:
    """Windowed MAP / MHE (``per_cycle=False``) or batch MAP per flight cycle
    (``per_cycle=True``) of ``setup.params`` along one checked unit series: the starting
    unknowns and observability at the prior mean, then per segment a warm-started NLP, its
    covariance and the arrival cost of the next (module docstring)."""
    o = options
    if not per_cycle and o.mode == "random_walk" and not setup.drift > 0:
        raise InputError("mhe random_walk: the drift must be > 0 (theta walks by it between "
                         "samples; with none, use mode 'constant')")
    t_start = time.perf_counter()
    ser = _kernel_series(series, p)
    n = len(ser.w)
    if per_cycle and ser.cycle is None:
        raise InputError("map_cycle: the data have no 'cycle' column")
    theta_base = setup.theta_base()  # fixed values + prior mean of the estimated ones
    kern = kernels_for(model, o.compiled)
    mode = "constant" if per_cycle else o.mode

    # starting unknowns at the prior mean; observability of the requested parameters
    r0 = model.solve_series(ser.w, np.tile(theta_base, (n, 1)), ser.p)
    x_prior = r0.x
    obs = check_observability(model, series, setup, x=x_prior if r0.converged.all() else None,
                              p=ser.p, warn=warn_unobservable)
    keep = [setup.params.index(q) for q in obs.observable]
    est = setup.param_index[keep]
    nt = len(est)

    theta_hat = np.tile(setup.prior_mean_vec(), (n, 1))
    theta_cov = np.full((n, setup.k, setup.k), np.nan)
    x_sol = x_prior.copy()
    th_sol_full = np.tile(theta_base, (n, 1))
    diag = _new_diagnostics(per_cycle, o, mode, obs, int((~r0.converged).sum()))
    cache = _NLPCache(kern, est, mode, o.hessian, o.ipopt_options, o.threads)
    lb = np.full(nt, setup.bounds[0])
    ub = np.full(nt, setup.bounds[1])
    prior = ArrivalCost.prior(setup.prior_mean_vec()[keep], setup.prior_std_vec()[keep])
    arrival = prior
    q2 = setup.drift ** 2
    th_prev = prior.mu.copy()
    # a constant-theta window must not hold a step of the drift model: with the drift per
    # cycle the windows restart at every cycle's first sample
    cut = per_cycle or (mode == "constant" and _drift_per_cycle(setup, series))
    segs = segments(n, int(o.window), int(o.stride or o.window), ser.cycle if cut else None,
                    per_cycle) if nt else []
    for seg in segs:
        a, b = seg.start, seg.stop
        m_len = b - a
        n_pad = int(np.ceil(m_len / _PAD) * _PAD)
        sl = slice(a, b)
        p_sl = None if ser.p is None else ser.p[sl]
        s_win = pad_rows(ser.s[sl], n_pad)
        s_win[m_len:] = 0.0  # padding samples carry no data
        if per_cycle:  # each cycle on its own: the prior, no arrival cost
            arrival, th_prev = prior, prior.mu
        # warm start: theta of the last window, x by the compiled solve at that theta
        x0, nfail = _solve_x(model, ser.w[sl], setup.full_theta(th_prev, est), p_sl,
                             x_prior[sl])
        diag["x_warm_start_failures"] += nfail
        d = None
        if mode == "random_walk":
            dtau = np.diff(pad_rows(ser.tau_h[sl], n_pad))
            d = np.tile(1.0 / np.sqrt(np.maximum(q2 * dtau, 1e-30)), (nt, 1))
            d[:, m_len - 1:] = 1e3  # padding samples: tied to the last real one
        nlp = cache.get(n_pad)
        pv = nlp.params(pad_rows(ser.w[sl], n_pad), pad_rows(ser.y[sl], n_pad), s_win, theta_base,
                        arrival.mu, arrival.C, d, None if p_sl is None else pad_rows(p_sl, n_pad))
        sol = nlp.solve(pv, pad_rows(x0, n_pad), th_prev, lb, ub)
        xk, thk = sol.x[:m_len], sol.theta[:m_len]
        th_full_k = setup.full_theta(thk, est)
        S, e = _window_info(kern, xk, th_full_k, ser, sl, est)
        info_k = np.einsum("nki,nkj->nij", S, S)
        _record_window(diag, seg, sol, info_k)
        cov_k = _window_covariance(mode, info_k, arrival.information, d)
        rows = np.arange(a, seg.assign_end)
        loc = rows - a
        theta_hat[np.ix_(rows, keep)] = thk[loc]
        theta_cov[np.ix_(rows, keep, keep)] = cov_k[loc]
        x_sol[rows] = xk[loc]
        th_sol_full[rows] = th_full_k[loc]
        if per_cycle:
            continue
        # arrival cost of the next window: fold in the samples that leave this one
        n_leave = seg.assign_end - a
        i_next = min(seg.assign_end, n - 1)
        if not sol.success:  # its solution is no evidence: carry the arrival cost over it
            span = ser.drift_h if mode == "constant" else ser.tau_h
            arrival = arrival.inflated(q2 * max(float(span[i_next] - span[a]), 0.0))
            if not o.arrival_cost:
                arrival = prior
            continue
        if mode == "constant":  # the setup's drift from this window's start to the next's
            arrival = arrival.fold_constant(
                thk[0], S[:n_leave], e[:n_leave],
                q2 * max(float(ser.drift_h[i_next] - ser.drift_h[a]), 0.0))
        else:
            steps = q2 * np.diff(ser.tau_h[a:a + n_leave])
            arrival = arrival.fold_random_walk(
                thk[:n_leave], S[:n_leave], e[:n_leave], steps,
                q2 * max(float(ser.tau_h[i_next] - ser.tau_h[seg.assign_end - 1]), 0.0))
        arrival = ArrivalCost(np.clip(arrival.mu, lb, ub), arrival.C)
        if not o.arrival_cost:
            arrival = prior
        th_prev = thk[n_leave - 1] if mode == "random_walk" else thk[0]

    # outputs at the estimate, normalised residuals of the used sensors
    y_hat = model.outputs_at(x_sol, ser.w, th_sol_full, ser.p)
    cols = [model.output_names.index(c) for c in series.sensors]
    resid = (series.y - y_hat[:, cols]) / series.sigma
    its = diag["iterations"]
    diag["mean_iterations"] = float(np.mean(its)) if its else 0.0
    diag["observable"] = list(obs.observable)
    timed(diag, t_start, n)
    diag["samples_per_second_nlp"] = n / diag["seconds_nlp"] if diag["seconds_nlp"] else None
    return make_result(series, setup, theta_hat, theta_cov, y_hat, resid, diag,
                       obs.unobservable)


def _drift_per_cycle(setup: CalibrationSetup, series: UnitSeries) -> bool:
    """Whether the setup's drift enters per cycle (``drift_per``, "auto" with a cycle column;
    :func:`series.prepare_unit` has refused "cycle" without one)."""
    return series.cycle is not None and setup.drift_per in ("cycle", "auto")


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
        self.check_options(options)
        super().__init__(model)
        self.options = MHEOptions(**options)

    @classmethod
    def option_names(cls) -> set[str]:
        return set(MHEOptions.__dataclass_fields__)

    @classmethod
    def takes_any_option(cls) -> bool:  # ``**options`` are MHEOptions' fields, no others
        return False

    @classmethod
    def check_options(cls, options: dict) -> None:
        super().check_options(options)
        MHEOptions(**options)  # its own rules (window, stride, mode, hessian)

    @classmethod
    def check_setup(cls, setup: CalibrationSetup) -> None:
        derived = [c for c in setup.sensors or () if c not in XS_NAMES]
        if derived:  # the compiled NLP's outputs are the measured channels x_s
            raise InputError(f"{cls.name}: reads the measured channels x_s only, not "
                             f"{', '.join(derived)}; use the ukf or ekf estimator")

    def estimate(self, df_unit: pd.DataFrame, setup: CalibrationSetup | None = None,
                 source=None, p=None) -> CalibrationResult:
        setup = setup or CalibrationSetup()
        self.check_setup(setup)
        series = prepare_unit(df_unit, setup, source)
        return run_windows(self.model, series, setup, self.options, self.per_cycle, p,
                           self.warn_unobservable)


class MAPCycleEstimator(MHEEstimator):
    """Batch MAP per flight cycle: one constant theta per ``cycle`` from all that cycle's
    samples, with the same NLP, the setup's prior as the only regularisation."""

    name = "map_cycle"
    per_cycle = True
