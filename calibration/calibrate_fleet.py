"""Calibrate a whole fleet: units in parallel, on this machine or a Dask cluster, resumable.

    from calibration.calibrate_fleet import calibrate_fleet
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

Effects. ``effects`` (specification strings such as ``"customer_bleed:f0=0.02"`` or
:class:`engine_model.physics.effects.Effect` instances) are switched on in the engine model that
every unit is calibrated with, their parameters held at the given values (theta alone is estimated):
what ``hyprog discover`` found, put back into the model (``hyprog pipeline --augment``). Each
worker builds that model variant once (:func:`worker_model`); the effects, as canonical
specifications (:meth:`Effect.spec`), are part of the ``calibration`` metadata, so a resumed
run with other effects is refused like one with other settings.

Noise. With ``CalibrationSetup(noise="data")`` (``hyprog calibrate --noise data``) the
measurement covariance is the data's own noise: before any work, each sensor's std per
operating condition is estimated from every unit of ``data``, within units, early in life
(:func:`with_data_noise`), and stored in the setup (``noise_table``), so it is recorded in the
metadata and a resumed run with other data's noise is refused like one with other settings.

Tasks. The random-walk filters (``ukf``, ``ekf``) run many units in lockstep in one process
(:mod:`calibration.kalman`), so their units are split into one group per worker, balanced by
samples (longest-processing-time first) and cut into tasks of at most
:data:`LOCKSTEP_MAX_ROWS` samples; the windowed estimators (``mhe``, ``map_cycle``) get one
unit per task, longest first. A worker reads only its units from ``data`` (partition pruning),
so a large fleet is never shipped whole, and the client reads the units for the checks before
the work in groups of at most :data:`LOCKSTEP_MAX_ROWS` samples (:func:`read_groups`: one read
for a fleet of many short units such as C-MAPSS's); memory is bounded by the largest task or
group, not by the fleet.

Output (``out``): the paper's feature table, a parquet directory partitioned by unit in the
layout of :mod:`engine_model.datasets`, one unit written atomically as soon as it is done
(:func:`datasets.write_unit_part`: a unit is complete or absent, never an empty folder). The
metadata of the input is kept and a ``calibration`` entry added (method, options, setup,
hyprog version, and per unit the ``input`` it was computed from: rows, sensors used and the
fingerprint of its rows, :func:`engine_model.datasets.fingerprint.rows_fingerprint`).

Safety of the output:

- one writer per ``out`` (:func:`engine_model.runtime.output_lock`): a second run into the
  same ``out`` is refused while the first runs; a lock left by a killed run is taken over;
- ``out`` must be absent, empty or a feature table hyprog wrote (a raw dataset or a folder of
  other files is refused), and never the data it reads (the ownership rule,
  :mod:`engine_model.runtime.ownership`, kind :data:`FEATURE_TABLE`);
- resume: rerunning with the same ``out`` skips a unit only when *its own* stored metadata
  matches this run: the settings (method, options, setup) and the fingerprint of the unit's
  input rows; any difference is an error naming the unit and the setting or input that
  differs;
- only temporaries whose writer is gone are deleted
  (:func:`engine_model.runtime.remove_stale_temporaries`).

Before any work every unit to calibrate is read once and checked (:func:`series.prepare_unit`:
columns, numbers, NaN, envelope, duplicated time stamps; :func:`unit_check.check_units`: the
data against the model at theta = 0, units of measure), so bad input fails before anything
is written. After estimating, :func:`unit_check.check_result` adds warnings (a channel the
model cannot explain, theta_hat at a bound) to each unit's summary; parameters the units
could not observe are one warning for the fleet, not one per unit.

The executor (serial, worker processes or Dask) is the runtime's one
(:func:`engine_model.runtime.cluster.executor`), shared with ``hyprog simulate``. Worker
processes die with their parent (:func:`engine_model.runtime.cluster.watch_parent`): on Linux
through ``prctl(PR_SET_PDEATHSIG, SIGKILL)``, everywhere through a watchdog thread that ends
the worker when its parent process is gone, so a SIGKILL of ``hyprog calibrate --jobs J``
leaves no worker behind.
"""

from __future__ import annotations

