"""The N-CMAPSS h5 layout (the published files, e.g. ``N-CMAPSS_DS02-006.h5``): read and write.

N-CMAPSS h5
-----------
Per split ``s`` in ``dev``/``test``: ``W_s`` (n, 4) ``alt Mach TRA T2``; ``X_s_s`` (n, k) the
present ``channels.NCMAPSS_XS``; ``X_v_s`` (n, k) the present ``channels.NCMAPSS_XV``
(includes ``T40``, ``P30``, ``phi``); ``T_s`` (n, k) the present theta; ``Y_s`` (n, 1) RUL;
``A_s`` (n, k) ``unit cycle Fc hs``. The column names are in ``W_var X_s_var X_v_var T_var
A_var``, fixed-length byte strings; readers map columns by these names, never by position.
Floats are float64; A and Y are written as int64 and read whether int or float. A group none
of whose columns is present is not written (``W`` and ``A`` always are). The root attribute
``hyprog`` holds the metadata JSON (:mod:`.metadata`). ``t`` is not stored: it reads back as
the sample index within its (unit, cycle) divided by ``sample_rate_hz`` (1 Hz when the file
does not say, as for the published files). Columns outside these groups are not written (a
warning names them). Reading is chunked and only the rows of the requested units are read.
Writing is atomic (:mod:`engine_model.runtime.atomic`).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pandas as pd

from engine_model.runtime.atomic import atomic_output

from ..channels import NCMAPSS_XS, NCMAPSS_XV, THETA_NAMES, W_NAMES
from ..validation import InputError, check_columns
from .metadata import (
    META_KEY,
    SAMPLE_RATE_KEY,
    metadata_for_write,
    metadata_json,
    parse_metadata,
    sample_rate,
)
from .paths import HDF5_MAGIC, existing_path, file_magic
from .provenance import H5_DATASET
from .schema import (
    INT_KEYS,
    MAX_FLOAT_ID,
    REQUIRED_COLUMNS,
    SOURCE_ROW,
    SPLITS,
    as_int_keys,
    assign_splits,
    canonical_columns,
    check_split,
    check_units_found,
    normalise_table,
    prepare_for_write,
    selected_columns,
)

NCMAPSS_SOURCE = "ncmapss-h5"
DEFAULT_H5_RATE_HZ = 1.0  # the published N-CMAPSS files are sampled at 1 Hz

# h5 groups: (array prefix, name array or None, channel names in the published order)
H5_GROUPS = (
    ("W", "W_var", W_NAMES),
    ("X_s", "X_s_var", NCMAPSS_XS),
    ("X_v", "X_v_var", NCMAPSS_XV),
    ("T", "T_var", THETA_NAMES),
    ("Y", None, ("RUL",)),
    ("A", "A_var", ("unit", "cycle", "Fc", "hs")),
)
H5_REQUIRED = ("W", "A")
H5_INT_GROUPS = ("A", "Y")
H5_CHUNK_ROWS = 1 << 18


# ---------------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------------

@contextmanager
def _open_h5(path: Path) -> Iterator[h5py.File]:
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputError(f"{path}: not an HDF5 file ({str(exc).splitlines()[0]})") from None
    try:
        yield f
    finally:
        f.close()


def _h5_metadata(f: h5py.File, path: Path) -> dict[str, Any]:
    raw = f.attrs.get(META_KEY)
    if isinstance(raw, np.ndarray):
        if raw.size != 1:
            raise InputError(f"{path}: the '{META_KEY}' attribute is an array of shape"
                             f" {raw.shape}, expected one JSON string")
        raw = raw.item()
    if isinstance(raw, bytes):
        raw = raw.decode()
    return parse_metadata(raw, str(path))


def _decode_names(arr: np.ndarray) -> list[str]:
    out = []
    for v in np.ravel(arr):
        s = v.decode("utf-8", errors="replace") if isinstance(v, bytes) else str(v)
        out.append(s.strip().strip("\x00").strip())
    return out


def _h5_names(f: h5py.File, group: str, var: str | None, fixed: tuple[str, ...],
              path: Path) -> list[str]:
    if var is None:
        return list(fixed)
    if var not in f:
        raise InputError(f"{path}: dataset {var} (the column names of {group}_*) is missing")
    return _decode_names(f[var][()])


def _h5_split_groups(f: h5py.File, split: str, path: Path) -> dict[str, tuple[h5py.Dataset,
                                                                             list[str]]]:
    """{group: (dataset, column names)} for one split, with shapes checked."""
    groups = {}
    for group, var, fixed in H5_GROUPS:
        name = f"{group}_{split}"
        if name not in f:
            if group in H5_REQUIRED:
                raise InputError(f"{path}: dataset {name} is missing")
            continue
        ds = f[name]
        if not isinstance(ds, h5py.Dataset):
            raise InputError(f"{path}: {name} is not a dataset")
        names = _h5_names(f, group, var, fixed, path)
        width = 1 if ds.ndim == 1 else (ds.shape[1] if ds.ndim == 2 else -1)
        if width != len(names):
            label = var or "RUL"
            raise InputError(f"{path}: dataset {name} has shape {ds.shape} but {label} names"
                             f" {len(names)} column(s)")
        groups[group] = (ds, names)
    rows = {f"{g}_{split}": ds.shape[0] for g, (ds, _) in groups.items()}
    if len(set(rows.values())) > 1:
        counts = ", ".join(f"{k} {v}" for k, v in rows.items())
        raise InputError(f"{path}: row counts differ between the {split} arrays ({counts})")
    seen: dict[str, str] = {}
    for group, (_, names) in groups.items():
        for n in names:
            if n in seen:
                raise InputError(f"{path}: column {n} appears in both {seen[n]} and {group}"
                                 f"_{split}")
            seen[n] = f"{group}_{split}"
    return groups


def _read_column(ds: h5py.Dataset, j: int) -> np.ndarray:
    """Column ``j`` of a 2-D dataset as float64, read in row chunks."""
    n = ds.shape[0]
    out = np.empty(n, dtype=np.float64)
    for a in range(0, n, H5_CHUNK_ROWS):
        b = min(n, a + H5_CHUNK_ROWS)
        out[a:b] = ds[a:b, j]
    return out


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True in ``mask``."""
    d = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(),
                    strict=True))


