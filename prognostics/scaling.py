"""Min-max scaling of the inputs to [-1, 1] (the paper, Sec. 4.2), fitted on training rows.

For every input column j with minimum ``a_j`` and maximum ``b_j`` over the **training units
only** (validation flights, conformal-calibration units and test units never enter the fit)::

    x'_j = 2 (x_j - a_j) / (b_j - a_j) - 1

A constant column (``b_j - a_j <= 1e-12 max(1, |a_j|, |b_j|)``: a health parameter that does
not wear, an unused setting) carries no information; it maps to 0 everywhere instead of
dividing by zero. Values outside the training range are not clipped: a test unit beyond the
fleet's envelope gives inputs beyond [-1, 1], which the network sees as they are.

The scaler is stored with the model as plain lists (:meth:`MinMaxScaler.to_dict`), so a
checkpoint holds no pickled object.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from engine_model.validation import InputError

CONSTANT_RTOL = 1e-12


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
        span = self.maximum - self.minimum
        ref = np.maximum(1.0, np.maximum(np.abs(self.minimum), np.abs(self.maximum)))
        return span <= CONSTANT_RTOL * ref

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

    def transform_frame(self, df: pd.DataFrame, dtype=np.float32) -> np.ndarray:
        """``transform(df[columns])`` computed one column at a time into one C-contiguous
        ``dtype`` array: the same numbers, without a float64 copy of the whole table."""
        scale, offset = self._affine()
        out = np.empty((len(df), len(self.columns)), dtype=dtype)
        for j, c in enumerate(self.columns):
            out[:, j] = df[c].to_numpy(np.float64) * scale[j] + offset[j]
        return out

    def to_dict(self) -> dict:
        return {"columns": list(self.columns), "minimum": self.minimum.tolist(),
                "maximum": self.maximum.tolist()}

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