import json
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from engine_model import datasets, runtime
from engine_model.datasets.fingerprint import rows_fingerprint
from engine_model.datasets.provenance import is_feature_table
from engine_model.runtime.cluster import executor
from engine_model.runtime.shared_model import process_model
from engine_model.validation import InputError

from .base import estimator_class
from .estimation_setup import CalibrationSetup
from .measurement_noise import noise_from_data
from .observability import UnobservableWarning
from .series import early_samples, prepare_unit, unit_label
from .unit_check import N_CHECK, bound_hits, check_result, check_units_many, summarise_unobservable

LOCKSTEP_METHODS = ("ukf", "ekf")
#: Most samples in one lockstep task (two DS02 units at 0.1 Hz, 80,000-130,000 samples each):
#: what a task holds in memory is bounded whatever the fleet's size (measured: peak RSS about
#: 1 GB for tasks of about 217,000 samples, and flat from task to task). A unit's estimate does
#: not depend on the units it runs beside (the pipeline's jobs / Dask tests compare files byte
#: for byte), so the cut changes no number.
LOCKSTEP_MAX_ROWS = 250_000
#: Samples checked against the model in one call before the work (:func:`check_inputs`).
CHECK_BATCH_POINTS = 8192


@dataclass
class FleetRun:
    """What :func:`calibrate_fleet` did. ``results``: unit -> :class:`CalibrationResult`
    (only when ``keep_results``); ``units``: unit -> summary dict (samples, seconds,
    non-converged, unobservable, warnings); ``skipped``: units already in ``out``;
    ``sensors``: the measured channels used; ``warnings``: every unit's warnings, then one
    line per set of parameters the units could not observe (also warned as
    :class:`~calibration.UnobservableWarning`; :func:`unit_check.summarise_unobservable`);
    ``effects``: the effects in the model (canonical specifications)."""

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
    sensors: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    effects: list = field(default_factory=list)
    metadata: dict = field(default_factory=dict)  # the data's, with the calibration record

    @property
    def samples(self) -> int:
        return int(sum(u["samples"] for u in self.units.values()))

    @property
    def samples_per_second(self) -> float:
        return self.samples / self.seconds if self.seconds > 0 else float("nan")


# ----------------------------------------------------------------------------- planning
def plan_tasks(lengths: dict, method: str, n_workers: int,
               max_rows: int | None = None) -> list[list]:
    """Units grouped into tasks (module docstring): balanced lockstep groups for the filters,
    single units, longest first, for the windowed estimators. A lockstep group is cut into
    tasks of at most ``max_rows`` samples [:data:`LOCKSTEP_MAX_ROWS`] (at least one unit each),
    so that a task's memory does not grow with the fleet."""
    max_rows = LOCKSTEP_MAX_ROWS if max_rows is None else max_rows
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
    tasks = []
    for g in groups:
        task, rows = [], 0
        for u in g:
            if task and rows + lengths[u] > max_rows:
                tasks.append(task)
                task, rows = [], 0
            task.append(u)
            rows += lengths[u]
        if task:
            tasks.append(task)
    return tasks


def setup_dict(setup: CalibrationSetup) -> dict:
    """The settings as the metadata stores them (JSON types: every tuple a list, at any
    depth, so that a stored entry compares equal to the same settings now)."""
    return json.loads(json.dumps(asdict(setup)))


def effect_specs(effects) -> list[str]:
    """``effects`` (specification strings or :class:`Effect` instances) as canonical
    specification strings (bad specifications are an :class:`InputError`)."""
    from engine_model.physics.effects import parse_effect_spec

    out = []
    for e in effects or ():
        out.append(parse_effect_spec(e).spec() if isinstance(e, str) else e.spec())
    return out


# ----------------------------------------------------------------------------- workers
def worker_model(threads: int | None, effects: Sequence[str] = ()):
    """The compiled model of this process for ``effects`` (canonical specifications, held at
    their values), built once per process
    (:func:`engine_model.runtime.shared_model.process_model`): the process-wide default model
    when there are no effects and ``threads`` is None, else a ``threads``-threaded variant
    (single-threaded in a worker)."""
    return process_model(effects, threads)


