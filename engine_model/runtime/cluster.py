"""The one executor of the fleet commands (simulate, calibrate, the pipeline): tasks run in
this process, on a pool of local worker processes or on a Dask cluster, behind one interface;
a worker builds its engine model once (:func:`.shared_model.process_model`).

    from engine_model.runtime.cluster import executor
    with executor(scheduler, jobs) as ex:            # Serial, ProcessPool or Cluster
        for result in ex.map(fn, tasks):             # as each task completes
            ...

The interface (:class:`Executor`): ``map(fn, tasks)`` yields ``fn(task)`` for every task as
each completes (in order for :class:`Serial`); ``n_workers`` (how many tasks run at once, for
planning) and ``worker_threads`` (the threads of a worker's engine model: None in this
process, which uses its own model, 1 in a worker); ``close()`` after the work, ``abort()`` on an
error or an interrupt (what is queued is cancelled, the workers end). As a context manager it
closes on success and aborts on an exception. :func:`executor` picks one:

- no ``scheduler`` and ``jobs == 1``: :class:`Serial`, in this process;
- no ``scheduler`` and ``jobs > 1``: :class:`ProcessPool` of ``jobs`` processes;
- ``scheduler`` (below): :class:`Cluster`.

Dask (:func:`connect`):

- ``"local"``: a ``distributed.LocalCluster`` of ``jobs`` single-threaded worker processes
  on this machine (closed with the :class:`Cluster`);
- ``"tcp://host:port"`` (any scheduler address): a client of that cluster; the workers must
  import hyprog (the same version) and read the paths the tasks name (a shared file system);
- a ``distributed.Client``: used as it is, not closed.

The tasks are pure functions of their arguments (their seeds travel with them), so where a task
runs does not change its result; the client writes what comes back.

:class:`ProcessPool`: ``jobs`` ``spawn`` worker processes that die with their parent
(:func:`watch_parent`: ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` on Linux, and everywhere a watchdog
thread that ends the worker once its parent is gone), so a SIGKILL of a command leaves no
worker behind.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Protocol

from engine_model.validation import InputError

CONNECT_TIMEOUT = "20s"

PR_SET_PDEATHSIG = 1  # linux/prctl.h
WATCH_PERIOD_S = 0.5


def watch_parent(parent_pid: int) -> None:
    """Make this (worker) process die with its parent ``parent_pid`` (module docstring):
    ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` on Linux, and a daemon thread that polls
    ``os.getppid()`` every ``WATCH_PERIOD_S`` and ends the process once the parent is gone
    (the child is re-parented then)."""
    import signal
    import sys

    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # pragma: no cover - no libc prctl
            pass
    if os.getppid() != parent_pid:  # the parent died before the signal was armed
        os._exit(1)

    def watch():
        while True:
            time.sleep(WATCH_PERIOD_S)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="hyprog-parent-watch", daemon=True).start()


class Executor(Protocol):
    """What runs a fleet command's tasks (module docstring)."""

    n_workers: int
    worker_threads: int | None

    def map(self, fn: Callable, tasks: Iterable) -> Iterator: ...

    def close(self) -> None: ...

    def abort(self) -> None: ...

    def __enter__(self): ...

    def __exit__(self, kind, *exc): ...


class _Lifetime:
    """Closed after the work, aborted on an exception (module docstring)."""

    def abort(self) -> None:
        self.close()

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, kind, *exc):
        if kind is None:
            self.close()
        else:
            self.abort()


class Serial(_Lifetime):
    """The tasks one after the other in this process, in their order."""

    n_workers = 1
    worker_threads = None

    def map(self, fn: Callable, tasks: Iterable) -> Iterator:
        for t in tasks:
            yield fn(t)


class ProcessPool(_Lifetime):
    """``jobs`` worker processes (``spawn``) that die with this process (module docstring)."""

    worker_threads = 1

    def __init__(self, jobs: int):
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        self.n_workers = jobs
        self.ex = ProcessPoolExecutor(max_workers=jobs, mp_context=mp.get_context("spawn"),
                                      initializer=watch_parent, initargs=(os.getpid(),))

    def map(self, fn: Callable, tasks: Iterable) -> Iterator:
        """``fn(task)`` for every task, yielded as each completes; what is queued is
        cancelled when the caller stops."""
        from concurrent.futures import as_completed

        futures = [self.ex.submit(fn, t) for t in tasks]
        try:
            for f in as_completed(futures):
                yield f.result()
        finally:
            for f in futures:
                f.cancel()

    def close(self) -> None:
        self.ex.shutdown(wait=True, cancel_futures=True)

    def abort(self) -> None:
        """Stop now (an interrupt or an error): cancel what is queued, end the workers."""
        procs = list((getattr(self.ex, "_processes", None) or {}).values())
        self.ex.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(timeout=5)


class Cluster(_Lifetime):
    """A Dask client and what to close with it (see :func:`connect`)."""

    worker_threads = 1

    def __init__(self, client, cluster=None, owned: bool = True):
        self.client = client
        self.cluster = cluster
        self.owned = owned

    @property
    def n_workers(self) -> int:
        """Worker threads of the cluster (at least 1)."""
        return max(1, sum(self.client.nthreads().values()))

    def map(self, fn: Callable, tasks: Iterable) -> Iterator:
        """``fn(task)`` for every task on the cluster, yielded as each completes; what is not
        yet done is cancelled when the caller stops (an error, an interrupt)."""
        from distributed import as_completed

        futures = self.client.map(fn, list(tasks), pure=False)
        try:
            for f in as_completed(futures):
                result = f.result()
                f.release()  # the worker may drop it: the caller holds it now
                yield result
        finally:
            self.client.cancel(futures)

    def close(self) -> None:
        if self.owned:
            self.client.close()
            if self.cluster is not None:
                self.cluster.close()


def _probe(address: str) -> None:
    """A TCP address whose port refuses connections is an InputError at once (the Dask
    client would retry it for :data:`CONNECT_TIMEOUT`)."""
    import socket
    from urllib.parse import urlsplit

    if not address.startswith("tcp://"):
        return
    try:
        parts = urlsplit(address)
        host, port = parts.hostname, parts.port
    except ValueError:
        return
    if not host or not port:
        return
    try:
        with socket.create_connection((host, port), timeout=5):
            pass
    except ConnectionRefusedError as e:
        raise InputError(f"Dask scheduler {address}: cannot connect ({e.strerror or e}: "
                         "is `dask scheduler` running there?)") from None
    except OSError:
        return  # unresolved, unreachable or slow: the client says so after its timeout


def check_scheduler(scheduler) -> None:
    """What can be told of a scheduler address without connecting (before any output is
    made): an empty one is an error."""
    if isinstance(scheduler, str) and not scheduler.strip():
        raise InputError("--scheduler: empty address; give tcp://HOST:PORT or 'local'")


def connect(scheduler, jobs: int = 1) -> Cluster:
    """A :class:`Cluster` for ``scheduler`` (module docstring); an address that does not answer
    is an :class:`InputError` naming it."""
    try:
        from distributed import Client, LocalCluster
    except ModuleNotFoundError:  # pragma: no cover - a dependency of hyprog
        raise InputError("--scheduler needs the 'distributed' package") from None
    if isinstance(scheduler, Cluster):
        return Cluster(scheduler.client, owned=False)
    if not isinstance(scheduler, str):
        return Cluster(scheduler, owned=False)  # a Client
    if scheduler == "local":
        cluster = LocalCluster(n_workers=max(1, int(jobs)), threads_per_worker=1,
                               processes=True, dashboard_address=None)
        return Cluster(Client(cluster), cluster)
    check_scheduler(scheduler)
    _probe(scheduler)
    try:
        client = Client(scheduler, timeout=CONNECT_TIMEOUT)
    except (OSError, TimeoutError) as e:
        raise InputError(f"Dask scheduler {scheduler}: cannot connect ({e})") from None
    except ValueError as e:  # not an address
        raise InputError(f"Dask scheduler {scheduler}: not a scheduler address ({e}); give "
                         "tcp://HOST:PORT or 'local'") from None
    return Cluster(client)


def executor(scheduler=None, jobs: int = 1) -> Executor:
    """The executor for ``scheduler`` (an address, ``"local"``, a ``distributed.Client`` or a
    :class:`Cluster`; None: this machine) and ``jobs`` (module docstring)."""
    if scheduler is not None:
        return connect(scheduler, jobs)
    return ProcessPool(jobs) if jobs > 1 else Serial()


__all__ = ["Cluster", "Executor", "ProcessPool", "Serial", "connect", "executor", "watch_parent"]
