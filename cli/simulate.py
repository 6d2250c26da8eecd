"""``hyprog simulate``: generate an N-CMAPSS-like run-to-failure fleet."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import typer

from cli.common import (
    UNIT_LIST,
    CliError,
    Overwrite,
    Quiet,
    check_choice,
    console,
    echo_json,
    parse_units,
    user_errors,
)

# engine_model.simulator.flight_profiles: the recorded part of a flight
RECORDS = ("above_10kft", "all")


def simulate(
    out: Annotated[Path, typer.Option(
        "--out", help="Output: parquet directory, or h5 file (.h5/.hdf5/.he5).")],
    preset: Annotated[str, typer.Option(
        "--preset", help="Fleet preset: ds02, ds02-study (a drawn ds02-like fleet of 30 "
        "units) or tiny.")] = "tiny",
    units: Annotated[str | None, typer.Option(
        "--units", help=f"Unit numbers of the preset {UNIT_LIST} (default: all).")] = None,
    rate: Annotated[float | None, typer.Option(
        "--rate-hz", "--rate", help="Sample rate [Hz]: 1 (native) or 1/k, e.g. 0.1 as in the "
        "paper (the pipeline's [simulate] rate_hz).")] = None,
    seed: Annotated[int, typer.Option("--seed", help="Random seed.")] = 0,
    effect: Annotated[list[str] | None, typer.Option(
        "--effect", help="NAME[:param=value,...] switched on in the truth (repeatable); "
        "see `hyprog effects`.")] = None,
    fmt: Annotated[Literal["parquet", "h5"] | None, typer.Option(
        "--format", help="File format; default: h5 when --out ends in .h5/.hdf5/.he5, else "
        "parquet. A --format that contradicts the --out suffix (h5 to .parquet, parquet to "
        ".h5) is refused.")] = None,
    record: Annotated[str | None, typer.Option(
        "--record", help="above_10kft (N-CMAPSS, default) or all.")] = None,
    overwrite: Overwrite = False,
    scheduler: Annotated[str | None, typer.Option(
        "--scheduler", help="Simulate the units on a Dask cluster: its scheduler address "
        "(tcp://host:port; the workers need hyprog installed, this process writes --out), "
        "or 'local' for a local cluster of --jobs workers. Same result as without.")] = None,
    jobs: Annotated[int, typer.Option(
        "--jobs", help="Worker processes, one unit per task (or the workers of the local Dask "
        "cluster with --scheduler local). Same result as one.")] = 1,
    quiet: Quiet = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print a JSON report only.")] = False,
):
    """Simulate a fleet to failure and write it (atomically) with its metadata. An existing
    --out is replaced only when hyprog wrote it (or with --overwrite). Each unit's random
    draws depend only on the seed and the unit, so --units and --scheduler do not change a
    unit's data.

    \b
    Examples:
      hyprog simulate --preset tiny --out fleet --seed 0
      hyprog simulate --preset ds02 --out ds02 --scheduler tcp://10.0.0.5:8786
    """
    from engine_model import datasets, runtime
    from engine_model.physics.effects import parse_effect_spec
    from engine_model.simulator import fleet
    from engine_model.validation import check_seed

    with user_errors(output=out):
        if record is not None:
            check_choice(record, "--record", RECORDS)
        check_seed(seed, "--seed")
        if jobs < 1:
            raise CliError(f"--jobs {jobs}: expected an integer >= 1")
        unit_list = parse_units(units)
        effects = [parse_effect_spec(e) for e in (effect or [])]
        preset_obj = fleet.get_preset(preset)
        if rate is not None:
            fleet.check_rate(rate)
        n_units = len(fleet.select_units(preset_obj, unit_list))
        fmt = datasets.output_format(out, fmt, what="--format")
        out = datasets.check_dataset_output(out, directory=fmt == "parquet", overwrite=overwrite)
        with runtime.output_lock(out):  # one writer per output
            path, report = _run(fleet, preset, preset_obj, out, unit_list, rate, seed, effects,
                                record, fmt, overwrite, n_units, as_json or quiet, scheduler,
                                jobs)
    rep = {"out": str(path), "rows": report.total_rows, "seconds": round(report.seconds, 2),
           "units": {str(u): {"rows": report.rows[u], "eol": report.eol[u], "t_s": report.t_s[u],
                              "dropped": report.dropped[u]} for u in report.rows}}
    if as_json:
        echo_json(rep)
        return
    if quiet:  # --quiet: the result is in --out, nothing more is printed
        return
    console().print(f"wrote {path}: {rep['rows']:,} rows, {len(report.rows)} units in "
                    f"{report.seconds:.1f} s")


def _run(fleet, preset, preset_obj, out, unit_list, rate, seed, effects, record, fmt,
         overwrite, n_units, no_bar, scheduler, jobs):
    """The simulation itself, with a progress bar on a terminal's stderr unless ``no_bar``."""
    kw = {"overwrite": overwrite, "scheduler": scheduler, "jobs": jobs}
    if no_bar:
        return fleet.simulate(preset_obj, out, unit_list, rate, seed, effects, record, fmt, **kw)
    from rich.progress import Progress

    err = console(stderr=True)
    with Progress(console=err, transient=True, disable=not err.is_terminal) as bar:
        task = bar.add_task(f"simulating {preset} ({n_units} units)", total=n_units)
        return fleet.simulate(preset_obj, out, unit_list, rate, seed, effects, record, fmt,
                              progress=lambda k, n, rows: bar.update(task, completed=k), **kw)