def unit_frames(df: pd.DataFrame) -> dict[int, pd.DataFrame]:
    """unit -> its rows, indexed by the 1-based rows of the user's file when ``df`` has
    :data:`datasets.SOURCE_ROW` (so that errors name them), else 0..n-1."""
    out = {}
    for u, g in df.groupby("unit", sort=False):
        if datasets.SOURCE_ROW in g.columns:
            g = g.set_index(datasets.SOURCE_ROW)
            g.index.name = None
        else:
            g = g.reset_index(drop=True)
        out[int(u)] = g
    return out


def run_task(task: dict) -> list[tuple]:
    """Calibrate one task's units (in a worker): returns ``[(unit, features, result)]``;
    ``result.diagnostics["warnings"]`` holds :func:`unit_check.check_result`'s warnings."""
    method, setup, options = task["method"], task["setup"], task["options"]
    frames = task.get("frames")
    if frames is None:
        df, _ = datasets.read_dataset(task["path"], units=task["units"], source_rows=True)
        by_unit = unit_frames(df)
        frames = [by_unit[u] for u in task["units"]]
    model = worker_model(task.get("threads"), task.get("effects", ()))
    est = estimator_class(method)(model=model, **options)
    # each unit's record names its unobservable parameters and the driver warns once for the
    # fleet, in the caller's process (a worker's warning would reach stderr as Python prints
    # it, and never the caller's report); no warning filter is touched, since tasks may run
    # in threads of the caller's process
    est.warn_unobservable = False
    results = est.estimate_many(frames, setup, task.get("source"))
    out = []
    for u, f, r in zip(task["units"], frames, results, strict=True):
        # the estimator checked the frame (prepare_unit); the warnings need only its label
        r.diagnostics["warnings"] = check_result(r, unit_label(f), setup)
        r.diagnostics["at_bound"] = bound_hits(r, setup)
        out.append((u, r.to_features(f), r))
    return out


# ----------------------------------------------------------------------------- driver
def _flat(d, prefix="") -> dict:
    """``{"setup": {"noise_scale": 1}}`` -> ``{"setup.noise_scale": 1}``."""
    out = {}
    for k, v in (d or {}).items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and v:
            out.update(_flat(v, key + "."))
        else:
            out[key] = v
    return out


def _first_difference(stored: dict, now: dict) -> str | None:
    """The first setting that differs between two calibration entries, in words."""
    a, b = _flat(stored), _flat(now)
    for k in sorted(set(a) | set(b)):
        if k in ("hyprog_version",) or k.startswith("input."):
            continue
        if a.get(k) != b.get(k):
            return f"{k} is {a.get(k)!r} there, {b.get(k)!r} now"
    return None


#: A feature table (the ownership rule's kind): written into unit by unit and resumed, never
#: replaced (:mod:`engine_model.runtime.ownership`).
FEATURE_TABLE = runtime.OutputKind("a feature table (hyprog calibrate's output)",
                                   directory=True, ours=is_feature_table, resumed=True)


def check_output_dir(out: Path, inputs=()) -> None:
    """``out`` is absent, empty or a feature table hyprog wrote, and none of ``inputs``
    (module docstring; the ownership rule)."""
    runtime.check_output(out, FEATURE_TABLE, inputs=inputs)


def input_record(df: pd.DataFrame, unit: int, sensors) -> dict:
    """What a feature table records of one unit's input: unit, rows, sensors used and the
    fingerprint of its rows (:func:`engine_model.datasets.fingerprint.rows_fingerprint`)."""
    return {"unit": int(unit), "rows": int(len(df)), "sensors": list(sensors),
            "sha256": rows_fingerprint(df)}


#: Setup keys of feature tables written by an earlier hyprog -> today's name (a resumed
#: calibration compares settings, not spellings).
LEGACY_SETUP_KEYS = {"drift_std_per_sqrt_h": "drift"}
#: Setup keys added later -> the value every table written before them was computed with.
ADDED_SETUP_KEYS = {"noise": "model", "noise_table": [], "model_error": 0.0}


