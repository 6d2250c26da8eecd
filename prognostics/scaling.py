"""Scaling of the network inputs, fitted on training rows: the paper's min-max scaling
(:class:`MinMaxScaler`) and standardisation per operating condition (:class:`ConditionScaler`).

Min-max scaling to [-1, 1] (the paper, Sec. 4.2)
------------------------------------------------

For every input column j with minimum ``a_j`` and maximum ``b_j`` over the **training units
only** (validation flights, conformal-calibration units and test units never enter the fit)::

    x'_j = 2 (x_j - a_j) / (b_j - a_j) - 1

A constant column (``b_j - a_j <= 1e-12 max(1, |a_j|, |b_j|)``: a health parameter that does
not wear, an unused setting) carries no information; it maps to 0 everywhere instead of
dividing by zero. Values outside the training range are not clipped: a test unit beyond the
fleet's envelope gives inputs beyond [-1, 1], which the network sees as they are.

Standardisation per operating condition
---------------------------------------
A fleet flying several operating conditions (C-MAPSS FD002 / FD004: six) shows sensor levels
set by the condition far more than by wear; the standard remedy (Wang, Yu, Siegel & Lee, "A
similarity-based prognostics approach for remaining useful life estimation of engineered
systems", PHM 2008; used by most published FD002 / FD004 models) is to standardise every
sensor within its condition. With the table's integer ``condition`` column (``hyprog data
import-cmapss`` writes it; 0 means "no condition matched")::

    x'_j = (x_j - m_{c j}) / s_{c j}      m, s: mean and std of column j over the training rows
                                          of condition c

except for the operating settings themselves (the ``w`` columns, which define the condition
and would become its noise), which are min-max scaled over the fleet as above. A column that
is constant within a condition (``s_{cj}`` within the rounding test above of 0) maps to 0 there.
Rows of a condition the training rows did not contain, or of condition 0, are an error naming
the first such unit and cycle: the model has no statistics for them.

Both scalers are stored with the model as plain lists (``to_dict``; :func:`scaler_from_dict`
reads either back), so a checkpoint holds no pickled object.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from engine_model.channels import W_NAMES
from engine_model.validation import InputError

CONSTANT_RTOL = 1e-12
CONDITION = "condition"


def _is_constant(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    ref = np.maximum(1.0, np.maximum(np.abs(lo), np.abs(hi)))
    return (hi - lo) <= CONSTANT_RTOL * ref


@dataclass(frozen=True)
class MinMaxScaler:
    """Column-wise affine map ``x' = x * scale + offset`` onto [-1, 1] (module docstring)."""

    columns: tuple[str, ...]
    minimum: np.ndarray
    maximum: np.ndarray

    @classmethod
    def fit(cls, x: np.ndarray, columns: Sequence[str]) -> MinMaxScaler:
        """Fit on the training rows ``x`` (n, k) whose columns are ``columns``."""
        x = np.asarray(x)
        if x.ndim != 2 or x.shape[1] != len(columns):
            raise InputError(f"scaler: expected (n, {len(columns)}) training rows, got "
                             f"{x.shape}")
        if len(x) == 0:
            raise InputError("scaler: no training rows to fit on")
        return cls(tuple(columns), x.min(axis=0).astype(np.float64),
                   x.max(axis=0).astype(np.float64))

    @classmethod
    def fit_frame(cls, df: pd.DataFrame, columns: Sequence[str],
                  rows: np.ndarray | None = None) -> MinMaxScaler:
        """Fit on the rows ``rows`` (a boolean mask; None: all) of ``df[columns]``, one column
        at a time (no float64 copy of the whole table)."""
        columns = list(columns)
        lo, hi = np.empty(len(columns)), np.empty(len(columns))
        for j, c in enumerate(columns):
            v = df[c].to_numpy(np.float64)
            v = v if rows is None else v[rows]
            if v.size == 0:
                raise InputError("scaler: no training rows to fit on")
            lo[j], hi[j] = v.min(), v.max()
        return cls(tuple(columns), lo, hi)

    @property
    def constant(self) -> np.ndarray:
        return _is_constant(self.minimum, self.maximum)

    def subset(self, columns: Sequence[str]) -> MinMaxScaler:
        """The scaler of ``columns`` only (in that order)."""
        idx = [self.columns.index(c) for c in columns]
        return MinMaxScaler(tuple(columns), self.minimum[idx], self.maximum[idx])

    def _affine(self) -> tuple[np.ndarray, np.ndarray]:
        span = np.where(self.constant, 1.0, self.maximum - self.minimum)
        scale = np.where(self.constant, 0.0, 2.0 / span)
        offset = np.where(self.constant, 0.0, -1.0 - self.minimum * scale)
        return scale, offset

    def transform(self, x: np.ndarray, dtype=np.float32) -> np.ndarray:
        """Scaled copy of ``x`` (n, k) as a C-contiguous ``dtype`` array."""
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != len(self.columns):
            raise InputError(f"scaler: expected (n, {len(self.columns)}) rows, got {x.shape}")
        scale, offset = self._affine()
        return np.ascontiguousarray(x * scale + offset, dtype=dtype)

    def transform_frame(self, df: pd.DataFrame, dtype=np.float32,
                        source: str = "table") -> np.ndarray:
        """``transform(df[columns])`` computed one column at a time into one C-contiguous
        ``dtype`` array: the same numbers, without a float64 copy of the whole table."""
        scale, offset = self._affine()
        out = np.empty((len(df), len(self.columns)), dtype=dtype)
        for j, c in enumerate(self.columns):
            out[:, j] = df[c].to_numpy(np.float64) * scale[j] + offset[j]
        return out

    def to_dict(self) -> dict:
        return {"kind": "minmax", "columns": list(self.columns),
                "minimum": self.minimum.tolist(), "maximum": self.maximum.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> MinMaxScaler:
        try:
            cols = tuple(str(c) for c in d["columns"])
            lo = np.asarray(d["minimum"], dtype=np.float64)
            hi = np.asarray(d["maximum"], dtype=np.float64)
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"scaler: malformed record ({e})") from None
        if lo.shape != (len(cols),) or hi.shape != (len(cols),) or np.any(hi < lo):
            raise InputError("scaler: minimum/maximum do not match its columns")
        return cls(cols, lo, hi)


