"""One builder per cached file: of several processes that miss the same file of the cache at
once (pytest-xdist workers, the pipeline's worker processes), one builds it and the others
wait and load it, instead of each spending the same work.

:func:`build_lock` holds an exclusive lock on ``.<name>.building`` beside the cached file for
a block; the caller checks again inside the block whether the file appeared meanwhile. Used
for the compiled libraries (:mod:`engine_model.solver.codegen`, 20-40 s of the compiler) and
the starting-guess table (:mod:`engine_model.solver.guess_table`, about 30 s of solves).
Unlike :mod:`engine_model.runtime.lock` (an output that a second writer is refused), a cache
file is the same whoever builds it, so the second process waits rather than fails.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def build_lock(path: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``.<path name>.building`` for the block. ``fcntl.flock``: the
    kernel releases it when its process ends, however it ends, so a lock is never stale; the
    lock file itself stays (a few bytes, reused). Where there is no ``fcntl`` (Windows) the
    block runs unlocked: two processes may then build the same file, each writing it
    atomically (:mod:`engine_model.runtime.atomic`)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover
        yield
        return
    with open(path.with_name(f".{path.name}.building"), "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)
