"""Fleet data sets on disk: hyprog parquet and the N-CMAPSS h5 layout.

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

Metadata (a JSON-serialisable dict, unknown keys kept)
------------------------------------------------------
``preset`` (str), ``seed`` (int), ``effects`` (list of ``{"name": str, "params": dict}``),
``sample_rate_hz`` (float; ``sample_rate`` is accepted when reading), ``hyprog_version``
(filled in on write when absent), ``dev_units`` / ``test_units`` (lists of int), and
``source_format`` (``"ncmapss-h5"``, set by :func:`read_ncmapss_h5`). Nothing time-dependent is
added, so the same table and metadata give the same bytes.

Parquet (the native format)
---------------------------
A directory, hive-partitioned by unit: ``<path>/unit=<n>/part-0.parquet``; the part files do
not hold ``unit`` (the directory name does). Each part file carries the metadata as JSON in its
Arrow schema metadata under the key ``hyprog``; there is no sidecar. Columns keep the order they
were written in, with ``unit`` first. :func:`read_parquet` also reads a single parquet file
(``unit`` from a column, or from a ``unit=<n>`` parent directory).

N-CMAPSS h5 (the published files' layout, e.g. ``N-CMAPSS_DS02-006.h5``)
-------------------------------------------------------------------------
Per split ``s`` in ``dev``/``test``: ``W_s`` (n, 4) ``alt Mach TRA T2``; ``X_s_s`` (n, k) the
present ``channels.NCMAPSS_XS``; ``X_v_s`` (n, k) the present ``channels.NCMAPSS_XV``
(includes ``T40``, ``P30``, ``phi``); ``T_s`` (n, k) the present theta; ``Y_s`` (n, 1) RUL;
``A_s`` (n, k) ``unit cycle Fc hs``. The column names are in ``W_var X_s_var X_v_var T_var
A_var``, fixed-length byte strings; readers map columns by these names, never by position.
Floats are float64; A and Y are written as int64 and read whether int or float. A group none
of whose columns is present is not written (``W`` and ``A`` always are). The root attribute
``hyprog`` holds the metadata JSON. ``t`` is not stored: it reads back as the sample index
within its (unit, cycle) divided by ``sample_rate_hz`` (1 Hz when the file does not say, as
for the published files). Columns outside these groups are not written (a warning names them).
Reading is chunked and only the rows of the requested units are read.

Atomicity
---------
Writers build the output in a temporary sibling (``.<name>.tmp-*``) and move it into place
with ``os.replace`` only after everything was written; an existing target is replaced then,
and on any exception the temporary is removed and the target is left as it was.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import uuid
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.dataset as pds
import pyarrow.parquet as pq

from .channels import NCMAPSS_XS, NCMAPSS_XV, THETA_NAMES, W_NAMES, XS_NAMES, XV_NAMES
from .validation import InputError, check_columns

__all__ = [
    "BOOKKEEPING", "REQUIRED_COLUMNS", "META_KEY", "SAMPLE_RATE_KEY", "NCMAPSS_SOURCE",
    "write_parquet", "read_parquet", "read_metadata", "write_ncmapss_h5", "read_ncmapss_h5",
    "read_dataset", "write_dataset", "summarize", "canonical_columns", "written_units",
    "write_unit_part", "remove_stale_temporaries",
]

BOOKKEEPING = ("unit", "cycle", "t", "Fc", "hs", "RUL")
REQUIRED_COLUMNS = ("unit", "cycle", *W_NAMES)
INT_KEYS = ("unit", "cycle")  # must be integers, never NaN
INT_OPTIONAL = ("Fc", "hs", "RUL")  # int64 when every value is an integer
META_KEY = "hyprog"  # parquet schema-metadata key and h5 root attribute
SAMPLE_RATE_KEY = "sample_rate_hz"
NCMAPSS_SOURCE = "ncmapss-h5"
DEFAULT_H5_RATE_HZ = 1.0  # the published N-CMAPSS files are sampled at 1 Hz

PARQUET_PART = "part-0.parquet"
PARQUET_COMPRESSION = "zstd"
H5_SUFFIXES = (".h5", ".hdf5", ".he5")
_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
_PARQUET_MAGIC = b"PAR1"

SPLITS = ("dev", "test")
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
_CANONICAL = (*BOOKKEEPING, *W_NAMES, *XS_NAMES, *XV_NAMES, "phi", *THETA_NAMES)


# ---------------------------------------------------------------------------------------------
# table checks shared by readers and writers
# ---------------------------------------------------------------------------------------------

def canonical_columns(columns: Iterable[str]) -> list[str]:
    """``columns`` in the schema order (bookkeeping, w, x_s, x_v, phi, theta), others after."""
    cols = list(columns)
    known = [c for c in _CANONICAL if c in cols]
    return known + [c for c in cols if c not in known]


def _check_unique(columns: Sequence[str], source: str) -> None:
    seen: set[str] = set()
    dup = sorted({c for c in columns if c in seen or seen.add(c)})
    if dup:
        raise InputError(f"{source}: duplicate column(s) {', '.join(dup)}")


def _as_int_keys(df: pd.DataFrame, source: str) -> pd.DataFrame:
    """``unit``/``cycle`` to int64 (NaN or fractions are errors); Fc/hs/RUL to int64 if exact."""
    out = {}
    for name in INT_KEYS:
        col = df[name]
        if col.dtype == np.int64:
            continue
        values = col.to_numpy(dtype=np.float64, na_value=np.nan)
        bad = ~np.isfinite(values)
        if bad.any():
            row = df.index[int(np.flatnonzero(bad)[0])]
            raise InputError(f"{source}: column {name} is NaN (or missing) at row {row}")
        frac = values != np.round(values)
        if frac.any():
            row = df.index[int(np.flatnonzero(frac)[0])]
            raise InputError(f"{source}: column {name} = {values[frac][0]:g} at row {row} is"
                             " not an integer")
        out[name] = values.astype(np.int64)
    for name in INT_OPTIONAL:
        if name in df.columns and df[name].dtype != np.int64:
            values = df[name].to_numpy(dtype=np.float64, na_value=np.nan)
            if np.isfinite(values).all() and (values == np.round(values)).all():
                out[name] = values.astype(np.int64)
    if "t" in df.columns and df["t"].dtype != np.float64:
        out["t"] = df["t"].to_numpy(dtype=np.float64, na_value=np.nan)
    return df.assign(**out) if out else df


def _sort_keys(df: pd.DataFrame) -> list[str]:
    return [c for c in ("unit", "cycle", "t") if c in df.columns]


def _is_sorted(df: pd.DataFrame, keys: Sequence[str]) -> bool:
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


def _normalise_table(df: pd.DataFrame, source: str, unit_first: bool = True) -> pd.DataFrame:
    """Check and coerce the bookkeeping columns, sort by unit, cycle, t, reset the index."""
    if not isinstance(df, pd.DataFrame):
        raise InputError(f"{source}: expected a pandas DataFrame, got {type(df).__name__}")
    _check_unique(list(df.columns), source)
    check_columns(list(df.columns), INT_KEYS, what=source)
    df = _as_int_keys(df, source)
    keys = _sort_keys(df)
    if not _is_sorted(df, keys):
        df = df.sort_values(keys, kind="stable")
    df = df.reset_index(drop=True)
    if unit_first and df.columns[0] != "unit":
        df = df[["unit", *[c for c in df.columns if c != "unit"]]]
    return df


def _prepare_for_write(df: pd.DataFrame, source: str) -> pd.DataFrame:
    if not isinstance(df, pd.DataFrame):
        raise InputError(f"{source}: expected a pandas DataFrame, got {type(df).__name__}")
    check_columns(list(df.columns), REQUIRED_COLUMNS, what=source)
    if len(df) == 0:
        raise InputError(f"{source}: the table has no rows")
    return _normalise_table(df, source)


# ---------------------------------------------------------------------------------------------
# metadata
# ---------------------------------------------------------------------------------------------

def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (set, frozenset)):
        return sorted(obj)
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")


def _metadata_json(metadata: Mapping[str, Any] | None, source: str) -> str:
    """Metadata as canonical JSON (sorted keys, no whitespace): the same dict, the same bytes."""
    try:
        return json.dumps(dict(metadata or {}), default=_json_default, sort_keys=True,
                          separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{source}: metadata is not JSON-serialisable ({exc})") from None


def _hyprog_version() -> str:
    try:
        from importlib.metadata import version

        return version("hyprog")
    except Exception:  # not installed (a source checkout on sys.path)
        return "unknown"


def _metadata_for_write(metadata: Mapping[str, Any] | None, source: str) -> dict[str, Any]:
    meta = json.loads(_metadata_json(metadata, source))
    if not isinstance(meta, dict):
        raise InputError(f"{source}: metadata must be a dict")
    meta.setdefault("hyprog_version", _hyprog_version())
    return meta


def _parse_metadata(raw: bytes | str | None, source: str) -> dict[str, Any]:
    if raw is None:
        return {}
    try:
        meta = json.loads(raw)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{source}: the '{META_KEY}' metadata is not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise InputError(f"{source}: the '{META_KEY}' metadata is not a JSON object")
    return meta


def _sample_rate(meta: Mapping[str, Any], default: float | None = None) -> float | None:
    for key in (SAMPLE_RATE_KEY, "sample_rate"):
        if meta.get(key) is not None:
            return float(meta[key])
    return default


# ---------------------------------------------------------------------------------------------
# atomic output
# ---------------------------------------------------------------------------------------------

def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def _default_mode(directory: bool) -> int:
    umask = os.umask(0)
    os.umask(umask)
    return (0o777 if directory else 0o666) & ~umask


def _swap_into_place(tmp: Path, target: Path) -> None:
    """Move ``tmp`` to ``target``; an existing target is moved aside first and removed after."""
    if not target.exists() and not target.is_symlink():
        os.replace(tmp, target)
        return
    if target.is_file() and tmp.is_file():
        os.replace(tmp, target)  # atomic replacement of a file
        return
    backup = target.with_name(f".{target.name}.old-{uuid.uuid4().hex[:8]}")
    os.replace(target, backup)
    try:
        os.replace(tmp, target)
    except BaseException:
        os.replace(backup, target)
        raise
    _remove(backup)


@contextmanager
def _atomic_output(target: Path, directory: bool) -> Iterator[Path]:
    """Yield a temporary sibling of ``target`` to write into; move it in place on success."""
    target.parent.mkdir(parents=True, exist_ok=True)
    prefix = f".{target.name}.tmp-"
    if directory:
        tmp = Path(tempfile.mkdtemp(prefix=prefix, dir=target.parent))
    else:
        fd, name = tempfile.mkstemp(prefix=prefix, dir=target.parent)
        os.close(fd)
        tmp = Path(name)
    try:
        yield tmp
        tmp.chmod(_default_mode(directory))
        _swap_into_place(tmp, target)
    except BaseException:
        _remove(tmp)
        raise


# ---------------------------------------------------------------------------------------------
# paths and format detection
# ---------------------------------------------------------------------------------------------

def _existing(path: str | os.PathLike) -> Path:
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file or directory")
    return p


def _magic(path: Path) -> bytes:
    try:
        with open(path, "rb") as fh:
            return fh.read(8)
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None


def _detect_format(path: Path) -> str:
    """'parquet' or 'h5' from the path (directory, suffix) or, failing that, the magic bytes."""
    if path.is_dir():
        return "parquet"
    suffix = path.suffix.lower()
    if suffix in H5_SUFFIXES:
        return "h5"
    if suffix in (".parquet", ".pq"):
        return "parquet"
    head = _magic(path)
    if head.startswith(_HDF5_MAGIC):
        return "h5"
    if head.startswith(_PARQUET_MAGIC):
        return "parquet"
    raise InputError(f"{path}: not a parquet dataset or an N-CMAPSS h5 file (unknown format)")


# ---------------------------------------------------------------------------------------------
# parquet
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
    table = pa.Table.from_pandas(part, preserve_index=False)
    # replace (not extend) the schema metadata: the pandas block holds library versions
    table = table.replace_schema_metadata({META_KEY.encode(): meta_json})
    file.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, file, compression=PARQUET_COMPRESSION)


def write_parquet(df: pd.DataFrame, path: str | os.PathLike,
                  metadata: Mapping[str, Any] | None = None) -> Path:
    """Write ``df`` as a parquet directory partitioned by unit (``unit=<n>/part-0.parquet``).

    Rows are sorted by unit, cycle, t; ``metadata`` is stored as JSON under the schema metadata
    key ``hyprog`` of every part file. The directory appears only when complete (see module doc).
    Returns the path written.
    """
    path = Path(path)
    source = str(path)
    table = _prepare_for_write(df, source)
    meta_json = _metadata_json(_metadata_for_write(metadata, source), source).encode()
    units = table["unit"].to_numpy()
    body = table.drop(columns="unit")
    with _atomic_output(path, directory=True) as tmp:
        for unit, rows in _unit_slices(units):
            _write_part(body.iloc[rows], tmp / f"unit={unit}" / PARQUET_PART, meta_json)
    return path


@contextmanager
def parquet_unit_writer(path: str | os.PathLike, metadata: Mapping[str, Any] | None = None
                        ) -> Iterator[Callable[[pd.DataFrame], None]]:
    """Stream a fleet to a parquet directory one unit at a time (the same layout as
    :func:`write_parquet`), so a large fleet never has to be in memory at once::

        with parquet_unit_writer(path, meta) as write_unit:
            for df_unit in units:
                write_unit(df_unit)

    The directory appears only when the block completes; on any error nothing is left.
    ``metadata`` is fixed when the writer opens (it goes into every part file).
    """
    path = Path(path)
    source = str(path)
    meta_json = _metadata_json(_metadata_for_write(metadata, source), source).encode()
    written: set[int] = set()
    with _atomic_output(path, directory=True) as tmp:
        def write_unit(df: pd.DataFrame) -> None:
            table = _prepare_for_write(df, source)
            units = table["unit"].to_numpy()
            body = table.drop(columns="unit")
            for unit, rows in _unit_slices(units):
                if unit in written:
                    raise InputError(f"{source}: unit {unit} written twice")
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
    interrupted writer leaves every unit either complete or absent. An existing partition of
    the same unit is replaced. Returns the part file."""
    path = Path(path)
    source = str(path)
    table = _prepare_for_write(df, source)
    units = table["unit"].unique()
    if len(units) != 1:
        raise InputError(f"{source}: write_unit_part takes one unit, got {len(units)}")
    meta_json = _metadata_json(_metadata_for_write(metadata, source), source).encode()
    unit_dir = path / f"unit={int(units[0])}"
    unit_dir.mkdir(parents=True, exist_ok=True)
    target = unit_dir / PARQUET_PART
    with _atomic_output(target, directory=False) as tmp:
        _write_part(table.drop(columns="unit"), tmp, meta_json)
    return target


