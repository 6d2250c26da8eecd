"""Fleet simulator: N-CMAPSS-like run-to-failure fleets from the engine model.

For every unit (all random draws from ``SeedSequence([seed, unit])``, so a unit's data do not
depend on which other units are simulated):

1. a pool of routes of the unit's flight class and one flight per cycle drawn from it
   (:mod:`flight_profiles`: take-off, climb, cruise, descent at 1 Hz, day temperature offset);
2. the unit's health trajectory (:mod:`degradation`): initial wear, linear normal degradation,
   a smooth onset of abnormal degradation at ``t_s`` in the failure mode's parameters, end of
   life when the health index reaches 0; wear accumulates with the flights' severity;
3. the "truth" steady state of every sample with ``theta`` of its cycle and the optional
   physical effects switched on (:mod:`effect_library`), warm-started along the series; series
   effects (spool and thermal dynamics) are applied flight by flight;
4. measurement noise on the 16 measured channels (:mod:`sensor_noise`).

The table has one row per recorded sample with the N-CMAPSS names (``unit cycle t Fc hs RUL``,
``w``, ``x_s``, ``x_v`` with ``phi``, the true ``theta``); ``x_v`` and ``theta`` are the
simulator's truth (as in N-CMAPSS, where they are released for development). Metadata record
the preset, seed, sample rate, effects (with parameters), splits and each unit's specification;
the calibration and discrepancy code never read the effects entry (that is how data with an
undeclared effect are made).

A steady-state point that does not converge is never written as if valid: the sample is
dropped and counted in the returned :class:`SimulationReport` (and a warning is issued).

Memory: with ``out`` the units are written one at a time as they are simulated (parquet), so
the fleet is never in memory at once (the h5 format and ``out=None`` do hold it all).

Dask: ``scheduler`` (an address, ``"local"`` or a ``distributed.Client``,
:mod:`engine_model.runtime.cluster`) simulates one unit per task on the cluster's workers (each
builds its own single-threaded model of the truth once); the client writes each unit as it comes
back with the same writer. A unit's draws depend only on ``(seed, unit)``, so the fleet is the one
simulated locally, byte for byte.

Interruption and resume: the parquet directory (or h5 file) appears under its name only when
complete. A parquet fleet is built unit by unit in a hidden folder next to it
(:func:`partial_dir`, keyed on the settings), each unit written atomically; an interrupted run
(Ctrl-C, SIGTERM, SIGKILL) leaves that folder, and the next run with the same settings keeps
its complete units and simulates only the others (a unit's data depend only on ``(seed,
unit)``, so the fleet is the uninterrupted run's, byte for byte). Hidden temporaries of a
killed writer are deleted by the next run once their writer is gone.
"""

from __future__ import annotations

import json
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd

from engine_model.channels import (
    OUTPUT_NAMES,
    PAPER_THETA,
    THETA_NAMES,
    W_NAMES,
    XS_NAMES,
    XV_NAMES,
)
from engine_model.runtime.atomic import atomic_output, remove_path, swap_into_place
from engine_model.runtime.cluster import check_scheduler, executor
from engine_model.runtime.ownership import OWNED_FILE
from engine_model.runtime.shared_model import process_model
from engine_model.validation import InputError, check_seed

from . import degradation, flight_profiles, sensor_noise


@dataclass(frozen=True)
class UnitSpec:
    """One unit of a fleet preset.

    ``eol`` and ``t_s`` are (low, high) cycle ranges (equal bounds fix the value);
    ``max_cruise_alt_ft`` / ``max_duration_h`` restrict its routes (shorter, lower flights).
    """

    unit: int
    Fc: int
    mode: str
    eol: tuple[int, int]
    t_s: tuple[int, int]
    split: str = "dev"
    max_cruise_alt_ft: float | None = None
    max_duration_h: float | None = None
    n_routes: int = 8


@dataclass(frozen=True)
class Preset:
    name: str
    description: str
    units: tuple[UnitSpec, ...]
    rate_hz: float = 0.1
    record: str = "above_10kft"
    wear_params: tuple | None = None  # initial wear + normal degradation (None: all ten)


