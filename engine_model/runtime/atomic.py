"""Atomic output: nothing half-written is ever visible under the target's name.

Atomicity
---------
Writers build the output in a temporary sibling (``.<name>.tmp-<host>-<pid>-<random>``)
and move it into place with ``os.replace`` only after everything was written; an existing
target is replaced then (only one that :func:`.ownership.check_output` allows: what hyprog
wrote, or anything with ``overwrite=True``), and on any exception the temporary is removed
and the target is left as it was. A writer killed before it could clean up leaves only hidden
``.<name>.tmp-*`` entries, which readers ignore. The temporary's name holds the writer's host
and process id, so :func:`remove_stale_temporaries` deletes only those whose writer is gone
(a process of this host that no longer runs), never another running writer's file.

Replacing a folder takes two renames (the old target aside to ``.<name>.old-<host>-<pid>-*``,
the new one in); a writer killed between them leaves the previous output only in that backup,
so a stale backup is moved back under its name when the name is free and deleted otherwise
(:func:`remove_stale_temporaries_of`, :func:`remove_stale_temporaries`).
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import tempfile
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from .critical import critical_section
from .ownership import check_output

TEMPORARY_GLOB = ".*.tmp-*"
TMP_MARK = ".tmp-"
BACKUP_GLOB = ".*.old-*"
OLD_MARK = ".old-"


def host_name() -> str:
    """This machine's name as it appears in temporaries and lock files (no '-' or '/')."""
    return socket.gethostname().replace("-", "_").replace("/", "_") or "localhost"


def temporary_prefix(name: str) -> str:
    """``.<name>.tmp-<host>-<pid>-``: the prefix of this process's temporaries of ``name``."""
    return f".{name}{TMP_MARK}{host_name()}-{os.getpid()}-"


def pid_alive(pid: int) -> bool:
    """True when a process ``pid`` runs on this machine (or exists but is not ours)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


#: A hyprog temporary or backup: ``.<name>.tmp-<host>-<pid>-<random>[<suffix>]`` or
#: ``.<name>.old-<host>-<pid>-<random>``, read from the right (``<name>`` may itself contain
#: ``.tmp-`` or ``-``; ``<host>`` has no ``-``, :func:`host_name`).
HYPROG_TEMPORARY = re.compile(r"^\.(?P<name>.+)\.(?P<kind>tmp|old)-(?P<host>[^-/]+)-"
                              r"(?P<pid>\d+)-(?P<random>[A-Za-z0-9_]+)(?P<suffix>\.[^-/]*)?$")


def temporary_writer(name: str) -> tuple[str, int] | None:
    """(host, pid) of the writer of a temporary named by :func:`temporary_prefix` (or of a
    backup named by :func:`swap_into_place`), or None for any other name."""
    m = HYPROG_TEMPORARY.match(name)
    return None if m is None else (m["host"], int(m["pid"]))


def writer_gone(name: str) -> bool:
    """True when ``name`` is a hyprog temporary or backup whose writer, a process of this
    host, no longer runs. Any other name (another program's file, a user's backup) is never
    taken for one."""
    who = temporary_writer(name)
    if who is None:
        return False
    host, pid = who
    return host == host_name() and not pid_alive(pid)


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
    """Move ``tmp`` to ``target``; an existing target is moved aside first and removed after.

    Both renames are inside one ``try``: an exception (a signal's included) after the first
    puts the old target back. The backup is renamed to a temporary before it is deleted, so a
    writer killed while deleting it leaves a temporary (deleted by the next writer), never a
    half-deleted backup that could be put back."""
    if not target.exists() and not target.is_symlink():
        os.replace(tmp, target)
        return
    if target.is_file() and tmp.is_file():
        os.replace(tmp, target)  # atomic replacement of a file
        return
    backup = target.with_name(f".{target.name}{OLD_MARK}{host_name()}-{os.getpid()}-"
                              f"{uuid.uuid4().hex[:8]}")
    try:
        with critical_section():  # a signal waits until both renames are done
            os.replace(target, backup)
            os.replace(tmp, target)
    except BaseException:
        if backup.exists() and not target.exists() and not target.is_symlink():
            os.replace(backup, target)
        raise
    trash = target.with_name(f"{temporary_prefix(target.name)}{uuid.uuid4().hex[:8]}")
    os.replace(backup, trash)
    remove_path(trash)


@contextmanager
def atomic_output(target: Path, directory: bool, overwrite: bool = False,
                  ours: Callable[[Path], bool] | None = None,
                  want: str | None = None) -> Iterator[Path]:
    """Yield a temporary sibling of ``target`` to write into; move it in place on success.
    An existing ``target`` must be one hyprog may replace (:func:`.ownership.check_output`
    with the writer's recogniser ``ours`` and its description ``want``; ``overwrite=True``
    replaces anything)."""
    target = check_output(target, directory, overwrite, ours, want)
    target.parent.mkdir(parents=True, exist_ok=True)
    prefix = temporary_prefix(target.name)
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


def _clean_stale(entries, name: str | None = None) -> int:
    """Remove the stale temporaries among ``entries`` (of the output ``name`` only, when
    given) and put back or remove stale backups (module docstring); returns how many entries
    were handled."""
    n = 0
    for q in entries:
        m = HYPROG_TEMPORARY.match(q.name)
        if m is None or (name is not None and m["name"] != name):
            continue  # not a hyprog temporary, or another output's
        if not writer_gone(q.name) or not (q.exists() or q.is_symlink()):
            continue  # a running writer's, or gone with an entry handled before
        if m["kind"] == "old":
            original = q.with_name(m["name"])
            if not original.exists() and not original.is_symlink():
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
