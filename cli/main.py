"""The ``hyprog`` console script: the root typer app and its sub-apps.

Exit codes (one rule for every command, README "Bad input")
-----------------------------------------------------------
- 0: done.
- 1: a computation failed (e.g. the steady state did not converge); the message says where.
- 2: bad input or usage: a file, column, row, unit or option value the user can fix, and
  click's own usage errors (unknown option, missing argument, a value of the wrong type).
  Exactly one ``error: ...`` line on stderr, no traceback, no box.
- 130: interrupted (Ctrl-C); 143: terminated (SIGTERM, turned into an exit so that locks
  are released and worker processes ended, :func:`cli.common.terminate_as_exit`); both
  print one line, ``error: interrupted`` or ``error: terminated``.

The root group (:class:`HyprogGroup`) runs click in non-standalone mode and prints click's
usage errors as that one line; :func:`cli.common.user_errors` does the same for the library's
:class:`engine_model.InputError`.
"""

from __future__ import annotations

import sys

import typer
from typer.core import TyperGroup

from cli import (
    adapt,
    calibrate,
    data,
    effects,
    evaluate,
    experiment,
    model,
    predict,
    simulate,
    train,
)
from cli import discover as discover_cmd
from cli import pipeline as pipeline_cmd
from cli.common import (
    APP_SETTINGS,
    EXIT_USAGE,
    TERMINATED,
    PlainUsageCommand,
    error_line,
    exit_code_after,
    forget_unhandled_interrupt,
    signal_line,
    terminate_as_exit,
)


def _click_class(name: str) -> type:
    """A click exception class, found through typer's public ``BadParameter`` / ``Abort`` (typer
    0.2x vendors its own click, so ``import click`` would name other classes)."""
    for c in (*typer.BadParameter.__mro__, *typer.Abort.__mro__):
        if c.__name__ == name:
            return c
    raise ImportError(f"typer has no click {name}")  # pragma: no cover


ClickException = _click_class("ClickException")
UsageError = _click_class("UsageError")
Abort = typer.Abort


class HyprogGroup(TyperGroup):
    """The root command: click's usage errors become one ``error:`` line and exit 2."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True,
             **extra):
        stopped = True  # by a signal, unless the command returns by itself
        try:
            with terminate_as_exit():  # SIGINT, SIGTERM: the finally blocks run (locks, workers)
                rv = super().main(args=args, prog_name=prog_name, complete_var=complete_var,
                                  standalone_mode=False, **extra)
            # typer returns 130 for a KeyboardInterrupt; any other return is the command's own
            # (a signal whose exception Python swallowed in a finalizer let it finish)
            stopped = rv == 130
        except ClickException as e:
            if type(e).__name__ == "NoArgsIsHelpError":  # a bare group: its help, one line
                e.show()
                ctx = getattr(e, "ctx", None)
                where = ctx.command_path if ctx is not None else "hyprog"
                typer.echo(error_line(f"{where}: missing a command (listed above)"), err=True)
                rv = EXIT_USAGE
            else:
                ctx = getattr(e, "ctx", None)
                where = f"{ctx.command_path}: " if ctx is not None else ""
                # (typer validates a Literal choice through pydantic, whose message starts
                # "Value error, ": the reader needs the value and the choices, not the layer)
                typer.echo(error_line(where + e.format_message().replace("Value error, ", "")),
                           err=True)
                rv = EXIT_USAGE
        except Abort:
            if not TERMINATED:
                typer.echo("error: aborted", err=True)
            rv = 130
        except (Exception, SystemExit, KeyboardInterrupt):
            if not TERMINATED:
                raise
            rv = None  # the signal's exit (or another error an extension's call made of it)
        if TERMINATED and standalone_mode:  # a further Ctrl-C must not cut the exit short
            import signal

            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, signal.SIG_IGN)
        if TERMINATED and stopped:  # Ctrl-C or SIGTERM ended the command: one line
            typer.echo(signal_line(), err=True)
            rv = exit_code_after(0)
        rv = rv if isinstance(rv, int) else 0
        forget_unhandled_interrupt()  # else `python -m` may die by SIGINT after exit 130
        if not standalone_mode:
            return rv
        sys.exit(rv)


app = typer.Typer(
    name="hyprog",
    cls=HyprogGroup,
    help="Hybrid physics + deep-learning prognostics for turbofan engine fleets.",
    no_args_is_help=True,
    **APP_SETTINGS,
)
#: (name, command or sub-app, the one line of the root's command list), in the order a user
#: meets them.
_COMMANDS = (
    ("pipeline", pipeline_cmd.pipeline, "Data to report: calibrate, discover, train, evaluate."),
    ("simulate", simulate.simulate, "Simulate a fleet to failure (data with the true health)."),
    ("data", data.app, "Inspect datasets; import C-MAPSS."),
    ("calibrate", calibrate.app, "Estimate each unit's health parameters theta(t)."),
    ("discover", discover_cmd.discover, "Find what the engine model lacks, from residuals."),
    ("adapt", adapt.adapt, "Fit the effects every engine of a fleet shares."),
    ("effects", effects.effects, "List the effects the simulator and discover know."),
    ("train", train.train, "Train a RUL model on a feature table."),
    ("evaluate", evaluate.evaluate, "Score a RUL model on the test units."),
    ("predict", predict.predict, "Predict the RUL of every sample of a table."),
    ("experiment", experiment.app, "The paper's experiments and ablations."),
    ("model", model.app, "The engine model F(w, theta): points, envelope, reference."),
)
for _name, _target, _short in _COMMANDS:
    if isinstance(_target, typer.Typer):
        app.add_typer(_target, name=_name, short_help=_short)
    else:
        app.command(_name, cls=PlainUsageCommand, short_help=_short)(_target)


def _version(value: bool):
    if value:
        from importlib.metadata import PackageNotFoundError, version

        try:
            typer.echo(f"hyprog {version('hyprog')}")
        except PackageNotFoundError:
            typer.echo("hyprog (not installed)")
        raise typer.Exit()


@app.callback()
def main(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                 help="Print the version and exit."),
):
    """Hybrid physics + deep-learning prognostics for turbofan engine fleets."""


if __name__ == "__main__":  # pragma: no cover
    app()