def _ds02_units() -> tuple[UnitSpec, ...]:
    """The paper's DS02 fleet (Table of units): EOL and t_s as published; flight classes and
    route caps chosen so that each unit's recorded time per cycle is close to the paper's
    m_i / EOL (about 3.1 h above 10,000 ft for units 2-20 and 11, 0.6 h for unit 14, 1.8 h
    for unit 15)."""
    hpt, both = "HPT", "HPT+LPT"
    return (
        UnitSpec(2, 2, hpt, (75, 75), (17, 17)),
        UnitSpec(5, 2, hpt, (89, 89), (17, 17)),
        UnitSpec(10, 2, hpt, (82, 82), (17, 17)),
        UnitSpec(16, 2, both, (63, 63), (16, 16)),
        UnitSpec(18, 2, both, (71, 71), (17, 17)),
        UnitSpec(20, 2, both, (66, 66), (17, 17)),
        UnitSpec(11, 2, both, (59, 59), (19, 19), split="test"),
        UnitSpec(14, 1, both, (76, 76), (36, 36), split="test", max_cruise_alt_ft=24000.0,
                 max_duration_h=1.4),
        UnitSpec(15, 1, both, (67, 67), (24, 24), split="test", max_cruise_alt_ft=30000.0,
                 max_duration_h=2.6),
    )


STUDY_DEV, STUDY_TEST = 24, 6


def _ds02_study_units() -> tuple[UnitSpec, ...]:
    """A ``ds02``-like fleet for the many-fleet study of issue 30: 24 development and 6 test
    units, every unit's end of life drawn from 55-95 cycles and its onset from 14-38 (the
    range of ``ds02``'s published values, 59-89 and 16-36), so that every seed gives another
    fleet; failure modes alternate HPT / HPT+LPT (``ds02``'s two), and every third unit flies
    ``ds02``'s shorter, lower class (flight class 1, cruise at most 24,000 ft, at most 1.4 h:
    unit 14's), in development and test alike."""
    units = []
    for i in range(STUDY_DEV + STUDY_TEST):
        short = i % 3 == 2
        units.append(UnitSpec(
            i + 1, 1 if short else 2, ("HPT", "HPT+LPT")[i % 2], (55, 95), (14, 38),
            split="test" if i >= STUDY_DEV else "dev",
            max_cruise_alt_ft=24000.0 if short else None, max_duration_h=1.4 if short else None))
    return tuple(units)


PRESETS: dict[str, Preset] = {
    "ds02": Preset(
        "ds02", "the paper's N-CMAPSS DS02 fleet: 6 development units (HPT, HPT+LPT modes), "
        "3 test units (HPT+LPT; 14 and 15 fly shorter, lower flights)", _ds02_units(),
        wear_params=PAPER_THETA),
    "ds02-study": Preset(
        "ds02-study", "ds02-like fleets for a study (24 development, 6 test units; end of life "
        "and onset drawn per seed, modes HPT and HPT+LPT, a third on short, low flights)",
        _ds02_study_units(), wear_params=PAPER_THETA),
    "tiny": Preset(
        "tiny", "four units with short flights and short lives, for tests and data_samples/",
        (UnitSpec(1, 1, "HPT", (10, 12), (4, 5), max_duration_h=1.3, n_routes=3),
         UnitSpec(2, 1, "HPT+LPT", (10, 12), (4, 5), max_duration_h=1.3, n_routes=3),
         UnitSpec(3, 1, "HPT+LPT", (9, 11), (4, 5), max_duration_h=1.3, n_routes=3),
         UnitSpec(4, 1, "HPT+LPT", (9, 11), (4, 5), split="test", max_duration_h=1.3,
                  n_routes=3)),
        wear_params=PAPER_THETA),
}


@dataclass
class SimulationReport:
    """What :func:`simulate` did: rows per unit, dropped (non-converged) samples, timings."""

    rows: dict = field(default_factory=dict)
    dropped: dict = field(default_factory=dict)
    eol: dict = field(default_factory=dict)
    t_s: dict = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def total_rows(self) -> int:
        return int(sum(self.rows.values()))


