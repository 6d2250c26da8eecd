"""``hyprog model ...``: the physics-based engine model ``F(w, theta) -> (x_s, x_v)``.

Three commands, each a few lines over :class:`engine_model.EngineModel`:

- ``point``      every output of one operating point;
- ``envelope``   a sweep of random operating points of the civil envelope: convergence rate,
                 speed, and where points fail;
- ``reference``  the model against the C-MAPSS FD002 reference table, channel by channel.

Heavy modules (CasADi, the engine model, pandas) are imported inside the functions so that
``hyprog --help`` is fast. The engine model is built once per process and kept in
``_MODEL`` (tests and repeated calls share it).
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path
from typing import Annotated

import typer

from cli.common import CliError, console, echo_json, fail, plain, user_errors

app = typer.Typer(
    help="The physics-based engine model F(w, theta) -> (x_s, x_v).",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)

REFERENCE_CSV = "cmapss-fd002-operating-points.csv"
# the repository's data_samples/ (editable install or a checkout) first, then the working dir
_REFERENCE_CANDIDATES = (
    Path(__file__).resolve().parent.parent / "data_samples" / REFERENCE_CSV,
    Path("data_samples") / REFERENCE_CSV,
)
REFERENCE_W = ("alt_kft", "Mach", "TRA", "T2")
# channels compared with C-MAPSS; Ps30 and phi are left out on purpose: in the C-MAPSS files
# they do not follow their stated definitions (see the .md beside the reference table)
REFERENCE_CHANNELS = (
    "T24", "T30", "T50", "P2", "P15", "P30", "Nf", "Nc", "epr", "NRf", "NRc", "BPR", "W31", "W32",
)
KT_TO_MS = 0.514444  # knot -> m/s
MAX_FAILURE_ROWS = 20

_MODEL = None


# ----------------------------------------------------------------------------- helpers
def get_model():
    """The process-wide :class:`engine_model.EngineModel` (built, compiled and cached once)."""
    global _MODEL
    if _MODEL is None:
        from engine_model import EngineModel

        if sys.stderr.isatty():
            with console(stderr=True).status(
                    "building the engine model (the first run compiles C, later ones load it)"):
                _MODEL = EngineModel(compiled=True)
        else:
            _MODEL = EngineModel(compiled=True)
    return _MODEL


def _fmt(v, digits: int | None = None) -> str:
    """Numbers for tables: about six significant figures, fixed point."""
    v = plain(v)
    if v is None:
        return "-"
    if isinstance(v, bool):
        return str(v)
    if digits is None:
        a = abs(v)
        digits = 2 if a >= 100 else 4 if a >= 1 else 5
    return f"{v:.{digits}f}"


def _fmt_err(e) -> str:
    e = plain(e)
    if e is None:
        return "-"
    return "0.00" if abs(e) < 0.005 else f"{e:+.2f}"


def _err_style(e) -> str:
    e = plain(e)
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


@app.command()
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
):
    """Every output of the engine model at one operating point."""
    with user_errors():
        from engine_model import ENVELOPE, OUTPUT_NAMES, THETA_NAMES

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
            from engine_model import atmosphere

            t2_isa = float(atmosphere.t2_from_flight(alt, mach, dt_isa)) * 1.8
            lo, hi = ENVELOPE.T2
            if not lo <= t2_isa <= hi:
                raise CliError(f"--dt-isa {dt_isa:g} gives T2 = {t2_isa:.2f} degR, outside the"
                               f" flight envelope [{lo:g}, {hi:g}] degR")
        th = parse_theta(theta)
        s = get_model().point(alt, mach, tra, T2=t2, dT_isa=dt_isa or 0.0, theta=th)

    converged = bool(s["converged"])
    values = {"alt": alt, "Mach": mach, "TRA": tra, "T2": float(s["T2"])}
    values.update({k: th.get(k, 0.0) for k in THETA_NAMES})
    values.update({k: s[k] for k in OUTPUT_NAMES})
    if as_json:
        echo_json({**values, "converged": converged, "residual_norm": s["residual_norm"],
                    "iterations": int(s["iterations"])})
    else:
        from rich.table import Table

        from engine_model.channels import UNITS

        con = console()
        con.print(f"[bold]Engine model at alt {alt:g} ft, Mach {mach:g}, TRA {tra:g} %,"
                  f" T2 {values['T2']:.2f} degR[/]"
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
        con.print(f"converged: {converged}, max |r| = {float(s['residual_norm']):.1e},"
                  f" {int(s['iterations'])} Newton iterations")
    if not converged:
        fail(f"the steady state did not converge at alt {alt:g} ft, Mach {mach:g},"
              f" TRA {tra:g} %, T2 {values['T2']:.2f} degR"
              f" (max |r| = {float(s['residual_norm']):.1e}); outputs are NaN", code=2)


# ----------------------------------------------------------------------------- envelope
def random_envelope(n: int, seed: int = 0):
    """``n`` random operating points of the civil envelope, as a DataFrame with the columns
    alt, Mach, TRA, T2 [degR] and the ten theta columns.

    alt uniform 0-42,000 ft; Mach uniform from 0 to min(0.85, the Mach of 350 kt calibrated
    airspeed at that altitude); TRA 20-100 %; ISA day offset +-15 K; theta uniform in
    [-0.05, 0]. The draws of :func:`engine_model.sampling.random_envelope`.
    """
    import pandas as pd

    from engine_model import THETA_NAMES
    from engine_model.sampling import random_envelope as sample

    w, theta, dT = sample(n, seed, return_day_offset=True)
    alt, mach, tra, T2 = w.T
    df = pd.DataFrame({"alt": alt, "Mach": mach, "TRA": tra, "T2": T2})
    df[list(THETA_NAMES)] = theta
    df["dT_isa"] = dT
    return df


def envelope_report(model, n: int, seed: int = 0) -> dict:
    """Solve ``n`` random envelope points; convergence rate, speed and the failing points."""
    from engine_model import THETA_NAMES, W_NAMES

    pts = random_envelope(n, seed)
    t0 = time.perf_counter()
    out = model.evaluate(pts[list(W_NAMES) + list(THETA_NAMES)])
    elapsed = time.perf_counter() - t0
    ok = out["converged"].to_numpy(bool)
    bad = pts.loc[~ok].copy()
    bad["residual_norm"] = out.loc[~ok, "residual_norm"]
    failures = [{"row": int(i), **row} for i, row in zip(bad.index, bad.to_dict("records"),
                                                          strict=True)]
    return {
        "n_points": n,
        "seed": seed,
        "n_failed": int((~ok).sum()),
        "convergence_rate": float(ok.mean()),
        "seconds": elapsed,
        "points_per_second": n / elapsed if elapsed > 0 else None,
        "failures": failures,
    }


@app.command()
def envelope(
    n: Annotated[int, typer.Option("--n", min=1, help="Number of random points.")] = 2000,
    seed: Annotated[int, typer.Option("--seed", help="Random seed.")] = 0,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
):
    """Sweep random points of the civil envelope: convergence rate, speed, failures.

    alt 0-42,000 ft, Mach up to min(0.85, 350 kt CAS), TRA 20-100 %, ISA +-15 K,
    theta uniform in [-0.05, 0]. A report: exits 0 even when points fail.
    """
    with user_errors():
        rep = envelope_report(get_model(), n, seed)
    if as_json:
        echo_json(rep)
        return
    from rich.table import Table

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
def default_reference() -> Path:
    for p in _REFERENCE_CANDIDATES:
        if p.is_file():
            return p
    return _REFERENCE_CANDIDATES[0]


def load_reference(path: Path):
    """Read the reference table: numeric columns alt_kft, Mach, TRA, T2 and any of
    :data:`REFERENCE_CHANNELS`. Rows are numbered from 1 (header excluded) in messages."""
    import pandas as pd

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(2, "no such file", str(path))
    df = pd.read_csv(path)
    df.columns = [str(c).strip() for c in df.columns]
    missing = [c for c in REFERENCE_W if c not in df.columns]
    if missing:
        raise CliError(f"missing column(s) {', '.join(missing)}; expected"
                       f" {', '.join(REFERENCE_W)} and channels such as T30, Nc"
                       f" (got {', '.join(df.columns)})")
    channels = [c for c in REFERENCE_CHANNELS if c in df.columns]
    if not channels:
        raise CliError(f"no channel to compare; expected some of {', '.join(REFERENCE_CHANNELS)}")
    if df.empty:
        raise CliError("the table has no rows")
    df.index = pd.RangeIndex(1, len(df) + 1)
    for c in list(REFERENCE_W) + channels:
        num = pd.to_numeric(df[c], errors="coerce")
        bad = num.isna() & df[c].notna()
        if bad.any():
            i = bad.idxmax()
            raise CliError(f"row {i}, column {c}: {df.at[i, c]!r} is not a number")
        if c in REFERENCE_W and num.isna().any():
            raise CliError(f"row {num.isna().idxmax()}, column {c}: value is missing")
        df[c] = num.astype(float)
    return df[list(REFERENCE_W) + channels]


def compare_reference(model, ref) -> list[dict]:
    """The model at every row of the reference table: per channel the reference value, the
    model value and the error ``100 (model - reference) / reference`` [%]."""
    import pandas as pd

    w = pd.DataFrame({"alt": ref["alt_kft"] * 1000.0, "Mach": ref["Mach"], "TRA": ref["TRA"],
                      "T2": ref["T2"]}, index=ref.index)
    out = model.evaluate(w)
    channels = [c for c in REFERENCE_CHANNELS if c in ref.columns]
    records = []
    for i in ref.index:
        rec = {"row": int(i), **{c: float(ref.at[i, c]) for c in REFERENCE_W},
               "converged": bool(out.at[i, "converged"])}
        for c in channels:
            r, m = float(ref.at[i, c]), float(out.at[i, c])
            err = 100.0 * (m - r) / r if math.isfinite(r) and r != 0.0 else float("nan")
            rec[f"{c}_ref"], rec[f"{c}_model"], rec[f"{c}_err_pct"] = r, m, err
        errs = [abs(rec[f"{c}_err_pct"]) for c in channels
                if math.isfinite(rec[f"{c}_err_pct"])]
        rec["max_abs_err_pct"] = max(errs) if errs else float("nan")
        records.append(rec)
    return records


@app.command()
def reference(
    csv: Annotated[Path | None, typer.Argument(
        help="Reference table (default: data_samples/cmapss-fd002-operating-points.csv).",
        show_default=False)] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
):
    """The model against C-MAPSS FD002 early-life means at its six operating points.

    Each row runs at alt_kft * 1000 ft, Mach, TRA and the table's T2; theta = 0.
    Ps30 and phi are not compared: in C-MAPSS they break their own definitions.
    """
    path = csv if csv is not None else default_reference()
    with user_errors(path):
        ref = load_reference(path)
        records = compare_reference(get_model(), ref)
    channels = [c for c in REFERENCE_CHANNELS if c in ref.columns]
    if as_json:
        echo_json(records)
    else:
        _print_reference(records, channels, path)
    bad = [r for r in records if not r["converged"]]
    if bad:
        fail(f"{path}: the steady state did not converge at row(s)"
              f" {', '.join(str(r['row']) for r in bad)}", code=2)


def _print_reference(records, channels, path):
    from rich.table import Table

    from engine_model.channels import UNITS

    con = console()
    con.print("[bold]hyprog engine model versus C-MAPSS[/]")
    con.print(f"reference: {path}", soft_wrap=True)
    for rec in records:
        con.print(f"\n[bold]row {rec['row']}[/]: alt {rec['alt_kft'] * 1000:g} ft,"
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
