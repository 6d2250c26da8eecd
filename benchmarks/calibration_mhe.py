"""Accuracy and speed of the windowed MAP / MHE (and the batch MAP per cycle) on a fleet.

    python benchmarks/calibration_mhe.py                       # ds02 at 0.1 Hz, MHE, 2 jobs
    python benchmarks/calibration_mhe.py --methods mhe,map_cycle --units 2 11 --jobs 2
    python benchmarks/calibration_mhe.py --data fleet.parquet  # a fleet already simulated

The fleet comes from :func:`engine_model.fleet.simulate` (or ``--data``); its true theta
columns are the reference. Units run in parallel processes (``--jobs``), each with its own
compiled model. Per method and parameter the table gives the RMSE and bias of theta_hat
against the truth, the consistency (fraction of samples with the truth inside +-1.96 reported
std), the Cramer-Rao bound beside it and run time.

The bound (``CRB``) is the posterior (Bayesian) Cramer-Rao bound of the windowed MAP under the
estimator's own assumptions, computed at the **true** theta with exact sensitivities: the
inverse of the window's Fisher information ``sum_k S_k^T S_k`` plus the arrival information,
which is propagated window to window exactly as the estimator does (inflated by the drift
``q^2 dtau``), starting from the prior. For ``map_cycle`` it is the inverse of the cycle's
Fisher information plus the prior. ``CRB`` in the table is the RMS over samples of the bound's
standard deviation; ``ratio`` = RMSE / CRB. Caveat printed with the table: the simulated fleet
degrades all ten health parameters (initial wear and normal degradation), the estimator only
the requested ones, so part of the error is model mismatch the bound does not contain.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from engine_model.channels import PAPER_THETA, THETA_NAMES  # noqa: E402


def _bound(model, df, setup, method, window, stride):
    """Per-sample posterior CRB variances (N, k) at the true theta (module docstring)."""
    from calibration.base import prepare_unit
    from calibration.mhe import _kernel_series, kernels_for
    from calibration.mhe_nlp import reduced_sensitivity

    series = prepare_unit(df, setup)
    ser = _kernel_series(series, None)
    theta_true = df[list(THETA_NAMES)].to_numpy(float)
    x = model.solve_series(ser.w, theta_true).x
    kern = kernels_for(model)
    est = setup.param_index
    n, k = len(df), len(est)
    S = np.empty((n, ser.y.shape[1], k))
    for a in range(0, n, 4096):
        sl = slice(a, min(n, a + 4096))
        jr, je = kern.jacobians(x[sl], theta_true[sl], ser.w[sl], ser.y[sl], ser.s[sl], None)
        S[sl] = reduced_sensitivity(jr, je, est)
    info = np.einsum("nki,nkj->nij", S, S)
    out = np.empty((n, k))
    prior_info = np.diag(1.0 / setup.prior_std_vec() ** 2)
    if method == "map_cycle":
        cyc = df["cycle"].to_numpy()
        for c in np.unique(cyc):
            m = cyc == c
            out[m] = np.diag(np.linalg.inv(prior_info + info[m].sum(0)))
        return out
    q2 = setup.drift_std_per_sqrt_h ** 2
    tau = ser.tau_h
    arr = prior_info
    stride = stride or window
    a = 0
    while a < n:
        b = min(a + window, n)
        end = b if b == n else min(a + stride, n)
        post = arr + info[a:b].sum(0)
        out[a:end] = np.diag(np.linalg.inv(post))
        leave = np.linalg.inv(arr + info[a:end].sum(0))
        gap = tau[min(end, n - 1)] - tau[a]
        arr = np.linalg.inv(leave + np.eye(k) * q2 * gap)
        if b == n:
            out[end:] = out[end - 1]
            break
        a = end
    return out


def _run_unit(args):
    df, method, opts, params = args
    from calibration.base import CalibrationSetup, get_estimator
    from engine_model import EngineModel

    model = _run_unit.model = getattr(_run_unit, "model", None) or EngineModel(n_threads=1)
    setup = CalibrationSetup(params=params)
    kw = {} if method == "map_cycle" else opts
    t0 = time.perf_counter()
    res = get_estimator(method, model, **kw).estimate(df, setup)
    seconds = time.perf_counter() - t0
    truth = df[list(params)].to_numpy(float)
    est = res.theta_hat.to_numpy()
    std = res.theta_std.to_numpy()
    d = res.diagnostics
    return dict(unit=int(df["unit"].iloc[0]), n=len(df), err=est - truth, std=std,
                seconds=seconds, windows=d["windows"], nonconv=d["non_converged_windows"],
                iters=d["mean_iterations"], status=sorted(set(d["status"])))


def _bound_unit(args):
    df, method, opts, params = args
    from calibration.base import CalibrationSetup
    from engine_model import EngineModel

    model = _bound_unit.model = getattr(_bound_unit, "model", None) or EngineModel(n_threads=1)
    return _bound(model, df, CalibrationSetup(params=params), method, opts.get("window", 60),
                  opts.get("stride"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="ds02")
    ap.add_argument("--rate", type=float, default=0.1)
    ap.add_argument("--data", help="parquet of a simulated fleet (skips the simulation)")
    ap.add_argument("--units", type=int, nargs="*")
    ap.add_argument("--methods", default="mhe")
    ap.add_argument("--window", type=int, default=60)
    ap.add_argument("--stride", type=int)
    ap.add_argument("--mode", default="constant")
    ap.add_argument("--hessian", default="gauss-newton")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--params", default=",".join(PAPER_THETA),
                    help="comma-separated health parameters, or 'all'")
    a = ap.parse_args(argv)
    params = THETA_NAMES if a.params == "all" else tuple(a.params.split(","))
    t0 = time.perf_counter()
    if a.data:
        fleet_df = pd.read_parquet(a.data)
        if a.units:
            fleet_df = fleet_df[fleet_df["unit"].isin(a.units)]
        src = a.data
    else:
        from engine_model import fleet

        fleet_df, _, _ = fleet.simulate(a.preset, units=a.units, rate_hz=a.rate)
        src = f"engine_model.fleet.simulate({a.preset!r}, rate_hz={a.rate})"
    t_sim = time.perf_counter() - t0
    units = [g.reset_index(drop=True) for _, g in fleet_df.groupby("unit", sort=True)]
    n_all = sum(len(u) for u in units)
    print(f"fleet: {src}: {len(units)} units, {n_all:,} samples ({t_sim:.0f} s to load or "
          f"simulate); {os.cpu_count()} cores, {a.jobs} jobs")
    opts = dict(window=a.window, stride=a.stride, mode=a.mode, hessian=a.hessian)
    order = sorted(range(len(units)), key=lambda i: -len(units[i]))  # longest first
    for method in a.methods.split(","):
        t1 = time.perf_counter()
        jobs = [(units[i], method, opts, params) for i in order]
        with ProcessPoolExecutor(max_workers=a.jobs) as ex:
            rows = list(ex.map(_run_unit, jobs))
        wall = time.perf_counter() - t1  # estimation only (with the workers' start-up)
        with ProcessPoolExecutor(max_workers=a.jobs) as ex:
            for r, c in zip(rows, ex.map(_bound_unit, jobs), strict=True):
                r["crb"] = c
        err = np.concatenate([r["err"] for r in rows])
        std = np.concatenate([r["std"] for r in rows])
        crb = np.concatenate([r["crb"] for r in rows])
        desc = method if method == "map_cycle" else (
            f"mhe ({a.mode}, window {a.window}, stride {a.stride or a.window}, {a.hessian})")
        print(f"\n### {desc}\n")
        print("| parameter | RMSE | bias | consistency (95 %) | mean reported std | CRB | "
              "RMSE / CRB |")
        print("|---|---|---|---|---|---|---|")
        for j, q in enumerate(params):
            ok = np.isfinite(err[:, j])
            e, s, c = err[ok, j], std[ok, j], crb[ok, j]
            rmse = float(np.sqrt(np.mean(e ** 2)))
            bound = float(np.sqrt(np.mean(c)))
            print(f"| {q} | {rmse:.2e} | {np.mean(e):+.2e} | {np.mean(np.abs(e) <= 1.96 * s):.3f}"
                  f" | {np.mean(s):.2e} | {bound:.2e} | {rmse / bound:.2f} |")
        cpu = sum(r["seconds"] for r in rows)
        print(f"\nrun time {wall:.0f} s wall for {n_all:,} samples = {n_all / wall:,.0f} "
              f"samples/s ({a.jobs} jobs; {n_all / cpu:,.0f} samples/s per process); windows "
              f"{sum(r['windows'] for r in rows):,}, not converged "
              f"{sum(r['nonconv'] for r in rows)}, mean IPOPT iterations "
              f"{np.mean([r['iters'] for r in rows]):.1f}; statuses "
              f"{sorted({s for r in rows for s in r['status']})}")
        print("\n| unit | samples | seconds | RMSE " + " | RMSE ".join(params) + " |")
        print("|---|---|---|" + "---|" * len(params))
        for r in sorted(rows, key=lambda r: r["unit"]):
            rm = np.sqrt(np.nanmean(r["err"] ** 2, axis=0))
            print(f"| {r['unit']} | {r['n']:,} | {r['seconds']:.0f} | "
                  + " | ".join(f"{v:.2e}" for v in rm) + " |")
    print("\nnote: the fleet degrades all ten health parameters (initial wear, normal "
          "degradation); the estimator holds the others at 0, so part of the error is model "
          "mismatch that the bound does not contain.")


if __name__ == "__main__":
    main()
