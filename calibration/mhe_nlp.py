"""The windowed MAP problem as an IPOPT nonlinear program, built once per window length.

One window holds ``N`` consecutive samples ``k = 1..N`` of one unit. Decision variables are the
model's eight internal unknowns ``x_k`` (:data:`engine_model.physics.turbofan.UNKNOWN_NAMES`) at
every sample and the estimated health parameters, either one ``theta`` for the window
(``mode="constant"``) or one ``theta_k`` per sample (``mode="random_walk"``). The problem
(simultaneous formulation)::

    min  1/2 sum_k |e_k|^2 + 1/2 |C (theta_1 - mu)|^2 + 1/2 sum_k |D_k o (theta_k - theta_k-1)|^2
    s.t.  r(x_k, w_k, theta_k, p_k) = 0                       k = 1..N   (7 steady-state residuals)
          theta_lo <= theta <= theta_hi
    e_k = s_k o (y_k - h(x_k, w_k, theta_k, p_k))             normalised measurement residuals

``s_k = 1 / sigma_k`` per channel (0 for a channel that is not used, so a sensor subset is the
same program); ``mu`` and ``C`` (``C^T C`` = arrival information) are the arrival cost that
carries the previous windows' information; ``D_k`` (1/std of the random-walk step, random-walk
mode only) is the drift prior.

Speed. All per-sample work goes through four small functions of one sample (``x``, all ten
``theta``, ``w``, all sixteen measured channels, ``p``), generated as C and compiled once per
engine model (cached on disk, :mod:`engine_model.solver.codegen`), then evaluated over the window by
``Function.map``:

- ``fg``:   the residuals ``r`` and ``e``                       (objective and constraints)
- ``grad``: ``J_e^T e`` over ``z = (x, theta)``                 (objective gradient, by
  reverse mode: ``ca.gradient(|e|^2 / 2, z)``, one backward sweep instead of the product
  with the whole Jacobian; equal to 1e-15 relative, its C a fifth of the size: 1.6 s of
  gcc instead of 15 s, 2026-11-28)
- ``jac``:  ``dr/dz`` and ``de/dz``                              (constraint Jacobian, Fisher)
- ``hgn``:  ``J_e^T J_e``                                       (Gauss-Newton Hessian)
- ``hex``:  ``d2/dz2 [lam_f e^T e / 2 + lam_g^T r]``            (exact Hessian; compiled lazily,
  about 100 s the first time on this machine, then cached)

The window's gradient, constraint Jacobian and Hessian of the Lagrangian are assembled from the
per-sample blocks with constant sparse matrices (no Python loop at run time) and handed to
``nlpsol("ipopt")`` as ``grad_f``, ``jac_g`` and ``hess_lag``. With ``hessian="gauss-newton"``
the Hessian of the Lagrangian is the constrained Gauss-Newton matrix ``J_e^T J_e`` plus the
prior's (constant) Hessian: the constraint curvature ``lam_g^T d2r`` and the residual curvature
``e^T d2e`` are left out (Bock's generalised Gauss-Newton; both vanish at a zero-noise solution,
and its convergence is linear with a small rate when the residuals are small). With
``hessian="exact"`` the full second derivatives are used.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sps

from engine_model.channels import OUTPUT_NAMES, THETA_NAMES, W_NAMES, XS_NAMES
from engine_model.physics.turbofan import N_UNKNOWNS
from engine_model.solver.interface import SymbolicSteadyStateModel
from engine_model.solver.model import ad_options

N_X = N_UNKNOWNS  # the engine model's unknowns per sample
N_TH = len(THETA_NAMES)
N_Y = len(XS_NAMES)
N_W = len(W_NAMES)
N_Z = N_X + N_TH  # per-sample variables of the kernels: x and all ten theta

HESSIANS = ("gauss-newton", "exact")
MODES = ("constant", "random_walk")

# IPOPT defaults for the window problems (overridable through ``ipopt_options``)
IPOPT_DEFAULTS = {
    "print_level": 0,
    "sb": "yes",
    "linear_solver": "mumps",
    "tol": 1e-8,
    "acceptable_tol": 1e-6,
    "acceptable_iter": 3,
    "max_iter": 60,
    "mu_strategy": "adaptive",
    "mu_init": 1e-4,
    "bound_push": 1e-6,
    "bound_frac": 1e-6,
    "nlp_scaling_method": "none",
    "warm_start_init_point": "yes",
    "warm_start_bound_push": 1e-6,
    "warm_start_mult_bound_push": 1e-6,
}


class StageKernels:
    """The per-sample functions of one engine model (see the module docstring).

    ``compiled=True`` generates C for ``fg``, ``grad``, ``jac`` and ``hgn`` (one library,
    cached); ``hex`` is compiled on first use. ``compiled=False`` evaluates the same
    expression graphs in CasADi's virtual machine (slower; no compiler needed). ``mode``:
    how CasADi differentiates ``jac`` and ``hgn``, ``"reverse"`` (the default) or
    ``"forward"`` (until 2026-11-29; kept to compare, ``benchmarks/sensitivities_ad.py``).
    """

    def __init__(self, model: SymbolicSteadyStateModel, compiled: bool = True,
                 mode: str = "reverse"):
        how = ad_options(mode)
        rs = model.residual_system()
        self.n_p = len(rs.param_names)
        self.compiled = compiled
        self._key = "hyprog_mhe" + (("_" + model.variant_key) if model.variant_key else "")
        iy = [OUTPUT_NAMES.index(c) for c in XS_NAMES]
        x = ca.SX.sym("x", N_X)
        th = ca.SX.sym("theta", N_TH)
        w = ca.SX.sym("w", N_W)
        y = ca.SX.sym("y", N_Y)
        s = ca.SX.sym("s", N_Y)
        p = ca.SX.sym("p", self.n_p)
        res = rs.residual(x, w, th, p)
        e = (y - rs.outputs(x, w, th, p)[iy]) * s
        z = ca.vertcat(x, th)
        # the Jacobians by ``mode``: reverse (one adjoint sweep per residual and reading,
        # not one tangent sweep per unknown) gives the same numbers to rounding, the
        # Jacobians and the Gauss-Newton Hessian in 57 % fewer instructions, compiled in 7 s
        # instead of 20 s (benchmarks/sensitivities_ad.py)
        jr = ca.jacobian(res, z, how)
        je = ca.jacobian(e, z, how)
        args = [x, th, w, y, s, p]
        names = ["x", "theta", "w", "y", "s", "p"]
        self._sym = dict(args=args, names=names, res=res, e=e, z=z)
        fns = [
            ca.Function("mhe_fg", args, [res, e], names, ["r", "e"]),
            ca.Function("mhe_grad", args, [ca.gradient(0.5 * ca.sumsqr(e), z)], names,
                        ["g"]),
            ca.Function("mhe_jac", args, [jr, je], names, ["jr", "je"]),
            ca.Function("mhe_hgn", args, [ca.mtimes(je.T, je)], names, ["h"]),
        ]
        if compiled:
            from engine_model.solver.codegen import compile_functions

            lib = compile_functions(self._key + "_k1", fns, opt="-O1")
            self.f = {k: lib["mhe_" + k] for k in ("fg", "grad", "jac", "hgn")}
        else:
            self.f = {f.name()[4:]: f for f in fns}
        self._hex = None

    @property
    def hex(self) -> ca.Function:
        """Exact Hessian of ``lam_f |e|^2 / 2 + lam_g^T r`` in ``z`` (17 x 17)."""
        if self._hex is None:
            sy = self._sym
            lf = ca.SX.sym("lam_f")
            lg = ca.SX.sym("lam_g", N_X)
            lag = lf * 0.5 * ca.sumsqr(sy["e"]) + ca.dot(lg, sy["res"])
            h = ca.hessian(lag, sy["z"])[0]
            fn = ca.Function("mhe_hex", sy["args"] + [lf, lg], [h],
                             sy["names"] + ["lam_f", "lam_g"], ["h"])
            if self.compiled:
                from engine_model.solver.codegen import compile_functions

                self._hex = compile_functions(self._key + "_k2", [fn], opt="-O1")["mhe_hex"]
            else:
                self._hex = fn
        return self._hex

    def jacobians(self, x, theta, w, y, s, p):
        """Per-sample ``dr/dz`` (N, 7, 17) and ``de/dz`` (N, 16, 17) at (N, .) arrays."""
        n = len(x)
        f = self.f["jac"].map(n, "serial")
        pm = np.zeros((n, self.n_p)) if p is None else p
        jr, je = f(x.T, theta.T, w.T, y.T, s.T, pm.T)
        jr = np.asarray(jr).reshape(N_X, N_Z, n, order="F").transpose(2, 0, 1)
        je = np.asarray(je).reshape(N_Y, N_Z, n, order="F").transpose(2, 0, 1)
        return jr, je

    def residuals(self, x, theta, w, y, s, p):
        n = len(x)
        f = self.f["fg"].map(n, "serial")
        pm = np.zeros((n, self.n_p)) if p is None else p
        r, e = f(x.T, theta.T, w.T, y.T, s.T, pm.T)
        return np.asarray(r).T, np.asarray(e).T


def reduced_sensitivity(jr: np.ndarray, je: np.ndarray, est: np.ndarray) -> np.ndarray:
    """``de/dtheta`` along the steady state (x eliminated by the implicit function theorem):
    ``S = de/dth - de/dx (dr/dx)^-1 dr/dth`` for the estimated columns ``est``; (N, 16, n_th).
    """
    cols = N_X + np.asarray(est, int)
    jr_x, jr_t = jr[:, :, :N_X], jr[:, :, cols]
    je_x, je_t = je[:, :, :N_X], je[:, :, cols]
    return je_t - je_x @ np.linalg.solve(jr_x, jr_t)


def _assembly(shape, rows, cols, src, n_src, triu=False):
    """Sparsity of a matrix whose nonzeros are sums of source entries, and the constant
    (nnz x n_src) 0/1 matrix ``A`` with ``nonzeros = A @ source`` (CCS order)."""
    rows = np.asarray(rows, np.int64).ravel()
    cols = np.asarray(cols, np.int64).ravel()
    src = np.asarray(src, np.int64).ravel()
    if triu:
        keep = rows <= cols
        rows, cols, src = rows[keep], cols[keep], src[keep]
    key = cols * shape[0] + rows
    uniq, inv = np.unique(key, return_inverse=True)
    r_u, c_u = (uniq % shape[0]).astype(int), (uniq // shape[0]).astype(int)
    sp = ca.Sparsity.triplet(int(shape[0]), int(shape[1]), r_u.tolist(), c_u.tolist())
    a = sps.csc_matrix((np.ones(len(src)), (inv, src)), shape=(len(uniq), int(n_src)))
    a.sum_duplicates()
    return sp, ca.DM(a)


@dataclass
class WindowSolution:
    x: np.ndarray  # (N, 7)
    theta: np.ndarray  # (N, n_th) per-sample estimate (repeated in constant mode)
    lam_g: np.ndarray
    iterations: int
    status: str
    success: bool
    seconds: float
    objective: float


class WindowNLP:
    """The windowed MAP program for ``n`` samples, ``est`` estimated theta (indices into
    THETA_NAMES), ``mode`` and ``hessian``; built once, solved many times with different
    parameters (data, arrival cost, drift) and warm starts."""

    def __init__(self, kernels: StageKernels, n: int, est, mode: str = "constant",
                 hessian: str = "gauss-newton", ipopt_options: dict | None = None,
                 threads: int = 1):
        if mode not in MODES:
            raise ValueError(f"mode {mode!r}: one of {', '.join(MODES)}")
        if hessian not in HESSIANS:
            raise ValueError(f"hessian {hessian!r}: one of {', '.join(HESSIANS)}")
        self.k, self.n, self.mode, self.hessian = kernels, int(n), mode, hessian
        self.est = np.asarray(est, int)
        nt = len(self.est)
        self.nt = nt
        n = self.n
        rw = mode == "random_walk"
        # variable layout: random walk -> z_k = (x_k, theta_k) interleaved (banded KKT);
        # constant -> all x, then theta (arrowhead)
        if rw:
            nzv = N_X + nt
            vx = np.arange(n)[:, None] * nzv + np.arange(N_X)[None, :]
            vt = np.arange(n)[:, None] * nzv + N_X + np.arange(nt)[None, :]
            nv = n * nzv
        else:
            vx = np.arange(n * N_X).reshape(n, N_X)
            vt = np.tile(n * N_X + np.arange(nt), (n, 1))
            nv = n * N_X + nt
        self.vx, self.vt, self.nv = vx, vt, nv
        vz = np.concatenate([vx, vt], axis=1)  # (n, 7 + nt) variable index per kernel column
        zsel = np.concatenate([np.arange(N_X), N_X + self.est])  # kernel columns used
        nzs = len(zsel)

        V = ca.MX.sym("V", nv)
        W = ca.MX.sym("W", N_W, n)
        Y = ca.MX.sym("Y", N_Y, n)
        S = ca.MX.sym("S", N_Y, n)
        TF = ca.MX.sym("TF", N_TH, 1)  # fixed (not estimated) theta
        MU = ca.MX.sym("MU", nt, 1)
        C = ca.MX.sym("C", nt, nt)
        D = ca.MX.sym("D", nt, max(n - 1, 1)) if rw else ca.MX.sym("D", 0, 1)
        PM = ca.MX.sym("PM", kernels.n_p, n)
        P = ca.vertcat(ca.vec(W), ca.vec(Y), ca.vec(S), TF, MU, ca.vec(C), ca.vec(D), ca.vec(PM))
        self._p_sizes = [N_W * n, N_Y * n, N_Y * n, N_TH, nt, nt * nt, D.numel(), kernels.n_p * n]

        X = ca.reshape(V[vx.ravel().tolist()], N_X, n)
        E_sel = ca.DM(sps.csc_matrix((np.ones(nt), (self.est, np.arange(nt))), shape=(N_TH, nt)))
        if rw:
            TH = ca.reshape(V[vt.ravel().tolist()], nt, n)
            TH_full = ca.repmat(TF, 1, n) + ca.mtimes(E_sel, TH)
            th_first = TH[:, 0]
        else:
            TH = V[vt[0].tolist()]
            TH_full = TF + ca.mtimes(E_sel, TH)
            th_first = TH
        kargs = [X, TH_full, W, Y, S, PM]

        def mapped(fn):
            if threads > 1 and n >= 4 * threads:
                return fn.map(n, "thread", threads)
            return fn.map(n, "serial")

        R, E = mapped(kernels.f["fg"])(*kargs)
        prior = ca.sumsqr(ca.mtimes(C, th_first - MU))
        if rw:
            prior = prior + ca.sumsqr(D * (TH[:, 1:] - TH[:, :-1]))
        prior = 0.5 * prior
        f = 0.5 * ca.sumsqr(E) + prior
        g = ca.vec(R)

        # --- gradient: per-sample J_e^T e (17 x n), selected columns -> variables
        G = mapped(kernels.f["grad"])(*kargs)
        kk = np.repeat(np.arange(n), nzs)
        src = kk * N_Z + np.tile(zsel, n)
        sp_g, a_g = _assembly((nv, 1), vz.ravel(), np.zeros(n * nzs), src, n * N_Z)
        grad = ca.densify(ca.MX(sp_g, ca.mtimes(a_g, ca.vec(G)))) + ca.gradient(prior, V)

        # --- constraint Jacobian: per-sample dr/dz (7 x 17 each)
        JR, _ = mapped(kernels.f["jac"])(*kargs)
        ri = np.arange(N_X)
        rows = (np.arange(n)[:, None, None] * N_X + ri[None, :, None]) + 0 * zsel[None, None, :]
        cols = np.broadcast_to(vz[:, None, :], (n, N_X, nzs))
        src = (np.arange(n)[:, None, None] * N_Z + zsel[None, None, :]) * N_X + ri[None, :, None]
        sp_j, a_j = _assembly((n * N_X, nv), rows, cols, src, N_X * N_Z * n)
        jac = ca.MX(sp_j, ca.mtimes(a_j, ca.vec(JR)))

        # --- Hessian of the Lagrangian (upper triangle)
        lam_f = ca.MX.sym("lam_f")
        lam_g = ca.MX.sym("lam_g", n * N_X)
        if hessian == "exact":
            LG = ca.reshape(lam_g, N_X, n)
            HS = mapped(kernels.hex)(*kargs, lam_f, LG)
        else:
            HS = lam_f * mapped(kernels.f["hgn"])(*kargs)
        rows = np.broadcast_to(vz[:, :, None], (n, nzs, nzs))
        cols = np.broadcast_to(vz[:, None, :], (n, nzs, nzs))
        src = ((np.arange(n)[:, None, None] * N_Z + zsel[None, None, :]) * N_Z
               + zsel[None, :, None])
        sp_h, a_h = _assembly((nv, nv), rows, cols, src, N_Z * N_Z * n, triu=True)
        h_data = ca.MX(sp_h, ca.mtimes(a_h, ca.vec(HS)))
        h_prior = ca.triu(ca.hessian(prior, V)[0])
        hess = h_data + lam_f * h_prior

        self.nlp_fg = ca.Function("mhe_nlp_fg", [V, P], [f, g])
        grad_f = ca.Function("grad_f", [V, P], [f, grad], ["x", "p"], ["f", "grad_f_x"])
        jac_g = ca.Function("jac_g", [V, P], [g, jac], ["x", "p"], ["g", "jac_g_x"])
        hess_lag = ca.Function("hess_lag", [V, P, lam_f, lam_g], [hess],
                               ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])
        ipopt = dict(IPOPT_DEFAULTS)
        ipopt.update(ipopt_options or {})
        opts = {"ipopt": ipopt, "print_time": False, "grad_f": grad_f, "jac_g": jac_g,
                "hess_lag": hess_lag, "error_on_fail": False,
                "calc_lam_p": False, "no_nlp_grad": True}
        self.solver = ca.nlpsol(f"mhe_{mode}_{n}", "ipopt", {"x": V, "p": P, "f": f, "g": g},
                                opts)
        self.lbg = np.zeros(n * N_X)

    # ------------------------------------------------------------------ parameters
    def params(self, w, y, s, theta_fixed, mu, c, d=None, p=None) -> np.ndarray:
        n, nt = self.n, self.nt
        if self.mode == "random_walk":
            d = np.zeros((nt, max(n - 1, 1))) if d is None else np.asarray(d, float)
            d = d.reshape(nt, max(n - 1, 1))
        else:
            d = np.zeros(0)
        pm = np.zeros((self.k.n_p, n)) if p is None else np.asarray(p, float).T
        parts = [np.asarray(w, float).T, np.asarray(y, float).T, np.asarray(s, float).T,
                 np.asarray(theta_fixed, float), np.asarray(mu, float), np.asarray(c, float),
                 d, pm]
        return np.concatenate([np.ravel(a, order="F") for a in parts])

    def pack(self, x, theta) -> np.ndarray:
        """Decision vector from x (N, 7) and theta ((N, nt) or (nt,))."""
        v = np.zeros(self.nv)
        v[self.vx.ravel()] = np.asarray(x, float).ravel()
        th = np.asarray(theta, float)
        if self.mode == "random_walk":
            v[self.vt.ravel()] = np.broadcast_to(th, (self.n, self.nt)).ravel()
        else:
            v[self.vt[0]] = th.reshape(-1, self.nt)[-1] if th.ndim == 2 else th
        return v

    def unpack(self, v):
        v = np.asarray(v, float).ravel()
        return v[self.vx], v[self.vt]

    def solve(self, pvec, x0, theta0, lb, ub, lam_g0=None) -> WindowSolution:
        v0 = self.pack(x0, theta0)
        lbx = np.full(self.nv, -np.inf)
        ubx = np.full(self.nv, np.inf)
        lbx[self.vt.ravel()] = np.broadcast_to(lb, (self.n, self.nt)).ravel()
        ubx[self.vt.ravel()] = np.broadcast_to(ub, (self.n, self.nt)).ravel()
        v0 = np.clip(v0, lbx, ubx)
        kw = dict(x0=v0, p=pvec, lbx=lbx, ubx=ubx, lbg=self.lbg, ubg=self.lbg)
        if lam_g0 is not None:
            kw["lam_g0"] = lam_g0
        t0 = time.perf_counter()
        sol = self.solver(**kw)
        dt = time.perf_counter() - t0
        st = self.solver.stats()
        x, th = self.unpack(sol["x"])
        status = str(st.get("return_status", "unknown"))
        ok = bool(st.get("success", False)) or status in ("Solve_Succeeded",
                                                          "Solved_To_Acceptable_Level")
        return WindowSolution(x=x, theta=th, lam_g=np.asarray(sol["lam_g"]).ravel(),
                              iterations=int(st.get("iter_count", -1)), status=status,
                              success=ok, seconds=dt, objective=float(sol["f"]))