def remove_stale_temporaries(path: str | os.PathLike) -> int:
    """Delete the hidden temporaries an interrupted writer left under ``path``; returns how
    many were removed."""
    p = Path(path)
    if not p.is_dir():
        return 0
    stale = [q for q in p.rglob(".*.tmp-*")]
    for q in stale:
        _remove(q)
    return len(stale)


def _is_hive_by_unit(path: Path) -> bool:
    return any(p.is_dir() and p.name.startswith("unit=") for p in path.iterdir())


def _parquet_files(path: Path) -> list[Path]:
    files = sorted(p for p in path.rglob("*.parquet")
                   if not any(part.startswith((".", "_")) for part in p.relative_to(path).parts))
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


def _open_parquet(path: Path) -> tuple[pds.Dataset, int | None]:
    """A pyarrow dataset over ``path`` and, for a lone part file, the unit of its directory."""
    try:
        if path.is_dir():
            _parquet_files(path)
            partitioning = None
            if _is_hive_by_unit(path):
                partitioning = pds.partitioning(pa.schema([("unit", pa.int64())]), flavor="hive")
            return pds.dataset(path, format="parquet", partitioning=partitioning), None
        dataset = pds.dataset(path, format="parquet")
        unit = None if "unit" in dataset.schema.names else _unit_from_dir(path)
        return dataset, unit
    except (pa.ArrowException, OSError) as exc:
        raise _arrow_error(path, exc) from None