def get_preset(name: str) -> Preset:
    if name not in PRESETS:
        raise InputError(f"unknown preset {name!r} (known: {', '.join(sorted(PRESETS))})")
    return PRESETS[name]


def select_units(preset: Preset, units: Sequence[int] | None) -> tuple[UnitSpec, ...]:
    if units is None:
        return preset.units
    known = {u.unit: u for u in preset.units}
    bad = [u for u in units if u not in known]
    if bad:
        raise InputError(f"preset {preset.name}: no unit {', '.join(map(str, bad))}"
                         f" (units: {', '.join(str(u) for u in known)})")
    return tuple(known[u] for u in units)


# ------------------------------------------------------------------------------ one unit
def _unit_rngs(seed: int, unit: int):
    ss = np.random.SeedSequence([int(seed), int(unit)])
    route_ss, flight_ss, health_ss, noise_ss = ss.spawn(4)
    return (int(route_ss.generate_state(1)[0]), int(flight_ss.generate_state(1)[0]),
            np.random.default_rng(health_ss), np.random.default_rng(noise_ss))


def _flights(spec: UnitSpec, n: int, route_seed: int, flight_seed: int, rate_hz: float,
             record: str):
    pool = flight_profiles.route_pool(spec.Fc, spec.n_routes, seed=route_seed,
                                      max_cruise_alt_ft=spec.max_cruise_alt_ft,
                                      max_duration_h=spec.max_duration_h)
    return flight_profiles.fly_unit(pool, n, flight_seed, rate_hz=rate_hz, record=record)


def simulate_unit(model, spec: UnitSpec, seed: int = 0, rate_hz: float = 0.1,
                  record: str = "above_10kft", noise_scale: float = 1.0,
                  p_default: np.ndarray | None = None, series_effects=(), wear_params=None):
    """Simulate one unit to failure with the truth ``model``; returns (DataFrame, info)."""
    route_seed, flight_seed, rng_health, rng_noise = _unit_rngs(seed, spec.unit)
    n_max = int(spec.eol[1])
    flights = _flights(spec, n_max, route_seed, flight_seed, rate_hz, record)
    # damage per cycle in reference flight hours: severity per hour x flight hours
    severity = np.array([f.severity * f.duration_h for f in flights])
    severity = severity / np.mean(severity)
    health = degradation.simulate_health(model, spec.mode, eol=spec.eol, t_s=spec.t_s,
                                         rng=rng_health, severity=severity,
                                         wear_params=wear_params)
    eol = int(health.eol)
    flights = flights[:eol]
    sizes = np.array([len(f.t) for f in flights])
    cycle = np.repeat(np.arange(1, eol + 1), sizes)
    w = np.concatenate([f.w for f in flights])
    t = np.concatenate([f.t for f in flights])
    theta = health.theta[cycle - 1]
    p = _p_rows(model, p_default, cycle)
    res = model.solve_series(w, theta, p)
    y = model.outputs_at(res.x, w, theta, p)
    out = pd.DataFrame(y, columns=list(OUTPUT_NAMES))
    keep = res.converged
    if series_effects:  # e.g. dynamics: flight by flight, on the time series of outputs
        # of the converged samples only (a dropped sample's outputs must not reach the
        # samples after it through a lag; the lag integrates over the gap it leaves)
        out["t"] = t
        starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
        for s0, n in zip(starts, sizes, strict=True):
            rows = s0 + np.flatnonzero(keep[s0:s0 + n])
            if not len(rows):
                continue
            part = out.iloc[rows]
            for eff in series_effects:
                part = eff.apply_series(part)
            out.loc[part.index, part.columns] = part
        out = out.drop(columns="t")
    df = pd.DataFrame({
        "unit": np.full(len(w), spec.unit, np.int64), "cycle": cycle.astype(np.int64),
        "t": t, "Fc": np.full(len(w), spec.Fc, np.int64),
        "hs": health.hs[cycle - 1].astype(np.int64), "RUL": (eol - cycle).astype(np.int64),
    })
    for j, name in enumerate(W_NAMES):
        df[name] = w[:, j]
    for name in (*XS_NAMES, *XV_NAMES, "phi"):
        df[name] = out[name].to_numpy()
    for j, name in enumerate(THETA_NAMES):
        df[name] = theta[:, j]
    df = sensor_noise.add_noise(df, rng_noise, scale=noise_scale)
    dropped = int((~keep).sum())
    if dropped:
        warnings.warn(f"unit {spec.unit}: {dropped} samples did not converge and were dropped",
                      stacklevel=2)
        df = df[keep].reset_index(drop=True)
    info = {"eol": eol, "t_s": int(health.t_s), "dropped": dropped, "mode": spec.mode}
    return df, info


