"""``hyprog model ...``: the physics-based engine model ``F(w, theta) -> (x_s, x_v)``.

Three commands, each a few lines over :class:`engine_model.EngineModel`:

- ``point``      every output of one operating point;
- ``envelope``   a sweep of random operating points of the civil envelope: convergence rate,
                 speed, and where points fail;
- ``reference``  the model against the C-MAPSS FD002 reference table, channel by channel.

The logic is in the library (:mod:`engine_model.analysis.envelope`,
:mod:`engine_model.analysis.reference`); the engine model is the process-wide one
(:func:`cli.common.get_model`). Heavy modules (CasADi, the engine model, pandas) are imported
inside the functions so that ``hyprog --help`` is fast.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer

from cli.common import (
    APP_SETTINGS,
    EXIT_FAILED,
    CliError,
    PlainUsageCommand,
    Quiet,
    console,
    echo_json,
    fail,
    get_model,
    user_errors,
)

app = typer.Typer(
    help="The physics-based engine model F(w, theta) -> (x_s, x_v).",
    no_args_is_help=True,
    **APP_SETTINGS,
)

MAX_FAILURE_ROWS = 20


# ----------------------------------------------------------------------------- helpers
def _number(v):
    """A Python number (or None for NaN) from a numpy or Python value
    (:func:`engine_model.datasets.jsonable.jsonable`; imported on use: ``--help`` reads no
    data library)."""
    from engine_model.datasets.jsonable import jsonable

    return jsonable(v)


def _fmt(v, digits: int | None = None) -> str:
    """Numbers for tables: about six significant figures, fixed point."""
    v = _number(v)
    if v is None:
        return "-"
    if isinstance(v, bool):
        return str(v)
    if digits is None:
        a = abs(v)
        digits = 2 if a >= 100 else 4 if a >= 1 else 5
    return f"{v:.{digits}f}"


def _fmt_err(e) -> str:
    e = _number(e)
    if e is None:
        return "-"
    return "0.00" if abs(e) < 0.005 else f"{e:+.2f}"


def _err_style(e) -> str:
    e = _number(e)
    if e is None:
        return "red"
    return "green" if abs(e) < 2.0 else "yellow" if abs(e) < 5.0 else "red"


def parse_theta(items: list[str] | None) -> dict[str, float]:
    """``["HPT_eff_mod=-0.02", ...]`` -> ``{"HPT_eff_mod": -0.02}``, checked against
    :data:`engine_model.THETA_NAMES` and the envelope's theta range."""
    from engine_model import ENVELOPE, THETA_NAMES

    lo, hi = ENVELOPE.theta
    out: dict[str, float] = {}
    for item in items or []:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise CliError(f"--theta {item!r}: expected NAME=VALUE, e.g. HPT_eff_mod=-0.02")
        if name not in THETA_NAMES:
            raise CliError(f"--theta {item!r}: unknown health parameter {name!r};"
                           f" one of {', '.join(THETA_NAMES)}")
        try:
            value = float(text)
        except ValueError:
            raise CliError(f"--theta {item!r}: {text.strip()!r} is not a number") from None
        if not math.isfinite(value):
            raise CliError(f"--theta {item!r}: value must be finite")
        if not lo <= value <= hi:
            raise CliError(f"--theta {item!r}: {value:g} is outside [{lo:g}, {hi:g}]"
                           " (fractional health delta: 0 nominal, -0.02 = 2 % lost)")
        if name in out:
            raise CliError(f"--theta {name} given more than once")
        out[name] = value
    return out


def _check_range(option: str, value: float, limits: tuple, unit: str):
    lo, hi = limits
    if not math.isfinite(value):
        raise CliError(f"{option} {value}: value must be finite")
    if not lo <= value <= hi:
        raise CliError(f"{option} {value:g} is outside the flight envelope [{lo:g}, {hi:g}] {unit}")


# ----------------------------------------------------------------------------- point
_W_DIGITS = {"alt": 0, "Mach": 3, "TRA": 1, "T2": 2}


def _point_groups(theta_given: bool):
    from engine_model import OUTPUT_NAMES, THETA_NAMES, W_NAMES, XS_NAMES, XV_NAMES

    extra = tuple(n for n in OUTPUT_NAMES if n not in XS_NAMES + XV_NAMES)
    groups = [("w", W_NAMES), ("x_s", XS_NAMES), ("x_v", XV_NAMES), ("extra", extra)]
    if theta_given:
        groups.insert(1, ("theta", THETA_NAMES))
    return groups


