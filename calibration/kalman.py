"""Random-walk Kalman filters of the health parameters, run over many units in lockstep.

The UKF (:mod:`calibration.ukf`) and the EKF (:mod:`calibration.ekf`) share everything but the
measurement update: the state space of :mod:`calibration.base` (theta a random walk in
operating time, the exact steady-state model as the measurement), the data preparation, the
observability check, the lockstep driver and the final ``x_hat``.

Lockstep. Per-step Python overhead, not the engine model, limits a filter that runs one sample
at a time. :class:`LockstepFilter` therefore runs ``U`` units (lanes) side by side: step ``n``
predicts and updates sample ``n`` of every unit that has one, with one batched call of the
compiled model for all lanes' points and numpy linear algebra on stacked (U, k, k) arrays.
Lanes are ordered by length, longest first, so the active lanes of a step are a prefix. The
units stay independent: a lane's numbers do not depend on which other lanes run with it.

Warm start. Each lane keeps the unknowns ``x`` of its model points of the previous step and
the LU factors of their last Jacobian (:class:`engine_model.model.JacobianStore`); at 0.1 Hz
a step moves ``w`` little and theta less, so the Newton-chord iteration converges in 1-3
residual evaluations without a fresh Jacobian (refreshed when convergence is slow). A point
that does not converge from there is retried from the model's tabulated guess (with
continuation, :meth:`EngineModel.solve`); if it still fails the lane skips the update of that
sample (prediction only) and the sample is counted in ``diagnostics["n_nonconverged"]``.

``x_hat`` (all x_s and x_v channels) is evaluated after the run at the filtered ``theta_hat``
of every sample in one batched solve, warm-started from the filter's own points.
"""

from __future__ import annotations

import time
from abc import abstractmethod
from collections.abc import Sequence

import numpy as np
import pandas as pd

from engine_model.channels import OUTPUT_NAMES
from engine_model.model import JacobianStore

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


