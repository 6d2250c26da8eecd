"""Typed results of an evaluation: :class:`Evaluation`, over the nested dict of
:func:`.metrics.evaluate_predictions` (which stays the JSON written by ``hyprog evaluate
--json``), with the predictions it was computed from.

    result = estimator.evaluate(features)         # prognostics.RulEstimator
    result.rmse, result.rmse_last, result.horizon  # every test sample; last cycle; cycles
    result.to_frame()                              # one row per test unit
    result.to_json("metrics.json")                 # the same JSON as hyprog evaluate --json
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

import pandas as pd

from engine_model.datasets.jsonable import jsonable

from .metrics import evaluate_predictions
from .outputs import write_text


@dataclass(frozen=True)
class Evaluation:
    """Metrics of a RUL model on test units (the two protocols of :mod:`.metrics`, the
    prediction horizon, accuracy over life, error by true RUL) and the per-sample
    ``predictions`` they come from (``unit``, ``cycle``, ``RUL``, ``RUL_pred``, ...)."""

    metrics: dict
    predictions: pd.DataFrame

    @classmethod
    def of(cls, predictions: pd.DataFrame) -> Evaluation:
        """Evaluate a prediction frame (:func:`.metrics.evaluate_predictions`)."""
        return cls(evaluate_predictions(predictions), predictions)

    @property
    def rmse(self) -> float:
        """RMSE over every test sample [cycles] (the paper's protocol)."""
        return self.metrics["samples"]["overall"]["rmse"]

    @property
    def score(self) -> float:
        """NASA score over every test sample."""
        return self.metrics["samples"]["overall"]["score"]

    @property
    def rmse_last(self) -> float:
        """RMSE of the per-cycle mean at each unit's last observed cycle [cycles] (the
        C-MAPSS protocol)."""
        return self.metrics["last"]["overall"]["rmse"]

    @property
    def horizon(self) -> float:
        """Mean prediction horizon over the test units [cycles]."""
        return self.metrics["horizon"]["mean"]

    @property
    def units(self) -> list[int]:
        return sorted(int(u) for u in self.metrics["samples"]["units"])

    def to_frame(self) -> pd.DataFrame:
        """One row per test unit: ``unit``, ``samples``, ``rmse``, ``score``, the last
        observed ``cycle`` with its ``RUL`` and ``RUL_pred``, ``horizon``, the α-λ outcome
        and relative accuracy at each λ (``within_0.5``, ``ra_0.5``, ...), and ``coverage``
        / ``width`` with an interval."""
        m = self.metrics
        al = m["alpha_lambda"]
        rows = []
        for u in self.units:
            s, last = m["samples"]["units"][u], m["last"]["units"][u]
            row = {"unit": u, "samples": s["n"], "rmse": s["rmse"], "score": s["score"],
                   "cycle": last["cycle"], "RUL": last["RUL"], "RUL_pred": last["RUL_pred"],
                   "horizon": m["horizon"]["units"][u]}
            for lam in al["lambdas"]:
                e = al["units"][u][f"{lam:g}"]
                row[f"within_{lam:g}"] = None if e is None else e["within"]
                row[f"ra_{lam:g}"] = None if e is None else e["relative_accuracy"]
            for k in ("coverage", "width"):
                if k in s:
                    row[k] = s[k]
            rows.append(row)
        return pd.DataFrame(rows)

    def to_json(self, path: str | os.PathLike | None = None) -> str:
        """The metrics as JSON (NaN as null; the ``hyprog evaluate --json`` layout), written
        to ``path`` (atomically) when given."""
        text = json.dumps(jsonable(self.metrics), indent=2, allow_nan=False)
        if path is not None:
            write_text(path, text + "\n")
        return text
