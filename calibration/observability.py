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


def check_observability(model: SteadyStateModel, series: UnitSeries, setup: CalibrationSetup,
                        x=None, p=None, apply_policy: bool = True) -> Observability:
    """Fisher information of ``setup.sensors`` about ``setup.params`` over the unit at the
    prior mean, its rank, and which parameters are unobservable. With ``apply_policy``,
    ``setup.unobservable == "raise"`` raises :class:`UnobservableError` and ``"exclude"``
    warns (:class:`UnobservableWarning`)."""
    n = len(series)
    idx = np.unique(np.linspace(0, n - 1, min(n, setup.observability_samples)).astype(int))
    w = series.w[idx]
    th = np.tile(setup.theta_base(), (len(idx), 1))
    pm = None if p is None else np.asarray(p)[idx] if np.ndim(p) == 2 else p
    if x is None:
        r = model.solve_series(w, th, pm)
        ok = r.converged
        if not ok.any():
            raise InputError(f"{error_prefix(series.unit, None)}steady state did not converge at "
                             "the prior mean anywhere; cannot check observability")
        xs, w, th, sig = r.x[ok], w[ok], th[ok], series.sigma[idx][ok]
        pm = pm[ok] if pm is not None and np.ndim(pm) == 2 else pm
    else:
        xs, sig = np.asarray(x)[idx], series.sigma[idx]
    S = scaled_sensitivities(model, w, xs, th, sig, series.sensors, setup.param_index, pm)
    info = fisher_information(S) * (n / len(xs))
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
        warnings.warn(msg + "; held at the prior mean, reported as NaN",
                      UnobservableWarning, stacklevel=2)
    return obs
