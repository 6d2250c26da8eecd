"""Split-conformal prediction intervals for RUL (Vovk, Gammerman & Shafer, *Algorithmic Learning
in a Random World*, 2005; Lei, G'Sell, Rinaldo, Tibshirani & Wasserman, "Distribution-free
predictive inference for regression", JASA 113, 2018, Sec. 2.2).

Given a trained predictor ``ŷ`` and ``n`` calibration pairs ``(x_i, y_i)`` it never saw, the
nonconformity scores are the absolute residuals ``R_i = |y_i - ŷ(x_i)|``. With
``k = ⌈(n + 1)(1 - α)⌉`` and ``q̂ = R_(k)`` (the k-th smallest score; ``+inf`` when ``k > n``),
the interval ``[ŷ(x) - q̂, ŷ(x) + q̂]`` covers a new ``y`` with probability

    1 - α  <=  P(y in C(x))  <  1 - α + 1 / (n + 1)

**if the calibration and test pairs are exchangeable** (the upper bound needs continuous
scores without ties). Lower bounds of the RUL interval are clipped at 0 (a RUL is not
negative), which can only raise coverage.

Exchangeability here. The calibration pairs are the windows of whole held-out development
units (:mod:`.splits`), never test units and never rows the network trained or stopped on. The
samples of one unit are strongly correlated (one engine, one degradation path), so the
guarantee is really over units: it holds when the test units are drawn from the same fleet
process as the calibration units, and with few calibration units the realised coverage of a
test unit scatters widely around ``1 - α``. Units with another failure mode or other missions
(the paper's units 14 and 15) break the assumption; the measured test coverage reports how far.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from engine_model.validation import InputError


def conformal_rank(n: int, alpha: float) -> int:
    """``k = ⌈(n + 1)(1 - α)⌉``, the rank of the calibration score used as the quantile."""
    if not 0.0 < alpha < 1.0:
        raise InputError(f"alpha must lie in (0, 1), got {alpha}")
    # subtract a hair so that an exact integer product is not pushed up by rounding
    return int(math.ceil((n + 1) * (1.0 - alpha) - 1e-9))


def conformal_quantile(scores, alpha: float) -> float:
    """``q̂ = R_(k)`` of the module docstring (``inf`` when ``k > n``)."""
    r = np.sort(np.asarray(scores, float).ravel())
    if r.size == 0:
        raise InputError("conformal: no calibration scores")
    if not np.all(np.isfinite(r)):
        raise InputError("conformal: calibration scores must be finite")
    k = conformal_rank(r.size, alpha)
    return float(r[k - 1]) if k <= r.size else float("inf")


@dataclass(frozen=True)
class SplitConformal:
    """Absolute-residual split-conformal interval at level ``1 - alpha``."""

    alpha: float
    quantile: float
    n_scores: int
    units: tuple[int, ...] = ()

    @classmethod
    def calibrate(cls, y_true, y_pred, alpha: float, units=()) -> SplitConformal:
        scores = np.abs(np.asarray(y_true, float) - np.asarray(y_pred, float))
        return cls(float(alpha), conformal_quantile(scores, alpha), int(scores.size),
                   tuple(int(u) for u in units))

    def interval(self, y_pred) -> tuple[np.ndarray, np.ndarray]:
        """``(max(ŷ - q̂, 0), ŷ + q̂)``."""
        p = np.asarray(y_pred, float)
        return np.maximum(p - self.quantile, 0.0), p + self.quantile

    def to_dict(self) -> dict:
        """JSON-ready; an infinite quantile (too few scores for the level) is ``None``."""
        q = self.quantile if math.isfinite(self.quantile) else None
        return {"alpha": self.alpha, "quantile": q, "n_scores": self.n_scores,
                "units": list(self.units)}

    @classmethod
    def from_dict(cls, d: dict) -> SplitConformal:
        try:
            q = float("inf") if d["quantile"] is None else float(d["quantile"])
            return cls(float(d["alpha"]), q, int(d["n_scores"]),
                       tuple(int(u) for u in d.get("units", ())))
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"conformal: malformed record ({e})") from None
