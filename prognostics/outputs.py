"""Atomic output files: a reader never sees half a file, an error leaves the old file alone.

Every writer builds its file as a hidden temporary sibling (``.<name>.tmp-<host>-<pid>-<random>``,
:func:`engine_model.runtime.atomic.temporary_prefix`) and moves it into place with
``os.replace`` (atomic on POSIX within a file system) only after writing succeeded; on any
exception the temporary is removed. A writer killed outright (SIGKILL) leaves only its hidden
temporary, which :func:`engine_model.runtime.atomic.remove_stale_temporaries` deletes once
that process is gone.
"""

from __future__ import annotations

import json
import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pandas as pd

from engine_model.runtime.atomic import temporary_prefix


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` if the block succeeds."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.parent / f"{temporary_prefix(target.name)}{uuid.uuid4().hex}{target.suffix}"
    try:
        yield tmp
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_text(path: str | os.PathLike, text: str) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def write_json(path: str | os.PathLike, obj) -> Path:
    return write_text(path, json.dumps(obj, indent=1, allow_nan=False, default=_plain) + "\n")


def write_table(path: str | os.PathLike, df: pd.DataFrame) -> Path:
    """CSV for ``.csv``, parquet (one file) otherwise."""
    p = Path(path)
    with atomic_path(p) as tmp:
        if p.suffix.lower() == ".csv":
            df.to_csv(tmp, index=False)
        else:
            df.to_parquet(tmp, index=False)
    return p


def _plain(o):
    if hasattr(o, "item"):
        return o.item()
    if hasattr(o, "tolist"):
        return o.tolist()
    raise TypeError(f"not JSON-serialisable: {type(o).__name__}")


def finite_or_none(v):
    """JSON-ready number: NaN / inf -> None."""
    import math

    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None
