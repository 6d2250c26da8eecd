"""Fingerprints of data: what a resumed run compares to know that its earlier output was
computed from the very same input. One module for all of them; each function says in its name
what it hashes, and each value is pinned by a test (``tests/test_output_ownership.py``):
committed results and caches are keyed on them, so the hashing never changes.

==========================  ===================================================  ================
function                    hashes (hex SHA-256 of ...)                          keys
==========================  ===================================================  ================
:func:`rows_fingerprint`    a table's column names and dtypes, its row count     a calibrated
                            and ``pandas.util.hash_pandas_object`` of its rows   unit's input
                            (:data:`.schema.SOURCE_ROW` left out)                (resume)
:func:`table_fingerprint`   a table's column names (JSON), the row hashes and    the paper
                            its metadata (JSON, sorted keys)                     experiment's
                                                                                 runs
:func:`files_fingerprint`   the relative names and bytes of the data files of    the pipeline's
                            a dataset path (hidden entries left out)             stages
==========================  ===================================================  ================

``hash_pandas_object`` gives a 64-bit hash per row, stable across runs and machines for the
same values: a changed value, row, column or column order gives another fingerprint; the same
data read from parquet or from a re-written copy give the same one (the first two). The third
notices other data under the same path, also a change that reading would not show.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import pandas as pd

from .schema import SOURCE_ROW

FILE_CHUNK = 1 << 20


def rows_fingerprint(df: pd.DataFrame) -> str:
    """Hex SHA-256 of ``df``'s columns with their dtypes, its row count and its rows
    (module docstring; the 1-based source rows excluded)."""
    frame = df.drop(columns=[SOURCE_ROW], errors="ignore").reset_index(drop=True)
    h = hashlib.sha256()
    h.update(repr([(str(c), str(frame[c].dtype)) for c in frame.columns]).encode())
    h.update(len(frame).to_bytes(8, "little"))
    rows = pd.util.hash_pandas_object(frame, index=False).to_numpy(np.uint64)
    h.update(np.ascontiguousarray(rows).tobytes())
    return h.hexdigest()


def table_fingerprint(df: pd.DataFrame, metadata: dict | None) -> str:
    """Hex SHA-256 of ``df``'s column names, its rows and ``metadata`` (module docstring)."""
    h = hashlib.sha256()
    h.update(json.dumps(list(map(str, df.columns))).encode())
    h.update(pd.util.hash_pandas_object(df, index=False).to_numpy().tobytes())
    h.update(json.dumps(metadata or {}, sort_keys=True, default=str).encode())
    return h.hexdigest()


def files_fingerprint(path: str | os.PathLike) -> str:
    """Hex SHA-256 over the relative names and bytes of the data files of ``path`` (a file,
    or every non-hidden file under a directory, in path order)."""
    p = Path(path)
    files = [p] if p.is_file() else sorted(
        q for q in p.rglob("*") if q.is_file()
        and not any(part.startswith(".") for part in q.relative_to(p).parts))
    h = hashlib.sha256()
    for f in files:
        h.update(str(f.relative_to(p) if f != p else f.name).encode() + b"\0")
        with open(f, "rb") as fh:
            while chunk := fh.read(FILE_CHUNK):
                h.update(chunk)
    return h.hexdigest()


__all__ = ["files_fingerprint", "rows_fingerprint", "table_fingerprint"]
