"""The pipeline's stages, each a function ``(ctx, folder, ...) -> summary`` over the library.

=============  ==============================================================================
stage          what it does (and the library it calls)
=============  ==============================================================================
simulate       only with no DATA and ``[simulate] preset``: a fleet
               (``engine_model.simulator.fleet``);
               otherwise DATA, or the committed ``data_samples/tiny`` fleet
calibrate      theta_hat of every unit and the paper's feature table
               (:func:`calibration.calibrate_fleet.calibrate_fleet`; resumes unit by unit)
discover       the model-discrepancy loop and its report (:mod:`calibration.discrepancy`)
features       the table the networks learn from: the calibrated one, or with ``augment`` and
               effects found, a recalibration with the found effects in the model, held at
               their values (``calibrate_fleet(effects=...)``: resumable, checked); its
               development / test / conformal split and the input columns of every input set
               are resolved and checked here, before any training
train          one model per input set (:func:`prognostics.ensemble.fit`, saved with
               :mod:`prognostics.checkpoint`; a finished model is kept across an interruption)
evaluate       metrics per test unit and predictions (:meth:`RulModel.evaluate`)
=============  ==============================================================================

Every stage writes only inside its own folder (:mod:`.state`), through atomic writers.
simulate, calibrate and features stream the fleet unit by unit (never the whole fleet in
memory) and run on ``[run] jobs`` workers or the Dask cluster of ``[run] scheduler``
(``Context.cluster``), with the same result.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from data_samples import TINY_FLEET, sample_path
from engine_model.datasets.jsonable import jsonable
from engine_model.validation import InputError, collected_warnings

from .config import calibration_setup, train_config


def default_data() -> Path:
    """The packaged sample fleet (``data_samples/tiny``), the data of a run without DATA."""
    return sample_path(TINY_FLEET)


@dataclass
class Context:
    """What every stage sees: the output folder, the configuration and the console."""

    out: Path
    config: dict
    quiet: bool = False
    log: Callable[[str], None] = field(default=lambda msg: None)
    source: str = "data"
    config_source: str = "config"  # the TOML file, or "config" for the defaults
    _cluster: object = None

    @property
    def jobs(self) -> int:
        return self.config["run"]["jobs"]

    @property
    def adapted(self):
        """The adapted model of ``[calibrate] model_effects`` (:mod:`calibration.adaptation`),
        or None."""
        path = self.config["calibrate"]["model_effects"]
        if not path:
            return None
        from calibration.adaptation import load_adapted

        return load_adapted(path)

    @property
    def cluster(self):
        """The Dask cluster of ``[run] scheduler`` (:func:`engine_model.runtime.cluster.connect`),
        connected on first use (a resumed run whose stages are done starts none); None
        without a scheduler."""
        scheduler = self.config["run"]["scheduler"]
        if scheduler is None:
            return None
        if self._cluster is None:
            from engine_model.runtime.cluster import connect

            self.log(f"  Dask: {scheduler}")
            self._cluster = connect(scheduler, self.jobs)
        return self._cluster

    def close(self) -> None:
        """Close the Dask cluster if this run started one."""
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None

    def rel(self, path: Path) -> str:
        """``path`` relative to the output folder (markers stay valid if it is moved)."""
        return Path(path).relative_to(self.out).as_posix()

    def path(self, rel: str) -> Path:
        return self.out / rel


# ----------------------------------------------------------------------------- helpers
def split_units(present, metadata: dict, data_cfg: dict, source: str) -> dict:
    """Development, test and conformal units: the config's, else the metadata's, else every
    unit but the last for development and the last for test."""
    present = sorted(int(u) for u in present)
    meta = metadata or {}
    test = data_cfg["test_units"]
    how = "config"
    if test is None:
        test = [u for u in (meta.get("test_units") or []) if u in present]
        how = "metadata" if test else "last unit"
        if not test:
            test = present[-1:]
    dev = data_cfg["dev_units"]
    if dev is None:
        dev = [u for u in (meta.get("dev_units") or []) if u in present and u not in test]
        if not dev:
            dev = [u for u in present if u not in test]
    for name, group in (("dev_units", dev), ("test_units", test),
                        ("conformal_units", data_cfg["conformal_units"])):
        missing = [u for u in group if u not in present]
        if missing:
            raise InputError(f"{source}: [data] {name}: unit(s) "
                             f"{', '.join(map(str, missing))} not in the data")
    both = sorted(set(dev) & set(test))
    if both:
        raise InputError(f"{source}: unit(s) {', '.join(map(str, both))} are both development "
                         "and test units")
    conf = list(data_cfg["conformal_units"])
    if set(conf) - set(dev):
        raise InputError(f"{source}: [data] conformal_units must be development units")
    if not [u for u in dev if u not in conf]:
        raise InputError(f"{source}: no development unit left to train on")
    if not test:
        raise InputError(f"{source}: no test unit")
    return {"dev": sorted(dev), "test": sorted(test), "conformal": sorted(conf), "how": how}


def check_data_against_config(ctx: Context, data: Path) -> None:
    """What the configuration asks of the data, checked before any stage runs, naming the
    configuration file and key: the units of ``[data]`` are in the data, the split leaves a
    development and a test unit, and every ``[train] inputs`` resolves
    (:func:`prognostics.features.resolve_inputs`) against the columns the feature table will
    have: the data's, a channel or parameter with ``_hat`` / ``_hat_std`` (calibrate adds
    them) and the flight table's health coordinates (the flight models add them)."""
    from engine_model.channels import THETA_NAMES, UNITS
    from engine_model.datasets import read_columns, read_dataset, read_metadata
    from prognostics.choices import LIBRARY_MODELS
    from prognostics.features import HEALTH_STEMS, resolve_inputs

    source = ctx.config_source
    dc = ctx.config["data"]
    present = sorted(int(u) for u in read_dataset(data, columns=["unit"])[0]["unit"].unique())
    missing = [u for u in dc["units"] or () if u not in present]
    if missing:
        raise InputError(f"{source}: [data] units: unit(s) {', '.join(map(str, missing))} "
                         f"not in {data} (its units: {', '.join(map(str, present))})")
    chosen = [u for u in present if dc["units"] is None or u in dc["units"]]
    try:
        split = split_units(chosen, read_metadata(data), dc, source)
    except InputError as e:
        raise InputError(f"{e} ({data}: unit(s) {', '.join(map(str, chosen))})") from None
    fit = [u for u in split["dev"] if u not in split["conformal"]]
    outside = [u for u in ctx.config["train"]["val_units"] or () if u not in fit]
    if outside:
        raise InputError(f"{source}: [train] val_units: unit(s) {', '.join(map(str, outside))}"
                         f" are not training units of {data} (those: "
                         f"{', '.join(map(str, fit))})")
    hats = [f"{c}_hat" for c in UNITS] + [f"{q}_hat_std" for q in THETA_NAMES]
    flights = [f"{h}{s}" for h in HEALTH_STEMS for s in ("", "_hat")] + ["HI_hat_rel"] + \
        [f"{q}{s}" for q in THETA_NAMES for s in ("_hat_rel", "_mode")]
    columns = [*read_columns(data), *hats, *flights]  # the feature (and flight) table's
    model = ctx.config["train"]["model"]
    for spec in ctx.config["train"]["inputs"]:
        try:
            cols = resolve_inputs(spec, columns, "the feature table")
        except InputError as e:
            raise InputError(f"{source}: [train] inputs {spec!r} is not an input set, a group "
                             f"or columns the feature table will have ({e})") from None
        if model in LIBRARY_MODELS and len(cols) != 1:
            raise InputError(f"{source}: [train] inputs {spec!r}: the {model} model reads one "
                             f"health index (inputs = [\"HI_hat_rel\"]), not {len(cols)} columns")


