"""Whose is an existing output path: a writer replaces only what hyprog wrote.

A writer given an output path that already holds something (:func:`check_output`):

- nothing there, or an empty directory: written;
- a dataset hyprog wrote, of the same kind (a parquet directory whose part files carry the
  ``hyprog`` metadata, an h5 file with the ``hyprog`` root attribute): replaced as a whole,
  atomically (the metadata says hyprog wrote it: :func:`written_by_hyprog`);
- anything else (a folder of other files, a regular file, a dataset of the other kind: a
  directory where a file is to be written or the reverse): refused with an
  :class:`~engine_model.validation.InputError` that says what is there, unless the caller
  passes ``overwrite=True`` (``hyprog ... --overwrite``);
- the current directory or one of its parents: always refused (replacing it would pull the
  ground from under the shell that runs hyprog).

Nothing is deleted before the new output is complete (:mod:`.atomic`).
"""

from __future__ import annotations

import os
from pathlib import Path

from ..validation import InputError
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


def is_empty_dir(path: Path) -> bool:
    return path.is_dir() and not any(path.iterdir())


def describe(path: Path) -> str:
    """What is at ``path``, in words (for a refusal)."""
    if path.is_symlink() and not path.exists():
        return "a broken symbolic link"
    if path.is_dir():
        n = sum(1 for _ in path.iterdir())
        return f"a directory of {n} entr{'y' if n == 1 else 'ies'} that hyprog did not write"
    if path.is_file():
        return "a file that hyprog did not write"
    return "something that is not a file or a directory"


def check_output(path: str | os.PathLike, directory: bool, overwrite: bool = False) -> Path:
    """The absolute output path, after the checks of the module docstring; ``directory``: the
    writer makes a directory (parquet) rather than a file (h5). Raises InputError."""
    p = Path(os.path.abspath(path))
    cwd = Path.cwd().resolve()
    if p.resolve() == cwd or p.resolve() in cwd.parents:
        raise InputError(f"{path}: is the current directory or one of its parents; name a new"
                         " output inside it (e.g. --out fleet)")
    if not p.exists() and not p.is_symlink():
        return p
    if directory and is_empty_dir(p):
        return p
    kind_ok = p.is_dir() == directory and not p.is_symlink()
    if kind_ok and written_by_hyprog(p):
        return p
    if overwrite:
        return p
    want = "a parquet directory" if directory else "a file"
    if written_by_hyprog(p):
        what = f"a hyprog {'directory' if p.is_dir() else 'file'}"
    else:
        what = describe(p)
    raise InputError(f"{path}: exists and is {what}; hyprog writes {want} there only with"
                     " --overwrite (which replaces it), or choose another output")


__all__ = ["check_output", "written_by_hyprog"]
