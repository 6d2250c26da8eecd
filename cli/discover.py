"""``hyprog discover DATA --out DIR``: find what the calibrated model lacks, add it, and
report the residual before and after (:mod:`calibration.discrepancy`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import typer

from cli.common import (
    UNIT_LIST,
    CliError,
    ModelError,
    Noise,
    Overwrite,
    Quiet,
    console,
    echo_json,
    parse_drift,
    parse_list,
    parse_model_error,
    parse_units,
    user_errors,
)

_METHODS = ("coarse", "mhe", "ukf", "ekf", "map_cycle")


def _drift_or_mle(text: str | None):
    """``--drift``: a number, or ``"mle"`` (also the default)."""
    v = parse_drift(text)
    return "mle" if v is None else v


def discover(
    data: Annotated[Path, typer.Argument(
        metavar="DATA", help="Dataset: parquet directory or N-CMAPSS h5.")],
    out: Annotated[Path, typer.Option("--out", help="Report directory (discover.json, "
                                      "discover.md, residuals.png).")],
    method: Annotated[Literal[_METHODS], typer.Option(
        "--method", help="Warm start of the null fit: coarse (the same fit on every 16th "
        "sample) or an estimator.")] = "coarse",
    candidates: Annotated[str | None, typer.Option(
        "--candidates", help="Comma-separated effects to test (default: the library's steady and "
        "sensor effects; add map_scaling for map adaptation of each component).")] = None,
    alpha: Annotated[float, typer.Option("--alpha", help="Family-wise false-discovery level "
                                         "per dataset.")] = 0.01,
    max_effects: Annotated[int, typer.Option("--max-effects", help="Most effects to add.")]
    = 3,
    params: Annotated[str | None, typer.Option(
        "--params", help="Health parameters to estimate (default: HPT_eff_mod,LPT_eff_mod,"
        "LPT_flow_mod).")] = None,
    sensors: Annotated[str | None, typer.Option("--sensors", help="Channels to use (default: all "
                                                "x_s in the data).")] = None,
    drift: Annotated[str | None, typer.Option(
        "--drift", help="Random-walk std of theta per sqrt(hour), or 'mle' (default: "
        "mle).")] = None,
    units: Annotated[str | None, typer.Option("--units", help="Units to use "
                                              f"{UNIT_LIST} (default: all).")] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the family-wise sampling.")]
    = 0,
    model_effects: Annotated[Path | None, typer.Option(
        "--model-effects", help="Adapted model (hyprog adapt --out FILE): look for what that "
        "model lacks.")] = None,
    noise: Noise = None,
    model_error: ModelError = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the JSON report.")] = False,
    overwrite: Overwrite = False,
    quiet: Quiet = False,
):
    """Screen every candidate effect with score tests, confirm and add the significant
    ones, and report what remains (verdict, effects with uncertainty, before/after). An
    existing --out is replaced only when it is an earlier report that holds nothing else (or
    with --overwrite); never the DATA it reads.

    \b
    Example:
      hyprog discover data_samples/tiny --method ukf --out discover-report
    """
    with user_errors(data, output=out):
        from calibration import CalibrationSetup
        from calibration.consistency import with_measured_noise
        from calibration.discrepancy import DiscoverOptions
        from calibration.discrepancy import discover as run
        from calibration.discrepancy.candidates import check_names
        from calibration.discrepancy.discovery_report import (
            check_report_target,
            report_dict,
            write_report,
        )
        from cli.common import get_model
        from engine_model.datasets import read_dataset
        from engine_model.runtime import output_lock

        p, s = parse_list(params, "--params"), parse_list(sensors, "--sensors")
        kw = {k: v for k, v in {"params": p, "sensors": s, "noise": noise,
                                "model_error": parse_model_error(model_error)}.items()
              if v is not None}
        setup = CalibrationSetup(**kw)
        opts = DiscoverOptions(method=method, candidates=parse_list(candidates,
                                                                    "--candidates"),
                               alpha=alpha, max_effects=max_effects, drift=_drift_or_mle(drift),
                               seed=seed)
        check_names(opts.candidates)
        unit_list = parse_units(units)
        fixed = ()
        if model_effects is not None:
            from calibration.adaptation import load_adapted
            fixed = tuple(load_adapted(model_effects).effects)
        check_report_target(out, overwrite, (data,))  # before the run, not after it
        with output_lock(out):  # one writer per report; released on Ctrl-C / SIGTERM too
            df, meta = read_dataset(data, units=unit_list)
            # R as hyprog calibrate resolves it, the dataset's not-physical channels left out
            setup = with_measured_noise(setup, data, fixed, unit_list,
                                        consistent=model_error == "consistent",
                                        log=None if (as_json or quiet) else console().print)
            setup = setup.for_dataset(meta)
            if "unit" not in df.columns:
                df = df.assign(unit=1)
            if len(df) == 0:
                raise CliError("no rows")
            frames = [g for _, g in df.groupby("unit", sort=True)]
            err = console(stderr=True)
            show = not (as_json or quiet) and err.is_terminal
            say = (lambda msg: err.print(msg)) if show else None
            result = run(frames, setup, opts, base_model=get_model(quiet or as_json),
                         source=data, progress=say, fixed_effects=fixed)
            write_report(result, out, overwrite, (data,))
    if as_json:
        echo_json(report_dict(result))
        return
    if quiet:  # --quiet: the result is in --out, nothing more is printed
        return
    c = console()
    c.print(f"verdict: {result.verdict}")
    for f in result.found:
        c.print(f"  added {f['spec']} (p = {f['p_value']:.3g})")
    for a in result.ambiguous:
        c.print(f"  ambiguous: {a['candidates'][0]} or {a['candidates'][1]}")
    if result.unknown:
        c.print(f"  unknown effect on {', '.join(result.unknown['channels'])}")
    b, a = result.before, result.after
    c.print(f"residual chi^2/dof ({b['on']}): {b['chi2_per_dof']:.3g} -> "
            f"{a['chi2_per_dof']:.3g}; report in {out}")
