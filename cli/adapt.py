"""``hyprog adapt DATA --out adapted.json``: adapt the engine model to a fleet's measured data
(:mod:`calibration.adaptation`) and write the adapted model that ``calibrate``, ``discover``
and ``pipeline`` load with ``--model-effects``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cli.common import (
    UNIT_LIST,
    CliError,
    Overwrite,
    Quiet,
    console,
    echo_json,
    parse_list,
    parse_units,
    user_errors,
)


def adapt(
    data: Annotated[Path, typer.Argument(
        metavar="DATA", help="Dataset with unit, cycle, condition and the "
                                         "channels (hyprog data import-cmapss writes one).")],
    out: Annotated[Path, typer.Option("--out", help="Adapted model to write (JSON).")],
    channels: Annotated[str | None, typer.Option(
        "--channels", help="Channels to fit (default: T24,T30,T50,P15,P30,Nf,Nc).")] = None,
    candidates: Annotated[str | None, typer.Option(
        "--candidates", help="Candidates (default: design_scaling, map_scaling, map_slope, "
        "customer_bleed, hp_offtake, reynolds, inlet_loss, nozzle_area, sensor_gain; also "
        "duct_loss, cooling_flow, map_pressure_ratio when named).")] = None,
    early_cycles: Annotated[int, typer.Option(
        "--early-cycles", help="Cycles of early life used (cycle <= this).", min=1)] = 20,
    units: Annotated[str | None, typer.Option("--units", help="Units to use "
                                              f"{UNIT_LIST} (default: all).")] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the held-out engine folds.", min=0)]
    = 0,
    model_error: Annotated[float | None, typer.Option(
        "--model-error", help="The model's own error, a relative std added to each sample's "
        "noise (default 0.001, calibration.adaptation.data.MODEL_ERROR; 0: the noise alone).",
        min=0.0)] = None,
    model_error_shared: Annotated[bool | None, typer.Option(
        "--model-error-shared/--model-error-independent", help="The model's own error is "
        "the same for every sample at one operating condition (one offset per condition and "
        "channel, with the model error as its prior; Kennedy & O'Hagan; the default when "
        "the model error is above 0), or independent noise of each sample (as the FD002 "
        "adaptation ccd7e93d was fitted).", show_default=False)] = None,
    judge: Annotated[int, typer.Option(
        "--judge", help="Candidates judged with each condition left out per step, the best "
        "in sample first (default 3, calibration.adaptation.selection.TOP).", min=1)] = 3,
    as_json: Annotated[bool, typer.Option("--json", help="Print the record as JSON.")] = False,
    overwrite: Overwrite = False,
    quiet: Quiet = False,
):
    """Fit what every engine shares (candidate effects, chosen by leaving each operating
    condition out) apart from each engine's own health, and write the adapted model.

    \b
    Example:
      hyprog adapt fd002 --out adapted.json
    """
    with user_errors(data, output=out):
        from calibration.adaptation import adapt as run
        from calibration.adaptation import write_adapted
        from calibration.adaptation.artefact import ADAPTED_MODEL
        from calibration.adaptation.data import DEFAULT_CHANNELS, MODEL_ERROR
        from calibration.adaptation.groups import check_groups
        from engine_model.datasets import read_dataset
        from engine_model.runtime.ownership import check_output

        check_output(out, ADAPTED_MODEL, overwrite, (data,))  # before the work, not after
        cands = check_groups(parse_list(candidates, "--candidates"))
        chans = parse_list(channels, "--channels") or list(DEFAULT_CHANNELS)
        df, _meta = read_dataset(data, units=parse_units(units))
        if len(df) == 0:
            raise CliError(f"{data}: no rows")
        err = console(stderr=True)
        say = None if (quiet or as_json) else (lambda msg: err.print(msg, soft_wrap=True))
        res = run(df, tuple(chans), cands, early_cycles,
                  log=say, source=str(data), seed=seed,
                  model_error=MODEL_ERROR if model_error is None else model_error,
                  judge=judge, model_error_shared=model_error_shared)
        record = res.record()
        write_adapted(record, out, overwrite, (data,))
    if as_json:
        echo_json(record)
        return
    if quiet:
        return
    _print(record, out)


def _print(rec: dict, out: Path) -> None:
    from rich.table import Table

    c = console()
    s = rec["selection"]
    c.print(f"fitted {', '.join(rec['channels'])} on {rec['data']['units']} engines, "
            f"{rec['data']['samples']:,} early-life samples, in {rec['seconds']:.0f} s")
    if not rec["effects"]:
        c.print("no candidate lowers the error on held-out conditions: the model is kept")
    for p in rec["parameters"]:
        flag = " (at a bound of its valid range)" if p["at_bound"] else ""
        c.print(f"  {p['candidate']}.{p['parameter']} = {p['value']:.4g} ± {p['std']:.2g}"
                f"{flag}")
    t = Table(title="mean error per condition, % (worst channel)")
    t.add_column("condition")
    for col in ("in sample, before", "after", "condition left out, before", "after"):
        t.add_column(col, justify="right")
    ins, outs = s["mean_error_pct_in_sample"], s["mean_error_pct_condition_out"]
    for cond in sorted(ins["before"], key=int):
        row = [ins["before"][cond], ins["after"][cond], outs["before"][cond],
               outs["after"][cond]]
        t.add_row(str(cond), *[_worst(r) for r in row])
    c.print(t)
    for label, key in (("in sample", "chi2_in_sample"), ("condition left out",
                                                         "chi2_condition_out"),
                       ("engines left out", "chi2_engines_out")):
        c.print(f"chi2 per sample and channel, {label}: {s[key]['before']:.3g} -> "
                f"{s[key]['after']:.3g}")
    c.print(f"wrote {out}")


def _worst(errors: dict) -> str:
    ch = max(errors, key=lambda k: abs(errors[k]))
    return f"{errors[ch]:+.2f} ({ch})"
