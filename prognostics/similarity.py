"""Similarity-based RUL on the health index: the development units' run-to-failure trajectories
as a library, no network.

The method of Wang, Yu, Siegel & Lee (*A similarity-based prognostics approach for remaining
useful life estimation of engineered systems*, PHM 2008; the winner of the PHM08 challenge on
C-MAPSS-type data), on the health index of θ̂ (:mod:`.flights`, ``HI_hat``: the physics
says where the engine is, the fleet's histories say how long such an engine lasts):

1. **Library.** Each development unit ``i``: its health index per flight, ``h_i(1 .. L_i)``,
   and its RUL at each flight.
2. **Match.** At flight ``n`` of a unit, its last ``k = min(K, n)`` flights
   ``x = h(n - k + 1 .. n)`` are compared with every window of ``k`` consecutive flights of
   each library unit; the mean squared difference ``d_i(m)`` of the window ending at the
   library's flight ``m`` is smallest at ``m_i``, whose RUL ``r_i = RUL_i(m_i)`` is the unit's
   vote. Matching a window, not one flight, compares the level and the rate of loss: the
   context across flights.
3. **Weight.** Two copies of one trajectory with independent white noise of variance
   ``σ²`` differ by ``2 σ²`` per flight, so the Gaussian likelihood of unit ``i``'s best
   match would be ``exp(-k d_i / (4 σ²))``; the prediction is the weighted mean of the votes,
   ``ŷ = Σ w_i r_i / Σ w_i``, ``w_i = exp(-k (d_i - min_j d_j) / (4 σ²))``. ``σ²`` is taken
   as half the mean variance of the library units' first differences. That is not the noise
   alone: near the end of life the trend's change from flight to flight dominates it (on the
   ``ds02`` fleet 70-85 % of it; the noise before onset is 15-50 times smaller), and the
   health index's errors are correlated from flight to flight. So ``σ²`` acts as the kernel's
   bandwidth, set by the library's own flight-to-flight spread, and the weights are a kernel
   (Wang et al. weight by a similar kernel), not a calibrated likelihood: on ``ds02`` the
   average flight spreads its weight over about three of the six library units.

**Which health index.** The class matches whichever column it is given (``HI_hat`` by
default, as Wang et al. match their fused index). The trained model's default
(:data:`.train_config.DEFAULT_INPUTS`) is ``HI_hat_rel``, the health index minus its mean over
the unit's first flights (:mod:`.flights`, causal): engines leave the factory at different
health (initial wear), and when that level says little about how long an engine lasts,
matching the absolute index pairs engines by it, most before the onset of fault, where the
index barely moves; the change since entry into service is the degradation. (Our simulator
draws a unit's end of life apart from its initial wear; where the level from new does set
the life, as a smaller margin from new might in service, give ``HI_hat``.) Chosen by the
many-fleet study (``benchmarks/health_study.py``, fixed before its 20 test fleets were
scored): at 6, 12 and 24 training units, ``HI_hat_rel`` minus ``HI_hat`` -1.03, -1.16,
-1.25 cycles RMSE, 95 % intervals below zero (on ``ds02``'s three test units the other way,
7.93 against 6.64). It needs each unit's history from entry into service: a table whose
units start in mid-life takes their first flights in it as their early life.

Every prediction of flight ``n`` reads flights ``1 .. n`` of its unit only (causal); it is
issued at the flight's end, like the flight models' (:mod:`.flights`). Library units
shorter than ``k`` flights do not vote.

As a trained model (``hyprog train --model similarity``, :func:`.ensemble.fit`) the library
is the training units' flights with their RUL capped like every model's targets,
``min(RUL, max_rul)`` (so a vote, and the weighted mean of the votes, never exceeds the
cap); it is stored as arrays (:meth:`SimilarityRul.to_arrays`) in the model directory
(:mod:`.checkpoint`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from engine_model.validation import InputError

from .features import TARGET
from .flights import one_per_cycle

HI_COLUMN = "HI_hat"


def _series(flights: pd.DataFrame, column: str, source: str) -> dict[int, pd.DataFrame]:
    missing = [c for c in ("unit", "cycle", column) if c not in flights.columns]
    if missing:
        raise InputError(f"{source}: missing column(s) {', '.join(missing)} (a flight table "
                         "with the health index of θ̂: prognostics.flights)")
    if flights.empty:
        raise InputError(f"{source}: no flights")
    if not one_per_cycle(flights):
        raise InputError(f"{source}: several rows for one unit and cycle (a sample table? "
                         "the predictor reads a flight table: prognostics.flights)")
    if not np.isfinite(flights[column].to_numpy(float)).all():
        raise InputError(f"{source}: {column} is not finite in every flight")
    return {int(u): g.sort_values("cycle") for u, g in flights.groupby("unit", sort=True)}


@dataclass(frozen=True)
class SimilarityRul:
    """The library of the module docstring and the match's window ``K`` (flights)."""

    library: tuple  # ((hi, rul) per development unit, in unit order)
    sigma2: float
    window: int
    column: str = HI_COLUMN

    @classmethod
    def fit(cls, flights: pd.DataFrame, window: int = 10, column: str = HI_COLUMN
            ) -> SimilarityRul:
        """The library of the development units' flight table ``flights`` (with ``RUL``)."""
        if int(window) != window or window < 1:
            raise InputError(f"similarity: window must be an integer >= 1, got {window}")
        if TARGET not in flights.columns:
            raise InputError(f"similarity: the development flights need a {TARGET} column")
        units = _series(flights, column, "similarity library")
        if not np.isfinite(flights[TARGET].to_numpy(float)).all():
            raise InputError(f"similarity library: {TARGET} is not finite in every flight")
        lib = tuple((g[column].to_numpy(float), g[TARGET].to_numpy(float))
                    for g in units.values())
        diffs = [np.var(np.diff(h)) for h, _ in lib if len(h) > 2]
        if not diffs:
            raise InputError("similarity: the library needs a unit with at least three flights")
        sigma2 = 0.5 * float(np.mean(diffs))
        if not sigma2 > 0:
            raise InputError(f"similarity: {column} does not vary along the library's units")
        return cls(lib, sigma2, int(window), column)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The library as flat arrays: ``hi`` and ``rul`` (every unit's flights, one unit
        after another) and ``lengths`` (flights per unit); :meth:`from_arrays` inverts it."""
        return {"hi": np.concatenate([h for h, _ in self.library]),
                "rul": np.concatenate([r for _, r in self.library]),
                "lengths": np.array([len(h) for h, _ in self.library], np.int64)}

    @classmethod
    def from_arrays(cls, arrays, sigma2: float, window: int, column: str = HI_COLUMN,
                    source: str = "similarity library") -> SimilarityRul:
        """The predictor of :meth:`to_arrays`' arrays, checked (a stored library that does
        not describe units is refused, naming ``source``)."""
        try:
            hi, rul = (np.asarray(arrays[k], float) for k in ("hi", "rul"))
            lengths = np.asarray(arrays["lengths"])
        except KeyError as e:
            raise InputError(f"{source}: no {e.args[0]!r} array") from None
        if (hi.ndim != 1 or rul.shape != hi.shape or lengths.ndim != 1 or not len(lengths)
                or not np.issubdtype(lengths.dtype, np.integer) or (lengths < 1).any()
                or int(lengths.sum()) != len(hi)):
            raise InputError(f"{source}: the arrays do not describe a library (hi {hi.shape}, "
                             f"rul {rul.shape}, lengths {lengths.shape})")
        if not (np.isfinite(hi).all() and np.isfinite(rul).all()):
            raise InputError(f"{source}: the library is not finite")
        if not (float(sigma2) > 0 and np.isfinite(sigma2)) or int(window) != window \
                or window < 1:
            raise InputError(f"{source}: bandwidth {sigma2!r} or window {window!r} invalid")
        cut = np.cumsum(lengths)[:-1]
        lib = tuple(zip(np.split(hi, cut), np.split(rul, cut), strict=True))
        return cls(lib, float(sigma2), int(window), column)

    def predict_unit(self, hi) -> np.ndarray:
        """The prediction at every flight of one unit whose health index per flight is
        ``hi`` (in flight order)."""
        h = np.asarray(hi, float)
        out = np.empty(len(h))
        for n in range(len(h)):
            k = min(self.window, n + 1)
            x = h[n - k + 1:n + 1]
            d, votes = [], []
            for lib_hi, lib_rul in self.library:
                if len(lib_hi) < k:
                    continue
                windows = np.lib.stride_tricks.sliding_window_view(lib_hi, k)
                dist = np.mean((windows - x) ** 2, axis=1)
                m = int(np.argmin(dist))
                d.append(dist[m])
                votes.append(lib_rul[m + k - 1])
            if not votes:
                raise InputError(f"similarity: no library unit has {k} flights")
            d = np.asarray(d)
            w = np.exp(-k * (d - d.min()) / (4.0 * self.sigma2))
            out[n] = float(np.sum(w * np.asarray(votes)) / np.sum(w))
        return out

    def predict(self, flights: pd.DataFrame, max_rul: float | None = None) -> pd.DataFrame:
        """Per flight of ``flights`` (a flight table with the health index): ``unit``,
        ``cycle``, ``t``, ``RUL`` and ``hs`` where present, and ``RUL_pred`` (capped at ``max_rul``
        like capped targets when given)."""
        keep = [c for c in ("unit", "cycle", "t", TARGET, "hs") if c in flights.columns]
        frames = []
        for _, g in _series(flights, self.column, "similarity").items():
            f = g[keep].copy()
            pred = self.predict_unit(g[self.column].to_numpy(float))
            f["RUL_pred"] = pred if max_rul is None else np.clip(pred, 0.0, max_rul)
            frames.append(f)
        return pd.concat(frames, ignore_index=True)