def _p_rows(model, p_default, cycle):
    """Effect parameters per row: the chosen values, with context parameters (``cycle``)
    filled from the sample's cycle."""
    names = list(model.param_names)
    if not names:
        return None
    p = np.tile(np.asarray(p_default if p_default is not None else model.p_default, float),
                (len(cycle), 1))
    for j, name in enumerate(names):
        if name.endswith(".cycle"):
            p[:, j] = cycle
    return p


# ------------------------------------------------------------------------------ a fleet
def check_rate(rate_hz) -> float:
    """The sample rate [Hz] as a float; it must be 1 Hz divided by an integer (the flights are
    generated at 1 Hz and decimated)."""
    rate = float(rate_hz)
    if (not np.isfinite(rate) or rate <= 0 or rate > 1.0
            or abs(1.0 / rate - round(1.0 / rate)) > 1e-9):
        raise InputError(f"rate_hz {rate:g}: the sample rate must be 1 Hz divided by an "
                         "integer (1, 0.5, 0.1, ...)")
    return rate


def check_effects(effects) -> None:
    """Every effect switched on injects something: one whose parameters are all at their
    neutral defaults would leave the fleet without it, silently (an error naming its typical
    size instead)."""
    from engine_model.physics.effect_base import EffectSet

    EffectSet(effects)  # an effect given twice: one line, before anything is written
    for e in effects:
        if e.is_neutral():
            raise InputError(f"effect {e.spec()}: every parameter is at its neutral default, "
                             "so the fleet would contain no effect; give its size, e.g. "
                             f"{e.typical_spec()}")


# ------------------------------------------------------------------------------ Dask tasks
def truth_model(effect_specs: Sequence[str] = (), threads: int | None = 1):
    """The truth model of this process for the steady effects among ``effect_specs``
    (specification strings), built once per process (:func:`shared_model.process_model`; a Dask
    worker's is single-threaded)."""
    from engine_model.physics.effects import parse_effect_spec, split_series_effects

    steady, _ = split_series_effects([parse_effect_spec(e) for e in effect_specs])
    return process_model([e.spec() for e in steady], threads)


def simulate_unit_task(task: dict, model=None) -> tuple:
    """One unit of a fleet (on whichever executor runs it): ``task`` holds the unit's
    :class:`UnitSpec`, the seed, rate, record, noise scale, wear parameters, the effects as
    specifications and the threads of the truth model (None: this process's own); ``model``
    replaces that truth model (only in the calling process). Returns ``(unit, DataFrame,
    info)``; a warning about dropped samples is left to the caller, which says it once
    wherever the unit ran."""
    import warnings as _warnings

    from engine_model.physics.effects import parse_effect_spec, split_series_effects

    truth = model if model is not None else truth_model(task["effects"], task.get("threads", 1))
    _, series = split_series_effects([parse_effect_spec(e) for e in task["effects"]])
    with _warnings.catch_warnings():  # the client warns about dropped samples
        _warnings.simplefilter("ignore")
        df, info = simulate_unit(truth, task["spec"], task["seed"], task["rate"],
                                 task["record"], task["noise_scale"],
                                 np.asarray(truth.p_default, float), series,
                                 task["wear_params"])
    return task["spec"].unit, df, info


