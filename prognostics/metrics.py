"""Prognostics metrics: RMSE, NASA score, per-cycle mean, prediction horizon, interval coverage.

Conventions (written down because the literature flips signs)
-------------------------------------------------------------
Error of a prediction ``ŷ`` of the true RUL ``y`` (the paper's Sec. 4.5 and this issue's
convention): ``Δ = y - ŷ``, **true minus predicted**.

- ``Δ > 0``: the RUL is under-estimated, the prediction is **early** (maintenance too soon):
  ``α = 1/13``.
- ``Δ < 0``: the RUL is over-estimated, the prediction is **late** (the engine fails before we
  expect it to): ``α = 1/10``, the harder penalty.

- RMSE ``= sqrt(mean(Δ²))``.
- NASA score ``s = Σ_j (exp(α_j |Δ_j|) - 1)`` with ``α_j = 1/13`` for ``Δ_j > 0`` (early) and
  ``1/10`` for ``Δ_j <= 0`` (late; ``Δ = 0`` costs 0 either way): e.g. ``ŷ = y - 10``
  (``Δ = +10``, early) costs ``exp(10/13) - 1 = 1.158``, ``ŷ = y + 10`` (``Δ = -10``, late)
  costs ``e - 1 = 1.718``. This is the PHM08 score of Saxena, Goebel, Simon & Eklund, "Damage
  propagation modeling for aircraft engine run-to-failure simulation", PHM 2008, eq. 1, which
  writes it with ``d = ŷ - y = -Δ``; the paper's eq. (score) omits the ``- 1`` (a constant
  ``m`` per test set). The paper reports ``s x 10^5`` summed over every test sample.
- Per-cycle mean (the paper's ``ŷ_u^[c]``): the mean prediction over the samples of cycle ``c``
  of unit ``u``, with the min/max of those predictions as the band.
- Prediction horizon (the paper's ``t_EOL - t_{|Δ| <= 5}``): on the per-cycle mean,
  ``t_{|Δ|<=5}`` is the first cycle ``c`` such that ``|ŷ^[c'] - y^[c']| <= 5`` for every
  observed cycle ``c' >= c``; ``t_EOL = c_last + y^[c_last]`` (the last observed cycle plus its
  true RUL: the failure cycle, also for a truncated unit). A unit whose last observed cycle is
  already off by more than 5 has horizon 0 (no warning time).
- Interval coverage: the fraction of samples with ``lower <= y <= upper``; width: mean
  ``upper - lower``.

Phases (issue 30): the same metrics over the samples **before onset** (``hs == 1``, the
simulator's healthy state: degradation is normal wear only), **after onset** (``hs == 0``)
and near the end, **RUL <= 30** cycles. Before onset θ says little about the end of life, so
an overall figure mixes a part no predictor can do well with the part that matters; the
phases keep them apart. The onset phases need an ``hs`` column in the prediction frame.

Protocols
---------
``samples``: every predicted sample of the test units (the paper's, Sec. 4.5).
``last``: one prediction per unit, the per-cycle mean at its last observed cycle (the C-MAPSS
convention of scoring each test trajectory once at its end).

A prediction frame has columns ``unit``, ``cycle``, ``RUL`` (true), ``RUL_pred`` and, when the
model has an interval, ``RUL_lower`` and ``RUL_upper``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from engine_model.validation import InputError

LATE_A = 10.0
EARLY_A = 13.0
HORIZON_TOL = 5.0
END_PHASE_RUL = 30.0


def rmse(y_true, y_pred) -> float:
    delta = np.asarray(y_true, float) - np.asarray(y_pred, float)
    return float(np.sqrt(np.mean(delta * delta))) if delta.size else float("nan")


def nasa_score(y_true, y_pred) -> float:
    """NASA / PHM08 score (module docstring) with ``Δ = y - ŷ``: early (``Δ > 0``) costs
    ``exp(Δ/13) - 1``, late (``Δ <= 0``) ``exp(-Δ/10) - 1``."""
    delta = np.asarray(y_true, float) - np.asarray(y_pred, float)
    return float(np.sum(np.where(delta > 0, np.expm1(delta / EARLY_A),
                                 np.expm1(-delta / LATE_A))))


def coverage(y_true, lower, upper) -> float:
    y = np.asarray(y_true, float)
    return float(np.mean((np.asarray(lower) <= y) & (y <= np.asarray(upper)))) if y.size \
        else float("nan")


def mean_width(lower, upper) -> float:
    w = np.asarray(upper, float) - np.asarray(lower, float)
    return float(np.mean(w)) if w.size else float("nan")


def _has_interval(pred: pd.DataFrame) -> bool:
    return "RUL_lower" in pred.columns and "RUL_upper" in pred.columns


def check_prediction_frame(pred: pd.DataFrame) -> None:
    missing = [c for c in ("unit", "cycle", "RUL", "RUL_pred") if c not in pred.columns]
    if missing:
        raise InputError(f"predictions: missing column(s) {', '.join(missing)}")


def per_cycle(pred: pd.DataFrame) -> pd.DataFrame:
    """One row per (unit, cycle): true ``RUL`` (when the frame has it), ``mean`` / ``min`` /
    ``max`` of the predictions, ``n`` samples, and the mean ``lower`` / ``upper`` of the
    interval when there is one."""
    missing = [c for c in ("unit", "cycle", "RUL_pred") if c not in pred.columns]
    if missing:
        raise InputError(f"predictions: missing column(s) {', '.join(missing)}")
    agg = {"mean": ("RUL_pred", "mean"), "min": ("RUL_pred", "min"),
           "max": ("RUL_pred", "max"), "n": ("RUL_pred", "size")}
    if "RUL" in pred.columns:
        agg = {"RUL": ("RUL", "mean"), **agg}
    if _has_interval(pred):
        agg.update(lower=("RUL_lower", "mean"), upper=("RUL_upper", "mean"))
    return pred.groupby(["unit", "cycle"], sort=True).agg(**agg).reset_index()


def prediction_horizon(cycles, y_true, y_mean, tol: float = HORIZON_TOL) -> float:
    """``t_EOL - t_{|Δ| <= tol}`` of one unit from its per-cycle true and mean predicted RUL
    (module docstring)."""
    c = np.asarray(cycles, float)
    if c.size == 0:
        return float("nan")
    order = np.argsort(c)
    c, y, m = c[order], np.asarray(y_true, float)[order], np.asarray(y_mean, float)[order]
    ok = np.abs(m - y) <= tol
    if not ok[-1]:
        return 0.0
    bad = np.flatnonzero(~ok)
    first = c[bad[-1] + 1] if bad.size else c[0]
    t_eol = c[-1] + y[-1]
    return float(t_eol - first)


def _sample_metrics(df: pd.DataFrame) -> dict:
    out = {"n": int(len(df)), "rmse": rmse(df["RUL"], df["RUL_pred"]),
           "score": nasa_score(df["RUL"], df["RUL_pred"])}
    if _has_interval(df):
        out["coverage"] = coverage(df["RUL"], df["RUL_lower"], df["RUL_upper"])
        out["width"] = mean_width(df["RUL_lower"], df["RUL_upper"])
    return out


def phase_metrics(pred: pd.DataFrame) -> dict:
    """``{phase: {"n", "rmse", "score"}}`` for ``before onset``, ``after onset`` (with an
    ``hs`` column) and ``RUL <= 30`` (module docstring); a phase without samples is left
    out."""
    masks = {}
    if "hs" in pred.columns:
        hs = pred["hs"].to_numpy()
        masks["before onset"] = hs == 1
        masks["after onset"] = hs == 0
    masks[f"RUL <= {END_PHASE_RUL:g}"] = pred["RUL"].to_numpy(float) <= END_PHASE_RUL
    return {name: _sample_metrics(pred[m]) for name, m in masks.items() if m.any()}


def evaluate_predictions(pred: pd.DataFrame) -> dict:
    """Both protocols, per unit and overall, and the prediction horizon per unit.

    Returns ``{"samples": {"overall": m, "units": {u: m}, "phases": {phase: m}}, "last":
    {"overall": m, "units": {u: {"cycle", "RUL", "RUL_pred", "delta"}}}, "horizon":
    {"units": {u: h}, "mean": h}}`` (phases: :func:`phase_metrics`) where ``m`` holds
    ``n``, ``rmse``, ``score`` (and ``coverage``, ``width`` with an interval) and
    ``delta = RUL - RUL_pred`` (the module's ``Δ``).
    """
    check_prediction_frame(pred)
    if len(pred) == 0:
        raise InputError("predictions: no predicted samples to evaluate")
    samples = {"overall": _sample_metrics(pred),
               "units": {int(u): _sample_metrics(g) for u, g in pred.groupby("unit")},
               "phases": phase_metrics(pred)}
    pc = per_cycle(pred)
    last = pc.groupby("unit").tail(1)
    last_units = {}
    for r in last.itertuples(index=False):
        e = {"cycle": int(r.cycle), "RUL": float(r.RUL), "RUL_pred": float(r.mean),
             "delta": float(r.RUL - r.mean)}
        if _has_interval(pred):
            e["lower"], e["upper"] = float(r.lower), float(r.upper)
        last_units[int(r.unit)] = e
    last_overall = {"n": int(len(last)), "rmse": rmse(last["RUL"], last["mean"]),
                    "score": nasa_score(last["RUL"], last["mean"])}
    if _has_interval(pred):
        last_overall["coverage"] = coverage(last["RUL"], last["lower"], last["upper"])
        last_overall["width"] = mean_width(last["lower"], last["upper"])
    horizon = {int(u): prediction_horizon(g["cycle"], g["RUL"], g["mean"])
               for u, g in pc.groupby("unit")}
    return {"samples": samples, "last": {"overall": last_overall, "units": last_units},
            "horizon": {"units": horizon, "mean": float(np.mean(list(horizon.values())))}}