class LockstepFilter:
    """State of ``U`` random-walk filters of ``k`` parameters: plain arrays ``m`` (U, k) and
    ``P`` (U, k, k), plus the warm-start unknowns ``x`` (U, n_points, 7) of each lane's model
    points. Subclasses implement :meth:`update`.

    ``predict(q_var)`` adds the random-walk step ``q_var`` (U,) times the identity to ``P``;
    ``update(w, y, sigma)`` assimilates one sample per lane; :meth:`batch_filter` runs whole
    series. All three act on the first ``A`` lanes given by the arrays' length (the active
    prefix).
    """

    n_points: int = 1  # model points per lane and step

    def __init__(self, model, setup: CalibrationSetup, n_lanes: int, tol: float = 1e-10,
                 max_iter: int = 30):
        self.model = model
        self.setup = setup
        self.k = setup.k
        self.tol = tol
        self.max_iter = max_iter
        self.lo, self.hi = setup.bounds
        self.pidx = setup.param_index
        self.theta_base = setup.theta_base()
        self.m = np.tile(setup.prior_mean_vec(), (n_lanes, 1))
        self.P = np.tile(np.diag(setup.prior_std_vec() ** 2), (n_lanes, 1, 1))
        self.x = None  # (U, n_points, 7) after the first step
        self._maps: dict = {}
        self._lu = None  # Jacobian factors of every lane's points, carried between steps
        self.iterations = 0
        self.solves = 0
        self.retries = 0
        # per-step outputs of the last update, for the driver
        self.innovation = None  # (A, m) normalised (y - y_pred) / sigma
        self.nis = None  # (A,)
        self.ok = None  # (A,) update done
        self.x_center = None  # (A, 7) unknowns at the prior mean

    # -- model evaluation
    def solve_points(self, w, theta_est, lanes: int):
        """Solve the steady state at ``theta_est`` (A, P, k) and ``w`` (A, 4) of the first
        ``lanes`` lanes, warm-started; returns unknowns (A, P, 7), outputs (A, P, n_out) and
        a converged mask (A, P)."""
        A, npt, _ = theta_est.shape
        th = np.broadcast_to(self.theta_base, (A, npt, len(self.theta_base))).copy()
        th[:, :, self.pidx] = theta_est
        th = th.reshape(A * npt, -1)
        W = np.repeat(w, npt, axis=0)
        if self.x is None:
            x0 = self.model.initial_guess(W, th)
        else:
            x0 = self.x[:A].reshape(A * npt, -1)
        lu = None
        if self.model.compiled:
            if self._lu is None:
                self._lu = JacobianStore.empty(len(self.m) * npt, x0.shape[1])
            s = self._lu
            lu = JacobianStore(s.LU[:A * npt], s.PIV[:A * npt], s.HAVE[:A * npt])
        r = self.model._newton(W, th, x0, None, self.tol, self.max_iter, lu=lu)
        self.model._reject_off_map(r)
        self.iterations += int(r.iterations.sum())
        self.solves += len(W)
        bad = np.flatnonzero(~r.converged)
        if bad.size:
            self.retries += bad.size
            r2 = self.model.solve(W[bad], th[bad], tol=self.tol, max_iter=self.max_iter,
                                  check=False)
            r.x[bad], r.converged[bad] = r2.x, r2.converged
            self.iterations += int(r2.iterations.sum())
        y = self.outputs(r.x, W, th)
        x = r.x.reshape(A, npt, -1)
        if self.x is None:
            self.x = np.zeros((len(self.m), npt, x.shape[-1]))
            self.x[:A] = x
        else:
            conv = r.converged.reshape(A, npt)
            self.x[:A] = np.where(conv[:, :, None], x, self.x[:A])
        return x, y.reshape(A, npt, -1), r.converged.reshape(A, npt)

    def _serial(self, key, x, w, th):
        """Compiled function ``key`` of the model mapped serially over a batch padded to a
        multiple of 8 (for the few dozen points of one step this is several times faster than
        :meth:`EngineModel.outputs_at`, whose thread map starts threads on every call).
        Returns the mapped outputs and the batch size."""
        n = len(x)
        nb = max(8, -(-n // 8) * 8)
        f = self._maps.get((key, nb))
        if f is None:
            f = self._maps[(key, nb)] = self.model._f[key].map(nb, "serial")
        pad = nb - n
        args = [x, w, th, self.model._p_matrix(None, n)]
        if pad:
            args = [np.concatenate([a, np.repeat(a[-1:], pad, axis=0)]) for a in args]
        out = f(*[a.T for a in args])
        return out, nb

    def outputs(self, x, w, th):
        """Model outputs (N, n_out) at the unknowns ``x``."""
        y, _ = self._serial("outputs", x, w, th)
        return np.asarray(y)[:, : len(x)].T

    def sensitivities(self, x, w, th):
        """Exact ``dy/dtheta`` (N, n_out, 10) at the unknowns ``x`` (implicit function
        theorem on the residual system, as :meth:`EngineModel.sensitivities`)."""
        (dth, _), nb = self._serial("sens", x, w, th)
        n, nt = len(x), th.shape[1]
        d = np.asarray(dth).T.reshape(nb, nt, -1)[:n]
        return d.transpose(0, 2, 1)

    # -- filter steps
    def predict(self, q_var: np.ndarray):
        """Random walk: ``P += q_var I`` for the first ``len(q_var)`` lanes."""
        A = len(q_var)
        idx = np.arange(self.k)
        self.P[:A, idx, idx] += q_var[:, None]

    @abstractmethod
    def update(self, w: np.ndarray, y: np.ndarray, sigma: np.ndarray, rows: np.ndarray):
        """Assimilate one sample per active lane: ``w`` (A, 4), readings ``y`` (A, m) of the
        sensors at output rows ``rows``, their noise std ``sigma`` (A, m)."""

    def _finish_update(self, A):
        """Symmetrise, keep positive definite and project the mean onto the bounds."""
        P = self.P[:A]
        P = 0.5 * (P + np.swapaxes(P, 1, 2))
        self.P[:A] = make_pd(P)
        np.clip(self.m[:A], self.lo, self.hi, out=self.m[:A])


def make_pd(P: np.ndarray, floor: float = 1e-18) -> np.ndarray:
    """Symmetric positive definite version of stacked symmetric matrices (U, k, k): returned
    unchanged when the Cholesky factorisation of every matrix succeeds, else the failed ones'
    eigenvalues are floored at ``floor`` plus 1e-12 of their largest."""
    try:
        np.linalg.cholesky(P)
        return P
    except np.linalg.LinAlgError:
        pass
    lam, V = np.linalg.eigh(P)
    lam = np.maximum(lam, floor + 1e-12 * np.abs(lam).max(axis=1, keepdims=True))
    return np.einsum("uij,uj,ukj->uik", V, lam, V)


def _stack_padded(series: Sequence[UnitSeries], attr: str, n_max: int):
    first = getattr(series[0], attr)
    out = np.zeros((n_max, len(series), *first.shape[1:]))
    for u, s in enumerate(series):
        a = getattr(s, attr)
        out[: len(a), u] = a
    return out


class KalmanEstimator(Estimator):
    """Common estimator of the UKF and the EKF: checks observability per unit, runs the units
    in lockstep groups (same sensors and observable parameters), and evaluates ``x_hat``."""

    filter_class: type[LockstepFilter]

    def __init__(self, model=None, tol: float = 1e-10, max_iter: int = 30,
                 max_lanes: int = 64, **filter_options):
        super().__init__(model)
        self.tol = tol
        self.max_iter = max_iter
        self.max_lanes = max_lanes
        self.filter_options = filter_options

    def make_filter(self, setup: CalibrationSetup, n_lanes: int) -> LockstepFilter:
        return self.filter_class(self.model, setup, n_lanes, tol=self.tol,
                                 max_iter=self.max_iter, **self.filter_options)

    def estimate(self, df_unit: pd.DataFrame, setup: CalibrationSetup | None = None,
                 source=None) -> CalibrationResult:
        return self.estimate_many([df_unit], setup, source)[0]

    def estimate_many(self, units: Sequence[pd.DataFrame], setup: CalibrationSetup | None = None,
                      source=None) -> list[CalibrationResult]:
        setup = setup or CalibrationSetup()
        t0 = time.perf_counter()
        series = [prepare_unit(df, setup, source) for df in units]
        obs = [check_observability(self.model, s, setup) for s in series]
        t_obs = time.perf_counter() - t0
        groups: dict = {}
        for i, (s, o) in enumerate(zip(series, obs, strict=True)):
            groups.setdefault((s.sensors, o.observable), []).append(i)
        results: list = [None] * len(series)
        for (_, observable), members in groups.items():
            sub = setup.with_params(observable)
            for c0 in range(0, len(members), self.max_lanes):
                chunk = members[c0:c0 + self.max_lanes]
                out = self._run_group([series[i] for i in chunk], sub, setup,
                                      [obs[i] for i in chunk])
                for i, r in zip(chunk, out, strict=True):
                    results[i] = r
        for r in results:
            r.diagnostics["observability_seconds"] = t_obs / len(results)
        return results

    def _run_group(self, series: list[UnitSeries], sub: CalibrationSetup,
                   setup: CalibrationSetup, obs) -> list[CalibrationResult]:
        t0 = time.perf_counter()
        order = np.argsort([-len(s) for s in series], kind="stable")
        series_o = [series[i] for i in order]
        lengths = np.array([len(s) for s in series_o])
        n_max, U = int(lengths[0]), len(series_o)
        W = _stack_padded(series_o, "w", n_max)
        Y = _stack_padded(series_o, "y", n_max)
        SIG = _stack_padded(series_o, "sigma", n_max)
        SIG[SIG == 0] = 1.0
        DT = _stack_padded(series_o, "dtau_h", n_max)
        q2 = sub.drift_std_per_sqrt_h ** 2
        active = (lengths[None, :] > np.arange(n_max)[:, None]).sum(axis=1)
        rows = np.array([OUTPUT_NAMES.index(c) for c in series_o[0].sensors])
        k, m = sub.k, len(rows)
        M = np.zeros((n_max, U, k))
        PP = np.zeros((n_max, U, k, k))
        E = np.zeros((n_max, U, m))
        NIS = np.zeros((n_max, U))
        OK = np.zeros((n_max, U), bool)
        XC = np.zeros((n_max, U, 7))
        f = self.make_filter(sub, U)
        for n in range(n_max):
            A = int(active[n])
            if n > 0:
                f.predict(q2 * DT[n, :A])
            f.update(W[n, :A], Y[n, :A], SIG[n, :A], rows)
            M[n, :A] = f.m[:A]
            PP[n, :A] = f.P[:A]
            E[n, :A] = f.innovation
            NIS[n, :A] = f.nis
            OK[n, :A] = f.ok
            XC[n, :A] = f.x_center
        t_filter = time.perf_counter() - t0
        # x_hat at the filtered theta, one batched solve over every lane's samples
        sel = np.concatenate([np.arange(L) * U + u for u, L in enumerate(lengths)])
        th_full = sub.full_theta(M.reshape(n_max * U, k)[sel])
        w_all = W.reshape(n_max * U, 4)[sel]
        r = self.model._newton(w_all, th_full, XC.reshape(n_max * U, 7)[sel], None,
                               self.tol, self.max_iter)
        self.model._reject_off_map(r)
        bad = np.flatnonzero(~r.converged)
        if bad.size:
            r2 = self.model.solve(w_all[bad], th_full[bad], tol=self.tol, check=False)
            r.x[bad], r.converged[bad] = r2.x, r2.converged
        y_all = self.model.outputs_at(r.x, w_all, th_full)
        y_all[~r.converged] = np.nan
        n_total = int(lengths.sum())
        seconds = time.perf_counter() - t0
        results_o = []
        start = 0
        full_idx = [setup.params.index(q) for q in sub.params]
        for u, s in enumerate(series_o):
            L = len(s)
            th = np.full((L, setup.k), np.nan)
            cov = np.full((L, setup.k, setup.k), np.nan)
            th[:, full_idx] = M[:L, u]
            cov[:, np.ix_(full_idx, full_idx)[0], np.ix_(full_idx, full_idx)[1]] = PP[:L, u]
            ok = OK[:L, u]
            diag = {
                "method": self.name,
                "n_samples": L,
                "fisher_rank": obs[order[u]].rank,
                "fisher_information": obs[order[u]].fisher.tolist(),
                "data_only_std": obs[order[u]].data_std,
                "n_nonconverged": int((~ok).sum()),
                "x_hat_nonconverged": int((~r.converged[start:start + L]).sum()),
                "nis_mean": float(NIS[:L, u][ok].mean()) if ok.any() else float("nan"),
                "nis_dof": m,
                "iterations": f.iterations / max(f.solves, 1),
                "newton_retries": f.retries,
                "lanes": U,
                "residuals": "innovations (y - y_pred) / sigma, before the update",
                "filter_seconds": t_filter * L / n_total,
                **self.describe(),
            }
            # the group's wall time shared out by samples
            diag["seconds"] = seconds * L / n_total
            diag["samples_per_second"] = n_total / seconds
            results_o.append(make_result(s, setup, th, cov, y_all[start:start + L], E[:L, u],
                                         diag, obs[order[u]].unobservable))
            start += L
        out = [None] * U
        for j, i in enumerate(order):
            out[i] = results_o[j]
        return out

    def describe(self) -> dict:
        return {}


__all__ = ["KalmanEstimator", "LockstepFilter", "make_pd", "timed"]
