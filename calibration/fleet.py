"""Calibrate a whole fleet: units in parallel, on this machine or a Dask cluster, resumable.

    from calibration.fleet import calibrate_fleet
    run = calibrate_fleet("data_samples/tiny", method="ukf", out="features", jobs=2)

Units are independent, so they are spread over workers:

- ``jobs=1`` (default) runs in this process with the process-wide model
  (:func:`base.default_model`).
- ``jobs=J > 1`` starts ``J`` worker processes (``spawn``), each with its own single-threaded
  compiled model (loaded from the disk cache, about 2 s).
- ``scheduler="tcp://host:8786"`` (or a ``distributed.Client``) sends the work to a Dask
  cluster; the workers must be able to import hyprog and, when ``data`` is a path, read it
  (a shared file system). Without a cluster, ``scheduler="local"`` starts a
  ``distributed.LocalCluster`` of ``jobs`` single-threaded worker processes.

Tasks. The random-walk filters (``ukf``, ``ekf``) run many units in lockstep in one process
(:mod:`calibration.kalman`), so their units are split into one group per worker, balanced by
samples (longest-processing-time first); the windowed estimators (``mhe``, ``map_cycle``) get
one unit per task, longest first. A worker reads only its units from ``data`` (partition
pruning), so a large fleet is never shipped whole.

Output (``out``): the paper's feature table, a parquet directory partitioned by unit in the
layout of :mod:`engine_model.datasets`, one unit written atomically as soon as it is done
(:func:`datasets.write_unit_part`). Rerunning with the same ``out`` skips units already
written (resumable); an interrupted run leaves complete units and nothing half-written. The
metadata of the input is kept and a ``calibration`` entry added (method, options, setup,
hyprog version); resuming into a directory written with other settings is refused.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from engine_model import datasets
from engine_model.validation import InputError

from .base import estimator_class
from .setup import CalibrationSetup

LOCKSTEP_METHODS = ("ukf", "ekf")


@dataclass
class FleetRun:
    """What :func:`calibrate_fleet` did. ``results``: unit -> :class:`CalibrationResult`
    (only when ``keep_results``); ``units``: unit -> summary dict (samples, seconds,
    non-converged, unobservable); ``skipped``: units already in ``out``."""

    method: str
    setup: CalibrationSetup
    options: dict
    results: dict = field(default_factory=dict)
    features: dict = field(default_factory=dict)
    units: dict = field(default_factory=dict)
    skipped: list = field(default_factory=list)
    seconds: float = 0.0
    out: str | None = None
    workers: int = 1

    @property
    def samples(self) -> int:
        return int(sum(u["samples"] for u in self.units.values()))

    @property
    def samples_per_second(self) -> float:
        return self.samples / self.seconds if self.seconds > 0 else float("nan")


# ----------------------------------------------------------------------------- planning
def plan_tasks(lengths: dict, method: str, n_workers: int) -> list[list]:
    """Units grouped into tasks (module docstring): balanced lockstep groups for the filters,
    single units, longest first, for the windowed estimators."""
    order = sorted(lengths, key=lambda u: (-lengths[u], u))
    if method not in LOCKSTEP_METHODS:
        return [[u] for u in order]
    n = max(1, min(n_workers, len(order)))
    groups: list[list] = [[] for _ in range(n)]
    load = np.zeros(n)
    for u in order:
        j = int(np.argmin(load))
        groups[j].append(u)
        load[j] += lengths[u]
    return [g for g in groups if g]


def setup_dict(setup: CalibrationSetup) -> dict:
    d = asdict(setup)
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}


# ----------------------------------------------------------------------------- workers
_WORKER_MODEL = {}


def _worker_model(threads: int | None):
    """The compiled model of this worker process (single-threaded in parallel runs)."""
    if threads is None:
        from .base import default_model

        return default_model()
    if threads not in _WORKER_MODEL:
        from engine_model import EngineModel

        _WORKER_MODEL[threads] = EngineModel(n_threads=threads)
    return _WORKER_MODEL[threads]


def run_task(task: dict) -> list[tuple]:
    """Calibrate one task's units (in a worker): returns ``[(unit, features, result)]``."""
    method, setup, options = task["method"], task["setup"], task["options"]
    frames = task.get("frames")
    if frames is None:
        df, _ = datasets.read_dataset(task["path"], units=task["units"])
        frames = [g.reset_index(drop=True) for _, g in df.groupby("unit", sort=False)]
        by_unit = {int(f["unit"].iloc[0]): f for f in frames}
        frames = [by_unit[u] for u in task["units"]]
    model = _worker_model(task.get("threads"))
    est = estimator_class(method)(model=model, **options)
    results = est.estimate_many(frames, setup, task.get("source"))
    out = []
    for u, f, r in zip(task["units"], frames, results, strict=True):
        out.append((u, r.to_features(f), r))
    return out


# ----------------------------------------------------------------------------- executors
class _Serial:
    def __init__(self, threads=None):
        self.threads = threads

    def run(self, tasks):
        for t in tasks:
            yield run_task(t)

    def close(self):
        pass


class _Processes:
    def __init__(self, jobs):
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        self.ex = ProcessPoolExecutor(max_workers=jobs, mp_context=mp.get_context("spawn"))

    def run(self, tasks):
        from concurrent.futures import as_completed

        futures = [self.ex.submit(run_task, t) for t in tasks]
        try:
            for f in as_completed(futures):
                yield f.result()
        finally:
            for f in futures:
                f.cancel()

    def close(self):
        self.ex.shutdown(wait=True, cancel_futures=True)


