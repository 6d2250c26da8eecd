"""The names hyprog gives the hidden entries it makes beside (or inside) an output, so that
they are told apart from everything else: a writer's temporary, the backup of a folder being
replaced and the lock of an output, each carrying the writer's host and process id.

==========  =======================================================================
entry       name
==========  =======================================================================
temporary   ``.<name>.tmp-<host>-<pid>-<random>[<suffix>]`` (:func:`temporary_prefix`)
backup      ``.<name>.old-<host>-<pid>-<random>`` (:func:`backup_name`)
lock        ``.<name>.hyprog-lock`` (:data:`LOCK_SUFFIX`)
==========  =======================================================================

``<host>`` is :func:`host_name` (no ``-``), so a name is read from the right: ``<name>`` may
itself contain ``.tmp-`` or ``-``. Nothing else is ever taken for one of these (a user's
``notes.old-2019`` has no host and pid).
"""

from __future__ import annotations

import os
import re
import socket
import uuid

TMP_MARK = ".tmp-"
OLD_MARK = ".old-"
TEMPORARY_GLOB = ".*.tmp-*"
BACKUP_GLOB = ".*.old-*"
LOCK_SUFFIX = ".hyprog-lock"


def host_name() -> str:
    """This machine's name as it appears in temporaries and lock files (no '-' or '/')."""
    return socket.gethostname().replace("-", "_").replace("/", "_") or "localhost"


def temporary_prefix(name: str) -> str:
    """``.<name>.tmp-<host>-<pid>-``: the prefix of this process's temporaries of ``name``."""
    return f".{name}{TMP_MARK}{host_name()}-{os.getpid()}-"


def backup_name(name: str) -> str:
    """``.<name>.old-<host>-<pid>-<random>``: where this process moves ``name`` aside while it
    puts a new output in its place."""
    return f".{name}{OLD_MARK}{host_name()}-{os.getpid()}-{uuid.uuid4().hex[:8]}"


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


#: A hyprog temporary or backup (module docstring).
HYPROG_TEMPORARY = re.compile(r"^\.(?P<name>.+)\.(?P<kind>tmp|old)-(?P<host>[^-/]+)-"
                              r"(?P<pid>\d+)-(?P<random>[A-Za-z0-9_]+)(?P<suffix>\.[^-/]*)?$")


def temporary_writer(name: str) -> tuple[str, int] | None:
    """(host, pid) of the writer of a temporary named by :func:`temporary_prefix` (or of a
    backup named by :func:`backup_name`), or None for any other name."""
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


def is_hyprog_entry(name: str) -> bool:
    """True for the name of a hyprog temporary, backup or lock file (module docstring)."""
    return HYPROG_TEMPORARY.match(name) is not None or (
        name.startswith(".") and name.endswith(LOCK_SUFFIX) and len(name) > len(LOCK_SUFFIX) + 1)


__all__ = ["BACKUP_GLOB", "HYPROG_TEMPORARY", "LOCK_SUFFIX", "OLD_MARK", "TEMPORARY_GLOB",
           "TMP_MARK", "backup_name", "host_name", "is_hyprog_entry", "pid_alive",
           "temporary_prefix", "temporary_writer", "writer_gone"]
