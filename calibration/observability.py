"""Observability of the health parameters, checked by every estimator before it estimates.

:func:`check_observability` computes the Fisher information of the chosen sensors about the
chosen parameters over the unit (exact sensitivities ``S_k = R_k^{-1/2} dF/dtheta`` at the
prior mean, up to ``observability_samples`` samples spread over the unit, scaled to the unit's
length)::

    I = sum_k S_k^T S_k

While ``I`` is rank-deficient (smallest eigenvalue below ``observability_rtol`` times the
largest) or a parameter's data-only standard deviation ``sqrt((I^-1)_jj)`` exceeds
``observability_max_std`` (default 0.02, the default prior std: data that pin a parameter down
less well than the prior already does say nothing useful about it; e.g. ``Nf`` and ``P2``
alone, which the fan-speed control and the inlet fix, give HPT_eff_mod a data-only std of about
0.1 over two flights), the parameter with the largest weight in the weakest direction (or the
largest std) is declared **unobservable**. Policy ``setup.unobservable``: ``"exclude"``
(default) holds it at its prior mean, reports NaN for its estimate and standard deviation,
lists it in ``diagnostics["unobservable"]`` and issues an :class:`UnobservableWarning`;
``"raise"`` raises :class:`UnobservableError` instead. It is never silently estimated.

Holding a parameter at its prior mean is exact only while it stays there: if the engine's
real value moves, the observable parameters absorb the part of its signature they share, and
their standard deviations do not know it. Measured in ``tests/test_calibration.py`` (sensors
P2 and P15 on a degraded unit, HPT efficiency withheld): LPT efficiency ends 0.033 off with a
reported std of 0.009. Choose sensors that observe every parameter, or ``"raise"``.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from engine_model.solver.interface import SteadyStateModel
from engine_model.validation import InputError

from .estimation_setup import DEFAULT_PRIOR_STD, CalibrationSetup
from .series import UnitSeries, error_prefix


class UnobservableError(InputError):
    """The chosen sensors cannot determine one of the chosen health parameters."""


class UnobservableWarning(UserWarning):
    """A requested health parameter was not estimated because it is unobservable."""


def scaled_sensitivities(model: SteadyStateModel, w, x, theta_full, sigma, sensors, params_idx,
                         p=None):
    """``S = diag(1/sigma) dy/dtheta`` (N, m, k) for ``sensors`` and the theta at ``params_idx``
    at the converged unknowns ``x``, exact (implicit function theorem, CasADi)."""
    dth = model.sensitivities_at(np.asarray(x, float), np.asarray(w, float),
                                 np.asarray(theta_full, float), p).theta
    return scale_sensitivities(model, dth, sigma, sensors, params_idx)


def scale_sensitivities(model: SteadyStateModel, dth, sigma, sensors, params_idx) -> np.ndarray:
    """``diag(1/sigma) dy/dtheta`` (N, m, k) from every output's ``dy/dtheta`` ``dth``
    (N, n_out, 10): the rows of ``sensors``, the columns of ``params_idx``."""
    rows = [model.output_names.index(c) for c in sensors]
    J = dth[:, rows][:, :, params_idx]
    return J / sigma[:, :, None]


def fisher_information(S: np.ndarray) -> np.ndarray:
    """``sum_k S_k^T S_k`` of scaled sensitivities (N, m, k) -> (k, k)."""
    return np.einsum("nmi,nmj->ij", S, S)


def observability_split(info: np.ndarray, rtol: float = 1e-8,
                        max_std: float = DEFAULT_PRIOR_STD):
    """Greedy rank test of a Fisher information (module docstring). Returns ``(keep,
    dropped, rank)``: indices into its rows of the observable and unobservable parameters and
    the numerical rank of ``info``."""
    info = 0.5 * (np.asarray(info, float) + np.asarray(info, float).T)
    lam_all = np.linalg.eigvalsh(info)
    lmax_all = max(float(lam_all[-1]), 0.0)
    rank = int(np.sum(lam_all > rtol * lmax_all)) if lmax_all > 0 else 0
    keep = list(range(len(info)))
    dropped = []
    while keep:
        sub = info[np.ix_(keep, keep)]
        lam, vec = np.linalg.eigh(sub)
        lmax = float(lam[-1])
        if lmax <= 0 or lam[0] < rtol * lmax:
            j = int(np.argmax(np.abs(vec[:, 0])))
        else:
            std = np.sqrt(np.clip(np.diag(np.linalg.inv(sub)), 0, None))
            if std.max() <= max_std:
                break
            j = int(np.argmax(std))
        dropped.append(keep.pop(j))
    return keep, sorted(dropped), rank


@dataclass
class Observability:
    """Result of :func:`check_observability`."""

    observable: tuple  # parameter names
    unobservable: tuple
    fisher: np.ndarray  # (k, k) over the whole unit, all requested parameters
    rank: int
    data_std: dict  # parameter -> sqrt((I^-1)_jj) of the observable block


#: Most sample points of one batched solve and sensitivity evaluation of
#: :func:`check_observability_many` (units are added whole; at least one a batch): the
#: sensitivities of a point take 36 x 14 doubles, so a batch holds about 40 MB whatever the
#: fleet's size.
OBSERVABILITY_BATCH_POINTS = 8192


def sample_rows(n: int, setup: CalibrationSetup) -> np.ndarray:
    """The rows of a unit of ``n`` samples the Fisher information is computed at: up to
    ``setup.observability_samples`` spread evenly over the unit, first and last included."""
    return np.unique(np.linspace(0, n - 1, min(n, setup.observability_samples)).astype(int))


def check_observability(model: SteadyStateModel, series: UnitSeries, setup: CalibrationSetup,
                        x=None, p=None, apply_policy: bool = True,
                        warn: bool = True) -> Observability:
    """Fisher information of ``setup.sensors`` about ``setup.params`` over the unit at the
    prior mean, its rank, and which parameters are unobservable. ``x``: the unit's unknowns at
    the prior mean when known (else solved along the series); ``p``: its effect parameters
    ((n_p,) or (N, n_p)). With ``apply_policy``, ``setup.unobservable == "raise"`` raises
    :class:`UnobservableError` and ``"exclude"`` warns (:class:`UnobservableWarning`; not
    with ``warn=False``, for a caller that reports the fleet's summary instead)."""
    return check_observability_many(model, [series], setup, [x], [p], apply_policy, warn)[0]


def check_observability_many(model: SteadyStateModel, series: Sequence[UnitSeries],
                             setup: CalibrationSetup, xs: Sequence | None = None,
                             ps: Sequence | None = None, apply_policy: bool = True,
                             warn: bool = True) -> list[Observability]:
    """:func:`check_observability` of every unit of ``series`` (``xs``, ``ps``: each unit's
    ``x`` and ``p``, default None), in batches of whole units of up to
    :data:`OBSERVABILITY_BATCH_POINTS` sample points.

    Why batched: the work per unit is two small model calls (the solve along the series and
    the sensitivities at a few hundred points), so for a fleet of many short units (C-MAPSS:
    100 units of about 200 cycles) the calls' overhead cost as much as the evaluations, and a
    large batch lets the sensitivities run on every core. The numbers are each unit's alone,
    bit for bit: the solve treats every unit as its own series (``solve_series(...,
    starts=...)``), the sensitivities are evaluated point by point, and each unit's Fisher
    information is summed over its own points only. Units are assessed in order, so the first
    unit that fails raises, after the warnings of the units before it, as one call each
    would."""
    n_units = len(series)
    xs = [None] * n_units if xs is None else list(xs)
    ps = [None] * n_units if ps is None else list(ps)
    rows = [sample_rows(len(s), setup) for s in series]
    out: list = []
    batch: list[int] = []
    points = 0
    for i in range(n_units + 1):
        if batch and (i == n_units or points + len(rows[i]) > OBSERVABILITY_BATCH_POINTS):
            infos = _fisher_batch(model, [series[j] for j in batch], setup,
                                  [rows[j] for j in batch], [xs[j] for j in batch],
                                  [ps[j] for j in batch])
            out += [_assess(info, series[j], setup, apply_policy, warn)
                    for j, info in zip(batch, infos, strict=True)]
            batch, points = [], 0
        if i < n_units:
            batch.append(i)
            points += len(rows[i])
    return out


def _fisher_batch(model, series, setup, rows, xs, ps) -> list:
    """Each unit's Fisher information (k, k) scaled to its length, or an InputError to raise
    when its steady state converged nowhere (raised in order by :func:`_assess`)."""
    theta = setup.theta_base()
    pms = [None if p is None else np.asarray(p)[idx] if np.ndim(p) == 2 else p
           for p, idx in zip(ps, rows, strict=True)]
    to_solve = [i for i, x in enumerate(xs) if x is None]
    x_pts: list = [None] * len(series)
    conv: list = [None] * len(series)
    if to_solve:
        lengths = np.array([len(rows[i]) for i in to_solve])
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        w = np.concatenate([series[i].w[rows[i]] for i in to_solve])
        pm = (None if all(pms[i] is None for i in to_solve) else
              np.concatenate([model.p_matrix(pms[i], len(rows[i])) for i in to_solve]))
        r = model.solve_series(w, np.tile(theta, (len(w), 1)), pm, starts=starts)
        for i, a, n in zip(to_solve, starts, lengths, strict=True):
            x_pts[i], conv[i] = r.x[a:a + n], r.converged[a:a + n]
    for i, x in enumerate(xs):
        if x is not None:
            x_pts[i] = np.asarray(x)[rows[i]]
            conv[i] = np.ones(len(rows[i]), bool)
    used = [i for i in range(len(series)) if conv[i].any()]
    infos: list = [None] * len(series)
    for i in range(len(series)):
        if not conv[i].any():
            infos[i] = InputError(f"{error_prefix(series[i].unit, None)}steady state did not "
                                  "converge at the prior mean anywhere; cannot check "
                                  "observability")
    if not used:
        return infos
    w = np.concatenate([series[i].w[rows[i]][conv[i]] for i in used])
    x = np.concatenate([x_pts[i][conv[i]] for i in used])
    pm = (None if all(pms[i] is None for i in used) else
          np.concatenate([model.p_matrix(pms[i] if np.ndim(pms[i]) != 2 else pms[i][conv[i]],
                                         int(conv[i].sum())) for i in used]))
    dth = model.sensitivities_at(x, w, np.tile(theta, (len(w), 1)), pm).theta
    a = 0
    for i in used:
        m = int(conv[i].sum())
        sig = series[i].sigma[rows[i]][conv[i]]
        S = scale_sensitivities(model, dth[a:a + m], sig, series[i].sensors, setup.param_index)
        infos[i] = fisher_information(S) * (len(series[i]) / m)
        a += m
    return infos


def _assess(info, series: UnitSeries, setup: CalibrationSetup,
            apply_policy: bool, warn: bool = True) -> Observability:
    """The rank test of one unit's Fisher information and the policy (module docstring)."""
    if isinstance(info, Exception):
        raise info
    keep, dropped, rank = observability_split(info, setup.observability_rtol,
                                              setup.observability_max_std)
    sub = info[np.ix_(keep, keep)]
    std = np.sqrt(np.diag(np.linalg.inv(sub))) if keep else np.array([])
    obs = Observability(observable=tuple(setup.params[i] for i in keep),
                        unobservable=tuple(setup.params[i] for i in dropped),
                        fisher=info, rank=rank,
                        data_std={setup.params[i]: float(s) for i, s in zip(keep, std,
                                                                            strict=True)})
    if apply_policy and obs.unobservable:
        msg = (f"{error_prefix(series.unit, None)}health parameter(s) {', '.join(obs.unobservable)}"
               f" cannot be observed with sensors {', '.join(series.sensors)} (Fisher "
               f"information rank {rank} of {setup.k}; a parameter also counts as "
               f"unobservable when the data pin it down less than the prior std "
               f"{setup.observability_max_std:g} does)")
        if setup.unobservable == "raise" or not obs.observable:
            raise UnobservableError(msg)
        if warn:
            warnings.warn(msg + "; held at the prior mean, reported as NaN",
                          UnobservableWarning, stacklevel=4)
    return obs
