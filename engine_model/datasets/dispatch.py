"""Read or write a dataset in either format, chosen by the path (:mod:`.paths`).

parquet: a directory or a ``.parquet`` file (:mod:`.parquet`); N-CMAPSS h5: ``.h5`` /
``.hdf5`` (:mod:`.ncmapss_h5`). The dev/test split of a parquet dataset comes from its
metadata's ``dev_units`` / ``test_units``, of an h5 file from its arrays.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from ..validation import InputError
from .ncmapss_h5 import read_h5_columns, read_h5_metadata, read_ncmapss_h5, write_ncmapss_h5
from .parquet import read_parquet, read_parquet_columns, read_parquet_metadata, write_parquet
from .paths import detect_format, existing_path, output_format
from .schema import check_split


def read_metadata(path: str | os.PathLike) -> dict[str, Any]:
    """The metadata of a parquet dataset or h5 file without reading the table."""
    p = existing_path(path)
    if detect_format(p) == "h5":
        return read_h5_metadata(p)
    return read_parquet_metadata(p)


def read_columns(path: str | os.PathLike) -> list[str]:
    """The column names of a dataset (either format) without reading the table."""
    p = existing_path(path)
    if detect_format(p) == "h5":
        return read_h5_columns(p)
    return read_parquet_columns(p)


def read_dataset(path: str | os.PathLike, units: Sequence[int] | None = None,
                 columns: Sequence[str] | None = None,
                 split: str = "both", source_rows: bool = False
                 ) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Read parquet (a directory or ``.parquet`` file) or N-CMAPSS h5 (``.h5``/``.hdf5``).

    ``split`` selects dev/test units: from the arrays for h5, from the metadata's
    ``dev_units`` / ``test_units`` for parquet. ``source_rows`` adds the column
    :data:`~.schema.SOURCE_ROW` (1-based row of the user's file) for error messages.
    """
    p = existing_path(path)
    if detect_format(p) == "h5":
        return read_ncmapss_h5(p, split=split, units=units, columns=columns,
                               source_rows=source_rows)
    check_split(split, p)
    if split != "both":
        key = f"{split}_units"
        listed = read_parquet_metadata(p).get(key)
        if listed is None:
            raise InputError(f"{p}: the metadata has no {key}; cannot select split {split!r}")
        listed = [int(u) for u in listed]
        outside = [int(u) for u in units or () if int(u) not in set(listed)]
        if outside:  # as the h5 reader: a unit asked for outside the split is an error
            raise InputError(f"{p}: unit(s) {', '.join(map(str, outside))} not in the "
                             f"{split} split ({key}: {', '.join(map(str, listed))})")
        units = listed if units is None else [int(u) for u in units]
    return read_parquet(p, units=units, columns=columns, source_rows=source_rows)


def write_dataset(df: pd.DataFrame, path: str | os.PathLike,
                  metadata: Mapping[str, Any] | None = None,
                  format: str | None = None, overwrite: bool = False,
                  inputs: Sequence[str | os.PathLike | None] = ()) -> Path:
    """Write ``df`` as ``format`` ``"parquet"`` or ``"h5"``; None infers it from the suffix
    (``.h5``/``.hdf5`` -> h5, anything else -> parquet); a format the suffix contradicts is
    refused (:func:`~.paths.output_format`). An existing ``path`` is replaced only when hyprog
    wrote it or with ``overwrite``, never when it is one of ``inputs`` (:mod:`.provenance`)."""
    p = Path(path)
    if format in ("hdf5", "ncmapss-h5"):
        format = "h5"
    if output_format(p, format) == "parquet":
        return write_parquet(df, p, metadata, overwrite=overwrite, inputs=inputs)
    return write_ncmapss_h5(df, p, metadata, overwrite=overwrite, inputs=inputs)
