"""What an estimator may ask of a steady-state model: the public, typed interface.

Estimators (:mod:`calibration`) are written against :class:`SteadyStateModel`, never against
:class:`engine_model.EngineModel`'s internals, so that the same filter runs on the engine and
on a small analytic model in a test. Shapes: ``w`` (N, 4) operating points, ``theta`` (N, 10)
health parameters (or (10,) for every row, or None for a new engine), ``p`` (N, n_p) effect
parameters (or (n_p,), or None for their defaults), ``x`` (N, n_x) unknowns of the residual
system ``r(x; w, theta, p) = 0``; outputs are (N, n_out) in the order of ``output_names``.

Sensitivities at a solution are exact, by the implicit function theorem on the residual system
(for ``q`` any of ``theta``, ``w``, ``p``)::

    dy/dq = dy/dq|_x - dy/dx (dr/dx)^-1 dr/dq
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from .newton_driver import JacobianStore, SolveResult


@dataclass
class Sensitivities:
    """Exact derivatives of every output at the steady state of each point: ``theta`` (N,
    n_out, n_theta) per unit of theta (fraction), ``w`` (N, n_out, 4) per ft, -, %, degR, and
    ``p`` (N, n_out, n_p) per unit of each effect parameter (in its documented unit)."""

    theta: np.ndarray
    w: np.ndarray
    p: np.ndarray


@runtime_checkable
class SteadyStateModel(Protocol):
    """A batched steady-state model ``y = F(w, theta, p)`` defined by a residual system."""

    param_names: tuple  # effect parameters p, in order
    unknown_names: tuple  # unknowns x, in order
    output_names: tuple  # outputs y, in order

    @property
    def n_unknowns(self) -> int: ...

    @property
    def variant_key(self) -> str:
        """A short name of the model variant (its effects) for on-disk caches; '' for the
        base model."""
        ...

    def p_matrix(self, p, n: int) -> np.ndarray:
        """Effect parameters as an (n, n_p) matrix (defaults where ``p`` is None)."""
        ...

    def initial_guess(self, w, theta=None) -> np.ndarray:
        """Starting unknowns (N, n_x)."""
        ...

    def jacobian_store(self, n: int) -> JacobianStore | None:
        """Storage for ``n`` points' Jacobian factors carried between :meth:`solve_from`
        calls, or None where the model cannot carry them."""
        ...

    def solve_from(self, w, theta, x0, p=None, tol: float = 1e-10, max_iter: int = 30,
                   lu: JacobianStore | None = None, retry: bool = True) -> SolveResult:
        """Newton from the given unknowns ``x0`` (optionally from carried Jacobian factors);
        roots off the model's valid region are not converged; with ``retry``, failed points
        are solved again from the model's own starting guess and by continuation."""
        ...

    def solve(self, w, theta=None, p=None, x0=None, tol: float = 1e-10, max_iter: int = 30,
              check: bool = True) -> SolveResult:
        """The steady state from the model's own starting guess (or ``x0``), with retry."""
        ...

    def solve_series(self, w, theta=None, p=None, tol: float = 1e-10, max_iter: int = 30,
                     chunk: int = 64, starts=None) -> SolveResult:
        """The steady state along a time series, warm-started sample to sample; ``starts``:
        the first rows of several independent series stacked in ``w``, each solved as by a
        call of its own (default: one series)."""
        ...

    def outputs_at(self, x, w, theta=None, p=None) -> np.ndarray:
        """All outputs (N, n_out) at given unknowns (no solve)."""
        ...

    def residuals_at(self, x, w, theta=None, p=None) -> np.ndarray:
        """Residuals (N, n_x) at given unknowns."""
        ...

    def sensitivities_at(self, x, w, theta=None, p=None) -> Sensitivities:
        """Exact ``dy/dtheta``, ``dy/dw``, ``dy/dp`` at converged unknowns ``x``."""
        ...


@runtime_checkable
class SymbolicSteadyStateModel(SteadyStateModel, Protocol):
    """A steady-state model that also exposes its residual system as CasADi Functions (for
    optimisers that make the unknowns of many points decision variables, e.g. the MHE)."""

    def residual_system(self):
        """A :class:`engine_model.solver.model.ResidualSystem`."""
        ...