def _read(path, units=None):
    from engine_model.datasets import read_dataset

    return read_dataset(path, units=units)


def _round_trip(o):
    """Round trip through JSON (:func:`engine_model.datasets.jsonable.jsonable`): int keys
    become strings, numpy scalars Python numbers, NaN None (what a resumed run reads back from
    the marker)."""
    return json.loads(json.dumps(jsonable(o)))


# ----------------------------------------------------------------------------- stages
def simulate(ctx: Context, folder: Path) -> dict:
    """A fleet of ``[simulate] preset`` into ``folder/fleet``."""
    from engine_model.physics.effects import parse_effect_spec
    from engine_model.simulator.fleet import simulate as run

    c = ctx.config["simulate"]
    effects = [parse_effect_spec(e) for e in c["effects"]]
    t0 = time.perf_counter()
    path, rep = run(c["preset"], out=folder / "fleet", units=ctx.config["data"]["units"],
                    rate_hz=c["rate_hz"], seed=c["seed"], effects=effects,
                    scheduler=ctx.cluster, jobs=ctx.jobs)
    return {"data": ctx.rel(path), "preset": c["preset"], "seconds": time.perf_counter() - t0,
            "rows": rep.total_rows, "dropped": int(sum(rep.dropped.values()))}


def _calibrate_into(ctx: Context, table: Path, data: Path, effects=()):
    """:func:`calibration.calibrate_fleet.calibrate_fleet` of every unit into ``table`` (resumes
    unit by unit; ``[run]`` workers or Dask cluster), with ``effects`` in the model."""
    from calibration.calibrate_fleet import calibrate_fleet

    c = ctx.config["calibrate"]
    progress = None
    if not ctx.quiet:
        def progress(done, total):
            ctx.log(f"  calibrated {done} of {total} unit(s)")
    adapted = ctx.adapted
    setup = calibration_setup(ctx.config)
    effects = [*(adapted.effects if adapted else ()), *effects]
    if c["model_error"] == "consistent":
        from calibration.consistency import with_consistent_model_error

        setup, nis = with_consistent_model_error(setup, data, effects,
                                                 ctx.config["data"]["units"])
        if not ctx.quiet:
            ctx.log(f"  model error {setup.model_error:.4g}: mean NIS per channel {nis:.3g}")
    return calibrate_fleet(data, c["method"], setup, {},
                           ctx.config["data"]["units"], ctx.jobs, ctx.cluster, table,
                           keep_results=False, progress=progress,
                           effects=effects,
                           model_source=adapted.provenance() if adapted else None)


