"""Random-walk Kalman filters of the health parameters over whole units, in lockstep groups.

The UKF (:mod:`calibration.ukf`) and the EKF (:mod:`calibration.ekf`) share everything but the
measurement update: the state space of :mod:`calibration.estimation_setup` (theta a random walk in
operating time, the exact steady-state model as the measurement), the data preparation, the
observability check, this driver and the final ``x_hat``. The filter state and its model
evaluation are :class:`lockstep.LockstepFilter`.

:class:`KalmanEstimator` groups units that share sensors and observable parameters, stacks each
group's series as lanes ordered by length, longest first (:class:`Lanes`: the active lanes of
a step are a prefix), runs the filter step by step (``predict`` then ``update`` for every
active lane, :class:`Trace` records the state), and counts a sample whose model points did not
converge in ``diagnostics["n_nonconverged"]`` (that lane skipped its update).

``x_hat`` (all x_s and x_v channels) is evaluated after the run at the filtered ``theta_hat``
of every sample in one batched solve, warm-started from the filter's own points.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from engine_model.channels import W_NAMES

from .base import Estimator
from .estimation_setup import CalibrationSetup
from .lockstep import LockstepFilter
from .observability import check_observability_many
from .result import CalibrationResult, make_result
from .series import UnitSeries, prepare_unit


def _stack_padded(series: Sequence[UnitSeries], attr: str, n_max: int) -> np.ndarray:
    first = getattr(series[0], attr)
    out = np.zeros((n_max, len(series), *first.shape[1:]))
    for u, s in enumerate(series):
        a = getattr(s, attr)
        out[: len(a), u] = a
    return out


@dataclass
class Lanes:
    """Units stacked step by step, longest first: arrays (n_max, U, ...) zero-padded past
    each unit's end (``sigma`` padded with 1), ``active[n]`` the number of lanes with a
    sample at step ``n`` (a prefix)."""

    series: list
    lengths: np.ndarray
    w: np.ndarray
    y: np.ndarray
    sigma: np.ndarray
    dtau_h: np.ndarray
    active: np.ndarray

    @property
    def n_lanes(self) -> int:
        return len(self.series)

    @property
    def sensors(self) -> tuple:
        return self.series[0].sensors

    @classmethod
    def stack(cls, series: list[UnitSeries]) -> Lanes:
        lengths = np.array([len(s) for s in series])
        n_max = int(lengths.max())
        sigma = _stack_padded(series, "sigma", n_max)
        sigma[sigma == 0] = 1.0
        active = (lengths[None, :] > np.arange(n_max)[:, None]).sum(axis=1)
        return cls(series, lengths, _stack_padded(series, "w", n_max),
                   _stack_padded(series, "y", n_max), sigma,
                   _stack_padded(series, "dtau_h", n_max), active)


@dataclass
class Trace:
    """The filter's state after every step (n_max, U, ...): mean ``m``, covariance ``P``,
    normalised innovations, NIS, whether the update ran, unknowns at the mean."""

    m: np.ndarray
    P: np.ndarray
    innovation: np.ndarray
    nis: np.ndarray
    ok: np.ndarray
    x_center: np.ndarray

    @classmethod
    def empty(cls, n_max: int, U: int, k: int, m: int, n_x: int) -> Trace:
        return cls(np.zeros((n_max, U, k)), np.zeros((n_max, U, k, k)),
                   np.zeros((n_max, U, m)), np.zeros((n_max, U)),
                   np.zeros((n_max, U), bool), np.zeros((n_max, U, n_x)))

    def record(self, n: int, A: int, f: LockstepFilter) -> None:
        self.m[n, :A] = f.m[:A]
        self.P[n, :A] = f.P[:A]
        self.innovation[n, :A] = f.innovation
        self.nis[n, :A] = f.nis
        self.ok[n, :A] = f.ok
        self.x_center[n, :A] = f.x_center


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
        obs = check_observability_many(self.model, series, setup,  # batched over units
                                       warn=self.warn_unobservable)
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
        """Filter a group of units (same sensors and observable parameters) in lockstep,
        longest first, then evaluate ``x_hat`` and assemble one result per unit."""
        t0 = time.perf_counter()
        order = np.argsort([-len(s) for s in series], kind="stable")
        lanes = Lanes.stack([series[i] for i in order])
        rows = np.array([self.model.output_names.index(c) for c in lanes.sensors])
        f = self.make_filter(sub, lanes.n_lanes)
        trace = self._filter(f, lanes, sub.drift ** 2, rows)
        t_filter = time.perf_counter() - t0
        y_all, x_conv = self._x_hat(lanes, sub, trace)
        seconds = time.perf_counter() - t0
        n_total = int(lanes.lengths.sum())
        full_idx = np.array([setup.params.index(q) for q in sub.params])
        out: list = [None] * lanes.n_lanes
        start = 0
        for u, s in enumerate(lanes.series):
            L = len(s)
            th = np.full((L, setup.k), np.nan)
            cov = np.full((L, setup.k, setup.k), np.nan)
            th[:, full_idx] = trace.m[:L, u]
            cov[:, full_idx[:, None], full_idx[None, :]] = trace.P[:L, u]
            ok = trace.ok[:L, u]
            o = obs[order[u]]
            diag = {
                "method": self.name,
                "n_samples": L,
                "fisher_rank": o.rank,
                "fisher_information": o.fisher.tolist(),
                "data_only_std": o.data_std,
                "n_nonconverged": int((~ok).sum()),
                "x_hat_nonconverged": int((~x_conv[start:start + L]).sum()),
                "nis_mean": float(trace.nis[:L, u][ok].mean()) if ok.any() else float("nan"),
                "nis_dof": len(rows),
                "iterations": f.iterations / max(f.solves, 1),
                "newton_retries": f.retries,
                "lanes": lanes.n_lanes,
                "residuals": "innovations (y - y_pred) / sigma, before the update",
                "filter_seconds": t_filter * L / n_total,
                **self.describe(),
                # the group's wall time shared out by samples
                "seconds": seconds * L / n_total,
                "samples_per_second": n_total / seconds,
            }
            out[order[u]] = make_result(s, setup, th, cov, y_all[start:start + L],
                                        trace.innovation[:L, u], diag, o.unobservable)
            start += L
        return out

    @staticmethod
    def _filter(f: LockstepFilter, lanes: Lanes, q2: float, rows: np.ndarray) -> Trace:
        """Run the filter over every step of the lanes; record its state per step."""
        n_max, U = lanes.w.shape[:2]
        trace = Trace.empty(n_max, U, f.k, len(rows), f.model.n_unknowns)
        for n in range(n_max):
            A = int(lanes.active[n])
            if n > 0:
                f.predict(q2 * lanes.dtau_h[n, :A])
            f.update(lanes.w[n, :A], lanes.y[n, :A], lanes.sigma[n, :A], rows)
            trace.record(n, A, f)
        return trace

    def _x_hat(self, lanes: Lanes, sub: CalibrationSetup, trace: Trace):
        """Every model output at the filtered theta of every sample: one batched solve over
        all lanes' samples, warm-started from the filter's own points. Returns the outputs
        (NaN where not converged; samples of lane 0, then lane 1, ...) and the converged
        mask."""
        n_max, U = lanes.w.shape[:2]
        sel = np.concatenate([np.arange(L) * U + u for u, L in enumerate(lanes.lengths)])
        th_full = sub.full_theta(trace.m.reshape(n_max * U, -1)[sel])
        w_all = lanes.w.reshape(n_max * U, len(W_NAMES))[sel]
        x0 = trace.x_center.reshape(n_max * U, -1)[sel]
        r = self.model.solve_from(w_all, th_full, x0, None, self.tol, self.max_iter,
                                  retry=True)
        y_all = self.model.outputs_at(r.x, w_all, th_full)
        y_all[~r.converged] = np.nan
        return y_all, r.converged

    def describe(self) -> dict:
        return {}


__all__ = ["KalmanEstimator", "Lanes", "Trace"]