def _first_parquet_file(path: Path) -> Path:
    return _parquet_files(path)[0] if path.is_dir() else path


def read_metadata(path: str | os.PathLike) -> dict[str, Any]:
    """The metadata of a parquet dataset or h5 file without reading the table."""
    p = _existing(path)
    if _detect_format(p) == "h5":
        with _open_h5(p) as f:
            return _h5_metadata(f, p)
    file = _first_parquet_file(p)
    try:
        schema_meta = pq.read_schema(file).metadata or {}
    except (pa.ArrowException, OSError) as exc:
        raise _arrow_error(file, exc) from None
    return _parse_metadata(schema_meta.get(META_KEY.encode()), str(file))


def read_columns(path: str | os.PathLike) -> list[str]:
    """The column names of a dataset (either format) without reading the table."""
    p = _existing(path)
    if _detect_format(p) == "h5":
        with _open_h5(p) as f:
            names: list[str] = []
            for split in SPLITS:
                if f"A_{split}" in f:
                    for _, cols in _h5_split_groups(f, split, p).values():
                        names += [c for c in cols if c not in names]
            return canonical_columns(["t", *names])
    file = _first_parquet_file(p)
    try:
        cols = list(pq.read_schema(file).names)
    except (pa.ArrowException, OSError) as exc:
        raise _arrow_error(file, exc) from None
    return canonical_columns(["unit", *[c for c in cols if c != "unit"]])


