"""The drift rate ``q`` of theta's random walk by maximum (marginal) likelihood.

Linearised at a fit (:mod:`.null_fit`), the model of one unit is linear-Gaussian in the
per-cycle ``Theta``: ``e(Theta) = e0 + J (Theta - Theta0)``, prior ``N(mu, Lambda_q^-1)``.
Its marginal likelihood is then exact (e.g. MacKay 1992; Rasmussen & Williams 2006, eq. 2.30
in information form)::

    -log p(y | q) = min_Theta [1/2 |e|^2 + 1/2 (Theta - mu)^T Lambda_q (Theta - mu)]
                    + 1/2 log det(J^T J + Lambda_q) - 1/2 log det(Lambda_q) + const

summed over units (they share ``q``, not theta). It is minimised over ``log q`` (bounded scalar
search, :func:`scipy.optimize.minimize_scalar`) and the fit is redone at the new ``q``;
:func:`estimate_drift` does this twice (the linearisation point moves little, so the second round
changes ``q`` little) and returns the second round's ``q``. This replaces a hand-set ``--drift``: on
the ``tiny`` fleet (10-cycle lives, fast wear) it gives q of about 0.003 per sqrt(hour) for the
per-cycle model, three times the default 1e-3.

The same estimate serves the estimators of :mod:`calibration` (``hyprog calibrate --drift
mle``, :func:`setup_with_drift_mle`): ``q`` is the random walk of theta per sqrt(hour of
operation), whether its prior puts a flight's wear at the next cycle's first sample
(``drift_per="cycle"``, the model here) or spreads it over the flight (``"time"``: the sum
of a flight's steps has the same variance ``q^2 tau``). It is estimated between flights, so the
data need a ``cycle`` column and a unit with two or more cycles.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from calibration.estimation_setup import CalibrationSetup
from engine_model.validation import InputError

from .null_fit import FitState, Problem

Q_RANGE = (1e-5, 1.0)  # per sqrt(hour)


def neg_log_evidence(problem: Problem, state: FitState, q: float) -> float:
    lin = state.lin
    total = 0.0
    k = problem.k
    for i, u in enumerate(problem.units):
        C = u.n_cycles
        A = np.zeros((C * k, C * k))
        for c in range(C):
            A[c * k:(c + 1) * k, c * k:(c + 1) * k] = lin.A[i][c]
        lam = problem.prior_precision(u, q)
        th0 = state.Theta[i].ravel()
        mu = np.tile(problem.mu0, C)
        g0 = lin.g_th[i].ravel()
        e0 = float(np.sum(lin.e[i] ** 2))
        H = A + lam
        rhs = A @ th0 - g0 + lam @ mu
        th = np.linalg.solve(H, rhs)
        dt = th - th0
        val = 0.5 * e0 + g0 @ dt + 0.5 * dt @ A @ dt + 0.5 * (th - mu) @ lam @ (th - mu)
        _, ld_h = np.linalg.slogdet(H)
        _, ld_l = np.linalg.slogdet(lam)
        total += val + 0.5 * ld_h - 0.5 * ld_l
    return float(total)


def drift_mle(problem: Problem, state: FitState) -> float:
    """The maximum-likelihood ``q`` [per sqrt(hour)] at the linearisation of ``state``
    (units with one cycle carry no information on ``q``; with none, the setup's value)."""
    if all(u.n_cycles < 2 for u in problem.units):
        return problem.q
    lo, hi = np.log(Q_RANGE[0]), np.log(Q_RANGE[1])
    r = minimize_scalar(lambda lq: neg_log_evidence(problem, state, float(np.exp(lq))),
                        bounds=(lo, hi), method="bounded", options={"xatol": 1e-3})
    return float(np.exp(r.x))


def estimate_drift(frames: list, setup: CalibrationSetup, model=None, source=None) -> float:
    """The maximum-likelihood ``q`` [per sqrt(hour)] of the units ``frames`` (one DataFrame
    each, hyprog names): the per-cycle fit of :mod:`.null_fit` (no candidate effect; warm
    start ``coarse``), then twice: ``q`` at the fit's linearisation and the fit redone at
    that ``q``; the second ``q``."""
    from dataclasses import replace

    from .candidates import CandidateModel
    from .null_fit import coarse_start, fit, unit_data

    if model is None:
        from engine_model.runtime.shared_model import default_model

        model = default_model()
    cycle_setup = replace(setup, drift_per="cycle")
    units = [unit_data(f, cycle_setup, source) for f in frames]
    if all(u.n_cycles < 2 for u in units):
        where = f"{source}: " if source is not None else ""
        raise InputError(f"{where}--drift mle: no unit has two or more flight cycles (a "
                         "'cycle' column); theta's drift is estimated between cycles")
    problem = Problem(units, cycle_setup, CandidateModel([], model=model))
    phi = np.zeros(0)
    state = fit(problem, coarse_start(problem, phi), phi)
    for _ in range(2):
        problem.q = drift_mle(problem, state)
        state = fit(problem, state.Theta, phi, xs=state.lin.x, lin=state.lin)
    return float(problem.q)


def setup_with_drift_mle(text, data, setup: CalibrationSetup, units=None,
                         model=None) -> CalibrationSetup:
    """``setup`` with ``q`` estimated from the dataset ``data`` (path; ``units``: the units
    to use, default all) when ``text`` is ``"mle"``; otherwise ``setup`` unchanged."""
    if text != "mle":
        return setup
    from dataclasses import replace

    from engine_model.datasets import read_dataset

    df, _meta = read_dataset(data, units=units)
    if "unit" not in df.columns:
        df = df.assign(unit=1)
    frames = [g for _, g in df.groupby("unit", sort=True)]
    q = estimate_drift(frames, setup, model, source=data)
    return replace(setup, drift=q)
