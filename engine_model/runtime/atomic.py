"""Atomic output: nothing half-written is ever visible under the target's name, and a failed
write leaves the previous output in place. The one implementation of it: every writer of hyprog
(datasets, feature tables, model folders, reports, predictions, run records, figures) goes
through :func:`atomic_output` / :func:`atomic_outputs`.

Atomicity
---------
Writers build the output in a temporary sibling (``.<name>.tmp-<host>-<pid>-<random>``,
:mod:`.names`) and move it into place with ``os.replace`` only after everything was written;
an existing target is replaced then (only one that the ownership rule allows, checked before
the work and again just before the swap: :func:`.ownership.check_output`), and on any
exception the temporary is removed and the target is left as it was. Several outputs that
belong together (``predict``'s table and its ``.per_cycle`` sidecar) are swapped together:
both new or both old (:func:`swap_all_into_place`). A writer killed before it could clean up
leaves only hidden ``.<name>.tmp-*`` entries, which readers ignore. The temporary's name holds
the writer's host and process id, so :func:`remove_stale_temporaries` deletes only those whose
writer is gone (a process of this host that no longer runs), never another running writer's
file.

Replacing takes two renames per output (the old target aside to
``.<name>.old-<host>-<pid>-*``, the new one in); a writer killed between them leaves the
previous output only in that backup, so a stale backup is moved back under its name when the
name is free and deleted otherwise (:func:`remove_stale_temporaries_of`,
:func:`remove_stale_temporaries`). Of a group killed half-way, each output is then the old or
the new one; none is lost.

Cleaning after a killed run is this module's job alone: a command that resumes in a folder
calls :func:`remove_stale_temporaries` on it under its lock, a writer of one output
:func:`remove_stale_temporaries_of` (done by :func:`atomic_outputs` itself).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import uuid
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from .critical import critical_section
from .names import (
    BACKUP_GLOB,
    HYPROG_TEMPORARY,
    OLD_MARK,
    TEMPORARY_GLOB,
    TMP_MARK,
    backup_name,
    host_name,
    pid_alive,
    temporary_prefix,
    temporary_writer,
    writer_gone,
)
from .ownership import OutputKind, check_output


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


def _exists(path: Path) -> bool:
    return path.exists() or path.is_symlink()


def _discard(backup: Path, target: Path) -> None:
    """Delete a backup: renamed to a temporary first, so a writer killed while deleting it
    leaves a temporary (deleted by the next writer), never a half-deleted backup that could be
    put back."""
    trash = target.with_name(f"{temporary_prefix(target.name)}{uuid.uuid4().hex[:8]}")
    os.replace(backup, trash)
    remove_path(trash)


def swap_all_into_place(pairs: Sequence[tuple[Path, Path]]) -> None:
    """Move every ``tmp`` to its ``target``: all of them, or on an exception (a signal's
    included) none. The existing targets are moved aside to backups
    (:func:`.names.backup_name`) first and, if anything fails before every new output is in,
    the new ones go back to their temporaries and the backups back under their names; the
    backups are deleted only after. A single file replacing a file needs no backup
    (``os.replace`` is atomic)."""
    pairs = [(Path(tmp), Path(target)) for tmp, target in pairs]
    if len(pairs) == 1:
        tmp, target = pairs[0]
        if not _exists(target) or (target.is_file() and tmp.is_file()):
            os.replace(tmp, target)
            return
    backups, placed = [], []
    try:
        with critical_section():  # a signal waits until every rename is done
            for _, target in pairs:
                if _exists(target):
                    backup = target.with_name(backup_name(target.name))
                    backups.append((backup, target))  # before: a signal may end the rename
                    os.replace(target, backup)
            for tmp, target in pairs:
                placed.append((tmp, target))
                os.replace(tmp, target)
    except BaseException:
        for tmp, target in reversed(placed):
            if _exists(target) and not _exists(tmp):
                os.replace(target, tmp)
        for backup, target in backups:
            if backup.exists() and not _exists(target):
                os.replace(backup, target)
        raise
    for backup, target in backups:
        _discard(backup, target)


def swap_into_place(tmp: Path, target: Path) -> None:
    """Move ``tmp`` to ``target``; an existing target is moved aside first and removed after
    (:func:`swap_all_into_place`)."""
    swap_all_into_place([(tmp, target)])


def _temporary(target: Path, directory: bool) -> Path:
    """A new temporary sibling of ``target`` (a file keeps the target's suffix)."""
    prefix = temporary_prefix(target.name)
    if directory:
        return Path(tempfile.mkdtemp(prefix=prefix, dir=target.parent))
    fd, name = tempfile.mkstemp(prefix=prefix, suffix=target.suffix, dir=target.parent)
    os.close(fd)
    return Path(name)


@contextmanager
def atomic_outputs(targets: Sequence[tuple[str | os.PathLike, OutputKind]],
                   overwrite: bool = False,
                   inputs: Sequence[str | os.PathLike | None] = ()) -> Iterator[list[Path]]:
    """Yield one temporary sibling per ``(target, kind)`` to write into; when the block
    succeeds, move them all into place together (:func:`swap_all_into_place`: a sidecar file
    and its main output are both new or both old). Each target is checked by the ownership
    rule (:func:`.ownership.check_output` with its kind, ``overwrite`` and the command's
    ``inputs``) before anything is written and again just before the swap; what a killed
    writer of the same target left is cleaned first (:func:`remove_stale_temporaries_of`).
    On any exception the temporaries are removed and every target is left as it was."""
    for target, _ in targets:
        remove_stale_temporaries_of(os.path.abspath(target))
    checked = [(check_output(t, kind, overwrite, inputs), kind) for t, kind in targets]
    tmps: list[Path] = []
    try:
        for target, kind in checked:
            target.parent.mkdir(parents=True, exist_ok=True)
            tmps.append(_temporary(target, kind.directory))
        yield list(tmps)
        for (target, kind), tmp in zip(checked, tmps, strict=True):
            check_output(target, kind, overwrite, inputs)  # what is there now may be replaced
            tmp.chmod(default_mode(kind.directory))
        swap_all_into_place([(tmp, target) for tmp, (target, _) in zip(tmps, checked,
                                                                         strict=True)])
    except BaseException:
        for tmp in tmps:
            remove_path(tmp)
        raise


@contextmanager
def atomic_output(target: str | os.PathLike, kind: OutputKind, overwrite: bool = False,
                  inputs: Sequence[str | os.PathLike | None] = ()) -> Iterator[Path]:
    """:func:`atomic_outputs` of the one output ``target``: yields its temporary."""
    with atomic_outputs([(target, kind)], overwrite, inputs) as (tmp,):
        yield tmp


def _clean_stale(entries, name: str | None = None) -> int:
    """Remove the stale temporaries among ``entries`` (of the output ``name`` only, when
    given) and put back or remove stale backups (module docstring); returns how many entries
    were handled."""
    n = 0
    for q in entries:
        m = HYPROG_TEMPORARY.match(q.name)
        if m is None or (name is not None and m["name"] != name):
            continue  # not a hyprog temporary, or another output's
        if not writer_gone(q.name) or not _exists(q):
            continue  # a running writer's, or gone with an entry handled before
        if m["kind"] == "old":
            original = q.with_name(m["name"])
            if not _exists(original):
                os.replace(q, original)  # the writer died between its two renames
                n += 1
                continue
        remove_path(q)
        n += 1
    return n


def remove_stale_temporaries(path: str | os.PathLike) -> int:
    """Clean what interrupted writers left anywhere under the folder ``path`` (an output
    folder hyprog writes into): temporaries whose writer no longer runs (:func:`writer_gone`)
    are deleted, a running writer's are kept, and a stale backup of a replaced folder is put
    back or deleted (module docstring). Returns how many entries were handled."""
    p = Path(path)
    if not p.is_dir():
        return 0
    return _clean_stale([*p.rglob(TEMPORARY_GLOB), *p.rglob(BACKUP_GLOB)])


def remove_stale_temporaries_of(target: str | os.PathLike) -> int:
    """The same for the one output ``target``: only its own ``.<name>.tmp-*`` and
    ``.<name>.old-*`` siblings, without looking anywhere else in its parent folder (which may
    be a home directory)."""
    t = Path(target)
    if not t.parent.is_dir():
        return 0
    return _clean_stale([*t.parent.glob(f".{t.name}{TMP_MARK}*"),
                         *t.parent.glob(f".{t.name}{OLD_MARK}*")], t.name)


__all__ = ["BACKUP_GLOB", "HYPROG_TEMPORARY", "OLD_MARK", "TEMPORARY_GLOB", "TMP_MARK",
           "atomic_output", "atomic_outputs", "default_mode", "host_name", "pid_alive",
           "remove_path", "remove_stale_temporaries", "remove_stale_temporaries_of",
           "swap_all_into_place", "swap_into_place", "temporary_prefix", "temporary_writer",
           "writer_gone"]