@app.command(cls=PlainUsageCommand)
def point(
    alt: Annotated[float, typer.Option("--alt", help="Pressure altitude (ft).")],
    mach: Annotated[float, typer.Option("--mach", help="Flight Mach number.")],
    tra: Annotated[float, typer.Option("--tra", help="Throttle-resolver angle (%).")],
    t2: Annotated[float | None, typer.Option(
        "--t2", help="Fan-inlet total temperature (degR); default: ISA + --dt-isa.")] = None,
    dt_isa: Annotated[float | None, typer.Option(
        "--dt-isa", help="ISA day-temperature offset in K (default 0); excludes --t2.")] = None,
    theta: Annotated[list[str] | None, typer.Option(
        "--theta", metavar="NAME=VALUE",
        help="Health parameter delta, repeatable, e.g. --theta HPT_eff_mod=-0.02.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
    quiet: Quiet = False,
):
    """Every output of the engine model at one operating point.

    \b
    Example:
      hyprog model point --alt 35000 --mach 0.8 --tra 90 --theta HPT_eff_mod=-0.02
    """
    with user_errors():
        _check_point(alt, mach, tra, t2, dt_isa)
        th = parse_theta(theta)
        s = get_model(quiet).point(alt, mach, tra, T2=t2, dT_isa=dt_isa or 0.0, theta=th)
    from engine_model import OUTPUT_NAMES, THETA_NAMES

    converged = bool(s["converged"])
    values = {"alt": alt, "Mach": mach, "TRA": tra, "T2": float(s["T2"])}
    values.update({k: th.get(k, 0.0) for k in THETA_NAMES})
    values.update({k: s[k] for k in OUTPUT_NAMES})
    if as_json:
        echo_json({**values, "converged": converged, "residual_norm": s["residual_norm"],
                    "iterations": int(s["iterations"])})
    else:
        _print_point(values, th, s)
    if not converged:
        fail(f"the steady state did not converge at alt {alt:g} ft, Mach {mach:g},"
             f" TRA {tra:g} %, T2 {values['T2']:.2f} degR"
             f" (max |r| = {float(s['residual_norm']):.1e}); outputs are NaN", code=EXIT_FAILED)


def _check_point(alt: float, mach: float, tra: float, t2: float | None,
                 dt_isa: float | None) -> None:
    """The options of ``model point`` inside the flight envelope, named in the message."""
    from engine_model import ENVELOPE

    if t2 is not None and dt_isa is not None:
        raise CliError("give either --t2 or --dt-isa, not both")
    _check_range("--alt", alt, ENVELOPE.alt_ft, "ft")
    _check_range("--mach", mach, ENVELOPE.Mach, "")
    _check_range("--tra", tra, ENVELOPE.TRA, "%")
    if t2 is not None:
        _check_range("--t2", t2, ENVELOPE.T2, "degR")
    if dt_isa is not None:
        if not math.isfinite(dt_isa):
            raise CliError(f"--dt-isa {dt_isa}: value must be finite")
        from engine_model.physics import atmosphere
        from engine_model.units import k_to_r

        t2_isa = float(k_to_r(atmosphere.t2_from_flight(alt, mach, dt_isa)))
        lo, hi = ENVELOPE.T2
        if not lo <= t2_isa <= hi:
            raise CliError(f"--dt-isa {dt_isa:g} gives T2 = {t2_isa:.2f} degR, outside the"
                           f" flight envelope [{lo:g}, {hi:g}] degR")


def _print_point(values: dict, th: dict, s) -> None:
    from rich.table import Table

    from engine_model.channels import UNITS

    con = console()
    con.print(f"[bold]Engine model at alt {values['alt']:g} ft, Mach {values['Mach']:g},"
              f" TRA {values['TRA']:g} %, T2 {values['T2']:.2f} degR[/]"
              + "".join(f", {k} {v:+g}" for k, v in th.items()))
    table = Table()
    for col, kw in (("group", {}), ("channel", {}), ("value", {"justify": "right"}),
                    ("unit", {})):
        table.add_column(col, **kw)
    for g, names in _point_groups(bool(th)):
        for i, n in enumerate(names):
            table.add_row(g if i == 0 else "", n, _fmt(values[n], _W_DIGITS.get(n)),
                          UNITS.get(n, ""), end_section=(i == len(names) - 1))
    con.print(table)
    con.print(f"converged: {bool(s['converged'])}, max |r| = {float(s['residual_norm']):.1e},"
              f" {int(s['iterations'])} Newton iterations")


# ----------------------------------------------------------------------------- envelope
@app.command(cls=PlainUsageCommand)
def envelope(
    n: Annotated[int, typer.Option("--n", min=1, help="Number of random points.")] = 2000,
    seed: Annotated[int, typer.Option("--seed", help="Random seed.", min=0)] = 0,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
    quiet: Quiet = False,
):
    """Sweep random points of the civil envelope: convergence rate, speed, failures.

    alt 0-42,000 ft, Mach up to min(0.85, 350 kt CAS), TRA 20-100 %, ISA +-15 K,
    theta uniform in [-0.05, 0]. A report: exits 0 even when points fail.

    \b
    Example:
      hyprog model envelope --n 2000 --seed 0
    """
    from engine_model.analysis.envelope import envelope_report

    with user_errors():
        rep = envelope_report(get_model(quiet), n, seed)
    if as_json:
        echo_json(rep)
    else:
        _print_envelope(rep)


def _print_envelope(rep: dict) -> None:
    from rich.table import Table

    n, seed = rep["n_points"], rep["seed"]
    con = console()
    con.print(f"[bold]Envelope sweep: {n} random points, seed {seed}[/]")
    summary = Table(show_header=False)
    summary.add_column("what")
    summary.add_column("value", justify="right")
    rate_style = "green" if rep["n_failed"] == 0 else "red"
    summary.add_row("converged", f"[{rate_style}]{n - rep['n_failed']} / {n}"
                    f" ({100 * rep['convergence_rate']:.2f} %)[/]")
    summary.add_row("failed", str(rep["n_failed"]))
    summary.add_row("wall time", f"{rep['seconds']:.3f} s")
    summary.add_row("points / s", f"{rep['points_per_second']:,.0f}")
    con.print(summary)
    if rep["failures"]:
        fails = rep["failures"]
        t = Table(title=f"Failing points (first {min(len(fails), MAX_FAILURE_ROWS)}"
                        f" of {len(fails)})")
        for col in ("row", "alt [ft]", "Mach", "TRA [%]", "T2 [degR]", "dT_isa [K]", "max |r|"):
            t.add_column(col, justify="right")
        for f in fails[:MAX_FAILURE_ROWS]:
            t.add_row(str(f["row"]), f"{f['alt']:.0f}", f"{f['Mach']:.3f}", f"{f['TRA']:.1f}",
                      f"{f['T2']:.2f}", f"{f['dT_isa']:+.1f}", f"{f['residual_norm']:.1e}")
        con.print(t)
        span = {k: (min(f[k] for f in fails), max(f[k] for f in fails))
                for k in ("alt", "Mach", "TRA")}
        con.print(f"failures span alt {span['alt'][0]:.0f}-{span['alt'][1]:.0f} ft,"
                  f" Mach {span['Mach'][0]:.2f}-{span['Mach'][1]:.2f},"
                  f" TRA {span['TRA'][0]:.1f}-{span['TRA'][1]:.1f} %")


# ----------------------------------------------------------------------------- reference
@app.command(cls=PlainUsageCommand)
def reference(
    csv: Annotated[Path | None, typer.Argument(
        metavar="CSV",
        help="Reference table (default: data_samples/cmapss-fd002-operating-points.csv).",
        show_default=False)] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
    quiet: Quiet = False,
):
    """The model against C-MAPSS FD002 early-life means at its six operating points.

    Each row runs at alt_kft (in thousands of ft), Mach, TRA and the table's T2; theta = 0.
    Ps30 and phi are not compared: in C-MAPSS they break their own definitions.

    \b
    Example:
      hyprog model reference --json
    """
    from engine_model.analysis import reference as lib

    path = csv if csv is not None else lib.default_reference_path()
    with user_errors():  # the library's messages name the file
        ref = lib.load_reference(path)
        records = lib.compare_reference(get_model(quiet), ref)
    channels = lib.compared_channels(ref)
    if as_json:
        echo_json(records)
    else:
        _print_reference(records, channels, path)
    bad = [r for r in records if not r["converged"]]
    if bad:
        fail(f"{path}: the steady state did not converge at row(s)"
              f" {', '.join(str(r['row']) for r in bad)}", code=EXIT_FAILED)


def _print_reference(records, channels, path):
    from rich.table import Table

    from engine_model.channels import UNITS
    from engine_model.units import FT_PER_KFT

    con = console()
    con.print("[bold]hyprog engine model versus C-MAPSS[/]")
    con.print(f"reference: {path}", soft_wrap=True)
    for rec in records:
        con.print(f"\n[bold]row {rec['row']}[/]: alt {rec['alt_kft'] * FT_PER_KFT:g} ft,"
                  f" Mach {rec['Mach']:g}, TRA {rec['TRA']:g} %, T2 {rec['T2']:g} degR"
                  + ("" if rec["converged"] else " [red](not converged)[/]"))
        t = Table()
        t.add_column("channel")
        t.add_column("unit")
        t.add_column("C-MAPSS", justify="right")
        t.add_column("hyprog", justify="right")
        t.add_column("error %", justify="right")
        for c in channels:
            e = rec[f"{c}_err_pct"]
            t.add_row(c, UNITS.get(c, ""), _fmt(rec[f"{c}_ref"]), _fmt(rec[f"{c}_model"]),
                      f"[{_err_style(e)}]{_fmt_err(e)}[/]")
        con.print(t)
    con.print("\n[bold]Error % = 100 (hyprog - C-MAPSS) / C-MAPSS[/]")
    s = Table()
    s.add_column("channel")
    for rec in records:
        s.add_column(f"{rec['alt_kft']:g} kft\nM{rec['Mach']:g}\nTRA {rec['TRA']:g}",
                     justify="right")
    for c in channels:
        s.add_row(c, *(f"[{_err_style(r[f'{c}_err_pct'])}]{_fmt_err(r[f'{c}_err_pct'])}[/]"
                       for r in records))
    s.add_row("max |e|", *(_fmt(r["max_abs_err_pct"], 2) for r in records), end_section=True)
    con.print(s)
    con.print("Ps30 and phi are not compared: in C-MAPSS they break their own definitions.")