class _Dask:
    def __init__(self, scheduler, jobs):
        try:
            from distributed import Client, LocalCluster
        except ModuleNotFoundError:  # pragma: no cover - a dependency of hyprog
            raise InputError("--scheduler needs the 'distributed' package") from None
        self.cluster = None
        if isinstance(scheduler, str) and scheduler == "local":
            self.cluster = LocalCluster(n_workers=max(1, jobs), threads_per_worker=1,
                                        processes=True, dashboard_address=None)
            self.client = Client(self.cluster)
        elif isinstance(scheduler, str):
            try:
                self.client = Client(scheduler, timeout="20s")
            except OSError as e:
                raise InputError(f"Dask scheduler {scheduler}: cannot connect ({e})") from None
        else:
            self.client = scheduler  # a Client
        self.n_workers = max(1, sum(self.client.nthreads().values()))

    def run(self, tasks):
        from distributed import as_completed

        futures = self.client.map(run_task, tasks, pure=False)
        try:
            for f in as_completed(futures):
                yield f.result()
        finally:
            self.client.cancel(futures)

    def close(self):
        if self.cluster is not None:
            self.client.close()
            self.cluster.close()


# ----------------------------------------------------------------------------- driver
def _check_resume(out: Path, calib_meta: dict) -> list[int]:
    done = datasets.written_units(out)
    if not done:
        return []
    old = datasets.read_metadata(out).get("calibration", {})
    diff = [k for k in ("method", "options", "setup") if old.get(k) != calib_meta.get(k)]
    if diff:
        raise InputError(f"{out}: holds units calibrated with other settings "
                         f"({', '.join(diff)} differ: method {old.get('method')!r}); choose "
                         "another output or delete it")
    return done


def calibrate_fleet(data, method: str = "ukf", setup: CalibrationSetup | None = None,
                    options: dict | None = None, units: Sequence[int] | None = None,
                    jobs: int = 1, scheduler=None, out=None, keep_results: bool = True,
                    progress: Callable[[int, int], None] | None = None) -> FleetRun:
    """Calibrate every unit of ``data`` (a dataset path, or a DataFrame with a ``unit``
    column) with ``method`` (module docstring). ``options`` go to the estimator's constructor;
    ``progress(done_units, total_units)`` is called as units finish."""
    setup = setup or CalibrationSetup()
    options = dict(options or {})
    estimator_class(method)  # unknown method: clear error before any work
    if jobs < 1:
        raise InputError(f"jobs must be >= 1, got {jobs}")
    t0 = time.perf_counter()
    source = None
    if isinstance(data, pd.DataFrame):
        df_all, meta = data, {}
        if "unit" not in df_all.columns:
            raise InputError("data: a 'unit' column is needed to calibrate a fleet")
        if units is not None:
            missing = sorted(set(units) - set(df_all["unit"].unique()))
            if missing:
                raise InputError(f"data: unit(s) {missing} not found")
            df_all = df_all[df_all["unit"].isin(units)]
        lengths = df_all.groupby("unit").size().to_dict()
    else:
        source = str(data)
        meta = datasets.read_metadata(data)
        keys = datasets.read_dataset(data, units=units, columns=[])[0]
        lengths = keys.groupby("unit").size().to_dict()
        df_all = None
    lengths = {int(u): int(n) for u, n in lengths.items()}
    if not lengths:
        raise InputError(f"{source or 'data'}: no rows to calibrate")

    calib_meta = {"method": method, "options": options, "setup": setup_dict(setup),
                  "hyprog_version": datasets.hyprog_version()}
    run = FleetRun(method=method, setup=setup, options=options,
                   out=None if out is None else str(out))
    out_meta = {**meta, "calibration": calib_meta}
    todo = dict(lengths)
    if out is not None:
        out = Path(out)
        if out.exists() and not out.is_dir():
            raise InputError(f"{out}: exists and is not a directory")
        datasets.remove_stale_temporaries(out)
        run.skipped = [u for u in _check_resume(out, calib_meta) if u in todo]
        for u in run.skipped:
            todo.pop(u)

    if scheduler is not None:
        ex = _Dask(scheduler, jobs)
        n_workers, threads = ex.n_workers, 1
    elif jobs > 1:
        ex = _Processes(jobs)
        n_workers, threads = jobs, 1
    else:
        ex = _Serial()
        n_workers, threads = 1, None
    run.workers = n_workers
    tasks = []
    for group in plan_tasks(todo, method, n_workers) if todo else []:
        task = {"method": method, "setup": setup, "options": options, "units": group,
                "threads": threads, "source": source}
        if df_all is None:
            task["path"] = source
        else:
            task["frames"] = [df_all[df_all["unit"] == u].reset_index(drop=True) for u in group]
        tasks.append(task)
    done = 0
    try:
        for batch in ex.run(tasks):
            for u, feats, res in batch:
                if out is not None:
                    datasets.write_unit_part(feats, out, out_meta)
                if keep_results:
                    run.results[u] = res
                    run.features[u] = feats
                d = res.diagnostics
                run.units[u] = {"samples": len(feats), "seconds": float(d.get("seconds", 0)),
                                "n_nonconverged": int(d.get("n_nonconverged", 0)),
                                "unobservable": list(d.get("unobservable", []))}
                done += 1
                if progress is not None:
                    progress(done, len(todo))
    finally:
        ex.close()
    run.seconds = time.perf_counter() - t0
    return run


def features_of(run: FleetRun) -> pd.DataFrame:
    """The feature tables of a run kept in memory, concatenated by unit."""
    if not run.features:
        return pd.DataFrame()
    return pd.concat([run.features[u] for u in sorted(run.features)], ignore_index=True)


__all__ = ["FleetRun", "calibrate_fleet", "features_of", "plan_tasks", "run_task"]