def check_resume_unit(out: Path, unit: int, calib_meta: dict, record: dict | None) -> None:
    """The stored unit ``unit`` of ``out`` was computed with these settings and, unless
    ``record`` is None (a unit this run does not calibrate), from this input (its own
    metadata, not the first file's); InputError naming what differs."""
    part = out / f"unit={unit}" / datasets.PARQUET_PART
    stored = datasets.read_metadata(part).get("calibration") or {}
    setup = stored.get("setup")
    if isinstance(setup, dict):  # written before the field was renamed: the same setting
        setup = {LEGACY_SETUP_KEYS.get(k, k): v for k, v in setup.items()}
        stored = {**stored, "setup": {**ADDED_SETUP_KEYS, **setup}}
    diff = _first_difference({k: v for k, v in stored.items() if k != "input"},
                             {k: v for k, v in calib_meta.items() if k != "input"})
    if diff is not None:
        raise InputError(f"{out}: unit {unit} was calibrated with other settings ({diff});"
                         " choose another output or delete it")
    if record is None:
        return
    old = stored.get("input") or {}
    if old.get("sha256") != record["sha256"]:
        what = (f"{old.get('rows')} rows there, {record['rows']} now"
                if old.get("rows") != record["rows"] else "the same number of rows, other"
                " values")
        if not old:
            what = "no fingerprint of its input is stored (an older hyprog wrote it)"
        raise InputError(f"{out}: unit {unit} was calibrated from other input data ({what});"
                         " choose another output or delete it")
    if old.get("sensors") != record["sensors"]:
        raise InputError(f"{out}: unit {unit} was calibrated from sensors"
                         f" {', '.join(old.get('sensors') or [])}, now"
                         f" {', '.join(record['sensors'])}; choose another output or delete it")


def dataset_units(data, units: Sequence[int] | None = None) -> list[int]:
    """The units of the dataset ``data`` (those of ``units`` when given), without reading the
    fleet: a parquet directory by unit lists them in its partition names (and their row
    counts in the part files' footers); other layouts, or a partition without rows, are read
    for their keys only (so the reader's error names it). A unit that is not there is an
    InputError naming it."""
    import pyarrow.parquet as pq

    p = Path(data)
    parts = datasets.written_units(p) if p.is_dir() else []
    if parts and (units is None or set(units) <= set(parts)):
        chosen = sorted(parts if units is None else {int(u) for u in units})
        try:
            empty = [u for u in chosen if pq.read_metadata(
                p / f"unit={u}" / datasets.PARQUET_PART).num_rows == 0]
        except (OSError, ValueError):  # pyarrow's ArrowInvalid is a ValueError
            empty = chosen  # not readable as parquet: the reader says why
        if not empty:
            return chosen
    keys = datasets.read_dataset(data, units=units, columns=[])[0]
    return sorted(int(u) for u in keys["unit"].unique())


def unit_rows(data, units: Sequence[int]) -> dict[int, int] | None:
    """Each unit's row count from the part files' footers of a parquet directory by unit
    (nothing is read but the footers), or None for any other layout."""
    import pyarrow.parquet as pq

    p = Path(data)
    if not p.is_dir():
        return None
    try:
        return {int(u): pq.read_metadata(p / f"unit={u}" / datasets.PARQUET_PART).num_rows
                for u in units}
    except (OSError, ValueError):  # not readable as parquet: read unit by unit
        return None


def read_groups(units: Sequence[int], rows: dict[int, int] | None,
                max_rows: int = LOCKSTEP_MAX_ROWS) -> list[list[int]]:
    """``units`` in order, in consecutive groups of at most ``max_rows`` rows (at least one
    unit each); one unit a group when the row counts are unknown."""
    if rows is None:
        return [[u] for u in units]
    groups, size = [], 0
    for u in units:
        if groups and size + rows[u] <= max_rows:
            groups[-1].append(u)
            size += rows[u]
        else:
            groups.append([u])
            size = rows[u]
    return groups


def _units_of(data, df_all, lengths):
    """Yield ``(unit, frame)`` in unit order, with the rows of the user's file as the index: a
    path is read in groups of units of at most :data:`LOCKSTEP_MAX_ROWS` rows (one read for a
    fleet of many short units, one unit at a time for long ones)."""
    if df_all is not None:
        for u, f in unit_frames(df_all).items():
            yield u, f
        return
    units = sorted(lengths)
    for group in read_groups(units, unit_rows(data, units)):
        df, _ = datasets.read_dataset(data, units=group, source_rows=True)
        frames = unit_frames(df)
        for u in group:
            yield u, frames[u]


