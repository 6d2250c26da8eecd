"""The discrepancy loop: null fit, noise check, screen, confirm, identify, iterate, and what
remains (the package docstring gives the design and its references)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from calibration.base import ESTIMATORS
from calibration.estimation_setup import CalibrationSetup
from engine_model.channels import THETA_NAMES
from engine_model.validation import InputError, check_seed

from . import identifiability as ident
from .candidates import CandidateModel, build_candidates
from .confirm import confirm, holdout_masks
from .drift_mle import drift_mle
from .max_stat import screen
from .noise_check import check_noise
from .null_fit import FitState, Problem, coarse_start, fit, unit_data, warm_start
from .score_statistics import efficient_scores
from .unknown import structure

VERDICTS = ("nothing missing", "explained", "partly explained", "unknown effect", "ambiguous")
# two non-nested candidates are told apart when their maximised log-likelihoods differ by
# more than this (a likelihood ratio of e^5 ~ 150: "decisive" on Jeffreys' (1961) scale)
AMBIGUOUS_LOGLIK = 5.0
MAX_CONFIRM_TRIES = 3


@dataclass
class DiscoverOptions:
    """``method`` of the warm start (``coarse``: the same fit on every 16th sample,
    :func:`.null_fit.coarse_start`; or an estimator: ``mhe``, ``ukf``, ``ekf``, ``map_cycle``);
    ``candidates`` registry names (None: the library's steady and sensor effects);
    ``alpha`` family-wise level per dataset; ``max_effects`` to add; ``drift`` ``"mle"`` or
    a fixed q per sqrt(hour) (None: the setup's); ``noise`` ``"check"`` (scale the flagged
    channels' R) or ``"documented"``; ``n_draws`` and ``seed`` of the family-wise
    sampling; ``holdout_every`` (every n-th cycle held out)."""

    method: str = "coarse"
    candidates: tuple | None = None
    alpha: float = 0.01
    max_effects: int = 3
    drift: float | str | None = "mle"
    noise: str = "check"
    n_draws: int = 20000
    seed: int = 0
    holdout_every: int = 3

    def __post_init__(self):
        check_seed(self.seed, "discover seed")
        if self.method != "coarse" and self.method not in ESTIMATORS:
            raise InputError(f"method {self.method!r}: 'coarse' or one of "
                             f"{', '.join(ESTIMATORS)}")
        if not 0.0 < self.alpha < 0.5:
            raise InputError(f"alpha {self.alpha}: expected a level between 0 and 0.5")
        if self.max_effects < 0:
            raise InputError(f"max_effects {self.max_effects}: expected 0 or more")
        if self.noise not in ("check", "documented"):
            raise InputError(f"noise {self.noise!r}: 'check' or 'documented'")
        if isinstance(self.drift, str) and self.drift != "mle":
            raise InputError(f"drift {self.drift!r}: 'mle' or a number")
        if not isinstance(self.drift, str) and self.drift is not None and not self.drift > 0:
            raise InputError(f"drift {self.drift}: must be positive")


@dataclass
class Discovery:
    """What :func:`discover` found (``to_dict`` gives the JSON report)."""

    verdict: str
    found: list
    ambiguous: list
    unknown: dict
    before: dict
    after: dict
    screens: list
    noise: dict
    drift: dict
    theta_error: dict | None
    rejected: list
    diagnostics: dict = field(default_factory=dict)
    plots: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"verdict": self.verdict, "found": self.found, "ambiguous": self.ambiguous,
                "unknown": self.unknown, "before": self.before, "after": self.after,
                "theta_error": self.theta_error, "noise": self.noise, "drift": self.drift,
                "screens": self.screens, "rejected": self.rejected,
                "diagnostics": self.diagnostics}

    def to_json(self) -> str:
        """The report as JSON (``discover.json``, NaN as null)."""
        import json

        from engine_model.datasets.jsonable import jsonable

        return json.dumps(jsonable(self.to_dict()), indent=2, allow_nan=False)

    def to_frame(self) -> pd.DataFrame:
        """One row per candidate and screening iteration: ``iteration``, ``candidate``,
        ``effect``, score ``statistic``, ``df``, ``p_value``, ``significant`` and whether it
        was ``added`` to the model."""
        added = {f["name"] for f in self.found}
        rows = [{"iteration": s["iteration"], "candidate": c["name"], "effect": c["effect"],
                 "statistic": c["statistic"], "df": c["df"], "p_value": c["p_value"],
                 "significant": c["significant"], "added": c["name"] in added}
                for s in self.screens for c in s["candidates"]]
        return pd.DataFrame(rows, columns=["iteration", "candidate", "effect", "statistic",
                                           "df", "p_value", "significant", "added"])


def _channel_stats(problem: Problem, state: FitState, masks=None) -> dict:
    """Per channel on the (masked) samples: RMSE and bias of the whitened residual (noise
    units), lag-1 autocorrelation within flights, and chi^2 per degree of freedom overall.

    The degrees of freedom are the samples' residuals less what was fitted to them: on every
    sample, every flight's theta and the shared parameters; on held-out flights (``masks``),
    only those flights' own theta (the shared parameters were estimated without them). With
    one sample per flight (C-MAPSS) the flights' theta are a large part of the count: taking
    every flight's off the held-out samples' residuals left no degree of freedom (and a
    chi^2 "per dof" that was the plain sum)."""
    lin = problem.masked(state.lin, masks)  # the fit's own residual: no model run
    es, lag = [], []
    held_flights = 0
    for i, (u, e) in enumerate(zip(problem.units, lin.e, strict=True)):
        sel = lin.ok[i] & (masks[i] > 0 if masks is not None else True)
        es.append(e[sel])
        held_flights += len(np.unique(u.cyc[sel]))
        cyc = u.cyc[sel]
        same = cyc[1:] == cyc[:-1]
        lag.append((e[sel][1:][same], e[sel][:-1][same]))
    e = np.concatenate(es)
    n = len(e)
    a = np.concatenate([x for x, _ in lag])
    b = np.concatenate([y for _, y in lag])
    ch = {}
    for j, s in enumerate(problem.sensors):
        den = float(np.sum(e[:, j] ** 2)) or 1.0
        ch[s] = {"rmse": float(np.sqrt(np.mean(e[:, j] ** 2))) if n else None,
                 "bias": float(np.mean(e[:, j])) if n else None,
                 "lag1": float(np.sum(a[:, j] * b[:, j]) / den) if n else None}
    fitted = problem.k * held_flights if masks is not None \
        else problem.n_theta + len(state.free)
    dof = max(n * problem.m - fitted, 1)
    return {"samples": int(n), "chi2_per_dof": float(np.sum(e * e) / dof), "channels": ch}


def _excess(problem: Problem, state: FitState) -> float:
    """The residual's chi-square excess over its expectation under the noise model."""
    n = sum(int(ok.sum()) for ok in state.lin.ok)
    return float(state.lin.sse - (n * problem.m - problem.n_theta - len(state.free)))


def _theta_error(problem: Problem, frames, state: FitState) -> dict | None:
    """theta_hat per cycle against the truth (simulated data carry the true theta)."""
    names = problem.setup.params
    if not all(all(q in f.columns for q in names) for f in frames):
        return None
    errs = []
    for u, f, th in zip(problem.units, frames, state.Theta, strict=True):
        true = np.zeros((u.n_cycles, problem.k))
        vals = f[list(names)].to_numpy(float)
        np.add.at(true, u.cyc, vals)
        true /= np.bincount(u.cyc, minlength=u.n_cycles)[:, None]
        errs.append(th - true)
    e = np.vstack(errs)
    return {q: {"bias": float(e[:, j].mean()), "rmse": float(np.sqrt(np.mean(e[:, j] ** 2)))}
            for j, q in enumerate(names)}


def _screen_table(res, reports) -> list:
    rows = []
    for i in res.order():
        c = res.candidates[i]
        rows.append({"name": c.name, "effect": c.registry_name, "statistic": float(res.T[i]),
                     "df": int(res.df[i]), "p_value": float(res.p[i]),
                     "significant": bool(res.p[i] <= res.p_crit),
                     "one_step": {q: float(v) for q, v in zip(c.params, res.phi1[i],
                                                             strict=True)},
                     **reports[c.name]})
    return rows


def discover(frames: list[pd.DataFrame], setup: CalibrationSetup | None = None,
             options: DiscoverOptions | None = None, design=None, base_model=None,
             source=None, progress=None, fixed_effects=()) -> Discovery:
    """Run the loop on the units ``frames`` (one DataFrame per unit, hyprog names).

    ``fixed_effects`` (effect instances or specifications, e.g. an adapted model's,
    :mod:`calibration.adaptation`) are in the model at their values throughout: the loop
    looks for what *that* model lacks. A candidate with the name of a fixed effect is not
    tested (it is already in)."""
    t0 = time.perf_counter()
    o = options or DiscoverOptions()
    setup = setup or CalibrationSetup()
    say = progress or (lambda msg: None)
    from engine_model.physics.effects import parse_effect_spec

    fixed = [parse_effect_spec(e) if isinstance(e, str) else e for e in fixed_effects]
    if base_model is None:
        from engine_model.runtime.shared_model import default_model

        base_model = default_model()
    design = design or getattr(base_model, "design", None)
    if fixed:  # the warm start's estimator runs on the adapted model too
        from engine_model import EngineModel

        base_model = EngineModel(design=design, effects=fixed)
    if isinstance(o.drift, float | int) and not isinstance(o.drift, bool):
        from dataclasses import replace

        setup = replace(setup, drift=float(o.drift))
    units = [unit_data(f, setup, source) for f in frames]
    sensors = units[0].series.sensors
    carried, cands = build_candidates(o.candidates, sensors,
                                      all(u.cycle is not None for u in units))
    if fixed:
        names = {e.name for e in fixed}
        carried = [c for c in carried if c.name not in names]
        cands = [c for c in cands if c.name not in names]
        k = 0
        for c in carried:
            c.index = np.arange(k, k + len(c.params))
            k += len(c.params)
    say(f"building the candidate model ({len(cands)} candidates to test)")
    cm = CandidateModel(carried, design=design, fixed=fixed)
    problem = Problem(units, setup, cm)
    say(f"null fit: warm start {o.method}")
    phi0 = np.zeros(cm.n_phi)
    Theta0 = (coarse_start(problem, phi0) if o.method == "coarse" else
              warm_start(problem, frames, o.method, base_model))
    null = fit(problem, Theta0, phi0)
    noise = {"checked": o.noise == "check"}
    if o.noise == "check":
        flights = [u.cyc for u in units]
        nc = check_noise(null.lin.e, flights, null.lin.ok, sensors, o.alpha)
        noise.update({k: v for k, v in nc.items() if k != "scale"})
        noise["scale"] = dict(zip(sensors, map(float, nc["scale"]), strict=True))
        if np.any(nc["scale"] != 1.0):
            problem.scale = nc["scale"]
            null = fit(problem, null.Theta, null.phi, xs=null.lin.x)
    drift = {"method": "mle" if o.drift == "mle" else "given", "q": problem.q}

    def update_drift(state, accepted):
        if o.drift != "mle":
            return state
        problem.q = drift_mle(problem, state)
        # q enters the prior only: the model's linearisation at the state is unchanged
        state = fit(problem, state.Theta, state.phi, accepted, xs=state.lin.x,
                    lin=state.lin)
        drift["q"] = problem.q
        return state

    say("estimating the drift rate" if o.drift == "mle" else "null fit")
    null = update_drift(null, np.zeros(0, int))
    first_null = null
    masks = holdout_masks(problem, o.holdout_every)
    accepted = np.zeros(0, int)
    last_train = None
    found, ambiguous, rejected, screens = [], [], [], []
    done_names: set = set()
    it = 0
    while len(found) < o.max_effects:
        it += 1
        remaining = [c for c in cands if c.name not in done_names]
        if not remaining:
            break
        scores = efficient_scores(problem, null, accepted)
        res = screen(scores, remaining, o.alpha, o.n_draws, o.seed + it)
        reports = {c.name: ident.candidate_report(scores, c, res.p_crit, int(res.df[i]),
                                                  setup.params, problem.n_theta)
                   for i, c in enumerate(remaining)}
        screens.append({"iteration": it, "p_crit": res.p_crit,
                        "candidates": _screen_table(res, reports)})
        sig = [i for i in res.order() if res.p[i] <= res.p_crit
               and not reports[res.candidates[i].name]["absorbed"]]
        say(f"iteration {it}: {len(sig)} significant candidate(s)")
        if not sig:
            break
        cache: dict = {}

        def null_train(state=null, acc=accepted, cache=cache):
            if "fit" not in cache:
                cache["fit"] = fit(problem, state.Theta, state.phi, acc, masks=masks[0],
                                   xs=state.lin.x, lin=state.lin)
            return cache["fit"]

        excess = _excess(problem, null)
        excess_sd = float(np.sqrt(2.0 * sum(int(ok.sum()) for ok in null.lin.ok) * problem.m))
        chosen = None
        for i in sig[:MAX_CONFIRM_TRIES]:
            c = res.candidates[i]
            conf = confirm(problem, null, c, res.phi1[i], res.weights[i], res.p_crit,
                           accepted, masks, null_train, excess, excess_sd)
            if conf.accepted:
                chosen = (i, conf)
                break
            rejected.append({"iteration": it, "name": c.name, "reason": conf.reason})
            done_names.add(c.name)
        if chosen is None:
            break
        i, conf = chosen
        c = res.candidates[i]
        # ambiguity: another significant candidate with a nearly parallel projected signature
        amb = []
        for i2 in sig:
            c2 = res.candidates[i2]
            if i2 == i:
                continue
            rho, _, _ = ident.canonical_corr(scores, c, c2)
            if rho < ident.AMBIGUOUS_CORR:
                continue
            conf2 = confirm(problem, null, c2, res.phi1[i2], res.weights[i2], res.p_crit,
                            accepted, None)
            if abs(conf.fit.L - conf2.fit.L) < AMBIGUOUS_LOGLIK:
                amb.append({"candidates": [c.name, c2.name], "correlation": rho,
                            "loglik_difference": float(conf2.fit.L - conf.fit.L),
                            "separating_points": ident.separating_points(
                                problem, null, scores, c, c2)})
        if amb:
            ambiguous.extend(amb)
            break
        before = _channel_stats(problem, null)
        after = _channel_stats(problem, conf.fit)
        found.append({
            "name": c.name, "effect": c.registry_name,
            "spec": c.spec(conf.phi),
            "params": {q: float(v) for q, v in zip(c.params, conf.phi, strict=True)},
            "std": {q: float(v) for q, v in zip(c.params, conf.std, strict=True)},
            "ci95": {q: [float(a), float(b)] for q, (a, b) in zip(c.params, conf.ci,
                                                                  strict=True)},
            "fixed": {q: float(c.effect.values[q]) for q in c.fixed},
            "p_value": conf.p_value, "score_p_value": float(res.p[i]),
            "likelihood_ratio": conf.LR, "explained_share": conf.share,
            "held_out_sse": {"without": conf.sse_held_null, "with": conf.sse_held_alt},
            "residual_before": {k: v["rmse"] for k, v in before["channels"].items()},
            "residual_after": {k: v["rmse"] for k, v in after["channels"].items()},
            "iteration": it})
        done_names.add(c.name)
        accepted = np.concatenate([accepted, c.index]).astype(int)
        say(f"added {c.spec(conf.phi)}")
        last_train = conf.train_fit if o.drift != "mle" else None
        null = update_drift(conf.fit, accepted)
    final = null
    if found:
        # every added effect's parameters from the final joint fit (an effect added later
        # changes the estimate of an earlier one); the values at the time it was added kept
        from .confirm import parameter_cov

        cov = parameter_cov(problem, final)
        free = list(final.free)
        by_name = {c.name: c for c in cands}
        for f in found:
            c = by_name[f["name"]]
            pos = [free.index(i) for i in c.index]
            sd = np.sqrt(np.clip(np.diag(cov)[pos], 0, None))
            ph = final.phi[c.index]
            f["params_when_added"], f["std_when_added"] = f["params"], f["std"]
            f["params"] = {q: float(v) for q, v in zip(c.params, ph, strict=True)}
            f["std"] = {q: float(v) for q, v in zip(c.params, sd, strict=True)}
            f["ci95"] = {q: [float(max(v - 1.96 * e, lo)), float(min(v + 1.96 * e, hi))]
                         for q, v, e, lo, hi in zip(c.params, ph, sd, c.lower, c.upper,
                                                    strict=True)}
            f["spec"] = c.spec(ph)
    leftover = structure(final.lin.e, [(u, ok) for u, ok in zip(units, final.lin.ok,
                                                                strict=True)],
                         sensors, o.alpha, problem.n_theta + len(final.free),
                         [s in noise.get("channels", {}) for s in sensors])
    if masks is not None:
        # effect parameters estimated without the held-out flights, theta fitted on every
        # flight (a per-flight nuisance), residual of the held-out flights (confirm docstring)
        train, held = masks
        before = {"on": "held-out flights", **_channel_stats(problem, first_null, held)}
        if found:
            a_train = last_train or fit(problem, final.Theta, final.phi, accepted,
                                        masks=train, xs=final.lin.x, lin=final.lin)
            a_fit = fit(problem, final.Theta, a_train.phi, (), xs=final.lin.x)
            after = {"on": "held-out flights", **_channel_stats(problem, a_fit, held)}
        else:
            after = before
    else:
        before = {"on": "all samples (no held-out flights)",
                  **_channel_stats(problem, first_null)}
        after = {"on": "all samples (no held-out flights)", **_channel_stats(problem, final)}
    th_before = _theta_error(problem, frames, first_null)
    th_after = _theta_error(problem, frames, final)
    theta_error = None if th_before is None else {"before": th_before, "after": th_after}
    has_structure = bool(leftover["structure"])
    if ambiguous:
        verdict = "ambiguous"
    elif found:
        verdict = "partly explained" if has_structure else "explained"
    else:
        verdict = "unknown effect" if has_structure else "nothing missing"
    unknown = ({"channels": leftover["structure"], "hint": leftover["hint"]}
               if has_structure else {})
    diag = {"seconds": time.perf_counter() - t0, "units": [u.series.unit for u in units],
            "samples": int(sum(u.n for u in units)), "sensors": list(sensors),
            "params": list(setup.params), "method": o.method, "alpha": o.alpha,
            "candidates": [c.name for c in cands],
            "held_out": masks is not None, "tests": leftover["channels"],
            "nonconverged": final.n_nonconverged,
            "theta_names": list(THETA_NAMES),
            "model_effects": [e.spec() for e in fixed]}
    out = Discovery(verdict, found, ambiguous, unknown, before, after, screens, noise, drift,
                    theta_error, rejected, diag)
    out.plots = {"problem": problem, "before": first_null, "after": final}
    return out
