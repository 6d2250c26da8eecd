"""The batched damped Newton-chord iteration of the steady state, in C and in numpy.

Per point the iteration is (the same in ``newton_batch.c`` and :func:`newton_chord_numpy`)::

    r_i = r(x_i; w, theta, p)                      scaled residuals, converged when max|r_i| < tol
    J   = dr/dx (x_i)                              fresh on the first iteration, after a step
                                                   that raised the residual, and whenever the
                                                   last chord step cut max|r| by less than 4x;
                                                   otherwise the previous J is reused (chord)
    dx  = -J^-1 r_i,   a = min(1, min_j L_j / |dx_j|)   step limits L per unknown (STEP_LIMIT)
    x_{i+1} = x_i + a dx                           a step that raised max|r| is undone and
                                                   retried at half its length along the same dx

Each point leaves the loop when it converged; a point still above ``tol`` after ``max_iter``
iterations is returned with ``converged = False`` (never a silent wrong number). Reference:
Dennis & Schnabel, *Numerical Methods for Unconstrained Optimization and Nonlinear Equations*
(SIAM 1996), sec. 6.3 (backtracking) and 8.3 (chord / Shamanskii updates).

The C driver (``hyprog_newton_batch_lu`` of ``newton_batch.c``, compiled together with the
model's residual and residual-Jacobian functions, OpenMP threads over points) can carry each
point's LU factors between calls (:class:`JacobianStore`): a point solved before starts its
chord iteration from its last factors instead of a fresh Jacobian, which is what a time series
whose operating point and theta move little (the sigma points of a filter) needs.
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

# step limits per unknown (scaled units) of the damped iteration: the three compressor map
# coordinates may move one unit per step, the spool speeds and temperatures a few per cent
# (order of turbofan.UNKNOWN_NAMES; the last is the fan speed the controller selects)
STEP_LIMIT = np.array([1.0, 1.0, 1.0, 0.08, 0.15, 0.25, 0.25, 0.08])


@dataclass
class SolveResult:
    """Roots of a batch: unknowns ``x`` (N, n_x), ``converged`` (N,), ``residual_norm``
    (N,) the final max |r| (scaled residuals), ``iterations`` (N,) Newton iterations used
    (over every attempt), ``retried`` (N,) where a first attempt failed and a retry ran."""

    x: np.ndarray
    converged: np.ndarray
    residual_norm: np.ndarray
    iterations: np.ndarray
    retried: np.ndarray | None = None  # (N,) True where the first attempt failed

    def __post_init__(self):
        if self.retried is None:
            self.retried = np.zeros(len(self.x), bool)

    def put(self, idx, other: SolveResult, add_iterations: bool = True) -> None:
        """Overwrite rows ``idx`` with ``other``'s (a retry, so they are marked ``retried``),
        adding its iterations to the ones already spent."""
        self.x[idx] = other.x
        self.converged[idx] = other.converged
        self.residual_norm[idx] = other.residual_norm
        self.retried[idx] = True
        if add_iterations:
            self.iterations[idx] = self.iterations[idx] + other.iterations
        else:
            self.iterations[idx] = other.iterations


@dataclass
class JacobianStore:
    """Per-point LU factors of the Newton Jacobian kept between calls of the compiled driver:
    ``LU`` (n, n_x^2) row-major factors, ``PIV`` (n, n_x) int32 pivots, ``HAVE`` (n,) int32,
    1 where ``LU`` holds factors. Read and updated in place by the driver."""

    LU: np.ndarray
    PIV: np.ndarray
    HAVE: np.ndarray

    @classmethod
    def empty(cls, n: int, nx: int = len(STEP_LIMIT)) -> JacobianStore:
        return cls(np.zeros((n, nx * nx)), np.zeros((n, nx), np.int32), np.zeros(n, np.int32))

    def head(self, n: int) -> JacobianStore:
        """A view of the first ``n`` points' factors (the active lanes of a filter)."""
        return JacobianStore(self.LU[:n], self.PIV[:n], self.HAVE[:n])