def calibrate(ctx: Context, folder: Path, data: Path) -> dict:
    """theta_hat of every unit into ``folder/features`` (a rerun resumes unit by unit)."""
    from calibration.unit_check import fleet_warnings

    c = ctx.config["calibrate"]
    res = _calibrate_into(ctx, folder / "features", data)
    return _round_trip({"table": ctx.rel(folder / "features"), "method": c["method"],
                        "params": list(res.setup.params), "sensors": list(res.sensors),
                        "model_error": res.setup.model_error,
                        "samples": res.samples, "seconds": res.seconds,
                        "units": {u: {"samples": v["samples"],
                                      "n_nonconverged": v["n_nonconverged"]}
                                  for u, v in sorted(res.units.items())},
                        "resumed_units": res.skipped,
                        "warnings": fleet_warnings(list(res.warnings), res.units)})


def discover(ctx: Context, folder: Path, data: Path, calibrated: dict) -> dict:
    """The discrepancy loop on the data; its report in ``folder/report``. Its R and sensors
    are the calibrate stage's (``calibrated``: its summary): the same noise, the model error
    that stage used (found there when ``model_error = "consistent"``), the data's noise table
    recomputed from the same rows, the dataset's not-physical channels left out."""
    from dataclasses import replace

    from calibration.consistency import with_measured_noise
    from calibration.discrepancy import DiscoverOptions
    from calibration.discrepancy import discover as run
    from calibration.discrepancy.candidates import check_names
    from calibration.discrepancy.discovery_report import report_dict, write_report
    from engine_model.runtime.shared_model import default_model

    c = ctx.config["discover"]
    cal = calibration_setup(ctx.config)
    setup = replace(cal, model_error=calibrated.get("model_error", cal.model_error))
    opts = DiscoverOptions(method=c["method"],
                           candidates=None if c["candidates"] is None else tuple(c["candidates"]),
                           alpha=c["alpha"], max_effects=c["max_effects"], drift=c["drift"],
                           n_draws=c["n_draws"], seed=ctx.config["pipeline"]["seed"])
    check_names(opts.candidates)
    df, meta = _read(data, ctx.config["data"]["units"])
    setup = with_measured_noise(setup, data).for_dataset(meta)
    frames = [g for _, g in df.groupby("unit", sort=True)]
    say = None if ctx.quiet else (lambda msg: ctx.log(f"  {msg}"))
    adapted = ctx.adapted
    result = run(frames, setup, opts, base_model=default_model(), source=str(data),
                 progress=say, fixed_effects=tuple(adapted.effects) if adapted else ())
    write_report(result, folder / "report")
    r = report_dict(result)
    return _round_trip({"report": ctx.rel(folder / "report"), "verdict": r["verdict"],
                        "found": r["found"], "ambiguous": r["ambiguous"], "unknown": r["unknown"],
                        "before": r["before"], "after": r["after"],
                        "theta_error": r["theta_error"], "drift": r["drift"],
                        "noise": {k: v for k, v in r["noise"].items() if k != "channels"},
                        "rejected": r["rejected"],
                        "candidates": len(r["diagnostics"]["candidates"]),
                        "seconds": r["diagnostics"]["seconds"]})


