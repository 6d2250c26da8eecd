"""``hyprog evaluate MODEL_DIR FEATURES``: metrics on the test units, both protocols."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import typer

from cli.common import (
    UNIT_LIST,
    CliError,
    Quiet,
    caught_warnings,
    finish,
    parse_units,
    progress_bar,
    user_errors,
    wide_console,
)


def load_model_checked(model_dir: Path):
    """The model of ``model_dir``; its errors name the model directory (not the data)."""
    from prognostics.checkpoint import load_model

    with user_errors(model_dir):
        return load_model(model_dir)


def evaluate(
    model_dir: Annotated[Path, typer.Argument(
        metavar="MODEL_DIR", help="Model directory written by hyprog train.")],
    features: Annotated[Path, typer.Argument(
        metavar="FEATURES", help="Feature table with the model's inputs "
                                             "and RUL.")],
    units: Annotated[str | None, typer.Option(
        "--units", help=f"Units to evaluate {UNIT_LIST} (default: the metadata's "
        "test_units).")] = None,
    device: Annotated[Literal["auto", "cpu", "cuda"], typer.Option(
        "--device", help="Where the networks run.")] = "cpu",
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
    quiet: Quiet = False,
):
    """RMSE, NASA score, interval coverage per test unit and overall, on every sample (the
    paper's protocol) and at each unit's last cycle (C-MAPSS's); prediction horizon.

    \b
    Example:
      hyprog evaluate models/cnn features.parquet --json
    """
    from engine_model.datasets import read_dataset
    from prognostics.splits import metadata_units

    with caught_warnings() as warned:
        rul = load_model_checked(model_dir)
        with user_errors(features):
            df, meta = read_dataset(features)
            test = parse_units(units) or metadata_units(meta, "test_units", str(features))
            if not test:
                raise CliError(f"{features}: the metadata names no test_units; pass --units")
            with progress_bar("evaluating (windows x members)", quiet or as_json) as update:
                metrics, _ = rul.evaluate(df, test, device, source=str(features),
                                          progress=update)
    if finish(metrics, warned, as_json):
        return
    from rich.table import Table

    s, last, hz = metrics["samples"], metrics["last"], metrics["horizon"]
    interval = "coverage" in s["overall"]
    t = Table("unit", "samples", "RMSE", "s", "last cycle", "true RUL", "predicted",
              "RMSE last", "horizon", *(["coverage", "width"] if interval else []),
              title=f"{model_dir}: {rul.config.model.upper()} {rul.config.inputs}")

    def cells(m):
        return [f"{m['coverage']:.3f}", f"{m['width']:.3g}"] if interval else []

    for u, m in s["units"].items():
        e = last["units"][u]
        t.add_row(str(u), f"{m['n']:,}", f"{m['rmse']:.3f}", f"{m['score']:.4g}",
                  str(e["cycle"]), f"{e['RUL']:.3g}", f"{e['RUL_pred']:.3g}",
                  f"{abs(e['delta']):.3f}", f"{hz['units'][u]:.3g}", *cells(m))
    o = s["overall"]
    if len(s["units"]) > 1:  # with one unit the row would repeat it
        t.add_row("all", f"{o['n']:,}", f"{o['rmse']:.3f}", f"{o['score']:.4g}", "", "", "",
                  f"{last['overall']['rmse']:.3f}", f"{hz['mean']:.3g}", *cells(o))
    al = metrics["alpha_lambda"]
    life = Table("λ (fraction of life)", f"within ±{al['alpha']:.0%}", "relative accuracy",
                 title="accuracy at t_P + λ (t_EOL - t_P)")
    for lam in al["lambdas"]:
        k = f"{lam:g}"
        seen = [u for u, r in al["units"].items() if r[k] is not None]
        within = sum(al["units"][u][k]["within"] for u in seen)
        life.add_row(k, f"{within} of {len(seen)} units", f"{al['relative_accuracy'][k]:.3f}"
                     if seen else "-")
    bins = Table("true RUL", "samples", "median Δ", "Δ 25-75 %", "Δ 5-95 %",
                 title="Δ = true - predicted RUL (> 0: early)")
    for b in metrics["error_by_rul"]:
        bins.add_row(f"{b['lo']:g}-{b['hi']:g}", f"{b['n']:,}", f"{b['median']:+.3g}",
                     f"{b['q25']:+.3g} .. {b['q75']:+.3g}", f"{b['q05']:+.3g} .. {b['q95']:+.3g}")
    c = wide_console(t)
    for table in (t, life, bins):
        c.print(table)
