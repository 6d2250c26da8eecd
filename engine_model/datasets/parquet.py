"""hyprog parquet, the native dataset format: one table, partitioned by unit.

Parquet (the native format)
---------------------------
A directory, hive-partitioned by unit: ``<path>/unit=<n>/part-0.parquet``; the part files do
not hold ``unit`` (the directory name does). Each part file carries the metadata
(:mod:`.metadata`) as JSON in its Arrow schema metadata under the key ``hyprog``; there is no
sidecar. Columns keep the order they were written in, with ``unit`` first. Part files are
zstd-compressed. :func:`read_parquet` also reads a single parquet file (``unit`` from a column,
or from a ``unit=<n>`` parent directory) and a directory of parquet files holding ``unit``
(pandas' ``to_parquet``; an index it stored is read as the column(s) the file holds). Files
and directories whose name starts with ``.`` or ``_`` are not read (a writer's temporaries,
see :mod:`engine_model.runtime.atomic`); any other parquet file outside the layout (a copy in
a sub-folder) is an error naming it, not read.

Writers: :func:`write_parquet` (a whole table), :func:`parquet_unit_writer` (a stream of
units, the directory appears when the last is written) and :func:`write_unit_part` (one unit
added to an existing directory, for resumable writers; :func:`written_units` lists what is
complete). An existing output is replaced only when hyprog wrote it, or with
``overwrite=True`` (:mod:`engine_model.runtime.ownership`).

Rows of the user's file: ``read_parquet(..., source_rows=True)`` adds the column
:data:`~.schema.SOURCE_ROW`, the 1-based row each sample has in the file it was read from (in
a directory partitioned by unit, the row of that unit's part file), so that an error can name
the row the user sees, whatever the sorting did.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.dataset as pds
import pyarrow.parquet as pq

from engine_model.runtime.atomic import atomic_output

from ..validation import InputError, check_columns
from .metadata import META_KEY, metadata_for_write, metadata_json, parse_metadata
from .paths import PARQUET_MAGIC, PARQUET_PART, existing_path, file_magic
from .provenance import PARQUET_DATASET, PARQUET_FEATURES, UNIT_PARTITION
from .schema import (
    REQUIRED_COLUMNS,
    SOURCE_ROW,
    assign_splits,
    canonical_columns,
    check_units_found,
    normalise_table,
    prepare_for_write,
    selected_columns,
)

PARQUET_COMPRESSION = "zstd"


# ---------------------------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------------------------

def _unit_slices(units: np.ndarray) -> Iterator[tuple[int, slice]]:
    """(unit, row slice) for each run of equal values of a sorted ``units`` array."""
    edges = np.flatnonzero(np.diff(units)) + 1
    starts = np.concatenate(([0], edges))
    stops = np.concatenate((edges, [len(units)]))
    for a, b in zip(starts, stops, strict=True):
        yield int(units[a]), slice(int(a), int(b))


def _write_part(part: pd.DataFrame, file: Path, meta_json: bytes) -> None:
    """One unit's rows (without ``unit``) to one parquet file, metadata in the schema."""
    table = _arrow_table(part)
    # replace (not extend) the schema metadata: the pandas block holds library versions
    table = table.replace_schema_metadata({META_KEY.encode(): meta_json})
    file.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, file, compression=PARQUET_COMPRESSION)


def _arrow_table(df: pd.DataFrame) -> pa.Table:
    """``df`` as an Arrow table without its index. Columns of plain numpy numbers or booleans
    (a feature table, a simulated fleet) are handed over directly: the same Arrow types as
    ``Table.from_pandas`` gives them, at a fraction of its per-column cost (about half the
    time of writing one short unit); anything else goes through ``from_pandas``."""
    names = list(df.columns)
    if all(isinstance(c, str) for c in names) and len(set(names)) == len(names) and all(
            isinstance(t, np.dtype) and t.kind in "biuf" for t in df.dtypes):
        return pa.Table.from_arrays([pa.array(df[c].to_numpy()) for c in names], names=names)
    return pa.Table.from_pandas(df, preserve_index=False)


