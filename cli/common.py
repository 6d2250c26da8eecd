"""Helpers shared by the CLI commands: one-line errors, JSON output, the console, the shared
engine model, the options every command takes (``--quiet``) and the parsers of options several
commands take (``--units``, lists, ``--format``)."""

from __future__ import annotations

import json
import sys
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Literal, get_args

import typer
from typer.core import TyperCommand

EXIT_FAILED = 1  # a computation failed (no convergence)
EXIT_USAGE = 2  # bad input or usage (cli.main docstring: the exit-code rule)

QUIET_HELP = ("Print nothing but errors and warnings: no progress bars, status lines or "
              "closing summary (the result is in the output; --json prints a summary). A "
              "command whose result is a printed table still prints it. Every command takes it.")


def names_a_path(annotation) -> bool:
    """Whether a parameter's annotation is a path (``Path``, ``Path | None``, ``list[Path]``)."""
    return annotation is Path or any(names_a_path(a) for a in get_args(annotation))


class PlainUsageCommand(TyperCommand):
    """A command whose usage line names its arguments as click and POSIX do (``MODEL_DIR``,
    ``[DATA]``), not typer's ``{MODEL_DIR}``, and that refuses an empty path (``""`` would
    otherwise become ``Path("")``, the current directory: an unset shell variable in
    ``--out "$DIR"`` must not read or replace ``.``). Every command is registered with it
    (``@app.command(NAME, cls=PlainUsageCommand)``)."""

    def parse_args(self, ctx, args: list[str]) -> list[str]:
        if not ctx.resilient_parsing:
            opts, _, _ = self.make_parser(ctx).parse_args(args=list(args))
            for param in self.get_params(ctx):
                raw = opts.get(param.name)
                values = raw if isinstance(raw, list | tuple) else (raw,)
                if "" in values and names_a_path(param.type_descriptor.annotation):
                    raise typer.BadParameter("an empty path; name a file or folder",
                                             ctx=ctx, param=param)
        return super().parse_args(ctx, args)

    def collect_usage_pieces(self, ctx) -> list[str]:
        pieces = [self.options_metavar] if self.options_metavar else []
        for param in self.get_params(ctx):
            if param.param_type_name != "argument":
                continue
            name = param.metavar or param.name.upper()
            name = name if param.required else f"[{name}]"
            pieces.append(name + ("..." if param.nargs != 1 else ""))
        return pieces


#: Settings of every typer app: plain click help (rich markup would print ``<bool>`` after
#: every flag and swallow ``[run]``-style TOML table names), tracebacks never decorated.
APP_SETTINGS = {"rich_markup_mode": None, "pretty_exceptions_enable": False}

#: ``--quiet``, the same on every command (scripts pass it uniformly): a command's parameter
#: ``quiet: Quiet = False``.
Quiet = Annotated[bool, typer.Option("--quiet", help=QUIET_HELP)]

OVERWRITE_HELP = ("Replace --out even when hyprog did not write it (a file or folder of other "
                  "data), or when it holds files hyprog did not write (they are deleted). "
                  "Without it only hyprog's own earlier output is replaced. Never replaces a "
                  "special file (pipe, device) or what the command reads.")

#: ``--overwrite``, the same on every command that replaces its output (the ownership rule,
#: :mod:`engine_model.runtime.ownership`): a parameter ``overwrite: Overwrite = False``.
Overwrite = Annotated[bool, typer.Option("--overwrite", help=OVERWRITE_HELP)]
Noise = Annotated[Literal["model", "data"] | None, typer.Option(
    "--noise", help="The sensor noise in R: 'model' (the simulator's documented noise) or "
    "'data' (each sensor's std per operating condition, estimated from the data's early-life "
    "cycles within units; needs a condition column, as a C-MAPSS import has) (default: "
    "model).")]
ModelError = Annotated[str | None, typer.Option(
    "--model-error", help="The model's own error, a relative std added to the noise in "
    "quadrature, or 'consistent': the one at which the filter's mean normalised innovation "
    "squared per channel is 1 over the fleet (several calibrations) (default: 0).")]


def parse_model_error(text: str | None) -> float | None:
    """``--model-error``: a number, or 'consistent' (0 here: found later from the data, by
    :func:`calibration.consistency.with_measured_noise`); None when not given."""
    if text is None:
        return None
    try:
        return 0.0 if text == "consistent" else float(text)
    except ValueError:
        raise CliError(f"--model-error {text}: a relative std such as 0.003, or "
                       "'consistent'") from None


class CliError(Exception):
    """A mistake in the user's input, reported as one line (no traceback)."""