def _selected_columns(names: Sequence[str], columns: Sequence[str] | None,
                      source: str) -> list[str]:
    """The columns to return: ``unit``, ``cycle``, ``t`` (when present), then ``columns``."""
    if columns is None:
        return list(names)
    missing = [c for c in columns if c not in names]
    if missing:
        raise InputError(f"{source}: no column(s) {', '.join(missing)} in the file"
                         f" (has {', '.join(names)})")
    keys = [k for k in ("unit", "cycle", "t") if k in names]
    return keys + [c for c in columns if c not in keys]


def _check_units_found(found: np.ndarray, units: Sequence[int], source: str) -> None:
    missing = sorted(set(int(u) for u in units) - set(found.tolist()))
    if missing:
        raise InputError(f"{source}: unit(s) {', '.join(map(str, missing))} not in the file")


def read_parquet(path: str | os.PathLike, units: Sequence[int] | None = None,
                 columns: Sequence[str] | None = None) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Read a parquet dataset directory (or a single parquet file) -> ``(df, metadata)``.

    ``units`` reads only those units (partition pruning); ``columns`` loads only those columns
    besides ``unit``, ``cycle``, ``t``, which always come back. ``unit`` is int64, rows are
    sorted by unit, cycle, t.
    """
    p = _existing(path)
    source = str(p)
    if p.is_file() and _magic(p)[:4] != _PARQUET_MAGIC:
        raise InputError(f"{source}: not a parquet file")
    dataset, dir_unit = _open_parquet(p)
    names = list(dataset.schema.names) + (["unit"] if dir_unit is not None else [])
    check_columns(names, REQUIRED_COLUMNS, what=source)
    wanted = _selected_columns(names, columns, source)
    file_columns = [c for c in wanted if c in dataset.schema.names]
    flt = None
    if units is not None and dir_unit is None:
        flt = pds.field("unit").isin([int(u) for u in units])
    try:
        df = dataset.to_table(columns=file_columns, filter=flt).to_pandas()
    except (pa.ArrowException, OSError) as exc:
        raise _arrow_error(p, exc) from None
    if dir_unit is not None:
        df.insert(0, "unit", np.full(len(df), dir_unit, dtype=np.int64))
        if units is not None and dir_unit not in set(int(u) for u in units):
            df = df.iloc[:0]
    if units is not None:
        _check_units_found(df["unit"].unique(), units, source)
    df = _normalise_table(df[wanted], source)
    return df, read_metadata(p)


# ---------------------------------------------------------------------------------------------
# N-CMAPSS h5
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
        raw = raw.item()
    if isinstance(raw, bytes):
        raw = raw.decode()
    return _parse_metadata(raw, str(path))


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
                         f"{int(np.flatnonzero(bad)[0])}")
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
        _selected_columns([*names, "t"], sorted(columns), str(path))  # unknown -> InputError
    unit_col = _split_units(groups, split, path)
    all_units = sorted(int(u) for u in np.unique(unit_col))
    mask = np.ones(len(unit_col), bool) if units is None else np.isin(unit_col, list(units))
    runs, n_rows = _runs(mask), int(mask.sum())
    del unit_col, mask
    data: dict[str, np.ndarray] = {}
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


def read_ncmapss_h5(path: str | os.PathLike, split: str = "both",
                    units: Sequence[int] | None = None,
                    columns: Sequence[str] | None = None) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Read an N-CMAPSS h5 file (published layout, or one written by :func:`write_ncmapss_h5`).

    ``split`` is ``"dev"``, ``"test"`` or ``"both"`` (a split absent from the file is skipped
    for ``"both"``); ``units`` reads only those units' rows. Returns ``(df, metadata)``:
    metadata is the file's ``hyprog`` attribute (if any) with ``dev_units`` / ``test_units``
    (every unit of each split in the file), ``sample_rate_hz`` (1 Hz unless the file says) and
    ``source_format = "ncmapss-h5"``. ``t`` is rebuilt from the sample index (module doc).
    """
    if split not in ("both", *SPLITS):
        raise InputError(f"{path}: split must be 'dev', 'test' or 'both', got {split!r}")
    p = _existing(path)
    source = str(p)
    if p.is_dir() or not _magic(p).startswith(_HDF5_MAGIC):
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
        _check_units_found(df["unit"].unique(), units, source)
    df = _as_int_keys(df, source)
    rate = _sample_rate(meta, DEFAULT_H5_RATE_HZ)
    if "t" not in df.columns:
        df = _add_time(df, rate)
    order = canonical_columns(df.columns)
    if columns is not None:
        order = _selected_columns(order, columns, source)  # the keys, then the requested ones
    df = _normalise_table(df[order], source)
    meta.update(dev_units=split_units.get("dev", []), test_units=split_units.get("test", []),
                source_format=NCMAPSS_SOURCE)
    meta[SAMPLE_RATE_KEY] = rate
    return df, meta


