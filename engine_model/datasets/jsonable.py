"""Python and numpy values as JSON data: the one converter behind every JSON hyprog writes
(dataset metadata, run records, stage markers, reports, the CLI's ``--json``).

Conversions: numpy scalars become Python numbers (:meth:`numpy.generic.item`), arrays lists,
sets and frozensets sorted lists, paths strings.

- :func:`json_default` is the ``default`` hook of :func:`json.dumps`: it converts one value
  ``json`` cannot encode and raises TypeError for anything else. Non-finite numbers are left
  to ``json.dumps`` (``allow_nan=False`` refuses them: dataset metadata must be valid JSON).
- :func:`jsonable` converts a whole structure ahead of time: the same conversions, dict keys
  as strings, tuples as lists, and NaN and infinities as None (JSON ``null``: a metric that
  could not be computed). ``json.loads(json.dumps(jsonable(x)))`` is what a reader of the
  file gets back, so a record written and a record read are the same.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np


def json_default(obj: Any) -> Any:
    """``json.dumps`` ``default``: numpy scalars and arrays, sets (sorted) and paths."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (set, frozenset)):
        return sorted(obj)
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")


def jsonable(obj: Any) -> Any:
    """``obj`` as plain JSON data (module docstring); values that are neither JSON nor
    convertible are returned as they are (``json.dumps`` then says which)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (np.generic, np.ndarray, set, frozenset, Path)):
        return jsonable(json_default(obj))
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


__all__ = ["json_default", "jsonable"]
