"""``hyprog effects``: the library of optional physical effects."""

from __future__ import annotations

from typing import Annotated

import typer

from cli.common import Quiet, console, echo_json


def effects(
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
    quiet: Quiet = False,
):
    """List the effect library: name, parameters, units, default, realistic and valid ranges,
    and the channels each effect moves. Switch one on in a simulation with
    'hyprog simulate --effect NAME[:param=value,...]'.

    \b
    Example:
      hyprog effects --json
    """
    from engine_model.physics.effects import describe_effects

    lib = describe_effects()
    if as_json:
        echo_json(lib)
        return
    from rich.table import Table

    out = console()
    for e in lib:
        out.print(f"[bold]{e['name']}[/bold] ({e['kind']}): {e['description']}")
        t = Table(box=None, padding=(0, 1, 0, 2))
        for col in ("parameter", "unit", "default", "typical", "range", "valid", "kind"):
            t.add_column(col, no_wrap=True)
        for o in e["options"]:
            t.add_row(o, "", "", "", "", "", "option")
        for q in e["parameters"]:
            rng, valid = q["range"], q.get("valid")
            t.add_row(q["name"], q["unit"], _fmt(q["default"]), _fmt(q["typical"]),
                      "" if rng is None else f"{_fmt(rng[0])} .. {_fmt(rng[1])}",
                      "any" if valid is None else
                      f"{_fmt(valid[0]) or '-inf'} .. {_fmt(valid[1]) or 'inf'}", q["kind"])
        out.print(t)
        for q in e["parameters"]:
            out.print(f"  {q['name']}: {q['description']}")
        out.print("  moves: " + ", ".join(e["moves"]) + "\n")


def _fmt(v):
    return "" if v is None else f"{v:g}"
