"""``hyprog train FEATURES --model cnn --inputs hybrid --out MODEL_DIR``: train a RUL model."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import typer

from cli.common import (
    UNIT_LIST,
    CliError,
    Overwrite,
    Quiet,
    caught_warnings,
    console,
    finish,
    parse_units,
    user_errors,
)
from prognostics.choices import (
    LIBRARY_MODELS,
    MODEL_KINDS,
    NORMALISATIONS,
    SCHEDULES,
    VALIDATIONS,
)

INPUTS_HELP = ("Input set (default hybrid; HI_hat_rel for similarity: one health-index column) "
               "(data-driven, denoised, virtual, hybrid, truth-theta; for tcn and "
               "trend, or any model on a table with one row per cycle such as C-MAPSS, also "
               "physics, hybrid-health, physics-mode, health-mode), groups joined by '+' "
               "(w, xs, xs_hat, xv, xv_hat, theta_hat, theta, cmapss; health, theta_rel, "
               "mode, health_true likewise), "
               "explicit columns (alt,Mach,...), or a set plus columns (hybrid+Ps30,phi).")

#: TrainConfig's fields as this command's options, so that a bad value's error names the option.
OPTIONS = {f: "--" + f.replace("_", "-") for f in (
    "window", "stride", "epochs", "batch_size", "patience", "max_rul", "lr", "alpha", "device",
    "schedule", "normalise", "validation", "seed")}


def train(
    features: Annotated[Path, typer.Argument(
        metavar="FEATURES", help="Feature table (parquet from hyprog "
                                             "calibrate, or any table with its columns).")],
    out: Annotated[Path, typer.Option("--out", help="Model directory to write.")],
    model: Annotated[Literal[MODEL_KINDS], typer.Option(
        "--model", help="fnn or cnn (the paper's), dcnn (Li, Ding & Sun 2018's deeper CNN "
        "with dropout; window 30), or the flight models: tcn (a temporal CNN over the last "
        "20 flights' means and health coordinates) and trend (the same, learning a correction "
        "to the physics trend of the health index); or similarity (no network: the training "
        "units' health-index trajectories as a library, the last 10 flights matched to it; "
        "Wang et al. 2008).")] = "cnn",
    inputs: Annotated[str | None, typer.Option("--inputs", help=INPUTS_HELP)] = None,
    units: Annotated[str | None, typer.Option(
        "--units",
        help=f"Development units to train on {UNIT_LIST} (default: the metadata's "
        "dev_units).")] = None,
    window: Annotated[int | None, typer.Option(
        "--window", help="Window length (default 50 CNN, 30 DCNN, 20 flights for tcn and "
        "trend); the FNN takes one time step.")] = None,
    stride: Annotated[int, typer.Option("--stride", help="Window step.")] = 1,
    max_rul: Annotated[float | None, typer.Option(
        "--max-rul", help="Cap the RUL target (piecewise linear; default: no cap).")] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the first network.")] = 0,
    ensemble: Annotated[int, typer.Option(
        "--ensemble", help="Networks to train, seeds seed..seed+N-1 (mean and spread).")] = 1,
    epochs: Annotated[int | None, typer.Option(
        "--epochs", help="Maximum epochs (default: 60 FNN, 30 CNN, 250 DCNN, 300 TCN and trend, "
        "raised to at least 5,000 optimiser steps).")] = None,
    batch_size: Annotated[int | None, typer.Option(
        "--batch-size", help="Mini-batch size (default: 1024, halved until an epoch has 16 "
        "batches, not below 32).")] = None,
    lr: Annotated[float, typer.Option("--lr", help="Initial learning rate (Adam).")] = 1e-3,
    patience: Annotated[int | None, typer.Option(
        "--patience", help="Early-stopping patience in epochs (default: 5, raised to at "
        "least 2,000 optimiser steps).")] = None,
    schedule: Annotated[Literal[SCHEDULES], typer.Option(
        "--schedule", help="plateau (learning rate / 10 when validation stalls for half the "
        "patience) or constant (the paper's).")] = "plateau",
    normalise: Annotated[Literal[NORMALISATIONS], typer.Option(
        "--normalise", help="auto (condition when the table has a 'condition' column with "
        "several conditions, as C-MAPSS FD002/FD004 imports have; else minmax), minmax (the "
        "paper's, over the fleet) or condition (sensors standardised per operating "
        "condition).")] = "auto",
    drop_constant: Annotated[bool, typer.Option(
        "--drop-constant/--keep-constant", help="Drop input columns that are constant over "
        "the training rows, or keep them.")] = True,
    validation: Annotated[Literal[VALIDATIONS], typer.Option(
        "--validation", help="auto (10 % of the training units, whole, when there are at "
        "least two; else 10 % of the flights), flights or units.")] = "auto",
    val_units: Annotated[str | None, typer.Option(
        "--val-units", help=f"Validate on these whole units {UNIT_LIST}, or 'seed': 10 % of "
        "the training units drawn by the seed (what --validation auto does).")
    ] = None,
    conformal_units: Annotated[str | None, typer.Option(
        "--conformal-units", help=f"Development units held out to calibrate a conformal "
        f"interval {UNIT_LIST}.")] = None,
    alpha: Annotated[float | None, typer.Option(
        "--alpha", help="Miscoverage of the conformal interval (default 0.1: 90 %); needs "
        "--conformal-units.")] = None,
    device: Annotated[Literal["auto", "cpu", "cuda"], typer.Option(
        "--device", help="Where the networks run.")] = "auto",
    overwrite: Overwrite = False,
    quiet: Quiet = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print a JSON report only.")] = False,
):
    """Train a RUL model (the paper's FNN or 1-D CNN, Li et al.'s DCNN, a flight model, or the
    similarity library) on a feature table and save it (weights or library, scaler, inputs,
    interval) to the directory --out.
    An existing --out is replaced only when it is a model hyprog wrote that holds nothing else
    (or with --overwrite); never the FEATURES it reads.

    \b
    Examples:
      hyprog train features.parquet --model cnn --inputs hybrid --out models/cnn
      hyprog train fd002-features --model dcnn --max-rul 125 --out models/fd002   (C-MAPSS)
      hyprog train features.parquet --model similarity --out models/similarity
    """
    from engine_model.datasets import read_dataset
    from engine_model.runtime import output_lock
    from prognostics.checkpoint import check_model_target, save_model
    from prognostics.ensemble import fit
    from prognostics.train_config import DEFAULT_INPUTS, TrainConfig

    if inputs is None:
        inputs = DEFAULT_INPUTS.get(model, "hybrid")
    with user_errors():  # the options alone, before any file is read: errors name the option
        if ensemble < 1:
            raise CliError(f"--ensemble must be >= 1, got {ensemble}")
        if model in LIBRARY_MODELS and ensemble > 1:
            raise CliError(f"--ensemble {ensemble}: the {model} model has no network and "
                           "nothing random; one is the same as many")
        if model in LIBRARY_MODELS and (validation != "auto" or val_units is not None):
            raise CliError(f"--validation / --val-units: the {model} model optimises nothing "
                           "and stops nothing early; every development unit joins its library")
        by_seed = val_units is not None and val_units.strip().lower() == "seed"
        vu = None if by_seed else parse_units(val_units, "--val-units")
        cu = parse_units(conformal_units, "--conformal-units") or []
        if alpha is not None and not cu:
            raise CliError(f"--alpha {alpha:g}: there is no interval to set without "
                           "--conformal-units (the units it is calibrated on)")
        cfg = TrainConfig(model=model, inputs=inputs, window=window, stride=stride,
                          max_rul=max_rul, seed=seed, epochs=epochs, batch_size=batch_size,
                          lr=lr, patience=patience, schedule=schedule, normalise=normalise,
                          drop_constant=drop_constant,
                          validation="units" if vu or by_seed else validation,
                          val_units=tuple(vu) if vu else None,
                          units=tuple(parse_units(units) or []) or None,
                          conformal_units=tuple(cu), alpha=0.1 if alpha is None else alpha,
                          device=device)
        cfg.resolved(OPTIONS)
    with caught_warnings() as warned, user_errors(features, output=out):
        check_model_target(out, overwrite, (features,))  # before hours of training
        with output_lock(out):  # one writer per model directory; released on Ctrl-C too
            df, meta = read_dataset(features)
            rul = fit(df, meta, cfg, seeds=range(seed, seed + ensemble),
                      quiet=quiet or as_json, source=str(features))
            save_model(rul, out, overwrite, (features,))  # atomic: a killed run leaves none
    rep = {"out": str(out), "model": rul.config.model, "inputs": rul.config.inputs,
           "columns": list(rul.columns), "window": rul.window, "max_rul": rul.config.max_rul,
           "parameters": rul.parameters,
           "dropped_constant": list(rul.info.get("dropped_constant", [])),
           "batch_size": rul.config.batch_size, "epochs": rul.config.epochs,
           "patience": rul.config.patience, "validation": rul.config.validation,
           "units": rul.info.get("units"),
           "members": [{"seed": m.seed, "best_epoch": m.best_epoch, "epochs_run": len(m.history),
                        "val_loss": m.history[m.best_epoch - 1]["val_loss"],
                        "train_loss": m.history[m.best_epoch - 1]["train_loss"]}
                       for m in rul.members],
           "conformal": None if rul.conformal is None else rul.conformal.to_dict()}
    if rul.library is not None:  # no network: no batches, epochs, patience or validation
        rep.update(batch_size=None, epochs=None, patience=None, validation=None,
                   library={"units": len(rul.library.library),
                            "flights": sum(len(h) for h, _ in rul.library.library),
                            "sigma2": rul.library.sigma2})
    warned = [*warned, *rul.still_improving()]
    if finish(rep, warned, as_json):
        return
    if quiet:  # --quiet: the result is in --out, nothing more is printed
        return
    c = console()
    if rul.library is not None:
        lib = rep["library"]
        c.print(f"{rep['model'].upper()} on {rep['columns'][0]}, window {rep['window']} flights: "
                f"a library of {lib['units']} unit(s), {lib['flights']:,} flights (bandwidth "
                f"σ² {lib['sigma2']:.3g}); no network, no validation")
    else:
        _print_networks(c, rep)
    if rul.conformal is not None:
        c.print(f"conformal interval ±{rul.conformal.quantile:.3g} cycles at level "
                f"{1 - rul.conformal.alpha:.2f} from {rul.conformal.n_scores:,} samples of "
                f"unit(s) {', '.join(map(str, rul.conformal.units))}")
    c.print(f"wrote {out}")


def _print_networks(c, rep: dict) -> None:
    """The console lines of a trained network ensemble."""
    c.print(f"{rep['model'].upper()} on {len(rep['columns'])} inputs ({rep['inputs']}), window "
            f"{rep['window']}: {rep['parameters']:,} trainable parameters; batch "
            f"{rep['batch_size']}, at most {rep['epochs']} epochs, patience {rep['patience']}, "
            f"validation on {rep['validation']}"
            + (f" {', '.join(map(str, rep['units']['validation']))}"
               if rep["validation"] == "units" and (rep["units"] or {}).get("validation")
               else ""))
    if rep["dropped_constant"]:
        c.print(f"dropped constant input(s): {', '.join(rep['dropped_constant'])}")
    for m in rep["members"]:
        val = "-" if m["val_loss"] is None else f"{m['val_loss']:.4g}"
        c.print(f"seed {m['seed']}: best epoch {m['best_epoch']} of {m['epochs_run']}, "
                f"train MSE {m['train_loss']:.4g}, validation MSE {val}")
