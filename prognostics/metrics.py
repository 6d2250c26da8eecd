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

Accuracy over life (issue 31; Saxena, Celaya, Saha, Saha & Goebel, "Metrics for offline
evaluation of prognostic performance", IJPHM 1(1), 2010, Sec. 5; NASA ProgPy's
``alpha_lambda``). For one unit with first prediction at cycle ``t_P`` and failure at
``t_EOL``, the **λ-point** is ``t_λ = t_P + λ (t_EOL - t_P)``, taken at the first predicted
cycle at or after it (a λ-point after the unit's last observed cycle is not observed):

- **α-λ accuracy**: the per-cycle mean ``ŷ(t_λ)`` lies within ``±α`` of the true RUL,
  ``(1 - α) y(t_λ) <= ŷ(t_λ) <= (1 + α) y(t_λ)``; reported per unit and as the fraction of
  units that meet it, at ``α = 0.2`` (ProgPy's example) and ``λ = 0.25, 0.5, 0.75``.
- **Relative accuracy** ``RA(λ) = 1 - |y(t_λ) - ŷ(t_λ)| / y(t_λ)`` (1 is perfect; it goes
  negative when the error exceeds the true RUL); per unit and the mean over units.

**Error against true RUL** (the box plots of ceruleo's ``boxplot_errors_wrt_RUL``): the
samples' ``Δ`` grouped by bins of true RUL, ``[0, b), [b, 2b), ...``, with the bin width
``b`` the first of 1, 2, 5, 10, 20, 25, 50, 100, ... cycles that gives at most 8 bins; per
bin ``n``, mean, median, quartiles and the 5 / 95 % quantiles of ``Δ``.

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
ALPHA = 0.2
LAMBDAS = (0.25, 0.5, 0.75)
MAX_RUL_BINS = 8


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


def lambda_accuracy(pc: pd.DataFrame, alpha: float = ALPHA,
                    lambdas: tuple[float, ...] = LAMBDAS) -> dict:
    """α-λ accuracy and relative accuracy at the λ-points of each unit (module docstring),
    from a per-cycle table (:func:`per_cycle`, with ``RUL``).

    Returns ``{"alpha", "lambdas", "units": {u: {λ: {"cycle", "RUL", "RUL_pred", "within",
    "relative_accuracy"} or None}}, "fraction_within": {λ: f}, "relative_accuracy": {λ: m}}``,
    the last two over the units where the λ-point is observed (NaN when none is). λ keys are
    strings (``"0.5"``) so that the dict is JSON as it is.
    """
    units: dict[int, dict] = {}
    for u, g in pc.groupby("unit"):
        c = g["cycle"].to_numpy(float)
        y, m = g["RUL"].to_numpy(float), g["mean"].to_numpy(float)
        t_p, t_eol = c[0], c[-1] + y[-1]
        row = {}
        for lam in lambdas:
            k = int(np.searchsorted(c, t_p + lam * (t_eol - t_p) - 1e-9))
            if k >= len(c) or y[k] <= 0:
                row[f"{lam:g}"] = None
                continue
            row[f"{lam:g}"] = {"cycle": int(c[k]), "RUL": float(y[k]), "RUL_pred": float(m[k]),
                               "within": bool(abs(m[k] - y[k]) <= alpha * y[k]),
                               "relative_accuracy": float(1.0 - abs(y[k] - m[k]) / y[k])}
        units[int(u)] = row
    fraction, ra = {}, {}
    for lam in lambdas:
        seen = [r[f"{lam:g}"] for r in units.values() if r[f"{lam:g}"] is not None]
        fraction[f"{lam:g}"] = float(np.mean([e["within"] for e in seen])) if seen else \
            float("nan")
        ra[f"{lam:g}"] = float(np.mean([e["relative_accuracy"] for e in seen])) if seen else \
            float("nan")
    return {"alpha": alpha, "lambdas": list(lambdas), "units": units,
            "fraction_within": fraction, "relative_accuracy": ra}


def rul_bin_width(max_rul: float, max_bins: int = MAX_RUL_BINS) -> float:
    """The first of 1, 2, 5, 10, 20, 25, 50, 100, 200, 250, 500, ... cycles that cuts
    ``[0, max_rul]`` into at most ``max_bins`` bins (module docstring)."""
    decade = 1.0
    while True:
        for f in (1.0, 2.0, 2.5, 5.0):
            b = f * decade
            if (f != 2.5 or decade >= 10) and np.floor(max_rul / b) + 1 <= max_bins:
                return b
        decade *= 10.0


def error_by_rul(pred: pd.DataFrame, width: float | None = None) -> list[dict]:
    """``Δ = RUL - RUL_pred`` of every sample grouped by bins of true RUL (module docstring):
    one dict per non-empty bin, ``{"lo", "hi", "n", "mean", "median", "q05", "q25", "q75",
    "q95"}``, in order of RUL."""
    y = pred["RUL"].to_numpy(float)
    d = y - pred["RUL_pred"].to_numpy(float)
    b = width if width is not None else rul_bin_width(float(y.max()) if y.size else 0.0)
    k = np.floor(y / b).astype(int)
    out = []
    for i in np.unique(k):
        e = d[k == i]
        q05, q25, q50, q75, q95 = np.quantile(e, [0.05, 0.25, 0.5, 0.75, 0.95])
        out.append({"lo": float(i * b), "hi": float((i + 1) * b), "n": int(e.size),
                    "mean": float(e.mean()), "median": float(q50), "q05": float(q05),
                    "q25": float(q25), "q75": float(q75), "q95": float(q95)})
    return out


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
    {"units": {u: h}, "mean": h}, "alpha_lambda": ..., "error_by_rul": [...]}`` (phases:
    :func:`phase_metrics`; :func:`lambda_accuracy`; :func:`error_by_rul`) where ``m`` holds
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
            "horizon": {"units": horizon, "mean": float(np.mean(list(horizon.values())))},
            "alpha_lambda": lambda_accuracy(pc), "error_by_rul": error_by_rul(pred)}
