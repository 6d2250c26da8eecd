"""One writer per output path: a lock file next to the output.

:func:`output_lock` creates ``.<name>.hyprog-lock`` beside the output ``<name>`` with
``O_CREAT | O_EXCL`` (atomic on a local file system: of two writers exactly one creates it)
and writes ``<host> <pid>`` into it. A second writer finds the file and is refused with an
:class:`~engine_model.validation.InputError` naming the process that holds it. A lock left by
a writer that was killed (SIGKILL, power loss) is *stale* when it names a process of this host
that no longer runs; it is then taken over. A lock held by a process on another host cannot be
checked from here: the message names the host and the lock file, which the user deletes once
that run is known to be gone. The lock is removed when the block exits, normally or by an
exception (also SIGTERM and Ctrl-C, which the CLI turns into exceptions).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from engine_model.validation import InputError

from .critical import critical_section
from .names import LOCK_SUFFIX, host_name, pid_alive


def lock_path(path: str | os.PathLike) -> Path:
    """The lock file of output ``path``: ``.<name>.hyprog-lock`` in the same directory."""
    p = Path(os.path.abspath(path))
    return p.with_name(f".{p.name}{LOCK_SUFFIX}")


def read_lock(lock: Path) -> tuple[str, int] | None:
    """(host, pid) written in a lock file, None when it cannot be read or parsed."""
    try:
        host, pid = lock.read_text().split()[:2]
        return host, int(pid)
    except (OSError, ValueError):
        return None


def _try_create(lock: Path) -> bool:
    try:
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
    except FileExistsError:
        return False
    with os.fdopen(fd, "w") as fh:
        fh.write(f"{host_name()} {os.getpid()}\n")
    return True


def acquire(path: str | os.PathLike) -> Path:
    """Take the lock of output ``path`` (module docstring); returns the lock file."""
    lock = lock_path(path)
    for _ in range(3):
        try:
            lock.parent.mkdir(parents=True, exist_ok=True)
            created = _try_create(lock)
        except OSError as e:  # read-only, permission, a pseudo file system (/proc)
            why = ("it accepts no new files" if isinstance(e, FileNotFoundError)
                   and lock.parent.is_dir() else e.strerror or str(e))
            raise InputError(f"{path}: cannot write an output there ({lock.parent}:"
                             f" {why})") from None
        if created:
            return lock
        who = read_lock(lock)
        if who is None:  # being written this instant, or garbage: look once more
            continue
        host, pid = who
        if host == host_name() and not pid_alive(pid):
            lock.unlink(missing_ok=True)  # stale: its writer is gone
            continue
        if host == host_name() and pid == os.getpid():
            raise InputError(f"{path}: this process already writes it")
        where = "this machine" if host == host_name() else f"host {host}"
        raise InputError(f"{path}: another hyprog run (process {pid} on {where}) is writing"
                         f" it; wait for it to finish or choose another output (lock file"
                         f" {lock})")
    raise InputError(f"{path}: cannot take the lock {lock} (unreadable lock file; delete it if"
                     " no hyprog run writes this output)")


def release(lock: Path) -> None:
    """Remove a lock this process holds (another process's lock is left alone)."""
    with critical_section():
        who = read_lock(lock)
        if who is not None and who == (host_name(), os.getpid()):
            lock.unlink(missing_ok=True)


@contextmanager
def output_lock(path: str | os.PathLike) -> Iterator[Path]:
    """Hold the lock of output ``path`` for the block (module docstring)."""
    held = None
    try:
        with critical_section():  # a signal cannot fall between creating and holding it
            held = acquire(path)
        yield held
    finally:
        if held is not None:
            release(held)


__all__ = ["LOCK_SUFFIX", "acquire", "lock_path", "output_lock", "read_lock", "release"]