def write_parquet(df: pd.DataFrame, path: str | os.PathLike,
                  metadata: Mapping[str, Any] | None = None, overwrite: bool = False,
                  inputs: Sequence[str | os.PathLike | None] = ()) -> Path:
    """Write ``df`` as a parquet directory partitioned by unit (``unit=<n>/part-0.parquet``).

    Rows are sorted by unit, cycle, t; ``metadata`` is stored as JSON under the schema metadata
    key ``hyprog`` of every part file. Its ``dev_units`` / ``test_units``, when either is
    given, are checked as the h5 writer's (:func:`~.schema.assign_splits`: a unit in both or
    a unit of the table in neither is refused) and stored as the table's units of each. The
    directory appears only when complete (see :mod:`engine_model.runtime.atomic`); an existing
    ``path`` is replaced only when hyprog wrote it or with ``overwrite``, never when it is one
    of the command's ``inputs`` (:mod:`engine_model.runtime.ownership`). Returns the path
    written.
    """
    path = Path(path)
    source = str(path)
    table = prepare_for_write(df, source)
    meta = metadata_for_write(metadata, source)
    units = table["unit"].to_numpy()
    if meta.get("dev_units") is not None or meta.get("test_units") is not None:
        dev, test = assign_splits(units, meta, source)
        meta.update(dev_units=dev, test_units=test)
    meta_json = metadata_json(meta, source).encode()
    body = table.drop(columns="unit")
    kind = PARQUET_FEATURES if "calibration" in (metadata or {}) else PARQUET_DATASET
    with atomic_output(path, kind, overwrite, inputs) as tmp:
        for unit, rows in _unit_slices(units):
            _write_part(body.iloc[rows], tmp / f"unit={unit}" / PARQUET_PART, meta_json)
    return path


@contextmanager
def parquet_unit_writer(path: str | os.PathLike, metadata: Mapping[str, Any] | None = None,
                        overwrite: bool = False) -> Iterator[Callable[[pd.DataFrame], None]]:
    """Stream a fleet to a parquet directory one unit at a time (the same layout as
    :func:`write_parquet`), so a large fleet never has to be in memory at once::

        with parquet_unit_writer(path, meta) as write_unit:
            for df_unit in units:
                write_unit(df_unit)

    The directory appears only when the block completes; on any error nothing is left.
    ``metadata`` is fixed when the writer opens (it goes into every part file); each unit
    written is checked against its ``dev_units`` / ``test_units`` (:func:`~.schema.assign_splits`).
    An existing ``path`` is checked when the writer opens (:mod:`engine_model.runtime.ownership`).
    """
    path = Path(path)
    source = str(path)
    meta = metadata_for_write(metadata, source)
    meta_json = metadata_json(meta, source).encode()
    written: set[int] = set()
    with atomic_output(path, PARQUET_DATASET, overwrite) as tmp:
        def write_unit(df: pd.DataFrame) -> None:
            table = prepare_for_write(df, source)
            units = table["unit"].to_numpy()
            body = table.drop(columns="unit")
            for unit, rows in _unit_slices(units):
                if unit in written:
                    raise InputError(f"{source}: unit {unit} written twice")
                assign_splits(np.array([unit]), meta, source)
                written.add(unit)
                _write_part(body.iloc[rows], tmp / f"unit={unit}" / PARQUET_PART, meta_json)

        yield write_unit


def written_units(path: str | os.PathLike) -> list[int]:
    """Units whose partition ``<path>/unit=<n>/part-0.parquet`` is complete (a resumable
    writer's progress; see :func:`write_unit_part`). Empty when ``path`` does not exist."""
    p = Path(path)
    if not p.is_dir():
        return []
    out = []
    for d in p.iterdir():
        if d.is_dir() and d.name.startswith("unit=") and (d / PARQUET_PART).is_file():
            try:
                out.append(int(d.name.split("=", 1)[1]))
            except ValueError:
                continue
    return sorted(out)


def write_unit_part(df: pd.DataFrame, path: str | os.PathLike,
                    metadata: Mapping[str, Any] | None = None) -> Path:
    """Add one unit's rows to the parquet dataset directory ``path`` (created if needed), in
    the layout of :func:`write_parquet`, atomically: the part file is written under a hidden
    temporary name (which readers ignore) and renamed into place when complete, so an
    interrupted writer leaves every unit either complete or absent: the partition directory
    ``unit=<n>`` is built as a hidden temporary directory and renamed into place, so there is
    never an empty ``unit=<n>/`` (:func:`engine_model.runtime.atomic.atomic_output`, kind
    :data:`.provenance.UNIT_PARTITION`). An existing partition of the same unit is replaced
    when it holds nothing but its part file. The unit is checked against the metadata's
    ``dev_units`` / ``test_units`` (:func:`~.schema.assign_splits`). Returns the part file."""
    path = Path(path)
    source = str(path)
    table = prepare_for_write(df, source)
    units = table["unit"].unique()
    if len(units) != 1:
        raise InputError(f"{source}: write_unit_part takes one unit, got {len(units)}")
    meta = metadata_for_write(metadata, source)
    assign_splits(units, meta, source)
    meta_json = metadata_json(meta, source).encode()
    unit_dir = path / f"unit={int(units[0])}"
    with atomic_output(unit_dir, UNIT_PARTITION) as tmp:
        _write_part(table.drop(columns="unit"), tmp / PARQUET_PART, meta_json)
    return unit_dir / PARQUET_PART