def _conditions(df: pd.DataFrame, source: str) -> np.ndarray:
    if CONDITION not in df.columns:
        raise InputError(f"{source}: normalising per operating condition needs a "
                         f"{CONDITION!r} column (hyprog data import-cmapss writes it)")
    return df[CONDITION].to_numpy().astype(np.int64)


@dataclass(frozen=True)
class ConditionScaler:
    """Per-condition standardisation of the sensors, min-max scaling of the operating
    settings (module docstring). ``mean`` and ``std`` are ``(n_conditions, k)``, rows in
    the order of ``conditions``; the settings' rows are unused (their scaling is ``settings``)."""

    columns: tuple[str, ...]
    conditions: tuple[int, ...]
    mean: np.ndarray
    std: np.ndarray
    settings: MinMaxScaler

    @classmethod
    def fit_frame(cls, df: pd.DataFrame, columns: Sequence[str],
                  rows: np.ndarray | None = None, source: str = "table") -> ConditionScaler:
        columns = list(columns)
        cond = _conditions(df, source)
        cond = cond if rows is None else cond[rows]
        if cond.size == 0:
            raise InputError("scaler: no training rows to fit on")
        zero = cond == 0
        if zero.any():
            i = int(np.flatnonzero(rows)[np.flatnonzero(zero)[0]]) if rows is not None \
                else int(np.flatnonzero(zero)[0])
            raise InputError(f"{source}: unit {int(df['unit'].iloc[i])}, cycle "
                             f"{int(df['cycle'].iloc[i])}: condition 0 (no operating "
                             "condition matched) cannot be standardised by condition")
        conds = np.unique(cond)
        mean = np.zeros((len(conds), len(columns)))
        std = np.zeros((len(conds), len(columns)))
        for j, c in enumerate(columns):
            v = df[c].to_numpy(np.float64)
            v = v if rows is None else v[rows]
            for i, k in enumerate(conds):
                x = v[cond == k]
                mean[i, j], std[i, j] = x.mean(), x.std()
        settings = [c for c in columns if c in W_NAMES]
        mm = MinMaxScaler.fit_frame(df, settings, rows) if settings else \
            MinMaxScaler((), np.zeros(0), np.zeros(0))
        return cls(tuple(columns), tuple(int(k) for k in conds), mean, std, mm)

    @property
    def _flat(self) -> np.ndarray:
        """``(n_conditions, k)``: column j is constant within condition c."""
        return _is_constant(self.mean - self.std, self.mean + self.std)

    @property
    def constant(self) -> np.ndarray:
        """Columns constant within every condition (a setting: constant over the fleet)."""
        out = np.all(self._flat, axis=0)
        for j, c in enumerate(self.columns):
            if c in self.settings.columns:
                out[j] = bool(self.settings.constant[self.settings.columns.index(c)])
        return out

    def subset(self, columns: Sequence[str]) -> ConditionScaler:
        idx = [self.columns.index(c) for c in columns]
        keep = [c for c in self.settings.columns if c in set(columns)]
        return ConditionScaler(tuple(columns), self.conditions, self.mean[:, idx],
                               self.std[:, idx], self.settings.subset(keep))

    def transform_frame(self, df: pd.DataFrame, dtype=np.float32,
                        source: str = "table") -> np.ndarray:
        cond = _conditions(df, source)
        where = np.searchsorted(self.conditions, cond)
        where = np.clip(where, 0, len(self.conditions) - 1)
        unknown = np.asarray(self.conditions)[where] != cond
        if unknown.any():
            i = int(np.flatnonzero(unknown)[0])
            raise InputError(f"{source}: unit {int(df['unit'].iloc[i])}, cycle "
                             f"{int(df['cycle'].iloc[i])}: condition {int(cond[i])} is not one "
                             "the model was trained on (conditions "
                             f"{', '.join(map(str, self.conditions))})")
        scale_s, offset_s = self.settings._affine()
        flat = self._flat
        out = np.empty((len(df), len(self.columns)), dtype=dtype)
        for j, c in enumerate(self.columns):
            v = df[c].to_numpy(np.float64)
            if c in self.settings.columns:
                k = self.settings.columns.index(c)
                out[:, j] = v * scale_s[k] + offset_s[k]
                continue
            s = np.where(flat[:, j], 1.0, self.std[:, j])
            z = (v - self.mean[where, j]) / s[where]
            out[:, j] = np.where(flat[where, j], 0.0, z)
        return out

    def to_dict(self) -> dict:
        return {"kind": "condition", "columns": list(self.columns),
                "conditions": list(self.conditions), "mean": self.mean.tolist(),
                "std": self.std.tolist(), "settings": self.settings.to_dict()}

    @classmethod
    def from_dict(cls, d: dict) -> ConditionScaler:
        try:
            cols = tuple(str(c) for c in d["columns"])
            conds = tuple(int(k) for k in d["conditions"])
            mean = np.asarray(d["mean"], dtype=np.float64).reshape(len(conds), len(cols))
            std = np.asarray(d["std"], dtype=np.float64).reshape(len(conds), len(cols))
            settings = MinMaxScaler.from_dict(d["settings"])
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"scaler: malformed record ({e})") from None
        if np.any(std < 0) or list(conds) != sorted(set(conds)):
            raise InputError("scaler: malformed per-condition statistics")
        return cls(cols, conds, mean, std, settings)


Scaler = MinMaxScaler | ConditionScaler


def fit_scaler(kind: str, df: pd.DataFrame, columns: Sequence[str],
               rows: np.ndarray | None = None, source: str = "table") -> Scaler:
    """The scaler of ``kind`` (``minmax`` or ``condition``) fitted on ``rows`` of ``df``."""
    if kind == "minmax":
        return MinMaxScaler.fit_frame(df, columns, rows)
    if kind == "condition":
        return ConditionScaler.fit_frame(df, columns, rows, source)
    raise InputError(f"normalise must be minmax or condition, got {kind!r}")


def scaler_from_dict(d: dict) -> Scaler:
    """Either scaler from its ``to_dict`` record (a record without ``kind`` is min-max)."""
    kind = d.get("kind", "minmax") if isinstance(d, dict) else None
    if kind == "condition":
        return ConditionScaler.from_dict(d)
    if kind == "minmax":
        return MinMaxScaler.from_dict(d)
    raise InputError(f"scaler: unknown kind {kind!r}")
