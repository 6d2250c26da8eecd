"""The engine model as a user sees it: ``F(w, theta) -> (x_s, x_v)`` on batches.

>>> from engine_model import EngineModel
>>> m = EngineModel()                       # builds, compiles (cached on disk) and tabulates
>>> df = m.evaluate(pd.DataFrame({"alt": [0], "Mach": [0], "TRA": [100], "T2": [518.67]}))
>>> df[["T30", "Wf", "converged"]]

Steady state. The cycle of :mod:`turbofan` is a residual system ``r(x; w, theta, p) = 0``;
a batch of points is solved by Newton's method with the exact Jacobian ``dr/dx`` (CasADi
AD), compiled to C and evaluated over the batch with CasADi's thread map. Every point has
its own step control (step limits per unknown, backtracking when the residual grows) and
leaves the loop when ``max |r| < tol``; a point still above ``tol`` after ``max_iter``
iterations is returned with ``converged = False`` and its outputs set to NaN, never as a
valid number.

Starting guesses come from a table over (demanded corrected fan speed, Mach) that the model
fills by continuation when it is built: by similarity the corrected operating point of a
turbofan depends mainly on those two (T40 is stored as T40/T2). A time series can instead be
warm-started from its previous solution (:meth:`EngineModel.solve_series`).

Sensitivities ``d(outputs)/d(theta)`` and ``d(outputs)/d(w)`` at the solution are exact, by the
implicit function theorem on the residual system:
``dy/dq = dy/dq|_x - dy/dx (dr/dx)^-1 dr/dq``.
"""

from __future__ import annotations

import ctypes
import os
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
import pandas as pd

from . import atmosphere
from .channels import OUTPUT_NAMES, THETA_NAMES, W_NAMES
from .codegen import compile_functions
from .design import EngineDesign, design_engine
from .effects import EffectSet
from .turbofan import N_UNKNOWNS, UNKNOWN_NAMES, X_DESIGN, cycle, imperial_outputs
from .validation import InputError, check_columns, check_theta, check_w

# step limits per unknown (scaled units) for the damped Newton iteration
_STEP_LIMIT = np.array([1.0, 1.0, 1.0, 0.08, 0.15, 0.25, 0.25])
_TABLE_PCT = np.linspace(60.0, 104.0, 23)
_TABLE_MACH = np.linspace(0.0, 0.9, 10)
_TABLE_T2 = (540.0, 470.0, 400.0)  # degR, descending


def _load_newton_driver(library: str):
    """``hyprog_newton_batch_lu`` of the compiled library, typed for numpy arrays (the LU
    arguments may be None)."""
    lib = ctypes.CDLL(library)
    f = lib.hyprog_newton_batch_lu
    dbl = np.ctypeslib.ndpointer(np.float64, flags="C_CONTIGUOUS")
    i32 = np.ctypeslib.ndpointer(np.int32, flags="C_CONTIGUOUS")
    c_int = ctypes.c_int

    def opt(t):
        class Optional:  # an ndpointer that also accepts None (NULL)
            @classmethod
            def from_param(cls, obj):
                return None if obj is None else t.from_param(obj)
        return Optional

    f.argtypes = [c_int, c_int, c_int, c_int, c_int, dbl, dbl, dbl, dbl, dbl, i32, i32,
                  ctypes.c_double, c_int, dbl, c_int, opt(dbl), opt(i32), opt(i32)]
    f.restype = c_int
    return f


@dataclass
class JacobianStore:
    """Per-point LU factors of the Newton Jacobian kept between calls of
    :meth:`EngineModel._newton` (``lu=``): a point that was solved before starts its chord
    iteration from its last factors instead of a fresh Jacobian (a time series whose
    operating point and theta move little, e.g. the sigma points of a filter)."""

    LU: np.ndarray  # (n, 49)
    PIV: np.ndarray  # (n, 7) int32
    HAVE: np.ndarray  # (n,) int32, 1 where LU holds factors

    @classmethod
    def empty(cls, n: int, nx: int = 7) -> JacobianStore:
        return cls(np.zeros((n, nx * nx)), np.zeros((n, nx), np.int32), np.zeros(n, np.int32))


