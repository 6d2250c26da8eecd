"""What every CLI test checks the same way: a runner that keeps stderr apart, and the
one-line error rule of the README ("Bad input"): exit code, exactly one ``error: ...`` line
on stderr naming the culprit, no traceback, no help box."""

from __future__ import annotations

import inspect

from typer.testing import CliRunner


def cli_runner() -> CliRunner:
    """A runner whose ``result.stderr`` is the command's stderr alone."""
    if "mix_stderr" in inspect.signature(CliRunner.__init__).parameters:
        return CliRunner(mix_stderr=False)  # click < 8.2: keep stderr apart
    return CliRunner()


def assert_user_error(result, *fragments, code: int | None = 2):
    """Exit ``code`` (None: any non-zero), one ``error: ...`` line on stderr holding every
    fragment, no traceback and no help box."""
    if code is None:
        assert result.exit_code != 0, (result.stdout, result.stderr)
    else:
        assert result.exit_code == code, (result.exit_code, result.stdout, result.stderr)
    assert isinstance(result.exception, SystemExit), repr(result.exception)
    err = result.stderr
    assert err.startswith("error: ") and len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err + result.stdout and "╭" not in err, err
    for f in fragments:
        assert f in err, (f, err)
