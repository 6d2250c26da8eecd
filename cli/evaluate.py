"""``hyprog evaluate MODEL_DIR FEATURES``: metrics on the test units, both protocols."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Annotated

import typer

from cli.common import (
    CliError,
    Quiet,
    console,
    echo_json,
    parse_units,
    progress_bar,
    user_errors,
)


def load_model_warned(model_dir: Path):
    """Load a model; a version warning is printed as one ``warning: ...`` line on stderr."""
    from prognostics.checkpoint import load_model

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UserWarning)
        rul = load_model(model_dir)
    for w in caught:
        typer.echo(f"warning: {w.message}", err=True)
    return rul


def evaluate(
    model_dir: Annotated[Path, typer.Argument(help="Model directory written by hyprog train.")],
    features: Annotated[Path, typer.Argument(help="Feature table with the model's inputs "
                                             "and RUL.")],
    units: Annotated[str | None, typer.Option(
        "--units", help="Units to evaluate (default: the metadata's test_units).")] = None,
    device: Annotated[str, typer.Option("--device", help="auto, cpu or cuda.")] = "cpu",
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
    quiet: Quiet = False,
):
    """RMSE, NASA score, interval coverage per test unit and overall, on every sample (the
    paper's protocol) and at each unit's last cycle (C-MAPSS's); prediction horizon.

    Example: hyprog evaluate models/cnn features.parquet --json
    """
    from engine_model.datasets import read_dataset

    with user_errors(features):
        rul = load_model_warned(model_dir)
        df, meta = read_dataset(features)
        test = parse_units(units) or [int(u) for u in meta.get("test_units") or []]
        if not test:
            raise CliError(f"{features}: the metadata names no test_units; pass --units")
        with progress_bar("evaluating (windows x members)", quiet or as_json) as update:
            metrics, _ = rul.evaluate(df, test, device, source=str(features),
                                      progress=update)
    if as_json:
        echo_json(metrics)
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
    t.add_row("all", f"{o['n']:,}", f"{o['rmse']:.3f}", f"{o['score']:.4g}", "", "", "",
              f"{last['overall']['rmse']:.3f}", f"{hz['mean']:.3g}", *cells(o))
    console().print(t)