def console(stderr: bool = False):
    """The rich console of the commands' text output. In a pipe or a file its lines are not
    folded at 80 columns (a message stays one line, for grep); in a terminal they fold at its
    width."""
    from rich.console import Console

    c = Console(stderr=stderr, highlight=False)
    c.soft_wrap = not c.is_terminal
    return c


def wide_console(table):
    """The stdout console, as wide as ``table`` needs when stdout is not a terminal (rich
    would otherwise fold a wide table, headers too, at 80 columns in a pipe or a file)."""
    from rich.console import Console
    from rich.measure import Measurement

    c = console()
    need = Measurement.get(c, c.options.update_width(10_000), table).maximum
    if c.is_terminal or need <= c.width:
        return c
    return Console(highlight=False, width=need)


@contextmanager
def progress_bar(description: str, off: bool = False
                 ) -> Iterator[Callable[..., None] | None]:
    """A progress bar on stderr, drawn on a terminal only and removed when done; yields the
    callback ``update(done, total, description=None)`` for the library's ``progress``
    argument, or None when ``off`` (``--quiet``, ``--json``)."""
    if off:
        yield None
        return
    from rich.progress import Progress

    err = console(stderr=True)
    with Progress(console=err, transient=True, disable=not err.is_terminal) as bar:
        task = bar.add_task(description, total=None)

        def update(done: int, total: int, description: str | None = None) -> None:
            extra = {} if description is None else {"description": description}
            bar.update(task, completed=done, total=total, **extra)

        yield update


def error_line(message: str) -> str:
    """``error: <message>`` on one line (whitespace and newlines collapsed)."""
    return "error: " + " ".join(str(message).split())


@contextmanager
def caught_warnings() -> Iterator[list[str]]:
    """The library's warnings raised inside the block, for :func:`finish` to print or put in
    the ``--json`` report (:func:`engine_model.validation.collected_warnings`)."""
    from engine_model.validation import collected_warnings

    with collected_warnings() as messages:
        yield messages


def finish(report: dict, warned: list[str], as_json: bool) -> bool:
    """End a command: with ``--json`` print ``report`` with its ``warnings`` (a list, empty
    when none) and return True; else print each warning as a ``warning:`` line on stderr and
    return False (the caller prints its text)."""
    if as_json:
        echo_json({**report, "warnings": list(warned)})
        return True
    for m in warned:
        warn(m)
    return False


def warn(message: str) -> None:
    """One ``warning: ...`` line on stderr (text mode; ``--json`` reports carry warnings)."""
    typer.echo("warning: " + " ".join(str(message).split()), err=True)


def fail(message: str, code: int = EXIT_USAGE):
    """Print one ``error:`` line and exit with ``code``: :data:`EXIT_USAGE` (2) for bad
    input, :data:`EXIT_FAILED` (1) for a computation that failed."""
    typer.echo(error_line(message), err=True)
    raise typer.Exit(code)


@contextmanager
def user_errors(source: object = None, output: object = None) -> Iterator[None]:
    """Turn the errors a user can act on into one line on stderr and exit code 2 (bad
    input; :mod:`cli.main` states the rule). ``source``: what the block reads, named in an
    error that names no file; ``output``: what it writes, named instead of a hidden temporary
    (``.NAME.tmp-...``, :mod:`engine_model.runtime.atomic`) and for a failed write that
    names no file (a full disk)."""
    import pandas as pd

    from engine_model import InputError

    where = f"{source}: " if source is not None else ""

    def named(e: OSError, default: object) -> str:
        name = e.filename
        if name is not None and output is not None and ".tmp-" in str(name):
            name = output
        name = name if name is not None else default
        return "" if name is None else f"{name}: "

    try:
        yield
    except (CliError, InputError) as e:
        text = str(e)
        fail(text if source is not None and str(source) in text else f"{where}{text}")
    except FileNotFoundError as e:
        fail(f"{named(e, source)}no such file")
    except IsADirectoryError as e:
        fail(f"{named(e, source)}is a directory, expected a file")
    except OSError as e:
        writing = output if output is not None else source
        fail(f"{named(e, writing)}{e.strerror or e}")
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        fail(f"{where}cannot read as CSV: {e}")


#: Signals received inside :func:`terminate_as_exit`. The SystemExit its handler raises can
#: land inside an extension's call (e.g. CasADi converting a matrix), which may turn it into
#: another error; the entry point then still exits ``128 + signum`` (:func:`exit_code_after`).
TERMINATED: list[int] = []

#: The one line the entry point prints after a signal (:func:`signal_line`).
SIGNAL_WORDS = {2: "interrupted", 15: "terminated"}


def exit_code_after(default: int) -> int:
    """``128 + signum`` if a termination signal arrived, else ``default``."""
    return 128 + TERMINATED[0] if TERMINATED else default


