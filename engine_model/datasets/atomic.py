"""Atomic output: nothing half-written is ever visible under the target's name.

Atomicity
---------
Writers build the output in a temporary sibling (``.<name>.tmp-*``) and move it into place
with ``os.replace`` only after everything was written; an existing target is replaced then,
and on any exception the temporary is removed and the target is left as it was. A writer
killed before it could clean up leaves only hidden ``.<name>.tmp-*`` entries, which readers
ignore and :func:`remove_stale_temporaries` deletes.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

TEMPORARY_GLOB = ".*.tmp-*"


def remove_path(path: Path) -> None:
    """Delete a file or a directory tree (missing is fine)."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def default_mode(directory: bool) -> int:
    """The permission bits a plain ``open``/``mkdir`` would give under the current umask
    (``mkstemp``/``mkdtemp`` create owner-only entries)."""
    umask = os.umask(0)
    os.umask(umask)
    return (0o777 if directory else 0o666) & ~umask


def swap_into_place(tmp: Path, target: Path) -> None:
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
    remove_path(backup)


@contextmanager
def atomic_output(target: Path, directory: bool) -> Iterator[Path]:
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
        tmp.chmod(default_mode(directory))
        swap_into_place(tmp, target)
    except BaseException:
        remove_path(tmp)
        raise


def remove_stale_temporaries(path: str | os.PathLike) -> int:
    """Delete the hidden temporaries an interrupted writer left under ``path``; returns how
    many were removed."""
    p = Path(path)
    if not p.is_dir():
        return 0
    stale = [q for q in p.rglob(TEMPORARY_GLOB)]
    for q in stale:
        remove_path(q)
    return len(stale)