def calibrate_fleet(data, method: str = "ukf", setup: CalibrationSetup | None = None,
                    options: dict | None = None, units: Sequence[int] | None = None,
                    jobs: int = 1, scheduler=None, out=None, keep_results: bool = True,
                    progress: Callable[[int, int], None] | None = None,
                    check_data: bool = True, effects: Sequence = (),
                    model_source: dict | None = None) -> FleetRun:
    """Calibrate every unit of ``data`` (a dataset path, or a DataFrame with a ``unit``
    column) with ``method`` (module docstring). ``options`` go to the estimator's constructor;
    ``progress(done_units, total_units)`` is called as units finish. ``check_data`` compares
    every unit with the model before estimating (:func:`unit_check.check_units`).
    ``effects``: effects switched on in the model, held at their values (module
    docstring); ``model_source``: where they came from (an adapted model's
    :meth:`~calibration.adaptation.AdaptedModel.provenance`), recorded in the metadata as
    ``model_effects``."""
    setup = setup or CalibrationSetup()
    options = dict(options or {})
    # an unknown method or a bad option: a clear error before any work (no model built)
    estimator_class(method).check_options(options)
    estimator_class(method).check_setup(setup)
    specs = effect_specs(effects)  # a bad specification: clear error before any work
    if jobs < 1:
        raise InputError(f"jobs must be >= 1, got {jobs}")
    t0 = time.perf_counter()
    source = None
    if isinstance(data, pd.DataFrame):
        data = checked_frame(data)
        df_all, meta = data, {}
        if units is not None:
            missing = sorted(set(units) - set(df_all["unit"].unique()))
            if missing:
                raise InputError(f"data: unit(s) {missing} not found")
            df_all = df_all[df_all["unit"].isin(units)]
        lengths = df_all.groupby("unit").size().to_dict()
    else:
        source = str(data)
        meta = datasets.read_metadata(data)
        lengths = dict.fromkeys(dataset_units(data, units))  # rows: counted by check_inputs
        df_all = None
    lengths = {int(u): n for u, n in lengths.items()}
    setup = setup.for_dataset(meta)  # e.g. C-MAPSS's Ps30 out of the default sensors
    if not lengths:
        raise InputError(f"{source or 'data'}: no rows to calibrate")
    if setup.noise == "data" and not setup.noise_table:
        setup = with_data_noise(setup, data, source)

    calib_meta = {"method": method, "options": options, "setup": setup_dict(setup),
                  "hyprog_version": datasets.hyprog_version()}
    if specs:  # absent without effects: tables written before effects existed still resume
        calib_meta["effects"] = specs
    if model_source:
        calib_meta["model_effects"] = dict(model_source)
    run = FleetRun(method=method, setup=setup, options=options,
                   out=None if out is None else str(out), effects=specs,
                   metadata={**meta, "calibration": calib_meta})
    records = check_inputs(data, df_all, lengths, setup, source, check_data, specs)
    lengths = {u: records[u]["rows"] for u in lengths}
    run.sensors = list(records[min(records)]["sensors"])
    if out is None:
        return _calibrate(run, source, df_all, meta, calib_meta, lengths, records, None, jobs,
                          scheduler, keep_results, progress, t0)
    out = Path(out)
    inputs = () if source is None else (source,)
    check_output_dir(out, inputs)
    with runtime.output_lock(out):
        check_output_dir(out, inputs)  # again, now that no other writer can change it
        runtime.remove_stale_temporaries(out)
        done_before = set(datasets.written_units(out))
        for u in sorted(done_before):  # the folder holds one set of settings (and input)
            check_resume_unit(out, u, calib_meta, records.get(u))
        run.skipped = sorted(done_before & set(lengths))
        todo = {u: n for u, n in lengths.items() if u not in done_before}
        return _calibrate(run, source, df_all, meta, calib_meta, todo, records, out, jobs,
                          scheduler, keep_results, progress, t0)


