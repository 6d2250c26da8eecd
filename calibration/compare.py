"""Compare estimators against the truth and the Cramér-Rao bound on simulated data.

    from calibration.compare import compare, format_report
    report = compare("fleet/", methods=("ukf", "ekf", "mhe", "map_cycle"), jobs=2)
    print(format_report(report))

The data must carry the true theta columns of the estimated parameters (the simulator writes
them; real data do not have them, and the estimators never read them). Per method and
estimated parameter, over all samples of all units:

``rmse``, ``bias``   of ``theta_hat - theta_true``
``consistency``      fraction of samples with ``|theta_hat - theta_true| <= 1.96 std`` (the
                     estimator's own reported std; 0.95 for a consistent estimator)
``std``              mean reported standard deviation
``crb``              the Cramér-Rao bound under the estimator's own assumptions, with exact
                     sensitivities at the **true** theta (:mod:`calibration.crb`), as the RMS
                     over samples of the bound's standard deviation: the recursive posterior
                     bound for the random-walk filters (with the setup's drift model,
                     ``drift_per``) and the random-walk MHE (``posterior_time``: its walk is
                     in operating time, whatever ``drift_per``), the inverse
                     Fisher information of each window with the arrival information carried
                     from window to window for the constant-theta MHE, and the inverse of each
                     cycle's Fisher information plus the prior for ``map_cycle``
``ratio``            ``rmse / crb`` (1 is the best an unbiased estimator can do)

and per method: residual whiteness (the lag-1 autocorrelation of the normalised residuals
within each flight, averaged over sensors and units, ~0 for white residuals, and their mean
variance, ~1 for filter innovations when R is right), samples, non-converged samples or
windows, wall time and samples per second of the calibration itself (the bound is computed
afterwards and not timed), and the RMSE of each unit.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

from engine_model import datasets
from engine_model.validation import InputError

from .base import default_model
from .calibrate_fleet import calibrate_fleet, checked_frame
from .crb import posterior_crb, unit_sensitivities, windowed_crb
from .estimation_setup import CalibrationSetup
from .series import prepare_unit

DEFAULT_METHODS = ("ukf", "ekf", "mhe", "map_cycle")


def _bound_kind(method: str, options: dict) -> str:
    if method in ("ukf", "ekf"):
        return "posterior"
    if method == "map_cycle":
        return "cycle"
    # the random-walk MHE walks in operating time whatever ``drift_per`` (mhe docstring)
    return "posterior_time" if options.get("mode", "constant") == "random_walk" else "window"


def _window_labels(n: int, diag: dict) -> np.ndarray:
    """Per-sample label of the window whose estimate a sample reports (mhe diagnostics:
    ``window_starts`` and ``window_ends``, the end of the samples each window reports)."""
    labels = np.zeros(n, int)
    for i, (a, b) in enumerate(zip(diag["window_starts"], diag["window_ends"], strict=True)):
        labels[a:b] = i
    return labels


def unit_bound(model, df: pd.DataFrame, setup: CalibrationSetup, kind: str, diag: dict,
               S: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample bound variances (N, k) of ``setup.params`` for one unit (module docstring)
    and the sensitivities used (to reuse them for another method)."""
    series = prepare_unit(df, setup)
    if S is None:
        S = unit_sensitivities(model, series, setup, df[list(setup.params)].to_numpy(float))
    prior = np.diag(setup.prior_std_vec() ** 2)
    if kind == "posterior":
        cov = posterior_crb(S, series.q_diag(setup), prior)
    elif kind == "posterior_time":
        cov = posterior_crb(S, setup.drift ** 2 * series.dt_h, prior)
    elif kind == "cycle":
        cov = windowed_crb(S, series.cycle, prior, arrival=False)
    else:
        cov = windowed_crb(S, _window_labels(len(df), diag), prior, arrival=True,
                           q_var=series.q_diag(setup))
    return np.diagonal(cov, axis1=1, axis2=2), S


def _lag1(r: np.ndarray, cycle: np.ndarray | None) -> float:
    """Mean over columns of the lag-1 autocorrelation of ``r`` (N, m) within cycles."""
    r = np.asarray(r, float)
    if len(r) < 3:
        return float("nan")
    same = np.ones(len(r) - 1, bool) if cycle is None else cycle[1:] == cycle[:-1]
    a, b = r[:-1][same], r[1:][same]
    ok = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    a, b = a[ok], b[ok]
    if len(a) < 2:
        return float("nan")
    a = a - a.mean(axis=0)
    b = b - b.mean(axis=0)
    den = np.sqrt((a ** 2).sum(axis=0) * (b ** 2).sum(axis=0))
    rho = np.where(den > 0, (a * b).sum(axis=0) / np.where(den > 0, den, 1), np.nan)
    return float(np.nanmean(rho))


