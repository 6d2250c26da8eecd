"""Physics-only baseline: RUL from the trend of the health index computed from θ̂.

How far does physics alone get? No network, no training data beyond the calibration:

1. **θ̂ per cycle.** For each unit and cycle, the mean of the calibrated ``<q>_hat`` over the
   cycle's samples, placed by name in a 10-vector of zeros (``THETA_NAMES`` order; a parameter
   not estimated, or NaN because unobservable, stays at its nominal 0).
2. **Health index.** ``HI_c = HealthIndex(model)(θ̂_c)``, the simulator's N-CMAPSS definition
   (``engine_model.simulator.degradation``: the minimum of the normalised stall and EGT margins at
   the reference condition, 1 for a new engine, 0 at failure), evaluated with the engine model.
3. **Trend, refitted at every cycle ``n`` from cycles ``1..n`` only** (a prognosis may not
   look ahead). The form is a linear-to-exponential degradation curve,

       HI(c) = a - b (exp(λ (c - n)) - 1) / λ,        λ >= 0  (λ -> 0: a - b (c - n)),

   i.e. the exponential degradation model of Gebraeel, Lawley, Li & Ryan (IIE Transactions
   37, 2005) written so that ``a`` is the fitted HI now, ``b`` the current rate of loss, and
   the linear trend is its ``λ = 0`` member; it has the shape of the simulator's smooth
   exponential onset (``g(u) = e^u - 1 - u``) without needing the onset cycle. For each ``λ``
   on a grid over ``[0, 1]`` per cycle (refined by a bounded scalar search), ``(a, b)`` is the
   linear least-squares fit; the ``λ`` with the least squared error wins (variable projection,
   Golub & Pereyra 1973: no starting guess, no failed convergence).
4. **Extrapolate to HI = 0.** ``RUL_n = ln(1 + a λ / b) / λ`` (``a / b`` when ``λ = 0``); 0 when
   ``a <= 0``; ``max_rul`` when ``b <= 0`` (no degradation seen) and as the upper cap. With 2
   cycles the trend is linear; with 1 cycle there is no trend and the prediction is
   ``max_rul``.

``max_rul`` is the caller's prior on a life: the experiment uses the longest life among the
development units. Every sample of cycle ``n`` carries ``RUL_n`` (the baseline predicts once
per cycle, from the cycle's mean θ̂).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd
from scipy.optimize import minimize_scalar

from engine_model.channels import THETA_NAMES
from engine_model.validation import InputError

from .features import TARGET

LAMBDA_MAX = 1.0
LAMBDA_GRID = np.linspace(0.0, LAMBDA_MAX, 101)


def theta_per_cycle(df: pd.DataFrame, suffix: str = "_hat") -> pd.DataFrame:
    """``unit``, ``cycle`` and the 10 ``THETA_NAMES`` columns: the per-cycle mean of
    ``<q><suffix>`` where present (NaN -> 0), 0 elsewhere (step 1)."""
    present = [q for q in THETA_NAMES if q + suffix in df.columns]
    if not present:
        raise InputError(f"baseline: the table has no theta columns (<q>{suffix}); run hyprog "
                         "calibrate first")
    cols = [q + suffix for q in present]
    g = df.groupby(["unit", "cycle"], sort=True)[cols].mean().reset_index()
    out = g[["unit", "cycle"]].copy()
    for q in THETA_NAMES:
        out[q] = g[q + suffix].fillna(0.0).to_numpy() if q in present else 0.0
    return out


def _basis(c: np.ndarray, n: float, lam: float) -> np.ndarray:
    u = c - n
    return u if lam == 0.0 else np.expm1(lam * u) / lam


def _lsq(c: np.ndarray, hi: np.ndarray, n: float, lam: float) -> tuple[float, float, float]:
    """``(sse, a, b)`` of the linear fit ``hi ≈ a - b φ_λ(c)``."""
    A = np.column_stack([np.ones_like(c), -_basis(c, n, lam)])
    coef, *_ = np.linalg.lstsq(A, hi, rcond=None)
    r = hi - A @ coef
    return float(r @ r), float(coef[0]), float(coef[1])


def fit_trend(cycles, hi) -> tuple[float, float, float]:
    """``(a, b, λ)`` of the trend of step 3 at ``n = max(cycles)``."""
    c = np.asarray(cycles, float)
    h = np.asarray(hi, float)
    n = float(c.max())
    if len(c) < 3:
        _, a, b = _lsq(c, h, n, 0.0)
        return a, b, 0.0
    sse = np.array([_lsq(c, h, n, lam)[0] for lam in LAMBDA_GRID])
    i = int(np.argmin(sse))
    lo, hi_ = LAMBDA_GRID[max(i - 1, 0)], LAMBDA_GRID[min(i + 1, len(LAMBDA_GRID) - 1)]
    best = float(LAMBDA_GRID[i])
    if hi_ > lo:
        r = minimize_scalar(lambda lam: _lsq(c, h, n, lam)[0], bounds=(lo, hi_),
                            method="bounded", options={"xatol": 1e-6})
        if r.fun < sse[i]:
            best = float(r.x)
    _, a, b = _lsq(c, h, n, best)
    return a, b, best


def rul_from_trend(a: float, b: float, lam: float, max_rul: float) -> float:
    """Cycles until the trend of step 3 reaches HI = 0, in ``[0, max_rul]`` (step 4)."""
    if a <= 0.0:
        return 0.0
    if b <= 0.0:
        return float(max_rul)
    rul = a / b if lam == 0.0 else np.log1p(a * lam / b) / lam
    return float(min(max(rul, 0.0), max_rul))


def unit_rul(cycles, hi, max_rul: float) -> np.ndarray:
    """RUL predicted at every cycle of one unit from the HI history up to that cycle."""
    c = np.asarray(cycles, float)
    h = np.asarray(hi, float)
    out = np.empty(len(c))
    for k in range(len(c)):
        if k == 0:
            out[k] = max_rul
            continue
        out[k] = rul_from_trend(*fit_trend(c[:k + 1], h[:k + 1]), max_rul)
    return out


def trend_per_flight(flights: pd.DataFrame, max_rul: float, source: str = "table",
                     column: str = "HI_hat") -> np.ndarray:
    """Step 3-4's RUL at every row of a flight table (:mod:`.flights`, rows ordered by unit
    and cycle) from its health-index ``column``, each unit on its own."""
    if column not in flights.columns:
        raise InputError(f"{source}: the physics trend needs the health index of θ̂ (a table "
                         "with <q>_hat columns: run hyprog calibrate first)")
    out = np.empty(len(flights))
    cycle = flights["cycle"].to_numpy(float)
    hi = flights[column].to_numpy(float)
    for idx in flights.groupby("unit", sort=False).indices.values():
        out[idx] = unit_rul(cycle[idx], hi[idx], max_rul)
    return out


def baseline_per_cycle(df: pd.DataFrame, hi_fn: Callable[[np.ndarray], np.ndarray],
                       max_rul: float, units: Sequence[int] | None = None) -> pd.DataFrame:
    """Per (unit, cycle): θ̂ (10 columns), ``HI``, ``RUL_pred`` and true ``RUL`` when present.
    ``hi_fn`` maps an (n, 10) θ array to HI
    (``engine_model.physics.health_index.HealthIndex(model)``)."""
    if not max_rul > 0:
        raise InputError(f"baseline: max_rul must be positive, got {max_rul}")
    if units is not None:
        df = df[df["unit"].isin([int(u) for u in units])]
    th = theta_per_cycle(df)
    th["HI"] = np.asarray(hi_fn(th[list(THETA_NAMES)].to_numpy()), float)
    th["RUL_pred"] = trend_per_flight(th, max_rul, column="HI")
    if TARGET in df.columns:
        true = df.groupby(["unit", "cycle"], sort=True)[TARGET].mean().to_numpy()
        th[TARGET] = true
    return th


def baseline_predictions(df: pd.DataFrame, hi_fn: Callable[[np.ndarray], np.ndarray],
                         max_rul: float, units: Sequence[int] | None = None) -> pd.DataFrame:
    """Per-sample prediction frame (``unit``, ``cycle``, ``RUL``, ``RUL_pred``) for
    :func:`metrics.evaluate_predictions`: every sample carries its cycle's prediction."""
    pc = baseline_per_cycle(df, hi_fn, max_rul, units)
    if units is not None:
        df = df[df["unit"].isin([int(u) for u in units])]
    keep = [c for c in ("unit", "cycle", "t", TARGET) if c in df.columns]
    return df[keep].merge(pc[["unit", "cycle", "RUL_pred"]], on=["unit", "cycle"],
                          how="left").reset_index(drop=True)


def engine_health_index(effects: Sequence[str] = ()):
    """``HealthIndex`` of the engine model with ``effects`` (specification strings: those of an
    adapted model, :func:`health_effects`), built once per process
    (:func:`engine_model.runtime.shared_model.process_model`); without effects, the process-wide
    default model (built, or loaded from the C cache, once)."""
    from engine_model.physics.health_index import HealthIndex
    from engine_model.runtime.shared_model import process_model

    return HealthIndex(process_model(tuple(effects)))


def health_effects(metadata: dict | None) -> tuple[str, ...]:
    """The effects of the engine model that θ̂ was calibrated with: a feature table's
    metadata ``calibration.effects`` (``hyprog calibrate --model-effects``: an adapted
    model's), ``()`` for the model as designed. θ̂ is a deviation from that model, so its
    health index is evaluated with it: with the designed model, an adapted model's new engine
    (θ̂ = 0) would not read HI = 1."""
    cal = (metadata or {}).get("calibration") or {}
    return tuple(str(e) for e in cal.get("effects") or ())