def with_data_noise(setup: CalibrationSetup, data, source: str | None) -> CalibrationSetup:
    """``setup`` with :attr:`~CalibrationSetup.noise_table` estimated from every unit of
    ``data`` (a dataset path or the whole DataFrame; not only the units calibrated now, so
    that a calibration resumed or extended to other units uses the same noise): each sensor's
    std per operating condition, within units, early in life
    (:func:`calibration.measurement_noise.noise_from_data`). Without a choice of sensors, a
    sensor with one value per operating condition in the whole data (C-MAPSS's ``P2``: a
    function of the operating point, with no noise to estimate and nothing of the health) is
    left out (:attr:`~CalibrationSetup.exclude_sensors`)."""
    where = source or "data"
    df, meta = (data, {}) if isinstance(data, pd.DataFrame) else datasets.read_dataset(data)
    for c in ("condition", "cycle"):
        if c not in df.columns:
            raise InputError(f"{where}: no column {c!r}: the data's noise (--noise data) is "
                             "estimated per operating condition from early-life cycles (a "
                             "C-MAPSS import has both)")
    sensors = setup.for_dataset(meta).resolve_sensors(df.columns)
    if setup.sensors is None:  # one value per condition (C-MAPSS's P2): a function of the
        flat = [c for c in sensors  # operating point, no noise and nothing of the health
                if (df.groupby("condition")[c].nunique() <= 1).all()]
        setup = replace(setup, exclude_sensors=(*setup.exclude_sensors, *flat))
        sensors = tuple(c for c in sensors if c not in flat)
    table = noise_from_data(df, sensors, source=where)
    rows = tuple((int(c), ch, float(table.loc[c, ch])) for c in table.index for ch in sensors)
    return replace(setup, noise_table=rows)


def checked_frame(df: pd.DataFrame, source: str = "data") -> pd.DataFrame:
    """A table given as a DataFrame checked and sorted as a file's rows are when read
    (:func:`engine_model.datasets.schema.normalise_table`: integer units and cycles, numeric
    channels, rows by unit, cycle, t), so that the estimates do not depend on the order of
    its rows. A table without ``cycle`` is one series per unit, ordered by ``t``."""
    from engine_model.datasets.schema import normalise_table

    if "unit" not in df.columns:
        raise InputError(f"{source}: a 'unit' column is needed to calibrate a fleet")
    return normalise_table(df, source, keep_source_rows=False,
                           required=("unit", "cycle") if "cycle" in df.columns else ("unit",))


def check_labels(frame: pd.DataFrame, unit: int, source) -> None:
    """A unit's ``RUL`` (carried into the feature table, which the networks learn from) is
    finite and not negative where it is given: a NaN in one unit would leave a table whose
    units disagree on the column's type."""
    if "RUL" not in frame.columns:
        return
    v = pd.to_numeric(frame["RUL"], errors="coerce").to_numpy(float)
    bad = ~(np.isfinite(v) & (v >= 0))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        where = f"{source}: " if source else ""
        raise InputError(f"{where}unit {unit}, row {i + 1}: column RUL = {frame['RUL'].iloc[i]}"
                         " (the remaining useful life must be a finite number >= 0)")


def check_inputs(data, df_all, lengths, setup: CalibrationSetup, source,
                 check_data: bool = True, effects: Sequence[str] = ()) -> dict[int, dict]:
    """Read and check every unit once, before any output is touched (module docstring):
    :func:`series.prepare_unit` and, with ``check_data``, :func:`unit_check.check_units`
    (against the model with ``effects``). Returns unit -> its input record
    (:func:`input_record`).

    The model checks run in batches of units (:func:`unit_check.check_units_many`, one model
    call for up to :data:`CHECK_BATCH_POINTS` samples; only each unit's first
    :data:`unit_check.N_CHECK` samples are kept for it, so memory does not grow with the units'
    length). The order of the errors is that of one unit at a time: a unit whose data cannot
    be read is reported only after the units before it have been checked against the model."""
    records: dict[int, dict] = {}
    pending: list = []
    points = 0

    def flush():
        nonlocal points
        if pending:
            check_units_many(worker_model(None, effects), pending, setup, source)
        pending.clear()
        points = 0

    for u, frame in _units_of(data, df_all, lengths):
        try:
            series = prepare_unit(frame, setup, source)  # bad input: an error before any work
            check_labels(frame, u, source)
        except InputError:
            flush()
            raise
        records[u] = input_record(frame, u, series.sensors)
        if check_data:
            pending.append(early_samples(series, N_CHECK))
            points += len(pending[-1])
            if points >= CHECK_BATCH_POINTS:
                flush()
    flush()
    return records


