"""A fingerprint of one unit's input rows, so that a resumed calibration only skips a unit
whose output was computed from the very same data.

``unit_fingerprint(df)`` is the SHA-256 of the unit's table as read (rows sorted by cycle and
t, every column, the 1-based source rows excluded): the column names and dtypes, then
``pandas.util.hash_pandas_object`` of the rows (a 64-bit hash per row, stable across runs and
machines for the same values). A changed value, row, column or column order gives another
fingerprint; the same data read from parquet or from a re-written copy give the same one.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pandas as pd

from engine_model.datasets import SOURCE_ROW


def unit_fingerprint(df: pd.DataFrame) -> str:
    """Hex SHA-256 of one unit's rows (module docstring)."""
    frame = df.drop(columns=[SOURCE_ROW], errors="ignore").reset_index(drop=True)
    h = hashlib.sha256()
    h.update(repr([(str(c), str(frame[c].dtype)) for c in frame.columns]).encode())
    h.update(len(frame).to_bytes(8, "little"))
    rows = pd.util.hash_pandas_object(frame, index=False).to_numpy(np.uint64)
    h.update(np.ascontiguousarray(rows).tobytes())
    return h.hexdigest()


def input_record(df: pd.DataFrame, unit: int, sensors) -> dict:
    """What a feature table records of one unit's input: unit, rows, sensors used and the
    fingerprint (:func:`unit_fingerprint`)."""
    return {"unit": int(unit), "rows": int(len(df)), "sensors": list(sensors),
            "sha256": unit_fingerprint(df)}


__all__ = ["input_record", "unit_fingerprint"]
