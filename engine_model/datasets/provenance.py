"""Is an existing path a dataset hyprog wrote? (the data sets' recogniser for
:func:`engine_model.runtime.ownership.check_output`).

A parquet directory whose part files carry the ``hyprog`` metadata, or an h5 / parquet file
with it (:data:`.metadata.META_KEY`), is a dataset hyprog wrote: a writer of the same kind may
replace it as a whole. :func:`check_dataset_output` is the ownership rule with this recogniser.
"""

from __future__ import annotations

import os
from pathlib import Path

from engine_model.runtime.ownership import check_output

from .metadata import META_KEY
from .paths import HDF5_MAGIC, PARQUET_MAGIC

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


def check_dataset_output(path: str | os.PathLike, directory: bool,
                         overwrite: bool = False) -> Path:
    """:func:`~engine_model.runtime.ownership.check_output` for a dataset: a parquet
    directory (``directory=True``) or an h5 file that hyprog wrote may be replaced."""
    return check_output(path, directory, overwrite, ours=written_by_hyprog,
                        want="a parquet directory" if directory else "a file")


__all__ = ["check_dataset_output", "written_by_hyprog"]
