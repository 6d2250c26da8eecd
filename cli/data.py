"""``hyprog data ...``: look at a fleet dataset (hyprog parquet or N-CMAPSS h5), import the
C-MAPSS (2008) text files."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cli.common import (
    APP_SETTINGS,
    CliError,
    Overwrite,
    PlainUsageCommand,
    Quiet,
    console,
    echo_json,
    user_errors,
)

app = typer.Typer(help="Inspect fleet datasets (parquet or N-CMAPSS h5); import C-MAPSS.",
                  no_args_is_help=True, **APP_SETTINGS)


@app.command("info", cls=PlainUsageCommand)
def info(
    path: Annotated[Path, typer.Argument(
        metavar="PATH", help="Dataset: a parquet directory/file or an h5 file.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
    quiet: Quiet = False,
):
    """Summarise a dataset: units, split, cycles, rows, end of life, onset t_s, effects.

    \b
    Example:
      hyprog data info data_samples/tiny --json
    """
    from engine_model import datasets

    with user_errors(path):
        columns = datasets.read_columns(path)
        df, meta = datasets.read_dataset(path, columns=[c for c in ("Fc", "hs", "RUL")
                                                        if c in columns])
        rep = datasets.summarize(df, meta)
        rep["columns"] = datasets.column_groups(columns)
    if as_json:
        echo_json(rep)
        return
    from rich.table import Table

    out = console()
    head = [f"{path}", f"{rep['totals']['units']} units", f"{rep['totals']['rows']:,} rows",
            f"{rep['totals']['cycles']:,} cycles"]
    if rep.get("sample_rate_hz"):
        head.append(f"{rep['sample_rate_hz']:g} Hz")
    for key in ("preset", "seed"):
        if key in rep:
            head.append(f"{key} {rep[key]}")
    out.print(", ".join(head))
    t = Table("unit", "split", "cycles", "rows", "EOL", "t_s", "Fc")
    for u in rep["units"]:
        t.add_row(str(u["unit"]), u["split"], str(u["cycles"]), f"{u['rows']:,}", str(u["eol"]),
                  "-" if u["t_s"] is None else str(u["t_s"]), ",".join(map(str, u["Fc"])))
    out.print(t)
    eff = rep.get("effects") or []
    out.print("effects: " + (", ".join(_effect_label(e) for e in eff) if eff else "none"))
    out.print("columns: " + "; ".join(f"{g} ({len(c)})" for g, c in rep["columns"].items() if c))


@app.command("import-cmapss", cls=PlainUsageCommand)
def import_cmapss(
    train: Annotated[Path, typer.Argument(
        metavar="TRAIN", help="C-MAPSS train_FD00x.txt.")],
    out: Annotated[Path, typer.Option(
        "--out", help="Parquet dataset directory to write (an h5 name, .h5/.hdf5/.he5, is "
        "refused: the import writes parquet only).")],
    test: Annotated[Path | None, typer.Option("--test", help="test_FD00x.txt (with --rul).")
                    ] = None,
    rul: Annotated[Path | None, typer.Option("--rul", help="RUL_FD00x.txt (with --test).")
                   ] = None,
    overwrite: Overwrite = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
    quiet: Quiet = False,
):
    """Read a C-MAPSS (2008) subset into a hyprog parquet dataset (N-CMAPSS names, alt in ft,
    RUL per cycle; test unit u becomes unit 1000 + u). Written atomically; an existing --out
    is replaced only when it is a dataset hyprog wrote that holds nothing else (or with
    --overwrite); never the files it reads.

    \b
    Example:
      hyprog data import-cmapss train_FD002.txt --out fd002
    """
    from engine_model import datasets, runtime

    with user_errors(output=out):
        if (test is None) != (rul is None):
            raise CliError("give --test and --rul together (the RUL file belongs to the test"
                           " file)")
        datasets.output_format(out, "parquet", what="the format of import-cmapss")
        inputs = (train, test, rul)
        datasets.check_dataset_output(out, directory=True, overwrite=overwrite, inputs=inputs)
        df, meta = datasets.read_cmapss(train, test, rul)
        with runtime.output_lock(out):
            path = datasets.write_parquet(df, out, meta, overwrite=overwrite, inputs=inputs)
    rep = {"out": str(path), "rows": len(df), "dev_units": meta["dev_units"],
           "test_units": meta["test_units"], "test_unit_offset": meta["test_unit_offset"]}
    if as_json:
        echo_json(rep)
        return
    if quiet:  # --quiet: the result is in --out, nothing more is printed
        return
    console().print(f"wrote {path}: {len(df):,} rows, {len(meta['dev_units'])} train units,"
                    f" {len(meta['test_units'])} test units (test unit u is unit"
                    f" {meta['test_unit_offset']} + u)")


def _effect_label(e) -> str:
    if isinstance(e, dict):
        params = e.get("params") or {}
        inner = ",".join(f"{k}={v:g}" if isinstance(v, (int, float)) else f"{k}={v}"
                         for k, v in params.items())
        return f"{e.get('name', '?')}" + (f":{inner}" if inner else "")
    return str(e)