class CompiledNewton:
    """``hyprog_newton_batch_lu`` of a compiled library, typed for numpy arrays."""

    def __init__(self, library: str):
        lib = ctypes.CDLL(library)
        f = lib.hyprog_newton_batch_lu
        dbl = np.ctypeslib.ndpointer(np.float64, flags="C_CONTIGUOUS")
        i32 = np.ctypeslib.ndpointer(np.int32, flags="C_CONTIGUOUS")
        c_int = ctypes.c_int
        f.argtypes = [c_int, c_int, c_int, c_int, c_int, dbl, dbl, dbl, dbl, dbl, i32, i32,
                      ctypes.c_double, c_int, dbl, c_int, _nullable(dbl), _nullable(i32),
                      _nullable(i32)]
        f.restype = c_int
        self._f = f

    def __call__(self, w, theta, p, x0, tol: float, max_iter: int, threads: int,
                 lu: JacobianStore | None = None) -> SolveResult:
        n = len(w)
        W = np.ascontiguousarray(w, float)
        TH = np.ascontiguousarray(theta, float)
        P = np.ascontiguousarray(p, float)
        if P.shape[1] == 0:
            P = np.zeros((n, 1))  # a valid pointer; the model reads no parameter
        X = np.array(x0, float, order="C", copy=True)
        rn = np.empty(n)
        it = np.empty(n, np.int32)
        conv = np.empty(n, np.int32)
        rc = self._f(n, X.shape[1], W.shape[1], TH.shape[1], P.shape[1], W, TH, P, X, rn, it,
                     conv, float(tol), int(max_iter), STEP_LIMIT, int(threads),
                     *((None, None, None) if lu is None else (lu.LU, lu.PIV, lu.HAVE)))
        if rc != 0:
            raise RuntimeError(f"batched Newton driver failed (code {rc})")
        return SolveResult(x=X, converged=conv.astype(bool), residual_norm=rn,
                           iterations=it.astype(int))


def _nullable(t):
    class Nullable:  # an ndpointer that also accepts None (NULL)
        @classmethod
        def from_param(cls, obj):
            return None if obj is None else t.from_param(obj)

    return Nullable


def newton_chord_numpy(resjac: Callable, residual: Callable, w, theta, p, x0, tol: float,
                       max_iter: int) -> SolveResult:
    """The iteration of the module docstring over a batch in numpy, each point with its own
    step control. ``resjac(x, w, theta, p) -> (r (N, n_x), J (N, n_x, n_x))`` and
    ``residual(x, w, theta, p) -> r (N, n_x)`` evaluate the subset of points given (rows)."""
    n = len(w)
    x = np.array(x0, float).copy()
    k = x.shape[1]
    x_old = x.copy()
    dx_old = np.zeros_like(x)
    J = np.zeros((n, k, k))
    need_j = np.ones(n, bool)
    alpha = np.ones(n)
    rn_old = np.full(n, np.inf)
    rn_final = np.full(n, np.inf)
    conv = np.zeros(n, bool)
    iters = np.zeros(n, int)
    active = np.arange(n)
    for it in range(max_iter + 1):
        if active.size == 0:
            break
        r = np.empty((active.size, k))
        nj = need_j[active]
        ij, ir = active[nj], active[~nj]
        if ij.size:
            r[nj], J[ij] = resjac(x[ij], w[ij], theta[ij], p[ij])
        if ir.size:
            r[~nj] = residual(x[ir], w[ir], theta[ir], p[ir])
        rn = np.abs(r).max(axis=1)
        rn[~np.isfinite(rn)] = np.inf
        done = rn < tol
        conv[active[done]] = True
        rn_final[active[done]] = rn[done]
        iters[active[done]] = it
        if it == max_iter:
            rn_final[active[~done]] = rn[~done]
            iters[active[~done]] = it
            break
        keep = ~done
        act, rn, r, fresh = active[keep], rn[keep], r[keep], nj[keep]
        worse = rn >= rn_old[act]
        ok = ~worse
        a_ok = act[ok]
        with np.errstate(all="ignore"):
            dx = -np.linalg.solve(J[a_ok], r[ok][:, :, None])[:, :, 0]
        finite = np.all(np.isfinite(dx), axis=1)
        dx[~finite] = 0.0
        lim = np.min(STEP_LIMIT[:k] / np.maximum(np.abs(dx), 1e-300), axis=1)
        step_a = np.minimum(1.0, lim)
        slow = (~fresh[ok]) & (rn[ok] > 0.25 * rn_old[a_ok])
        need_j[a_ok] = slow | ~finite
        x_old[a_ok] = x[a_ok]
        dx_old[a_ok] = dx
        alpha[a_ok] = step_a
        rn_old[a_ok] = rn[ok]
        x[a_ok] = x[a_ok] + step_a[:, None] * dx
        a_bad = act[worse]
        alpha[a_bad] *= 0.5
        x[a_bad] = x_old[a_bad] + alpha[a_bad, None] * dx_old[a_bad]
        need_j[a_bad] = True
        rn_final[a_bad] = rn_old[a_bad]
        active = act
    return SolveResult(x=x, converged=conv, residual_norm=rn_final, iterations=iters)
