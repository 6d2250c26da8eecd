"""A JSON-ready summary of a fleet table (``hyprog data info``): units, split, cycles, rows,
end of life, onset of abnormal degradation, flight classes, effects, columns by group."""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from ..validation import check_columns
from .jsonable import json_default
from .metadata import sample_rate
from .schema import INT_KEYS, column_groups


def _effects(meta: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The metadata's effects as [{"name", "params"}], from a list of dicts/names or a dict."""
    raw = meta.get("effects") or []
    if isinstance(raw, Mapping):
        return [{"name": str(k), "params": v if v is not None else {}} for k, v in raw.items()]
    out = []
    for e in raw:
        if isinstance(e, Mapping):
            out.append({"name": str(e.get("name")), "params": e.get("params") or {}})
        else:
            out.append({"name": str(e), "params": {}})
    return out


def _split_label(unit: int, dev: set[int], test: set[int], any_listed: bool) -> str | None:
    if unit in dev:
        return "dev"
    if unit in test:
        return "test"
    return None if any_listed else "dev"


def end_of_life(df: pd.DataFrame) -> pd.Series:
    """Per unit (in unit order): its last cycle plus the ``RUL`` at that cycle, the cycle at
    which it fails (a test unit is cut before failure); the last cycle alone without a
    ``RUL`` column. One definition for ``data info``, the reports and the prognostics'
    lives (:func:`prognostics.flights.unit_lives`)."""
    cols = ["unit", "cycle", *(["RUL"] if "RUL" in df.columns else [])]
    last = (df[cols].sort_values(["unit", "cycle"], kind="stable")
            .groupby("unit", sort=True).last())
    return last["cycle"] + last["RUL"] if "RUL" in last.columns else last["cycle"]


def summarize(df: pd.DataFrame, metadata: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """A JSON-serialisable summary of a fleet table (for ``hyprog data info``).

    ``units``: one entry per unit with ``split`` (dev/test from the metadata; all dev when it
    lists neither), ``cycles`` (distinct cycles), ``rows``, ``eol`` (the end of life: the last
    cycle, plus its ``RUL`` where the table has one, so that a test unit cut before failure
    shows when it fails), ``t_s`` (first
    cycle with ``hs == 0``, None if none or no ``hs``), ``Fc`` (the flight classes flown);
    ``totals`` (units, rows, cycles); ``sample_rate_hz``; ``effects``; ``columns`` by group.
    """
    meta = dict(metadata or {})
    check_columns(list(df.columns), INT_KEYS, what="summarize")
    by_unit = df.groupby("unit", sort=True)
    rows = by_unit.size()
    cycles = by_unit["cycle"].nunique()
    eol = end_of_life(df).fillna(by_unit["cycle"].max()).round().astype(np.int64)
    onset = (df.loc[df["hs"] == 0].groupby("unit")["cycle"].min() if "hs" in df.columns
             else pd.Series(dtype=np.int64))
    classes = by_unit["Fc"].unique() if "Fc" in df.columns else pd.Series(dtype=object)
    dev = {int(u) for u in meta.get("dev_units") or []}
    test = {int(u) for u in meta.get("test_units") or []}
    listed = meta.get("dev_units") is not None or meta.get("test_units") is not None
    units = []
    for u in rows.index:
        t_s = onset.get(u)
        fc = classes.get(u)
        units.append({
            "unit": int(u),
            "split": _split_label(int(u), dev, test, listed),
            "cycles": int(cycles[u]),
            "rows": int(rows[u]),
            "eol": int(eol[u]),
            "t_s": None if t_s is None or pd.isna(t_s) else int(t_s),
            "Fc": [] if fc is None else sorted(int(v) for v in pd.unique(fc) if not pd.isna(v)),
        })
    summary = {
        "units": units,
        "totals": {"units": len(units), "rows": int(len(df)), "cycles": int(cycles.sum())},
        "sample_rate_hz": sample_rate(meta),
        "effects": _effects(meta),
        "columns": column_groups(list(df.columns)),
        "dev_units": sorted(u["unit"] for u in units if u["split"] == "dev"),
        "test_units": sorted(u["unit"] for u in units if u["split"] == "test"),
    }
    for key in ("preset", "seed", "hyprog_version", "source_format"):
        if key in meta:
            summary[key] = meta[key]
    return json.loads(json.dumps(summary, default=json_default))
