"""Paths and format detection: which of the two on-disk formats a path holds.

A directory is a parquet dataset; a file is N-CMAPSS h5 by its suffix (``.h5``, ``.hdf5``,
``.he5``) or parquet by ``.parquet`` / ``.pq``; failing that, by its magic bytes
(``\\x89HDF\\r\\n\\x1a\\n`` for HDF5, ``PAR1`` for parquet).
"""

from __future__ import annotations

import os
from pathlib import Path

from ..validation import InputError

H5_SUFFIXES = (".h5", ".hdf5", ".he5")
PARQUET_SUFFIXES = (".parquet", ".pq")
HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
PARQUET_MAGIC = b"PAR1"
PARQUET_PART = "part-0.parquet"  # the one part file of a unit's partition (:mod:`.parquet`)


def existing_path(path: str | os.PathLike) -> Path:
    """``path`` as a Path; InputError when nothing is there."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file or directory")
    return p


def file_magic(path: Path) -> bytes:
    """The first 8 bytes of a file."""
    try:
        with open(path, "rb") as fh:
            return fh.read(8)
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None


def detect_format(path: Path) -> str:
    """'parquet' or 'h5' from the path (directory, suffix) or, failing that, the magic bytes."""
    if path.is_dir():
        return "parquet"
    suffix = path.suffix.lower()
    if suffix in H5_SUFFIXES:
        return "h5"
    if suffix in PARQUET_SUFFIXES:
        return "parquet"
    head = file_magic(path)
    if head.startswith(HDF5_MAGIC):
        return "h5"
    if head.startswith(PARQUET_MAGIC):
        return "parquet"
    hint = ""
    if head[:1].isdigit() or head[:1] in (b" ", b"-"):  # a text file of numbers: C-MAPSS?
        hint = " (a C-MAPSS text file? import it first: hyprog data import-cmapss)"
    raise InputError(f"{path}: not a parquet dataset or an N-CMAPSS h5 file (unknown "
                     f"format){hint}")


def output_format(path: str | os.PathLike, format: str | None = None,
                  what: str = "the format") -> str:
    """The format (``"parquet"`` or ``"h5"``) to write ``path`` in: ``format`` when given,
    else from the suffix (``.h5``/``.hdf5``/``.he5`` -> h5, anything else -> parquet). A
    ``format`` that contradicts the suffix (h5 named ``.parquet``/``.pq``, parquet named
    ``.h5``) is an InputError naming both; ``what`` names the format's source (``--format``)."""
    suffix = Path(path).suffix.lower()
    named = "h5" if suffix in H5_SUFFIXES else "parquet" if suffix in PARQUET_SUFFIXES else None
    if format is None:
        return named or "parquet"
    if format not in ("parquet", "h5"):
        raise InputError(f"{path}: unknown format {format!r} (expected 'parquet' or 'h5')")
    if named is not None and named != format:
        raise InputError(f"{path}: the suffix {suffix} is for {named}, but {what} is {format};"
                         " change one of them")
    return format