def _calibrate(run, source, df_all, meta, calib_meta, todo, records, out, jobs, scheduler,
               keep_results, progress, t0) -> FleetRun:
    """Estimate the units of ``todo`` and write each to ``out`` as it is done."""
    setup, method, options = run.setup, run.method, run.options
    ex = executor(scheduler, jobs if todo else 1)  # serial, worker processes or Dask
    run.workers = ex.n_workers
    tasks = []
    for group in plan_tasks(todo, method, ex.n_workers) if todo else []:
        task = {"method": method, "setup": setup, "options": options, "units": group,
                "threads": ex.worker_threads, "source": source, "effects": run.effects}
        if df_all is None:
            task["path"] = source
        else:
            frames = unit_frames(df_all[df_all["unit"].isin(group)])
            task["frames"] = [frames[u] for u in group]
        tasks.append(task)
    done = 0
    with ex:  # closed after the work, aborted (workers ended) on an error or an interrupt
        for batch in ex.map(run_task, tasks):
            for u, feats, res in batch:
                if out is not None:
                    unit_meta = {**meta, "calibration": {**calib_meta, "input": records[u]}}
                    datasets.write_unit_part(feats, out, unit_meta)
                if keep_results:
                    run.results[u] = res
                    run.features[u] = feats
                d = res.diagnostics
                warns = list(d.get("warnings", []))
                run.units[u] = {"samples": len(feats), "seconds": float(d.get("seconds", 0)),
                                "n_nonconverged": int(d.get("n_nonconverged", 0)),
                                "unobservable": list(d.get("unobservable", [])),
                                "sensors": records[u]["sensors"], "warnings": warns,
                                "at_bound": list(d.get("at_bound", []))}
                done += 1
                if progress is not None:
                    progress(done, len(todo))
    # in unit order, not in the order the workers finished: the same run reports the same
    run.units = {u: run.units[u] for u in sorted(run.units)}
    run.warnings = [w for rec in run.units.values() for w in rec["warnings"]]
    for line in summarise_unobservable(run.units, run.setup.observability_max_std):
        run.warnings.append(line)
        warnings.warn(line, UnobservableWarning, stacklevel=3)  # at calibrate_fleet's caller
    run.seconds = time.perf_counter() - t0
    return run


def calibrate(data, method: str = "ukf", setup: CalibrationSetup | None = None,
              jobs: int = 1, effects: Sequence = (),
              progress: Callable[[int, int], None] | None = None) -> datasets.Dataset:
    """The library's one-call calibration: θ̂(t) of every unit of ``data`` (a
    :class:`~engine_model.datasets.Dataset`, a dataset path or a DataFrame) with ``method``,
    returned as the feature table (a Dataset: the data, ``<channel>_hat``, ``<q>_hat`` and
    ``<q>_hat_std`` per sample; its metadata the data's with the ``calibration`` record). The
    same numbers as ``hyprog calibrate``; :func:`calibrate_fleet` writes to disk, resumes and
    reports per unit::

        from calibration import calibrate
        features = calibrate(load_sample(), "ukf")  # engine_model.datasets.load_sample
    """
    frame = data.frame if isinstance(data, datasets.Dataset) else data
    run = calibrate_fleet(frame, method, setup, jobs=jobs, effects=effects, progress=progress)
    meta = dict(data.metadata) if isinstance(data, datasets.Dataset) else dict(run.metadata)
    meta["calibration"] = run.metadata["calibration"]
    source = data.source if isinstance(data, datasets.Dataset) else \
        "table" if isinstance(data, pd.DataFrame) else str(data)
    return datasets.Dataset(features_of(run), meta, source)


def features_of(run: FleetRun) -> pd.DataFrame:
    """The feature tables of a run kept in memory, concatenated by unit."""
    if not run.features:
        return pd.DataFrame()
    return pd.concat([run.features[u] for u in sorted(run.features)], ignore_index=True)


__all__ = ["FleetRun", "calibrate_fleet", "effect_specs", "features_of", "plan_tasks",
           "run_task", "worker_model"]