def compare(data, methods: Sequence[str] = DEFAULT_METHODS, setup: CalibrationSetup | None = None,
            options: dict | None = None, units: Sequence[int] | None = None, jobs: int = 1,
            scheduler=None, progress: Callable[[str, int, int], None] | None = None) -> dict:
    """Run ``methods`` on ``data`` (path or DataFrame with true theta) and compare (module
    docstring). ``options``: method -> estimator options. Returns a JSON-ready report."""
    setup = setup or CalibrationSetup()
    options = options or {}
    if isinstance(data, pd.DataFrame):
        data = checked_frame(data)
        df_all = data if units is None else data[data["unit"].isin(units)]
        source = "data"
    else:
        df_all, _ = datasets.read_dataset(data, units=units)
        source = str(data)
    missing = [q for q in setup.params if q not in df_all.columns]
    if missing:
        raise InputError(f"{source}: compare needs the true values of {', '.join(missing)} "
                         "(simulated data carry them as columns)")
    frames = {int(u): g.reset_index(drop=True) for u, g in df_all.groupby("unit", sort=True)}
    model = default_model()
    report = {"data": source, "units": sorted(frames), "samples": int(len(df_all)),
              "params": list(setup.params), "drift": setup.drift,
              "jobs": jobs, "methods": {}}
    S_cache: dict = {}
    for method in methods:
        opts = dict(options.get(method, {}))
        cb = None if progress is None else (lambda d, n, m=method: progress(m, d, n))
        t0 = time.perf_counter()
        run = calibrate_fleet(df_all, method, setup, opts, jobs=jobs, scheduler=scheduler,
                              progress=cb)
        wall = time.perf_counter() - t0
        kind = _bound_kind(method, opts)
        errs, stds, bounds, lag1, rvar, nonconv, per_unit = [], [], [], [], [], 0, {}
        unobservable = set()
        for u, df in frames.items():
            res = run.results[u]
            truth = df[list(setup.params)].to_numpy(float)
            errs.append(res.theta_hat.to_numpy() - truth)
            per_unit[u] = {"samples": len(df), **{
                q: float(np.sqrt(np.nanmean(errs[-1][:, j] ** 2)))
                if np.isfinite(errs[-1][:, j]).any() else None
                for j, q in enumerate(setup.params)}}
            stds.append(res.theta_std.to_numpy())
            var, S_cache[u] = unit_bound(model, df, setup, kind, res.diagnostics,
                                         S_cache.get(u))
            bounds.append(var)
            r = res.residuals.to_numpy()
            cyc = df["cycle"].to_numpy() if "cycle" in df.columns else None
            lag1.append(_lag1(r, cyc))
            rvar.append(float(np.nanmean(r ** 2)))
            nonconv += int(res.diagnostics.get("n_nonconverged", 0))
            unobservable.update(res.unobservable)
        e, s, b = np.concatenate(errs), np.concatenate(stds), np.concatenate(bounds)
        per = {}
        for j, q in enumerate(setup.params):
            ok = np.isfinite(e[:, j])
            if not ok.any():
                per[q] = {"rmse": None, "bias": None, "consistency": None, "std": None,
                          "crb": None, "ratio": None, "unobservable": True}
                continue
            rmse = float(np.sqrt(np.mean(e[ok, j] ** 2)))
            crb = float(np.sqrt(np.mean(b[ok, j])))
            per[q] = {"rmse": rmse, "bias": float(np.mean(e[ok, j])),
                      "consistency": float(np.mean(np.abs(e[ok, j]) <= 1.96 * s[ok, j])),
                      "std": float(np.mean(s[ok, j])), "crb": crb,
                      "ratio": rmse / crb if crb > 0 else None, "unobservable": False}
        report["methods"][method] = {
            "options": opts, "bound": kind, "params": per,
            "residual_lag1_autocorrelation": float(np.nanmean(lag1)),
            "residual_variance": float(np.nanmean(rvar)),
            "n_nonconverged": nonconv, "unobservable": sorted(unobservable),
            "seconds": wall, "samples_per_second": run.samples / wall if wall > 0 else None,
            "workers": run.workers, "rmse_per_unit": per_unit,
        }
    return report


def format_report(report: dict) -> str:
    """The comparison as markdown tables (one per method)."""
    lines = [f"data: {report['data']}, units {report['units']}, {report['samples']:,} samples;"
             f" drift q = {report['drift']:g} per sqrt(h)"]

    def f(v, fmt):
        return "-" if v is None else format(v, fmt)

    for method, m in report["methods"].items():
        lines += ["", f"### {method} (bound: {m['bound']})", "",
                  "| parameter | RMSE | bias | consistency (95 %) | mean std | CRB | RMSE / CRB |",
                  "|---|---|---|---|---|---|---|"]
        for q, p in m["params"].items():
            if p["unobservable"]:
                lines.append(f"| {q} | unobservable | | | | | |")
                continue
            lines.append(f"| {q} | {f(p['rmse'], '.2e')} | {f(p['bias'], '+.2e')} | "
                         f"{f(p['consistency'], '.3f')} | {f(p['std'], '.2e')} | "
                         f"{f(p['crb'], '.2e')} | {f(p['ratio'], '.2f')} |")
        lines += ["", f"run time {m['seconds']:.1f} s ({m['workers']} worker(s)), "
                  f"{f(m['samples_per_second'], ',.0f')} samples/s; non-converged "
                  f"{m['n_nonconverged']}; residual lag-1 autocorrelation "
                  f"{m['residual_lag1_autocorrelation']:+.3f}, variance "
                  f"{m['residual_variance']:.2f}", "",
                  "| unit | samples | " + " | ".join(f"RMSE {q}" for q in m["params"]) + " |",
                  "|---|---|" + "---|" * len(m["params"])]
        for u, row in m["rmse_per_unit"].items():
            lines.append(f"| {u} | {row['samples']:,} | "
                         + " | ".join(f(row[q], ".2e") for q in m["params"]) + " |")
    return "\n".join(lines)


__all__ = ["DEFAULT_METHODS", "compare", "format_report", "unit_bound"]
