"""The C-MAPSS protocol on training units alone: folds of whole units, held-out units truncated
the way NASA built its test files, and each one scored once, at its last observed cycle.

The published C-MAPSS models (Babu et al. 2016, Zheng et al. 2017, Li et al. 2018, ...) are
scored on NASA's test files: each test unit's trajectory "ends some time prior to system
failure" (Saxena, Goebel, Simon & Eklund, PHM 2008) and the model predicts its RUL once, at
the last observed cycle; the error is the RMSE over test units (and the PHM08 score). To choose
models and settings without ever touching a test file, hyprog builds the same situation from
the training units:

- :func:`unit_folds`: ``k`` folds of **whole units** (a unit's cycles are strongly correlated,
  so a fold that split a unit would validate on what it trained on), the units shuffled by a
  seeded generator and dealt round-robin, so fold sizes differ by at most one.
- :func:`truncate_units`: every held-out unit is cut at a random cycle ``c*``, drawn
  uniformly (seeded, per unit) from ``min(min_cycles, EOL)`` to ``EOL``, the unit's last
  cycle; its RUL at ``c*`` is then ``EOL - c*``, from 0 (a unit seen up to failure) to
  ``EOL - min_cycles``. NASA does not publish how it chose its cut points beyond the sentence
  above; the uniform cut is this module's choice (written down here so that it is not
  mistaken for NASA's), and ``min_cycles`` (the model's window, typically) keeps every held-out
  unit long enough for one prediction. With ``max_rul`` (the benchmark passes the target
  cap), the cut is drawn from ``max(min_cycles, EOL - max_rul)`` to ``EOL`` instead, so the
  true RUL at the cut is uniform on ``[0, max_rul]``: the range where the capped target *is*
  the true RUL, so the score measures the model where it was taught, not the cap. (A cut
  uniform over the whole life leaves a third of FD001's held-out units with a RUL above 125,
  where every capped prediction is wrong by construction; NASA's test errors of 12-18
  cycles show its test units are not like that.)
- :func:`last_cycle_scores`: the prediction at each unit's last observed cycle (the per-cycle
  mean, :func:`.metrics.per_cycle`), **capped like the targets**: clipped to ``[0,
  max_rul]`` when the model was trained on targets ``min(RUL, max_rul)``, because a prediction
  above the cap is one the targets never taught; the true RUL is not capped. Returns per unit
  the cycle, true and predicted RUL and ``Δ = RUL - RUL_pred``, and over the units the RMSE
  and the NASA score (:mod:`.metrics`' conventions).

Same seed, same folds and the same cut points, whatever else runs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from engine_model.validation import InputError, check_seed

from .metrics import nasa_score, per_cycle, rmse


@dataclass(frozen=True)
class Fold:
    """One fold: the units that train and the units held out (both sorted)."""

    train: tuple[int, ...]
    held_out: tuple[int, ...]


def unit_folds(units: Sequence[int], k: int, seed: int) -> list[Fold]:
    """``k`` folds of whole units (module docstring); each unit is held out exactly once."""
    units = sorted({int(u) for u in units})
    if not units:
        raise InputError("cross-validation: no units to fold")
    check_seed(seed, "cross-validation: seed")
    if not 2 <= k <= len(units):
        raise InputError(f"cross-validation: {k} folds of {len(units)} units; need 2 <= k <="
                         f" {len(units)}")
    order = np.random.default_rng(seed).permutation(units)
    held = [sorted(int(u) for u in order[i::k]) for i in range(k)]
    return [Fold(tuple(sorted(set(units) - set(h))), tuple(h)) for h in held]


def truncate_units(df: pd.DataFrame, units: Sequence[int], seed: int,
                   min_cycles: int = 1, max_rul: float | None = None) -> pd.DataFrame:
    """The rows of ``units`` in ``df``, each unit cut after a random cycle ``c*`` (module
    docstring; ``df`` needs ``unit`` and ``cycle``): a copy, in ``df``'s order, whose ``RUL``
    (when there is one) is still the true cycles to failure. The cut of a unit depends only on
    ``seed`` and the unit number."""
    missing = [c for c in ("unit", "cycle") if c not in df.columns]
    if missing:
        raise InputError(f"truncate: missing column(s) {', '.join(missing)}")
    check_seed(seed, "truncate: seed")
    if min_cycles < 1:
        raise InputError(f"truncate: min_cycles must be >= 1, got {min_cycles}")
    if max_rul is not None and not max_rul >= 0:
        raise InputError(f"truncate: max_rul must be >= 0, got {max_rul}")
    wanted = sorted({int(u) for u in units})
    absent = sorted(set(wanted) - {int(u) for u in df["unit"].unique()})
    if absent:
        raise InputError(f"truncate: unit(s) {absent} not in the table")
    rows = df[df["unit"].isin(wanted)]
    first = rows.groupby("unit")["cycle"].min()
    last = rows.groupby("unit")["cycle"].max()
    cut = {}
    for u in wanted:
        rng = np.random.default_rng([int(seed), u])  # per unit: independent of the others
        lo = min(int(first[u]) + min_cycles - 1, int(last[u]))
        if max_rul is not None:
            lo = max(lo, int(last[u]) - int(np.floor(max_rul)))
        cut[u] = int(rng.integers(lo, int(last[u]) + 1))
    keep = rows["cycle"].to_numpy() <= rows["unit"].map(cut).to_numpy()
    return rows[keep].copy()


def last_cycle_scores(pred: pd.DataFrame, max_rul: float | None = None) -> dict:
    """The score of each unit once, at its last observed cycle (module docstring): ``{"units":
    {u: {"cycle", "RUL", "RUL_pred", "delta"}}, "n", "rmse", "score"}``; ``RUL_pred`` is the
    per-cycle mean clipped to ``[0, max_rul]`` (``max_rul`` None: to ``[0, inf)``)."""
    pc = per_cycle(pred)
    if "RUL" not in pc.columns:
        raise InputError("predictions: a true RUL column is needed to score them")
    if len(pc) == 0:
        raise InputError("predictions: no predicted samples to score")
    if max_rul is not None and not max_rul > 0:
        raise InputError(f"max_rul must be positive, got {max_rul}")
    last = pc.groupby("unit").tail(1)
    y = last["RUL"].to_numpy(float)
    y_hat = np.clip(last["mean"].to_numpy(float), 0.0, np.inf if max_rul is None else max_rul)
    units = {int(u): {"cycle": int(c), "RUL": float(t), "RUL_pred": float(p),
                      "delta": float(t - p)}
             for u, c, t, p in zip(last["unit"], last["cycle"], y, y_hat, strict=True)}
    return {"units": units, "n": len(units), "rmse": rmse(y, y_hat),
            "score": nasa_score(y, y_hat)}


__all__ = ["Fold", "last_cycle_scores", "truncate_units", "unit_folds"]