def features(ctx: Context, folder: Path, data: Path, calibrated: dict,
             discovered: dict | None) -> dict:
    """The feature table to learn from, its split and the inputs of every input set."""
    from engine_model.datasets import read_columns, read_metadata

    specs = []
    if ctx.config["discover"]["augment"] and discovered and discovered["found"]:
        specs = [f["spec"] for f in discovered["found"]]
        ctx.log(f"  recalibrating with {', '.join(specs)}")
        table = folder / "features"
        _calibrate_into(ctx, table, data, specs)  # the found effects held at their values
    else:
        table = ctx.path(calibrated["table"])
    meta = read_metadata(table)
    columns = read_columns(table)
    rows = unit_rows(table)
    split = split_units(list(rows), meta, ctx.config["data"], str(table))
    inputs = {s: _input_columns(ctx, table, meta, columns, s, split)
              for s in ctx.config["train"]["inputs"]}
    return _round_trip({"table": ctx.rel(table), "effects": specs, "split": split,
                        "inputs": inputs, "rows": int(sum(rows.values()))})


def _input_columns(ctx: Context, table: Path, meta: dict, columns: list[str], spec: str,
                   split: dict) -> list[str]:
    """The input columns of the input set ``spec``: the feature table's, or, for a model that
    reads the flight table (a flight model, or health groups on one row per cycle), those
    of the flight table of the first development unit (its columns are every unit's)."""
    from prognostics.baseline import health_effects
    from prognostics.features import resolve_inputs, sort_table, unobservable_columns
    from prognostics.training import rows_for

    cfg = train_config(ctx.config, spec, split)
    if not cfg.reads_flights:
        return resolve_inputs(spec, columns, str(table))
    df, _ = _read(table, units=[split["dev"][0]])
    flights = rows_for(cfg, sort_table(df), health_effects(meta), str(table))
    return resolve_inputs(spec, list(flights.columns), str(table),
                          unobservable_columns(flights))


def unit_rows(table: Path) -> dict[int, int]:
    """unit -> rows of a feature table (a parquet directory by unit, as calibrate writes it),
    from the part files' footers: no column of the fleet is read."""
    import pyarrow.parquet as pq

    from engine_model.datasets import PARQUET_PART, written_units

    return {u: pq.read_metadata(table / f"unit={u}" / PARQUET_PART).num_rows
            for u in written_units(table)}


def train(ctx: Context, folder: Path, feats: dict) -> dict:
    """One model per input set into ``folder/<inputs>`` (a finished one is kept)."""
    from prognostics.checkpoint import load_model, save_model
    from prognostics.ensemble import fit
    from prognostics.outputs import write_json

    c, seed = ctx.config["train"], ctx.config["pipeline"]["seed"]
    split = feats["split"]
    table = ctx.path(feats["table"])
    df, meta = _read(table)
    out = {}
    for inputs in c["inputs"]:
        target, info = folder / inputs, folder / f"{inputs}.json"
        if (target / "model.json").is_file() and info.is_file():
            ctx.log(f"  {inputs}: kept from the interrupted run")
            model, seconds = load_model(target), json.loads(info.read_text())["seconds"]
        else:
            ctx.log(f"  training {c['model'].upper()} on {inputs} ({len(feats['inputs'][inputs])}"
                    " inputs)")
            cfg = train_config(ctx.config, inputs, split)
            t0 = time.perf_counter()
            model = fit(df, meta, cfg, seeds=range(seed, seed + c["ensemble"]),
                        quiet=ctx.quiet, source=str(table))
            seconds = time.perf_counter() - t0
            save_model(model, target)
            write_json(info, {"seconds": seconds})
        out[inputs] = {
            "model": ctx.rel(target), "seconds": seconds, "window": model.window,
            "parameters": model.parameters,
            "members": [{"seed": m.seed, "best_epoch": m.best_epoch, "epochs_run": len(m.history),
                         "history": [{k: h[k] for k in ("epoch", "train_loss", "val_loss")}
                                     for h in m.history]} for m in model.members],
            "conformal": None if model.conformal is None else model.conformal.to_dict()}
    return _round_trip(out)


def evaluate(ctx: Context, folder: Path, feats: dict, trained: dict) -> dict:
    """Metrics of every model on the test units; predictions in ``folder``."""
    from prognostics.checkpoint import load_model
    from prognostics.outputs import write_table

    table = ctx.path(feats["table"])
    df, _ = _read(table)
    test = feats["split"]["test"]
    out = {}
    for inputs, t in trained.items():
        model = load_model(ctx.path(t["model"]))
        with collected_warnings() as said:  # kept with the stage's result
            metrics, pred = model.evaluate(df, test, ctx.config["train"]["device"],
                                           source=str(table))
        path = folder / f"{inputs}.predictions.parquet"
        write_table(path, pred)
        out[inputs] = {"metrics": metrics, "predictions": ctx.rel(path), "warnings": said}
    return _round_trip(out)
