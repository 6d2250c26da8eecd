"""``hyprog predict MODEL_DIR DATA --out FILE``: RUL per sample and per cycle.

The two outputs (``--out`` and its ``<stem>.per_cycle<suffix>`` sidecar) follow the ownership
rule (:mod:`engine_model.runtime.ownership`; :func:`prognostics.outputs.write_predictions`):
checked before the model is loaded, written under the lock of each, atomically and together.
"""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path
from typing import Annotated, Literal

import typer

from cli.common import (
    UNIT_LIST,
    Overwrite,
    Quiet,
    caught_warnings,
    console,
    finish,
    parse_units,
    progress_bar,
    user_errors,
)


def predict(
    model_dir: Annotated[Path, typer.Argument(
        metavar="MODEL_DIR", help="Model directory written by hyprog train.")],
    data: Annotated[Path, typer.Argument(
        metavar="DATA", help="Table with the model's input columns.")],
    out: Annotated[Path, typer.Option(
        "--out", help="Per-sample predictions (.csv, else parquet); the per-cycle table goes "
        "to <stem>.per_cycle<suffix> beside it.")],
    units: Annotated[str | None, typer.Option(
        "--units", help=f"Units to predict {UNIT_LIST} (default: all).")] = None,
    device: Annotated[Literal["auto", "cpu", "cuda"], typer.Option(
        "--device", help="Where the networks run.")] = "cpu",
    as_json: Annotated[bool, typer.Option("--json", help="Print a JSON report only.")] = False,
    overwrite: Overwrite = False,
    quiet: Quiet = False,
):
    """Predict the RUL of every sample that ends a full window (columns RUL_pred, RUL_std for
    an ensemble, RUL_lower / RUL_upper with a conformal interval) and its per-cycle mean,
    min and max. A unit shorter than the window is left-padded with its first sample and
    gets one prediction, at its last sample. An existing --out (or its per-cycle sidecar) is
    replaced only when it is a prediction table hyprog wrote (or with --overwrite); never the
    model or the data it reads, never a special file (pipe, device).

    \b
    Example:
      hyprog predict models/cnn new_flights.parquet --out rul.csv
    """
    from cli.evaluate import load_model_checked
    from engine_model.datasets import read_dataset
    from engine_model.runtime import check_output, output_lock
    from prognostics.metrics import per_cycle
    from prognostics.outputs import check_table_suffix, prediction_targets, write_predictions

    with caught_warnings() as warned, user_errors(data, output=out):
        inputs = (model_dir, data)
        for target, kind in prediction_targets(out):  # before any work
            check_output(target, kind, overwrite, inputs)
        check_table_suffix(out)
        with ExitStack() as locks:  # one writer per output, released on Ctrl-C too
            for target, _ in prediction_targets(out):
                locks.enter_context(output_lock(target))
            rul = load_model_checked(model_dir)
            df, _ = read_dataset(data)
            with progress_bar("predicting (windows x members)", quiet or as_json) as update:
                pred = rul.predict(df, parse_units(units), device, source=str(data),
                                   progress=update)
            pc = per_cycle(pred)
            out, pc_path = write_predictions(pred, pc, out, overwrite, inputs)
    rep = {"out": str(out), "per_cycle": str(pc_path), "samples": len(pred),
           "cycles": len(pc), "units": sorted(int(u) for u in pred["unit"].unique()),
           "interval": rul.conformal is not None}
    if finish(rep, warned, as_json):
        return
    if quiet:  # --quiet: the result is in --out, nothing more is printed
        return
    console().print(f"wrote {out} ({rep['samples']:,} samples) and {rep['per_cycle']} "
                    f"({rep['cycles']} cycles) for unit(s) {', '.join(map(str, rep['units']))}")