def _assign_splits(units: np.ndarray, meta: Mapping[str, Any],
                   source: str) -> tuple[list[int], list[int]]:
    """(dev units, test units) present in the table, from the metadata lists."""
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
                     compression: str | None = "gzip") -> Path:
    """Write ``df`` in the N-CMAPSS h5 layout (module doc); atomic (temp file + os.replace).

    ``metadata['dev_units']`` / ``['test_units']`` choose the split (a unit in neither is an
    error when either is given; all units are dev when neither is). ``compression`` is an h5py
    filter name (``"gzip"``, ``"lzf"``) or None. Returns the path written.
    """
    path = Path(path)
    source = str(path)
    table = _prepare_for_write(df, source)
    meta = _metadata_for_write(metadata, source)
    dev, test = _assign_splits(table["unit"].to_numpy(), meta, source)
    meta.update(dev_units=dev, test_units=test)
    layout = _h5_layout(list(table.columns))
    _warn_dropped(list(table.columns), layout, source)
    _warn_if_t_lost(table, _sample_rate(meta, DEFAULT_H5_RATE_HZ), source)
    var_names = {g: v for g, v, _ in H5_GROUPS}
    with _atomic_output(path, directory=False) as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs[META_KEY] = _metadata_json(meta, source)
            for group, names in layout.items():
                if var_names[group] is not None:
                    f.create_dataset(var_names[group], data=np.array(names, dtype="S"))
            for split, split_units in (("dev", dev), ("test", test)):
                rows = table[table["unit"].isin(split_units)]
                for group, names in layout.items():
                    _create(f, f"{group}_{split}", _h5_array(rows, group, names), compression)
    return path