# ---------------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------------

def _hidden(name: str) -> bool:
    return name.startswith((".", "_"))


def _is_hive_by_unit(path: Path) -> bool:
    return any(p.is_dir() and p.name.startswith("unit=") for p in path.iterdir())


def _parquet_files(path: Path) -> list[Path]:
    """The parquet files of a dataset directory, in one of its two layouts: ``unit=<n>/
    *.parquet`` (the writers', or pandas' ``partition_cols=["unit"]``) or ``*.parquet``
    directly in it (``unit`` a column). Names starting with ``.`` or ``_`` are skipped. A
    parquet file anywhere else (a copy in a sub-folder, which would add its rows again) or a
    directory mixing the two layouts is an InputError naming the file."""
    if _is_hive_by_unit(path):
        files = sorted(f for d in path.iterdir() if d.is_dir() and d.name.startswith("unit=")
                       for f in d.iterdir() if f.suffix == ".parquet" and not _hidden(f.name))
    else:
        files = sorted(f for f in path.iterdir() if f.suffix == ".parquet"
                       and not _hidden(f.name))
    layout = "unit=<n>/*.parquet" if _is_hive_by_unit(path) else "*.parquet in it"
    keep = set(files)
    for f in sorted(path.rglob("*.parquet")):
        if f not in keep and not any(_hidden(part) for part in f.relative_to(path).parts):
            raise InputError(f"{f}: a parquet file outside the dataset's layout ({layout}) of"
                             f" {path}; move it out of the dataset directory")
    if not files:
        raise InputError(f"{path}: no parquet files in this directory")
    return files


def _unit_from_dir(file: Path) -> int | None:
    name = file.parent.name
    if name.startswith("unit="):
        try:
            return int(name.split("=", 1)[1])
        except ValueError:
            return None
    return None


def _arrow_error(path: Path, exc: Exception) -> InputError:
    first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return InputError(f"{path}: not a readable parquet dataset ({first})")


def _numeric(t: pa.DataType) -> bool:
    return pa.types.is_integer(t) or pa.types.is_floating(t) or pa.types.is_boolean(t)


def _not_a_number(file: Path, column: str) -> InputError | None:
    """InputError naming the first row of ``file``'s text ``column`` that is not a number;
    None when every value reads as one (pyarrow casts them)."""
    values = pq.read_table(file, columns=[column]).column(column).to_pandas()
    bad = pd.to_numeric(values, errors="coerce").isna() & values.notna()
    if not bad.any():
        return None
    return InputError(f"{file}: column {column}, row {int(bad.to_numpy().argmax()) + 1}: "
                      f"{values[bad].iloc[0]!r} is not a number")


def _check_same_columns(files: list[Path]) -> None:
    """Every part file of a directory has the first one's columns (a dataset read across
    them would otherwise take the first file's: a column one unit lacks would vanish from
    every unit, or come back as NaN for that unit, without a word), numeric where the first
    file's are (a column one unit stores as text, with a value that is not a number, failed
    in pyarrow's cast naming neither file nor row: the error names both)."""
    schema = pq.read_schema(files[0])
    first = set(schema.names)
    for f in files[1:]:
        other = pq.read_schema(f)
        names = set(other.names)
        if names != first:
            diff = sorted(first ^ names)
            raise InputError(f"{f}: its columns differ from {files[0].parent.name}'s (column(s) "
                             f"{', '.join(diff)} in one of them only)")
        for c in other.names:
            a, b = schema.field(c).type, other.field(c).type
            if _numeric(a) != _numeric(b):
                error = _not_a_number(f if _numeric(a) else files[0], c)
                if error is not None:
                    raise error


def _open_parquet(path: Path) -> tuple[pds.Dataset, int | None]:
    """A pyarrow dataset over ``path`` and, for a lone part file, the unit of its directory."""
    try:
        if path.is_dir():  # only the files of its layout (:func:`_parquet_files`)
            files = _parquet_files(path)
            _check_same_columns(files)
            partitioning = None
            if _is_hive_by_unit(path):
                partitioning = pds.partitioning(pa.schema([("unit", pa.int64())]), flavor="hive")
            return pds.dataset([str(f) for f in files], format="parquet",
                               partitioning=partitioning, partition_base_dir=str(path)), None
        dataset = pds.dataset(path, format="parquet")
        unit = None if "unit" in dataset.schema.names else _unit_from_dir(path)
        return dataset, unit
    except (pa.ArrowException, OSError) as exc:
        raise _arrow_error(path, exc) from None


