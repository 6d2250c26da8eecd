"""Helpers shared by the CLI commands: one-line errors, JSON output, the console."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from contextlib import contextmanager

import typer


class CliError(Exception):
    """A mistake in the user's input, reported as one line (no traceback)."""


def console(stderr: bool = False):
    from rich.console import Console

    return Console(stderr=stderr, highlight=False)


def fail(message: str, code: int = 1):
    typer.echo("error: " + " ".join(str(message).split()), err=True)
    raise typer.Exit(code)


@contextmanager
def user_errors(source: object = None) -> Iterator[None]:
    """Turn the errors a user can act on into one line on stderr and exit code 1."""
    import pandas as pd

    from engine_model import InputError

    where = f"{source}: " if source is not None else ""
    try:
        yield
    except (CliError, InputError) as e:
        fail(f"{where}{e}")
    except FileNotFoundError as e:
        fail(f"{e.filename or source}: no such file")
    except IsADirectoryError as e:
        fail(f"{e.filename or source}: is a directory, expected a file")
    except OSError as e:
        fail(f"{e.filename or source}: {e.strerror or e}")
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        fail(f"{where}cannot read as CSV: {e}")


def plain(v):
    """A JSON-ready Python scalar: NaN and infinities become null."""
    if hasattr(v, "item"):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def echo_json(obj):
    def walk(o):
        if isinstance(o, dict):
            return {str(k): walk(v) for k, v in o.items()}
        if isinstance(o, (list, tuple)):
            return [walk(v) for v in o]
        return plain(o)

    typer.echo(json.dumps(walk(obj), indent=2, allow_nan=False))