# ---------------------------------------------------------------------------------------------
# dispatch
# ---------------------------------------------------------------------------------------------

def read_dataset(path: str | os.PathLike, units: Sequence[int] | None = None,
                 columns: Sequence[str] | None = None,
                 split: str = "both") -> tuple[pd.DataFrame, dict[str, Any]]:
    """Read parquet (a directory or ``.parquet`` file) or N-CMAPSS h5 (``.h5``/``.hdf5``).

    ``split`` selects dev/test units: from the arrays for h5, from the metadata's
    ``dev_units`` / ``test_units`` for parquet.
    """
    p = _existing(path)
    if _detect_format(p) == "h5":
        return read_ncmapss_h5(p, split=split, units=units, columns=columns)
    if split not in ("both", *SPLITS):
        raise InputError(f"{p}: split must be 'dev', 'test' or 'both', got {split!r}")
    if split != "both":
        key = f"{split}_units"
        listed = read_metadata(p).get(key)
        if listed is None:
            raise InputError(f"{p}: the metadata has no {key}; cannot select split {split!r}")
        listed = [int(u) for u in listed]
        units = listed if units is None else [u for u in units if int(u) in set(listed)]
    return read_parquet(p, units=units, columns=columns)


def write_dataset(df: pd.DataFrame, path: str | os.PathLike,
                  metadata: Mapping[str, Any] | None = None,
                  format: str | None = None) -> Path:
    """Write ``df`` as ``format`` ``"parquet"`` or ``"h5"``; None infers it from the suffix
    (``.h5``/``.hdf5`` -> h5, anything else -> parquet)."""
    p = Path(path)
    fmt = format or ("h5" if p.suffix.lower() in H5_SUFFIXES else "parquet")
    if fmt == "parquet":
        return write_parquet(df, p, metadata)
    if fmt in ("h5", "hdf5", "ncmapss-h5"):
        return write_ncmapss_h5(df, p, metadata)
    raise InputError(f"{p}: unknown format {format!r} (expected 'parquet' or 'h5')")