@dataclass
class SolveResult:
    x: np.ndarray  # (N, 7) unknowns
    converged: np.ndarray  # (N,) bool
    residual_norm: np.ndarray  # (N,) max |r| (scaled residuals)
    iterations: np.ndarray  # (N,) Newton iterations used


@dataclass(frozen=True)
class ResidualSystem:
    """The steady state as equations, for optimisers that solve many points at once.

    ``residual(x, w, theta, p)`` (7 scaled residuals) and ``outputs(x, w, theta, p)`` (every
    channel of :data:`channels.OUTPUT_NAMES`, N-CMAPSS units) are CasADi Functions of the
    unknowns ``x`` (names in ``unknown_names``), so that e.g. a moving-horizon estimator can
    make ``x`` at every sample decision variables with ``residual == 0`` as constraints.
    """

    unknown_names: tuple
    output_names: tuple
    param_names: tuple
    x_design: np.ndarray
    residual: ca.Function
    outputs: ca.Function
    guess: object  # callable (w (N,4)) -> x0 (N,7)


class EngineModel:
    """Two-spool turbofan steady-state model with exact derivatives.

    Parameters
    ----------
    design : EngineDesign, optional
        Design point and maps; default :func:`design.design_engine()`.
    effects : sequence of effects.Effect, optional
        Optional physical effects built into the symbolic model; their parameters become the
        vector ``p`` (names in :attr:`param_names`).
    compiled : bool
        Generate and compile C (cached on disk) for the hot path; otherwise CasADi's virtual
        machine evaluates the same expression graph.
    n_threads : int, optional
        Threads for batch evaluation (default: all cores).
    """

    def __init__(self, design: EngineDesign | None = None, effects=(), compiled: bool = True,
                 n_threads: int | None = None):
        self.design = design or design_engine()
        self.effects = EffectSet(effects)
        self.compiled = compiled
        self.n_threads = max(1, n_threads or os.cpu_count() or 1)
        self.param_names = self.effects.param_names
        self.p_default = self.effects.defaults
        self._build()
        self._maps: dict = {}
        self._load_or_build_table()

    # ------------------------------------------------------------------ construction
    def _build(self):
        x = ca.SX.sym("x", N_UNKNOWNS)
        w = ca.SX.sym("w", len(W_NAMES))
        th = ca.SX.sym("theta", len(THETA_NAMES))
        p = ca.SX.sym("p", len(self.param_names))
        hook = self.effects.hook(p, w)
        res, st = cycle(self.design, w, th, x, hook)
        out = imperial_outputs(st, hook)
        y = ca.vertcat(*[out[k] for k in OUTPUT_NAMES])
        self.stations_expr = st
        J = ca.densify(ca.jacobian(res, x))
        f_res = ca.Function("hyprog_residual", [x, w, th, p], [res])
        f_out = ca.Function("hyprog_outputs", [x, w, th, p], [y])
        f_resjac = ca.Function("hyprog_resjac", [x, w, th, p], [res, J])
        # exact sensitivities by the implicit function theorem
        Jinv_r = ca.solve(J, ca.horzcat(ca.jacobian(res, th), ca.jacobian(res, w)))
        dy_dx = ca.jacobian(y, x)
        dth = ca.jacobian(y, th) - dy_dx @ Jinv_r[:, : th.numel()]
        dw = ca.jacobian(y, w) - dy_dx @ Jinv_r[:, th.numel():]
        f_sens = ca.Function("hyprog_sensitivities", [x, w, th, p], [dth, dw])
        # dx*/dtheta, used only to tabulate starting guesses
        self._f_dxdth = ca.Function("hyprog_dxdth", [x, w, th, p], [-Jinv_r[:, : th.numel()]])
        self._sym = dict(x=x, w=w, theta=th, p=p, res=res, y=y)
        self._symbolic = dict(residual=f_res, outputs=f_out, resjac=f_resjac, sens=f_sens)
        if self.compiled:
            name = "hyprog_engine" + (("_" + self.effects.key) if self.effects.key else "")
            hot = compile_functions(
                name + "_hot", [f_res, f_resjac], opt="-O2",
                extra_sources=(str(Path(__file__).with_name("newton_batch.c")),),
                extra_flags=(f"-DRES_FN={f_res.name()}", f"-DRESJAC_FN={f_resjac.name()}"),
                optional_flags=("-fopenmp",))
            self._newton_c = _load_newton_driver(hot["__library__"])
            cold = compile_functions(name + "_cold", [f_out, f_sens], opt="-O1")
            self._f = dict(residual=hot[f_res.name()], resjac=hot[f_resjac.name()],
                           outputs=cold[f_out.name()], sens=cold[f_sens.name()])
        else:
            self._f = dict(self._symbolic)
            self._newton_c = None

    def _mapped(self, key, n):
        """A thread-mapped version of function ``key`` for batches padded to size ``n``."""
        cache_key = (key, n)
        if cache_key not in self._maps:
            f = self._f[key]
            if n >= 2 * self.n_threads and self.n_threads > 1:
                self._maps[cache_key] = f.map(n, "thread", self.n_threads)
            else:
                self._maps[cache_key] = f.map(n, "serial")
        return self._maps[cache_key]

    _CHUNK = 2048

    @staticmethod
    def _bucket(n):
        return max(8, 1 << int(np.ceil(np.log2(max(n, 1)))))

    def _call(self, key, *args):
        """Evaluate function ``key`` column-wise on (k, N) arrays, in chunks of at most
        ``_CHUNK`` columns (the last chunk padded to a power of two)."""
        n = args[0].shape[1]
        results = None
        for s0 in range(0, n, self._CHUNK):
            s1 = min(n, s0 + self._CHUNK)
            m = s1 - s0
            nb = self._CHUNK if m == self._CHUNK else self._bucket(m)
            padded = []
            for a in args:
                a = a[:, s0:s1]
                if m < nb:
                    a = np.concatenate([a, np.repeat(a[:, -1:], nb - m, axis=1)], axis=1)
                padded.append(a)
            outs = self._mapped(key, nb)(*padded)
            if not isinstance(outs, (list, tuple)):
                outs = [outs]
            outs = [np.asarray(o)[:, :m] if o.shape[1] == nb else
                    np.asarray(o)[:, : o.shape[1] // nb * m] for o in outs]
            if results is None:
                results = [[o] for o in outs]
            else:
                for lst, o in zip(results, outs, strict=True):
                    lst.append(o)
        return [np.concatenate(lst, axis=1) for lst in results]

    def _load_or_build_table(self):
        """The starting-guess table, cached on disk next to the compiled code, keyed by a
        hash of the residual system (a changed model rebuilds it)."""
        import hashlib

        from .codegen import cache_dir

        if self.effects.effects:
            # Effects at their default parameters change the steady state little, and the
            # table is only a starting guess: share the base model's table (built or loaded
            # once) instead of tabulating every combination of effects.
            base = EngineModel(self.design, compiled=self.compiled, n_threads=self.n_threads)
            self._table, self._table_dth = base._table, base._table_dth
            return
        key = hashlib.sha256(self._symbolic["residual"].serialize().encode()).hexdigest()[:16]
        path = cache_dir() / f"table_{key}.npz"
        if path.exists():
            try:
                z = np.load(path)
                self._table, self._table_dth = z["table"], z["dth"]
                return
            except (OSError, KeyError, ValueError):
                pass
        self._build_table()
        staged = path.with_suffix(f".{os.getpid()}.tmp.npz")
        np.savez(staged, table=self._table, dth=self._table_dth)
        os.replace(staged, path)

    def _build_table(self):
        """Fill the starting-guess table by continuation over (T2, PCNfR_dmd, Mach).

        Sea-level pressure is used throughout: without Reynolds effects the corrected
        operating point does not depend on pressure, and T2 enters through the gas
        properties. Each node also stores dx*/dtheta for a first-order health correction.
        """
        d = self.design
        n_t, n_p, n_m = len(_TABLE_T2), len(_TABLE_PCT), len(_TABLE_MACH)
        table = np.zeros((n_t, n_p, n_m, N_UNKNOWNS))
        i_des = int(np.argmin(np.abs(_TABLE_PCT - 100.0)))
        order = list(range(i_des, n_p)) + list(range(i_des - 1, -1, -1))
        tra_of = self._tra_from_pct
        x_node = np.array(X_DESIGN, float)
        for it2, T2 in enumerate(_TABLE_T2):
            r = self._continuation(np.array([0.0, 0.0, 100.0, T2]), x_node, np.zeros(10))
            x_node = r.x[0]
            x_prev_col = x_node
            for j, mach in enumerate(_TABLE_MACH):
                x_prev = x_prev_col
                for k, i in enumerate(order):
                    if i == i_des - 1:
                        x_prev = table[it2, i_des, j]
                    w = np.array([[0.0, mach, tra_of(_TABLE_PCT[i]), T2]])
                    r = self._newton(w, np.zeros((1, 10)), x_prev[None, :], max_iter=60)
                    if not r.converged[0]:
                        r = self._continuation(w[0], x_prev, np.zeros(10))
                    table[it2, i, j] = r.x[0]
                    x_prev = r.x[0]
                    if k == 0:
                        x_prev_col = r.x[0]
        ww = np.array([[0.0, mach, tra_of(pct), T2] for T2 in _TABLE_T2 for pct in _TABLE_PCT
                       for mach in _TABLE_MACH])
        xx = table.reshape(-1, N_UNKNOWNS)
        zz = np.zeros((len(ww), len(THETA_NAMES)))
        f = self._f_dxdth.map(len(ww), "serial")
        dxdth = np.asarray(f(xx.T, ww.T, zz.T, self._p_matrix(None, len(ww)).T))
        dxdth = dxdth.reshape(N_UNKNOWNS, len(ww), len(THETA_NAMES)).transpose(1, 0, 2)
        dxdth = dxdth.reshape(n_t, n_p, n_m, N_UNKNOWNS, len(THETA_NAMES))
        scale = d.T40_des * 1.8 / np.asarray(_TABLE_T2)[:, None, None]
        dxdth[:, :, :, 4, :] *= scale[..., None]
        table[:, :, :, 4] *= scale  # store T40/T2
        self._table = table
        self._table_dth = dxdth

    def _tra_from_pct(self, pct):
        (t0, n0), (t1, n1) = self.design.spec.tra_schedule
        return t0 + (pct - n0) * (t1 - t0) / (n1 - n0)

    def _continuation(self, w_target, x_start, theta, steps=20):
        """Walk from sea-level static (theta = 0) to ``w_target``, ``theta`` in ``steps``
        Newton solves; the result's ``iterations`` is the total over all steps."""
        w0 = np.array([0.0, 0.0, 100.0, 518.67])
        x = x_start
        total = 0
        for lam in np.linspace(0, 1, steps + 1)[1:]:
            r = self._newton((w0 + lam * (w_target - w0))[None, :], theta[None, :] * lam,
                             x[None, :], max_iter=60)
            x = r.x[0]
            total += int(r.iterations[0])
        r.iterations[0] = total
        return r

    def initial_guess(self, w: np.ndarray, theta: np.ndarray | None = None) -> np.ndarray:
        """Starting unknowns (N, 7) for operating points ``w`` (N, 4) and health ``theta``
        (N, 10): trilinear interpolation in (T2, PCNfR_dmd, Mach) of the table, plus its
        first-order theta correction (linear extrapolation in T2 outside the nodes)."""
        w = np.atleast_2d(np.asarray(w, float))
        pct = self.design.nf_demand_pct(w[:, 2])
        t2n = np.asarray(_TABLE_T2)
        coords = [
            np.clip((w[:, 3] - t2n[0]) / (t2n[1] - t2n[0]), -1.0, len(t2n) - 1 + 1.0),
            np.clip((pct - _TABLE_PCT[0]) / (_TABLE_PCT[1] - _TABLE_PCT[0]), 0,
                    len(_TABLE_PCT) - 1),
            np.clip(w[:, 1] / (_TABLE_MACH[1] - _TABLE_MACH[0]), 0, len(_TABLE_MACH) - 1),
        ]
        sizes = (len(t2n), len(_TABLE_PCT), len(_TABLE_MACH))
        idx, frac = [], []
        for c, nmax in zip(coords, sizes, strict=True):
            i = np.clip(np.floor(c).astype(int), 0, nmax - 2)
            idx.append(i)
            frac.append(c - i)
        x = np.zeros((len(w), N_UNKNOWNS))
        th = None if theta is None else np.asarray(theta, float)
        for corner in range(8):
            bits = [(corner >> k) & 1 for k in range(3)]
            wgt = np.ones(len(w))
            ii = []
            for b, i, f in zip(bits, idx, frac, strict=True):
                wgt = wgt * (f if b else 1.0 - f)
                ii.append(i + b)
            x += wgt[:, None] * self._table[ii[0], ii[1], ii[2]]
            if th is not None:
                g = self._table_dth[ii[0], ii[1], ii[2]]
                x += wgt[:, None] * np.einsum("nkt,nt->nk", g, th)
        x[:, 4] *= w[:, 3] / (self.design.T40_des * 1.8)
        return x

    # ------------------------------------------------------------------ solving
    def _newton(self, w, theta, x0, p=None, tol=1e-10, max_iter=30,
                lu: JacobianStore | None = None):
        """Solve a batch by damped Newton-chord: in compiled C across threads when the model
        is compiled (``newton_batch.c``), else in numpy (:meth:`_newton_python`); both run the
        same iteration. ``lu`` (compiled only): Jacobian factors carried between calls, one
        row per point (:class:`JacobianStore`), read and updated in place."""
        if self._newton_c is None:
            return self._newton_python(w, theta, x0, p, tol, max_iter)
        n = len(w)
        W = np.ascontiguousarray(w, float)
        TH = np.ascontiguousarray(theta, float)
        P = np.ascontiguousarray(self._p_matrix(p, n), float)
        if P.shape[1] == 0:
            P = np.zeros((n, 1))
        X = np.array(x0, float, order="C", copy=True)
        rn = np.empty(n)
        it = np.empty(n, np.int32)
        conv = np.empty(n, np.int32)
        threads = self.n_threads if n >= 64 else 1
        rc = self._newton_c(n, X.shape[1], W.shape[1], TH.shape[1], P.shape[1], W, TH, P, X,
                            rn, it, conv, float(tol), int(max_iter), _STEP_LIMIT, threads,
                            *((None, None, None) if lu is None else (lu.LU, lu.PIV, lu.HAVE)))
        if rc != 0:
            raise RuntimeError(f"batched Newton driver failed (code {rc})")
        return SolveResult(x=X, converged=conv.astype(bool), residual_norm=rn,
                           iterations=it.astype(int))

    def _newton_python(self, w, theta, x0, p=None, tol=1e-10, max_iter=30):
        """Damped Newton-chord iteration over a batch, each point with its own step control.

        A point gets a fresh exact Jacobian on its first iteration and whenever the residual
        fell by less than a factor 4 over the last chord step; otherwise the previous
        Jacobian is reused, so most iterations cost one residual evaluation. A step that
        raised the residual is halved (backtracking along the previous direction).
        """
        n = len(w)
        p = self._p_matrix(p, n)
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
        wT, thT, pT = w.T.copy(), theta.T.copy(), p.T.copy()
        for it in range(max_iter + 1):
            if active.size == 0:
                break
            r = np.empty((active.size, k))
            nj = need_j[active]
            ij, ir = active[nj], active[~nj]
            if ij.size:
                rj, Jj = self._call("resjac", x[ij].T, wT[:, ij], thT[:, ij], pT[:, ij])
                r[nj] = rj.T
                J[ij] = Jj.reshape(k, ij.size, k).transpose(1, 0, 2)
            if ir.size:
                (rr,) = self._call("residual", x[ir].T, wT[:, ir], thT[:, ir], pT[:, ir])
                r[~nj] = rr.T
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
            lim = np.min(_STEP_LIMIT / np.maximum(np.abs(dx), 1e-300), axis=1)
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

    def _p_matrix(self, p, n):
        k = len(self.param_names)
        if p is None:
            return np.tile(np.asarray(self.p_default, float), (n, 1)).reshape(n, k)
        p = np.asarray(p, float)
        return np.tile(p, (n, 1)) if p.ndim == 1 else p

    def _theta_matrix(self, theta, n):
        if theta is None:
            return np.zeros((n, len(THETA_NAMES)))
        theta = np.asarray(theta, float)
        if theta.ndim == 1:
            theta = np.tile(theta, (n, 1))
        return theta

    def solve(self, w, theta=None, p=None, x0=None, tol=1e-10, max_iter=30, check=True):
        """Solve the steady state at every row of ``w`` (N, 4): returns :class:`SolveResult`.

        ``theta`` is (10,) or (N, 10); ``x0`` (N, 7) overrides the tabulated starting guess.
        Points that fail from the table's guess are retried by continuation from the design
        point before being flagged.
        """
        w = np.atleast_2d(np.asarray(w, float))
        n = len(w)
        th = self._theta_matrix(theta, n)
        if check:
            check_w(w)
            check_theta(th)
        x0 = self.initial_guess(w, th) if x0 is None else np.asarray(x0, float)
        res = self._newton(w, th, x0, p, tol, max_iter)
        self._reject_off_map(res)
        bad = np.flatnonzero(~res.converged)
        if bad.size and bad.size <= 200:
            pm = self._p_matrix(p, n)
            for i in bad:
                r = self._continuation(w[i], np.array(X_DESIGN, float), th[i])
                r2 = self._newton(w[i:i + 1], th[i:i + 1], r.x, pm[i:i + 1], tol, max_iter)
                res.x[i], res.converged[i] = r2.x[0], r2.converged[0]
                # iterations actually spent: the failed attempt, the continuation, the polish
                res.residual_norm[i] = r2.residual_norm[0]
                res.iterations[i] += r.iterations[0] + r2.iterations[0]
            self._reject_off_map(res)
        return res

    def valid_on_maps(self, x: np.ndarray) -> np.ndarray:
        """True where every compressor operates where its map means something: the head and
        flow factors along the speed line, ``1 + s_head beta`` and ``1 - s_flow beta``, stay
        above 0.1. A root of the residual system outside that region is non-physical (e.g.
        a compressor with a negative head) and is not reported as converged."""
        d = self.design
        ok = np.ones(len(x), bool)
        for j, cmap in enumerate((d.fan, d.lpc, d.hpc)):
            b = x[:, j]
            ok &= (1.0 + cmap.s_head * b > 0.1) & (1.0 - cmap.s_flow * b > 0.1)
        return ok

    def _reject_off_map(self, res: SolveResult):
        off = res.converged & ~self.valid_on_maps(res.x)
        res.converged[off] = False

    def solve_series(self, w, theta=None, p=None, tol=1e-10, max_iter=30, chunk=64):
        """Solve a time series with warm starts, vectorised over the whole series.

        Every ``chunk``-th sample is an anchor, solved from the tabulated guess. Every other
        sample starts from its own tabulated guess corrected by the offset between the
        preceding anchor's solution and that anchor's tabulated guess: what the table misses
        (mostly the nonlinear effect of theta and of the effects' parameters, which change
        slowly along a series) is carried forward. Samples that still fail are retried from
        the previous converged sample, then by :meth:`solve`'s continuation.
        """
        w = np.atleast_2d(np.asarray(w, float))
        n = len(w)
        th = self._theta_matrix(theta, n)
        check_w(w)
        check_theta(th)
        pm = self._p_matrix(p, n)
        chunk = max(1, int(chunk))
        guess = self.initial_guess(w, th)
        anchors = np.arange(0, n, chunk)
        ra = self._newton(w[anchors], th[anchors], guess[anchors], pm[anchors], tol, max_iter)
        self._reject_off_map(ra)
        offset = np.where(ra.converged[:, None], ra.x - guess[anchors], 0.0)
        # anchors that failed pass on the offset of the last one that converged
        ok_idx = np.maximum.accumulate(np.where(ra.converged, np.arange(len(anchors)), -1))
        offset = np.where((ok_idx >= 0)[:, None], offset[np.maximum(ok_idx, 0)], 0.0)
        x0 = guess + np.repeat(offset, chunk, axis=0)[:n]
        x0[anchors] = ra.x
        out = self._newton(w, th, x0, pm, tol, max_iter)
        self._reject_off_map(out)
        out.iterations[anchors] += np.where(ra.converged, ra.iterations, 0)
        bad = np.flatnonzero(~out.converged)
        if bad.size:
            good = np.flatnonzero(out.converged)
            prev = np.searchsorted(good, bad) - 1
            has = prev >= 0
            if has.any():
                src = good[prev[has]]
                b = bad[has]
                x1 = guess[b] + (out.x[src] - guess[src])
                r = self._newton(w[b], th[b], x1, pm[b], tol, max_iter)
                self._reject_off_map(r)
                out.x[b], out.converged[b] = r.x, r.converged
                out.residual_norm[b] = r.residual_norm
                out.iterations[b] += r.iterations
            bad = np.flatnonzero(~out.converged)
            if bad.size:
                r = self.solve(w[bad], th[bad], pm[bad], tol=tol, max_iter=max_iter,
                               check=False)
                out.x[bad], out.converged[bad] = r.x, r.converged
                out.residual_norm[bad] = r.residual_norm
                out.iterations[bad] += r.iterations
        return out

    # ------------------------------------------------------------------ outputs
    def outputs_at(self, x, w, theta=None, p=None) -> np.ndarray:
        """All outputs (N, len(OUTPUT_NAMES)) at given unknowns (no solve)."""
        w = np.atleast_2d(np.asarray(w, float))
        n = len(w)
        th = self._theta_matrix(theta, n)
        (y,) = self._call("outputs", np.asarray(x, float).T, w.T, th.T, self._p_matrix(p, n).T)
        return y.T

    def residuals_at(self, x, w, theta=None, p=None) -> np.ndarray:
        w = np.atleast_2d(np.asarray(w, float))
        n = len(w)
        th = self._theta_matrix(theta, n)
        (r,) = self._call("residual", np.asarray(x, float).T, w.T, th.T, self._p_matrix(p, n).T)
        return r.T

    def evaluate(self, data, theta=None, p=None, x0=None) -> pd.DataFrame:
        """Evaluate ``F(w, theta)`` on a DataFrame (columns alt, Mach, TRA, T2 and optionally
        the theta columns) or an (N, 4) array. Returns a DataFrame with every output channel
        in N-CMAPSS units plus ``converged``, ``residual_norm`` and ``iterations``; outputs of
        points that did not converge are NaN."""
        w, th, index = self._unpack(data, theta)
        res = self.solve(w, th, p, x0=x0)
        y = self.outputs_at(res.x, w, th, p)
        y[~res.converged] = np.nan
        df = pd.DataFrame(y, columns=list(OUTPUT_NAMES), index=index)
        df["converged"] = res.converged
        df["residual_norm"] = res.residual_norm
        df["iterations"] = res.iterations
        return df

    def _unpack(self, data, theta):
        if isinstance(data, pd.DataFrame):
            check_columns(data.columns, W_NAMES, "operating points")
            index = data.index
            w = data[list(W_NAMES)].to_numpy(float)
            th_cols = [c for c in THETA_NAMES if c in data.columns]
            if theta is None and th_cols:
                th = np.zeros((len(data), len(THETA_NAMES)))
                for c in th_cols:
                    th[:, THETA_NAMES.index(c)] = data[c].to_numpy(float)
                theta = th
            check_w(w, np.asarray(index), "operating points")
        else:
            w = np.atleast_2d(np.asarray(data, float))
            if w.shape[1] != len(W_NAMES):
                raise InputError(f"operating points: expected {len(W_NAMES)} columns "
                                 f"({', '.join(W_NAMES)}), got {w.shape[1]}")
            index = pd.RangeIndex(len(w))
        th = self._theta_matrix(theta, len(w))
        if th.shape != (len(w), len(THETA_NAMES)):
            raise InputError(f"theta: expected shape (N, {len(THETA_NAMES)}), got {th.shape}")
        check_theta(th, np.asarray(index), "health parameters")
        return w, th, index

    def sensitivities(self, data, theta=None, p=None, x=None):
        """Exact sensitivities at the steady state of each point.

        Returns ``(dy_dtheta, dy_dw)`` as arrays (N, n_outputs, 10) and (N, n_outputs, 4), rows
        in :data:`channels.OUTPUT_NAMES` order, derivatives per unit of theta (fraction) and of
        w (ft, -, %, degR).
        """
        w, th, _ = self._unpack(data, theta)
        if x is None:
            res = self.solve(w, th, p)
            if not res.converged.all():
                i = int(np.flatnonzero(~res.converged)[0])
                raise InputError(f"steady state did not converge at row {i}; no sensitivities")
            x = res.x
        dth, dw = self._call("sens", x.T, w.T, th.T, self._p_matrix(p, len(w)).T)
        n_out = len(OUTPUT_NAMES)
        dth = dth.T.reshape(len(w), len(THETA_NAMES), n_out).transpose(0, 2, 1)
        dw = dw.T.reshape(len(w), len(W_NAMES), n_out).transpose(0, 2, 1)
        return dth, dw

    def point(self, alt, Mach, TRA, T2=None, dT_isa=0.0, theta=None) -> pd.Series:
        """One operating point; ``T2`` [degR] defaults to ISA + ``dT_isa`` [K] at alt, Mach."""
        if T2 is None:
            T2 = float(atmosphere.t2_from_flight(alt, Mach, dT_isa)) * 1.8
        th = np.zeros(len(THETA_NAMES))
        for k, v in (theta or {}).items():
            if k not in THETA_NAMES:
                raise InputError(f"unknown health parameter {k!r}; one of {', '.join(THETA_NAMES)}")
            th[THETA_NAMES.index(k)] = v
        df = self.evaluate(np.array([[alt, Mach, TRA, T2]]), theta=th)
        s = df.iloc[0]
        s["T2"] = T2
        return s

    # ------------------------------------------------------------------ symbolic access
    def residual_system(self) -> ResidualSystem:
        return ResidualSystem(UNKNOWN_NAMES, OUTPUT_NAMES, self.param_names,
                              np.array(X_DESIGN, float), self._symbolic["residual"],
                              self._symbolic["outputs"], self.initial_guess)

    def casadi_function(self) -> ca.Function:
        """``F(w, theta, p) -> y``: the steady state as one CasADi Function (implicit solve by
        a Newton rootfinder, exact derivatives), for use inside an optimisation. Starting
        point of the rootfinder: the design unknowns."""
        x, w, th, p = (self._sym[k] for k in ("x", "w", "theta", "p"))
        g = ca.Function("g", [x, ca.vertcat(w, th, p)], [self._sym["res"]])
        rf = ca.rootfinder("hyprog_steady", "newton", g, {"abstol": 1e-11, "max_iter": 50,
                                                            "error_on_fail": False})
        ww = ca.MX.sym("w", w.numel())
        tt = ca.MX.sym("theta", th.numel())
        pp = ca.MX.sym("p", p.numel())
        xs = rf(ca.DM(X_DESIGN), ca.vertcat(ww, tt, pp))
        y = self._symbolic["outputs"](xs, ww, tt, pp)
        return ca.Function("hyprog_F", [ww, tt, pp], [y], ["w", "theta", "p"], ["y"])
