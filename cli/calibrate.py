"""``hyprog calibrate DATA ...`` (features for the prognostics) and ``hyprog calibrate compare``.

``calibrate`` is a group whose default command is ``run``: ``hyprog calibrate DATA --method
ukf --out FEATURES`` is ``hyprog calibrate run DATA ...``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import typer
from typer.core import TyperGroup

from cli.common import (
    APP_SETTINGS,
    UNIT_LIST,
    CliError,
    ModelError,
    Noise,
    PlainUsageCommand,
    Quiet,
    console,
    echo_json,
    parse_drift,
    parse_list,
    parse_model_error,
    parse_units,
    progress_bar,
    user_errors,
    warn,
)


class _DefaultRun(TyperGroup):
    """A group that runs ``run`` when the first argument is not one of its commands."""

    def parse_args(self, ctx, args):
        if args and args[0] not in self.commands and args[0] not in ("--help", "-h"):
            args = ["run", *args]
        return super().parse_args(ctx, args)


app = typer.Typer(cls=_DefaultRun, no_args_is_help=True, **APP_SETTINGS,
                  help="Estimate the health parameters theta(t) of every unit (UKF, EKF, "
                       "MHE, MAP per cycle) and write the paper's feature table. "
                       "'hyprog calibrate DATA --out F' is 'hyprog calibrate run DATA --out F'.")


def _with_drift_mle(drift, data, setup, units):
    """``setup`` with the drift estimated from ``data`` when ``--drift mle`` (the estimator
    and its imports, 0.7 s, only then)."""
    if drift != "mle":
        return setup
    from calibration.discrepancy.drift_mle import setup_with_drift_mle

    return setup_with_drift_mle(drift, data, setup, units)


def _setup(params, sensors, drift, noise_scale, prior_std, drift_per, noise=None,
           model_error=None):
    from calibration import CalibrationSetup
    from engine_model.channels import THETA_NAMES

    p, s = parse_list(params, "--params"), parse_list(sensors, "--sensors")
    model_error = parse_model_error(model_error)
    kw = _given(params=THETA_NAMES if p == ("all",) else p, sensors=s,
                drift=parse_drift(drift), noise_scale=noise_scale,
                prior_std=prior_std, drift_per=drift_per, noise=noise, model_error=model_error)
    return CalibrationSetup(**kw)


def _given(**kw) -> dict:
    """The options the user gave (those not None)."""
    return {k: v for k, v in kw.items() if v is not None}


def _options(method, window, stride, mode, hessian):
    """Estimator options of ``method``; MHE options given to another method are an error."""
    mhe = _given(window=window, stride=stride, mode=mode, hessian=hessian)
    if method == "mhe":
        return mhe
    if method == "map_cycle" and set(mhe) <= {"hessian"}:
        return mhe
    if mhe:
        raise CliError(f"{', '.join('--' + k for k in mhe)}: options of the mhe method, "
                       f"not {method}")
    return {}


Params = Annotated[str | None, typer.Option(
    "--params", help="Comma-separated health parameters to estimate, or 'all' (default: the "
    "paper's HPT_eff_mod,LPT_eff_mod,LPT_flow_mod).")]
Sensors = Annotated[str | None, typer.Option(
    "--sensors", help="Comma-separated measured channels to use (default: every x_s in the data); "
    "with --noise data also other model outputs the data record, e.g. C-MAPSS's BPR, W31, W32.")]
Drift = Annotated[str | None, typer.Option(
    "--drift", help="Random-walk std of theta per sqrt(hour), or 'mle': estimated from the "
    "data by maximum likelihood (default: 1e-3).")]
NoiseScale = Annotated[float | None, typer.Option(
    "--noise-scale", help="Multiplier of the documented sensor noise in R (default: 1).")]
PriorStd = Annotated[float | None, typer.Option(
    "--prior-std", help="Prior std of theta (default: 0.02).")]
DriftPer = Annotated[str | None, typer.Option(
    "--drift-per", help="cycle, time or auto (default: auto: cycle when the data have cycles).")]
Units = Annotated[str | None, typer.Option(
    "--units", help=f"Units to calibrate {UNIT_LIST} (default: all).")]
Jobs = Annotated[int, typer.Option("--jobs", help="Worker processes (default: 1).")]
Scheduler = Annotated[str | None, typer.Option(
    "--scheduler", help="Dask scheduler address (tcp://host:port), or 'local' for a local "
    "Dask cluster of --jobs workers.")]
Window = Annotated[int | None, typer.Option(
    "--window", help="mhe: samples per window (default: 60).")]
Stride = Annotated[int | None, typer.Option(
    "--stride", help="mhe: window step (default: the window).")]
Mode = Annotated[str | None, typer.Option(
    "--mode", help="mhe: constant or random_walk theta in a window (default: constant).")]
Hessian = Annotated[str | None, typer.Option(
    "--hessian", help="mhe / map_cycle: gauss-newton or exact (default: gauss-newton).")]
AsJson = Annotated[bool, typer.Option("--json", help="Print a JSON report only.")]
ModelEffects = Annotated[Path | None, typer.Option(
    "--model-effects", help="Adapted model (hyprog adapt --out FILE): its effects are switched "
    "on in the engine model and recorded in the output's metadata.")]


@app.command("run", cls=PlainUsageCommand)
def run(
    data: Annotated[Path, typer.Argument(
        metavar="DATA", help="Dataset: parquet directory or N-CMAPSS h5.")],
    out: Annotated[Path, typer.Option("--out", help="Feature table to write (parquet "
                                      "directory by unit; a rerun resumes).")],
    method: Annotated[Literal["ukf", "ekf", "mhe", "map_cycle"], typer.Option(
        "--method", help="The estimator.")] = "ukf",
    params: Params = None, sensors: Sensors = None, drift: Drift = None,
    noise_scale: NoiseScale = None, prior_std: PriorStd = None, drift_per: DriftPer = None,
    units: Units = None, jobs: Jobs = 1, scheduler: Scheduler = None, window: Window = None,
    stride: Stride = None, mode: Mode = None, hessian: Hessian = None,
    model_effects: ModelEffects = None, noise: Noise = None, model_error: ModelError = None,
    as_json: AsJson = False, quiet: Quiet = False,
):
    """Calibrate every unit and write the feature table (inputs, x_hat, theta_hat, std).

    \b
    Example:
      hyprog calibrate data_samples/tiny --method ukf --drift 0.01 --out features
    """
    import warnings

    from calibration import UnobservableWarning, estimator_class
    from calibration.calibrate_fleet import calibrate_fleet
    from calibration.consistency import with_measured_noise
    from calibration.unit_check import fleet_warnings
    from engine_model.channels import XS_NAMES
    from engine_model.datasets import read_columns

    with user_errors(output=out), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UnobservableWarning)
        setup = _setup(params, sensors, drift, noise_scale, prior_std, drift_per, noise,
                       model_error)
        opts = _options(method, window, stride, mode, hessian)
        estimator_class(method).check_options(opts)  # before the work below builds the model
        estimator_class(method).check_setup(setup)
        unit_list = parse_units(units)
        adapted = None
        if model_effects is not None:
            from calibration.adaptation import load_adapted
            adapted = load_adapted(model_effects)
        # before the drift's estimate, which needs them
        setup = with_measured_noise(
            setup, data, adapted.effects if adapted else (), unit_list,
            consistent=model_error == "consistent",
            log=None if (as_json or quiet) else lambda m: console().print(m))
        setup = _with_drift_mle(drift, data, setup, unit_list)
        with progress_bar(f"calibrating ({method})", as_json or quiet) as update:
            res = calibrate_fleet(data, method, setup, opts, unit_list, jobs, scheduler, out,
                                  keep_results=False, progress=update,
                                  effects=adapted.effects if adapted else (),
                                  model_source=adapted.provenance() if adapted else None)
    # the fleet's summary of unobservable parameters is both warned and in res.warnings
    warned = list(dict.fromkeys([*sorted({str(w.message) for w in caught
                                          if issubclass(w.category, UnobservableWarning)}),
                                 *res.warnings]))
    nonconverged = sum(v["n_nonconverged"] for v in res.units.values())
    in_data = set(read_columns(data))
    absent = [c for c in XS_NAMES if c not in res.sensors and c not in in_data]
    # in the data but not used: not physical (C-MAPSS's Ps30), constant, or not asked for
    left_out = [c for c in XS_NAMES if c not in res.sensors and c in in_data]
    rep = {"out": str(out), "method": method, "params": list(setup.params),
           "sensors": list(res.sensors), "sensors_absent": absent,
           "sensors_left_out": left_out,
           "units": {str(u): v for u, v in sorted(res.units.items())},
           "skipped": res.skipped, "samples": res.samples, "n_nonconverged": nonconverged,
           "seconds": round(res.seconds, 2), "samples_per_second": res.samples_per_second,
           "warnings": warned}
    if as_json:
        echo_json(rep)
        return
    if quiet:  # --quiet: the result is in --out, nothing more is printed
        return
    # a line per parameter and bound over the fleet, not one per unit (every unit's is in --json)
    for w in fleet_warnings(warned, res.units):
        warn(w)
    c = console()
    c.print(f"sensors ({len(res.sensors)}): {', '.join(res.sensors)}"
            + (f" (absent: {', '.join(absent)})" if absent else "")
            + (f" (in the data, not used: {', '.join(left_out)})" if left_out else ""),
            soft_wrap=True)
    if res.skipped:
        c.print(f"resumed: units {', '.join(map(str, res.skipped))} were already in {out}")
    c.print(f"wrote {out}: {len(res.units)} unit(s), {res.samples:,} samples with {method} in "
            f"{res.seconds:.1f} s ({res.samples_per_second:,.0f} samples/s)")
    if nonconverged:
        per = ", ".join(f"unit {u}: {v['n_nonconverged']}" for u, v in sorted(res.units.items())
                        if v["n_nonconverged"])
        c.print(f"{nonconverged:,} of {res.samples:,} samples did not converge ({per})")


@app.command("compare", cls=PlainUsageCommand)
def compare_cmd(
    data: Annotated[Path, typer.Argument(
        metavar="DATA", help="Simulated dataset (with the true theta).")],
    methods: Annotated[str, typer.Option("--methods", help="Comma-separated methods.")] =
    "ukf,ekf,mhe,map_cycle",
    params: Params = None, sensors: Sensors = None, drift: Drift = None,
    noise_scale: NoiseScale = None, prior_std: PriorStd = None, drift_per: DriftPer = None,
    units: Units = None, jobs: Jobs = 1, scheduler: Scheduler = None, window: Window = None,
    stride: Stride = None, mode: Mode = None, hessian: Hessian = None, as_json: AsJson = False,
    quiet: Quiet = False,
):
    """Each method against the truth: RMSE, bias, consistency, Cramér-Rao bound, whiteness,
    speed.

    \b
    Example:
      hyprog calibrate compare fleet/ --methods ukf,ekf --jobs 2 --json
    """
    import warnings

    from calibration import UnobservableWarning, estimator_class
    from calibration.compare import compare, format_report
    with user_errors(), warnings.catch_warnings():
        warnings.simplefilter("ignore", UnobservableWarning)  # reported in the table
        setup = _setup(params, sensors, drift, noise_scale, prior_std, drift_per)
        names = parse_list(methods, "--methods")
        classes = {m: estimator_class(m) for m in names}  # an unknown method: named first
        mhe = _given(window=window, stride=stride, mode=mode, hessian=hessian)
        opts = {"mhe": mhe, "map_cycle": _given(hessian=hessian)}
        unused = [k for k in mhe if not any(k in opts.get(m, {}) for m in names)]
        if unused:
            raise CliError(f"{', '.join('--' + k for k in unused)}: option(s) of the mhe "
                           f"method{' (--hessian: and map_cycle)' if 'hessian' in unused else ''}"
                           f", which --methods {methods} does not run")
        for m, cls in classes.items():  # before the drift's estimate and the runs
            cls.check_options(opts.get(m, {}))
            cls.check_setup(setup)
        setup = _with_drift_mle(drift, data, setup, parse_units(units))
        with progress_bar("comparing", as_json or quiet) as update:
            report = compare(data, names, setup, opts, parse_units(units), jobs, scheduler,
                             progress=None if update is None else
                             (lambda m, d, n: update(d, n, f"comparing: {m}")))
    if as_json:
        echo_json(report)
        return
    typer.echo(format_report(report))