def simulate(preset: str | Preset = "tiny", out: str | Path | None = None,
             units: Sequence[int] | None = None, rate_hz: float | None = None, seed: int = 0,
             effects: Sequence = (), record: str | None = None, fmt: str | None = None,
             noise_scale: float = 1.0, model=None,
             progress: Callable[[int, int, int], None] | None = None, overwrite: bool = False,
             scheduler=None, jobs: int = 1):
    """Simulate a fleet preset. With ``out`` the fleet is written (parquet unit by unit,
    resumable; or N-CMAPSS h5) and ``(path, report)`` is returned; without, ``(df, metadata,
    report)``. ``effects``: :class:`effects.Effect` instances switched on in the truth. An
    existing ``out`` is replaced only when hyprog wrote it, or with ``overwrite``
    (:mod:`engine_model.runtime.ownership`). ``scheduler``: simulate the units on a Dask
    cluster (module docstring; ``jobs`` workers for ``"local"``); without it, ``jobs > 1``
    worker processes (:class:`cluster.ProcessPool`), one unit per task; ``model`` is used only
    in this process (neither); all three run through the one executor
    (:func:`engine_model.runtime.cluster.executor`). ``fmt``: ``"parquet"`` or ``"h5"``;
    None follows ``out``'s suffix (``.h5`` -> h5, else parquet) and one that contradicts it
    is refused (:func:`engine_model.datasets.output_format`). ``seed`` must be an integer
    >= 0 (:func:`engine_model.validation.check_seed`)."""
    seed = check_seed(seed)
    p = get_preset(preset) if isinstance(preset, str) else preset
    check_effects(effects)
    specs = select_units(p, units)
    rate = check_rate(rate_hz if rate_hz is not None else p.rate_hz)
    rec = record or p.record
    meta = fleet_metadata(p, specs, rate, rec, seed, effects, noise_scale)
    check_scheduler(scheduler)
    if out is not None:
        from engine_model.datasets import output_format

        fmt = output_format(out, fmt)
        _check_out(Path(out), fmt, overwrite)  # before any work
    local_model = model if scheduler is None else None  # a model is used only here

    def produce(todo):
        names = [e.spec() for e in effects]
        n = 1 if local_model is not None else max(1, min(jobs, len(todo)))
        with executor(scheduler, n) as ex:  # serial, worker processes or Dask
            tasks = [{"spec": s, "seed": int(seed), "rate": rate, "record": rec,
                      "noise_scale": float(noise_scale), "wear_params": p.wear_params,
                      "effects": names, "threads": ex.worker_threads} for s in todo]
            fn = simulate_unit_task if local_model is None else \
                partial(simulate_unit_task, model=local_model)
            for unit, df, info in ex.map(fn, tasks):
                if info["dropped"]:
                    warnings.warn(f"unit {unit}: {info['dropped']} samples did not converge "
                                  "and were dropped", stacklevel=3)
                yield unit, df, info

    return _write(produce, specs, meta, out, fmt, progress, overwrite)


def fleet_metadata(p: Preset, specs, rate: float, rec: str, seed: int, effects,
                   noise_scale: float) -> dict:
    """The dataset metadata of a simulated fleet (module docstring)."""
    return {
        "preset": p.name, "seed": int(seed), "sample_rate_hz": rate, "record": rec,
        "effects": [e.to_dict() for e in effects],
        "dev_units": [s.unit for s in specs if s.split == "dev"],
        "test_units": [s.unit for s in specs if s.split == "test"],
        "units": {str(s.unit): {k: v for k, v in asdict(s).items() if k != "unit"}
                  for s in specs},
        "noise_scale": float(noise_scale),
        "wear_params": list(p.wear_params) if p.wear_params is not None else list(THETA_NAMES),
    }


def _check_out(out: Path, fmt: str, overwrite: bool) -> None:
    from engine_model import datasets

    if fmt not in ("parquet", "h5"):
        raise InputError(f"--format {fmt}: expected parquet or h5")
    datasets.check_dataset_output(out, directory=fmt == "parquet", overwrite=overwrite)


# ------------------------------------------------------------------------------ resume
PARTIAL_MARK = ".partial-"
UNIT_INFO_DIR = ".units"


