"""Floors: what a prediction reaches without a network, for every table (issue 30).

A network's error means little alone: these predictors need no training beyond a lookup on
the development units, and a table that reports a network beside them shows what the network
adds. All three predict once per flight from a flight table (:mod:`.flights`), at the end of
the flight, and use the development units' flights only.

- **Life** (no sensors): ``ŷ_c = max(L̄ - c, 0)``, ``L̄`` the mean end of life of the
  development units (last cycle plus its RUL). What knowing the fleet's typical life gives.
- **HI lookup** (no network): the development flights' RUL against their health index
  ``HI_hat`` (:mod:`.flights`), fitted as an isotonic (non-decreasing) curve, since a
  healthier engine does not have less life left (pool-adjacent-violators, Barlow et al.,
  *Statistical Inference under Order Restrictions*, 1972; ``scipy.optimize.isotonic_regression``);
  a test flight's prediction is the curve at its ``HI_hat``, linear between the fitted points
  and constant beyond them. What the current health alone gives.
- **Physics trend**: the baseline of :mod:`.baseline` (the health index's trend refitted at
  every flight and extrapolated to HI = 0), capped at the development units' longest life.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.optimize import isotonic_regression

from engine_model.validation import InputError

from .baseline import trend_per_flight
from .features import TARGET
from .flights import unit_lives

FLOORS = ("life", "hi-lookup", "physics-trend")


@dataclass(frozen=True)
class HiLookup:
    """The isotonic curve RUL(HI) of the module docstring."""

    hi: np.ndarray  # increasing knots
    rul: np.ndarray  # non-decreasing values at the knots

    @classmethod
    def fit(cls, hi, rul) -> HiLookup:
        h = np.asarray(hi, float)
        y = np.asarray(rul, float)
        ok = np.isfinite(h) & np.isfinite(y)
        if ok.sum() < 2:
            raise InputError("HI lookup: needs at least two development flights with a "
                             "health index")
        h, y = h[ok], y[ok]
        order = np.argsort(h, kind="stable")
        h, y = h[order], y[order]
        knots, inverse = np.unique(h, return_inverse=True)  # ties: one knot, weight = count
        w = np.bincount(inverse).astype(float)
        mean = np.bincount(inverse, weights=y) / w
        fitted = isotonic_regression(mean, weights=w, increasing=True).x
        return cls(knots, np.asarray(fitted, float))

    def __call__(self, hi) -> np.ndarray:
        return np.interp(np.asarray(hi, float), self.hi, self.rul)


def floor_predictions(dev: pd.DataFrame, evaluate: pd.DataFrame, which: Sequence[str] = FLOORS,
                      max_rul: float | None = None) -> dict[str, pd.DataFrame]:
    """Per floor, a per-flight prediction frame (``unit``, ``cycle``, ``RUL``, ``RUL_pred``
    and ``hs`` when present) on the flights of ``evaluate``, fitted on the flight table
    ``dev`` (development units only). ``max_rul`` caps every prediction like capped targets,
    and the HI lookup is fitted to the capped target (the mean of ``min(RUL, max_rul)`` at a
    health index, which is what a capped score asks; None: no cap; the trend is capped at
    the longest development life either way)."""
    unknown = [w for w in which if w not in FLOORS]
    if unknown:
        raise InputError(f"unknown floor(s) {', '.join(unknown)}; one of {', '.join(FLOORS)}")
    lives = unit_lives(dev)
    keep = [c for c in ("unit", "cycle", TARGET, "hs") if c in evaluate.columns]
    out = {}
    for name in which:
        frame = evaluate[keep].copy()
        if name == "life":
            pred = np.maximum(float(lives.mean()) - evaluate["cycle"].to_numpy(float), 0.0)
        elif name == "hi-lookup":
            if "HI_hat" not in dev.columns or "HI_hat" not in evaluate.columns:
                raise InputError("the HI lookup needs the health index of θ̂ (a flight table "
                                 "built from a table with <q>_hat columns)")
            target = dev[TARGET].to_numpy(float)
            if max_rul is not None:  # the curve of the capped target, not a capped curve
                target = np.minimum(target, max_rul)
            pred = HiLookup.fit(dev["HI_hat"], target)(evaluate["HI_hat"])
        else:
            pred = trend_per_flight(evaluate, float(lives.max()))
        frame["RUL_pred"] = pred if max_rul is None else np.clip(pred, 0.0, max_rul)
        out[name] = frame
    return out
