"""The fleet table's schema: column groups, canonical order, checks and normalisation.

Schema (one row per sample; the N-CMAPSS names of ``channels``)
----------------------------------------------------------------
bookkeeping  ``unit`` (int64), ``cycle`` (int64), ``t`` (float64, s since the start of the
             flight record), ``Fc`` (flight class 1/2/3), ``hs`` (1 healthy, 0 abnormal),
             ``RUL`` (cycles); ``Fc``/``hs``/``RUL`` are int64 when every value is an integer
w            ``alt Mach TRA T2``
x_s          ``channels.XS_NAMES`` (16), x_v ``channels.XV_NAMES`` (11) and ``phi``
theta        ``channels.THETA_NAMES`` (10)

Only ``unit cycle alt Mach TRA T2`` are required; any sensor, virtual or truth channel may be
absent (a user's file), and further columns are kept. ``unit`` and ``cycle`` must not be NaN.
Tables are returned sorted by ``unit, cycle, t`` with a fresh RangeIndex.

Ids: ``unit`` and ``cycle`` stored as integers must fit int64 (a uint64 above 2**63 - 1 is
refused); stored as floats or text they must be integers of magnitude at most
:data:`MAX_FLOAT_ID` (2**53 - 1: float64 holds every integer below 2**53 exactly, and no
2**53 read can be told from a rounded 2**53 + 1); otherwise the
error names the column, the row and the value. ``Fc``/``hs``/``RUL`` beyond that range stay
float64. The column name :data:`SOURCE_ROW` is reserved: a table holding it is not written.

Values: the channel columns (w, x_s, x_v, phi, theta, ``t``) are numbers; a column of numeric
strings (a CSV-born parquet file) is read as float64, a value that is not a number is an error
naming the column, the row and the value. Rows in messages are 1-based rows of the user's file
(:data:`SOURCE_ROW` when the reader added it, else the position in the table as given).

Splits: a dataset's units are either development (``dev``) or test units (``SPLITS``); which
is which is recorded in the metadata (:mod:`.metadata`) or, for h5, by the arrays.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from ..channels import THETA_NAMES, W_NAMES, XS_NAMES, XV_NAMES
from ..validation import InputError, check_columns

BOOKKEEPING = ("unit", "cycle", "t", "Fc", "hs", "RUL")
REQUIRED_COLUMNS = ("unit", "cycle", *W_NAMES)
INT_KEYS = ("unit", "cycle")  # must be integers, never NaN
INT_OPTIONAL = ("Fc", "hs", "RUL")  # int64 when every value is an integer
SORT_KEYS = ("unit", "cycle", "t")
SOURCE_ROW = "source_row"  # 1-based row of the user's file (readers add it on request)
#: the largest magnitude of a ``unit`` / ``cycle`` read as a float: float64 holds every
#: integer below 2**53 exactly; from 2**53 on, a value may be another id rounded (2**53 + 1
#: reads as 2**53), so ids would merge or change without a word
MAX_FLOAT_ID = 2**53 - 1
SPLITS = ("dev", "test")
CANONICAL = (*BOOKKEEPING, *W_NAMES, *XS_NAMES, *XV_NAMES, "phi", *THETA_NAMES)


def canonical_columns(columns: Iterable[str]) -> list[str]:
    """``columns`` in the schema order (bookkeeping, w, x_s, x_v, phi, theta), others after."""
    cols = list(columns)
    known = [c for c in CANONICAL if c in cols]
    return known + [c for c in cols if c not in known]


def column_groups(columns: Sequence[str]) -> dict[str, list[str]]:
    """The present ``columns`` by schema group: ``bookkeeping``, ``w``, ``x_s``, ``x_v``
    (with ``phi``), ``theta`` and ``other`` (everything else, in the given order)."""
    groups = {
        "bookkeeping": [c for c in BOOKKEEPING if c in columns],
        "w": [c for c in W_NAMES if c in columns],
        "x_s": [c for c in XS_NAMES if c in columns],
        "x_v": [c for c in (*XV_NAMES, "phi") if c in columns],
        "theta": [c for c in THETA_NAMES if c in columns],
    }
    known = {c for names in groups.values() for c in names}
    groups["other"] = [c for c in columns if c not in known]
    return groups


def check_unique(columns: Sequence[str], source: str) -> None:
    """InputError naming the duplicated column names, if any."""
    seen: set[str] = set()
    dup = sorted({c for c in columns if c in seen or seen.add(c)})
    if dup:
        raise InputError(f"{source}: duplicate column(s) {', '.join(dup)}")


NUMERIC_COLUMNS = ("t", *W_NAMES, *XS_NAMES, *XV_NAMES, "phi", *THETA_NAMES)


def row_label(df: pd.DataFrame, i: int):
    """The row of the ``i``-th row of ``df`` as the user knows it: the 1-based row of the file
    (:data:`SOURCE_ROW`, added by the readers), else the DataFrame's index label (a table
    given in memory)."""
    if SOURCE_ROW in df.columns:
        return int(df[SOURCE_ROW].iloc[i])
    label = df.index[i]
    return label.item() if hasattr(label, "item") else label


def first_non_number(col: pd.Series) -> int | None:
    """Position of the first value of ``col`` that is neither missing nor a number, or None."""
    bad = pd.to_numeric(col, errors="coerce").isna().to_numpy() & col.notna().to_numpy()
    return int(np.flatnonzero(bad)[0]) if bad.any() else None


def as_numeric(df: pd.DataFrame, source: str) -> pd.DataFrame:
    """The channel columns (:data:`NUMERIC_COLUMNS`) stored as text converted to float64; a
    value that is not a number is an InputError naming its column, row and value."""
    out = {}
    for name in NUMERIC_COLUMNS:
        if name not in df.columns or pd.api.types.is_numeric_dtype(df[name].dtype):
            continue
        col = df[name]
        i = first_non_number(col)
        if i is not None:
            raise InputError(f"{source}: row {row_label(df, i)}, column {name}: "
                             f"{col.iloc[i]!r} is not a number")
        out[name] = pd.to_numeric(col, errors="coerce").to_numpy(dtype=np.float64,
                                                                   na_value=np.nan)
    return df.assign(**out) if out else df


def as_int_keys(df: pd.DataFrame, source: str) -> pd.DataFrame:
    """``unit``/``cycle`` to int64 (NaN, fractions, an integer type's value beyond int64 or a
    float's beyond :data:`MAX_FLOAT_ID` are errors, and so is a cycle below 1: cycles count
    flights from 1, as C-MAPSS's and the simulator's do, and a unit's life is read from
    them); Fc/hs/RUL to int64 if exact; ``t`` to float64."""
    out = {}
    for name in (k for k in INT_KEYS if k in df.columns):
        col = df[name]
        if col.dtype == np.int64:
            continue
        if isinstance(col.dtype, np.dtype) and col.dtype.kind in "iu":  # exact, if it fits
            ints = col.to_numpy()
            big = ints > np.iinfo(np.int64).max if col.dtype.kind == "u" else np.zeros(0, bool)
            if big.any():
                i = int(np.flatnonzero(big)[0])
                raise InputError(f"{source}: column {name} = {ints[i]} at row {row_label(df, i)}"
                                 " is larger than an int64 holds")
            out[name] = ints.astype(np.int64)
            continue
        values = pd.to_numeric(col, errors="coerce").to_numpy(dtype=np.float64,
                                                               na_value=np.nan)
        bad = ~np.isfinite(values)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            text = f" ({col.iloc[i]!r})" if isinstance(col.iloc[i], str) else ""
            raise InputError(f"{source}: column {name} is NaN, missing or not a number{text}"
                             f" at row {row_label(df, i)}")
        frac = values != np.round(values)
        if frac.any():
            row = row_label(df, int(np.flatnonzero(frac)[0]))
            raise InputError(f"{source}: column {name} = {values[frac][0]:g} at row {row} is"
                             " not an integer")
        huge = np.abs(values) > MAX_FLOAT_ID
        if huge.any():
            i = int(np.flatnonzero(huge)[0])
            raise InputError(f"{source}: column {name} = {values[i]:g} at row {row_label(df, i)}"
                             " is beyond 2**53 - 1 in magnitude (not exact as a float; store ids"
                             " as int64)")
        out[name] = values.astype(np.int64)
    for name in INT_OPTIONAL:
        if name in df.columns and df[name].dtype != np.int64:
            values = pd.to_numeric(df[name], errors="coerce").to_numpy(dtype=np.float64,
                                                                       na_value=np.nan)
            if (np.isfinite(values).all() and (values == np.round(values)).all()
                    and (np.abs(values) <= MAX_FLOAT_ID).all()):
                out[name] = values.astype(np.int64)
    if "t" in df.columns and df["t"].dtype != np.float64:
        out["t"] = df["t"].to_numpy(dtype=np.float64, na_value=np.nan)
    if "cycle" in df.columns:
        cycle = out["cycle"] if "cycle" in out else df["cycle"].to_numpy()
        low = np.flatnonzero(cycle < 1)
        if low.size:
            i = int(low[0])
            unit = f"unit {int(df['unit'].iloc[i])}, " if "unit" in df.columns else ""
            raise InputError(f"{source}: {unit}row {row_label(df, i)}, column cycle = "
                             f"{int(cycle[i])}: cycles count flights from 1")
    return df.assign(**out) if out else df


def sort_keys(df: pd.DataFrame) -> list[str]:
    """The present ones of ``unit, cycle, t``: the order rows are kept in."""
    return [c for c in SORT_KEYS if c in df.columns]


def is_sorted(df: pd.DataFrame, keys: Sequence[str]) -> bool:
    """True when rows are already in lexicographic order of ``keys``."""
    if len(df) < 2:
        return True
    arrays = [df[k].to_numpy() for k in keys]
    undecided = np.ones(len(df) - 1, dtype=bool)  # pairs equal on all keys so far
    for a in arrays:
        lo, hi = a[:-1], a[1:]
        if (undecided & (hi < lo)).any():
            return False
        undecided &= hi == lo
    return True


def normalise_table(df: pd.DataFrame, source: str, unit_first: bool = True,
                    keep_source_rows: bool = True, required=INT_KEYS) -> pd.DataFrame:
    """Check and coerce the bookkeeping and channel columns, sort by unit, cycle, t, reset the
    index; :data:`SOURCE_ROW` is dropped after the checks unless ``keep_source_rows``.
    ``required``: the integer keys the table must have (a series without cycles: ``unit``
    alone)."""
    if not isinstance(df, pd.DataFrame):
        raise InputError(f"{source}: expected a pandas DataFrame, got {type(df).__name__}")
    check_unique(list(df.columns), source)
    check_columns(list(df.columns), required, what=source)
    df = as_int_keys(as_numeric(df, source), source)
    keys = sort_keys(df)
    if not is_sorted(df, keys):
        df = df.sort_values(keys, kind="stable")
    df = df.reset_index(drop=True)
    if not keep_source_rows and SOURCE_ROW in df.columns:
        df = df.drop(columns=SOURCE_ROW)
    if unit_first and df.columns[0] != "unit":
        df = df[["unit", *[c for c in df.columns if c != "unit"]]]
    return df


def prepare_for_write(df: pd.DataFrame, source: str) -> pd.DataFrame:
    """A table a writer may store: the required columns present, no column named
    :data:`SOURCE_ROW` (reserved for the readers), at least one row, normalised
    (:func:`normalise_table`)."""
    if not isinstance(df, pd.DataFrame):
        raise InputError(f"{source}: expected a pandas DataFrame, got {type(df).__name__}")
    if SOURCE_ROW in df.columns:
        raise InputError(f"{source}: column {SOURCE_ROW} is reserved (the readers add it for"
                         " the rows of error messages); rename or drop it before writing")
    check_columns(list(df.columns), REQUIRED_COLUMNS, what=source)
    if len(df) == 0:
        raise InputError(f"{source}: the table has no rows")
    return normalise_table(df, source)


def selected_columns(names: Sequence[str], columns: Sequence[str] | None,
                     source: str) -> list[str]:
    """The columns to return: ``unit``, ``cycle``, ``t`` (when present), then ``columns``."""
    if columns is None:
        return list(names)
    missing = [c for c in columns if c not in names]
    if missing:
        raise InputError(f"{source}: no column(s) {', '.join(missing)} in the file"
                         f" (has {', '.join(names)})")
    keys = [k for k in SORT_KEYS if k in names]
    return keys + [c for c in columns if c not in keys]


def check_units_found(found: np.ndarray, units: Sequence[int], source: str) -> None:
    """InputError naming the requested ``units`` that are not among ``found``."""
    missing = sorted(set(int(u) for u in units) - set(found.tolist()))
    if missing:
        raise InputError(f"{source}: unit(s) {', '.join(map(str, missing))} not in the file")


def check_split(split: str, source: object) -> None:
    """``split`` is ``"dev"``, ``"test"`` or ``"both"``."""
    if split not in ("both", *SPLITS):
        raise InputError(f"{source}: split must be 'dev', 'test' or 'both', got {split!r}")


def assign_splits(units: np.ndarray, meta: Mapping[str, Any],
                  source: str) -> tuple[list[int], list[int]]:
    """(dev units, test units) of the ``units`` present in a table being written, from the
    metadata's ``dev_units`` / ``test_units`` (both writers, and per unit for the streaming
    ones). All units are dev when neither list is given; a unit missing from the one list
    given is in the other. Refused (InputError): a unit in both lists, a present unit in
    neither. A listed unit the table lacks is left out of the result (a writer stores the
    lists of what it wrote)."""
    present = sorted(int(u) for u in np.unique(units))
    dev_meta, test_meta = meta.get("dev_units"), meta.get("test_units")
    if dev_meta is None and test_meta is None:
        return present, []
    dev_set = {int(u) for u in dev_meta or []}
    test_set = {int(u) for u in test_meta or []}
    both = dev_set & test_set
    if both:
        raise InputError(f"{source}: unit(s) {', '.join(map(str, sorted(both)))} are in both"
                         " dev_units and test_units")
    if dev_meta is None:
        dev_set = set(present) - test_set
    if test_meta is None:
        test_set = set(present) - dev_set
    stray = [u for u in present if u not in dev_set | test_set]
    if stray:
        raise InputError(f"{source}: unit(s) {', '.join(map(str, stray))} are in neither"
                         " dev_units nor test_units of the metadata")
    return [u for u in present if u in dev_set], [u for u in present if u in test_set]
