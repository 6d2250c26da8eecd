"""``run_pipeline``: every stage in order, each skipped when its output exists for the same
configuration and input (:mod:`.state`), under one lock on the output folder.

The output folder ``OUT`` is absent, empty, or one this function wrote before (it holds
``pipeline.json``); anything else is refused, as is the current directory or a parent of it
and a folder that is, holds or lies inside DATA or the configuration file (the ownership
rule, :mod:`engine_model.runtime.ownership`, kind :data:`PIPELINE_FOLDER`). One run at a time
writes into it (:func:`engine_model.runtime.output_lock`). Every file is written atomically
and every stage marks itself done last, so an interrupted run (Ctrl-C, SIGTERM) leaves no
half-written file; a SIGKILL can leave hidden temporaries, a folder's backup and the lock,
which the next run cleans (:func:`engine_model.runtime.remove_stale_temporaries`: a dead
writer's temporaries deleted, a backup put back; the lock's process is gone). The next run
redoes only what was not finished and gives the numbers an uninterrupted run gives.

Dependencies (what a stage's fingerprint holds besides its own table of the config):

==========  ===================================================================
calibrate   the data, ``[data] units``
discover    the data, ``[data] units``, ``[calibrate]`` (its setup), the seed
features    calibrate; with ``augment``: discover
train       features, ``[data]`` (the split), the seed
evaluate    train, features
report      every stage above
==========  ===================================================================

So a changed option reruns its stage and the stages that read its output, and only those.
The ``[run]`` table (workers, Dask scheduler) is in no fingerprint: it does not change a
result, so a run resumed with other workers or on a cluster skips what is done.
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from pathlib import Path

from engine_model.datasets.fingerprint import files_fingerprint
from engine_model.runtime import (
    OutputKind,
    check_output,
    output_lock,
    remove_stale_temporaries,
)
from engine_model.validation import InputError
from prognostics.outputs import write_json

from . import pipeline_report as report
from . import stages, state
from .config import results_config
from .state import stage_fingerprint

MARK = "pipeline.json"
FORMAT = "hyprog-pipeline"
STAGES = ("simulate", "calibrate", "discover", "features", "train", "evaluate", "report")


def is_pipeline_folder(path: Path) -> bool:
    """``path`` is a folder :func:`run_pipeline` wrote (its ``pipeline.json`` says so)."""
    try:
        return json.loads((path / MARK).read_text()).get("format") == FORMAT
    except (OSError, json.JSONDecodeError, AttributeError):
        return False


#: The pipeline's output folder (the ownership rule's kind): written into and resumed.
PIPELINE_FOLDER = OutputKind(f"a hyprog pipeline folder (with {MARK})", directory=True,
                             ours=is_pipeline_folder, resumed=True)


def check_out(out: Path, inputs=()) -> None:
    """``out`` may receive a pipeline run (module docstring); ``inputs``: DATA and the
    configuration file."""
    check_output(out, PIPELINE_FOLDER, inputs=inputs)


def check_data(data: Path | None) -> None:
    if data is not None and not Path(data).exists():
        raise InputError(f"{data}: no such file or directory")


def run_pipeline(out: str | Path, config: dict, data: str | Path | None = None,
                 quiet: bool = True, log: Callable[[str], None] | None = None,
                 inputs=()) -> dict:
    """Run (or resume) the pipeline into ``out``; returns ``{"stages": {name: {"status",
    "seconds"}}, "files", "metrics"}``. ``inputs``: the other files the command reads (its
    configuration file), never written over."""
    out = Path(out)
    check_data(None if data is None else Path(data))
    config_source = next((str(p) for p in inputs if p is not None), "config")
    if data is not None and config["simulate"]["preset"]:
        raise InputError(f"{config_source}: [simulate] preset {config['simulate']['preset']!r}"
                         f" and DATA {data} both given: the pipeline runs on one; drop one")
    inputs = (data, *inputs)
    check_out(out, inputs)
    log = log or (lambda msg: None)
    with output_lock(out):
        check_out(out, inputs)
        created = not out.exists() or not any(out.iterdir())
        out.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(out)  # what a killed run left (a dead writer's only)
        if not (out / MARK).is_file():
            write_json(out / MARK, {"format": FORMAT})
        ctx = stages.Context(out=out, config=config, quiet=quiet, log=log,
                             config_source=config_source)
        try:
            return _run(ctx, None if data is None else Path(data))
        except InputError:
            tidy_after_refusal(out, created)
            raise
        finally:
            ctx.close()


def tidy_after_refusal(out: Path, created: bool) -> None:
    """After bad input: remove the stage folders left empty (a stage refuses before it
    writes) and, when this run created ``out`` and nothing in it is done, ``out`` itself, so
    that a refused run leaves nothing behind."""
    for folder in (out / state.STAGES_DIR).glob("*"):
        if folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()
    stages_dir = out / state.STAGES_DIR
    if stages_dir.is_dir() and not any(stages_dir.iterdir()):
        stages_dir.rmdir()
    if created and [p.name for p in out.iterdir()] == [MARK]:
        shutil.rmtree(out)


def _run(ctx: stages.Context, data: Path | None) -> dict:
    cfg, out = ctx.config, ctx.out
    timings: dict = {}
    summaries: dict = {}

    def step(name: str, conf: dict, inputs: dict, fn, *args) -> dict:
        fp = stage_fingerprint(name, conf, inputs)
        t0 = time.perf_counter()
        got = state.done(out, name, fp)
        if got is not None:
            timings[name] = {"status": "skipped", "seconds": time.perf_counter() - t0}
            ctx.log(f"{name}: skipped (done for this configuration)")
        else:
            ctx.log(f"{name}: running")
            folder = state.stage_dir(out, name, fp)
            folder.mkdir(parents=True, exist_ok=True)
            got = fn(ctx, folder, *args)
            state.mark_done(out, name, fp, got)
            got = state.done(out, name, fp)
            timings[name] = {"status": "done", "seconds": time.perf_counter() - t0}
            ctx.log(f"{name}: done in {timings[name]['seconds']:.1f} s")
        summaries[name] = got
        return {"fp": fp, **got}

    data_cfg, seed = cfg["data"], cfg["pipeline"]["seed"]
    if data is None and cfg["simulate"]["preset"]:
        sim = step("simulate", {"simulate": cfg["simulate"], "units": data_cfg["units"]}, {},
                   stages.simulate)
        data, label = out / sim["data"], f"simulated {cfg['simulate']['preset']} fleet"
    elif data is None:
        data, label = stages.default_data(), "data_samples/tiny (the packaged sample fleet)"
    else:
        label = str(data)
    t0 = time.perf_counter()
    dfp = files_fingerprint(data)
    summaries["data"] = {"data": str(data), "label": label, "fingerprint": dfp}
    base = {"data": dfp, "units": data_cfg["units"]}
    adapted = ctx.adapted  # read and checked before any stage runs
    if adapted is not None:
        base["model_effects"] = adapted.sha256
    stages.check_data_against_config(ctx, data)  # units, input columns: before any stage
    timings["data"] = {"status": "checked", "seconds": time.perf_counter() - t0}
    cal = step("calibrate", {"calibrate": cfg["calibrate"]}, base, stages.calibrate, data)
    disc = None
    if cfg["discover"]["enabled"]:
        dconf = {"discover": {k: v for k, v in cfg["discover"].items() if k != "augment"},
                 "calibrate": cfg["calibrate"], "seed": seed}
        disc = step("discover", dconf, base, stages.discover, data, summaries["calibrate"])
    augment = cfg["discover"]["augment"] and disc is not None
    fin = {"calibrate": cal["fp"], **({"discover": disc["fp"]} if augment else {})}
    feats = step("features", {"augment": augment, "data": data_cfg,
                              "inputs": cfg["train"]["inputs"],  # resolved for the model:
                              "model": cfg["train"]["model"]}, fin, stages.features, data,
                 summaries["calibrate"], summaries.get("discover") if augment else None)
    tr = step("train", {"train": cfg["train"], "data": data_cfg, "seed": seed},
              {"features": feats["fp"]}, stages.train, summaries["features"])
    ev = step("evaluate", {"device": cfg["train"]["device"]},
              {"train": tr["fp"], "features": feats["fp"]}, stages.evaluate,
              summaries["features"], summaries["train"])
    rin = {"calibrate": cal["fp"], "features": feats["fp"], "train": tr["fp"],
           "evaluate": ev["fp"], "discover": None if disc is None else disc["fp"]}
    step("report", {"config": results_config(cfg)}, rin,
         lambda c, folder: report.write(out, cfg, summaries, dict(timings)))
    said = [f"calibrate: {w}" for w in summaries["calibrate"].get("warnings", [])]
    said += [f"evaluate ({k}): {w}" for k, v in summaries["evaluate"].items()
             for w in v.get("warnings", [])]
    result = {"out": str(out), "data": label, "stages": timings,
              "warnings": list(dict.fromkeys(said)),
              "seconds": sum(v["seconds"] for v in timings.values()),
              "files": summaries["report"]["files"],
              "split": summaries["features"]["split"],
              "rul": {k: {"rmse": v["metrics"]["samples"]["overall"]["rmse"],
                          "score": v["metrics"]["samples"]["overall"]["score"],
                          "rmse_last": v["metrics"]["last"]["overall"]["rmse"],
                          "horizon": v["metrics"]["horizon"]["mean"]}
                      for k, v in summaries["evaluate"].items()}}
    write_json(out / "run.json", result)
    return result