def partial_dir(out: Path, meta: dict) -> Path:
    """The hidden folder ``.<name>.partial-<key>`` next to ``out`` where a parquet fleet is
    built unit by unit; ``key`` hashes the metadata (preset, units, seed, rate, effects, ...)
    and the hyprog version, so a rerun with the same settings continues it and one with other
    settings does not."""
    import hashlib

    from engine_model.datasets import hyprog_version
    from engine_model.datasets.jsonable import json_default

    body = json.dumps({"meta": meta, "hyprog": hyprog_version()}, sort_keys=True,
                      default=json_default)
    return out.parent / f".{out.name}{PARTIAL_MARK}{hashlib.sha256(body.encode()).hexdigest()[:16]}"


def _done_units(stage: Path) -> dict[int, dict]:
    """unit -> its info (eol, t_s, dropped, rows) for the units complete in ``stage`` (part
    file and info both written)."""
    from engine_model.datasets import written_units

    done = {}
    for u in written_units(stage):
        try:
            done[u] = json.loads((stage / UNIT_INFO_DIR / f"{u}.json").read_text())
        except (OSError, json.JSONDecodeError):
            continue  # the info was not written: simulate the unit again
    return done


def _write_info(stage: Path, unit: int, info: dict) -> None:
    with atomic_output(stage / UNIT_INFO_DIR / f"{unit}.json", OWNED_FILE) as tmp:
        tmp.write_text(json.dumps(info))


def _write(produce, specs, meta, out, fmt, progress, overwrite):
    """Simulate the units ``produce(specs)`` yields (``(unit, df, info)``, in any order) and
    write them to ``out``. Parquet: each unit as it comes into :func:`partial_dir` (units
    already there from an interrupted run with the same settings are kept, not simulated
    again), renamed to ``out`` when the last is written; h5 and ``out=None``: the fleet in
    the preset's order."""
    from engine_model import datasets, runtime

    report = SimulationReport()
    t0 = time.perf_counter()
    order = {s.unit: k for k, s in enumerate(specs)}

    def note(unit, info):
        for d in ("rows", "dropped", "eol", "t_s"):
            getattr(report, d)[unit] = info[d]

    def finish(rep):
        rep.seconds = time.perf_counter() - t0
        for d in ("rows", "dropped", "eol", "t_s"):  # the preset's order, whatever came first
            setattr(rep, d, {u: getattr(rep, d)[u] for u in sorted(order, key=order.get)})
        return rep

    def run(todo, start=0):
        for k, (unit, df, info) in enumerate(produce(todo), start):
            info = {**info, "rows": len(df)}
            note(unit, info)
            if progress is not None:
                progress(k + 1, len(specs), len(df))
            yield unit, df, info

    if out is None or fmt == "h5":
        df = pd.concat([df for _, df, _ in sorted(run(specs), key=lambda r: order[r[0]])],
                       ignore_index=True)
        if out is None:
            return df, meta, finish(report)
        out = Path(out)
        runtime.remove_stale_temporaries_of(out)
        datasets.write_ncmapss_h5(df, out, meta, overwrite=overwrite)
        return out, finish(report)
    out = Path(out)
    runtime.remove_stale_temporaries_of(out)
    stage = partial_dir(out, meta)
    for other in out.parent.glob(f".{out.name}{PARTIAL_MARK}*"):
        if other != stage:  # an interrupted run with other settings: not continued
            remove_path(other)
    stage.mkdir(parents=True, exist_ok=True)
    runtime.remove_stale_temporaries(stage)
    done = {u: i for u, i in _done_units(stage).items() if u in order}
    for u, info in done.items():
        note(u, info)
    todo = [s for s in specs if s.unit not in done]
    for unit, df, info in run(todo, len(done)):
        datasets.write_unit_part(df, stage, meta)
        _write_info(stage, unit, info)
    remove_path(stage / UNIT_INFO_DIR)
    _check_out(out, fmt, overwrite)  # again: what is there now may be replaced
    swap_into_place(stage, out)
    return out, finish(report)
