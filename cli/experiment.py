"""``hyprog experiment paper --data FEATURES --out DIR``: the paper's tables, resumable."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import typer

from cli.common import (
    APP_SETTINGS,
    UNIT_LIST,
    CliError,
    PlainUsageCommand,
    Quiet,
    console,
    echo_json,
    parse_list,
    parse_units,
    split_items,
    user_errors,
)

app = typer.Typer(help="The paper's experiments and ablations on a feature table.",
                  no_args_is_help=True, **APP_SETTINGS)


def _seeds(text: str, option: str) -> tuple[int, ...]:
    """``"5"`` -> seeds 0..4; ``"0,3,7"`` -> those seeds."""
    try:
        if "," not in text:
            n = int(text)
            if n < 1:
                raise CliError(f"{option} {text}: expected a count >= 1 or a list of seeds")
            return tuple(range(n))
        seeds = tuple(int(s) for s in split_items(text, option))
    except ValueError:
        raise CliError(f"{option} {text}: expected a count or comma-separated seeds") from None
    twice = sorted({s for s in seeds if seeds.count(s) > 1})
    if twice:  # one network counted as two would report an ensemble spread of 0
        raise CliError(f"{option} {text}: seed(s) {', '.join(map(str, twice))} listed twice")
    return seeds


@app.command("paper", cls=PlainUsageCommand)
def paper(
    data: Annotated[Path, typer.Option("--data", help="Feature table (hyprog calibrate).")],
    out: Annotated[Path, typer.Option("--out", help="Output directory (a rerun resumes).")],
    seeds: Annotated[str, typer.Option(
        "--seeds", help="Main-table seeds: a count (5: seeds 0-4) or a list (0,3,7).")] = "5",
    ablation_seeds: Annotated[str | None, typer.Option(
        "--ablation-seeds",
        help="Seeds of the ablations (default: the first 3 main seeds).")] = None,
    ablations: Annotated[str, typer.Option(
        "--ablations", help="small, features, calibration, conformal (comma-separated), all "
        "or none.")] = "all",
    small_units: Annotated[str, typer.Option(
        "--small-units", help=f"Training units of ablation I {UNIT_LIST}.")] = "16,18,20",
    epochs: Annotated[int | None, typer.Option(
        "--epochs", help="Maximum epochs of every run (default: 60 FNN, 30 CNN).")] = None,
    alpha: Annotated[float, typer.Option("--alpha", help="Conformal miscoverage.")] = 0.1,
    device: Annotated[Literal["auto", "cpu", "cuda"], typer.Option(
        "--device", help="Where the networks run.")] = "auto",
    no_baseline: Annotated[bool, typer.Option(
        "--no-baseline", help="Skip the physics-only baseline (needs the engine model).")
    ] = False,
    no_figures: Annotated[bool, typer.Option(
        "--no-figures", help="Write the tables only (no PNG figures; an earlier run's figures "
        "in OUT are removed, as they may no longer match the tables).")] = False,
    quiet: Quiet = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print a JSON summary only.")] = False,
):
    """Main table (FNN/CNN, data-driven vs hybrid), horizon, ablations I, III, IV, conformal
    intervals and the physics baseline: Markdown + CSV tables and PNG figures in OUT. Every
    training run is cached in OUT/runs: a rerun resumes where it stopped.

    \b
    Example:
      hyprog experiment paper --data features.parquet --out results/paper --seeds 5
    """
    from engine_model.datasets import read_dataset
    from workflows.paper import PARTS, ExperimentConfig, run_experiment

    with user_errors(data, output=out):
        if ablations == "all":
            parts = PARTS
        elif ablations == "none":
            parts = ("main",)
        else:
            parts = ("main", *parse_list(ablations, "--ablations"))
        cfg = ExperimentConfig(
            seeds=_seeds(seeds, "--seeds"),
            ablation_seeds=None if ablation_seeds is None else
            _seeds(ablation_seeds, "--ablation-seeds"),
            parts=tuple(parts), small_units=tuple(parse_units(small_units, "--small-units")),
            epochs=epochs, device=device, alpha=alpha, baseline=not no_baseline,
            figures=not no_figures)
        df, meta = read_dataset(data)
        log = (lambda s: None) if as_json or quiet else \
            (lambda s: console(stderr=True).print(s))
        res = run_experiment(df, meta, out, cfg, log=log, source=str(data), inputs=(data,))
    if as_json:
        echo_json(res)
        return
    if quiet:  # --quiet: the result is in --out, nothing more is printed
        return
    console().print(f"{res['runs']} runs ({res['trained']} trained, {res['cached']} cached); "
                    f"tables {res['report']['tables']}, per-run {res['report']['runs']}, "
                    f"{len(res['report']['figures'])} figures")