def signal_line() -> str | None:
    """``error: interrupted`` (SIGINT) or ``error: terminated`` (SIGTERM) when a signal
    ended the command, else None."""
    if not TERMINATED:
        return None
    return error_line(SIGNAL_WORDS.get(TERMINATED[0], f"signal {TERMINATED[0]}"))


def forget_unhandled_interrupt() -> None:
    """Clear CPython's record of a KeyboardInterrupt that ended a string ``exec``.

    CPython (3.8 to 3.12 at least) sets ``_PyRuntime.signals.unhandled_keyboard_interrupt``
    when code run from a string (``exec("...")``: ``dataclasses``, ``namedtuple`` and
    friends build classes that way) ends with a KeyboardInterrupt, even when a caller then
    catches it; under ``python -m`` ``Py_RunMain`` reads that flag at exit and kills the
    process with SIGINT, so a Ctrl-C we handled (one ``error: interrupted`` line, exit 130)
    would be reported as death by signal (-2) whenever it happened to land inside such an
    exec. The flag is reset at the start of every string evaluation, so evaluating an empty
    string clears it (Modules/main.c ``pymain_run_module``, Python/pythonrun.c
    ``run_eval_code_obj``)."""
    exec("pass", {})  # noqa: S102 - a constant string: only its side effect on the flag


#: Seconds between the re-raises of a termination signal whose exception was lost
#: (:func:`terminate_as_exit`).
SIGNAL_RETRY_S = 0.02


def _signal_exception(signum: int) -> BaseException:
    """KeyboardInterrupt for SIGINT, ``SystemExit(128 + signum)`` for the others."""
    import signal

    return KeyboardInterrupt() if signum == signal.SIGINT else SystemExit(128 + signum)


