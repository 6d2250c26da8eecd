"""``--help`` of every ``hyprog`` command, found by walking the typer app: plain text (no reST
double backticks leaking into the terminal, no "[default]" eaten by rich's markup), exit 0,
and an example in every command that runs
something (the groups list their commands)."""

import re

import pytest
import typer
from typer.testing import CliRunner

from cli.main import app


def _paths(command, path=()):
    yield path, command
    for name, sub in sorted((getattr(command, "commands", None) or {}).items()):
        yield from _paths(sub, (*path, name))


COMMANDS = list(_paths(typer.main.get_command(app)))


def test_the_walk_finds_every_command():
    names = {" ".join(p) for p, _ in COMMANDS}
    assert {"pipeline", "train", "calibrate run", "data import-cmapss", "model point",
            "experiment paper", "discover", "effects", "simulate"} <= names


@pytest.mark.parametrize("path", [p for p, _ in COMMANDS], ids=lambda p: " ".join(p) or "root")
def test_help_is_plain_text_with_an_example(path):
    command = dict(COMMANDS)[path]
    res = CliRunner().invoke(app, [*path, "--help"], terminal_width=100)
    assert res.exit_code == 0, res.stdout
    text = res.stdout
    assert "``" not in text, text
    # rich reads "[...]" in a help string as markup and drops it: "window [60]." -> "window ."
    assert not re.search(r"\w \.(\s|$)", text), text
    assert "Usage:" in text
    if not hasattr(command, "commands"):  # a leaf: it does something, show how
        assert "Example: hyprog " + path[0] in text, text
