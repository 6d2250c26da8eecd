"""The fit the loop tests against: theta per flight cycle as a slow random walk, plus the
accepted effects' parameters, by bounded Gauss-Newton with exact Jacobians.

Model (one unit; the effect parameters ``phi`` are shared by the fleet)::

    y_n = G(w_n, theta_{c(n)}, phi) + eps_n,   eps_n ~ N(0, R_n),  R_n = diag(s_j sigma_nj)^2
    theta_1 ~ N(mu0, diag(prior_std^2)),   theta_c - theta_{c-1} ~ N(0, q^2 tau_c I)

``c(n)`` the flight cycle of sample ``n`` (theta is constant within a flight, as in N-CMAPSS
and the simulator; data without a ``cycle`` column are one cycle: constant theta), ``tau_c``
the recorded hours of the previous cycle, ``q`` the drift std per sqrt(hour) (the setup's, or
its maximum-likelihood value, :mod:`.drift_mle`), ``sigma`` the documented sensor noise and
``s_j`` the per-channel scale of the noise check (:mod:`.noise_check`). The negative log
posterior is ``L = 1/2 |e|^2 + 1/2 (Theta - mu)^T Lambda (Theta - mu)`` with the whitened
residual ``e = R^-1/2 (y - G)``.

Why a slow random walk and not a filter with loose process noise: a theta that may move
freely at every sample soaks up any effect whose signature lies in the span of ``dG/dtheta``
so the residual would show nothing. With one theta per cycle and the
drift prior, an effect that varies with the operating point *within* a flight cannot be
absorbed.

The fit starts from an existing estimator (:mod:`calibration`'s ``mhe``, ``ukf``, ``ekf`` or
``map_cycle``, public API, the cycle mean of its theta_hat) and is polished by Gauss-Newton
on ``(Theta, phi_free)``: exact Jacobians from the model's sensitivities, the step of the
bounded quadratic model (``scipy.optimize.lsq_linear`` on the Cholesky factor of the
Gauss-Newton matrix: theta within the setup's bounds, one-sided effect parameters on their
side of the neutral value) and a
backtracking line search on ``L`` (each trial a warm-started steady solve). The gradient and
Gauss-Newton matrix at the solution, over *every* candidate parameter, are what the score
tests use (:mod:`.score_statistics`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import lsq_linear

from calibration.estimation_setup import CalibrationSetup
from calibration.series import UnitSeries, prepare_unit
from engine_model.validation import InputError

from .candidates import CandidateModel
from .normal_matrix import NormalMatrix

#: Above this many unknowns (theta of every cycle and the free phi) the Gauss-Newton step is
#: solved in the matrix's block structure with an active set for the bounds
#: (:func:`structured_step`); at or below it, densely with a bounded least-squares solver
#: (exact for the box constraints). The dense factorisation costs the cube of the size: 85
#: C-MAPSS engines x 40 cycles x 3 parameters (10,200 unknowns) took more than 20 minutes.
DENSE_MAX = 1500


@dataclass
class UnitData:
    """One unit: its checked arrays (``series``), the cycle index ``cyc`` (N,) in
    ``0..n_cycles-1``, ``tau_h`` (n_cycles,) drift hours before each cycle (0 first), the
    cycle numbers ``cycle`` (N,) (or None) and the input frame's operating columns ``frame``
    (for the report and the unknown-effect basis)."""

    series: UnitSeries
    cyc: np.ndarray
    n_cycles: int
    tau_h: np.ndarray
    cycle: np.ndarray | None
    frame: pd.DataFrame

    @property
    def n(self) -> int:
        return len(self.cyc)


def unit_data(df: pd.DataFrame, setup: CalibrationSetup, source=None) -> UnitData:
    """One unit's data for the loop. Its theta is constant within a cycle and walks between
    cycles, by the drift over the previous cycle's duration: ``drift_per="cycle"`` whatever
    the setup says (with ``"time"`` the series' step at a cycle start is one sample period,
    not the flight between)."""
    if "cycle" in df.columns and setup.drift_per != "cycle":
        setup = replace(setup, drift_per="cycle")
    s = prepare_unit(df, setup, source)
    if s.cycle is None:
        cyc = np.zeros(len(s), int)
        return UnitData(s, cyc, 1, np.zeros(1), None, df.reset_index(drop=True))
    values, cyc = np.unique(s.cycle, return_inverse=True)
    if np.any(np.diff(s.cycle) < 0):
        raise InputError(f"unit {s.unit}: cycles must not decrease along the rows")
    starts = np.searchsorted(cyc, np.arange(len(values)))
    tau = np.asarray(s.dtau_h, float)[starts]
    tau[0] = 0.0
    return UnitData(s, cyc, len(values), tau, np.asarray(s.cycle, float),
                    df.reset_index(drop=True))


@dataclass
class Linearization:
    """The model at one parameter point, every unit: whitened residuals ``e`` (list of
    (N, m), zero where not converged or masked out), the unknowns ``x``, and when asked for,
    the Gauss-Newton blocks: per unit ``A`` (C, k, k) = sum J_th^T J_th per cycle, ``B``
    (C, k, n_phi), ``g_th`` (C, k) = sum J_th^T e; fleet ``D`` (n_phi, n_phi), ``g_phi``."""

    e: list
    x: list
    ok: list
    sse: float
    A: list = field(default_factory=list)
    B: list = field(default_factory=list)
    g_th: list = field(default_factory=list)
    D: np.ndarray | None = None
    g_phi: np.ndarray | None = None
    J_th: list = field(default_factory=list)
    J_phi: list = field(default_factory=list)


class Problem:
    """Units, setup, candidate model, per-channel noise scale ``scale`` (m,) and drift ``q``.

    ``Theta`` is a list of (C_u, k) arrays; ``phi`` the global candidate vector."""

    def __init__(self, units: list[UnitData], setup: CalibrationSetup, cm: CandidateModel,
                 q: float | None = None):
        if not units:
            raise InputError("discover: no unit to fit")
        sensors = units[0].series.sensors
        for u in units:
            if u.series.sensors != sensors:
                raise InputError(f"unit {u.series.unit}: sensors {u.series.sensors} differ "
                                 f"from {sensors}")
        self.units, self.setup, self.cm = units, setup, cm
        self.sensors = tuple(sensors)
        self.m = len(sensors)
        self.k = setup.k
        self.est_idx = setup.param_index
        self.scale = np.ones(self.m)
        self.q = float(setup.drift if q is None else q)
        self.mu0 = setup.prior_mean_vec()
        self.sd0 = setup.prior_std_vec()
        self.n_phi = cm.n_phi
        self.offsets = np.cumsum([0] + [u.n_cycles * self.k for u in units])

    @property
    def n_theta(self) -> int:
        return int(self.offsets[-1])

    # ------------------------------------------------------------------ prior
    def prior_precision(self, u: UnitData, q: float | None = None) -> np.ndarray:
        """Lambda (C k, C k) of the random-walk prior of one unit (module docstring)."""
        q = self.q if q is None else q
        C, k = u.n_cycles, self.k
        lam = np.zeros((C * k, C * k))
        lam[:k, :k] += np.diag(1.0 / self.sd0 ** 2)
        if C > 1:
            floor = max(float(np.median(u.series.dt_h[u.series.dt_h > 0])) if
                        np.any(u.series.dt_h > 0) else 1.0 / 360, 1e-6)
            tau = np.maximum(u.tau_h, floor)
            for c in range(1, C):
                wgt = 1.0 / (q * q * tau[c])
                a, b = slice((c - 1) * k, c * k), slice(c * k, (c + 1) * k)
                for s1, s2, sign in ((a, a, 1), (b, b, 1), (a, b, -1), (b, a, -1)):
                    lam[s1, s2] += sign * wgt * np.eye(k)
        return lam

    def prior_value(self, Theta) -> float:
        v = 0.0
        for u, th in zip(self.units, Theta, strict=True):
            d = (th - self.mu0).ravel()
            v += 0.5 * d @ self.prior_precision(u) @ d
        return float(v)

    # ------------------------------------------------------------------ model
    def theta_rows(self, u: UnitData, th: np.ndarray) -> np.ndarray:
        return self.setup.full_theta(th[u.cyc])

    def linearize(self, Theta, phi, xs=None, masks=None, derivatives=True) -> Linearization:
        """Evaluate every unit at (Theta, phi), warm-started from ``xs``; with
        ``derivatives`` the Gauss-Newton blocks (``masks``: per-unit sample weights 0/1)."""
        lin = Linearization(e=[], x=[], ok=[], sse=0.0)
        if derivatives:
            lin.D = np.zeros((self.n_phi, self.n_phi))
            lin.g_phi = np.zeros(self.n_phi)
        for i, (u, th) in enumerate(zip(self.units, Theta, strict=True)):
            s = u.series
            ev = self.cm.evaluate(s.w, self.theta_rows(u, th), self.sensors, phi,
                                  x0=None if xs is None else xs[i], cycle=u.cycle,
                                  est_idx=self.est_idx, derivatives=derivatives)
            sig = s.sigma * self.scale
            ok = ev.converged.copy()
            wgt = ok.astype(float) if masks is None else ok * masks[i]
            e = np.where(ok[:, None], (s.y - np.nan_to_num(ev.y)) / sig, 0.0) * wgt[:, None]
            lin.e.append(e)
            lin.x.append(ev.x)
            lin.ok.append(ok)
            lin.sse += float(np.sum(e * e))
            if derivatives:
                jt = np.nan_to_num(-ev.d_theta / sig[:, :, None] * wgt[:, None, None])
                jp = np.nan_to_num(-ev.d_phi / sig[:, :, None] * wgt[:, None, None])
                self._add_blocks(lin, u, e, jt, jp)
        return lin

    def _add_blocks(self, lin: Linearization, u: UnitData, e, jt, jp):
        """Append one unit's Gauss-Newton blocks from its whitened, weighted residual ``e``
        (N, m) and Jacobians ``jt`` (N, m, k), ``jp`` (N, m, n_phi)."""
        C = u.n_cycles
        A = np.zeros((C, self.k, self.k))
        np.add.at(A, u.cyc, np.einsum("nmi,nmj->nij", jt, jt))
        B = np.zeros((C, self.k, self.n_phi))
        np.add.at(B, u.cyc, np.einsum("nmi,nmj->nij", jt, jp))
        g = np.zeros((C, self.k))
        np.add.at(g, u.cyc, np.einsum("nmi,nm->ni", jt, e))
        lin.A.append(A)
        lin.B.append(B)
        lin.g_th.append(g)
        lin.D += np.einsum("nmi,nmj->ij", jp, jp)
        lin.g_phi += np.einsum("nmi,nm->i", jp, e)
        lin.J_th.append(jt)
        lin.J_phi.append(jp)

    def masked(self, lin: Linearization, masks) -> Linearization:
        """The linearisation ``lin`` (with derivatives, every sample) restricted to the
        samples of ``masks`` (per-unit weights 0/1): no model evaluation, the residuals and
        Jacobians are the same at the same point, only the sums change."""
        if masks is None:
            return lin
        out = Linearization(e=[], x=lin.x, ok=lin.ok, sse=0.0, D=np.zeros_like(lin.D),
                            g_phi=np.zeros_like(lin.g_phi))
        for i, u in enumerate(self.units):
            wgt = np.asarray(masks[i], float)
            e = lin.e[i] * wgt[:, None]
            out.e.append(e)
            out.sse += float(np.sum(e * e))
            self._add_blocks(out, u, e, lin.J_th[i] * wgt[:, None, None],
                             lin.J_phi[i] * wgt[:, None, None])
        return out

    def objective(self, lin: Linearization, Theta) -> float:
        return 0.5 * lin.sse + self.prior_value(Theta)

    # ------------------------------------------------------------------ normal equations
    def normal_equations(self, lin: Linearization, Theta, q: float | None = None):
        """Gradient ``grad`` of L and Gauss-Newton matrix ``H`` over ``[Theta (all units),
        phi (every candidate)]``, ``H`` in its block structure (:class:`NormalMatrix`)."""
        nt, n_phi = self.n_theta, self.n_phi
        grad = np.zeros(nt + n_phi)
        blocks, borders = [], []
        for i, u in enumerate(self.units):
            sl = slice(self.offsets[i], self.offsets[i + 1])
            C, k = u.n_cycles, self.k
            blk = np.zeros((C * k, C * k))
            for c in range(C):
                blk[c * k:(c + 1) * k, c * k:(c + 1) * k] = lin.A[i][c]
            lam = self.prior_precision(u, q)
            blocks.append(blk + lam)
            borders.append(lin.B[i].reshape(C * k, n_phi))
            grad[sl] = lin.g_th[i].ravel() + lam @ (Theta[i] - self.mu0).ravel()
        grad[nt:] = lin.g_phi
        return grad, NormalMatrix(blocks, borders, lin.D.copy(), np.asarray(self.offsets))


@dataclass
class FitState:
    """A converged fit: ``Theta`` (list of (C_u, k)), ``phi`` (global), ``free`` (indices of
    phi that were fitted), the linearization ``lin`` at the solution (with derivatives),
    ``grad`` / ``H`` over [Theta, every phi] (``H`` a :class:`NormalMatrix`), the objective
    ``L``, and ``iterations``. ``converged`` means the iteration stopped on its own: the
    relative decrease of ``L`` fell below the tolerance, or no step along the Gauss-Newton
    direction lowered ``L`` (the line search gave up, taken as the solution within the
    noise), not that a gradient norm was checked."""

    Theta: list
    phi: np.ndarray
    free: np.ndarray
    lin: Linearization
    grad: np.ndarray
    H: NormalMatrix
    L: float
    iterations: int
    converged: bool

    @property
    def n_nonconverged(self) -> int:
        return int(sum((~ok).sum() for ok in self.lin.ok))


def _bounds(problem: Problem, Theta, phi, free):
    lo_th, hi_th = problem.setup.bounds
    th = np.concatenate([t.ravel() for t in Theta])
    lo = [np.full(th.size, lo_th) - th]
    hi = [np.full(th.size, hi_th) - th]
    lower = np.full(problem.n_phi, -np.inf)
    upper = np.full(problem.n_phi, np.inf)
    for c in problem.cm.candidates:
        lower[c.index] = c.lower
        upper[c.index] = c.upper
    lo.append(lower[free] - phi[free])
    hi.append(upper[free] - phi[free])
    lo, hi = np.concatenate(lo), np.concatenate(hi)
    # a point exactly on a bound: lsq_linear needs lo < hi
    hi = np.maximum(hi, lo + 1e-15)
    return lo, hi


def _split(problem: Problem, z):
    return [z[problem.offsets[i]:problem.offsets[i + 1]].reshape(-1, problem.k)
            for i in range(len(problem.units))]


def _n_failed(lin: Linearization) -> int:
    return int(sum((~ok).sum() for ok in lin.ok))


def fit(problem: Problem, Theta, phi, free=(), masks=None, xs=None, max_iter: int = 12,
        rtol: float = 1e-6, lin: Linearization | None = None) -> FitState:
    """Bounded Gauss-Newton on ``(Theta, phi[free])`` from the given point (module
    docstring). Returns the state at the solution, linearised with derivatives.

    ``lin``: the linearisation (with derivatives, every sample, the problem's current noise
    scale) at exactly this ``(Theta, phi)``, e.g. the ``lin`` of an earlier fit that ended
    here: reused (restricted to ``masks``) instead of evaluating the model again."""
    Theta = [np.array(t, float) for t in Theta]
    phi = np.array(phi, float)
    free = np.asarray(free, int)
    nt = problem.n_theta
    sel = np.concatenate([np.arange(nt), nt + free])
    if lin is not None:
        lin = problem.masked(lin, masks)
    else:
        lin = problem.linearize(Theta, phi, xs, masks)
    if xs is not None and _n_failed(lin):  # a warm start that failed: from the model's guess
        lin = problem.linearize(Theta, phi, None, masks)
    n_all = sum(len(ok) for ok in lin.ok)
    if _n_failed(lin) == n_all:
        raise InputError("discover: the steady state converges at none of the data's points "
                         "at the starting theta; check the operating columns and units")
    L = problem.objective(lin, Theta)
    it, done = 0, False
    while it < max_iter:
        it += 1
        grad, H = problem.normal_equations(lin, Theta)
        g = grad[sel]
        lo, hi = _bounds(problem, Theta, phi, free)
        if len(sel) <= DENSE_MAX:
            Hs = H.dense()[np.ix_(sel, sel)]
            d = np.sqrt(np.maximum(np.diag(Hs), 1e-300))
            Hn = Hs / np.outer(d, d) + 1e-12 * np.eye(len(sel))
            R = np.linalg.cholesky(Hn).T
            b = np.linalg.solve(R.T, -g / d)
            step = lsq_linear(R, b, bounds=(lo * d, hi * d), method="bvls").x / d
            pred = -(g @ step + 0.5 * step @ Hs @ step)
        else:
            step = structured_step(H, free, g, lo, hi)
            pred = -(g @ step + 0.5 * step @ quad(H, free, step))
        if pred < rtol * (1.0 + abs(L)):
            done = True
            break
        alpha = 1.0
        while True:
            z = np.concatenate([np.concatenate([t.ravel() for t in Theta]), phi[free]])
            z_new = z + alpha * step
            Th_new = _split(problem, z_new[:nt])
            phi_new = phi.copy()
            phi_new[free] = z_new[nt:]
            trial = problem.linearize(Th_new, phi_new, lin.x, masks, derivatives=False)
            L_new = problem.objective(trial, Th_new)
            if _n_failed(trial) > _n_failed(lin):  # a sample lost is not a better fit
                L_new = np.inf
            if L_new <= L - 1e-4 * alpha * pred or alpha < 1e-3:
                break
            alpha *= 0.5
        if L_new > L:  # no decrease along the step: at the solution within noise
            done = True
            break
        Theta, phi = Th_new, phi_new
        lin = problem.linearize(Theta, phi, trial.x, masks)
        dec, L = L - L_new, L_new
        if dec < rtol * (1.0 + abs(L)):
            done = True
            break
    grad, H = problem.normal_equations(lin, Theta)
    return FitState(Theta, phi, free, lin, grad, H, L, it, done)


def quad(H: NormalMatrix, free, x) -> np.ndarray:
    """``H_SS x`` over ``S = [every theta, phi[free]]`` from the blocks."""
    free = np.asarray(free, int)
    nt = H.n_theta
    out = np.zeros_like(x)
    xf = x[nt:]
    acc = H.D[np.ix_(free, free)] @ xf
    for i, (blk, bor) in enumerate(zip(H.blocks, H.borders, strict=True)):
        sl = slice(H.offsets[i], H.offsets[i + 1])
        Bf = bor[:, free]
        out[sl] = blk @ x[sl] + Bf @ xf
        acc += Bf.T @ x[sl]
    out[nt:] = acc
    return out


def structured_step(H: NormalMatrix, free, g, lo, hi, max_rounds: int = 20) -> np.ndarray:
    """The Gauss-Newton step ``H_SS step = -g`` within the box ``[lo, hi]``, by an active
    set: a coordinate whose step leaves the box is held on the bound it crosses and the rest
    solved again, until the step is inside (at most ``max_rounds`` rounds; at the end the
    step is clipped into the box)."""
    fixed = np.zeros(len(g), bool)
    val = np.zeros(len(g))
    step = H.solve(free, -g)
    for _ in range(max_rounds):
        out = (step < lo) | (step > hi)
        if not out.any():
            break
        fixed |= out
        val = np.where(step < lo, lo, np.where(step > hi, hi, val))
        rhs = np.where(fixed, val, -g)
        step = H.solve(free, rhs, fixed)
    return np.clip(step, lo, hi)


COARSE_EVERY = 16


def thinned(u: UnitData, every: int) -> UnitData:
    """Every ``every``-th sample of each flight, counted from its first (kept, so the drift
    hours between flights and the cycle index are those of the full series)."""
    n = u.n
    first = np.r_[True, u.cyc[1:] != u.cyc[:-1]] if n else np.zeros(0, bool)
    start = np.maximum.accumulate(np.where(first, np.arange(n), 0))
    idx = np.flatnonzero((np.arange(n) - start) % every == 0)
    s = u.series
    ser = replace(s, w=s.w[idx], y=s.y[idx], sigma=s.sigma[idx], dt_h=s.dt_h[idx],
                  dtau_h=s.dtau_h[idx], index=s.index[idx],
                  cycle=None if s.cycle is None else s.cycle[idx])
    return UnitData(ser, u.cyc[idx], u.n_cycles, u.tau_h,
                    None if u.cycle is None else u.cycle[idx],
                    u.frame.iloc[idx].reset_index(drop=True))


def coarse_start(problem: Problem, phi, every: int = COARSE_EVERY) -> list:
    """Theta per cycle from the same fit (:func:`fit`, from the prior mean) on every
    ``every``-th sample of each flight: the warm start ``coarse``. Theta has three
    parameters per flight and a flight has hundreds of samples per channel, so a sixteenth
    of them puts the start within one Gauss-Newton step of the full fit's solution at a
    sixteenth of the cost per iteration (measured on the 4-unit ``tiny`` fleet: the full fit
    then takes one step, two evaluations with derivatives, instead of five steps from the
    prior mean; its objective within 0.07 of the same optimum, 1e5 in all)."""
    sub = Problem([thinned(u, every) for u in problem.units], problem.setup, problem.cm,
                  problem.q)
    sub.scale = problem.scale
    Theta0 = [np.tile(problem.mu0, (u.n_cycles, 1)) for u in problem.units]
    return fit(sub, Theta0, phi, max_iter=30).Theta


def warm_start(problem: Problem, frames: list[pd.DataFrame], method: str, model) -> list:
    """Theta per cycle from an existing estimator (public API): the cycle means of its
    theta_hat (unobservable parameters, NaN there, at the prior mean; the estimator's
    per-unit warning about them is not the loop's to give: a start, not a result)."""
    from calibration import get_estimator

    est = get_estimator(method, model=model)
    est.warn_unobservable = False
    results = est.estimate_many(frames, problem.setup)
    Theta = []
    for u, r in zip(problem.units, results, strict=True):
        th = r.theta_hat.to_numpy(float)
        th = np.where(np.isfinite(th), th, problem.mu0)
        out = np.zeros((u.n_cycles, problem.k))
        np.add.at(out, u.cyc, th)
        out /= np.bincount(u.cyc, minlength=u.n_cycles)[:, None]
        lo, hi = problem.setup.bounds
        Theta.append(np.clip(out, lo, hi))
    return Theta


def cho_inv_solve(H: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``H^-1 B`` for a symmetric positive (semi)definite ``H``, scaled for conditioning."""
    d = np.sqrt(np.maximum(np.diag(H), 1e-300))
    Hn = H / np.outer(d, d) + 1e-12 * np.eye(len(H))
    sol = cho_solve(cho_factor(Hn), (B.T / d).T if B.ndim == 2 else B / d)
    return (sol.T / d).T if B.ndim == 2 else sol / d