@contextmanager
def terminate_as_exit() -> Iterator[None]:
    """Inside the block SIGINT (Ctrl-C) raises KeyboardInterrupt and SIGTERM SystemExit(143),
    both recorded in :data:`TERMINATED`, so that the ``finally`` blocks run (the output lock
    released, temporaries removed, worker processes ended) and the entry point ends with one
    line (:func:`signal_line`) and exit ``128 + signum`` (130, 143) whatever the command did
    with the exception (typer turns KeyboardInterrupt into a silent exit 130). Only in the
    main thread (signals go there).

    **An exception that is lost is raised again.** Python runs a signal's handler between two
    bytecodes of whatever code runs then, and some of that code discards exceptions: CasADi's
    SWIG wrappers try each overload of a call and clear the error of those that do not match
    (their type checks call Python, e.g. ``shape`` -> ``size1``), and an exception in a
    finalizer is dropped (Python would print it as "Exception ignored"; inside the block
    ``sys.unraisablehook`` keeps such a signal exception off stderr). Measured: about 1 in 20
    Ctrl-C of ``discover`` was lost that way and the run went on to the end. So after the
    first signal a watcher thread sends the same signal to the main thread every
    :data:`SIGNAL_RETRY_S` s (``signal.pthread_kill``: it also interrupts a blocking wait)
    until the block is left, and the handler raises the exception again, except while an
    exception is being handled (``sys.exc_info()``: the signal's own exception running the
    ``finally`` and ``except`` blocks it meets, which must finish their clean-up
    undisturbed). A further Ctrl-C of the user is treated the same way: clean-up is never cut
    short (SIGKILL or Ctrl-\\ end the process at once). A signal that arrives while the block
    is being left is recorded and raises nothing; one inside a critical section (a lock
    being taken, a folder being swapped) reaches this handler only after the section, which
    holds it back itself (:mod:`engine_model.runtime.critical`). Worker processes are spawned,
    not forked, so none inherits the handlers or the thread."""
    import signal
    import threading
    import time

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    leaving, stop, retry = [], threading.Event(), [False]
    main_id = threading.get_ident()

    def _watch():
        while not stop.wait(SIGNAL_RETRY_S):
            retry[0] = True
            signal.pthread_kill(main_id, TERMINATED[0])

    watcher = threading.Thread(target=_watch, name="hyprog-signal-retry", daemon=True)

    def _on_signal(signum, frame):
        if leaving:
            if not TERMINATED:
                TERMINATED.append(signum)
            return
        if TERMINATED:  # the watcher's resend, or the user's next Ctrl-C
            retry[0] = False
            if sys.exc_info()[1] is not None:
                return
            raise _signal_exception(TERMINATED[0])
        TERMINATED.append(signum)
        watcher.start()
        raise _signal_exception(signum)

    def _unraisable(u):  # a finalizer dropped the signal's exception: it is raised again
        if not (TERMINATED and isinstance(u.exc_value, (KeyboardInterrupt, SystemExit))):
            previous_hook(u)

    TERMINATED.clear()  # a signal of an earlier command of this process is not this one's
    previous = {sig: signal.signal(sig, _on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    previous_hook, sys.unraisablehook = sys.unraisablehook, _unraisable
    try:
        yield
    finally:
        leaving.append(True)
        try:
            stop.set()
            if watcher.is_alive():
                watcher.join()
            time.sleep(0)  # run a resend that arrived before the watcher stopped: a no-op now
        finally:
            for sig, fn in previous.items():
                signal.signal(sig, fn)
            sys.unraisablehook = previous_hook


def get_model(quiet: bool = False):
    """The process-wide engine model (:func:`engine_model.runtime.shared_model.default_model`),
    with a status line on a terminal while it is built (none with ``quiet``)."""
    from engine_model.runtime.shared_model import default_model, is_built

    if not quiet and not is_built() and sys.stderr.isatty():
        with console(stderr=True).status(
                "building the engine model (the first run compiles C, later ones load it)"):
            return default_model()
    return default_model()


def split_items(text: str, option: str) -> list[str]:
    """The comma-separated items of ``text``, stripped; an empty list, an empty item
    (``"1,,2"``, ``"1,"``) or an item given twice is a one-line error naming ``option``."""
    items = [s.strip() for s in text.split(",")]
    if not any(items):
        raise CliError(f"{option} {text!r}: empty list")
    if not all(items):
        raise CliError(f"{option} {text!r}: an empty item (two commas, or one at an end)")
    twice = sorted({s for s in items if items.count(s) > 1})
    if twice:
        raise CliError(f"{option} {text}: {', '.join(twice)} listed twice")
    return items


def parse_list(text: str | None, option: str) -> tuple[str, ...] | None:
    """``"a, b,c"`` -> ``("a", "b", "c")`` (:func:`split_items`); None when the option was
    not given."""
    if text is None:
        return None
    return tuple(split_items(text, option))


def parse_drift(text: str | None) -> float | None:
    """The ``--drift`` option's number; None when not given or ``mle`` (what that means is
    the command's: ``calibrate`` keeps the setup's default unless ``mle``, where
    :func:`calibration.discrepancy.drift_mle.setup_with_drift_mle` estimates it; ``discover``
    estimates it in both cases); anything else that is not a positive, finite number is a
    one-line error."""
    if text is None or text == "mle":
        return None
    try:
        v = float(text)
    except ValueError:
        raise CliError(f"--drift {text}: expected 'mle' or a number") from None
    if not 0 < v < float("inf"):
        raise CliError(f"--drift {text}: must be positive and finite")
    return v


#: How every unit-list option's help says what it takes (:func:`parse_units`).
UNIT_LIST = "(comma-separated; ranges: 1-20,25)"

#: The most units one range of ``--units`` may name (``1-1000000000`` is a typing error, not
#: a fleet, and would build a list of that length).
MAX_RANGE_UNITS = 1_000_000


def parse_units(text: str | None, option: str = "--units") -> list[int] | None:
    """``"2,5,10"`` -> ``[2, 5, 10]``, ``"1-3,7"`` -> ``[1, 2, 3, 7]`` (a range includes
    both ends); None (all units) when the option was not given (an empty value is an error,
    not "all")."""
    if text is None:
        return None
    units = []
    for item in split_items(text, option):
        first, dash, last = item.partition("-")
        try:
            if dash and first:  # "1-3"; "-3" is the integer -3
                a, b = int(first), int(last)
                if b < a:
                    raise CliError(f"{option} {text}: range {item} runs backwards")
                if b - a >= MAX_RANGE_UNITS:
                    raise CliError(f"{option} {text}: range {item} names more than "
                                   f"{MAX_RANGE_UNITS:,} units")
                units += range(a, b + 1)
            else:
                units.append(int(item))
        except ValueError:
            raise CliError(f"{option} {text}: expected comma-separated integers or ranges "
                           f"(e.g. 1-20,25)") from None
    twice = sorted(u for u, n in Counter(units).items() if n > 1)
    if twice:  # "1,01", "1-5,3"
        raise CliError(f"{option} {text}: unit(s) {', '.join(map(str, twice))} listed twice")
    return units


def check_choice(value: str, option: str, choices: Sequence[str]) -> str:
    """``value`` if it is one of ``choices`` (e.g. ``--format``), else a one-line error."""
    if value not in choices:
        raise CliError(f"{option} {value}: expected {' or '.join(choices)}")
    return value


def echo_json(obj):
    """Print ``obj`` as indented JSON (:func:`engine_model.datasets.jsonable.jsonable`: numpy
    values as Python numbers, NaN and infinities as null)."""
    from engine_model.datasets.jsonable import jsonable

    typer.echo(json.dumps(jsonable(obj), indent=2, allow_nan=False))