def _read_rows(ds: h5py.Dataset, runs: Sequence[tuple[int, int]], n_rows: int) -> np.ndarray:
    """The rows of ``runs`` of ``ds`` as one float64 array, copied chunk by chunk into place."""
    shape = (n_rows,) + ds.shape[1:]
    out = np.empty(shape, dtype=np.float64)
    if out.size == 0:
        return out
    pos = 0
    for start, stop in runs:
        for a in range(start, stop, H5_CHUNK_ROWS):
            b = min(stop, a + H5_CHUNK_ROWS)
            ds.read_direct(out, np.s_[a:b], np.s_[pos:pos + b - a])
            pos += b - a
    return out


def _split_units(groups: Mapping[str, tuple[h5py.Dataset, list[str]]], split: str,
                 path: Path) -> np.ndarray:
    ds, names = groups["A"]
    if "unit" not in names:
        raise InputError(f"{path}: A_var has no 'unit' column (has {', '.join(names)})")
    units = _read_column(ds, names.index("unit"))
    bad = ~np.isfinite(units)
    if bad.any():
        raise InputError(f"{path}: A_{split}, column unit is NaN at row "
                         f"{int(np.flatnonzero(bad)[0]) + 1}")
    huge = np.abs(units) > MAX_FLOAT_ID
    if huge.any():
        i = int(np.flatnonzero(huge)[0])
        raise InputError(f"{path}: A_{split}, column unit = {units[i]:g} at row {i + 1} is"
                         " beyond 2**53 - 1 in magnitude (not an exact unit number)")
    return units


def _units_in(f: h5py.File, split: str, path: Path) -> list[int]:
    """The units of one split, from its A array only."""
    a = {"A": (f[f"A_{split}"], _h5_names(f, "A", "A_var", (), path))}
    return sorted(int(u) for u in np.unique(_split_units(a, split, path)))


def _read_split(f: h5py.File, split: str, path: Path, units: Sequence[int] | None,
                columns: set[str] | None) -> tuple[pd.DataFrame, list[int]]:
    """One split as a DataFrame (file order, no t yet) and all of the split's units."""
    groups = _h5_split_groups(f, split, path)
    if columns is not None:
        names = [n for _, group_names in groups.values() for n in group_names]
        selected_columns([*names, "t"], sorted(columns), str(path))  # unknown -> InputError
    unit_col = _split_units(groups, split, path)
    all_units = sorted(int(u) for u in np.unique(unit_col))
    mask = np.ones(len(unit_col), bool) if units is None else np.isin(unit_col, list(units))
    runs, n_rows = _runs(mask), int(mask.sum())
    data: dict[str, np.ndarray] = {SOURCE_ROW: np.flatnonzero(mask).astype(np.int64) + 1}
    del unit_col, mask
    for ds, names in groups.values():
        keep = [n for n in names if columns is None or n in columns or n in ("unit", "cycle")]
        if not keep:
            continue
        block = _read_rows(ds, runs, n_rows).reshape(n_rows, len(names))
        for n in keep:
            data[n] = block[:, names.index(n)]
    return pd.DataFrame(data, copy=False), all_units