def _first_parquet_file(path: Path) -> Path:
    return _parquet_files(path)[0] if path.is_dir() else path


def read_parquet_metadata(path: Path) -> dict[str, Any]:
    """The metadata of a parquet dataset directory or file (from its first part file)."""
    file = _first_parquet_file(path)
    try:
        schema_meta = pq.read_schema(file).metadata or {}
    except (pa.ArrowException, OSError) as exc:
        raise _arrow_error(file, exc) from None
    return parse_metadata(schema_meta.get(META_KEY.encode()), str(file))


def read_parquet_columns(path: Path) -> list[str]:
    """The column names of a parquet dataset (``unit`` included) in the schema order."""
    file = _first_parquet_file(path)
    try:
        cols = list(pq.read_schema(file).names)
    except (pa.ArrowException, OSError) as exc:
        raise _arrow_error(file, exc) from None
    return canonical_columns(["unit", *[c for c in cols if c != "unit"]])


def _check_no_empty_units(path: Path, df: pd.DataFrame, units: Sequence[int] | None) -> None:
    """InputError naming a ``unit=<n>`` partition that holds no rows (a unit of zero samples
    would otherwise vanish without a word)."""
    if not path.is_dir():
        return
    found = set(df["unit"].unique().tolist())
    wanted = None if units is None else {int(u) for u in units}
    for d in sorted(path.iterdir()):
        u = _unit_from_dir(d / PARQUET_PART)
        if u is None or not d.is_dir() or u in found or (wanted is not None and u not in wanted):
            continue
        if any(f.suffix == ".parquet" and not f.name.startswith((".", "_"))
               for f in d.iterdir()):
            raise InputError(f"{d}: unit {u} has no rows (an empty part file); delete the"
                             " partition or write the unit's samples")


def read_parquet(path: str | os.PathLike, units: Sequence[int] | None = None,
                 columns: Sequence[str] | None = None,
                 source_rows: bool = False) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Read a parquet dataset directory (or a single parquet file) -> ``(df, metadata)``.

    ``units`` reads only those units (partition pruning); ``columns`` loads only those columns
    besides ``unit``, ``cycle``, ``t``, which always come back. ``unit`` is int64, rows are
    sorted by unit, cycle, t. ``source_rows`` adds :data:`~.schema.SOURCE_ROW` (module doc).
    A ``unit=<n>`` partition without rows is an error.
    """
    p = existing_path(path)
    source = str(p)
    if p.is_file() and file_magic(p)[:4] != PARQUET_MAGIC:
        raise InputError(f"{source}: not a parquet file")
    dataset, dir_unit = _open_parquet(p)
    names = list(dataset.schema.names) + (["unit"] if dir_unit is not None else [])
    check_columns(names, REQUIRED_COLUMNS, what=source)
    wanted = selected_columns(names, columns, source)
    file_columns = [c for c in wanted if c in dataset.schema.names]
    flt = None
    by_unit = p.is_dir() and _is_hive_by_unit(p)
    in_file_order = not by_unit  # a file's row numbers need it read unfiltered
    if units is not None and by_unit:
        flt = pds.field("unit").isin([int(u) for u in units])
    try:  # the columns the files hold: pandas' index metadata is not applied
        df = dataset.to_table(columns=file_columns, filter=flt).to_pandas(ignore_metadata=True)
        sizes = [] if by_unit else [f.count_rows() for f in dataset.get_fragments()]
    except (pa.ArrowException, OSError) as exc:
        raise _arrow_error(p, exc) from None
    if by_unit:  # the row of the unit's part file
        rows = df.groupby("unit", sort=False).cumcount().to_numpy() + 1
    else:  # the row of its file (the files are read in order)
        rows = np.concatenate([np.arange(1, n + 1) for n in sizes] or [np.zeros(0, int)])
    df[SOURCE_ROW] = rows.astype(np.int64)
    wanted = [*wanted, SOURCE_ROW]
    if in_file_order and units is not None and dir_unit is None:
        df = df[df["unit"].isin([int(u) for u in units])]
    if dir_unit is not None:
        df.insert(0, "unit", np.full(len(df), dir_unit, dtype=np.int64))
        if units is not None and dir_unit not in set(int(u) for u in units):
            df = df.iloc[:0]
    if units is not None:
        check_units_found(df["unit"].unique(), units, source)
    _check_no_empty_units(p, df, units)
    df = normalise_table(df[wanted], source, keep_source_rows=source_rows)
    return df, read_parquet_metadata(p)
