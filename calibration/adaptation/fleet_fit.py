"""One fit of a whole fleet: parameters shared by every engine and each engine's own health,
by bounded Gauss-Newton with exact Jacobians.

Model (early life, engine ``u``, sample ``n``, channel ``j``; package docstring)::

    y_nj = G_j(w_n, delta_u(n), phi) + eps_nj,    eps_nj ~ N(0, sigma_j,c(n)^2)
    delta_u ~ N(0, diag(s_theta^2))        (manufacturing scatter of new engines)
    phi_i ~ N(0, s_phi,i^2), phi_i in [lo_i, hi_i]   (a prior and the valid range)

``phi`` (the free parameters of the candidate effects, :mod:`.groups`) is shared by the
fleet; ``delta_u`` (every health parameter) is each engine's own. The zero-mean prior on
``delta_u`` is what tells them apart: a fleet-wide offset of a component's efficiency costs the
prior of every engine if it is put in ``delta``, and almost nothing if it is put in the
shared ``design_scaling`` of that component.

The negative log posterior (``e`` the whitened residual)::

    L = 1/2 |e|^2 + 1/2 sum_u |delta_u / s_theta|^2 + 1/2 |phi / s_phi|^2

(with the model error shared, last paragraph: ``e`` whitened by the noise alone with the
offsets ``b`` added to the model, and ``1/2 |b / s|^2`` added to ``L``) is minimised by
Gauss-Newton with Levenberg-Marquardt damping (the damping scaled by the matrix's diagonal,
Marquardt 1963; Nocedal & Wright 2006, sec. 10.3), steps projected onto the bounds. A
parameter on a bound whose gradient points out of its range is held there for the iteration
(the active set of projected Newton methods, Bertsekas, "Projected Newton methods for
optimization problems with simple constraints", SIAM J. Control Optim. 20, 1982), and so is
one that the step, coupled to the others, pushes out; the same for an engine's health
parameter on a bound of the calibration envelope,
``engine_model.validation.ENVELOPE.theta``. (Holding only what the step pushed out released
such parameters every other iteration, and fits whose optimum lies on the bounds stopped at
the iteration cap short of it: 2026-11-28.) The normal equations are *bordered
block-diagonal* (one small block per engine, a dense border for the shared parameters),
solved by the Schur complement on the shared block (Triggs et al., "Bundle adjustment - a
modern synthesis", 2000, sec. 6.1), so the cost is linear in the number of engines. The
Gauss-Newton matrix at the optimum, inverted, is the posterior covariance; the shared block
of it (the inverse Schur complement) is the uncertainty of the adaptation, the health of
every engine marginalised out.

**The model's own error, shared by an operating point** (``FleetData.shared_error``). Each
sample's std may include the model's own error ``s_jc`` (:mod:`.data`). Counted as
independent noise of every sample, it is counted once per sample: a mismatch the model
makes at one operating condition, the same in all of that condition's ~280 FD002
samples, then weighs as ~280 independent errors, and the candidates' priors hardly count
beside it. Kennedy & O'Hagan's discrepancy is a function of the operating point ("Bayesian
calibration of computer models", JRSS B 63, 2001, sec. 4.3): one unknown offset per
condition ``c`` and channel ``j``, shared by that condition's samples::

    y_nj = G_j(w_n, delta_u(n), phi) + b_c(n),j + eps_nj,   b_cj ~ N(0, s_cj^2),
    eps_nj ~ N(0, sigma_nj^2 - s_cj^2)                       (the noise alone)

which, with ``b`` integrated out, is the Gaussian likelihood whose covariance couples the
samples of one condition and channel (``noise^2 I + s^2 1 1^T``). The fit carries the
``b_cj`` as shared parameters beside ``phi`` (the same Schur complement, a border of
``conditions x channels`` more columns, unbounded, with their prior) and reports everything
else as before: the residual, prediction and every error are the model's own (``b`` left
out), whitened by the combined std; ``cov`` is ``phi``'s posterior with the health and ``b``
integrated out. A condition the fit did not see has no ``b``: its prediction is the model's,
uncertain by ``s`` (:func:`mean_prediction_std`). The adaptation's default since 2026-11-30
(:func:`calibration.adaptation.data.fleet_data`; ``hyprog adapt --model-error-independent``
counts the error per sample, as the FD002 adaptation ccd7e93d was fitted). Within a
condition the samples' spread (between engines, with the settings' jitter) is then weighed
by the noise alone, where a channel written almost without noise (C-MAPSS's ``Nf``, ``P15``)
weighs most: the caveat of the noise alone (:mod:`.data`), now within each condition rather
than between conditions.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from engine_model.channels import THETA_NAMES
from engine_model.validation import ENVELOPE

#: Prior std of an engine's own health parameters when new (manufacturing scatter): 1 % on
#: every component efficiency and flow, a judgement. It sets how a fleet-wide offset is split
#: between the shared ``design_scaling`` and ``delta`` (with 85 engines the fleet mean of
#: ``delta`` costs 85 times its prior); the spread of early-life theta_hat across the FD002
#: engines is reported beside it (docs/adaptation.md).
S_THETA = 0.01
#: Bounds on ``delta``: the model's range of a health parameter.
THETA_LO, THETA_HI = ENVELOPE.theta
MAX_ITER = 40
#: Stop when the relative decrease of L in a step is below this.
REL_TOL = 1e-7


@dataclass
class FleetData:
    """Samples of a fleet: ``w`` (N, 4), ``y`` (N, m) readings of ``channels``, ``sigma``
    (N, m) their std in the likelihood, ``unit`` (N,) engine index 0..U-1 (rows grouped by
    engine, in order), ``units`` the engine ids, ``condition`` (N,) operating-condition
    label, ``cycle`` (N,); ``model_sd`` (N, m) the part of ``sigma`` that is the model's own
    error (:mod:`.data`; None: none), the same for every sample at one operating point;
    ``shared_error``: the likelihood treats it so (one discrepancy per condition and channel,
    module docstring) rather than as independent noise of each sample."""

    w: np.ndarray
    y: np.ndarray
    sigma: np.ndarray
    unit: np.ndarray
    units: tuple
    condition: np.ndarray
    cycle: np.ndarray
    channels: tuple
    model_sd: np.ndarray | None = None
    shared_error: bool = False

    def subset(self, rows) -> FleetData:
        """The samples ``rows`` (a mask or indices); engines renumbered, order kept."""
        rows = np.asarray(rows)
        rows = np.flatnonzero(rows) if rows.dtype == bool else rows
        ids, inv = np.unique(self.unit[rows], return_inverse=True)
        return FleetData(self.w[rows], self.y[rows], self.sigma[rows], inv.astype(int),
                         tuple(self.units[i] for i in ids), self.condition[rows],
                         self.cycle[rows], self.channels,
                         None if self.model_sd is None else self.model_sd[rows],
                         self.shared_error)

    @property
    def n_units(self) -> int:
        return len(self.units)


@dataclass
class Shared:
    """The shared parameters to fit: ``free`` (indices into the candidate model's ``phi``),
    their prior std ``prior`` and bounds ``lower`` / ``upper``."""

    free: np.ndarray
    prior: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    @classmethod
    def none(cls) -> Shared:
        z = np.zeros(0)
        return cls(np.zeros(0, int), z, z, z)


@dataclass
class FleetFit:
    """The fit: ``phi`` (the candidate model's whole vector), ``delta`` (U, k) every engine's
    health, ``cov`` the posterior covariance of ``phi[free]`` (every engine's health
    marginalised out), ``residual`` (N, m) whitened, ``prediction`` (N, m), ``converged``
    (N,), ``cost`` L, ``history`` L after every accepted step.

    The rest of the posterior at the optimum (Laplace approximation, the Gauss-Newton matrix
    ``[[H_uu, H_ub], [H_ub^T, H_bb]]`` inverted block by block): given ``phi``, engine
    ``u``'s health is Gaussian with mean ``delta_u - health_gain[u] (phi - phi_hat)`` and
    covariance ``health_cov[u] = H_uu^-1`` (U, k, k); ``health_gain[u] = H_uu^-1 H_ub``
    (U, k, p). With ``cov`` this is the whole joint posterior, used for the uncertainty of a
    prediction (:func:`mean_prediction_std`). ``s_theta`` is the engines' prior std.

    With the model error shared (:attr:`FleetData.shared_error`): ``discrepancy`` (C, m) the
    offsets ``b`` (reading minus model) of the conditions ``discrepancy_conditions`` (C,)
    and channels, and, when they were fitted rather than held, the border of the posterior
    is ``[phi[free], b]`` (``border_cov``, and ``health_gain``'s last axis); ``cov`` is its
    ``phi`` block; ``cost`` includes ``b``'s prior, the residual in it whitened by the noise
    alone (the reported ``residual`` is the model's, by the combined std). Without it
    ``discrepancy`` is None and ``border_cov`` is ``cov``."""

    phi: np.ndarray
    delta: np.ndarray
    cov: np.ndarray
    residual: np.ndarray
    prediction: np.ndarray
    converged: np.ndarray
    cost: float
    shared: Shared
    history: list = field(default_factory=list)
    x: np.ndarray | None = field(default=None, repr=False)
    health_cov: np.ndarray | None = field(default=None, repr=False)
    health_gain: np.ndarray | None = field(default=None, repr=False)
    s_theta: float = S_THETA
    discrepancy: np.ndarray | None = None
    discrepancy_conditions: np.ndarray | None = None
    border_cov: np.ndarray | None = field(default=None, repr=False)

    @property
    def iterations(self) -> int:
        """Gauss-Newton steps taken (:data:`MAX_ITER`: stopped at the cap; fewer: stopped by
        the step or cost rule, which does not by itself prove the optimum reached)."""
        return len(self.history) - 1

    def chi2_per_sample(self) -> float:
        """Mean squared whitened residual over the converged samples and channels."""
        e = self.residual[self.converged]
        return float(np.mean(e ** 2)) if e.size else float("nan")

    @property
    def std(self) -> np.ndarray:
        """Posterior std of ``phi[free]``."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    @property
    def offsets(self):
        """``(conditions, b (C, m))`` with the model error shared (the start or the held
        offsets of another fit: :func:`fit_fleet`'s ``discrepancy0``), else None."""
        return None if self.discrepancy is None else \
            (self.discrepancy_conditions, self.discrepancy)


def evaluate(model, data: FleetData, delta, phi, derivatives=False, x0=None):
    """The model at every sample with its engine's ``delta`` and the shared ``phi``:
    ``(evaluation, whitened residual, usable)``; a sample that did not converge has a zero
    residual and ``usable`` False. Warm-started from ``x0`` when given (from the guess table
    when that fails)."""
    est = np.arange(len(THETA_NAMES))
    ev = model.evaluate(data.w, delta[data.unit], data.channels, phi, derivatives=derivatives,
                        x0=x0, est_idx=est)
    if x0 is not None and not ev.converged.all():
        ev = model.evaluate(data.w, delta[data.unit], data.channels, phi,
                            derivatives=derivatives, est_idx=est)
    e = (data.y - ev.y) / data.sigma
    ok = ev.converged & np.all(np.isfinite(e), axis=1)
    return ev, np.where(ok[:, None], e, 0.0), ok


@dataclass
class _Discrepancy:
    """The offsets ``b_cj`` of a fit whose model error is shared (module docstring): the
    ``conditions`` (C,) of the data, each sample's condition ``row`` (N,) into them, the prior
    std ``prior`` (C m,) of ``b`` flattened condition-major, and ``sigma`` (N, m) each
    sample's std without the model's error (the noise alone)."""

    conditions: np.ndarray
    row: np.ndarray
    prior: np.ndarray
    sigma: np.ndarray

    @classmethod
    def of(cls, data: FleetData) -> _Discrepancy | None:
        """The discrepancy of ``data``, or None when its model error is not shared (or it
        has none)."""
        if not data.shared_error:
            return None
        if data.model_sd is None:
            raise ValueError("a shared model error needs the model error (FleetData.model_sd)")
        conditions, row = np.unique(data.condition, return_inverse=True)
        s = np.stack([data.model_sd[row == i].mean(axis=0) for i in range(len(conditions))])
        if not np.all(s > 0) or not np.allclose(data.model_sd, s[row], rtol=1e-9):
            raise ValueError("a shared model error needs one positive model error per "
                             "condition and channel")
        noise = np.sqrt(np.maximum(data.sigma ** 2 - data.model_sd ** 2,
                                   (1e-6 * data.sigma) ** 2))
        return cls(conditions, row, s.ravel(), noise)

    @property
    def size(self) -> int:
        return len(self.prior)

    def start(self, given) -> np.ndarray:
        """The offsets (C m,) from ``given`` = ``(conditions, values (C', m))`` (a fit's
        :attr:`FleetFit.offsets`), matched by condition; 0 where ``given`` lacks one."""
        b = np.zeros((len(self.conditions), self.sigma.shape[1]))
        if given is not None:
            at = {int(c): i for i, c in enumerate(given[0])}
            for i, c in enumerate(self.conditions):
                if int(c) in at:
                    b[i] = given[1][at[int(c)]]
        return b.ravel()

    def offsets(self, b) -> np.ndarray:
        """``b`` (C m,) at every sample: (N, m)."""
        return np.asarray(b).reshape(len(self.conditions), -1)[self.row]

    def jacobian(self) -> np.ndarray:
        """d(model + b)/db over the noise's std: (N, m, C m), one nonzero per sample and
        channel."""
        n, m = self.sigma.shape
        J = np.zeros((n, m, self.size))
        col = self.row[:, None] * m + np.arange(m)[None, :]
        J[np.arange(n)[:, None], np.arange(m)[None, :], col] = 1.0 / self.sigma
        return J


def _normal_equations(ev, e, ok, sigma, delta, z, free, prior, s_theta, starts, extra=None):
    """Gauss-Newton blocks at the current point: per engine ``Huu`` (U, k, k), ``gu`` (U, k),
    ``Hub`` (U, k, P); shared ``Hbb`` (P, P), ``gb`` (P,) (gradients of ``-L``). The shared
    block ``z`` is ``phi[free]`` followed by a discrepancy's offsets, whose whitened Jacobian
    is ``extra`` (N, m, P - len(free)); ``sigma`` the likelihood's std."""
    k = len(THETA_NAMES)
    sig = sigma[:, :, None]
    A = np.where(ok[:, None, None], ev.d_theta / sig, 0.0)
    B = np.where(ok[:, None, None], ev.d_phi[:, :, free] / sig, 0.0)
    if extra is not None:
        B = np.concatenate([B, np.where(ok[:, None, None], extra, 0.0)], axis=2)
    Huu = np.add.reduceat(np.einsum("nmi,nmj->nij", A, A), starts, axis=0) \
        + np.eye(k)[None] / s_theta ** 2
    gu = np.add.reduceat(np.einsum("nmi,nm->ni", A, e), starts, axis=0) - delta / s_theta ** 2
    Hub = np.add.reduceat(np.einsum("nmi,nmj->nij", A, B), starts, axis=0)
    Hbb = np.einsum("nmi,nmj->ij", B, B) + np.diag(1.0 / prior ** 2)
    gb = np.einsum("nmi,nm->i", B, e) - z / prior ** 2
    return Huu, gu, Hub, Hbb, gb


def _step(Huu, gu, Hub, Hbb, gb, lam, frozen, frozen_u):
    """The damped step of every engine and of the shared block (Schur complement on the
    shared block, module docstring); ``frozen`` shared parameters and ``frozen_u`` (U, k)
    engine parameters (at a bound, pushed out) do not move."""
    k = Huu.shape[1]
    Hd = Huu + lam * np.diagonal(Huu, axis1=1, axis2=2)[:, :, None] * np.eye(k)[None]
    if frozen_u.any():
        keep = ~frozen_u
        Hd = Hd * keep[:, :, None] * keep[:, None, :] + np.eye(k)[None] * frozen_u[:, :, None]
        gu = gu * keep
        Hub = Hub * keep[:, :, None]
    Hinv = np.linalg.inv(Hd)
    if not len(gb):
        return np.zeros(0), np.einsum("uij,uj->ui", Hinv, gu)
    S = Hbb + lam * np.diag(np.diag(Hbb)) - np.einsum("uib,uij,ujc->bc", Hub, Hinv, Hub)
    r = gb - np.einsum("uib,uij,uj->b", Hub, Hinv, gu)
    S[frozen, :] = 0.0
    S[:, frozen] = 0.0
    S[frozen, frozen] = 1.0
    r[frozen] = 0.0
    db = np.linalg.solve(S, r)
    return db, np.einsum("uij,uj->ui", Hinv, gu - Hub @ db)


def _pushed_out(value, direction, lower, upper) -> np.ndarray:
    """Which of ``value`` sit on a bound that ``direction`` points out of."""
    return ((value <= lower) & (direction < 0)) | ((value >= upper) & (direction > 0))


def fit_fleet(model, data: FleetData, shared: Shared, phi0=None, delta0=None,
              s_theta: float = S_THETA, max_iter: int = MAX_ITER, x0=None,
              discrepancy0=None, hold_discrepancy: bool = False) -> FleetFit:
    """Minimise ``L`` (module docstring) over ``phi[shared.free]`` and every engine's
    ``delta`` (and, with the model error shared, the offsets ``b``); ``model`` a
    :class:`calibration.discrepancy.candidates.CandidateModel`. The other entries of ``phi``
    stay at ``phi0`` (``Shared.none()``: the engines only, under an adaptation fitted on
    others). With the model error shared, ``b`` starts at ``discrepancy0`` (another fit's
    :attr:`FleetFit.offsets`, matched by condition; 0 where it has none) and, with
    ``hold_discrepancy``, stays there (held-out engines under the offsets the other engines
    gave: the model's error at a condition is the same for every engine)."""
    k = len(THETA_NAMES)
    phi = np.zeros(model.n_phi) if phi0 is None else np.array(phi0, float)
    delta = np.zeros((data.n_units, k)) if delta0 is None else np.array(delta0, float)
    free = shared.free
    p = len(free)
    starts = np.searchsorted(data.unit, np.arange(data.n_units))
    disc = _Discrepancy.of(data)
    held = None if disc is None else disc.start(discrepancy0)
    if disc is None or hold_discrepancy:
        lik, extra = data, None
        prior, lower, upper = shared.prior, shared.lower, shared.upper
        if disc is not None:  # the offsets held: the readings shifted, the noise alone
            lik = replace(data, sigma=disc.sigma, y=data.y - disc.offsets(held))
        z = phi[free].copy()
    else:
        lik, extra = replace(data, sigma=disc.sigma), disc.jacobian()
        unbounded = np.full(disc.size, np.inf)
        prior = np.concatenate([shared.prior, disc.prior])
        lower = np.concatenate([shared.lower, -unbounded])
        upper = np.concatenate([shared.upper, unbounded])
        z = np.concatenate([phi[free], held])

    def at(zz):
        ph = phi.copy()
        ph[free] = zz[:p]
        return ph

    def shifted(zz):
        return lik if extra is None else replace(lik, y=lik.y - disc.offsets(zz[p:]))

    def cost_of(e, dl, zz):
        return 0.5 * float(np.sum(e ** 2) + np.sum((dl / s_theta) ** 2)
                           + np.sum((zz / prior) ** 2))

    ev, e, ok = evaluate(model, shifted(z), delta, at(z), True, x0)
    cost = cost_of(e, delta, z)
    history = [cost]
    lam = 1e-3
    for _ in range(max_iter):
        blocks = _normal_equations(ev, e, ok, lik.sigma, delta, z, free, prior, s_theta,
                                   starts, extra)
        gu, gb = blocks[1], blocks[4]  # descent directions (gradients of -L)
        # the active set (Bertsekas 1982): a parameter at a bound that the gradient pushes
        # out is held there for this iteration
        at_bound = _pushed_out(z, gb, lower, upper)
        at_bound_u = _pushed_out(delta, gu, THETA_LO, THETA_HI)
        accepted = False
        while lam <= 1e8:
            db, dd = _step(*blocks, lam, at_bound, at_bound_u)
            # and so is one that the step, coupled to the others, pushes out
            frozen = at_bound | _pushed_out(z, db, lower, upper)
            frozen_u = at_bound_u | _pushed_out(delta, dd, THETA_LO, THETA_HI)
            if (frozen != at_bound).any() or (frozen_u != at_bound_u).any():
                db, dd = _step(*blocks, lam, frozen, frozen_u)
            new_z = np.clip(z + db, lower, upper)
            new_delta = np.clip(delta + dd, THETA_LO, THETA_HI)
            ev2, e2, ok2 = evaluate(model, shifted(new_z), new_delta, at(new_z), False, ev.x)
            cost2 = cost_of(e2, new_delta, new_z)
            if cost2 < cost and ok2.sum() >= ok.sum():
                accepted = True
                break
            lam *= 10.0
        if not accepted:
            break
        decrease = (cost - cost2) / max(cost, 1e-300)
        delta, z, cost = new_delta, new_z, cost2
        ev, e, ok = evaluate(model, shifted(z), delta, at(z), True, ev2.x)
        history.append(cost)
        lam = max(lam / 10.0, 1e-9)
        if decrease < REL_TOL:
            break
    Huu, _, Hub, Hbb, _ = _normal_equations(ev, e, ok, lik.sigma, delta, z, free, prior,
                                            s_theta, starts, extra)
    health_cov = np.linalg.inv(Huu)
    health_gain = np.einsum("uij,ujb->uib", health_cov, Hub)
    border_cov = np.linalg.pinv(Hbb - np.einsum("uib,uic->bc", Hub, health_gain)) \
        if len(z) else np.zeros((0, 0))
    if disc is not None:  # the model's own residual (b left out), whitened by the whole std
        e = np.where(ok[:, None], (data.y - ev.y) / data.sigma, 0.0)
    offsets = None if disc is None else \
        (held if extra is None else z[p:]).reshape(len(disc.conditions), -1)
    return FleetFit(at(z), delta, border_cov[:p, :p], e, ev.y, ok, cost, shared, history,
                    ev.x, health_cov, health_gain, s_theta, offsets,
                    None if disc is None else disc.conditions, border_cov)


def mean_prediction_std(fit: FleetFit, ev, data: FleetData, engine, usable) -> np.ndarray:
    """Std (m,) of the difference between the mean prediction of every channel over the
    ``usable`` samples of ``data`` (samples of **one** operating condition, as
    :func:`.selection.condition_out` passes them: the model-error term below treats them as
    sharing one error) and the mean of their readings, under the posterior of
    ``fit`` (Laplace, :class:`FleetFit`), the readings' noise and the model's own error.

    ``ev`` is the model's evaluation of ``data`` at ``fit``'s parameters with derivatives;
    ``engine`` (U_data,) the row of each of ``data``'s engines in ``fit.delta``, or -1 for an
    engine the fit did not see (its health then has its prior, ``s_theta``, and no
    correlation with ``phi``). A sample ``n`` of engine ``u`` moves with the shared
    parameters through ``G_n = J_phi,n - J_delta,n health_gain[u]`` and with the health of
    its engine, independent across engines given ``phi``, through ``J_delta,n``; with
    ``N`` usable samples and ``a_u = sum_(n in u) J_delta,n / N``::

        var_j = g_j cov g_j^T + sum_u a_u,j health_cov[u] a_u,j^T
                + sum_n (sigma_nj^2 - s_nj^2) / N^2 + (sum_n s_nj / N)^2,
        g_j = sum_n G_n,j / N

    (the prediction's variance from the shared parameters and from every engine's health;
    the readings' noise, which averages over the samples; the model's own error ``s =
    data.model_sd``, which does not: the samples of one operating condition share it, Kennedy
    & O'Hagan's discrepancy being a function of the operating point). With the model error
    shared in ``fit``, the shared parameters include the fitted offsets ``b`` of the
    conditions it saw (``fit.border_cov``), on which the prediction of a condition it did not
    see depends only through the engines' health; ``data`` must be such a condition. A
    parameter held at a bound is treated as free (the curvature at the optimum). The std is
    the fit's own statement of how well it knows the prediction: a mean error of many such
    stds says that its candidates, priors or model error do not hold there."""
    rows = np.flatnonzero(usable)
    if not len(rows):
        return np.full(len(data.channels), np.nan)
    border = fit.health_gain.shape[2]
    if border > len(fit.shared.free) and np.isin(data.condition[rows],
                                                 fit.discrepancy_conditions).any():
        raise ValueError("mean_prediction_std: the fit's offsets were fitted at these "
                         "samples' condition; it predicts a condition the fit did not see")
    n_rows = len(rows)
    k = len(THETA_NAMES)
    Jd = ev.d_theta[rows]
    Jp = np.zeros((n_rows, len(data.channels), border))
    Jp[:, :, :len(fit.shared.free)] = ev.d_phi[rows][:, :, fit.shared.free]
    eng = np.asarray(engine)[data.unit[rows]]
    seen = eng >= 0
    gain = np.zeros((n_rows, k, border))
    gain[seen] = fit.health_gain[eng[seen]]
    g = (Jp - np.einsum("nmk,nkb->nmb", Jd, gain)).sum(axis=0) / n_rows
    cov = fit.cov if fit.border_cov is None else fit.border_cov
    var = np.einsum("mb,bc,mc->m", g, cov, g) if border else 0.0
    for u in np.unique(data.unit[rows]):
        mine = data.unit[rows] == u
        a = Jd[mine].sum(axis=0) / n_rows
        cu = fit.health_cov[eng[mine][0]] if eng[mine][0] >= 0 \
            else np.eye(k) * fit.s_theta ** 2
        var = var + np.einsum("mk,kl,ml->m", a, cu, a)
    sd = np.zeros_like(data.sigma[rows]) if data.model_sd is None else data.model_sd[rows]
    var = var + np.sum(data.sigma[rows] ** 2 - sd ** 2, axis=0) / n_rows ** 2 \
        + sd.mean(axis=0) ** 2
    return np.sqrt(var)