def _add_time(df: pd.DataFrame, rate_hz: float) -> pd.DataFrame:
    """``t`` = sample index within (unit, cycle), in file order, divided by the sample rate."""
    index = df.groupby(["unit", "cycle"], sort=False).cumcount().to_numpy()
    return df.assign(t=index / rate_hz)


def read_h5_metadata(path: Path) -> dict[str, Any]:
    """The ``hyprog`` root attribute of an h5 file as a dict (``{}`` when absent)."""
    with _open_h5(path) as f:
        return _h5_metadata(f, path)


def read_h5_columns(path: Path) -> list[str]:
    """The column names stored in an h5 file (both splits; ``t`` included, as it reads back)
    in the schema order."""
    with _open_h5(path) as f:
        names: list[str] = []
        for split in SPLITS:
            if f"A_{split}" in f:
                for _, cols in _h5_split_groups(f, split, path).values():
                    names += [c for c in cols if c not in names]
        return canonical_columns(["t", *names])


def read_ncmapss_h5(path: str | os.PathLike, split: str = "both",
                    units: Sequence[int] | None = None,
                    columns: Sequence[str] | None = None,
                    source_rows: bool = False) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Read an N-CMAPSS h5 file (published layout, or one written by :func:`write_ncmapss_h5`).

    ``split`` is ``"dev"``, ``"test"`` or ``"both"`` (a split absent from the file is skipped
    for ``"both"``); ``units`` reads only those units' rows. Returns ``(df, metadata)``:
    metadata is the file's ``hyprog`` attribute (if any) with ``dev_units`` / ``test_units``
    (every unit of each split in the file), ``sample_rate_hz`` (1 Hz unless the file says) and
    ``source_format = "ncmapss-h5"``. ``t`` is rebuilt from the sample index (module doc).
    Refused: a unit beyond 2**53 - 1 in magnitude, a ``hyprog`` attribute that is not one JSON
    object of the right types (a ``sample_rate_hz`` that is not a finite number > 0).
    ``source_rows`` adds :data:`~.schema.SOURCE_ROW`, the 1-based row of each sample in its
    split's arrays (``W_dev`` ...).
    """
    check_split(split, path)
    p = existing_path(path)
    source = str(p)
    if p.is_dir() or not file_magic(p).startswith(HDF5_MAGIC):
        raise InputError(f"{source}: not an HDF5 file")
    wanted = None if columns is None else set(columns)
    frames, split_units = [], {}
    with _open_h5(p) as f:
        meta = _h5_metadata(f, p)
        present = [s for s in SPLITS if any(f"{g}_{s}" in f for g, _, _ in H5_GROUPS)]
        if split != "both":
            present = [split]
        if not present:
            raise InputError(f"{source}: dataset A_dev / A_test is missing (no dev or test"
                             " arrays in the file)")
        for s in SPLITS:
            if s in present:
                frame, split_units[s] = _read_split(f, s, p, units, wanted)
                frames.append(frame)
            elif f"A_{s}" in f:  # not read, but listed: the metadata describes the file
                split_units[s] = _units_in(f, s, p)
    both = set(split_units.get("dev", [])) & set(split_units.get("test", []))
    if both:
        raise InputError(f"{source}: unit(s) {', '.join(map(str, sorted(both)))} appear in both"
                         " the dev and the test arrays")
    df = pd.concat(frames, ignore_index=True) if len(frames) > 1 else frames[0]
    check_columns(list(df.columns), REQUIRED_COLUMNS if columns is None else INT_KEYS,
                  what=source)
    if units is not None:
        check_units_found(df["unit"].unique(), units, source)
    df = as_int_keys(df, source)
    rate = sample_rate(meta, DEFAULT_H5_RATE_HZ)
    if "t" not in df.columns:
        df = _add_time(df, rate)
    order = canonical_columns(c for c in df.columns if c != SOURCE_ROW)
    if columns is not None:
        order = selected_columns(order, columns, source)  # the keys, then the requested ones
    df = normalise_table(df[[*order, SOURCE_ROW]], source, keep_source_rows=source_rows)
    meta.update(dev_units=split_units.get("dev", []), test_units=split_units.get("test", []),
                source_format=NCMAPSS_SOURCE)
    meta[SAMPLE_RATE_KEY] = rate
    return df, meta


# ---------------------------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------------------------

def _h5_layout(columns: Sequence[str]) -> dict[str, list[str]]:
    """{group: present column names in the published order}; groups with none are left out."""
    layout = {}
    for group, _, names in H5_GROUPS:
        present = [n for n in names if n in columns]
        if present or group in H5_REQUIRED:
            layout[group] = present
    return layout


def _warn_dropped(columns: Sequence[str], layout: Mapping[str, list[str]], source: str) -> None:
    stored = {n for names in layout.values() for n in names} | {"t"}
    dropped = [c for c in columns if c not in stored]
    if dropped:
        warnings.warn(f"{source}: column(s) {', '.join(dropped)} have no place in the N-CMAPSS"
                      " layout and are not written", UserWarning, stacklevel=3)


def _warn_if_t_lost(df: pd.DataFrame, rate_hz: float, source: str) -> None:
    if "t" not in df.columns:
        return
    rebuilt = df.groupby(["unit", "cycle"], sort=False).cumcount().to_numpy() / rate_hz
    if not np.allclose(df["t"].to_numpy(), rebuilt, rtol=1e-9, atol=1e-6):
        warnings.warn(f"{source}: column t is not sample index / {rate_hz:g} Hz; the N-CMAPSS"
                      " layout does not store t, so it will read back differently",
                      UserWarning, stacklevel=3)


def _h5_array(df: pd.DataFrame, group: str, names: Sequence[str]) -> np.ndarray:
    block = df[list(names)]
    if group in H5_INT_GROUPS and all(block[c].dtype == np.int64 for c in names):
        arr = block.to_numpy(dtype=np.int64)
    else:
        arr = block.to_numpy(dtype=np.float64, na_value=np.nan)
    return arr.reshape(len(df), len(names))


def _create(f: h5py.File, name: str, data: np.ndarray, compression: str | None) -> None:
    opts: dict[str, Any] = {}
    if compression and data.size:
        opts = {"compression": compression,
                "chunks": (min(len(data), H5_CHUNK_ROWS // 4), data.shape[1])}
    f.create_dataset(name, data=data, **opts)


def write_ncmapss_h5(df: pd.DataFrame, path: str | os.PathLike,
                     metadata: Mapping[str, Any] | None = None,
                     compression: str | None = "gzip", overwrite: bool = False,
                     inputs: Sequence[str | os.PathLike | None] = ()) -> Path:
    """Write ``df`` in the N-CMAPSS h5 layout (module doc); atomic (temp file + os.replace).

    ``metadata['dev_units']`` / ``['test_units']`` choose the split (a unit in neither is an
    error when either is given, and so is a unit in both; all units are dev when neither is;
    :func:`~.schema.assign_splits`). ``unit`` / ``cycle`` beyond 2**53 - 1 in magnitude are
    refused (they would not read back exactly); so is a ``sample_rate_hz`` that is not a
    finite number > 0 (:func:`~.metadata.check_metadata`). ``compression`` is an h5py
    filter name (``"gzip"``, ``"lzf"``) or None. An existing ``path`` is replaced only when
    hyprog wrote it or with ``overwrite`` (:mod:`engine_model.runtime.ownership`). Returns the
    path written.
    """
    path = Path(path)
    source = str(path)
    table = prepare_for_write(df, source)
    for key in INT_KEYS:  # the readers take A as float64 (MAX_FLOAT_ID)
        huge = np.abs(table[key].to_numpy()) > MAX_FLOAT_ID
        if huge.any():
            raise InputError(f"{source}: {key} {table[key].to_numpy()[huge][0]} is beyond 2**53 - 1"
                             " in magnitude; the h5 layout reads it back as a float, where it"
                             " is not exact (write parquet)")
    meta = metadata_for_write(metadata, source)
    dev, test = assign_splits(table["unit"].to_numpy(), meta, source)
    meta.update(dev_units=dev, test_units=test)
    layout = _h5_layout(list(table.columns))
    _warn_dropped(list(table.columns), layout, source)
    _warn_if_t_lost(table, sample_rate(meta, DEFAULT_H5_RATE_HZ), source)
    var_names = {g: v for g, v, _ in H5_GROUPS}
    with atomic_output(path, H5_DATASET, overwrite, inputs) as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs[META_KEY] = metadata_json(meta, source)
            for group, names in layout.items():
                if var_names[group] is not None:
                    f.create_dataset(var_names[group], data=np.array(names, dtype="S"))
            for split, split_units in (("dev", dev), ("test", test)):
                rows = table[table["unit"].isin(split_units)]
                for group, names in layout.items():
                    _create(f, f"{group}_{split}", _h5_array(rows, group, names), compression)
    return path
