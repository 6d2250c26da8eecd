"""Is an existing path a dataset hyprog wrote? The data sets' output kinds for the ownership
rule (:mod:`engine_model.runtime.ownership`).

A parquet directory whose part files carry the ``hyprog`` metadata, or an h5 / parquet file
with it (:data:`.metadata.META_KEY`), is a dataset hyprog wrote: a writer of the same kind may
replace it as a whole. In a parquet directory hyprog writes only ``unit=<n>/part-0.parquet``
(:func:`dataset_layout`); any other entry is the user's and makes a replacement a refusal
unless ``--overwrite``. :data:`PARQUET_DATASET` and :data:`H5_DATASET` are the two kinds of
data, and :data:`PARQUET_FEATURES` a feature table (the data with ``hyprog calibrate``'s
record), which only a feature table replaces; :func:`check_dataset_output` is the ownership
rule for data.
"""

from __future__ import annotations

import os
from pathlib import Path

from engine_model.runtime.ownership import OutputKind, check_output
from engine_model.validation import InputError

from .metadata import META_KEY, parse_metadata
from .paths import HDF5_MAGIC, PARQUET_MAGIC, PARQUET_PART

PART_GLOB = "unit=*/*.parquet"


def _parquet_has_meta(file: Path) -> bool:
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        meta = pq.read_schema(file).metadata or {}
    except (pa.ArrowException, OSError):
        return False
    return META_KEY.encode() in meta


def _h5_has_meta(file: Path) -> bool:
    import h5py

    try:
        with h5py.File(file, "r") as f:
            return META_KEY in f.attrs
    except OSError:
        return False


def _head(file: Path) -> bytes:
    try:
        with open(file, "rb") as fh:
            return fh.read(8)
    except OSError:
        return b""


def written_by_hyprog(path: Path) -> bool:
    """True when ``path`` is a dataset hyprog wrote: a directory with ``unit=<n>`` part files
    carrying the ``hyprog`` metadata, or an h5 / parquet file with it."""
    if path.is_dir():
        parts = [p for p in path.glob(PART_GLOB) if not p.name.startswith((".", "_"))]
        return bool(parts) and all(_parquet_has_meta(p) for p in parts[:1])
    if path.is_file():
        head = _head(path)
        if head.startswith(HDF5_MAGIC):
            return _h5_has_meta(path)
        if head.startswith(PARQUET_MAGIC):
            return _parquet_has_meta(path)
    return False


def is_feature_table(path: Path) -> bool:
    """``path`` is a feature table hyprog wrote: a parquet dataset directory whose metadata
    (in its part files) has the ``calibration`` entry (``hyprog calibrate``'s output)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    if not (path.is_dir() and written_by_hyprog(path)):
        return False
    part = next(p for p in sorted(path.glob(PART_GLOB)) if not p.name.startswith((".", "_")))
    try:
        raw = (pq.read_schema(part).metadata or {}).get(META_KEY.encode())
        return "calibration" in parse_metadata(raw, str(part))
    except (pa.ArrowException, OSError, InputError):
        return False


def dataset_layout(path: Path) -> list[str]:
    """The files hyprog writes in a parquet dataset directory: ``unit=<n>/part-0.parquet``."""
    return [f"{d.name}/{PARQUET_PART}" for d in path.glob("unit=*")
            if d.name[5:].lstrip("-").isdigit() and (d / PARQUET_PART).is_file()]


#: A hyprog parquet dataset (a directory partitioned by unit) that is not a feature table: a
#: writer of data (simulate, import) never replaces a feature table without ``--overwrite``.
PARQUET_DATASET = OutputKind("a hyprog parquet dataset (not a feature table)", directory=True,
                             ours=lambda path: written_by_hyprog(path)
                             and not is_feature_table(path), layout=dataset_layout)
#: A feature table written whole (:func:`.parquet.write_parquet` of a table with the
#: ``calibration`` record): it replaces only a feature table.
PARQUET_FEATURES = OutputKind("a hyprog feature table", directory=True, ours=is_feature_table,
                              layout=dataset_layout)
#: One unit's partition ``unit=<n>/`` inside a dataset being written unit by unit (a resumable
#: writer's): replaced when it holds its part file and nothing else.
UNIT_PARTITION = OutputKind("a unit's partition", directory=True,
                            ours=lambda path: (path / PARQUET_PART).is_file(),
                            layout=lambda path: [PARQUET_PART])
#: A dataset file hyprog wrote (N-CMAPSS h5).
H5_DATASET = OutputKind("a hyprog dataset file", directory=False, ours=written_by_hyprog)


def check_dataset_output(path: str | os.PathLike, directory: bool, overwrite: bool = False,
                         inputs=()) -> Path:
    """:func:`~engine_model.runtime.ownership.check_output` for a dataset: a parquet
    directory (``directory=True``) or an h5 file that hyprog wrote may be replaced."""
    return check_output(path, PARQUET_DATASET if directory else H5_DATASET, overwrite, inputs)


__all__ = ["H5_DATASET", "PARQUET_DATASET", "PARQUET_FEATURES", "UNIT_PARTITION",
           "check_dataset_output", "dataset_layout", "is_feature_table", "written_by_hyprog"]
