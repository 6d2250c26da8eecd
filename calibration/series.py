"""One unit's data, checked and converted to the arrays every estimator uses.

:func:`prepare_unit` checks a unit's DataFrame (columns, NaN, envelope, positive readings;
errors name the source file, unit, row and column), evaluates the sensor noise ``sigma`` of
:mod:`engine_model.simulator.sensor_noise` and the drift time ``dtau`` of the random-walk prior
(:mod:`calibration.estimation_setup`: per cycle or per time).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from engine_model.channels import W_NAMES
from engine_model.datasets.schema import first_non_number
from engine_model.simulator.sensor_noise import sigma_abs
from engine_model.units import C_TO_K, R_PER_K
from engine_model.validation import ENVELOPE, InputError, check_w

from .estimation_setup import CalibrationSetup
from .measurement_noise import with_model_error


def error_prefix(unit, source) -> str:
    """The ``"<file>, unit <n>: "`` prefix of an error message (empty when neither known)."""
    parts = [str(source)] if source is not None else []
    if unit is not None:
        parts.append(f"unit {unit}")
    return (", ".join(parts) + ": ") if parts else ""


@dataclass
class UnitSeries:
    """One unit's data as arrays, checked.

    ``w`` (N, 4), ``y`` (N, m) readings of ``sensors``, ``sigma`` (N, m) their noise std,
    ``dt_h`` (N,) operating time since the previous sample [h] (0 at the first; one sample
    period across a flight boundary), ``dtau_h`` (N,) the drift time before each sample
    (``setup.drift_per``: equal to ``dt_h``, or the previous cycle's duration at a cycle's
    first sample and 0 elsewhere),
    ``cycle`` (N,) or None, ``index`` the input rows' labels, ``unit`` the unit label or None.
    """

    w: np.ndarray
    y: np.ndarray
    sigma: np.ndarray
    dt_h: np.ndarray
    dtau_h: np.ndarray
    sensors: tuple
    index: pd.Index
    cycle: np.ndarray | None = None
    unit: object = None

    def __len__(self):
        return len(self.w)

    def q_diag(self, setup: CalibrationSetup) -> np.ndarray:
        """(N,) variance of the random-walk step before each sample (same for every theta)."""
        return setup.drift ** 2 * self.dtau_h


def _numbers(df: pd.DataFrame, columns, where: str) -> np.ndarray:
    """``df[columns]`` as a float array; a value that is not a number is an InputError naming
    its row (the index label: the row of the user's file when the reader set it) and column."""
    try:
        return df[list(columns)].to_numpy(float)
    except (TypeError, ValueError):
        pass
    for c in columns:
        i = first_non_number(df[c])
        if i is not None:
            raise InputError(f"{where}row {df.index[i]}, column {c}: {df[c].iloc[i]!r} is not"
                             " a number")
    return df[list(columns)].apply(pd.to_numeric, errors="coerce").to_numpy(float)


def _t2_hint(w: np.ndarray) -> str:
    """`` (T2 looks like K ...)`` when the T2 column read as K or degC lies in the envelope
    (the model reads degR), else empty."""
    t2 = w[:, W_NAMES.index("T2")]
    lo, hi = ENVELOPE.T2
    for unit, as_r in (("K", t2 * R_PER_K), ("degC", (t2 + C_TO_K) * R_PER_K)):
        if np.all((as_r >= lo) & (as_r <= hi)) and not np.all((t2 >= lo) & (t2 <= hi)):
            return f" (column T2 looks like {unit}; the model reads degR)"
    return ""


def _check_duplicate_times(df: pd.DataFrame, where: str) -> None:
    """Two samples of one flight at the same time ``t`` are an error naming both rows."""
    keys = [k for k in ("cycle", "t") if k in df.columns]
    if "t" not in keys:
        return
    dup = df.duplicated(keys, keep=False).to_numpy()
    if dup.any():
        first = np.flatnonzero(dup)[:2]
        rows = " and ".join(str(df.index[i]) for i in first)
        at = ", ".join(f"{k} = {df[k].iloc[first[0]]:g}" for k in keys)
        raise InputError(f"{where}rows {rows} have the same {' and '.join(keys)} ({at}):"
                         f" duplicated time stamps ({int(dup.sum())} rows in all)")


def unit_label(df: pd.DataFrame, source=None):
    """The unit of ``df`` (the value of its ``unit`` column, as a Python scalar), or None
    without that column or rows; rows of several units are an InputError."""
    if "unit" not in df.columns or not len(df):
        return None
    u = pd.unique(df["unit"])
    if len(u) > 1:
        raise InputError(f"{error_prefix(None, source)}one unit at a time, got units "
                         f"{', '.join(map(str, u[:5]))}")
    return u[0].item() if hasattr(u[0], "item") else u[0]


def prepare_unit(df: pd.DataFrame, setup: CalibrationSetup, source=None) -> UnitSeries:
    """Check and convert one unit's DataFrame. Errors name the source (file), unit, row and
    column: a missing column, a value that is not a number, a NaN or infinite value, an
    operating point outside the envelope, a reading <= 0 where the noise model needs a
    positive one, two samples with the same cycle and time. Rows are the DataFrame's index
    labels (:func:`calibration.calibrate_fleet.calibrate_fleet` sets them to the 1-based rows of the
    user's file)."""
    unit = unit_label(df, source)
    where = error_prefix(unit, source)
    if len(df) == 0:
        raise InputError(f"{where}no rows")
    missing = [c for c in W_NAMES if c not in df.columns]
    if missing:
        raise InputError(f"{where}missing column(s) {', '.join(missing)}")
    try:
        sensors = setup.resolve_sensors(df.columns)
    except InputError as e:
        raise InputError(f"{where}{e}") from None
    index = df.index
    w = _numbers(df, W_NAMES, where)
    y = _numbers(df, sensors, where)
    for arr, names in ((w, W_NAMES), (y, sensors)):
        bad = ~np.isfinite(arr)
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise InputError(f"{where}row {index[i]}, column {names[j]}: value is {arr[i, j]}"
                             " (NaN or infinite)")
    nonpos = y <= 0
    if nonpos.any():
        i, j = np.argwhere(nonpos)[0]
        raise InputError(f"{where}row {index[i]}, column {sensors[j]} = {y[i, j]:g}: a "
                         "reading must be positive (noise is proportional to it)")
    try:
        check_w(w, np.asarray(index), "data")
    except InputError as e:
        raise InputError(f"{where}{str(e).removeprefix('data: ')}{_t2_hint(w)}") from None
    if setup.noise == "data":
        if "condition" not in df.columns:
            raise InputError(f"{where}no column 'condition': the data's noise (noise='data') "
                             "is per operating condition")
        sigma = setup.noise_scale * setup.data_noise(
            df["condition"].to_numpy(), sensors, where)
    else:
        sigma = sigma_abs(y, sensors, scale=setup.noise_scale)
    sigma = with_model_error(sigma, setup.model_error, y)
    n = len(df)
    cycle = df["cycle"].to_numpy() if "cycle" in df.columns else None
    _check_duplicate_times(df, where)
    period = setup.sample_period_s
    if "t" in df.columns:
        t = df["t"].to_numpy(float)
        if not np.all(np.isfinite(t)):
            i = int(np.flatnonzero(~np.isfinite(t))[0])
            raise InputError(f"{where}row {index[i]}, column t: value is {t[i]}")
        dt = np.diff(t, prepend=t[0])
        pos = dt[dt > 0]
        period = float(np.median(pos)) if pos.size else period
        new = dt <= 0
        if cycle is not None:
            new |= np.diff(cycle, prepend=cycle[0]) != 0
        dt = np.where(new, period, dt)
    else:
        dt = np.full(n, period)
    dt[0] = 0.0
    per = setup.drift_per
    if per == "auto":
        per = "cycle" if cycle is not None else "time"
    if per == "cycle":
        if cycle is None:
            raise InputError(f"{where}drift per cycle needs a 'cycle' column")
        starts = np.flatnonzero(np.diff(cycle, prepend=cycle[0]) != 0)
        # a cycle's recorded duration: the spacing of its samples, one period for the first
        durations = np.add.reduceat(dt, np.concatenate([[0], starts]))
        durations[0] += period
        dtau = np.zeros(n)
        dtau[starts] = durations[:-1]
    else:
        dtau = dt.copy()
    return UnitSeries(w=w, y=y, sigma=sigma, dt_h=dt / 3600.0, dtau_h=dtau / 3600.0,
                      sensors=sensors, index=index, cycle=cycle, unit=unit)


def early_samples(series: UnitSeries, n: int) -> UnitSeries:
    """The unit's first ``n`` samples (all when shorter), as a series of their own."""
    if len(series) <= n:
        return series
    cut = {k: getattr(series, k)[:n] for k in ("w", "y", "sigma", "dt_h", "dtau_h", "index")}
    if series.cycle is not None:
        cut["cycle"] = series.cycle[:n]
    return replace(series, **cut)
