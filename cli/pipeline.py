"""``hyprog pipeline [DATA] --out DIR``: data to RUL and a report, resumable
(:mod:`workflows.pipeline`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cli.common import Quiet, caught_warnings, console, finish, user_errors


def pipeline(
    data: Annotated[Path | None, typer.Argument(
        metavar="DATA",
        help="Fleet data: parquet directory or N-CMAPSS h5 (default: the committed "
             "data_samples/tiny fleet).")] = None,
    out: Annotated[Path, typer.Option("--out", help="Output folder: report.md, report.html, "
                                      "metrics.json, figures/ and the stages' work (a rerun "
                                      "resumes).")] = ...,
    config: Annotated[Path | None, typer.Option(
        "--config", help="TOML file with the options of every stage (unknown keys are "
        "errors; default: the built-in options).")] = None,
    augment: Annotated[bool, typer.Option(
        "--augment", help="Add the effects that discover finds to the model and recalibrate "
        "before training.")] = False,
    jobs: Annotated[int | None, typer.Option(
        "--jobs", help="Worker processes of simulate, calibrate and features (or of the local "
        "Dask cluster); overrides [run] jobs. Same numbers whatever the value.")] = None,
    scheduler: Annotated[str | None, typer.Option(
        "--scheduler", help="Run simulate, calibrate and features on a Dask cluster: its "
        "scheduler address (tcp://host:port; the workers must read DATA and --out at the same "
        "paths: a shared file system) or 'local'; overrides [run] scheduler. Same numbers as "
        "without.")] = None,
    model_effects: Annotated[Path | None, typer.Option(
        "--model-effects", help="Adapted model (hyprog adapt --out FILE) for calibrate and "
        "discover; overrides [calibrate] model_effects.")] = None,
    quiet: Quiet = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print a JSON summary only.")] = False,
):
    """Calibrate the fleet, look for model discrepancy, train the data-driven and hybrid
    networks, evaluate them on the test units and write one report (Markdown, a
    self-contained HTML page, metrics.json and PNG figures). A stage whose output exists for
    the same configuration and input is skipped, so a rerun resumes.

    \b
    Examples:
      hyprog pipeline --out results   (the packaged sample fleet, about a minute)
      hyprog pipeline fleet/ --config pipeline.toml --augment --out results
      hyprog pipeline fleet/ --scheduler tcp://10.0.0.5:8786 --out /shared/results
    """
    from workflows.pipeline import load_config, run_pipeline
    from workflows.pipeline.config import merge

    with caught_warnings() as warned, user_errors(output=out):
        cfg = load_config(config)
        if augment:
            cfg["discover"]["augment"] = True
        given = {k: v for k, v in (("jobs", jobs), ("scheduler", scheduler)) if v is not None}
        cfg = merge(cfg, {"run": given}, "--jobs/--scheduler")
        if model_effects is not None:
            cfg["calibrate"]["model_effects"] = str(model_effects)
        err = console(stderr=True)
        silent = quiet or as_json or not err.is_terminal  # progress on a terminal only
        log = (lambda msg: None) if silent else (lambda msg: err.print(msg, soft_wrap=True))
        res = run_pipeline(out, cfg, data, quiet=silent, log=log, inputs=(config,))
    if finish(res, [*res.pop("warnings"), *warned], as_json):
        return
    if quiet:  # --quiet: the result is in --out, nothing more is printed
        return
    c = console()
    for name, st in res["stages"].items():
        c.print(f"{name:10s} {st['status']:8s} {st['seconds']:7.1f} s")
    for inputs, m in res["rul"].items():
        c.print(f"{inputs}: RMSE {m['rmse']:.3f} cycles (last cycle {m['rmse_last']:.3f}), "
                f"NASA score {m['score']:.4g}, horizon {m['horizon']:.3g} cycles")
    c.print(f"report: {Path(res['out']) / 'report.md'} and report.html "
            f"({res['seconds']:.1f} s)")
