"""Critical sections: short steps that a termination signal must not split.

Taking a lock file is two steps (create it, note that this process holds it), and so is
replacing a folder (move the old one aside, move the new one in). The CLI turns SIGINT and
SIGTERM into exceptions (``cli.common.terminate_as_exit``), which Python raises between any two
bytecodes; one raised between the two steps would leave a lock nobody releases or an output
under no name.

:func:`critical_section` defers those signals itself, whatever handler is installed: on
entering (the outermost section, in the main thread, where Python runs signal handlers) it
replaces the SIGINT and SIGTERM handlers with one that only records the signal; on leaving it
puts the previous handlers back and raises the recorded signal again (``signal.raise_signal``),
so the previous handler (the CLI's, or Python's default KeyboardInterrupt) runs just after the
step, which has then either not started or is complete. Nobody needs to ask whether a section
is running. In another thread a section defers nothing: signal handlers, and the exceptions
they raise, only ever run in the main thread. Sections must stay short (no computation
inside).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

#: the signals a section defers
DEFERRED = (signal.SIGINT, signal.SIGTERM)

_DEPTH = [0]


@contextmanager
def critical_section() -> Iterator[None]:
    """Defer SIGINT and SIGTERM to the end of the block (module docstring)."""
    if threading.current_thread() is not threading.main_thread():
        yield  # no handler runs in this thread
        return
    outermost = _DEPTH[0] == 0
    pending: list[int] = []

    def record(signum, frame):
        if signum not in pending:
            pending.append(signum)

    previous = {sig: signal.signal(sig, record) for sig in DEFERRED} if outermost else {}
    _DEPTH[0] += 1
    try:
        yield
    finally:
        _DEPTH[0] -= 1
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        for sig in pending:
            signal.raise_signal(sig)  # the previous handler runs now, after the step


def in_critical_section() -> bool:
    """True inside :func:`critical_section` in the main thread."""
    return _DEPTH[0] > 0
