"""Critical sections: short steps that a termination signal must not split.

Taking a lock file is two steps (create it, note that this process holds it), and so is
replacing a folder (move the old one aside, move the new one in). The CLI turns SIGINT and
SIGTERM into exceptions (``cli.common.terminate_as_exit``), which Python raises between any two
bytecodes; one raised between the two steps would leave a lock nobody releases or an output
under no name. Inside :func:`critical_section` the CLI's handler only records the signal; it
raises it again just after the section ends (its watcher resends the signal every 20 ms), so
the step either has not started or is complete when the exception arrives. Sections must stay
short (no computation inside)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

_DEPTH = [0]


@contextmanager
def critical_section() -> Iterator[None]:
    """Defer a termination signal's exception to the end of the block (module docstring)."""
    _DEPTH[0] += 1
    try:
        yield
    finally:
        _DEPTH[0] -= 1


def in_critical_section() -> bool:
    """True inside :func:`critical_section` (read by the CLI's signal handler)."""
    return _DEPTH[0] > 0
