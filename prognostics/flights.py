"""Flight-level tables: one row per unit and flight, and the health coordinates of θ̂.

A sample-level feature table (``hyprog calibrate``'s, 0.1 Hz: hundreds of rows a flight) sees
a few minutes of one flight per window; the degradation that sets the remaining life shows
across flights (issue 30). :func:`flight_table` condenses a table to one row per
``(unit, cycle)``, available at the end of that flight (every value of row ``c`` is computed
from the samples of flights ``1 .. c`` only: the table is causal):

- **Aggregates.** Every numeric column but the keys is the flight's **mean** (``w``, ``x_s``,
  ``x̂_s``, ``x̂_v``, ``θ̂``, ``θ̂`` std, true ``θ`` in simulated data) under its own name, so
  the input groups of :mod:`.features` resolve on a flight table as on a sample table;
  ``RUL``, ``hs``, ``condition`` and ``Fc`` are the flight's last value. A table with one row
  per cycle (C-MAPSS) keeps its rows.
- **Health coordinates** (with a health index ``hi``,
  :class:`engine_model.physics.health_index.HealthIndex`): from the flight's mean θ̂ (a
  parameter not estimated, or unobservable, at its nominal 0, as
  :func:`.baseline.theta_per_cycle` places it) at the reference condition, the health index
  ``HI_hat`` and the normalised margins that define it, ``margin_fan_hat``,
  ``margin_lpc_hat``, ``margin_hpc_hat`` (stall) and ``margin_egt_hat`` (EGT): N-CMAPSS's
  definition (Arias Chao et al., *Data* 6(1):5, 2021), 1 for a new engine, 0 at the limit;
  ``HI_hat`` is their minimum. With the true θ in the table (simulation), ``HI`` and
  ``margin_*`` are the same at the true θ (the perfect calibration of the paper's ablation
  III); at the true θ they equal the simulator's health index.
- **Relative to the unit's own early life.** ``<q>_hat_rel = θ̂_c - θ̂_ref(c)`` and
  ``HI_hat_rel``, where the reference is the mean over the unit's first :data:`REF_FLIGHTS`
  flights, or over the flights seen so far while there are fewer (causal). Engines leave the
  factory different (initial wear; in C-MAPSS, a model-engine mismatch that lands in θ̂):
  the change since entry into service is what degradation is, and its direction names the
  failure mode (HPT alone, or HPT with LPT, in ``ds02``).
- **Failure mode** (issue 30): the direction of that change, ``<q>_mode``,

      m_q = Δθ̂_q / sqrt(|Δθ̂|² + (3 s)²),   s² = Σ_q σ̄_q²,

  with ``Δθ̂ = θ̂_c - θ̂_ref(c)`` over the estimated parameters and ``σ̄_q`` the flight's mean
  standard deviation of θ̂_q (``<q>_hat_std``). Once the change is well above its
  uncertainty (three standard deviations, the usual detection level) ``m`` is the unit vector
  of the change, its direction cosines: (-1, 0, 0) for a pure HPT efficiency loss, a mix for
  HPT with LPT; while the change is within the noise it shrinks to 0, so that no direction is
  claimed before there is one. A physical reading, not a fitted knob: the mode is where
  θ̂ moves, and the scale is θ̂'s own uncertainty. Without ``_hat_std`` columns, ``s = 0``.

A flight model's prediction for flight ``c`` is issued at the end of that flight (the
convention of the physics baseline, :mod:`.baseline`); on a sample table every sample of the
flight carries it (:func:`to_samples`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from engine_model.channels import THETA_NAMES
from engine_model.datasets.summary import end_of_life
from engine_model.validation import InputError

from .baseline import theta_per_cycle
from .features import HEALTH_STEMS, KEYS, TARGET, sort_table

REF_FLIGHTS = 5
MODE_SIGMAS = 3.0  # a change is a direction once it is this many standard deviations
LAST = (TARGET, "hs", "condition", "Fc")  # labels: the flight's last value
NOT_AGGREGATED = ("t",)
#: HealthIndex component -> column stem of its normalised margin
MARGINS = dict(zip(("SmFan", "SmLPC", "SmHPC", "EGT"), HEALTH_STEMS[1:], strict=True))


def unit_lives(flights: pd.DataFrame) -> pd.Series:
    """End of life of every unit of a flight table: its last cycle plus that cycle's RUL
    (:func:`engine_model.datasets.summary.end_of_life`)."""
    if TARGET not in flights.columns:
        raise InputError(f"a unit's life needs the {TARGET} column")
    return end_of_life(flights)


def one_per_cycle(df: pd.DataFrame) -> bool:
    """True when no two rows share a unit and a cycle."""
    return not df.duplicated(list(KEYS)).any()


def _health(th: pd.DataFrame, hi, suffix: str) -> dict[str, np.ndarray]:
    comp = hi.components(th[list(THETA_NAMES)].to_numpy())
    out = {"HI" + suffix: np.asarray(hi.of_components(comp), float)}
    for k, stem in MARGINS.items():
        out[stem + suffix] = np.asarray(comp[k], float)
    return out


def causal_reference(unit: np.ndarray, values: np.ndarray, n_ref: int = REF_FLIGHTS
                     ) -> np.ndarray:
    """Per row, the mean of the unit's first ``min(k + 1, n_ref)`` rows up to and including
    row ``k`` of that unit (rows ordered by unit, cycle; ``values`` (n,) or (n, m))."""
    if n_ref < 1:
        raise InputError(f"reference flights must be >= 1, got {n_ref}")
    v = np.asarray(values, float)
    out = np.empty_like(v)
    starts = np.flatnonzero(np.r_[True, unit[1:] != unit[:-1]])
    ends = np.r_[starts[1:], len(unit)]
    for a, b in zip(starts, ends, strict=True):
        seg = v[a:b]
        k = np.arange(1, b - a + 1)
        running = np.cumsum(seg, axis=0) / (k[:, None] if seg.ndim == 2 else k)
        stop = min(n_ref, b - a) - 1
        out[a:b] = running
        out[a + stop:b] = running[stop]
    return out


def flight_table(df: pd.DataFrame, hi=None, ref_flights: int = REF_FLIGHTS,
                 source: str = "table") -> pd.DataFrame:
    """The flight-level table of ``df`` (module docstring), ordered by unit and cycle; health
    coordinates when ``hi`` is given and the table has ``<q>_hat`` columns."""
    missing = [k for k in KEYS if k not in df.columns]
    if missing:
        raise InputError(f"{source}: missing column(s) {', '.join(missing)}")
    frame = sort_table(df)
    numeric = [c for c in frame.columns
               if c not in (*KEYS, *NOT_AGGREGATED) and np.issubdtype(frame[c].dtype, np.number)]
    means = [c for c in numeric if c not in LAST]
    lasts = [c for c in numeric if c in LAST]
    g = frame.groupby(list(KEYS), sort=True)
    out = g[means].mean() if means else g.size().to_frame("n").drop(columns="n")
    if lasts:
        out = out.join(g[lasts].last())
    out = out.reset_index()
    if hi is None:
        return out
    estimated = [q for q in THETA_NAMES if q + "_hat" in out.columns
                 and not out[q + "_hat"].isna().all()]
    if not estimated:
        return out
    # ``out`` already holds each flight's mean of every column: θ per cycle is read from it
    cols = dict(_health(theta_per_cycle(out), hi, "_hat"))
    if all(q in out.columns for q in estimated):
        cols.update(_health(theta_per_cycle(out, suffix=""), hi, ""))
    unit = out["unit"].to_numpy()
    rel_src = np.column_stack([out[q + "_hat"].to_numpy(float) for q in estimated]
                              + [cols["HI_hat"]])
    rel = rel_src - causal_reference(unit, rel_src, ref_flights)
    for j, q in enumerate(estimated):
        cols[q + "_hat_rel"] = rel[:, j]
    cols["HI_hat_rel"] = rel[:, -1]
    delta = rel[:, :-1]
    std = [out[q + "_hat_std"].to_numpy(float) for q in estimated if q + "_hat_std" in out]
    s2 = np.sum(np.square(std), axis=0) if len(std) == len(estimated) else 0.0
    norm = np.sqrt(np.sum(delta * delta, axis=1) + MODE_SIGMAS ** 2 * s2)
    with np.errstate(invalid="ignore", divide="ignore"):
        mode = np.where(norm[:, None] > 0, delta / norm[:, None], 0.0)
    for j, q in enumerate(estimated):
        cols[q + "_mode"] = mode[:, j]
    out = out.drop(columns=[c for c in cols if c in out.columns])  # a flight table again
    return pd.concat([out, pd.DataFrame(cols, index=out.index)], axis=1)


def to_samples(flight_pred: pd.DataFrame, df: pd.DataFrame,
               columns: Sequence[str] = ("RUL_pred",)) -> pd.DataFrame:
    """Per-sample frame (``unit``, ``cycle``, ``t`` and ``RUL`` when ``df`` has them) with the
    flight-level ``columns`` of the sample's flight."""
    frame = sort_table(df)
    keep = [c for c in ("unit", "cycle", "t", TARGET, "hs") if c in frame.columns]
    return frame[keep].merge(flight_pred[[*KEYS, *columns]], on=list(KEYS),
                             how="inner").reset_index(drop=True)
