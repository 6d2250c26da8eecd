"""The engine model as a user sees it: ``F(w, theta, p) -> (x_s, x_v)`` on batches.

>>> from engine_model import EngineModel
>>> m = EngineModel()                       # builds, compiles (cached on disk) and tabulates
>>> df = m.evaluate(pd.DataFrame({"alt": [0], "Mach": [0], "TRA": [100], "T2": [518.67]}))
>>> df[["T30", "Wf", "converged"]]

Steady state. The cycle of :mod:`turbofan` is a residual system ``r(x; w, theta, p) = 0`` in
eight unknowns ``x`` (:data:`turbofan.UNKNOWN_NAMES`); ``p`` are the parameters of the optional
effects (:mod:`effects`), a first-class input next to ``theta`` everywhere. A batch of points
is solved by the damped Newton-chord iteration of :mod:`newton_driver` with the exact Jacobian
``dr/dx`` (CasADi AD): compiled to C with the residual functions and run over the batch on
OpenMP threads (``newton_batch.c``), or in numpy when the model is not compiled. A point that
does not converge is returned with ``converged = False`` and NaN outputs, never as a valid
number; a root outside the compressor maps' valid region (:meth:`EngineModel.valid_on_maps`)
is not converged either.

Retry (:meth:`EngineModel.solve_from`, the one place it is written): a point that failed from
its given start is solved again from the tabulated starting guess, then by continuation from
the design point (sea-level static, new engine) to its own ``w`` and ``theta``.

Starting guesses come from :class:`guess_table.GuessTable` (demanded corrected fan speed,
Mach, T2); a time series can instead be warm-started sample to sample
(:meth:`EngineModel.solve_series`).

Outputs, residuals and the exact sensitivities ``d(outputs)/d(theta, w, p)`` (implicit function
theorem, :mod:`interface`) are evaluated at given unknowns by CasADi Functions compiled to C
and mapped over the batch (:mod:`batch_eval`). :class:`EngineModel` satisfies
:class:`interface.SymbolicSteadyStateModel`, the interface every estimator uses.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
import pandas as pd

from engine_model.channels import OUTPUT_NAMES, THETA_NAMES, W_NAMES
from engine_model.physics import atmosphere
from engine_model.physics.design import EngineDesign, design_engine
from engine_model.physics.effects import EffectSet
from engine_model.physics.turbofan import (
    N_UNKNOWNS,
    UNKNOWN_NAMES,
    X_DESIGN,
    cycle,
    imperial_outputs,
)
from engine_model.units import T_STD_R, k_to_r
from engine_model.validation import InputError, check_columns, check_theta, check_w

from .batch_eval import BatchEvaluator
from .codegen import KeyedLibrary, cache_dir, compile_keyed_all
from .guess_table import GuessTable
from .interface import Sensitivities
from .newton_driver import CompiledNewton, JacobianStore, SolveResult, newton_chord_numpy

N_THETA = len(THETA_NAMES)
N_W = len(W_NAMES)
CONTINUATION_STEPS = 20
MAX_CONTINUATION_POINTS = 200  # per call; more failures than this are reported as they are
# CasADi's ``ad_weight``: 0 differentiates by forward mode, 1 by reverse mode
AD_WEIGHT = {"forward": 0.0, "reverse": 1.0}


def ad_options(mode: str) -> dict:
    """The options of ``casadi.jacobian`` that differentiate by ``mode``: ``"forward"`` (one
    tangent sweep per input) or ``"reverse"`` (one adjoint sweep per output); another mode
    is a ValueError."""
    if mode not in AD_WEIGHT:
        raise ValueError(f"mode {mode!r}: expected one of {', '.join(AD_WEIGHT)}")
    return {"helper_options": {"ad_weight": AD_WEIGHT[mode]}}


@dataclass(frozen=True)
class ResidualSystem:
    """The steady state as equations, for optimisers that solve many points at once.

    ``residual(x, w, theta, p)`` (8 scaled residuals) and ``outputs(x, w, theta, p)`` (every
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
    guess: object  # callable (w (N,4)) -> x0 (N,8)


def _sens_outputs(outputs) -> tuple[str, ...]:
    """``EngineModel(sens_outputs=...)`` checked, in :data:`channels.OUTPUT_NAMES` order (one
    set of outputs is one compiled library, whatever order it was given in)."""
    if outputs is None:
        return OUTPUT_NAMES
    outputs = (outputs,) if isinstance(outputs, str) else tuple(outputs)
    unknown = [c for c in outputs if c not in OUTPUT_NAMES]
    if unknown:
        raise InputError(f"sens_outputs: {', '.join(unknown)} not outputs of the model")
    if not outputs or len(set(outputs)) != len(outputs):
        raise InputError(f"sens_outputs {', '.join(outputs) or '(none)'}: expected distinct "
                         "outputs, at least one")
    return tuple(c for c in OUTPUT_NAMES if c in outputs)


class _LazyFunctions(dict):
    """Functions by name; a missing one among the derived functions (``resjac``, ``sens``,
    ``dxdth``) is taken from ``derive(key)`` (which builds it, and what is built with it,
    once) on first use."""

    def __init__(self, derive, **functions):
        super().__init__(functions)
        self._derive = derive

    def __missing__(self, key):
        derived = self._derive(key)
        if key not in derived:
            raise KeyError(key)
        self[key] = derived[key]
        return self[key]


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
        machine evaluates the same expression graph and the Newton iteration runs in numpy.
    n_threads : int, optional
        Threads for batch evaluation (default: all cores).
    """

    unknown_names = UNKNOWN_NAMES
    output_names = OUTPUT_NAMES

    def __init__(self, design: EngineDesign | None = None, effects=(), compiled: bool = True,
                 n_threads: int | None = None, sens_outputs=None):
        self.design = design or design_engine()
        self.effects = EffectSet(effects)
        self.compiled = compiled
        self.sens_outputs = _sens_outputs(sens_outputs)
        self.n_threads = max(1, n_threads or os.cpu_count() or 1)
        self.param_names = self.effects.param_names
        self.p_default = self.effects.defaults
        self._build()
        self._guess = self._load_or_build_table()

    @property
    def n_unknowns(self) -> int:
        return N_UNKNOWNS

    @property
    def variant_key(self) -> str:
        return self.effects.key

    # ------------------------------------------------------------------ construction
    def _build(self):
        """The residual system and its outputs as CasADi Functions, and the compiled code.

        The derived functions (the Newton Jacobian, the exact sensitivities, dx*/dtheta) are
        built only when needed (:meth:`_derived`): building the sensitivities' graph takes
        about 1 s, half of a model's start-up, and a compiled model whose libraries are in the
        cache never needs them. The libraries are looked up by a key of what they are derived
        from (:meth:`_library_key`) instead of the hash of their generated C."""
        x = ca.SX.sym("x", N_UNKNOWNS)
        w = ca.SX.sym("w", N_W)
        th = ca.SX.sym("theta", N_THETA)
        p = ca.SX.sym("p", len(self.param_names))
        hook = self.effects.hook(p, w)
        res, st = cycle(self.design, w, th, x, hook)
        out = imperial_outputs(st, hook)
        y = ca.vertcat(*[out[k] for k in OUTPUT_NAMES])
        self.stations_expr = st
        # common subexpressions (the gas-property polynomials of one temperature, used by
        # several stations) are evaluated once in the generated code
        f_res = ca.Function("hyprog_residual", [x, w, th, p], [res], {"cse": True})
        f_out = ca.Function("hyprog_outputs", [x, w, th, p], [y], {"cse": True})
        self._sym = dict(x=x, w=w, theta=th, p=p, res=res, y=y)
        self._derived_functions: dict[str, ca.Function] = {}
        self._symbolic = _LazyFunctions(self._derived, residual=f_res, outputs=f_out)
        self._residual_serialized = f_res.serialize()
        if self.compiled:
            tag = self.effects.key
            if len(tag) > 80:  # a file name has at most 255 bytes: a long variant is hashed
                tag = "v" + hashlib.sha256(tag.encode()).hexdigest()[:16]
            name = "hyprog_engine" + (("_" + tag) if tag else "")
            key = self._library_key(f_out)
            # the sensitivities of some outputs only: another sensitivity library, the same
            # hot and output ones
            sens_key = key if self.sens_outputs == OUTPUT_NAMES else hashlib.sha256(
                "\0".join((key, *self.sens_outputs)).encode()).hexdigest()
            sym = self._symbolic
            # three libraries, whose compilers run side by side (compile_keyed_all): the
            # solver's inner loop at -O3; the outputs, which every filter step evaluates at
            # its sigma points, at -O1; the sensitivities (2.8 MB of C for the base model)
            # at -Og, a third less compiler time than -O1 for the same numbers at the same
            # speed, which every new variant pays (benchmarks/results/engine_cold_library_og.md)
            hot, out, sens = compile_keyed_all([
                KeyedLibrary(name + "_hot", key, ("hyprog_residual", "hyprog_resjac"),
                             lambda: [sym["residual"], sym["resjac"]], opt="-O3",
                             extra_sources=(str(Path(__file__).with_name("newton_batch.c")),),
                             extra_flags=("-DRES_FN=hyprog_residual",
                                          "-DRESJAC_FN=hyprog_resjac"),
                             optional_flags=("-fopenmp",)),
                KeyedLibrary(name + "_out", key, ("hyprog_outputs",),
                             lambda: [sym["outputs"]], opt="-O1"),
                KeyedLibrary(name + "_sens", sens_key, ("hyprog_sensitivities",),
                             lambda: [sym["sens"]], opt="-Og")])
            self._newton_c = CompiledNewton(hot["__library__"])
            fns = _LazyFunctions(self._derived, residual=hot["hyprog_residual"],
                                 resjac=hot["hyprog_resjac"], outputs=out["hyprog_outputs"],
                                 sens=sens["hyprog_sensitivities"])
        else:
            fns = self._symbolic
            self._newton_c = None
        self._eval = BatchEvaluator(fns, self.n_threads)

    def _library_key(self, f_out: ca.Function) -> str:
        """What the compiled code is generated from: the residual and output Functions
        (serialised: the physics and the effects), the CasADi version, and the source of this
        module (how the derived functions are built) and of the code generator."""
        from . import codegen

        parts = [self._residual_serialized, f_out.serialize(), ca.__version__,
                 Path(__file__).read_text(), Path(codegen.__file__).read_text()]
        return hashlib.sha256("\0".join(parts).encode()).hexdigest()

    def _derived(self, key: str) -> dict[str, ca.Function]:
        """The functions derived from the residual system, each built on first use: the
        Newton Jacobian ``resjac`` (0.2 s), the exact sensitivities ``sens``
        (:meth:`sensitivity_function`, about 2 s of graph work) and ``dx*/dtheta`` ``dxdth``
        (for tabulating starting guesses). A model evaluated by CasADi's virtual machine
        solves and reads outputs without ever building the last two."""
        derived = self._derived_functions
        if key in derived or key not in ("resjac", "sens", "dxdth"):
            return derived
        x, w, th, p, res = (self._sym[k] for k in ("x", "w", "theta", "p", "res"))
        J = self._newton_jacobian()
        if key == "resjac":
            derived["resjac"] = ca.Function("hyprog_resjac", [x, w, th, p], [res, J],
                                            {"cse": True})
        elif key == "sens":
            derived["sens"] = self.sensitivity_function()
        else:  # forward mode, as the cached starting-guess tables were built
            derived["dxdth"] = ca.Function("hyprog_dxdth", [x, w, th, p],
                                           [-ca.solve(J, ca.jacobian(res, th))])
        return derived

    def _newton_jacobian(self):
        """``dr/dx`` (8 x 8, dense), built once: by reverse mode (one adjoint sweep per
        residual), 17 % fewer instructions than CasADi's default forward mode here, the same
        numbers."""
        if "J" not in self._sym:
            self._sym["J"] = ca.densify(ca.jacobian(self._sym["res"], self._sym["x"],
                                                    ad_options("reverse")))
        return self._sym["J"]

    def sensitivity_function(self, mode: str = "reverse") -> ca.Function:
        """The exact sensitivities of the outputs :attr:`sens_outputs` by the implicit
        function theorem (module docstring) as a CasADi Function of ``(x, w, theta, p)``:
        ``dy/dtheta - dy/dx J^-1 dr/dtheta``, likewise in ``w`` and ``p``.

        ``mode``: how CasADi differentiates, ``"reverse"`` (one adjoint sweep per residual or
        output; what the model compiles and evaluates) or ``"forward"`` (one tangent sweep per
        input; what it did until 2026-11-29, kept to compare). The same numbers to 2e-15 of
        each block's (theta, w, p) largest magnitude; reverse takes 7 % fewer instructions
        for the base model (36 outputs of 14 inputs), 43 % fewer with the discovery loop's
        29 effect parameters and 70 % fewer for the adaptation's model (42 parameters, 7
        channels) (``benchmarks/sensitivities_ad.py``)."""
        how = ad_options(mode)
        J = self._newton_jacobian()
        x, w, th, p, res, y = (self._sym[k] for k in ("x", "w", "theta", "p", "res", "y"))
        if self.sens_outputs != OUTPUT_NAMES:
            y = y[[OUTPUT_NAMES.index(c) for c in self.sens_outputs]]
        n_th, n_w = th.numel(), w.numel()
        Jinv_r = ca.solve(J, ca.horzcat(ca.jacobian(res, th, how), ca.jacobian(res, w, how),
                                        ca.jacobian(res, p, how)))
        dy_dx = ca.jacobian(y, x, how)
        out = [ca.jacobian(y, th, how) - dy_dx @ Jinv_r[:, :n_th],
               ca.jacobian(y, w, how) - dy_dx @ Jinv_r[:, n_th:n_th + n_w]]
        if p.numel():
            out.append(ca.jacobian(y, p, how) - dy_dx @ Jinv_r[:, n_th + n_w:])
        return ca.Function("hyprog_sensitivities", [x, w, th, p], out, {"cse": True})

    def _load_or_build_table(self) -> GuessTable:
        """The starting-guess table, cached on disk next to the compiled code."""
        if self.effects.effects:
            # Effects at their default parameters change the steady state little, and the
            # table is only a starting guess: share the base model's table (built or loaded
            # once) instead of tabulating every combination of effects.
            return EngineModel(self.design, compiled=self.compiled,
                               n_threads=self.n_threads)._guess
        key = GuessTable.cache_key(self._residual_serialized)
        return GuessTable.load_or_build(cache_dir() / f"table_{key}.npz", self._build_table,
                                        self.design.T40_des, self.design.nf_demand_pct,
                                        self.design.spec.throttle.alt_flight_weight)

    def _build_table(self) -> GuessTable:
        return GuessTable.build(
            solve_from=lambda w, th, x0, max_iter: self.solve_from(
                w, th, x0, max_iter=max_iter, retry=False),
            continuation=self._continuation, dx_dtheta=self._dx_dtheta,
            tra_from_pct=self.design.tra_from_pct, n_theta=N_THETA,
            t40_des_k=self.design.T40_des, nf_demand_pct=self.design.nf_demand_pct,
            x_design=np.array(X_DESIGN, float),
            flight_weight=self.design.spec.throttle.alt_flight_weight)

    def _dx_dtheta(self, x, w, theta) -> np.ndarray:
        n = len(x)
        (d,) = self._eval("dxdth", x.T, w.T, theta.T, self.p_matrix(None, n).T)
        return d.T.reshape(n, N_THETA, N_UNKNOWNS).transpose(0, 2, 1)

    def _continuation(self, w_target, x_start, theta, steps=CONTINUATION_STEPS) -> SolveResult:
        """Walk from sea-level static (theta = 0) to ``w_target``, ``theta`` in ``steps``
        Newton solves: one point (``w_target`` (4,)) or a batch ((k, 4), each on its own path,
        solved together); the result's ``iterations`` is the total over all steps."""
        w_t = np.atleast_2d(np.asarray(w_target, float))
        th = np.atleast_2d(np.asarray(theta, float))
        x = np.broadcast_to(np.asarray(x_start, float), (len(w_t), N_UNKNOWNS)).copy()
        w0 = np.array([0.0, 0.0, 100.0, T_STD_R])
        total = np.zeros(len(w_t), int)
        for lam in np.linspace(0, 1, steps + 1)[1:]:
            r = self._newton(w0 + lam * (w_t - w0), th * lam, x, None, 1e-10, 60)
            x = r.x
            total += r.iterations
        r.iterations = total
        return r

    # ------------------------------------------------------------------ arguments
    def p_matrix(self, p, n: int) -> np.ndarray:
        """Effect parameters as an (n, n_p) matrix: the defaults where ``p`` is None, a (n_p,)
        vector repeated, or an (n, n_p) matrix as it is."""
        k = len(self.param_names)
        if p is None:
            return np.tile(np.asarray(self.p_default, float), (n, 1)).reshape(n, k)
        p = np.asarray(p, float)
        if p.shape not in ((k,), (n, k)):  # a wrong stride would read past the array in C
            raise InputError(f"effect parameters p: shape {p.shape}, expected ({k},) or "
                             f"({n}, {k}) for this model's {k} parameter(s)")
        return np.tile(p, (n, 1)) if p.ndim == 1 else p

    @staticmethod
    def theta_matrix(theta, n: int) -> np.ndarray:
        """Health parameters as an (n, 10) matrix (zeros where ``theta`` is None)."""
        if theta is None:
            return np.zeros((n, N_THETA))
        theta = np.asarray(theta, float)
        if theta.shape not in ((N_THETA,), (n, N_THETA)):
            raise InputError(f"health parameters theta: shape {theta.shape}, expected "
                             f"({N_THETA},) or ({n}, {N_THETA})")
        return np.tile(theta, (n, 1)) if theta.ndim == 1 else theta

    def initial_guess(self, w: np.ndarray, theta: np.ndarray | None = None) -> np.ndarray:
        """Starting unknowns (N, 8) for operating points ``w`` (N, 4) and health ``theta``
        (N, 10): the tabulated guess with its first-order theta correction."""
        return self._guess(w, theta)

    def jacobian_store(self, n: int) -> JacobianStore | None:
        """Jacobian factors of ``n`` points to carry between :meth:`solve_from` calls (the
        compiled driver only; None for an interpreted model)."""
        return JacobianStore.empty(n, N_UNKNOWNS) if self._newton_c is not None else None

    # ------------------------------------------------------------------ solving
    def _newton(self, w, theta, x0, p, tol, max_iter, lu=None, backend="auto") -> SolveResult:
        """One Newton-chord run over a batch (:mod:`newton_driver`), no validity check."""
        pm = self.p_matrix(p, len(w))
        if backend == "auto":
            backend = "c" if self._newton_c is not None else "numpy"
        if backend == "c":
            if self._newton_c is None:
                raise InputError("the compiled Newton driver needs EngineModel(compiled=True)")
            threads = self.n_threads if len(w) >= 64 else 1
            return self._newton_c(w, theta, pm, x0, tol, max_iter, threads, lu)
        if backend != "numpy":
            raise InputError(f"Newton backend {backend!r}: one of auto, c, numpy")

        def resjac(x, w_, th, p_):
            n = len(x)
            r, J = self._eval("resjac", x.T, w_.T, th.T, p_.T)
            return r.T, J.reshape(N_UNKNOWNS, n, N_UNKNOWNS).transpose(1, 0, 2)

        def residual(x, w_, th, p_):
            (r,) = self._eval("residual", x.T, w_.T, th.T, p_.T)
            return r.T

        return newton_chord_numpy(resjac, residual, np.asarray(w, float),
                                  np.asarray(theta, float), pm, x0, tol, max_iter)

    def solve_from(self, w, theta, x0, p=None, tol: float = 1e-10, max_iter: int = 30,
                   lu: JacobianStore | None = None, retry: bool = True,
                   backend: str = "auto") -> SolveResult:
        """Newton from the given unknowns ``x0`` (N, 8) at ``w`` (N, 4), ``theta`` (N, 10)
        and ``p``; ``lu`` carries each point's Jacobian factors between calls (compiled driver
        only, read and updated in place). Roots off the maps are not converged. With
        ``retry``, failed points are solved again from the tabulated guess and then by
        continuation (module docstring); ``iterations`` counts every attempt. ``backend``
        ``"c"`` or ``"numpy"`` picks the Newton implementation (default: C when compiled)."""
        w = np.atleast_2d(np.asarray(w, float))
        th = self.theta_matrix(theta, len(w))
        res = self._newton(w, th, x0, p, tol, max_iter, lu, backend)
        self._reject_off_map(res)
        if retry:
            self._retry(res, w, th, p, tol, max_iter, from_table=True)
        return res

    def _retry(self, res: SolveResult, w, th, p, tol, max_iter, from_table: bool):
        bad = np.flatnonzero(~res.converged)
        if bad.size and from_table:
            pm = self.p_matrix(p, len(w))
            r = self._newton(w[bad], th[bad], self.initial_guess(w[bad], th[bad]), pm[bad],
                             tol, max_iter)
            self._reject_off_map(r)
            res.put(bad, r)
            bad = bad[~r.converged]
        if bad.size and bad.size <= MAX_CONTINUATION_POINTS:
            pm = self.p_matrix(p, len(w))
            r = self._continuation(w[bad], np.array(X_DESIGN, float), th[bad])
            r2 = self._newton(w[bad], th[bad], r.x, pm[bad], tol, max_iter)
            self._reject_off_map(r2)
            # iterations actually spent: the failed attempts, the continuation, the polish
            r2.iterations = r2.iterations + r.iterations
            res.put(bad, r2)

    def solve(self, w, theta=None, p=None, x0=None, tol=1e-10, max_iter=30,
              check=True) -> SolveResult:
        """Solve the steady state at every row of ``w`` (N, 4): returns :class:`SolveResult`.

        ``theta`` is (10,) or (N, 10); ``x0`` (N, 8) overrides the tabulated starting guess.
        Points that fail are retried by continuation from the design point before being
        flagged (a retry from the tabulated guess would repeat the first attempt).
        """
        w = np.atleast_2d(np.asarray(w, float))
        th = self.theta_matrix(theta, len(w))
        if check:
            check_w(w)
            check_theta(th)
        x0 = self.initial_guess(w, th) if x0 is None else np.asarray(x0, float)
        res = self.solve_from(w, th, x0, p, tol, max_iter, retry=False)
        self._retry(res, w, th, p, tol, max_iter, from_table=False)
        return res

    def valid_on_maps(self, x: np.ndarray) -> np.ndarray:
        """True where every compressor operates where its map means something
        (:meth:`maps.CompressorMap.on_map`: from deep choke to just past the surge line). A
        root of the residual system outside that region is non-physical and is not reported
        as converged."""
        d = self.design
        ok = np.ones(len(x), bool)
        for j, cmap in enumerate((d.fan, d.lpc, d.hpc)):
            ok &= cmap.on_map(x[:, j])
        return ok

    def _reject_off_map(self, res: SolveResult):
        off = res.converged & ~self.valid_on_maps(res.x)
        res.converged[off] = False

    def solve_series(self, w, theta=None, p=None, tol=1e-10, max_iter=30, chunk=64,
                     starts=None):
        """Solve a time series with warm starts, vectorised over the whole series.

        Every ``chunk``-th sample is an anchor, solved from the tabulated guess. Every other
        sample starts from its own tabulated guess corrected by the offset between the
        preceding anchor's solution and that anchor's tabulated guess: what the table misses
        (mostly the nonlinear effect of theta and of the effects' parameters, which change
        slowly along a series) is carried forward. Samples that still fail are retried from
        the previous converged sample, then as :meth:`solve` retries.

        ``starts`` (S,), the first rows of several independent series stacked in ``w`` (the
        first 0; default one series): each is solved exactly as by a call of its own (its
        anchors count from its first row, nothing is carried across a series boundary, the
        last retry is one :meth:`solve` per series), but all share the batched Newton calls,
        so many short series (a fleet's units) cost one call instead of one each.
        """
        w = np.atleast_2d(np.asarray(w, float))
        n = len(w)
        th = self.theta_matrix(theta, n)
        check_w(w)
        check_theta(th)
        pm = self.p_matrix(p, n)
        chunk = max(1, int(chunk))
        starts = np.zeros(1, int) if starts is None else np.asarray(starts, int)
        if starts.size == 0 or starts[0] != 0 or np.any(np.diff(starts) <= 0) or starts[-1] >= n:
            raise InputError(f"solve_series: starts must rise from 0 below {n}, got {starts}")
        series = np.searchsorted(starts, np.arange(n), side="right") - 1  # series of each row
        is_anchor = (np.arange(n) - starts[series]) % chunk == 0
        anchors = np.flatnonzero(is_anchor)
        guess = self.initial_guess(w, th)
        ra = self.solve_from(w[anchors], th[anchors], guess[anchors], pm[anchors], tol,
                             max_iter, retry=False)
        offset = np.where(ra.converged[:, None], ra.x - guess[anchors], 0.0)
        # anchors that failed pass on the offset of the last one of their series that converged
        ok_idx = np.maximum.accumulate(np.where(ra.converged, np.arange(len(anchors)), -1))
        first_anchor = np.searchsorted(anchors, starts)[series[anchors]]
        offset = np.where((ok_idx >= first_anchor)[:, None], offset[np.maximum(ok_idx, 0)], 0.0)
        x0 = guess + offset[np.cumsum(is_anchor) - 1]
        x0[anchors] = ra.x
        out = self.solve_from(w, th, x0, pm, tol, max_iter, retry=False)
        out.iterations[anchors] += np.where(ra.converged, ra.iterations, 0)
        bad = np.flatnonzero(~out.converged)
        if bad.size:
            good = np.flatnonzero(out.converged)
            prev = np.searchsorted(good, bad) - 1
            has = prev >= 0
            has[has] = series[good[prev[has]]] == series[bad[has]]
            if has.any():
                src = good[prev[has]]
                b = bad[has]
                x1 = guess[b] + (out.x[src] - guess[src])
                out.put(b, self.solve_from(w[b], th[b], x1, pm[b], tol, max_iter, retry=False))
            bad = np.flatnonzero(~out.converged)
            for s in np.unique(series[bad]):  # continuation is capped per call: one per series
                b = bad[series[bad] == s]
                out.put(b, self.solve(w[b], th[b], pm[b], tol=tol, max_iter=max_iter,
                                      check=False))
        return out

    # ------------------------------------------------------------------ at given unknowns
    def _columns(self, x, w, theta, p):
        w = np.atleast_2d(np.asarray(w, float))
        n = len(w)
        return (np.asarray(x, float).T, w.T, self.theta_matrix(theta, n).T,
                self.p_matrix(p, n).T)

    def outputs_at(self, x, w, theta=None, p=None) -> np.ndarray:
        """All outputs (N, len(OUTPUT_NAMES)) at given unknowns (no solve)."""
        (y,) = self._eval("outputs", *self._columns(x, w, theta, p))
        return y.T

    def residuals_at(self, x, w, theta=None, p=None) -> np.ndarray:
        """The scaled residuals (N, N_UNKNOWNS), one per unknown, at given unknowns."""
        (r,) = self._eval("residual", *self._columns(x, w, theta, p))
        return r.T

    def sensitivities_at(self, x, w, theta=None, p=None) -> Sensitivities:
        """Exact ``dy/dtheta`` (N, n_out, 10), ``dy/dw`` (N, n_out, 4) and ``dy/dp`` (N, n_out,
        n_p) at converged unknowns ``x`` (rows in :data:`channels.OUTPUT_NAMES` order; NaN in
        the rows of outputs outside :attr:`sens_outputs`)."""
        s = self.sensitivities_of(x, w, theta, p, self.sens_outputs)
        if self.sens_outputs == OUTPUT_NAMES:
            return s
        rows = [OUTPUT_NAMES.index(c) for c in self.sens_outputs]

        def full(a):
            out = np.full((a.shape[0], len(OUTPUT_NAMES), a.shape[2]), np.nan)
            out[:, rows] = a
            return out

        return Sensitivities(theta=full(s.theta), w=full(s.w), p=full(s.p))

    def sensitivities_of(self, x, w, theta, p, outputs) -> Sensitivities:
        """:meth:`sensitivities_at` of the outputs ``outputs`` only, rows in that order. A
        model built with ``sens_outputs`` computes no others (the adaptation's model: its
        fitted channels, whose sensitivities take 57 % of the instructions of every
        output's for seven of them); asking for another output is an error."""
        missing = [c for c in outputs if c not in self.sens_outputs]
        if missing:
            raise InputError(f"the model computes no sensitivities of {', '.join(missing)} "
                             f"(built for {', '.join(self.sens_outputs)})")
        cols = self._columns(x, w, theta, p)
        n, n_out, n_p = cols[0].shape[1], len(self.sens_outputs), len(self.param_names)
        outs = self._eval("sens", *cols)
        rows = [self.sens_outputs.index(c) for c in outputs]
        every = rows == list(range(n_out))

        def per_point(a, k):
            a = a.T.reshape(n, k, n_out).transpose(0, 2, 1)
            return a if every else a[:, rows]

        dp = per_point(outs[2], n_p) if n_p else np.zeros((n, len(rows), 0))
        return Sensitivities(theta=per_point(outs[0], N_THETA), w=per_point(outs[1], N_W), p=dp)

    # ------------------------------------------------------------------ DataFrame API
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
                th = np.zeros((len(data), N_THETA))
                for c in th_cols:
                    th[:, THETA_NAMES.index(c)] = data[c].to_numpy(float)
                theta = th
            check_w(w, np.asarray(index), "operating points")
        else:
            w = np.atleast_2d(np.asarray(data, float))
            if w.shape[1] != N_W:
                raise InputError(f"operating points: expected {N_W} columns "
                                 f"({', '.join(W_NAMES)}), got {w.shape[1]}")
            index = pd.RangeIndex(len(w))
        th = self.theta_matrix(theta, len(w))
        if th.shape != (len(w), N_THETA):
            raise InputError(f"theta: expected shape (N, {N_THETA}), got {th.shape}")
        check_theta(th, np.asarray(index), "health parameters")
        return w, th, index

    def sensitivities(self, data, theta=None, p=None, x=None):
        """Exact sensitivities at the steady state of each point of ``data`` (solved unless
        the unknowns ``x`` are given): ``(dy_dtheta, dy_dw)`` as arrays (N, n_out, 10) and
        (N, n_out, 4), rows in :data:`channels.OUTPUT_NAMES` order (:meth:`sensitivities_at`
        also gives ``dy/dp``)."""
        w, th, _ = self._unpack(data, theta)
        if x is None:
            res = self.solve(w, th, p)
            if not res.converged.all():
                i = int(np.flatnonzero(~res.converged)[0])
                raise InputError(f"steady state did not converge at row {i}; no sensitivities")
            x = res.x
        s = self.sensitivities_at(x, w, th, p)
        return s.theta, s.w

    def point(self, alt, Mach, TRA, T2=None, dT_isa=0.0, theta=None) -> pd.Series:
        """One operating point; ``T2`` [degR] defaults to ISA + ``dT_isa`` [K] at alt, Mach."""
        if T2 is None:
            T2 = float(k_to_r(atmosphere.t2_from_flight(alt, Mach, dT_isa)))
        th = np.zeros(N_THETA)
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
        point of the rootfinder: the design unknowns, so it converges near the design point
        (take-off and climb power) only. Far from it (ground idle, part power at altitude)
        the plain Newton iteration does not converge and the Function returns its last
        iterate, wrong or NaN, without an error (CasADi's rootfinder reports no failure
        through a Function's outputs): check the residual of ``residual_system`` there, or
        use :meth:`solve`, which has the tabulated starting guess and the continuation."""
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