# ---------------------------------------------------------------------------------------------
# summary
# ---------------------------------------------------------------------------------------------

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


def column_groups(columns: Sequence[str]) -> dict[str, list[str]]:
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


def _split_label(unit: int, dev: set[int], test: set[int], any_listed: bool) -> str | None:
    if unit in dev:
        return "dev"
    if unit in test:
        return "test"
    return None if any_listed else "dev"


def summarize(df: pd.DataFrame, metadata: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """A JSON-serialisable summary of a fleet table (for ``hyprog data info``).

    ``units``: one entry per unit with ``split`` (dev/test from the metadata; all dev when it
    lists neither), ``cycles`` (distinct cycles), ``rows``, ``eol`` (last cycle), ``t_s`` (first
    cycle with ``hs == 0``, None if none or no ``hs``), ``Fc`` (the flight classes flown);
    ``totals`` (units, rows, cycles); ``sample_rate_hz``; ``effects``; ``columns`` by group.
    """
    meta = dict(metadata or {})
    check_columns(list(df.columns), INT_KEYS, what="summarize")
    by_unit = df.groupby("unit", sort=True)
    rows = by_unit.size()
    cycles = by_unit["cycle"].nunique()
    eol = by_unit["cycle"].max()
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
    rate = _sample_rate(meta)
    summary = {
        "units": units,
        "totals": {"units": len(units), "rows": int(len(df)), "cycles": int(cycles.sum())},
        "sample_rate_hz": rate,
        "effects": _effects(meta),
        "columns": column_groups(list(df.columns)),
        "dev_units": sorted(u["unit"] for u in units if u["split"] == "dev"),
        "test_units": sorted(u["unit"] for u in units if u["split"] == "test"),
    }
    for key in ("preset", "seed", "hyprog_version", "source_format"):
        if key in meta:
            summary[key] = meta[key]
    return json.loads(json.dumps(summary, default=_json_default))
